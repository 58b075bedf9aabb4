"""VehicleState (pure) reads PX4's ESTIMATOR_STATUS horizontal accuracy into the estimate (the arrival tolerance
follows it). Real MAVLink frames, packed and parsed by pymavlink."""

from __future__ import annotations

import time

from pymavlink.dialects.v20 import common as mavlink2

from companion.estimation.vehicle_state import VehicleState
from companion.mavlink_io.telemetry import decode

M = mavlink2


def _wire(msg, sysid: int = 1):
    """The typed event of ``msg`` as it comes off the wire (packed and parsed by pymavlink)."""
    tx = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=1)
    return decode(mavlink2.MAVLink(None).parse_char(msg.pack(tx)))


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


def test_a_reordered_cable_angle_sample_is_rejected_not_taken():
    """The swing sensor's samples obey the same rule as position and attitude: one older than the sample held
    (a reordered datagram) is counted as out_of_order and the newer one stays (the feed-forward once saw the
    swing jump back and forth in time under 50 ± 25 ms of jitter)."""
    st = VehicleState(cable_length_m=1.0, max_time_rate=1e4)
    now = time.monotonic()
    st.ingest(_wire(M.MAVLink_heartbeat_message(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4, 0, 0, 0, 3)), now)

    def swing(t_us: int, alpha: float):
        return _wire(M.MAVLink_debug_float_array_message(t_us, b"SWING", 1, [alpha, 0.0, 0.0, 0.0, 1.0] + [0.0] * 53))

    assert st.ingest(swing(1_000_000, 0.10), now) != "REJECTED"
    assert st.ingest(swing(1_020_000, 0.12), now) != "REJECTED"
    assert st.ingest(swing(1_004_000, 0.05), now) == "REJECTED"  # arrived late, after the 1.020 s sample
    assert st.rejected["out_of_order"] == 1
    assert abs(st.swing_sensor[0] - 0.12) < 1e-6 and st.swing_sensor_t_s == 1.02
    assert st.ingest(swing(1_024_000, 0.13), now) != "REJECTED" and abs(st.swing_sensor[0] - 0.13) < 1e-6
