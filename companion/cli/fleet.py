"""``slungpilot fleet N``: N bundled vehicles and N companions flying at once, all on one Zenoh router.

Starts a Zenoh router (in this process), then N ``slungpilot fly --sitl --realtime --instance i`` (vehicle id and
MAVLink system id 1+i, each with its own bundled vehicle), every companion a Zenoh **client** of the router, and a
subscriber that counts each vehicle's swing stream (sequence gaps = loss). Prints a line per vehicle when all
have landed: outcome, tick p99, swing samples received and lost. Ctrl-C or SIGTERM passes on to every companion
(each holds and lands); killed outright, the fleet takes its companions and their vehicles with it
(:mod:`companion.proclife`). ``slungpilot view --zenoh-connect ENDPOINT`` shows them all live.

Why clients: with eclipse-zenoh 1.10 a router forwards between its clients, but two *peers* that only know the
router do not get each other's samples (docs/zenoh.md); clients always go through the router.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import zenoh

from companion import proclife
from companion.zenoh_io.session import open_session, zenoh_config


def add_fleet_arguments(p: argparse.ArgumentParser) -> None:
    """``fleet``'s options."""
    p.add_argument("n", type=int, metavar="N", help="how many vehicle + companion pairs (1..16)")
    p.add_argument("--mission", default="open_field", metavar="FILE|NAME",
                   help="the mission every vehicle flies (default open_field; each in its own simulated world)")
    p.add_argument("--router", default=None, metavar="ENDPOINT",
                   help="the router's endpoint (default a free tcp/127.0.0.1 port)")
    p.add_argument("--run-dir", type=Path, default=None, help="where the run folders go (default runs/fleet-<time>)")
    p.add_argument("--lockstep", action="store_true", help="fly in lockstep instead of real time")
    p.add_argument("--rate-hz", type=float, default=None,
                   help="each companion's control rate (default fly's 250 Hz; 100 Hz flies the missions as well and a "
                        "pair then takes ~0.21 of a core instead of ~0.35 on a slow 2-core VM, where fleet 8 fits only "
                        "at 100 Hz; a faster CPU carries fleet 8 at 250 Hz, docs/zenoh.md)")
    p.add_argument("--rt-priority", type=int, default=10, metavar="N",
                   help="each companion's --rt-priority (default 10: control threads SCHED_FIFO, so the 2N "
                        "processes sharing this machine cannot preempt a tick; 0 = normal scheduling; refused "
                        "without CAP_SYS_NICE or `ulimit -r`, and the per-vehicle line says so; not in --lockstep)")
    p.add_argument("--zenoh-rates", default=None, metavar="STREAM=HZ,...",
                   help="each companion's --zenoh-rates (downsampling at the edge, e.g. swing=25,state=10,setpoint=5)")


def _free_tcp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class _StreamCounter:
    """Per (vehicle id, stream): samples received, payload bytes and sequence numbers skipped (loss). Runs on
    Zenoh's threads; only counts under a lock."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.count: dict[tuple[str, str], int] = {}
        self.bytes: dict[tuple[str, str], int] = {}
        self.lost: dict[tuple[str, str], int] = {}
        self._last: dict[tuple[str, str], int] = {}

    def __call__(self, s: zenoh.Sample) -> None:
        raw = s.payload.to_bytes()
        parts = str(s.key_expr).split("/")
        if len(parts) != 3:
            return
        key = (parts[1], parts[2])
        try:
            seq = int(json.loads(raw)["seq"])
        except (ValueError, KeyError, TypeError):
            seq = None
        with self.lock:
            self.count[key] = self.count.get(key, 0) + 1
            self.bytes[key] = self.bytes.get(key, 0) + len(raw)
            last = self._last.get(key)
            if seq is not None:
                if last is not None and seq > last + 1:
                    self.lost[key] = self.lost.get(key, 0) + seq - last - 1
                self._last[key] = seq if last is None else max(seq, last)

    def of(self, vid: str, stream: str) -> tuple[int, int, int]:
        """(samples, bytes, lost) of one vehicle's stream."""
        with self.lock:
            k = (vid, stream)
            return self.count.get(k, 0), self.bytes.get(k, 0), self.lost.get(k, 0)


def _vehicle_argv(args: argparse.Namespace, i: int, ep: str, root: Path) -> list[str]:
    """The command line of vehicle ``i``'s ``fly --sitl`` (a Zenoh client of the router at ``ep``)."""
    argv = [sys.executable, "-m", "companion.cli", "-q", "fly", "--sitl", "--instance", str(i),
            "--mission", args.mission, "--zenoh-mode", "client", "--zenoh-connect", ep, "--no-recording",
            "--no-plots", "--run-dir", str(root / f"vehicle-{1 + i}")]
    if not args.lockstep:
        argv.append("--realtime")
    if args.zenoh_rates:
        argv += ["--zenoh-rates", args.zenoh_rates]
    if args.rate_hz is not None:
        argv += ["--rate-hz", f"{args.rate_hz:g}"]
    if args.rt_priority and not args.lockstep:  # lockstep has no deadlines (and would run FIFO flat out)
        argv += ["--rt-priority", str(args.rt_priority)]
    return argv


def _wait_forwarding_signals(procs: list[subprocess.Popen]) -> list[int]:
    """Wait for every vehicle; SIGINT or SIGTERM meanwhile is passed on to them as SIGINT. Their exit codes."""
    def forward(signum: int, _frame: Any) -> None:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGINT)

    old = signal.signal(signal.SIGINT, forward)
    old_term = signal.signal(signal.SIGTERM, forward)
    try:
        return [p.wait() for p in procs]
    finally:
        signal.signal(signal.SIGINT, old)
        signal.signal(signal.SIGTERM, old_term)


def _vehicle_result(vid: str, code: int, root: Path, counter: _StreamCounter) -> dict[str, Any]:
    """Vehicle ``vid``'s outcome, loop timing and streams (from its report and what the listener received),
    printed as one line."""
    rep_file = root / f"vehicle-{vid}" / "report.json"
    rep = json.loads(rep_file.read_text()) if rep_file.exists() else {}
    loop = rep.get("loop", {})
    published = rep.get("zenoh", {}).get("published", {})
    sim_s = float(rep.get("sim_time_s") or float("nan"))  # stream rates are in vehicle time
    streams = {}
    for stream in ("swing", "state", "setpoint", "status", "obstacles"):
        got, nbytes, lost = counter.of(vid, stream)
        streams[stream] = {"published": published.get(stream), "received": got, "lost": lost, "bytes": nbytes,
                           "bytes_per_sample": nbytes / got if got else None}
    total_bytes = sum(v["bytes"] for v in streams.values())
    sw = streams["swing"]
    print(f"  vehicle {vid}: {rep.get('outcome', '?')} (exit {code}), tick p99 "
          f"{loop.get('tick_ms_p99', float('nan')):.3f} ms "
          f"(CPU {loop.get('tick_cpu_ms_p99', float('nan')):.3f} ms), "
          f"late ticks {loop.get('late_ticks')}, preempted {loop.get('preempted_ticks')} "
          f"({loop.get('scheduling')}), swing samples "
          f"{sw['received']} of {sw['published']} published, {sw['lost']} lost in sequence; "
          f"{total_bytes / 1e3:.0f} kB over Zenoh ({total_bytes / sim_s / 1e3:.1f} kB/s)", flush=True)
    return {"exit": code, "outcome": rep.get("outcome"), "tick_ms_p99": loop.get("tick_ms_p99"),
            "tick_cpu_ms_p99": loop.get("tick_cpu_ms_p99"),
            "late_ticks": loop.get("late_ticks"), "preempted_ticks": loop.get("preempted_ticks"),
            "scheduling": loop.get("scheduling"), "sim_time_s": sim_s, "streams": streams,
            "bytes_per_sim_s": total_bytes / sim_s if sim_s > 0 else None}


#: one vehicle + companion pair's share of a core in real-time flight, Zenoh on (measured 2026-12-03 on the 2-core
#: VM, docs/zenoh.md): ~0.21 at 100 Hz control, ~0.35 at 250 Hz; a line through both
PAIR_CORE_BASE, PAIR_CORE_PER_HZ = 0.11, 0.00096
DEFAULT_RATE_HZ = 250.0  # fly's own default (FlightSetup.rate_hz)


def pairs_core_need(n: int, rate_hz: float) -> float:
    """Cores ``n`` pairs need in real-time flight at ``rate_hz`` (the measured line above)."""
    return n * (PAIR_CORE_BASE + PAIR_CORE_PER_HZ * rate_hz)


def capacity_warning(n: int, rate_hz: float, cores: int) -> str | None:
    """A warning when ``n`` real-time pairs at ``rate_hz`` need more than 90 % of ``cores`` (the router and the
    counting subscriber need the rest), naming the rate that fits; None when they fit."""
    need = pairs_core_need(n, rate_hz)
    if need <= 0.9 * cores:
        return None
    fits = [r for r in (200.0, 150.0, 100.0, 50.0) if r < rate_hz and pairs_core_need(n, r) <= 0.9 * cores]
    hint = f"; --rate-hz {fits[0]:g} needs ~{pairs_core_need(n, fits[0]):.1f}" if fits else ""
    return (f"fleet: {n} pairs at {rate_hz:g} Hz need ~{need:.1f} cores in flight on the CPU this was measured on "
            f"(a faster one needs less) and this machine has {cores}: late setpoints, stream loss and vehicles that "
            f"land on their own are likely{hint}")


def run_fleet(args: argparse.Namespace) -> int:
    """Fly the fleet; exit 0 when every vehicle completed its mission."""
    n = args.n
    if not 1 <= n <= 16:
        from companion.errors import ConfigError

        raise ConfigError(f"N: 1..16 pairs, got {n}")
    ep = args.router or f"tcp/127.0.0.1:{_free_tcp_port()}"
    root = args.run_dir or Path("runs") / f"fleet-{datetime.now(UTC).strftime('%Y%m%d-%H%M%S-%f')[:-3]}"
    root.mkdir(parents=True, exist_ok=True)
    counter = _StreamCounter()
    procs: list[subprocess.Popen] = []
    router_cfg = zenoh_config("router", mode="router", listen=[ep])
    client_cfg = zenoh_config("listener", mode="client", connect=[ep])
    with open_session(router_cfg), open_session(client_cfg) as sub_session:
        sub_session.declare_subscriber("slungpilot/*/*", counter)
        warning = None if args.lockstep else capacity_warning(n, args.rate_hz or DEFAULT_RATE_HZ, os.cpu_count() or 1)
        if warning:
            print(warning, file=sys.stderr, flush=True)
        print(f"fleet: router on {ep}; {n} vehicles flying {args.mission} "
              f"({'lockstep' if args.lockstep else 'real time'}); run folders in {root}", flush=True)
        for i in range(n):
            with (root / f"vehicle-{1 + i}.log").open("w") as err:
                procs.append(subprocess.Popen(_vehicle_argv(args, i, ep, root), stdout=subprocess.DEVNULL,
                                              stderr=err, start_new_session=True, preexec_fn=proclife.preexec()))
        codes = _wait_forwarding_signals(procs)
        time.sleep(0.5)  # the last samples through the router
    ok = True
    per_vehicle: dict[str, Any] = {}
    for i, code in enumerate(codes):
        vid = str(1 + i)
        per_vehicle[vid] = _vehicle_result(vid, code, root, counter)
        ok = ok and code == 0
    summary = {"router": ep, "n": n, "mission": args.mission, "lockstep": bool(args.lockstep), "codes": codes,
               "swing_received": {v: d["streams"]["swing"]["received"] for v, d in per_vehicle.items()},
               "swing_lost": {v: d["streams"]["swing"]["lost"] for v, d in per_vehicle.items()},
               "vehicles": per_vehicle}
    (root / "fleet.json").write_text(json.dumps(summary, indent=1) + "\n")
    return 0 if ok else 1
