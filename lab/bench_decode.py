"""Micro-benchmark of the companion's telemetry input path: µs per received message (issue 25).

The message mix is the bundled vehicle's lockstep stream (one 4 ms tick: ATTITUDE, LOCAL_POSITION_NED, the
cable-angle DEBUG_FLOAT_ARRAY, HIGHRES_IMU, SYSTEM_TIME; every fifth tick also GLOBAL_POSITION_INT,
ATTITUDE_QUATERNION, ATTITUDE_TARGET and the payload's LOCAL_POSITION_NED and GLOBAL_POSITION_INT), packed
as real frames. Timed per message, as the flight app handles it:

* ``lite``: ``codec.decode_lite`` alone (what the link does before the app sees a message);
* ``lite+ingest``: that, then what the flight does with the message (``Runner._on_message`` and
  ``Pilot.on_telemetry``; before typed telemetry ``FlightApp._on_message``): ``decode`` to a typed event where the
  code has it, ``VehicleState.ingest``, ``SwingFeed.ingest``, the link health's frame and sample bookkeeping, the
  lockstep marker check, ``RequestLink.answer_of``;
* ``frame+ingest`` (typed code only): ``codec.check_crc`` + ``telemetry.decode_frame`` straight from the frame's
  bytes (no message object, as a loop reading frames itself could), then the same;
* ``decode``: ``telemetry.decode`` alone, from the LiteMessage.

    python -m lab.bench_decode [--ticks 2000] [--rounds 7] [--compare /work/base]

``--compare DIR`` runs the same measurement with ``PYTHONPATH=DIR`` (e.g. a checkout of older code, which has no
typed telemetry) in alternation with this code, so both see the same machine load; the best round of each is
printed. Times are the process's CPU time (a busy machine's waits left out). Speed is printed, never asserted.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any


class _Sink:
    def __init__(self) -> None:
        self.frames: list[bytes] = []

    def write(self, buf: bytes) -> None:
        self.frames.append(bytes(buf))


def stream(ticks: int) -> list[bytes]:
    """The frames of ``ticks`` lockstep ticks of the bundled vehicle (system 1) and its payload (system 2)."""
    import math

    from pymavlink.dialects.v20 import common as M

    from companion.mavlink_io import codec

    veh = M.MAVLink(_Sink(), srcSystem=1, srcComponent=1)
    pay = M.MAVLink(veh.file, srcSystem=2, srcComponent=1)
    codec.send_heartbeat(veh, M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4, 129, 6 << 16, M.MAV_STATE_ACTIVE)
    codec.send_extended_sys_state(veh, 0, M.MAV_LANDED_STATE_IN_AIR)
    for k in range(ticks):
        ms = 1000 + 4 * k
        s = math.sin(0.01 * k)
        codec.send_attitude(veh, ms, 0.05 * s, -0.03 * s, 0.2, 0.1 * s, 0.02, -0.01)
        codec.send_local_position_ned(veh, ms, 0.01 * k, 0.5 * s, -3.0, 2.5, 0.3 * s, -0.01)
        codec.send_debug_float_array5(veh, ms * 1000, b"SWING", 1, 0.1 * s, -0.05 * s, 0.2, -0.1, 1.0)
        veh.highres_imu_send(ms * 1000, 0.3 * s, -0.1, -9.7, 0.01, 0.02, 0.03, 0.2, 0.0, 0.4, 1013.0, 0.0, 40.0,
                             25.0, 0x1FFF, 0)
        if k % 5 == 0:
            codec.send_global_position_int(veh, ms, 473977420 + k, 85455940 + k, 491000, 3000, 250, 3, -1, 9000)
            codec.send_attitude_quaternion(veh, ms, 1.0, 0.0, 0.0, 0.1, 0.01, 0.02, 0.03)
            codec.send_attitude_target(veh, ms, 0, (1.0, 0.0, 0.0, 0.0), 0.0, 0.0, 0.0, 0.6)
            codec.send_local_position_ned(pay, ms, 0.01 * k, 0.5 * s, -2.0, 2.5, 0.3 * s, -0.01)
            codec.send_global_position_int(pay, ms, 473977420 + k, 85455940 + k, 490000, 2000, 250, 3, -1, 9000)
        codec.send_system_time(veh, 0, ms)
    return veh.file.frames


def _consumers() -> tuple[Any, Any, Any, Any]:
    from pymavlink.dialects.v20 import common as M

    from companion.core.vehicle_params import VehicleParams
    from companion.estimation.swing_feed import SwingFeed
    from companion.estimation.vehicle_state import VehicleState
    from companion.flight.health import LinkHealth
    from companion.mavlink_io.commands import RequestLink

    state = VehicleState(cable_length_m=1.0, payload_sysid=2, max_time_rate=1e6)
    feed = SwingFeed(VehicleParams(), "auto")
    req = RequestLink(M.MAVLink(_Sink()), lambda: (state.vehicle_sysid, state.vehicle_compid), lambda w: [0.0])
    return state, feed, req, LinkHealth(period_s=0.004)


def _untyped(msgs: list[Any]) -> float:
    """Seconds for what ``FlightApp._on_message`` did per message before typed telemetry (less the answers)."""
    state, feed, req, health = _consumers()
    marker = -1
    t0 = time.process_time()
    for msg in msgs:
        wall = time.monotonic()
        mtype = state.ingest(msg, wall)
        if mtype != "REJECTED":
            feed.ingest(mtype, msg, state)
        src = msg.get_srcSystem()
        if src == state.vehicle_sysid:
            health.on_frame(src, msg.get_srcComponent(), msg.get_seq())
            if mtype == "LOCAL_POSITION_NED":
                health.on_sample("position", state.pos_t_s)
            elif mtype == "ATTITUDE":
                health.on_sample("attitude", state.att_t_s)
            elif mtype == "SYSTEM_TIME" and msg.time_boot_ms != marker:
                marker = msg.time_boot_ms
        req.answer_of(msg)
    return time.process_time() - t0


def _typed(msgs: list[Any], decode: Any, source: Any) -> float:
    """Seconds for what ``Runner._on_message`` / ``Runner._on_frame`` do per message: decode, then the flight's own
    :meth:`~companion.flight.pilot.Pilot.on_telemetry` (or ``on_unread_frame``), and the answer check."""
    from pymavlink.dialects.v20 import common as M

    from companion.config import resolve_mission
    from companion.core.mission import load_mission
    from companion.flight.pilot import Pilot
    from companion.flight.setup import FlightSetup
    from companion.mavlink_io.commands import RequestLink

    pilot = Pilot(load_mission(resolve_mission("forest")), FlightSetup(lockstep=True))
    st = pilot.state
    req = RequestLink(M.MAVLink(_Sink()), lambda: (st.vehicle_sysid, st.vehicle_compid), lambda w: [0.0])
    t0 = time.process_time()
    for msg in msgs:
        wall = time.monotonic()
        ev = decode(msg)
        if ev is None:
            pilot.on_unread_frame(*source(msg))
            continue
        pilot.on_telemetry(ev, wall)
        req.answer_of(ev)
    return time.process_time() - t0


def measure(ticks: int) -> dict[str, float]:
    """µs per message of each path over one pass of :func:`stream`'s frames (fresh state each pass)."""
    from companion.mavlink_io import codec

    try:
        from companion.mavlink_io import telemetry
    except ImportError:  # code from before typed telemetry (issue 25)
        telemetry = None
    frames = stream(ticks)
    n = len(frames)
    out: dict[str, float] = {}
    t0 = time.process_time()
    lites = [codec.decode_lite(f) for f in frames]
    lite_s = time.process_time() - t0
    out["lite"] = lite_s / n * 1e6
    if telemetry is None:
        out["lite+ingest"] = (lite_s + _untyped(lites)) / n * 1e6
        return out
    typed_s = _typed(lites, telemetry.decode, lambda m: (m.get_srcSystem(), m.get_srcComponent(), m.get_seq()))
    out["lite+ingest"] = (lite_s + typed_s) / n * 1e6
    # the frames straight to events, as a loop without message objects can read them (CRC checked first)
    check, decode_frame = codec.check_crc, telemetry.decode_frame
    t0 = time.process_time()
    good = [f for f in frames if check(f, f[7] | (f[8] << 8) | (f[9] << 16))]
    check_s = time.process_time() - t0
    out["frame+ingest"] = (check_s + _typed(good, decode_frame, lambda f: (f[5], f[6], f[4]))) / n * 1e6
    t0 = time.process_time()
    for m in lites:
        telemetry.decode(m)
    out["decode"] = (time.process_time() - t0) / n * 1e6
    return out


def _best(rounds: list[dict[str, float]]) -> dict[str, float]:
    return {k: round(min(r[k] for r in rounds), 3) for k in rounds[0]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m lab.bench_decode", description=__doc__.split("\n\n")[0])
    ap.add_argument("--ticks", type=int, default=2000, help="ticks of telemetry per round (default 2000)")
    ap.add_argument("--rounds", type=int, default=7, help="rounds (default 7); the best is printed")
    ap.add_argument("--compare", type=Path, metavar="DIR", help="also run the code at DIR (PYTHONPATH), alternating")
    ap.add_argument("--json", action="store_true", help="one round as JSON (used by --compare)")
    args = ap.parse_args(argv)
    measure(200)  # warm-up: imports, caches, the first frames' lazy work
    if args.json:
        print(json.dumps(measure(args.ticks)))
        return 0
    here: list[dict[str, float]] = []
    there: list[dict[str, float]] = []
    for _ in range(args.rounds):
        if args.compare is not None:
            env = dict(os.environ, PYTHONPATH=str(args.compare))
            res = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--json", "--ticks", str(args.ticks)],
                                 env=env, capture_output=True, text=True, check=True, cwd=str(args.compare))
            there.append(json.loads(res.stdout.strip().splitlines()[-1]))
        here.append(measure(args.ticks))
    n = len(stream(args.ticks))
    print(f"telemetry input, µs per message (best of {args.rounds} rounds of {n} messages):")
    if there:
        print(f"  {args.compare}: {_best(there)}")
    print(f"  this code: {_best(here)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
