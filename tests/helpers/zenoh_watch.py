"""Test helper process: watch one vehicle's Zenoh streams during a flight, feed it a trunk, report as JSON.

Usage: python zenoh_watch.py ENDPOINT OUT.json [OBSTACLE_JSON]

Listens on ENDPOINT (the companion connects to it, so the watcher is up before the flight starts), records
the swing sequence numbers, the obstacle sets, the state track and the liveliness of ``slungpilot/1``; once
the vehicle is airborne at mission altitude it publishes four malformed samples and then OBSTACLE_JSON on
``slungpilot/1/obstacles/in/perception``, then asks the ``config`` queryable once. Stops when the vehicle's
liveliness token goes away (or after 150 s) and writes what it saw to OUT.json.
"""

import json
import sys
import threading
import time

import zenoh

from companion.zenoh_io.session import open_session, zenoh_config

endpoint, out_path = sys.argv[1], sys.argv[2]
obstacle_doc = sys.argv[3] if len(sys.argv) > 3 else None
lock = threading.Lock()
seen = {"swing_seq": [], "obstacle_sets": [], "state": [], "alive": [], "config": None, "published_at_x": None,
        "encodings": {}, "status": []}
gone = threading.Event()


def on_sample(s: zenoh.Sample) -> None:
    key = str(s.key_expr)
    d = json.loads(s.payload.to_bytes())
    with lock:
        seen["encodings"][key.rsplit("/", 1)[-1]] = str(s.encoding)
        if key.endswith("/swing"):
            seen["swing_seq"].append(d["seq"])
        elif key.endswith("/obstacles"):
            seen["obstacle_sets"].append(d)
        elif key.endswith("/state"):
            seen["state"].append(d)
        elif key.endswith("/status"):
            seen["status"].append(d)


def on_alive(s: zenoh.Sample) -> None:
    with lock:
        seen["alive"].append([str(s.key_expr), str(s.kind)])
    if s.kind == zenoh.SampleKind.DELETE:
        gone.set()


with open_session(zenoh_config("listener", listen=[endpoint])) as session:
    session.declare_subscriber("slungpilot/1/**", on_sample)
    session.liveliness().declare_subscriber("slungpilot/*/alive", on_alive, history=True)
    pub = session.declare_publisher("slungpilot/1/obstacles/in/perception")
    # one bad sample per publisher: the companion parses only each publisher's newest unread sample
    bad_pubs = [session.declare_publisher(f"slungpilot/1/obstacles/in/broken{i}") for i in range(4)]
    print("ready", flush=True)
    deadline = time.monotonic() + 150.0
    while not gone.is_set() and time.monotonic() < deadline:
        time.sleep(0.005)
        with lock:
            last = seen["state"][-1] if seen["state"] else None
        if last is None:
            continue
        pos = last.get("pos_ned_m")
        if seen["published_at_x"] is not None and seen["config"] is None:
            # after feeding the trunk: a query blocks until its replies are final
            for reply in session.get("slungpilot/1/config", timeout=2.0):
                if reply.ok is not None:
                    seen["config"] = json.loads(reply.ok.payload.to_bytes())
        if obstacle_doc and seen["published_at_x"] is None and pos and pos[2] < -1.8:
            for bp, bad in zip(bad_pubs, (b"not json", b'{"obstacles": [{"x_m": 1, "y_m": 0, "radius_m": NaN}]}',
                                          b'{"obstacles": [{"x_m": 1, "y_m": 0, "radius_m": -0.3}]}',
                                          b'{"trunks": []}'), strict=True):
                bp.put(bad)  # each must be counted and ignored
            pub.put(obstacle_doc.encode())
            seen["published_at_x"] = pos[0]
with open(out_path, "w") as fh:
    json.dump(seen, fh)
