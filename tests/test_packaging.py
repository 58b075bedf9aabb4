"""A plain install works like one (issue 13): build the wheel, install it away from the source tree, and fly the
bundled vehicle from another directory with the shipped configs read as package data."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.shares_cores  # lockstep processes, no deadline: they may share the cores (conftest.py)

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> tuple[Path, dict[str, str]]:
    """The project built as a wheel and installed (no deps: they are this venv's) into a folder of its own."""
    tmp = tmp_path_factory.mktemp("wheel")
    build = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(tmp / "dist"),
                            str(ROOT)], capture_output=True, text=True, timeout=300)
    assert build.returncode == 0, build.stderr[-2000:]
    wheels = list((tmp / "dist").glob("slungpilot-*.whl"))
    assert len(wheels) == 1
    target = tmp / "site"
    inst = subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(target),
                           str(wheels[0])], capture_output=True, text=True, timeout=300)
    assert inst.returncode == 0, inst.stderr[-2000:]
    # The wheel's copy comes first on the path, ahead of the editable install of this checkout.
    env = {**os.environ, "PYTHONPATH": str(target)}
    return tmp, env


def _run(args: list[str], env: dict[str, str], cwd: Path, timeout: float = 180.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=timeout, env=env, cwd=cwd)


@pytest.mark.slow
def test_the_wheel_ships_the_configs_and_a_version(installed):
    tmp, env = installed
    where = tmp / "elsewhere"
    where.mkdir()
    code = ("import companion, companion.config as c; print(companion.__file__); print(companion.__version__); "
            "print(sorted(c.shipped_missions())); print(c.shipped_config('controller.toml').is_file())")
    out = _run(["-c", code], env, where)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[0].startswith(str(tmp / "site"))  # not the source tree
    assert lines[1] != "0+unknown"
    assert "forest" in lines[2] and "group1" in lines[2]
    assert lines[3] == "True"
    ver = _run(["-m", "companion.cli", "--version"], env, where)
    assert ver.returncode == 0 and ver.stdout.startswith("slungpilot ")


@pytest.mark.slow
def test_fly_sitl_from_another_directory_with_a_shipped_mission(installed):
    tmp, env = installed
    where = tmp / "user-dir"
    where.mkdir()
    out = _run(["-m", "companion.cli", "fly", "--sitl", "--mission", "group1", "--no-zenoh", "--no-plots",
                "--run-dir", "run"], env, where)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-3000:]
    rep = json.loads((where / "run" / "report.json").read_text())
    assert rep["outcome"] == "completed" and rep["reached_goal"] is True
    assert rep["mission"] == "group1"
