"""The bundled vehicle forked ahead of its command line (``sim_bridge.prefork``): the same flight as a fresh
``python -m sim_bridge``, and forked only where that is safe. Its process lifetime is tested in
tests/test_sitl_launcher.py and tests/test_process_lifetime.py."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest

import companion
from sim_bridge import prefork

ROOT = Path(companion.__file__).resolve().parents[1]

pytestmark = pytest.mark.shares_cores  # lockstep flights: no deadline (conftest.py)


def _fly(run_dir: Path, fork: bool) -> str:
    env = dict(os.environ, **{prefork.ENV_SWITCH: "1" if fork else "0"})
    out = subprocess.run([sys.executable, "-m", "companion.cli", "-v", "fly", "--sitl", "--no-zenoh", "--no-plots",
                          "--no-recording", "--planner", "shaped", "--run-dir", str(run_dir)],
                         cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    return out.stderr


def test_a_forked_vehicle_flies_the_forest_bit_for_bit_as_a_fresh_one(tmp_path):
    """The Table 2 forest in lockstep, ``shaped``: the flight log of a vehicle forked ahead is the same file as that of
    ``python -m sim_bridge`` (the vehicle inherits nothing that changes its physics or its timing of telemetry)."""
    forked, fresh = _fly(tmp_path / "forked", True), _fly(tmp_path / "fresh", False)
    assert "starting the bundled vehicle (forked ahead)" in forked
    assert "starting the bundled vehicle: " in fresh and "forked ahead" not in fresh
    a, b = (tmp_path / d / "flight_log.npz" for d in ("forked", "fresh"))
    assert a.read_bytes() == b.read_bytes()


def test_no_fork_beside_another_thread_or_when_switched_off(monkeypatch):
    """A thread's locks would stay held in the child: forking waits for a single-threaded process. The switch turns
    it off everywhere."""
    monkeypatch.delenv(prefork.ENV_SWITCH, raising=False)
    stop = threading.Event()
    t = threading.Thread(target=stop.wait)
    t.start()
    try:
        assert not prefork.can_fork()
    finally:
        stop.set()
        t.join()
    alone = threading.active_count() == 1  # pytest-xdist's worker may run threads of its own
    assert prefork.can_fork() == (alone and sys.platform.startswith("linux"))
    monkeypatch.setenv(prefork.ENV_SWITCH, "0")
    assert not prefork.can_fork()
