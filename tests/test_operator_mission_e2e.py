"""Issue 27's acceptance flow in one flight (real processes, loopback UDP, real time).

A MAVSDK ground station uploads a take-off, four waypoints through the Table 2 forest (one held 2 s), a landing and
a fence (inclusion square, exclusion circle) to the bundled vehicle on its own GCS link; ``slungpilot fly
--connect ... --mission autopilot --base-mission forest`` downloads and flies them through MAVProxy (the companion
is MAVProxy's master, the vehicle and the operator's link are its outputs: MAVProxy never forwards between two
outputs, docs/autopilots.md). On MAVProxy's output the ground station (system 255, the one the companion obeys)
hears the companion's STATUSTEXT and its HEARTBEAT (an onboard controller, not a second ground station), is refused a
pause under a system id it is not (DENIED, counted in the report), pauses the flight mid-leg
(MAV_CMD_DO_PAUSE_CONTINUE 0 to component 191), sees the vehicle hold, resumes it (param1 1) and the mission
completes: every waypoint in order, no collision, airframe and payload inside the fence all along (checked on the
flight log against the uploaded fence's geometry).

Timing is generous on waiting, never on speed: a command without an answer is sent again (the command protocol),
and the hold is measured from 5 s after the pause (the reference brakes at its own limits first).
"""

from __future__ import annotations

import asyncio
import json
import shutil

import numpy as np
import pytest
from _operator_helpers import (
    DEFAULT_HOME,
    MAVPROXY,
    ROUTE,
    fence_margins_m,
    mavproxy_flight,
    mavsdk_upload,
    route_fence,
)
from pymavlink.dialects.v20 import common as M

pytestmark = [pytest.mark.slow,
              pytest.mark.paired,  # outcomes only, 0.4 of a core over 36 s: may run beside one other such test
              pytest.mark.skipif(shutil.which("mavproxy.py", path=str(MAVPROXY.parent)) is None,
                                 reason="MAVProxy is not installed in this environment")]
FLY_ARGS = ["--mission", "autopilot", "--base-mission", "forest", "--planner", "safe"]
HOLD_S = 8.0  # how long the ground station keeps the flight paused


def _upload(port: int) -> None:
    """The MAVSDK ground station's upload on the vehicle's GCS link (listening on ``port``), then it leaves."""

    async def go() -> None:
        drone = await asyncio.wait_for(mavsdk_upload(f"udpin://127.0.0.1:{port}", DEFAULT_HOME), 120.0)
        drone.destroy()

    asyncio.run(go())


def _pause_mid_leg(gcs, fly) -> None:
    """Pause once the cruise is 1.5 s old, hold ``HOLD_S``, resume; then wait for the end."""
    gcs.pump(1.5)  # mid-leg, moving
    assert gcs.command(0, as_sysid=200) == (M.MAV_RESULT_DENIED, 200)  # not the GCS it obeys
    assert gcs.command(0) == (M.MAV_RESULT_ACCEPTED, 255), gcs.texts
    assert gcs.pump(10.0, lambda: gcs.said("paused")), gcs.texts
    gcs.pump(HOLD_S)
    assert gcs.command(1) == (M.MAV_RESULT_ACCEPTED, 255), gcs.texts
    assert gcs.pump(240.0, lambda: gcs.said("slungpilot done")), gcs.texts


def test_a_ground_station_s_mission_is_flown_paused_resumed_and_completed_through_mavproxy(tmp_path):
    pytest.importorskip("mavsdk.asyncio", reason="mavsdk (the test extra) is not installed")
    with mavproxy_flight(tmp_path, FLY_ARGS, before_fly=_upload) as (gcs, fly, run):
        _pause_mid_leg(gcs, fly)
        err = fly.communicate(timeout=120)[1]
    rep = json.loads((run / "report.json").read_text())
    texts = [x[2] for x in gcs.texts]
    assert fly.returncode == 0 and rep["outcome"] == "completed", (rep["outcome"], rep.get("outcome_detail"),
                                                                   err[-2000:])
    am = rep["autopilot_mission"]  # what was flown is what the ground station uploaded
    assert am["items"] == 6 and am["fence_items"] == 5 and am["home_shift_m"] == [0.0, 0.0, 0.0]
    assert np.allclose(am["waypoints"], [[n, e, -alt] for n, e, alt, _ in ROUTE], atol=0.02)
    # every waypoint, in order (the held one within reach), then the goal
    legs = rep["waypoints"]
    reached = [w["reached_at_s"] for w in legs]
    assert [w["name"] for w in legs] == ["item 1", "item 2", "item 3", "goal"] and None not in reached, legs
    assert reached == sorted(reached) and legs[1]["closest_m"] < 0.3
    assert rep["collisions"] == 0 and rep["reached_goal"]
    log = np.load(run / "flight_log.npz")
    n, margin = fence_margins_m(log, route_fence())
    assert n > 1000 and margin > 0.0, margin  # airframe and payload inside the fence, every sample
    # the pause: asked mid-leg while moving, then held still until the resume
    op = rep["operator"]
    assert set(op["denied_by_sender"]) == {"200/190"} and op["gcs_sysid"] == 255  # once (twice if an ACK was lost)
    assert any("denied" in x for x in texts), texts
    orders = {o["order"]: o["t_s"] for o in op["orders"]}
    t_pause, t_resume = orders["pause"], orders["resume"]
    t, pos, vel = log["t_s"], log["pos_ned_m"], log["vel_ned_mps"]
    speed = np.hypot(vel[:, 0], vel[:, 1])
    held = (t > t_pause + 5.0) & (t < t_resume)
    print(json.dumps({"pause_s": t_pause, "resume_s": t_resume, "speed_at_pause": float(speed[np.searchsorted(
        t, t_pause)]), "held_speed_max": float(speed[held].max()), "fence_margin_m": margin,
        "time_to_goal_s": rep["time_to_goal_s"], "reached_at_s": reached, "texts": texts}, indent=1))
    assert speed[np.searchsorted(t, t_pause)] > 0.3
    assert held.sum() > 50 and speed[held].max() < 0.3 and np.ptp(pos[held, :2], axis=0).max() < 0.3
    assert reached[-1] is not None and t_resume < t[-1]
    # what the ground station heard: the companion's phases, the pause and resume, the end
    for phase in ("slungpilot mission:", "phase: climb", "phase: cruise", "companion: paused",
                  "companion: resuming", "slungpilot done: completed"):
        assert any(phase in x for x in texts), (phase, texts)
    assert set(gcs.companion_hb) == {M.MAV_TYPE_ONBOARD_CONTROLLER}
