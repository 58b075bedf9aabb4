"""How ``fly --sitl`` starts: the bundled vehicle forked ahead of its command line (``sim_bridge.prefork``) flies
as a fresh ``python -m sim_bridge`` does and is forked only where that is safe; neither process imports
``scipy.linalg`` for numba's BLAS probe. The forked vehicle's process lifetime is tested in
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
    """``fly --sitl`` (the Table 2 forest, ``shaped``, lockstep) with its import log; its stderr."""
    env = dict(os.environ, **{prefork.ENV_SWITCH: "1" if fork else "0"})
    out = subprocess.run([sys.executable, "-X", "importtime", "-m", "companion.cli", "-v", "fly", "--sitl",
                          "--no-zenoh", "--no-plots", "--no-recording", "--planner", "shaped", "--run-dir",
                          str(run_dir)], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    return out.stderr


@pytest.fixture(scope="module")
def flights(tmp_path_factory) -> dict[str, tuple[Path, str]]:
    base = tmp_path_factory.mktemp("fly")
    return {name: (base / name, _fly(base / name, name == "forked")) for name in ("forked", "fresh")}


def test_a_forked_vehicle_flies_the_forest_bit_for_bit_as_a_fresh_one(flights):
    """The flight log with a vehicle forked ahead is the same file as with ``python -m sim_bridge`` (the vehicle
    inherits nothing that changes its physics or the timing of its telemetry)."""
    (a, forked), (b, fresh) = flights["forked"], flights["fresh"]
    assert "starting the bundled vehicle (forked ahead)" in forked
    assert "starting the bundled vehicle: " in fresh and "forked ahead" not in fresh
    assert (a / "flight_log.npz").read_bytes() == (b / "flight_log.npz").read_bytes()


def test_neither_fly_nor_its_vehicle_imports_scipy_linalg(flights):
    """Numba's BLAS probe would import ``scipy.linalg`` (~0.16 s) in each process; no kernel of ours needs BLAS, so
    both skip it (``companion.core.kernel_cache.skip_numba_blas_probe``), the companion's own import log read here
    and the vehicle's in tests/test_sitl_vehicle.py."""
    for _run, err in flights.values():
        imported = {ln.rsplit("|", 1)[-1].strip() for ln in err.splitlines() if ln.startswith("import time")}
        assert "numba" in imported and "scipy.linalg" not in imported


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
