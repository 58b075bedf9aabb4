"""Replay a flown run's ``flight.tlog`` through the swing estimator, offline (issue 11).

A flight against a real autopilot takes minutes of real time; its tlog keeps every datagram both ways. This feeds
the recorded telemetry, in the order the companion received it, through the same decoding, :class:`VehicleState` and
:class:`SwingFeed` the flight app uses, and at each setpoint the companion sent (one per tick) asks for the tick's
estimate and hands the estimator the thrust that tick commanded (from the run's ``flight_log.npz``). So an
estimator change can be scored on a recorded ArduCopter SIM_SLUP flight in seconds, with another
``--swing-input`` or noise configuration. The replay is open loop: the flight itself does not change, only what the
estimator would have said.

Scores: against the payload's position fixes (ArduPilot's convention; each fix against the estimate of its own
time, as the report's ``swing_estimator.error_at_fixes``) and against the cable-angle sensor where the vehicle has
one (the bundled vehicle; the report's ``swing_estimation_error``).

    python -m lab.swing_replay RUN_DIR [--swing-input estimate_imu] [--set q_force=1.0 ...]
"""

from __future__ import annotations

import argparse
import bisect
import json
import math
import sys
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from companion.core.mission import load_mission
from companion.estimation.swing_config import SwingEstimatorConfig
from companion.estimation.swing_feed import ESTIMATOR_INPUTS, SLACK_FRACTION, SwingFeed, estimator_config
from companion.estimation.swing_model import swing_from_offset
from companion.estimation.vehicle_state import VehicleState
from companion.mavlink_io.link import tlog_messages
from companion.mavlink_io.telemetry import decode


@dataclass
class ReplayResult:
    """What the estimator would have said over the flight."""

    swing_input: str
    ticks: int
    estimated_ticks: int
    fix_error: dict[str, float | int] | None  # vs the payload's fixes (rad)
    sensor_error: dict[str, float | int] | None  # vs the cable-angle sensor (rad)
    counts: dict[str, int]
    series: dict[str, np.ndarray]  # per tick: t_s, alpha, beta, sensor_alpha, sensor_beta (NaN where absent),
    # fade, sigma_rad, drag_n_per_mps, payload_drag_n_per_mps2; "fixes": (n, 3) taut payload fixes (t s, α, β rad)

    def summary(self) -> dict[str, Any]:
        return {"swing_input": self.swing_input, "ticks": self.ticks, "estimated_ticks": self.estimated_ticks,
                "error_at_fixes": self.fix_error, "error_vs_sensor": self.sensor_error, "counts": self.counts}


def _thrust_lookup(run_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    with np.load(run_dir / "flight_log.npz") as z:
        return np.asarray(z["t_s"], dtype=float), np.asarray(z["thrust_n"], dtype=float)


def _tick_row(state: VehicleState, feed: SwingFeed, tick_t: np.ndarray, tick_thrust: np.ndarray) -> tuple | None:
    """One tick of the replay, as the app does it (start the feed, choose the swing, tell it the thrust the flight
    commanded at that tick): (t s, estimate's α, β, the cable sensor's α, β (rad), fade, σ (rad), drag, payload
    drag); NaN where there is none. None before the first estimate."""
    est = state.estimate()
    if est is None:
        return None
    feed.maybe_start(state)
    chosen = feed.choose(est)
    i = bisect.bisect_left(tick_t, est.t_s - 1e-6)
    if i < len(tick_t) and abs(tick_t[i] - est.t_s) < 1e-3 and tick_thrust[i] > 0.0:
        feed.commanded(est.t_s, float(tick_thrust[i]))
    sensor = state.swing_sensor if state.swing_sensor is not None and \
        est.t_s - state.swing_sensor_t_s <= state.swing_max_age_s else None
    se = feed.last
    return (est.t_s,
            float(chosen.swing[0]) if se is not None else math.nan,
            float(chosen.swing[1]) if se is not None else math.nan,
            float(sensor[0]) if sensor is not None else math.nan,
            float(sensor[1]) if sensor is not None else math.nan,
            se.fade if se is not None else math.nan,
            se.sigma_rad if se is not None else math.nan,
            se.drag_n_per_mps if se is not None else math.nan,
            se.payload_drag_n_per_mps2 if se is not None else math.nan)


def _sensor_error(arr: np.ndarray) -> dict[str, Any] | None:
    """The estimate's swing against the cable sensor's over the ticks that have both (rad): count, RMS, max."""
    both = np.all(np.isfinite(arr[:, 1:5]), axis=1)
    if not np.any(both):
        return None
    e = np.hypot(arr[both, 1] - arr[both, 3], arr[both, 2] - arr[both, 4])
    return {"ticks": int(both.sum()), "rms_rad": float(np.sqrt(np.mean(e ** 2))), "max_rad": float(e.max())}


def replay(run_dir: Path, swing_input: str = "estimate_imu", settings: dict[str, Any] | None = None,
           payload_sysid: int = 2, payload_mass_kg: float | None = None,
           cable_length_m: float | None = None) -> ReplayResult:
    """Replay ``run_dir`` (a ``slungpilot fly`` run folder with ``flight.tlog``, ``flight_log.npz`` and
    ``mission.toml``) through a fresh estimator fed as ``swing_input`` would feed it, configured as the app
    configures it from the mission, with ``settings`` (SwingEstimatorConfig fields) changed; ``payload_mass_kg``
    / ``cable_length_m`` replace the mission's (its ``[payload]`` table)."""
    if swing_input not in ESTIMATOR_INPUTS:
        raise ValueError(f"swing_input: one of {ESTIMATOR_INPUTS}, got {swing_input!r}")
    mission = load_mission(run_dir / "mission.toml")
    params = mission.companion_params()
    params = replace(params, m=params.m if payload_mass_kg is None else payload_mass_kg,
                     l=params.l if cable_length_m is None else cable_length_m)
    params.validate()
    state = VehicleState(cable_length_m=params.l, payload_sysid=payload_sysid, swing_input=swing_input)
    config = replace(estimator_config(mission), **(settings or {}))
    config.validate()
    feed = SwingFeed(params, swing_input, config)
    tick_t, tick_thrust = _thrust_lookup(run_dir)
    ours: tuple[int, int] | None = None  # our (system, component): the companion shares the vehicle's system
    rows: list[tuple[float, ...]] = []
    fixes: list[tuple[float, float, float]] = []  # taut payload fixes (t s, α, β rad)
    ticks = 0
    for wall, msg in tlog_messages(run_dir / "flight.tlog"):
        mtype = msg.get_type()
        if mtype == "SET_ATTITUDE_TARGET":  # one of our ticks (sent after the tick's estimate)
            me = (msg.get_srcSystem(), msg.get_srcComponent())
            if ours is None:
                ours = me
            if me != ours:
                continue
            ticks += 1
            row = _tick_row(state, feed, tick_t, tick_thrust)
            if row is not None:
                rows.append(row)
            continue
        if ours is not None and (msg.get_srcSystem(), msg.get_srcComponent()) == ours:
            continue  # our own commands and requests
        ev = decode(msg)
        if ev is None:
            continue
        mt = state.ingest(ev, wall)
        if mt != "REJECTED":
            feed.ingest(ev, state)
            if mt == "GLOBAL_POSITION_INT":
                for t_fix, off, _vel in feed.take_fresh_offsets():
                    if float(np.linalg.norm(off)) >= SLACK_FRACTION * feed.params.l:
                        fixes.append((t_fix, *swing_from_offset(off)))
    arr = np.array(rows, dtype=float).reshape(-1, 9)
    sensor_err = _sensor_error(arr)
    series = {k: arr[:, j] for j, k in enumerate(("t_s", "alpha", "beta", "sensor_alpha", "sensor_beta", "fade",
                                                   "sigma_rad", "drag_n_per_mps", "payload_drag_n_per_mps2"))}
    series["fixes"] = np.array(fixes, dtype=float).reshape(-1, 3)
    return ReplayResult(swing_input, ticks, int(np.isfinite(arr[:, 1]).sum()), feed.fix_error_summary(),
                        sensor_err, dict(feed.counts), series)


def parse_settings(sets: list[str]) -> dict[str, Any]:
    """``KEY=VALUE`` items (SwingEstimatorConfig fields; a value is a number or a JSON list) as a dict."""
    names = {f.name for f in fields(SwingEstimatorConfig)}
    changes: dict[str, Any] = {}
    for item in sets:
        key, _, value = item.partition("=")
        if key not in names:
            raise SystemExit(f"--set {item}: no such estimator setting (one of {', '.join(sorted(names))})")
        parsed = json.loads(value) if value[:1] == "[" else float(value)
        changes[key] = tuple(parsed) if isinstance(parsed, list) else parsed
    return changes


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m lab.swing_replay", description=__doc__.split("\n\n")[0])
    ap.add_argument("run_dir", type=Path, help="a run folder with flight.tlog, flight_log.npz and mission.toml")
    ap.add_argument("--swing-input", default="estimate_imu", choices=ESTIMATOR_INPUTS)
    ap.add_argument("--payload-sysid", type=int, default=2, help="the payload's MAVLink system (default 2)")
    ap.add_argument("--payload-mass", type=float, metavar="KG", help="the payload mass the estimator assumes")
    ap.add_argument("--cable-length", type=float, metavar="M", help="the cable length the estimator assumes")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="an estimator setting (SwingEstimatorConfig field), e.g. q_force=1.0; repeatable")
    args = ap.parse_args(argv)
    try:
        res = replay(args.run_dir, args.swing_input, parse_settings(args.set), args.payload_sysid, args.payload_mass,
                     args.cable_length)
    except ValueError as exc:  # a setting or override out of range
        raise SystemExit(f"error: {exc}") from None
    print(json.dumps(res.summary(), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
