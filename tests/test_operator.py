"""The ground station's commands to the companion, decided and carried out (issue 27; pure: no sockets): who may
command, what each command means in each phase and what is answered, and the flight sequence's reactions (pause
holds the core, continue resumes it, land lands where it is, return holds then lands)."""

from __future__ import annotations

import numpy as np
import pytest

from companion.core.mission import load_mission
from companion.flight import operator as op
from companion.flight.core import FlightCore
from companion.flight.phase import CoreOrder, CorePhase, State
from companion.flight.sequence import FlightSequence, Observation
from companion.mavlink_io.telemetry import CommandInt, CommandLong

PAUSE, CONTINUE = 0.0, 1.0


def _cmd(command: int, param1: float = 0.0, src: int = 255, target: tuple[int, int] = (1, 191)) -> CommandLong:
    return CommandLong(src, 190, 0, command, target[0], target[1], (param1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))


def test_who_may_command_and_what_is_answered_in_each_phase():
    desk = op.OperatorDesk()
    pause = _cmd(op.MAV_CMD_DO_PAUSE_CONTINUE, PAUSE)
    assert desk.on_command(pause, 1, State.MISSION, False).order is op.Order.PAUSE
    assert desk.on_command(_cmd(op.MAV_CMD_DO_PAUSE_CONTINUE, CONTINUE), 1, State.MISSION, True).order is \
        op.Order.RESUME
    # not ours: another component, another system, the broadcast component (the autopilot answers those)
    for target in ((1, 1), (2, 191), (1, 0)):
        assert desk.on_command(_cmd(op.MAV_CMD_NAV_LAND, target=target), 1, State.MISSION, False) is None
    assert desk.on_command(_cmd(op.MAV_CMD_NAV_LAND, target=(0, 191)), 1, State.MISSION, False).result == op.ACCEPTED
    # phases where it makes no sense: temporarily rejected, saying the phase
    ans = desk.on_command(pause, 1, State.ARM, False)
    assert ans.result == op.TEMPORARILY_REJECTED and ans.order is None and "arm" in ans.text
    assert desk.on_command(_cmd(op.MAV_CMD_NAV_LAND), 1, State.LAND, False).order is None  # already landing
    assert desk.on_command(_cmd(op.MAV_CMD_NAV_RETURN_TO_LAUNCH), 1, State.HOLD, False).order is op.Order.RETURN
    assert desk.on_command(_cmd(400), 1, State.MISSION, False).result == op.UNSUPPORTED
    ci = CommandInt(255, 190, 0, op.MAV_CMD_NAV_LAND, 1, 191, (0.0,) * 7, 6)  # COMMAND_INT alike
    assert desk.on_command(ci, 1, State.MISSION, False).order is op.Order.LAND
    # --gcs-sysid: that system only; others denied, said and counted by sender
    strict = op.OperatorDesk(gcs_sysid=255)
    ans = strict.on_command(_cmd(op.MAV_CMD_NAV_LAND, src=200), 1, State.MISSION, False)
    assert ans.result == op.DENIED and ans.to_system == 200 and "255" in ans.text and ans.order is None
    assert strict.on_command(_cmd(op.MAV_CMD_NAV_LAND), 1, State.MISSION, False).result == op.ACCEPTED
    # signing on and no GCS named: nobody is obeyed
    assert op.OperatorDesk(signing=True).on_command(pause, 1, State.MISSION, False).result == op.DENIED
    assert strict.summary()["denied_by_sender"] == {"200/190": 1}


def _obs(t: float, **kw) -> Observation:
    return Observation(now_s=t, wall_s=t, heartbeat_wall_s=t, telemetry_wall_s=t, telemetry_ready=True,
                       vehicle_ready=True, armed=True, mode="offboard", on_ground=False, heartbeats=int(t * 10) + 1,
                       estimate_ok=True, **kw)


def _in_mission() -> FlightSequence:
    seq = FlightSequence()
    seq.state = State.MISSION
    seq._armed_seen = True
    return seq


def test_pause_holds_continue_resumes_land_lands_return_holds_then_lands():
    seq = _in_mission()
    seq.order(op.Order.PAUSE, "pause ordered")
    step = seq.step(_obs(1.0))
    assert seq.paused and step.core is CoreOrder.PAUSE and seq.state is State.MISSION
    seq.order(op.Order.RESUME, "resume ordered")
    step = seq.step(_obs(2.0))
    assert not seq.paused and step.core is CoreOrder.RESUME and seq.outcome == "running"
    assert [o for _, o in seq.orders_done] == [op.Order.PAUSE, op.Order.RESUME]
    seq.order(op.Order.LAND, "land ordered by the ground station (system 255)")
    step = seq.step(_obs(3.0))
    assert seq.state is State.LAND and step.core is CoreOrder.PAUSE
    assert seq.outcome == "aborted" and "ground station" in seq.detail
    ret = _in_mission()
    ret.order(op.Order.RETURN, "return ordered")
    step = ret.step(_obs(1.0))
    assert ret.state is State.HOLD and step.core is CoreOrder.PAUSE and ret.outcome == "aborted"


def test_the_core_resumes_where_it_paused_and_still_holds_at_the_goal():
    mission = load_mission("config/missions/forest.toml")
    core = FlightCore(mission)
    core.phase = CorePhase.CRUISE
    goal_hold = core._hold_ned_m.copy()
    core.hold_here(brake=True)
    assert core.phase is CorePhase.HOLD_HERE
    assert core.resume() and core.phase is CorePhase.CRUISE and not core._braking
    assert np.array_equal(core._hold_ned_m, goal_hold)  # at the goal it hovers at the goal, not where it paused
    assert not core.resume()  # nothing to resume now
    core.descend()
    assert not core.resume()


class _Wire:
    def __init__(self) -> None:
        self.frames: list[bytes] = []

    def write(self, buf) -> None:
        self.frames.append(bytes(buf))


def test_statustext_chunks_as_mavlink2_and_keeps_to_its_rate():
    from pymavlink.dialects.v20 import common as M

    from companion.mavlink_io import statustext as stx

    wire = _Wire()
    out = stx.StatusTextOut(M.MAVLink(wire, srcSystem=1, srcComponent=191), burst=6, rate_hz=2.0)
    long_text = "slungpilot hold: position or attitude older than 0.3 s (stale telemetry)"  # 73 characters
    out.say(4, long_text, 0.0)
    out.say(6, "x" * 100, 0.0)  # fills two chunks exactly: an empty third ends it
    rx = M.MAVLink(None)
    msgs = [m for f in wire.frames for m in rx.parse_buffer(f) or []]
    assert [(m.get_srcSystem(), m.get_srcComponent()) for m in msgs] == [(1, 191)] * 5
    assert [(m.id, m.chunk_seq) for m in msgs] == [(1, 0), (1, 1), (2, 0), (2, 1), (2, 2)]
    assert "".join(m.text for m in msgs[:2]) == long_text and msgs[0].severity == 4 and msgs[4].text == ""
    out.say(6, "short", 0.0)  # one token left: sent, id 0
    out.say(6, "later", 0.0)  # none left: waits
    assert out.sent == 6 and out.waiting == 1
    out.pump(0.4)  # 0.8 token: still waiting
    assert out.sent == 6
    out.pump(0.5)  # 1.0 token
    assert out.sent == 7 and out.waiting == 0
    for k in range(30):  # a flood: the queue keeps the newest 20
        out.say(6, f"t{k}", 0.5)
    assert out.dropped == 10 and out.waiting == 20


@pytest.mark.parametrize("planner", ["shaped", "safe"])
def test_a_paused_mission_holds_then_resumes_and_completes_with_every_planner(planner):
    """Closed loop in-process (the bundled physics, the flight core): paused mid-leg at 4.5 s the vehicle stops and
    hovers; resumed at 9 s it flies on to the goal, clean. The shaped planner stops along its checked path."""
    from companion.report.metrics import compute_metrics
    from companion.report.run_folder import log_arrays
    from lab.inprocess import fly_inprocess

    mission = load_mission("config/missions/forest.toml").with_(planner=planner)

    def orders(core, t_s):
        if abs(t_s - 4.5) < 1e-6:
            core.hold_here(brake=True)
        elif abs(t_s - 9.0) < 1e-6:
            assert core.resume()

    flog = fly_inprocess(mission, on_tick=orders)
    a = log_arrays(flog)
    t, v = a["t_s"], np.hypot(a["vel_ned_mps"][:, 0], a["vel_ned_mps"][:, 1])
    speed_at_pause = float(v[np.searchsorted(t, 4.5)])
    assert speed_at_pause > 1.0  # it was paused mid-leg, flying
    held = (t > 7.5) & (t < 9.0)
    assert float(v[held].max()) < 0.1  # stopped and hovering
    rep = compute_metrics(flog, mission)
    assert rep["reached_goal"] and rep["collisions"] == 0 and rep["time_to_goal_s"] > 9.0
