"""Command-line tools for the Zenoh side: ``listen``, ``obstacles publish``, ``zenoh-router``, ``bench zenoh``.

The flight command wires :class:`companion.zenoh_io.telemetry.ZenohTelemetry`; these are the user's tools around it.
Each ``add_*_parser(subparsers)`` adds a subcommand whose ``func(args) -> int`` runs it. Also runnable on its
own: ``python -m companion.cli.zenoh_cmds listen``.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import queue
import sys
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from companion.config import read_toml, resolve_obstacles
from companion.errors import ConfigError
from companion.zenoh_io import schema as ts
from companion.zenoh_io.obstacle_store import parse_obstacles_in
from companion.zenoh_io.session import (
    DEFAULT_PREFIX,
    add_zenoh_arguments,
    check_key_part,
    open_session,
    zenoh_config_from_args,
)

log = logging.getLogger(__name__)


# -- listen ------------------------------------------------------------------------------------------------
def add_listen_parser(subparsers: Any) -> argparse.ArgumentParser:
    """``listen [KEYEXPR] [--json]``: watch the streams."""
    p = subparsers.add_parser(
        "listen", help="watch the Zenoh streams (rate, loss, latest values per key)",
        description="Subscribe to KEYEXPR (default <prefix>/**) and show per key the rate, the loss counted "
        "from sequence gaps and the latest values, refreshed twice a second; --json prints every sample.",
    )
    p.add_argument("keyexpr", nargs="?", default=None, metavar="KEYEXPR", help="key expression (default <prefix>/**)")
    p.add_argument("--json", action="store_true", help="print every sample as one JSON line instead of the view")
    p.add_argument("--duration", type=float, default=0.0, help="stop after this many seconds (0: until Ctrl-C)")
    p.add_argument("--count", type=int, default=0, help="stop after this many samples (0: no limit)")
    add_zenoh_arguments(p, "listener")
    p.set_defaults(func=run_listen)
    return p


@dataclass
class KeyStats:
    """What the view shows per key."""

    count: int = 0
    lost: int = 0
    last_seq: int | None = None
    arrivals: deque = field(default_factory=lambda: deque(maxlen=2000))
    latest: dict | None = None
    latency_s: float = math.nan

    def update(self, d: dict | None, t_rx: float) -> None:
        self.count += 1
        self.arrivals.append(t_rx)
        if d is None:
            return
        self.latest = d
        seq = d.get("seq")
        if isinstance(seq, int):
            if self.last_seq is not None and seq > self.last_seq + 1:
                self.lost += seq - self.last_seq - 1
            self.last_seq = seq
        if isinstance(d.get("wall_s"), float):
            self.latency_s = t_rx - d["wall_s"]

    def rate_hz(self, now: float, window_s: float = 2.0) -> float:
        n = sum(1 for t in self.arrivals if t >= now - window_s)
        return n / window_s


def _deg(x: Any) -> str:
    return "  -  " if x is None else f"{math.degrees(x):+6.1f}"


def summarize(d: dict | None) -> str:
    """One line of the latest values of a sample, by schema."""
    if d is None:
        return "(not JSON)"
    s = d.get("schema")
    if s == ts.SWING:
        return (f"α {_deg(d.get('alpha_rad'))}° β {_deg(d.get('beta_rad'))}° α̇ {_deg(d.get('alpha_rate_radps'))}°/s "
                f"β̇ {_deg(d.get('beta_rate_radps'))}°/s R_max {d.get('r_max_m')} m [{d.get('envelope_mode')}]")
    if s == ts.STATE:
        p = d.get("pos_ned_m") or []
        return "pos " + " ".join(f"{x:+.2f}" for x in p if x is not None) + " m"
    if s == ts.OBSTACLES:
        return f"{d.get('count')} obstacles from {', '.join(d.get('sources', []))}; rejected {d.get('rejected_count')}"
    if s == ts.STATUS:
        keys = [k for k in d if k not in ts.HEADER_KEYS][:6]
        return ", ".join(f"{k}={d[k]}" for k in keys)[:100]
    body = {k: v for k, v in d.items() if k not in ts.HEADER_KEYS}
    return json.dumps(body)[:100]


def render(stats: dict[str, KeyStats], alive: set[str], now: float) -> str:
    """The text of the view."""
    lines = [f"slungpilot listen — {time.strftime('%H:%M:%S')} — alive: {', '.join(sorted(alive)) or '(none)'}",
             f"{'key':34s} {'rate Hz':>8s} {'count':>8s} {'lost':>6s} {'lat ms':>7s}  latest"]
    for key in sorted(stats):
        st = stats[key]
        lat = f"{st.latency_s * 1e3:7.1f}" if math.isfinite(st.latency_s) else "      -"
        lines.append(f"{key:34s} {st.rate_hz(now):8.1f} {st.count:8d} {st.lost:6d} {lat}  {summarize(st.latest)}")
    return "\n".join(lines)


def run_listen(args: argparse.Namespace) -> int:
    """Subscribe and show the view (or ``--json`` lines) until Ctrl-C, ``--duration`` or ``--count``."""
    prefix = getattr(args, "zenoh_prefix", DEFAULT_PREFIX)
    keyexpr = args.keyexpr or f"{prefix}/**"
    q: queue.SimpleQueue = queue.SimpleQueue()
    stats: dict[str, KeyStats] = {}
    alive: set[str] = set()

    def on_sample(s: zenoh.Sample) -> None:  # zenoh thread: copy out and queue only
        q.put(("s", str(s.key_expr), str(s.encoding), s.payload.to_bytes(), time.time()))

    def on_alive(s: zenoh.Sample) -> None:
        q.put(("a", str(s.key_expr), s.kind == zenoh.SampleKind.PUT, b"", time.time()))

    t_end = time.monotonic() + args.duration if args.duration > 0 else math.inf
    n = 0
    tty = sys.stdout.isatty()
    with open_session(zenoh_config_from_args(args, "listener")) as session:
        session.declare_subscriber(keyexpr, on_sample)
        if not args.json:
            session.liveliness().declare_subscriber(f"{prefix}/*/alive", on_alive, history=True)
        next_draw = time.monotonic() + 0.5
        while time.monotonic() < t_end and not (args.count and n >= args.count):
            try:
                kind, key, enc, raw, t_rx = q.get(timeout=0.1)
            except queue.Empty:
                kind = ""
            if kind == "s":
                n += 1
                try:
                    d = json.loads(raw)
                except ValueError:
                    d = None
                if args.json:
                    body = d if d is not None else raw.decode("utf-8", "replace")
                    out = {"key": key, "encoding": enc, "sample": body}
                    print(json.dumps(out), flush=True)
                else:
                    stats.setdefault(key, KeyStats()).update(d if isinstance(d, dict) else None, t_rx)
            elif kind == "a":
                (alive.add if enc else alive.discard)(key)
            if not args.json and time.monotonic() >= next_draw:
                next_draw = time.monotonic() + 0.5
                text = render(stats, alive, time.time())
                print(("\x1b[H\x1b[2J" + text) if tty else text + "\n", flush=True)
    if not args.json:
        print(render(stats, alive, time.time()), flush=True)
    return 0


# -- obstacles publish -------------------------------------------------------------------------------------
def add_obstacles_parser(subparsers: Any) -> argparse.ArgumentParser:
    """``obstacles publish FILE``: feed live obstacles to a vehicle (or all) from a file."""
    p = subparsers.add_parser("obstacles", help="feed live obstacles over Zenoh",
                              description="Tools for the live obstacle input of the companion.")
    sub = p.add_subparsers(dest="obstacles_command", required=True, metavar="ACTION")
    pub = sub.add_parser(
        "publish", help="publish the obstacles of FILE",
        description="Publish the obstacles of FILE (a mission TOML's [[obstacles]] or a JSON file "
        '{"obstacles": [...], "expires_s": ...} or a JSON list) to <prefix>/<id>/obstacles/in/<name> '
        "(or <prefix>/world/obstacles/<name> with --world).",
    )
    pub.add_argument("file", type=Path, metavar="FILE",
                     help="mission .toml or .json file, or a shipped obstacle file by name (trunk: one trunk on the "
                          "open_field mission's path)")
    who = pub.add_mutually_exclusive_group()
    who.add_argument("--vehicle-id", default="1", help="the vehicle to feed (default 1)")
    who.add_argument("--world", action="store_true", help="publish to every vehicle (<prefix>/world/obstacles)")
    pub.add_argument("--name", default="cli", help="publisher name, the last key chunk (default cli)")
    pub.add_argument("--expires", type=float, default=None, metavar="S",
                     help="obstacles expire S s after the companion receives them (default: never)")
    pub.add_argument("--repeat-hz", type=float, default=0.0, help="republish at this rate (default 0: once)")
    pub.add_argument("--duration", type=float, default=0.0, help="with --repeat-hz: stop after S s (0: Ctrl-C)")
    pub.add_argument("--clear", action="store_true", help="send an empty list (removes this publisher's obstacles)")
    pub.add_argument("--wait-s", type=float, default=5.0,
                     help="wait up to S s for a subscriber; if none came, send nothing and exit 3 (default 5)")
    add_zenoh_arguments(pub, "listener")
    pub.set_defaults(func=run_obstacles_publish)
    return p


def obstacles_key(prefix: str, vehicle_id: str | None, name: str, world: bool) -> str:
    """The key a live obstacle publisher puts to."""
    check_key_part("prefix", prefix)
    check_key_part("name", name)
    if world:
        return f"{prefix}/world/obstacles/{name}"
    return f"{prefix}/{check_key_part('vehicle_id', vehicle_id or '1')}/obstacles/in/{name}"


def load_obstacles_payload(path: Path, expires_s: float | None, clear: bool = False) -> bytes:
    """The JSON payload to publish from ``path``, validated as the companion will; :class:`ConfigError`."""
    if clear:
        return json.dumps({"schema": ts.OBSTACLES_IN, "version": ts.SCHEMA_VERSION, "obstacles": []}).encode()
    if path.suffix == ".toml":
        items = read_toml(path).get("obstacles", [])
        doc: dict[str, Any] = {"obstacles": items}
    else:
        try:
            raw = json.loads(path.read_text())
        except FileNotFoundError:
            raise ConfigError(f"{path}: file not found") from None
        except (OSError, ValueError) as exc:
            raise ConfigError(f"{path}: not readable JSON: {exc}") from None
        doc = {"obstacles": raw} if isinstance(raw, list) else raw
    if isinstance(doc, dict) and expires_s is not None:
        doc["expires_s"] = expires_s
    payload = json.dumps(doc).encode()
    try:
        parse_obstacles_in(payload, "check")
    except ValueError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    return payload


def run_obstacles_publish(args: argparse.Namespace) -> int:
    """Publish once (after a subscriber is seen or ``--wait-s``) or repeatedly at ``--repeat-hz``."""
    key = obstacles_key(args.zenoh_prefix, args.vehicle_id, args.name, args.world)
    payload = load_obstacles_payload(resolve_obstacles(args.file), args.expires, args.clear)
    n = len(json.loads(payload)["obstacles"])
    with open_session(zenoh_config_from_args(args, "listener")) as session:
        pub = session.declare_publisher(
            key, encoding=zenoh.Encoding.APPLICATION_JSON.with_schema(ts.encoding_schema(ts.OBSTACLES_IN)),
            congestion_control=zenoh.CongestionControl.BLOCK,
        )
        deadline = time.monotonic() + args.wait_s
        if not pub.matching_status.matching:
            print(f"waiting up to {args.wait_s:g} s for a subscriber to {key}", file=sys.stderr, flush=True)
        while not pub.matching_status.matching and time.monotonic() < deadline:
            time.sleep(0.02)
        if not pub.matching_status.matching:
            print(f"slungpilot obstacles publish: nobody subscribes to {key} (waited {args.wait_s:g} s): is the "
                  f"companion flying with Zenoh on, as vehicle {args.vehicle_id}, reachable at the endpoint given? "
                  "Nothing was sent.", file=sys.stderr)
            return 3
        pub.put(payload)
        print(f"published {n} obstacles to {key}", flush=True)
        if args.repeat_hz > 0:
            t_end = time.monotonic() + args.duration if args.duration > 0 else math.inf
            period = 1.0 / args.repeat_hz
            while time.monotonic() + period < t_end:
                time.sleep(period)
                pub.put(payload)
        time.sleep(0.2)  # let the last sample leave before the session closes
    return 0


# -- router ------------------------------------------------------------------------------------------------
def add_router_parser(subparsers: Any) -> argparse.ArgumentParser:
    """``zenoh-router``: a Python Zenoh session in router mode."""
    p = subparsers.add_parser(
        "zenoh-router", help="run a Zenoh router (joins peers that cannot see each other)",
        description="A Zenoh session in router mode, listening on tcp/127.0.0.1:7447 unless --zenoh-listen "
        "is given. Companions then use --zenoh-connect to it. zenohd does the same where installed.",
    )
    p.add_argument("--duration", type=float, default=0.0, help="stop after this many seconds (0: until Ctrl-C)")
    add_zenoh_arguments(p, "router")
    p.set_defaults(func=run_router)
    return p


def run_router(args: argparse.Namespace) -> int:
    """Run the router until Ctrl-C (or ``--duration``)."""
    cfg = zenoh_config_from_args(args, "router")
    with open_session(cfg) as session:
        print(f"zenoh router {session.zid()} up; listening on {cfg.get_json('listen/endpoints')}", flush=True)
        t_end = time.monotonic() + args.duration if args.duration > 0 else math.inf
        while time.monotonic() < t_end:
            time.sleep(min(0.2, max(0.0, t_end - time.monotonic())))
    return 0


# -- bench -------------------------------------------------------------------------------------------------
def cmd_bench_zenoh(seconds: float) -> int:
    """Print the ``bench zenoh`` numbers (targets: zero loss, p99 < 2 ms, < 20 µs per publish)."""
    from companion.cli.bench_zenoh import run_bench_zenoh

    print(f"slungpilot bench zenoh: 250 Hz swing stream, two processes over loopback TCP, {seconds:g} s")
    for background in (True, False):
        r = run_bench_zenoh(seconds, background=background)
        lat, pub = r["latency_us"], r["publish_us"]
        how = "background thread (default)" if background else "direct put in the loop"
        print(f"  publish: {how}")
        print(f"    sent {r['sent']}, received {r['received']}, lost {r['lost']}")
        print(f"    latency publish->receive  p50 {lat['p50'] / 1e3:7.3f} ms  p99 {lat['p99'] / 1e3:7.3f} ms"
              f"  max {lat['max'] / 1e3:7.3f} ms")
        print(f"    cost per publish_swing    p50 {pub['p50']:7.1f} µs  p99 {pub['p99']:7.1f} µs"
              f"  mean {pub['mean']:7.1f} µs")
    print("  targets: 0 lost, p99 < 2 ms, < 20 µs per publish (reported, not asserted)")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """A stand-alone parser with the three tools plus ``bench``."""
    p = argparse.ArgumentParser(prog="python -m companion.cli.zenoh_cmds")
    sub = p.add_subparsers(dest="command", required=True)
    add_listen_parser(sub)
    add_obstacles_parser(sub)
    add_router_parser(sub)
    b = sub.add_parser("bench", help="bench zenoh")
    b.add_argument("--seconds", type=float, default=5.0)
    b.set_defaults(func=lambda a: cmd_bench_zenoh(a.seconds))
    return p


def main(argv: list[str] | None = None) -> int:
    """``python -m companion.cli.zenoh_cmds``: the same tools and exit codes as ``slungpilot``."""
    from companion.launch.dispatch import dispatch

    return dispatch(build_parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
