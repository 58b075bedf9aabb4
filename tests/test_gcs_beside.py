"""Beside a ground station (issue 27): a pymavlink GCS reaches the companion through MAVProxy, a real router, while
the companion flies the bundled vehicle (real time, loopback UDP, real processes).

Topology: MAVProxy forwards between its master and its outputs, never between two outputs, so the companion is its
master and the vehicle and the GCS are outputs (mavlink-router, ArduPilot's routing and PX4's forwarding route
between all their links; docs/autopilots.md, *Beside a ground station*)::

    vehicle (sim_bridge) ──udp── MAVProxy ──udp── companion (fly --connect udpin)
                                    └─────udp── GCS (pymavlink, system 255)

The GCS orders a landing mid-leg and the vehicle lands where it was. (The pause, the resume and a pause refused
from another system are tested in one flight with a ground station's uploaded mission:
tests/test_operator_mission_e2e.py.)
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from _operator_helpers import COMPANION, MAVPROXY, mavproxy_flight
from pymavlink.dialects.v20 import common as M

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(shutil.which("mavproxy.py", path=str(MAVPROXY.parent)) is None,
                                 reason="MAVProxy is not installed in this environment")]
FLY_ARGS = ["--planner", "safe"]


@pytest.mark.paired  # wall clock, light: may run beside one other such test (tests/conftest.py)
def test_gcs_land_lands_where_the_vehicle_is(tmp_path):
    """MAV_CMD_NAV_LAND to the companion mid-leg: ACCEPTED, it brakes, the vehicle lands there; outcome aborted."""
    with mavproxy_flight(tmp_path, FLY_ARGS) as (gcs, fly, run):
        gcs.pump(1.5)  # mid-leg
        gcs.conn.mav.command_long_send(*COMPANION, M.MAV_CMD_NAV_LAND, 0, 0, 0, 0, 0, 0, 0, 0)
        assert gcs.pump(5.0, lambda: any(a[1] == M.MAV_CMD_NAV_LAND for a in gcs.acks)), (gcs.acks, gcs.texts)
        assert gcs.pump(120.0, lambda: gcs.said("slungpilot done")), gcs.texts
        err = fly.communicate(timeout=120)[1]
    rep = json.loads((run / "report.json").read_text())
    assert [a[2] for a in gcs.acks if a[1] == M.MAV_CMD_NAV_LAND] == [M.MAV_RESULT_ACCEPTED]
    assert rep["outcome"] == "aborted" and rep["final_phase"] == "landed", (rep["outcome"], rep["final_phase"],
                                                                           err[-2000:])
    assert "land ordered by the ground station (system 255)" in rep["outcome_detail"]
    t_land = rep["operator"]["orders"][0]["t_s"]
    log = np.load(run / "flight_log.npz")
    t, pos = log["t_s"], log["pos_ned_m"]
    asked_at = pos[np.searchsorted(t, t_land), :2]
    print(json.dumps({"landed_from_asked_m": float(np.hypot(*(pos[-1, :2] - asked_at))), "final_z": float(pos[-1, 2]),
                      "collisions": rep["collisions"]}))
    assert float(np.hypot(*(pos[-1, :2] - asked_at))) < 3.0 and rep["collisions"] == 0
