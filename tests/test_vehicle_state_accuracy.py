"""VehicleState (pure) reads PX4's ESTIMATOR_STATUS horizontal accuracy into the estimate (the arrival tolerance
follows it). Real MAVLink frames, packed and parsed by pymavlink."""

from __future__ import annotations

import time

from pymavlink.dialects.v20 import common as mavlink2

from companion.estimation.vehicle_state import VehicleState

M = mavlink2


def _wire(msg, sysid: int = 1):
    tx = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=1)
    return mavlink2.MAVLink(None).parse_char(msg.pack(tx))


def test_estimator_status_accuracy_reaches_the_estimate_and_nonsense_is_ignored():
    st = VehicleState(cable_length_m=1.0, max_time_rate=1e4)
    now = time.monotonic()
    st.ingest(_wire(M.MAVLink_heartbeat_message(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4, 0, 0, 0, 3)), now)
    st.ingest(_wire(M.MAVLink_attitude_message(1000, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)), now)
    st.ingest(_wire(M.MAVLink_local_position_ned_message(1000, 0.0, 0.0, -2.0, 0.0, 0.0, 0.0)), now)
    assert st.estimate().pos_accuracy_m is None  # nothing reported: the default tolerance
    status = M.MAVLink_estimator_status_message(1_000_000, 0, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.35, 0.5)
    st.ingest(_wire(status), now)
    assert abs(st.estimate().pos_accuracy_m - 0.35) < 1e-6  # (a float32 on the wire)
    bad = M.MAVLink_estimator_status_message(1_000_000, 0, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1, float("nan"), 0.5)
    st.ingest(_wire(bad), now)
    assert abs(st.estimate().pos_accuracy_m - 0.35) < 1e-6  # a NaN does not replace what was known
