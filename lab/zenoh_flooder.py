"""A Zenoh peer that floods obstacle lists as fast as asked until SIGINT, then prints how many it put (JSON): the
fault scenarios' and the ACL tests' hostile publisher. ``python -m lab.zenoh_flooder --connect ENDPOINT``."""

from __future__ import annotations

import json
import signal
import sys
import time


def flood_main(argv: list[str]) -> int:
    """``python -m lab.zenoh_flooder``: put obstacle lists as fast as asked until SIGINT; prints the count."""
    import argparse

    import zenoh

    p = argparse.ArgumentParser(prog="python -m lab.zenoh_flooder")
    p.add_argument("--connect", required=True)
    p.add_argument("--rate-hz", type=float, default=1000.0)
    p.add_argument("--trunks", type=int, default=256, help="far-away trunks per list (without --payload)")
    p.add_argument("--payload", default=None, help="the JSON to put instead of far-away trunks")
    p.add_argument("--key", default="slungpilot/1/obstacles/in/flood")
    p.add_argument("--vary", action="store_true", help="the first trunk moves by 1 µm per list: every list differs")
    p.add_argument("--user", default=None, help="log in with this user (Zenoh usrpwd authentication) ...")
    p.add_argument("--password", default=None, help="... and password; client mode")
    a = p.parse_args(argv)
    payload = (a.payload.encode() if a.payload is not None else
               json.dumps({"obstacles": [{"x_m": 200.0 + 2.0 * i, "y_m": 150.0, "radius_m": 0.3}
                                         for i in range(a.trunks - (1 if a.vary else 0))]}).encode())
    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"client"' if a.user else '"peer"')
    cfg.insert_json5("connect/endpoints", json.dumps([a.connect]))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    if a.user:
        cfg.insert_json5("transport/auth/usrpwd", json.dumps({"user": a.user, "password": a.password or ""}))
        cfg.insert_json5("connect/timeout_ms", "5000")  # a router still starting: keep trying for 5 s
        cfg.insert_json5("connect/retry", json.dumps({"period_init_ms": 250, "period_max_ms": 1000}))
    stop = []
    signal.signal(signal.SIGINT, lambda *_: stop.append(1))
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    sent = 0
    try:
        session = zenoh.open(cfg)
    except Exception as exc:  # e.g. the router refused our credentials
        print(json.dumps({"sent": 0, "error": str(exc)}), flush=True)
        return 3
    print("flooding", file=sys.stderr, flush=True)
    with session as s:
        pub = s.declare_publisher(a.key)
        period = 1.0 / a.rate_hz
        t_next = time.monotonic()
        while not stop:
            if a.vary and a.payload is None:
                head = json.dumps({"x_m": 100.0 + 1e-6 * sent, "y_m": 150.0, "radius_m": 0.3}).encode()
                pub.put(payload[:len(b'{"obstacles": [')] + head + b", " + payload[len(b'{"obstacles": ['):])
            else:
                pub.put(payload)
            sent += 1
            t_next += period
            delay = t_next - time.monotonic()
            if delay > 0:
                time.sleep(delay)
    print(json.dumps({"sent": sent}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(flood_main(sys.argv[1:]))
