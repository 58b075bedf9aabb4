"""Beside a ground station (issue 27): a pymavlink GCS reaches the companion through MAVProxy, a real router, while
the companion flies the bundled vehicle (real time, loopback UDP, real processes).

Topology: MAVProxy forwards between its master and its outputs, never between two outputs, so the companion is its
master and the vehicle and the GCS are outputs (mavlink-router, ArduPilot's routing and PX4's forwarding route
between all their links; docs/autopilots.md, *Beside a ground station*)::

    vehicle (sim_bridge) ──udp── MAVProxy ──udp── companion (fly --connect udpin)
                                    └─────udp── GCS (pymavlink, system 255)

The GCS sees the companion's HEARTBEAT (an onboard controller, component 191) and its STATUSTEXT (phases), is
refused a pause under a system id it is not (DENIED, counted), pauses the flight mid-leg (the vehicle stops and
holds within 5 s), resumes it, and the mission completes.
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


def test_gcs_through_mavproxy_pauses_resumes_and_the_mission_completes(tmp_path):
    with mavproxy_flight(tmp_path, FLY_ARGS) as (gcs, fly, run):
        gcs.pump(1.5)  # mid-leg
        assert gcs.command(0, as_sysid=200) == (M.MAV_RESULT_DENIED, 200)  # not the GCS it obeys
        assert gcs.command(0) == (M.MAV_RESULT_ACCEPTED, 255), gcs.texts
        gcs.pump(8.0)
        assert gcs.command(1) == (M.MAV_RESULT_ACCEPTED, 255)
        assert gcs.pump(120.0, lambda: gcs.said("slungpilot done")), gcs.texts
        err = fly.communicate(timeout=120)[1]
    rep = json.loads((run / "report.json").read_text())
    assert fly.returncode == 0 and rep["outcome"] == "completed", (rep["outcome"], rep.get("outcome_detail"),
                                                                   err[-2000:])
    assert set(gcs.companion_hb) == {M.MAV_TYPE_ONBOARD_CONTROLLER}  # what it is, not a second ground station
    assert gcs.said("slungpilot done: completed") and any("denied" in t for _, _, t in gcs.texts)
    op = rep["operator"]
    assert set(op["denied_by_sender"]) == {"200/190"} and op["gcs_sysid"] == 255  # once (twice if an ACK was lost)
    orders = {o["order"]: o["t_s"] for o in op["orders"]}
    t_pause, t_resume = orders["pause"], orders["resume"]
    log = np.load(run / "flight_log.npz")
    t, pos, vel = log["t_s"], log["pos_ned_m"], log["vel_ned_mps"]
    speed = np.hypot(vel[:, 0], vel[:, 1])
    assert speed[np.searchsorted(t, t_pause)] > 0.5  # paused mid-leg, moving
    # the reference stops at the generator's limits and comes back to where the pause was asked (1.1 m past it and
    # back, 2026-12-03): still within 5 s
    held = (t > t_pause + 5.0) & (t < t_resume)
    assert held.sum() > 100
    at_pause = float(speed[np.searchsorted(t, t_pause)])
    drift = float(np.ptp(pos[held, :2], axis=0).max())
    print(json.dumps({"pause_s": t_pause, "resume_s": t_resume, "speed_at_pause": at_pause,
                      "held_speed_max": float(speed[held].max()), "held_drift_m": drift,
                      "time_to_goal_s": rep["time_to_goal_s"], "texts": [x[2] for x in gcs.texts]}, indent=1))
    assert speed[held].max() < 0.3 and np.ptp(pos[held, :2], axis=0).max() < 0.3  # stopped, and held there
    assert rep["collisions"] == 0


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
