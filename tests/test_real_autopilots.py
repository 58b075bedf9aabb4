"""The companion against real autopilots in software (issue 10): PX4 v1.15 SITL with the SIH quadrotor and
ArduCopter SITL with its simulated slung payload, built from their own sources (docs/autopilots.md). Each test
skips, saying why, where the binaries are not found (``SLUNGPILOT_PX4_BUILD``, ``SLUNGPILOT_ARDUPILOT``).

Real time (these autopilots run on the wall clock); a flight takes a minute or two including the autopilot's
own start-up (PX4 SIH reports ready to arm ~40 s after boot, ArduCopter ~25 s). No parameter is set by hand:
what a vehicle needs, the companion sets itself and lists in the report.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from lab import sitl_external
from lab.procs import free_udp_port

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.slow

PX4, PX4_WHY = sitl_external.find_px4()
ARDUCOPTER, ARDUCOPTER_WHY = sitl_external.find_arducopter()
needs_px4 = pytest.mark.skipif(PX4 is None, reason=PX4_WHY)
needs_arducopter = pytest.mark.skipif(ARDUCOPTER is None, reason=ARDUCOPTER_WHY)


def _fly(run_dir: Path, port: int, *extra: str, timeout: float = 420.0) -> tuple[subprocess.CompletedProcess, dict]:
    out = subprocess.run([sys.executable, "-m", "companion.cli", "-q", "fly", "--connect", f"udpin://127.0.0.1:{port}",
                          "--no-zenoh", "--no-recording", "--no-plots", "--run-dir", str(run_dir), *extra],
                         capture_output=True, text=True, timeout=timeout, cwd=ROOT)
    rep = json.loads((run_dir / "report.json").read_text())
    print(json.dumps({k: rep.get(k) for k in ("outcome", "time_to_goal_s", "max_swing_rad", "min_clearance_m",
                                              "collisions", "path_length_m", "swing_estimation_error",
                                              "autopilot_params", "mission_frame", "tracking_error_m")}, indent=1))
    return out, rep


def _stop(proc: subprocess.Popen) -> None:
    try:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(20)
    except (ProcessLookupError, subprocess.TimeoutExpired):
        os.killpg(proc.pid, signal.SIGKILL)


@pytest.fixture
def px4(tmp_path):
    instance = 6
    proc = sitl_external.start_px4_sih(tmp_path, instance)
    yield 14540 + instance
    _stop(proc)


@pytest.fixture
def arducopter(tmp_path):
    port = free_udp_port()
    proc = sitl_external.start_arducopter(tmp_path, port, payload=True)
    yield port
    _stop(proc)


@needs_px4
def test_px4_sih_flies_the_table2_forest(px4, tmp_path):
    out, rep = _fly(tmp_path / "run", px4)
    assert out.returncode == 0, out.stderr[-3000:]
    assert rep["outcome"] == "completed" and rep["collisions"] == 0 and rep["min_clearance_m"] > 0
    assert rep["autopilot"]["family"] == "px4" and rep["autopilot"]["version"]["flight_sw_version"].startswith("1.15")
    assert rep["autopilot_params"]["set"] == {}  # PX4 needs nothing changed
    assert "wind" not in rep  # the simulated wind is the bundled vehicle's, not PX4's
    # the loop lag measured against PX4 SIH is the profile's clean-link figure (0.17 s): nothing faded
    assert rep["loop_lag"]["lag_ms_max"] is not None and rep["loop_lag"]["faded_s"] == 0.0, rep["loop_lag"]


@needs_arducopter
def test_arducopter_with_its_slung_payload_flies_the_table2_forest(arducopter, tmp_path):
    out, rep = _fly(tmp_path / "run", arducopter, "--mission", "forest_arducopter_sitl")
    assert out.returncode == 0, out.stderr[-3000:]
    assert rep["outcome"] == "completed" and rep["collisions"] == 0 and rep["min_clearance_m"] > 0
    assert rep["autopilot"]["family"] == "ardupilot"
    assert rep["autopilot_params"]["set"].get("GUID_OPTIONS", 0) == 8.0  # set by the companion, said in the report
    est = rep["swing_estimator"]
    assert est is not None and est["inputs"].get("payload_fix", 0) > 50  # ArduPilot's payload fixes feed it
    assert rep["max_swing_rad"] is not None
    # ArduCopter's loop lag (0.18-0.29 s measured) is its profile's clean-link figure: the feed-forward never faded
    assert rep["loop_lag"]["lag_ms_max"] is not None and rep["loop_lag"]["faded_s"] == 0.0, rep["loop_lag"]


@needs_arducopter
def test_arducopter_sensorless_tracks_its_payload_and_damps_it(arducopter, tmp_path):
    """Issue 11 on ArduCopter SITL: the estimate from the vehicle's own IMU, attitude, velocity and commanded thrust
    (no payload fixes used; they only score it) tracks SIM_SLUP's payload and damps its swing. Measured
    2026-12-02: error at the fixes 0.025-0.027 rad RMS, max swing 0.35-0.36 rad against 0.64 with no swing input."""
    out, rep = _fly(tmp_path / "run", arducopter, "--mission", "forest_arducopter_sitl",
                    "--swing-input", "estimate_imu")
    assert out.returncode == 0, out.stderr[-3000:]
    assert rep["outcome"] == "completed" and rep["collisions"] == 0
    est = rep["swing_estimator"]
    assert est["inputs"].get("payload_fix", 0) == 0 and est["inputs"].get("imu", 0) > 1000
    err = est["error_at_fixes"]
    assert err["fixes"] > 50 and err["rms_rad"] <= 0.03, err  # issue 11's sensorless target
    assert rep["max_swing_rad"] < 0.5  # none: 0.64 rad
    assert 0.5 < est["drag_n_per_mps"] < 1.5  # the SITL quad drags ~1 N per m/s (the estimator found 1.0-1.05)


@needs_arducopter
def test_arducopter_without_param_writes_is_refused_with_what_to_set(arducopter, tmp_path):
    out, rep = _fly(tmp_path / "run", arducopter, "--no-param-writes", timeout=180)
    assert out.returncode == 4
    assert rep["outcome"] == "refused" and "GUID_OPTIONS" in rep["outcome_detail"]
    assert "Set GUID_OPTIONS to 8" in out.stderr


@needs_px4
def test_px4_lands_by_itself_when_the_companion_is_killed(tmp_path):
    from lab.faults_vehicle import companion_killed_vehicle_failsafe

    r = companion_killed_vehicle_failsafe(tmp_path, vehicle="px4", instance=6, watch_s=60.0)
    print(json.dumps(r, indent=1))
    assert r["left_offboard_s"] is not None and r["left_offboard_s"] <= 2.5  # COM_OF_LOSS_T 1 s
    assert r["landed_s"] is not None and r["disarmed_s"] is not None and r["max_descent_mps"] < 1.5


@needs_arducopter
def test_arducopter_lands_by_itself_when_the_companion_is_killed(tmp_path):
    from lab.faults_vehicle import companion_killed_vehicle_failsafe

    r = companion_killed_vehicle_failsafe(tmp_path, vehicle="ardupilot", watch_s=60.0)
    print(json.dumps(r, indent=1))
    assert r["landed_s"] is not None and r["disarmed_s"] is not None and r["max_descent_mps"] < 1.5


@needs_arducopter
def test_arducopter_carrying_an_unknown_payload_hops_identifies_and_flies_it(tmp_path):
    """Issue 28 against a real autopilot: ArduCopter's slung payload is 0.35 kg on 1.3 m, the mission declares the
    vehicle's 0.25 kg on 1 m and says the payload is unknown (``[payload] identify = true``): the companion hops,
    identifies from ArduCopter's own IMU and attitude, and flies on; the report says what it found and flew."""
    port = free_udp_port()
    proc = sitl_external.start_arducopter(tmp_path, port, payload=True, mass_kg=0.35, cable_m=1.3)
    try:
        text = (ROOT / "config" / "missions" / "forest_arducopter_sitl.toml").read_text()
        mission = tmp_path / "unknown_payload.toml"
        mission.write_text(text.replace("[payload]\n", "[payload]\nidentify = true\n"))
        out, rep = _fly(tmp_path / "run", port, "--mission", str(mission))
    finally:
        _stop(proc)
    print(json.dumps(rep["payload"], indent=1))
    assert out.returncode == 0, out.stderr[-3000:]
    assert rep["outcome"] == "completed" and rep["collisions"] == 0
    flown = rep["payload"]["flown"]
    assert flown["hop_m"] is not None and flown["hop_m"] >= 0.5
    assert rep["payload"]["identified"] is not None and rep["payload"]["identified"]["samples"] > 100
    # each value trusted must be near the truth; one not trusted flies as declared, and the report says why
    assert abs(flown["mass_kg"] - 0.35) < 0.15 if flown["mass_identified"] else flown["mass_kg"] == 0.25
    assert abs(flown["cable_length_m"] - 1.3) < 0.2 if flown["cable_identified"] else flown["cable_length_m"] == 1.0
    assert flown["reason"] or (flown["mass_identified"] and flown["cable_identified"])


def _fly_arducopter_carrying(tmp_path: Path, true: tuple[float, float], *, declared: tuple[float, float], alt_m: float,
                             identify: bool) -> tuple[subprocess.CompletedProcess, dict]:
    """ArduCopter SITL with SIM_SLUP's payload ``true`` (kg, m), flying ``forest_arducopter_sitl`` declaring
    ``declared`` at ``alt_m``."""
    port = free_udp_port()
    proc = sitl_external.start_arducopter(tmp_path, port, payload=True, mass_kg=true[0], cable_m=true[1])
    try:
        mission = _arducopter_mission(tmp_path, mass_kg=declared[0], cable_m=declared[1], alt_m=alt_m,
                                      identify=identify)
        return _fly(tmp_path / "run", port, "--mission", str(mission))
    finally:
        _stop(proc)


def _arducopter_mission(tmp_path: Path, *, mass_kg: float, cable_m: float, alt_m: float, identify: bool) -> Path:
    """``forest_arducopter_sitl`` declaring another payload, flown at ``alt_m`` (a long cable needs the height)."""
    text = (ROOT / "config" / "missions" / "forest_arducopter_sitl.toml").read_text()
    for old, new in (("m = 0.25                    # SIM_SLUP_WEIGHT", f"m = {mass_kg!r}"),
                     ("l = 1.0\n", f"l = {cable_m!r}\n"), ("[0.0, 0.0, -2.0]", f"[0.0, 0.0, {-alt_m!r}]"),
                     ("[10.0, 0.0, -2.0]", f"[10.0, 0.0, {-alt_m!r}]")):
        assert old in text, old
        text = text.replace(old, new)
    if identify:
        text = text.replace("[payload]\n", "[payload]\nidentify = true\n")
    path = tmp_path / "payload.toml"
    path.write_text(text)
    return path


@needs_arducopter
def test_arducopter_with_a_heavy_payload_on_a_2_m_cable_flies_the_forest(tmp_path):
    """Issue 28 on a real autopilot: SIM_SLUP's payload 0.6 kg on 2 m, declared so, flown at 3 m. Measured
    2026-12-06: completed, 10.07 s, 0.227 rad, 0.67 m clear (0.25 kg on 2 m: 10.11 s, 0.227 rad; on 3 m at 4 m:
    10.92 s, 0.182 rad); the paper's 1 m: 7.33 s, 0.36 rad."""
    out, rep = _fly_arducopter_carrying(tmp_path, (0.6, 2.0), declared=(0.6, 2.0), alt_m=3.0, identify=False)
    assert out.returncode == 0, out.stderr[-3000:]
    assert rep["outcome"] == "completed" and rep["collisions"] == 0 and rep["min_clearance_m"] > 0.3
    assert rep["max_swing_rad"] < 0.35, rep["max_swing_rad"]


@needs_arducopter
def test_arducopter_with_a_payload_heavier_and_longer_than_declared_identifies_it(tmp_path):
    """Issue 28's mis-declared payload on a real autopilot: SIM_SLUP's 0.35 kg on 2 m, the mission declares 0.25 kg
    on 1.54 m (40 % heavier, 30 % longer than declared) and ``identify = true``. Measured 2026-12-06: hop 0.5 m,
    identified 0.28 ± 0.06 kg on 2.02 ± 0.06 m, both flown; completed, 9.48 s, 0.255 rad (without identify: too
    little excitation in the cruise to identify, 0.306 rad, clean)."""
    out, rep = _fly_arducopter_carrying(tmp_path, (0.35, 2.0), declared=(0.25, 1.54), alt_m=3.0, identify=True)
    print(json.dumps(rep["payload"], indent=1))
    assert out.returncode == 0, out.stderr[-3000:]
    assert rep["outcome"] == "completed" and rep["collisions"] == 0
    flown = rep["payload"]["flown"]
    assert flown["cable_identified"] and abs(flown["cable_length_m"] - 2.0) < 0.2, flown
    assert rep["payload"]["declared"] == {"mass_kg": 0.25, "cable_length_m": 1.54}
    assert any("cable length" in line for line in rep["payload"]["mismatch"])
