"""The pilot on its own: pure and synchronous, fed typed telemetry and the time, no sockets and no event loop.

A runner would send what ``tick`` returns; here the test reads it. These pin down the pilot's contract with its
runners: the vehicle is found from its HEARTBEAT (the runner then locks the link), a new lockstep marker is
reported once, set-up requests come back to be sent, answers route to the sequence, nothing is streamed before the
vehicle is ready, and a failing tick is caught at the tick's boundary.
"""

from __future__ import annotations

from companion.config import resolve_mission
from companion.core.mission import load_mission
from companion.flight.phase import State
from companion.flight.pilot import Pilot
from companion.flight.setup import FlightSetup
from companion.mavlink_io import telemetry as tm

MAV_TYPE_QUADROTOR, MAV_AUTOPILOT_PX4 = 2, 12


def _pilot() -> Pilot:
    return Pilot(load_mission(resolve_mission("forest")), FlightSetup(lockstep=True))


def _heartbeat(seq: int = 0) -> tm.Heartbeat:
    return tm.Heartbeat(1, 1, seq, MAV_TYPE_QUADROTOR, MAV_AUTOPILOT_PX4, 0, 0, 3)


def test_the_vehicle_is_found_from_its_heartbeat_once_and_the_setup_is_asked():
    p = _pilot()
    first = p.on_telemetry(_heartbeat(), wall_s=0.0)
    again = p.on_telemetry(_heartbeat(1), wall_s=0.01)
    assert first.vehicle_found and not again.vehicle_found
    assert p.profile.autopilot == "px4" and p.state.vehicle_sysid == 1
    out = p.tick(wall_s=0.02)
    assert p.seq.state is State.CONFIGURE
    assert [r.key for r in out.requests][:1] == ["message_interval:ATTITUDE"]  # asked one at a time
    assert out.setpoint is None and out.est is None  # nothing streams before telemetry and readiness


def test_a_marker_is_reported_once_and_a_repeat_only_after_half_a_second():
    p = _pilot()
    p.on_telemetry(_heartbeat(), wall_s=0.0)
    marker = tm.SystemTime(1, 1, 2, 4)
    assert p.on_telemetry(marker, wall_s=1.0).marker
    assert not p.on_telemetry(tm.SystemTime(1, 1, 3, 4), wall_s=1.1).marker  # the same step asked again
    assert p.on_telemetry(tm.SystemTime(1, 1, 4, 4), wall_s=1.6).marker  # re-asked after a lost answer
    assert p.on_telemetry(tm.SystemTime(1, 1, 5, 8), wall_s=1.61).marker  # the next step


def test_answers_reach_the_sequence_and_parameters_are_kept_only_when_asked():
    p = _pilot()
    p.on_telemetry(_heartbeat(), wall_s=0.0)
    p.on_answer("param:MPC_THR_HOVER", 0.4)  # nobody asked yet: not kept
    assert p.params == {"read": {}, "set": {}}
    for _ in range(50):  # through the set-up, answering each request as PX4 would
        out = p.tick(wall_s=0.0)
        for r in out.requests:
            p.on_answer(f"param:{r.key[11:]}" if r.key.startswith("param_read:") else r.key, 0.4
                        if r.key.startswith("param_read:") else 0)
        if p.seq.state is State.WAIT_READY:
            break
    assert p.seq.state is State.WAIT_READY and p.params["read"] == {"MPC_THR_HOVER": 0.4}


def test_a_failing_tick_is_counted_at_the_boundary_not_raised():
    p = _pilot()
    p.on_telemetry(_heartbeat(), wall_s=0.0)

    def boom() -> None:
        raise RuntimeError("a bug in the estimate")

    p.state.estimate = boom  # the tick's first step fails
    out = p.tick(wall_s=0.0)
    assert out.setpoint is None and p.tick_errors == 1 and p.tick_errors_in_row == 1
