"""Test helper process: count swing samples per vehicle until every vehicle that came alive has gone.

Usage: python zenoh_count.py ENDPOINT MODE OUT.json N_VEHICLES
"""

import json
import sys
import threading
import time

import zenoh

from companion.zenoh_io.session import open_session, zenoh_config

endpoint, mode, out_path, n_vehicles = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
lock = threading.Lock()
seqs: dict[str, list[int]] = {}
alive: set[str] = set()
gone: set[str] = set()


def on_swing(s: zenoh.Sample) -> None:
    d = json.loads(s.payload.to_bytes())
    with lock:
        seqs.setdefault(str(s.key_expr), []).append(d["seq"])


def on_alive(s: zenoh.Sample) -> None:
    with lock:
        (alive.add if s.kind == zenoh.SampleKind.PUT else gone.add)(str(s.key_expr))


with open_session(zenoh_config("listener", mode=mode, connect=[endpoint])) as session:
    session.declare_subscriber("slungpilot/*/swing", on_swing)
    session.liveliness().declare_subscriber("slungpilot/*/alive", on_alive, history=True)
    print("ready", flush=True)
    deadline = time.monotonic() + 180.0
    while time.monotonic() < deadline:
        with lock:
            if len(gone) >= n_vehicles:
                break
        time.sleep(0.05)
with open(out_path, "w") as fh:
    json.dump({"seqs": seqs, "alive": sorted(alive), "gone": sorted(gone)}, fh)
