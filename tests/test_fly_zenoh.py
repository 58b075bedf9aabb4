"""A real flight with real Zenoh: streams seen from another process, a trunk fed in mid-flight and avoided."""

import json
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = [pytest.mark.slow, pytest.mark.shares_cores]  # each flies a mission or a peer against the vehicle

ROOT = Path(__file__).resolve().parents[1]
FOREST = ROOT / "config" / "missions" / "forest.toml"
LIVE_TRUNK = {"x_m": 6.0, "y_m": 0.1, "radius_m": 0.3, "height_m": 4.0, "safe_distance_m": 0.1}


def _free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _open_field_mission(tmp: Path) -> Path:
    """The forest mission with every trunk removed: the straight line to (10, 0) is free."""
    text = FOREST.read_text().split("[[obstacles]]")[0]
    f = tmp / "open_field.toml"
    f.write_text(text.replace('name = "forest"', 'name = "open_field"'))
    return f


@pytest.fixture(scope="module")
def zenoh_flight(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("zflight")
    port = _free_tcp_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    watch = subprocess.Popen(
        [sys.executable, str(ROOT / "tests" / "helpers" / "zenoh_watch.py"), endpoint, str(tmp / "seen.json"),
         json.dumps({"obstacles": [LIVE_TRUNK]})],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    assert watch.stdout.readline().strip() == "ready"
    fly = subprocess.run(
        [sys.executable, "-m", "companion.cli.main", "fly", "--sitl", "--mission", str(_open_field_mission(tmp)),
         "--run-dir", str(tmp / "run"), "--no-plots", "--zenoh-connect", endpoint],
        cwd=ROOT, capture_output=True, text=True, timeout=240,
    )
    _, werr = watch.communicate(timeout=60)
    assert watch.returncode == 0, werr[-2000:]
    return fly, json.loads((tmp / "seen.json").read_text()), tmp / "run"


def test_flight_succeeds_with_zenoh_on(zenoh_flight):
    fly, _, run = zenoh_flight
    assert fly.returncode == 0, fly.stderr[-3000:]
    rep = json.loads((run / "report.json").read_text())
    assert rep["zenoh"]["keys_prefix"] == "slungpilot/1" and rep["zenoh"]["obstacles_in_accepted"] >= 1
    assert rep["zenoh"]["obstacles_in_rejected"] == 4, "bad obstacle samples are counted (and ignored)"


def test_status_stream_carries_the_loop_lag(zenoh_flight):
    _, seen, _ = zenoh_flight
    lags = [s["loop_lag_ms"] for s in seen["status"] if s.get("loop_lag_ms") is not None]
    assert lags and all(50.0 <= v <= 110.0 for v in lags), seen["status"][-3:]
    assert all(s["ff_lag_trust"] == 1.0 for s in seen["status"])  # a clean link: the feed-forward never fades


def test_swing_stream_of_a_lockstep_flight_arrives_without_gaps(zenoh_flight):
    _, seen, run = zenoh_flight
    seqs = seen["swing_seq"]
    rep = json.loads((run / "report.json").read_text())
    assert len(seqs) > 1000
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs))), "sequence gap or reordering in the swing stream"
    assert seqs[-1] + 1 == rep["zenoh"]["published"]["swing"], "samples published after the last one we saw"
    assert "slungpilot.swing/v1" in seen["encodings"]["swing"]


def test_live_trunk_is_used_and_avoided(zenoh_flight):
    _, seen, run = zenoh_flight
    assert seen["published_at_x"] is not None and seen["published_at_x"] < 4.0, "fed before the vehicle got there"
    live = [s for s in seen["obstacle_sets"] if s.get("obstacles")]
    assert live, "the trunk never showed up on the obstacles stream"
    (obs,) = live[-1]["obstacles"]
    assert obs["x_m"] == 6.0 and "perception" in obs["source"]
    rep = json.loads((run / "report.json").read_text())
    assert rep["reached_goal"] and rep["collisions"] == 0 and rep["min_clearance_m"] > 0.0
    log = np.load(run / "flight_log.npz")
    pos = log["pos_ned_m"]
    near = np.abs(pos[:, 0] - 6.0) < 0.5
    # the straight line passes 0.1 m from the trunk's axis; the vehicle detours by more than its radius
    assert np.max(np.abs(pos[near, 1] - 0.1)) > 0.3 + 0.28, "no detour around the live trunk"


def test_config_queryable_and_liveliness(zenoh_flight):
    _, seen, _ = zenoh_flight
    cfg = seen["config"]
    assert cfg is not None
    body = cfg.get("config", cfg)
    assert body["mission"]["name"] == "open_field" and body["vehicle"]["m"] == 0.25
    assert "smc" in body["controller"]
    kinds = [k for key, k in seen["alive"] if key == "slungpilot/1/alive"]
    assert kinds[0].endswith("PUT") and kinds[-1].endswith("DELETE"), kinds


def test_two_vehicles_two_companions_one_subscriber_through_a_router(tmp_path):
    """Two bundled vehicles, two companions and one subscriber, all Zenoh clients of one Python router."""
    endpoint = f"tcp/127.0.0.1:{_free_tcp_port()}"
    router = subprocess.Popen(
        [sys.executable, "-m", "companion.cli.main", "zenoh-router", "--zenoh-listen", endpoint, "--duration", "150"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        assert "router" in router.stdout.readline()
        sub = subprocess.Popen(
            [sys.executable, str(ROOT / "tests" / "helpers" / "zenoh_count.py"), endpoint, "client",
             str(tmp_path / "seen.json"), "2"],
            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )
        assert sub.stdout.readline().strip() == "ready"
        mission = _open_field_mission(tmp_path)
        flights = [
            subprocess.Popen(
                [sys.executable, "-m", "companion.cli.main", "fly", "--sitl", "--mission", str(mission), "--no-plots",
                 "--run-dir", str(tmp_path / f"v{vid}"), "--zenoh-mode", "client", "--zenoh-connect", endpoint,
                 "--vehicle-id", vid],
                cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            )
            for vid in ("1", "2")
        ]
        for vid, f in zip(("1", "2"), flights, strict=True):
            _, err = f.communicate(timeout=240)
            rep = tmp_path / f"v{vid}" / "report.json"
            vehicle = json.loads(rep.read_text()).get("sitl_vehicle") if rep.exists() else None
            assert f.returncode == 0, f"{err[-2000:]}\nits vehicle's process: {vehicle}"
        _, serr = sub.communicate(timeout=60)
        assert sub.returncode == 0, serr[-2000:]
    finally:
        router.terminate()
        router.wait(timeout=20)
    seen = json.loads((tmp_path / "seen.json").read_text())
    assert seen["gone"] == ["slungpilot/1/alive", "slungpilot/2/alive"]
    for vid in ("1", "2"):
        seqs = seen["seqs"][f"slungpilot/{vid}/swing"]
        rep = json.loads((tmp_path / f"v{vid}" / "report.json").read_text())
        assert rep["zenoh"]["keys_prefix"] == f"slungpilot/{vid}"
        assert len(seqs) > 1000 and seqs == list(range(seqs[0], seqs[0] + len(seqs)))


def test_the_recording_shows_the_live_trunk_with_its_source(zenoh_flight):
    """Issue 14: the run folder's recording.rrd draws the trunk fed in mid-flight, labelled with its publisher."""
    from rerun.chunk import RrdReader

    _, _, run = zenoh_flight
    labels, events = [], []
    for chunk in RrdReader(run / "recording.rrd").stream():
        batch = chunk.to_record_batch()
        if chunk.entity_path == "/world/trunks/live" and "Cylinders3D:labels" in batch.schema.names:
            labels += [x for x in batch.column("Cylinders3D:labels").to_pylist() if x]
        if chunk.entity_path == "/log/events":
            events += [" ".join(x) for x in batch.column("TextLog:text").to_pylist() if x]
    assert any("slungpilot/1/obstacles/in/perception" in lab for lab in labels), labels
    assert any("live trunk from slungpilot/1/obstacles/in/perception" in e for e in events), events
