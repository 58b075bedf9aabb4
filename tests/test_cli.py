"""The command line as a new user meets it (issue 14): fast help, exit codes documented, clear one-line errors,
run folders that never collide, shipped missions and obstacle files by name, and the README's live example."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.shares_cores  # lockstep processes, no deadline: they may share the cores (conftest.py)

ROOT = Path(__file__).resolve().parents[1]


def _cli(*args: str, timeout: float = 60.0, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "companion.cli", *args], capture_output=True, text=True,
                          timeout=timeout, cwd=cwd)


@pytest.mark.parametrize("argv", [["--help"], ["fly", "--help"], ["missions", "--help"]])
def test_help_imports_nothing_heavy(argv):
    code = ("import sys; from companion.cli.main import build_parser\n"
            f"try:\n    build_parser({argv!r}).parse_args({argv!r})\nexcept SystemExit:\n    pass\n"
            "heavy = [m for m in ('numpy', 'numba', 'matplotlib', 'scipy', 'pymavlink') if m in sys.modules]\n"
            "print('HEAVY', heavy, file=sys.stderr)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert "HEAVY []" in out.stderr, out.stderr[-500:]


def test_every_exit_code_is_in_fly_help():
    out = _cli("fly", "--help")
    assert out.returncode == 0
    text = " ".join(out.stdout.split())
    for code in ("0 goal reached", "1 mission not completed", "2 broken mission", "3 no vehicle or link lost",
                 "4 the autopilot", "5 preempted", "6 failsafe", "130 interrupted"):
        assert code in text, code


def test_connect_with_sitl_is_refused_not_ignored(tmp_path):
    out = _cli("fly", "--sitl", "--connect", "udpin://127.0.0.1:14999", "--run-dir", str(tmp_path / "r"))
    assert out.returncode == 2 and "--connect: not with --sitl" in out.stderr
    assert "Traceback" not in out.stderr


def test_a_port_in_use_is_one_clear_line_and_no_run_folder(tmp_path):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
        out = _cli("fly", "--connect", f"udpin://127.0.0.1:{port}", "--no-zenoh", cwd=tmp_path)
    assert out.returncode == 3, out.stderr
    lines = [ln for ln in out.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and f"MAVLink port {port}" in lines[0] and "in use" in lines[0], out.stderr
    assert not (tmp_path / "runs").exists()


def test_run_folders_started_in_the_same_instant_never_collide(tmp_path):
    from companion.cli.fly import new_run_dir
    from companion.config import shipped_missions
    from companion.core.mission import load_mission

    m = load_mission(shipped_missions()["forest"])
    dirs = {new_run_dir(m, tmp_path) for _ in range(20)}
    assert len(dirs) == 20 and all(d.is_dir() for d in dirs)


def test_missions_lists_the_shipped_ones_and_fly_finds_them_by_name():
    out = _cli("missions")
    assert out.returncode == 0
    for name in ("forest", "group1", "open_field"):
        assert name in out.stdout
    bad = _cli("fly", "--sitl", "--mission", "no_such_mission")
    from companion.config import shipped_missions

    assert bad.returncode == 2 and f"shipped: {', '.join(sorted(shipped_missions()))};" in bad.stderr


def test_obstacles_publish_with_nobody_listening_sends_nothing_and_says_so():
    from lab.procs import free_tcp_port

    out = _cli("obstacles", "publish", "trunk", "--zenoh-connect", f"tcp/127.0.0.1:{free_tcp_port()}",
               "--wait-s", "1")
    assert out.returncode == 3 and "nobody subscribes" in out.stderr and "published" not in out.stdout


@pytest.mark.slow
def test_the_readme_live_obstacle_example_changes_the_path(tmp_path):
    """README: a shipped trunk published while the open field is flown; the vehicle flies around it.

    The publisher listens and is up before the flight starts: the other way round (the flight listening, the
    publisher connecting) its connection retries raced a lockstep flight that reaches the trunk ~2 s of wall time
    after start, and the trunk once arrived with the vehicle already in it (fresh machine, 2026-12-04)."""
    from lab.procs import free_tcp_port

    ep = f"tcp/127.0.0.1:{free_tcp_port()}"
    pub = subprocess.Popen([sys.executable, "-m", "companion.cli", "obstacles", "publish", "trunk",
                            "--zenoh-listen", ep, "--wait-s", "120"], cwd=ROOT, stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True)
    assert pub.stderr.readline().startswith("waiting up to 120 s for a subscriber")
    fly = _cli("-q", "fly", "--sitl", "--mission", "open_field", "--zenoh-connect", ep, "--no-plots", "--run-dir",
               str(tmp_path / "run"), timeout=240)
    out, err = pub.communicate(timeout=60)
    assert pub.returncode == 0 and "published 1 obstacles" in out, err
    assert fly.returncode == 0, fly.stderr[-2000:]
    rep = json.loads((tmp_path / "run" / "report.json").read_text())
    assert rep["collisions"] == 0 and rep["zenoh"]["obstacles_in_accepted"] == 1
    pos = np.load(tmp_path / "run" / "flight_log.npz")["pos_ned_m"]
    near = np.abs(pos[:, 0] - 6.0) < 0.5
    assert np.max(np.abs(pos[near, 1] - 0.1)) > 0.3 + 0.28, "no detour around the published trunk"


@pytest.mark.slow
def test_bench_fly_flies_this_tree_and_another_interleaved():
    """`bench fly --against DIR` flies real `fly --sitl` commands of this checkout and of DIR, one after the other
    (here DIR is this tree again): a line of numbers each, the goal reached."""
    proc = subprocess.run([sys.executable, "-m", "companion.cli.main", "bench", "fly", "--repeats", "1", "--against",
                           str(ROOT)], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-2000:]
    lines = [ln for ln in proc.stdout.splitlines() if "end to end" in ln and "in flight" in ln]
    assert [ln.split(":")[0].strip() for ln in lines] == ["this", str(ROOT)]
    assert all("goal: True" in ln for ln in lines)


def test_sitl_airmode_reaches_the_vehicle_and_needs_sitl():
    """``fly --sitl --sitl-airmode 0`` starts the bundled vehicle with ``--airmode 0``; without --sitl it is refused
    (a real autopilot's MC_AIRMODE is its own)."""
    from companion.cli.fly import spec_from_args
    from companion.cli.main import build_parser
    from companion.errors import ConfigError

    def spec(*argv: str):
        args = build_parser(["fly"]).parse_args(["fly", "--no-zenoh", *argv])
        from companion.cli.fly import mission_from_args

        return spec_from_args(args, mission_from_args(args))

    sitl_args = spec("--sitl", "--sitl-airmode", "0").sitl_args
    assert sitl_args[sitl_args.index("--airmode") + 1] == "0"
    assert "--airmode" not in spec("--sitl").sitl_args
    with pytest.raises(ConfigError, match="--sitl-airmode: only with --sitl"):
        spec("--sitl-airmode", "1")
