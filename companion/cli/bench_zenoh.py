"""``bench zenoh`` and the small stand-in flight process used by the Zenoh tests.

``python -m companion.cli.bench_zenoh drive ...`` uses :class:`ZenohTelemetry` exactly as the flight app does:
one asyncio loop, per tick ``obstacles_now`` then the ``publish_*`` calls, sim time advancing by ``--dt``.
It prints one JSON line ``{"event": "ready", ...}`` when declared and ``{"event": "done", ...}`` at the end.

``python -m companion.cli.bench_zenoh sub ...`` is the receiving side of the benchmark: it counts samples of one
key, checks sequence gaps and measures publish-to-receive latency from the samples' ``wall_s``.

:func:`run_bench_zenoh` runs the benchmark between two processes over loopback and returns the numbers.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import math
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from typing import Any

import numpy as np
import zenoh

from companion import proclife
from companion.core.obstacles import Obstacle
from companion.zenoh_io.session import add_zenoh_arguments, zenoh_config, zenoh_config_from_args
from companion.zenoh_io.telemetry import ZenohTelemetry
from companion.zenoh_io.telemetry_options import TelemetryOptions

MISSION_OBSTACLES = (Obstacle(3.0, 0.5, 0.3), Obstacle(8.0, -0.5, 0.25))


def free_tcp_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def fake_swing(t_s: float) -> tuple[float, float, float, float]:
    """A smooth swing signal (rad, rad/s) for driving the streams."""
    w = 2.0 * math.pi * 0.5
    return (0.1 * math.sin(w * t_s), 0.05 * math.cos(w * t_s), 0.1 * w * math.cos(w * t_s),
            -0.05 * w * math.sin(w * t_s))


def _percentiles_us(xs: list[float]) -> dict[str, float]:
    a = np.asarray(xs) * 1e6 if xs else np.zeros(1)
    return {"p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99)), "mean": float(a.mean()),
            "max": float(a.max())}


async def _wait_matching(zt: ZenohTelemetry, timeout_s: float) -> bool:
    pub = zt._pubs["swing"]
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if pub.matching_status.matching:
            return True
        await asyncio.sleep(0.01)
    return False


async def drive(args: argparse.Namespace) -> dict[str, Any]:
    """The stand-in flight loop; returns the summary printed as the ``done`` event."""
    opts = TelemetryOptions(prefix=args.zenoh_prefix, vehicle_id=args.vehicle_id or "1")
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)
    cost_swing: list[float] = []
    cost_tick: list[float] = []
    async with ZenohTelemetry(zenoh_config_from_args(args, "companion"), opts) as zt:
        zt.set_config_provider(lambda: {
            "vehicle": {"id": opts.vehicle_id, "M": 1.25, "m": 0.25, "l": 1.0},
            "mission": {"name": "zenoh-driver", "obstacles": [o.as_dict() for o in MISSION_OBSTACLES]},
            "controller": {"kind": "smc"},
        })
        print(json.dumps({"event": "ready", "keys": zt.keys, "pid": os.getpid()}), flush=True)
        matched = await _wait_matching(zt, args.wait_match_s) if args.wait_match_s > 0 else False
        k = 0
        wall0 = time.perf_counter()
        while not stop.is_set() and (args.ticks <= 0 or k < args.ticks):
            t = k * args.dt
            t0 = time.perf_counter()
            obs = zt.obstacles_now(t, MISSION_OBSTACLES)
            swing = fake_swing(t)
            t1 = time.perf_counter()
            zt.publish_swing(t, swing, 0.4 + 0.1 * abs(swing[0]), "live")
            cost_swing.append(time.perf_counter() - t1)
            pos = (0.5 * t, 0.0, -2.0)
            zt.publish_state(t, pos, (0.5, 0.0, 0.0), (0.01, -0.02, 0.0), (pos[0] + 0.1, 0.0, -1.0))
            zt.publish_setpoint(t, {"thrust": 0.55, "q": [1.0, 0.0, 0.0, 0.0], "ref_pos_ned_m": pos,
                                    "force_att": [1.0, 0.0], "force_rep": [0.0, 0.0]})
            zt.publish_status(t, {"mode": "OFFBOARD", "armed": True, "link_ok": True, "progress": k})
            zt.publish_obstacles(t, obs)
            cost_tick.append(time.perf_counter() - t0)
            k += 1
            if args.realtime:
                delay = wall0 + k * args.dt - time.perf_counter()
                await asyncio.sleep(max(0.0, delay))
            else:
                await asyncio.sleep(args.pause_s)
        if args.linger_s > 0 and not stop.is_set():
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), args.linger_s)
        summary = {
            "event": "done", "ticks": k, "matched": matched, "seq": dict(zt.seq),
            "rejected": zt.store.rejected_count, "accepted": zt.store.accepted_count,
            "live_sources": list(zt.store.sources()),
            "publish_swing_us": _percentiles_us(cost_swing), "tick_all_streams_us": _percentiles_us(cost_tick),
        }
    return summary


def subscribe(args: argparse.Namespace) -> dict[str, Any]:
    """Receive ``--count`` samples of ``--key`` (or until ``--timeout-s``); gaps, latency."""
    got: list[tuple[float, bytes]] = []
    done = threading.Event()

    def on_sample(s: zenoh.Sample) -> None:
        got.append((time.time(), s.payload.to_bytes()))
        if len(got) >= args.count:
            done.set()

    with zenoh.open(zenoh_config_from_args(args, "listener")) as session:
        session.declare_subscriber(args.key, on_sample)
        print(json.dumps({"event": "ready"}), flush=True)
        done.wait(args.timeout_s)
    seqs: list[int] = []
    lat: list[float] = []
    for t_rx, raw in list(got):
        d = json.loads(raw)
        seqs.append(d["seq"])
        if d["seq"] >= args.warmup:
            lat.append(t_rx - d["wall_s"])
    missing = sorted(set(range(args.count)) - set(seqs))
    return {"event": "done", "received": len(got), "lost": len(missing), "missing_first": missing[:10],
            "latency_us": _percentiles_us(lat)}


def run_bench_zenoh(
    seconds: float = 5.0, rate_hz: float = 250.0, express: bool = False, background: bool = True,
) -> dict[str, Any]:
    """The 250 Hz swing stream from this process to a subscriber process over loopback TCP.

    Returns sent/received/lost, latency percentiles (µs, by wall clock, same host) and the cost of
    ``publish_swing`` in the publishing loop (µs). Numbers only; nothing is asserted.
    """
    port = free_tcp_port()
    ep = f"tcp/127.0.0.1:{port}"
    n = max(1, int(seconds * rate_hz))
    dt = 1.0 / rate_hz
    opts = TelemetryOptions(prefix="slungpilot-bench", vehicle_id="1", express=express,
                            subscribe_obstacles=False, background=background)
    cmd = [sys.executable, "-m", "companion.cli.bench_zenoh", "sub", "--zenoh-connect", ep,
           "--key", "slungpilot-bench/1/swing", "--count", str(n), "--timeout-s", str(seconds + 15.0),
           "--warmup", str(int(0.5 * rate_hz))]
    cost: list[float] = []
    with ZenohTelemetry(zenoh_config("companion", listen=[ep]), opts) as zt:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, preexec_fn=proclife.preexec())
        try:
            pub = zt._pubs["swing"]
            deadline = time.monotonic() + 15.0
            while not pub.matching_status.matching and time.monotonic() < deadline:
                time.sleep(0.01)
            time.sleep(0.2)
            t_start = time.perf_counter()
            for k in range(n):
                t = k * dt
                sw = fake_swing(t)
                t0 = time.perf_counter()
                zt.publish_swing(t, sw, 0.45, "live")
                cost.append(time.perf_counter() - t0)
                delay = t_start + (k + 1) * dt - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)
            out, _ = proc.communicate(timeout=seconds + 30.0)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    sub = json.loads(out.strip().splitlines()[-1])
    return {
        "rate_hz": rate_hz, "express": express, "background": background, "sent": n,
        "received": sub["received"], "lost": sub["lost"],
        "missing_first": sub["missing_first"],
        "latency_us": sub["latency_us"], "publish_us": _percentiles_us(cost),
    }


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m companion.cli.bench_zenoh")
    sub = p.add_subparsers(dest="cmd", required=True)
    d = sub.add_parser("drive", help="stand-in flight loop publishing every stream")
    add_zenoh_arguments(d, "companion")
    d.add_argument("--ticks", type=int, default=0, help="ticks to run (0: until SIGTERM/SIGINT)")
    d.add_argument("--dt", type=float, default=0.004, help="sim time per tick, s")
    d.add_argument("--realtime", action="store_true", help="pace ticks at dt of wall time")
    d.add_argument("--pause-s", type=float, default=0.0005, help="wall pause per tick when not --realtime")
    d.add_argument("--wait-match-s", type=float, default=0.0, help="wait up to this for a swing subscriber")
    d.add_argument("--linger-s", type=float, default=0.0, help="stay up this long after the ticks")
    s = sub.add_parser("sub", help="benchmark receiver")
    add_zenoh_arguments(s, "listener")
    s.add_argument("--key", required=True)
    s.add_argument("--count", type=int, required=True)
    s.add_argument("--timeout-s", type=float, default=30.0)
    s.add_argument("--warmup", type=int, default=0, help="samples with seq below this are not in latency stats")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    res = asyncio.run(drive(args)) if args.cmd == "drive" else subscribe(args)
    print(json.dumps(res), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
