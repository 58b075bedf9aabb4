"""A lossy UDP proxy for fault tests: drops, delays, jitters (and so reorders) datagrams in both directions.

    python -m lab.udp_proxy --vehicle 127.0.0.1:14580 --companion 127.0.0.1:14540 \\
        --listen-vehicle-side 24540 --delay-ms 50 --jitter-ms 25 --drop 0.01 --seed 1

Topology: the vehicle sends its telemetry to ``--listen-vehicle-side`` (its onboard remote), the proxy forwards
each datagram to ``--companion`` from its companion-side socket, and what the companion answers there is
forwarded to ``--vehicle``. Each datagram gets ``delay ± jitter`` (uniform) on its own, so with jitter larger
than the gap between datagrams they arrive out of order, as on a congested radio link. Seeded: the same
datagram sequence gets the same fate. Prints ``PROXY READY <companion-side port>`` when listening; counts on
exit (SIGTERM/SIGINT) as one JSON line.
"""

from __future__ import annotations

import argparse
import heapq
import json
import random
import selectors
import signal
import socket
import sys
import time


def _addr(text: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    return host or "127.0.0.1", int(port)


def run(vehicle: tuple[str, int] | None, companion: tuple[str, int], vehicle_side_port: int, delay_s: float,
        jitter_s: float, drop: float, seed: int) -> dict[str, int]:
    """Forward until SIGTERM/SIGINT; returns the counters. ``vehicle`` None: the address the first vehicle-side
    datagram came from (a vehicle that dials out from an ephemeral port, as ArduCopter SITL's ``udpclient``)."""
    rng = random.Random(seed)
    v_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    v_sock.bind(("127.0.0.1", vehicle_side_port))
    c_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    c_sock.bind(("127.0.0.1", 0))
    for s in (v_sock, c_sock):
        s.setblocking(False)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
    sel = selectors.DefaultSelector()
    sel.register(v_sock, selectors.EVENT_READ, "to_companion")
    sel.register(c_sock, selectors.EVENT_READ, "to_vehicle")
    counts = {"to_companion": 0, "to_vehicle": 0, "dropped": 0, "reordered": 0, "no_vehicle": 0}
    queue: list[tuple[float, int, bytes, str]] = []
    n = 0
    last_release = {"to_companion": 0.0, "to_vehicle": 0.0}
    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    signal.signal(signal.SIGINT, lambda *_: stop.append(1))
    print(f"PROXY READY {c_sock.getsockname()[1]}", flush=True)
    while not stop:
        now = time.monotonic()
        while queue and queue[0][0] <= now:
            _, _, data, way = heapq.heappop(queue)
            if way == "to_vehicle" and vehicle is None:  # 'first' and the vehicle has not spoken yet
                counts["no_vehicle"] += 1
                continue
            try:
                if way == "to_companion":
                    c_sock.sendto(data, companion)
                else:
                    v_sock.sendto(data, vehicle)
            except OSError:
                pass
            counts[way] += 1
        timeout = max(0.0, queue[0][0] - now) if queue else 0.05
        for key, _ in sel.select(min(timeout, 0.05)):
            sock, way = key.fileobj, key.data
            while True:
                try:
                    data, src = sock.recvfrom(65535)
                except (BlockingIOError, InterruptedError):
                    break
                except OSError:
                    break
                if vehicle is None and way == "to_companion":
                    vehicle = src
                if drop > 0.0 and rng.random() < drop:
                    counts["dropped"] += 1
                    continue
                release = time.monotonic() + max(0.0, delay_s + rng.uniform(-jitter_s, jitter_s))
                if release < last_release[way]:
                    counts["reordered"] += 1
                last_release[way] = max(last_release[way], release)
                n += 1
                heapq.heappush(queue, (release, n, data, way))
    return counts


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m lab.udp_proxy", description=__doc__.split("\n\n")[0])
    p.add_argument("--vehicle", required=True,
                   help="HOST:PORT the vehicle listens on (its onboard port), or 'first': where its first datagram "
                        "came from")
    p.add_argument("--companion", required=True, help="HOST:PORT the companion listens on")
    p.add_argument("--listen-vehicle-side", type=int, required=True,
                   help="port the vehicle sends its telemetry to (its onboard remote)")
    p.add_argument("--delay-ms", type=float, default=0.0, help="mean one-way delay, ms")
    p.add_argument("--jitter-ms", type=float, default=0.0, help="uniform ± jitter around the delay, ms")
    p.add_argument("--drop", type=float, default=0.0, help="drop probability per datagram (0..1)")
    p.add_argument("--seed", type=int, default=1)
    a = p.parse_args(argv)
    vehicle = None if a.vehicle == "first" else _addr(a.vehicle)
    counts = run(vehicle, _addr(a.companion), a.listen_vehicle_side, a.delay_ms / 1e3, a.jitter_ms / 1e3,
                 a.drop, a.seed)
    print(json.dumps(counts), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
