"""The 3-D view and its recordings (issue 14), the way a user meets them.

* a real flight's ``recording.rrd`` read back with Rerun's own reader: entities, sample counts, the
  ``mission_time`` timeline starting at the mission's first tick;
* Rerun's web viewer served on loopback by ``slungpilot replay --web``, opened in headless Chromium, and the
  screenshot checked for the trunks' colour and for content (skipped, saying why, without Chromium);
* ``fly --view web`` prints a loopback URL that serves the viewer during the flight and stops it afterwards;
* ``slungpilot view`` records two vehicles from Zenoh under their own paths;
* the geometry against the companion's own model functions, and the logging queue's drop-when-full rule.
"""

from __future__ import annotations

import collections
import json
import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

rr = pytest.importorskip("rerun")
from rerun.chunk import RrdReader  # noqa: E402

from companion.core.model import payload_offset_ned_m  # noqa: E402
from companion.core.obstacles import Obstacle  # noqa: E402
from companion.core.rotations import quat_from_euler  # noqa: E402
from companion.viz import scene  # noqa: E402
from companion.viz.recorder import Recorder  # noqa: E402

pytestmark = pytest.mark.paired  # wall clock, light: may run beside one other such test (tests/conftest.py)

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMEDRIVER = shutil.which("chromedriver")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def read_recording(path: Path) -> tuple[collections.Counter, collections.Counter, dict[str, list]]:
    """Rows per entity (temporal and static) and, per entity, its chunks' Arrow record batches."""
    rows: collections.Counter = collections.Counter()
    static: collections.Counter = collections.Counter()
    batches: dict[str, list] = collections.defaultdict(list)
    for chunk in RrdReader(path).stream():
        (static if chunk.is_static else rows)[chunk.entity_path] += chunk.num_rows
        batches[chunk.entity_path].append(chunk.to_record_batch())
    return rows, static, batches


def _column(batches: list, name: str) -> list:
    vals: list = []
    for b in batches:
        if name in b.schema.names:
            vals.extend(b.column(name).to_pylist())
    return vals


def _times_s(batches: list, name: str) -> np.ndarray:
    """A duration timeline's values in seconds (Rerun stores nanoseconds)."""
    import pyarrow as pa

    return np.concatenate([b.column(name).cast(pa.int64()).to_numpy(zero_copy_only=False) * 1e-9
                           for b in batches if name in b.schema.names])


# ------------------------------------------------------------------------------------------------ geometry
def test_quaternions_match_the_companions_rotation():
    rng = np.random.default_rng(3)
    e = rng.uniform(-1.0, 1.0, (20, 3)) * np.array([0.8, 0.8, 3.0])
    q = scene.quat_xyzw_from_euler(e)
    for row, qq in zip(e, q, strict=True):
        w, x, y, z = quat_from_euler(*row)
        assert np.allclose(qq, [x, y, z, w], atol=1e-12)


def test_payload_points_match_eqs_3_4():
    pos = np.array([[1.0, 2.0, -3.0], [0.0, 0.0, -1.0]])
    a, b = np.array([0.2, -0.4]), np.array([0.1, 0.3])
    got = scene.payload_pos_ned_m(pos, a, b, 0.8)
    for i in range(2):
        assert np.allclose(got[i], pos[i] + payload_offset_ned_m(a[i], b[i], 0.8))


def test_envelope_cylinder_hangs_from_the_airframe_to_the_cable_length():
    strips = scene.envelope_strips(1.2)
    pts = np.concatenate(strips)
    assert np.allclose(np.hypot(pts[:, 0], pts[:, 1]), 1.0)  # unit radius: the view scales it by R_max
    assert pts[:, 2].min() == 0.0 and pts[:, 2].max() == pytest.approx(1.2)  # NED: down to the payload


def test_trunks_are_split_by_source_and_withdrawn_ones_marked_gone():
    m = Obstacle(1.0, 0.0, 0.2)
    a1 = Obstacle(5.0, 0.0, 0.3, source="lidar")
    a2 = Obstacle(5.5, 0.0, 0.3, source="lidar")  # lidar moved its trunk: the old one is not "gone"
    b = Obstacle(7.0, 1.0, 0.3, source="camera")
    mission, live, gone = scene.split_trunks((m, a1, a2, b), (m, a2))
    assert mission == [m] and live == [a2] and gone == [b]
    assert scene.split_trunks((m, a1), None) == ([m], [a1], [])
    t = scene.trunk_arrays([m, b])
    assert t.labels == ["mission", "camera"] and np.allclose(t.centers[:, 2], [-2.0, -2.0])


# ------------------------------------------------------------------------------------------------ the queue
def test_a_full_queue_drops_and_counts_without_blocking(tmp_path):
    def slow(rec, items):
        time.sleep(0.05)

    rec = Recorder("t", slow, [rr.FileSink(str(tmp_path / "q.rrd"))], max_queue=100, flush_s=0.01).open()
    try:
        t0 = time.perf_counter()
        accepted = sum(rec.put((float(i),)) for i in range(5000))
        elapsed = time.perf_counter() - t0
    finally:
        rec.close()
    assert accepted + rec.dropped == 5000 and rec.dropped > 0
    assert elapsed < 1.0, "put never waits for the logging thread"


def test_a_failing_handler_is_counted_and_the_recording_still_closes(tmp_path):
    def broken(rec, items):
        raise RuntimeError("boom")

    rec = Recorder("t", broken, [rr.FileSink(str(tmp_path / "b.rrd"))], flush_s=0.01).open()
    rec.put((1.0,))
    time.sleep(0.1)
    rec.close()
    assert rec.handler_errors >= 1 and (tmp_path / "b.rrd").exists()


# ------------------------------------------------------------------------------------------------ live trunk
def test_live_trunks_are_drawn_with_their_source_and_marked_gone_when_withdrawn(tmp_path):
    """The sink with a synthetic flight: a live trunk arrives, then its publisher withdraws it."""
    from companion.cli.bench_view import synthetic_tick
    from companion.config import shipped_config
    from companion.core.mission import load_mission
    from companion.viz.flight import RECORDING_FILE, open_flight_recording

    mission = load_mission(shipped_config("missions/forest.toml"))
    live = Obstacle(6.0, 0.1, 0.3, source="slungpilot/1/obstacles/in/lidar")
    app = SimpleNamespace(phase="mission", state=SimpleNamespace(payload_pos_ned_m=None),
                          obstacles_seen=tuple(mission.obstacles))
    current = list(mission.obstacles)
    view = open_flight_recording(mission, tmp_path)
    view.current_obstacles = lambda: current
    for k in range(750):  # 3 s at 250 Hz
        if k == 250:
            app.obstacles_seen = (*mission.obstacles, live)
            current = [*mission.obstacles, live]
        if k == 500:
            current = list(mission.obstacles)
        est, cmd = synthetic_tick(k / 250.0)
        view.on_tick(est, None if k < 3 else cmd, app)  # the mission starts at the first command
    view.recorder.close()
    rows, static, batches = read_recording(tmp_path / RECORDING_FILE)
    assert rows["/plots/swing"] == 747 and view.stats()["dropped"] == 0
    assert rows["/world/uav"] == pytest.approx(747 / 250 * 30, abs=2)  # 30 Hz of mission time
    labels = [x for x in _column(batches["/world/trunks/live"], "Cylinders3D:labels") if x]
    assert any(live.source in lab for lab in labels)
    gone = [x for x in _column(batches["/world/trunks/gone"], "Cylinders3D:labels") if x]
    assert any(live.source in lab for lab in gone)
    text = " ".join(str(x) for x in _column(batches["/log/events"], "TextLog:text"))
    assert "live trunk from slungpilot/1/obstacles/in/lidar" in text and "gone" in text
    assert static["/world/trunks/mission"] == 1


# ------------------------------------------------------------------------------------------------ real flight
@pytest.fixture(scope="module")
def flown(tmp_path_factory) -> Path:
    run = tmp_path_factory.mktemp("viz") / "run"
    res = subprocess.run(
        [sys.executable, "-m", "companion.cli.main", "fly", "--sitl", "--no-zenoh", "--no-plots",
         "--run-dir", str(run)],
        cwd=ROOT, capture_output=True, text=True, timeout=300,
    )
    assert res.returncode == 0, res.stderr[-3000:]
    return run


@pytest.mark.slow
def test_a_flight_recording_reads_back_with_every_entity(flown):
    rows, static, batches = read_recording(flown / "recording.rrd")
    rep = json.loads((flown / "report.json").read_text())
    rec = rep["recording"]
    assert rec["dropped"] == 0 and rec["handler_errors"] == 0 and rec["bytes"] > 0
    ticks = rec["ticks"]
    for ent in ("/plots/swing", "/plots/attitude", "/plots/thrust", "/plots/thrust_norm", "/plots/envelope"):
        assert rows[ent] == ticks, ent  # every tick from the mission's start on
    t = _times_s(batches["/plots/swing"], "mission_time")
    assert t.min() == 0.0, "mission time starts at the mission's first tick, not at the vehicle's boot"
    flight_s = t.max()
    assert flight_s > rep["sim_time_s"]  # the landing is recorded too
    frames = rows["/world/uav"]
    assert frames == pytest.approx(flight_s * 30.0, rel=0.02)
    for ent in ("/world/envelope", "/world/payload", "/world/cable"):
        assert rows[ent] == frames, ent
    assert 0 < rows["/world/reference"] <= frames  # no reference while landing
    assert any(k.startswith("/world/path/flown/") for k in rows)
    for ent in ("/world", "/world/uav/airframe", "/world/envelope/cylinder", "/world/trunks/mission",
                "/world/mission/start", "/world/mission/goal"):
        assert static[ent] >= 1, ent
    radii = [r for r in _column(batches["/world/trunks/mission"], "Cylinders3D:radii") if r]
    from companion.config import shipped_config
    from companion.core.mission import load_mission

    forest = load_mission(shipped_config("missions/forest.toml"))
    assert radii[0] == pytest.approx([o.radius_m for o in forest.obstacles])  # the forest's trunks
    text = " ".join(str(x) for x in _column(batches["/log/events"], "TextLog:text"))
    assert "mission start" in text and "cruise" in text and "land" in text


@pytest.mark.skipif(CHROMIUM is None or CHROMEDRIVER is None,
                    reason="needs Debian's chromium and chromium-driver (apt-get install chromium chromium-driver)")
def test_replay_in_the_web_viewer_renders_the_flight_in_headless_chromium(flown, tmp_path):
    webdriver = pytest.importorskip("selenium.webdriver", reason="needs selenium (the test extra)")
    from selenium.webdriver.chrome.service import Service

    port = _free_port()
    replay = subprocess.Popen(
        [sys.executable, "-m", "companion.cli.main", "replay", str(flown), "--web", "--port", str(port)],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
    )
    try:
        line = replay.stdout.readline()
        assert f"http://127.0.0.1:{port}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A" in line, line
        url = line.split(": ", 1)[1].split()[0]
        opts = webdriver.ChromeOptions()
        opts.binary_location = CHROMIUM
        for a in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync",
                  "--window-size=1400,900", f"--user-data-dir={tempfile.mkdtemp(dir=tmp_path)}"):
            opts.add_argument(a)
        driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=opts)
        shot = tmp_path / "viewer.png"
        try:
            driver.get(url)
            deadline = time.monotonic() + 240.0  # the viewer's wasm compiles slowly on a busy 2-core machine
            found = 0
            while time.monotonic() < deadline:
                time.sleep(3.0)
                driver.save_screenshot(str(shot))
                img = _png_rgb(shot)
                found = _trunk_pixels(img)
                if found > 300:
                    break
            console = [e.get("message", "")[:200] for e in driver.get_log("browser") if e.get("level") == "SEVERE"
                       and "rerun.io" not in e.get("message", "")][-5:]  # the closed network's refusals aside
        finally:
            driver.quit()
        img = _png_rgb(shot)
        # The trunks' brown (shaded in 3-D) must be on screen: the scene rendered our data, not only the UI.
        assert found > 300, f"no trunks on screen ({found} brown pixels); screenshot at {shot}; console {console}"
        flat = img.reshape(-1, 3).astype(float)
        background = np.median(flat, axis=0)
        differs = np.mean(np.abs(flat - background).sum(axis=1) > 40)
        assert differs > 0.05 and flat.std(axis=0).mean() > 15, "the page is not a blank canvas"
    finally:
        os.killpg(replay.pid, signal.SIGINT)
        replay.wait(20)
    assert _port_closed(port), "replay stops the web viewer on Ctrl-C"


def _png_rgb(path: Path) -> np.ndarray:
    from PIL import Image  # pillow comes with rerun-sdk

    return np.asarray(Image.open(path).convert("RGB"))


def _trunk_pixels(img: np.ndarray) -> int:
    """Pixels in the trunks' shaded brown (RGB 139, 69, 19 lit from any side): red > green > blue, clearly."""
    r, g, b = (img[..., i].astype(int) for i in range(3))
    return int(np.sum((r > 60) & (r - g > 25) & (g - b > 12) & (r < 230) & (b < 90)))


def _port_closed(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(0.5)
        return s.connect_ex(("127.0.0.1", port)) != 0


@pytest.mark.slow
def test_fly_view_web_serves_the_viewer_on_loopback_during_the_flight(tmp_path):
    port = _free_port()
    fly = subprocess.Popen(
        [sys.executable, "-m", "companion.cli.main", "fly", "--sitl", "--no-zenoh", "--no-plots",
         "--view", "web", "--view-port", str(port), "--run-dir", str(tmp_path / "run")],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        line = fly.stdout.readline()  # printed before the vehicle starts, so the flight is still ahead
        assert line.startswith(f"live view: http://127.0.0.1:{port}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A"), line
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=10) as resp:
            assert resp.status == 200 and b"rerun" in resp.read().lower()
        grpc_port = int(line.split("%3A")[-1].split("%2F")[0])
        listening = [c for c in _listeners() if c[1] in (port, grpc_port)]
        assert listening and all(addr == "127.0.0.1" for addr, _ in listening), listening
        _, err = fly.communicate(timeout=300)
    finally:
        if fly.poll() is None:
            fly.kill()
    assert fly.returncode == 0, err[-2000:]
    assert _port_closed(port) and _port_closed(grpc_port), "the web viewer stops with the flight"
    rep = json.loads((tmp_path / "run" / "report.json").read_text())
    assert rep["recording"]["bytes"] > 0 and rep["recording"]["dropped"] == 0


def _listeners() -> list[tuple[str, int]]:
    out = subprocess.run(["ss", "-ltnH"], capture_output=True, text=True).stdout if shutil.which("ss") else ""
    res = []
    for ln in out.splitlines():
        parts = ln.split()
        if len(parts) >= 4 and ":" in parts[3]:
            addr, _, p = parts[3].rpartition(":")
            res.append((addr, int(p)))
    return res


# ------------------------------------------------------------------------------------------------ fleet
@pytest.mark.slow
def test_view_records_every_vehicle_on_zenoh_under_its_own_path(tmp_path):
    from companion.zenoh_io.session import zenoh_config
    from companion.zenoh_io.telemetry import ZenohTelemetry
    from companion.zenoh_io.telemetry_options import TelemetryOptions

    ep1, ep2 = (f"tcp/127.0.0.1:{_free_port()}" for _ in range(2))
    out = tmp_path / "fleet.rrd"
    trunk = Obstacle(6.0, 0.1, 0.3, source="slungpilot/2/obstacles/in/lidar")
    with ZenohTelemetry(zenoh_config("companion", listen=[ep1]), TelemetryOptions(vehicle_id="1")) as z1, \
            ZenohTelemetry(zenoh_config("companion", listen=[ep2]), TelemetryOptions(vehicle_id="2")) as z2:
        view = subprocess.Popen(
            [sys.executable, "-m", "companion.cli.main", "view", "--headless", "--save", str(out), "--duration", "6",
             "--zenoh-connect", ep1, "--zenoh-connect", ep2],
            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )
        assert view.stdout.readline().startswith("subscribed to slungpilot/*/{state,swing,setpoint,obstacles,status}")
        time.sleep(1.0)  # both connections are up (connect retries back off to 1 s)
        for k in range(100):  # 2 s at 50 Hz
            t = k * 0.02
            for i, z in enumerate((z1, z2)):
                pos = [t, 2.0 * i, -2.0]
                z.publish_swing(t, [0.1 * math.sin(t), 0.05, 0.0, 0.0], 0.4, "swing")
                z.publish_state(t, pos, [1.0, 0, 0], [0.05, -0.02, 0.0], [pos[0], pos[1], 0.0])
                z.publish_setpoint(t, {"ref_pos_ned_m": [t + 0.1, 2.0 * i, -2.0], "thrust_n": 12.0})
                z.publish_status(t, {"phase": "mission", "outcome": "running"})
                z.publish_obstacles(t, [Obstacle(3.0, 1.0, 0.2)] + ([trunk] if i == 1 else []))
            time.sleep(0.02)
        stdout, stderr = view.communicate(timeout=60)
    assert view.returncode == 0, stderr[-2000:]
    assert "vehicles seen: 1 (" in stdout and ", 2 (" in stdout and "dropped 0" in stdout, stdout
    rows, static, batches = read_recording(out)
    for vid in ("1", "2"):
        assert rows[f"/world/{vid}/uav"] >= 80, (vid, rows)
        assert rows[f"/world/{vid}/payload"] >= 80 and rows[f"/world/{vid}/reference"] >= 80
        assert rows[f"/plots/{vid}/swing"] >= 80 and rows[f"/world/{vid}/trunks/mission"] >= 1
        assert static[f"/world/{vid}/uav/airframe"] == 1
    labels = [x for x in _column(batches["/world/2/trunks/live"], "Cylinders3D:labels") if x]
    assert any(trunk.source in lab for lab in labels)


# ------------------------------------------------------------------------------------------------ plan view
def test_plan_view_marks_live_trunks_and_explains_its_circles_and_the_time_axis_starts_at_mission_start():
    import matplotlib.pyplot as plt

    from companion.report.plots import _plan, timeseries_figure

    n = 50
    t = 47.0 + np.arange(n) * 0.1  # a vehicle that booted 47 s before the mission
    pos = np.column_stack([np.linspace(0, 10, n), np.zeros(n), np.full(n, -2.0)])
    a = {"t_s": t, "pos_ned_m": pos, "payload_pos_ned_m": pos + np.array([0.0, 0.0, 1.0]), "ref_pos_ned_m": pos,
         "euler_rad": np.zeros((n, 3)), "swing": np.zeros((n, 4)), "r_max_m": np.full(n, 0.4)}
    obstacles = [Obstacle(3.0, 1.0, 0.3), Obstacle(6.0, 0.1, 0.3, source="slungpilot/1/obstacles/in/lidar")]
    fig, ax = plt.subplots()
    _plan(ax, a, obstacles, [0, 0, -2], [10, 0, -2], "t")
    texts = [x.get_text() for x in ax.get_legend().get_texts()]
    plt.close(fig)
    assert "trunk (mission file)" in texts and "trunk added live: lidar" in texts
    assert any(x.startswith("safe distance") for x in texts) and any(x.startswith("crown") for x in texts)
    assert any(x.startswith("swing envelope R_max") for x in texts)
    fig = timeseries_figure(a)
    x = fig.axes[0].lines[0].get_xdata()
    plt.close(fig)
    assert x[0] == 0.0 and x[-1] == pytest.approx(4.9)
