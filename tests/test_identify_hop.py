"""A payload the mission says is unknown (``[payload] identify = true``): the hop before the cruise, the
identification beside the loop, and the flight going on with what it found (issue 28). The pieces on their own,
then whole flights against the bundled vehicle carrying 0.35 kg on 1.3 m while the mission's vehicle says
0.25 kg on 1 m: lockstep, and real time (the identification in its thread)."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from companion.core.mission import PayloadConfig, load_mission
from companion.core.obstacles import Obstacle
from companion.estimation.estimate import Estimate
from companion.estimation.payload_id import PayloadId
from companion.estimation.swing_estimator import SwingEstimator
from companion.estimation.swing_feed import SwingFeed
from companion.estimation.vehicle_state import VehicleState
from companion.flight.core import FlightCore
from companion.flight.core_hop import HOP_M, HOP_WINDOW_S, hop_room_m
from companion.flight.identification import Identification
from companion.flight.phase import CorePhase

pytestmark = pytest.mark.paired  # wall clock, light: may run beside one other such test (tests/conftest.py)

ROOT = Path(__file__).resolve().parents[1]
FOREST = ROOT / "config" / "missions" / "forest.toml"


def _unknown_payload_mission(**payload):
    m = load_mission(FOREST)
    return replace(m, payload=PayloadConfig(identify=True, **payload))


def test_hop_room_stops_short_of_a_trunk_and_is_whole_in_the_open():
    east = np.array([0.0, 1.0])
    trunk = Obstacle(x_m=0.0, y_m=2.0, radius_m=0.3, safe_distance_m=0.1)
    assert hop_room_m(np.zeros(2), east, [], 1.0) == pytest.approx(HOP_M)
    # the point must stay 1.0 m outside the 0.4 m ring: room up to y = 2.0 - 1.4 = 0.6 m
    assert hop_room_m(np.zeros(2), east, [trunk], 1.0) == pytest.approx(0.6, abs=0.051)
    assert hop_room_m(np.zeros(2), east, [trunk], 2.0) == 0.0


def test_the_climb_ends_in_the_hop_only_when_the_mission_asks():
    assert FlightCore(load_mission(FOREST))._after_climb() is CorePhase.CRUISE
    core = FlightCore(_unknown_payload_mission())
    assert core._after_climb() is CorePhase.IDENTIFY
    core.hop_target_ned_m = np.zeros(3)  # flown once
    assert core._after_climb() is CorePhase.CRUISE


def test_an_identified_long_cable_rebuilds_the_flight_for_it():
    mission = _unknown_payload_mission()
    core = FlightCore(mission)
    a_tuned = core.cfg.planner.shaped_a_max_mps2
    core.phase = CorePhase.IDENTIFY
    core.end_identify(replace(mission.vehicle, m=0.5, l=2.0))
    assert core.hop_identified and core._identify_done(_est("cable_sensor"))  # the cable sensor: cruise at once
    assert core.params.m == 0.5 and core.params.l == 2.0
    assert core.cfg.planner.shaped_a_max_mps2 < a_tuned  # the longer pendulum: gentler accelerations
    assert core._full_cable_r_max > FlightCore(mission)._full_cable_r_max
    assert core._thrust_max > FlightCore(mission)._thrust_max  # the heavier total: more thrust allowed


def _est(source: str, fade: float = 1.0, t_s: float = 10.0) -> Estimate:
    return Estimate(t_s=t_s, pos_ned_m=np.array([0.0, 0.0, -2.0]), vel_ned_mps=np.zeros(3), euler_rad=np.zeros(3),
                    rates_frd_rad_s=np.zeros(3), swing=np.zeros(4), swing_source=source, swing_fade=fade)


def test_a_restarted_swing_estimator_is_waited_for_before_the_cruise():
    """A sensorless flight's estimator restarts on the identified payload: the cruise waits for its trust (as after
    the climb, up to swing_wait_s), not cruising off on an untrusted estimate."""
    core = FlightCore(_unknown_payload_mission())
    core.swing_wait_s = 5.0
    core.phase = CorePhase.IDENTIFY
    assert not core._identify_done(_est("estimate", fade=1.0))  # not identified yet
    core.end_identify(None)
    assert not core._identify_done(_est("estimate", fade=0.2, t_s=10.0))
    assert core._identify_done(_est("estimate", fade=0.95, t_s=10.5))  # trusted
    core.t_swing_wait_s = None
    assert not core._identify_done(_est("estimate", fade=0.2, t_s=20.0))
    assert core._identify_done(_est("estimate", fade=0.2, t_s=25.0))  # or the wait is over


def test_no_imu_no_identification_the_declared_payload_flies_on():
    mission = _unknown_payload_mission()
    core = FlightCore(mission)
    core.phase = CorePhase.IDENTIFY
    ident = Identification(mission)
    ident.on_tick(CorePhase.IDENTIFY, 10.0)
    assert not ident.due
    ident.on_tick(CorePhase.IDENTIFY, 10.0 + HOP_WINDOW_S)
    assert ident.due
    assert ident.conclude(core) is None
    assert core.hop_identified and core.params.m == mission.vehicle.m
    assert not ident.used["mass_identified"] and not ident.used["cable_identified"]
    assert "too few samples" in ident.used["reason"]
    assert not ident.due


def test_a_given_mass_is_kept_and_a_payload_too_heavy_to_lift_ends_the_flight():
    mission = _unknown_payload_mission(mass_kg=0.3)  # the mass is measured, the cable is not
    ident = Identification(mission)
    core = FlightCore(mission)
    ident.watch._result = PayloadId(cable_length_m=1.6, payload_mass_kg=0.9, mass_ratio=0.42,
                                    cable_length_sigma_m=0.01, payload_mass_sigma_kg=0.01, swing_signal_mps2=0.3,
                                    residual_mps2=0.01, n_samples=400, window_s=8.0, ok=True)
    feed = SwingFeed(mission.companion_params())
    feed.estimator = SwingEstimator(mission.companion_params())  # a sensorless flight's estimator, running
    state = VehicleState(cable_length_m=1.0)
    assert ident.conclude(core, feed, state) is None
    assert core.params.m == 0.3 and core.params.l == 1.6
    assert feed.estimator is None and feed.params.l == 1.6  # restarts on the identified cable at the next tick
    assert state.cable_length_m == 1.6
    # a cable the swing pins down is flown even when the mass (blurred by the wind) is not trusted
    blurred = Identification(_unknown_payload_mission())
    blurred.watch._result = replace(ident.watch._result, payload_mass_kg=0.17, payload_mass_sigma_kg=0.07)
    core = FlightCore(blurred.mission)
    assert blurred.conclude(core) is None
    assert core.params.m == blurred.mission.vehicle.m and core.params.l == 1.6
    assert blurred.used["cable_identified"] and not blurred.used["mass_identified"]
    assert blurred.used["reason"].startswith("too uncertain: mass ± 0.070 kg")
    heavy = Identification(_unknown_payload_mission())
    heavy.watch._result = replace(ident.watch._result, payload_mass_kg=2.0, mass_ratio=0.6)
    reason = heavy.conclude(FlightCore(heavy.mission))
    assert reason is not None and "needs 0.8" in reason and "limit 0.75" in reason


def _fly(tmp_path: Path, *extra: str) -> tuple[subprocess.CompletedProcess, dict]:
    text = FOREST.read_text().replace('model = "paper"', 'model = "none"') + "\n[payload]\nidentify = true\n"
    mission = tmp_path / "unknown_payload.toml"
    mission.write_text(text)
    run = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "companion.cli", "-q", "fly", "--sitl", "--mission", str(mission),
                        "--no-zenoh", "--no-plots", "--planner", "shaped", "--run-dir", str(run),
                        "--true-payload-mass-kg", "0.35", "--true-cable-length-m", "1.3", *extra],
                       capture_output=True, text=True, timeout=300, cwd=ROOT)
    return r, json.loads((run / "report.json").read_text())


def _assert_identified_and_flown(r: subprocess.CompletedProcess, rep: dict) -> None:
    assert r.returncode == 0, (rep.get("outcome"), rep.get("outcome_detail"), r.stderr[-2000:])
    assert rep["outcome"] == "completed" and rep["collisions"] == 0
    flown = rep["payload"]["flown"]
    assert flown["mass_identified"] and flown["cable_identified"] and 0.5 <= flown["hop_m"] <= HOP_M
    assert flown["mass_kg"] == pytest.approx(0.35, rel=0.05)
    assert flown["cable_length_m"] == pytest.approx(1.3, rel=0.05)
    assert rep["payload"]["identified"]["ok"] and rep["payload"]["identified"]["window_s"] <= HOP_WINDOW_S


@pytest.mark.slow
@pytest.mark.shares_cores
def test_lockstep_flight_hops_identifies_and_flies_the_identified_payload(tmp_path):
    _assert_identified_and_flown(*_fly(tmp_path))


@pytest.mark.slow
def test_real_time_flight_identifies_beside_the_loop(tmp_path):
    r, rep = _fly(tmp_path, "--realtime")
    _assert_identified_and_flown(r, rep)
    assert rep["loop"]["tick_errors"] == 0


def test_in_process_flights_skip_the_hop_and_fly_the_declared_payload():
    from lab.inprocess import fly_inprocess

    mission = replace(_unknown_payload_mission(), timeout_s=20.0, hold_s=3.0)  # the safe planner (not timed)
    flog = fly_inprocess(mission, stop_when_done=True)
    assert 1 <= flog.phase.count("identify") <= 2  # the tick that entered it, then straight on
    assert "cruise" in flog.phase and flog.phase[-1] == "done"
    # the hold at the goal is at the goal (it once hovered back to the hop's point, through the forest)
    end = np.asarray(flog.pos[-1])
    assert abs(end[0] - mission.goal_ned_m[0]) < 0.2 and abs(end[1] - mission.goal_ned_m[1]) < 0.2, end
