"""Issue 27 against ArduCopter SITL (opt-in like tests/test_real_autopilots.py: skipped, saying why, where
``SLUNGPILOT_ARDUPILOT`` does not point at a build): the companion, an onboard controller now, still hears
ArduCopter's STATUSTEXT; ``ARMING_CHECK 0`` (pre-arm bit present, not enabled) no longer ends ``not_ready``; and a
signed flight reads the slung payload's unsigned stream only with ``--accept-unsigned 2``, saying so.

Real time, a minute or two each; one SITL at a time (its payload dials a fixed TCP port).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pymavlink import mavutil

from lab import sitl_external
from lab.procs import free_udp_port

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.slow
ARDUCOPTER, WHY = sitl_external.find_arducopter()
needs_arducopter = pytest.mark.skipif(ARDUCOPTER is None, reason=WHY)
KEY = bytes(range(1, 33))


def _prepare(port: int, *, params: dict[str, float] | None = None, signing_key: bytes | None = None) -> None:
    """Before the companion: on the port ArduCopter sends to, set ``params`` and/or give it the signing key
    (SETUP_SIGNING), then let go of the port."""
    conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255, source_component=190)
    try:
        assert conn.wait_heartbeat(timeout=60) is not None
        for name, value in (params or {}).items():
            for _ in range(10):
                conn.mav.param_set_send(1, 1, name.encode(), value, 9)
                m = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=1.0)
                if m is not None and m.param_id == name and m.param_value == value:
                    break
            else:
                raise AssertionError(f"ArduCopter did not take {name}={value}")
        if signing_key is not None:
            ts = int((time.time() - 1_420_070_400) * 100_000)
            for _ in range(3):
                conn.mav.setup_signing_send(1, 1, list(signing_key), ts)
                time.sleep(0.3)
    finally:
        conn.close()


def _fly(run: Path, port: int, *extra: str) -> tuple[int, dict, str]:
    out = subprocess.run([sys.executable, "-m", "companion.cli", "-q", "fly", "--connect",
                          f"udpin://127.0.0.1:{port}", "--mission", "forest_arducopter_sitl", "--ready-timeout", "120",
                          "--no-zenoh", "--no-recording", "--no-plots", "--run-dir", str(run), *extra],
                         capture_output=True, text=True, timeout=420, cwd=ROOT)
    rep = json.loads((run / "report.json").read_text())
    print(json.dumps({k: rep.get(k) for k in ("outcome", "outcome_detail", "time_to_goal_s", "max_swing_rad",
                                              "collisions", "vehicle_statustext")}, indent=1))
    print(json.dumps({"signing": rep["link"].get("signing"), "swing_inputs": (rep.get("swing_estimator") or {}).get(
        "inputs"), "senders": _senders(run / "flight.tlog")}, indent=1))
    return out.returncode, rep, out.stderr


def _senders(tlog: Path) -> dict[str, int]:
    """Frames in the flight's .tlog by "system/component signed|unsigned" (what the link received and sent)."""
    from companion.mavlink_io.tlog import tlog_frames

    out: dict[str, int] = {}
    for _, f in tlog_frames(tlog) if tlog.exists() else ():
        if f[0] == 0xFD:
            k = f"{f[5]}/{f[6]} {'signed' if f[2] & 1 else 'unsigned'}"
            out[k] = out.get(k, 0) + 1
    return out


@pytest.fixture
def arducopter(tmp_path):
    port = free_udp_port()
    proc = sitl_external.start_arducopter(tmp_path, port, payload=True)
    yield port
    _stop(proc)


@needs_arducopter
def test_arducopter_with_arming_check_0_flies_and_talks_to_an_onboard_controller(arducopter, tmp_path):
    _prepare(arducopter, params={"ARMING_CHECK": 0.0})
    code, rep, err = _fly(tmp_path / "run", arducopter)
    assert code == 0 and rep["outcome"] == "completed", (rep["outcome"], rep.get("outcome_detail"), err[-2000:])
    assert rep["collisions"] == 0
    # ArduCopter sends its STATUSTEXT to every active channel: the onboard controller heard it ("Arming motors")
    assert any("Arming motors" in t for t in rep["vehicle_statustext"]), rep["vehicle_statustext"]


@pytest.fixture
def arducopter_payload_on_serial0(tmp_path):
    """ArduCopter SITL with its slung payload dialling SERIAL0 (TCP 5763) and the companion on SERIAL1. With signing
    on, ArduPilot accepts unsigned frames on channel 0 only (GCS_Signing.cpp ``accept_unsigned_callback``: "assumed
    to be secure channel"): on SERIAL2, where the payload dials by default, its unsigned stream is dropped by
    ArduPilot itself (measured: no frame of system 2 reached the companion), on SERIAL0 it is forwarded, unsigned."""
    port = free_udp_port()
    proc = _start_arducopter(tmp_path / "arducopter-swapped", "--serial0", "tcp:5763", "--serial1",
                             f"udpclient:127.0.0.1:{port}", "--serial2", "tcp:5765")
    yield port
    _stop(proc)


def _start_arducopter(run: Path, *serials: str) -> subprocess.Popen:
    """ArduCopter SITL with its slung payload (as lab.sitl_external starts it) on the given serial ports."""
    root = ARDUCOPTER
    assert root is not None
    run.mkdir()
    parm = run / "simulation.parm"
    parm.write_text("SIM_SLUP_ENABLE 1\nSIM_SLUP_WEIGHT 0.25\nSIM_SLUP_LINELEN 1\nSIM_SLUP_SYSID 2\nSIM_SLUP_DRAG 1\n")
    return subprocess.Popen(
        [str(root / "build/sitl/bin/arducopter"), "--model", "quad", "-I", "0", "--wipe", "--home",
         sitl_external.ARDUCOPTER_HOME, "--defaults", f"{root / 'Tools/autotest/default_params/copter.parm'},{parm}",
         "--sysid", "1", *serials], cwd=run, stdout=(run / "arducopter.log").open("w"), stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL, start_new_session=True)


def _stop(proc: subprocess.Popen) -> None:
    try:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(20)
    except (ProcessLookupError, subprocess.TimeoutExpired):
        os.killpg(proc.pid, signal.SIGKILL)


@needs_arducopter
def test_arducopter_signed_reads_its_unsigned_payload_only_when_told(arducopter_payload_on_serial0, tmp_path):
    port = arducopter_payload_on_serial0
    key = tmp_path / "key.hex"
    key.write_text(KEY.hex() + "\n")
    _prepare(port, signing_key=KEY)
    code, rep, err = _fly(tmp_path / "run", port, "--signing-key", str(key), "--accept-unsigned", "2")
    assert code == 0 and rep["outcome"] == "completed", (rep["outcome"], rep.get("outcome_detail"), err[-2000:])
    sig = rep["link"]["signing"]
    assert sig["accept_unsigned_systems"] == [2] and sig["accepted_unsigned"].get("2", 0) > 100
    assert rep["swing_estimator"]["inputs"].get("payload_fix", 0) > 50  # the payload's fixes fed the estimator
    assert not any(s.startswith("1/") for s in sig["dropped_by_sender"])  # ArduCopter's own frames all signed


@needs_arducopter
def test_arducopter_signed_without_accept_unsigned_counts_the_payload_dropped(arducopter_payload_on_serial0, tmp_path):
    """The issue's flight: signed, the payload's unsigned stream dropped; now counted by sender in the report."""
    port = arducopter_payload_on_serial0
    key = tmp_path / "key.hex"
    key.write_text(KEY.hex() + "\n")
    _prepare(port, signing_key=KEY)
    code, rep, err = _fly(tmp_path / "run", port, "--signing-key", str(key))
    assert code == 0 and rep["outcome"] == "completed", (rep["outcome"], rep.get("outcome_detail"), err[-2000:])
    sig = rep["link"]["signing"]
    assert sig["accepted_unsigned"] == {} and sig["dropped_by_sender"]["2/35"]["unsigned"] > 100
    assert rep["swing_estimator"]["inputs"].get("payload_fix", 0) == 0


@needs_arducopter
def test_arducopter_routes_a_mavproxy_gcs_to_the_companion_which_pauses_and_resumes(tmp_path):
    """The real set-up beside a ground station: ArduCopter routes between its ports. SERIAL0 to MAVProxy with a
    pymavlink GCS on its output, SERIAL1 to the companion: the GCS's commands to (1, 191) reach the companion through
    ArduPilot's routing, the companion's STATUSTEXT reaches the GCS the same way; pause mid-leg, resume, completed."""
    import numpy as np
    from _operator_helpers import MAVPROXY, Gcs
    from pymavlink.dialects.v20 import common as M

    mp_port, gcs_port, comp = free_udp_port(), free_udp_port(), free_udp_port()
    mavproxy = subprocess.Popen([sys.executable, str(MAVPROXY), "--master", f"udpin:127.0.0.1:{mp_port}", "--out",
                                 f"udpin:127.0.0.1:{gcs_port}", "--non-interactive", "--daemon", "--nowait",
                                 "--default-modules", "", "--state-basedir", str(tmp_path)],
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                cwd=tmp_path)
    sitl = _start_arducopter(tmp_path / "arducopter", "--serial0", f"udpclient:127.0.0.1:{mp_port}", "--serial1",
                             f"udpclient:127.0.0.1:{comp}")
    run = tmp_path / "run"
    fly = subprocess.Popen([sys.executable, "-m", "companion.cli", "-q", "fly", "--connect", f"udpin://127.0.0.1:{comp}",
                            "--mission", "forest_arducopter_sitl", "--ready-timeout", "120", "--gcs-sysid", "255",
                            "--no-zenoh", "--no-recording", "--no-plots", "--run-dir", str(run)],
                           cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        gcs = Gcs(gcs_port)
        assert gcs.pump(180.0, lambda: gcs.said("slungpilot mission")), gcs.texts
        assert gcs.pump(60.0, lambda: gcs.said("phase: cruise")), gcs.texts
        gcs.pump(1.5)  # mid-leg
        assert gcs.command(0, as_sysid=200) == (M.MAV_RESULT_DENIED, 200)
        assert gcs.command(0) == (M.MAV_RESULT_ACCEPTED, 255)
        gcs.pump(8.0)
        assert gcs.command(1) == (M.MAV_RESULT_ACCEPTED, 255)
        assert gcs.pump(120.0, lambda: gcs.said("slungpilot done")), gcs.texts
        err = fly.communicate(timeout=120)[1]
    finally:
        for p in (fly, mavproxy):
            p.terminate()
            try:
                p.wait(20)
            except subprocess.TimeoutExpired:
                p.kill()
        _stop(sitl)
    rep = json.loads((run / "report.json").read_text())
    assert fly.returncode == 0 and rep["outcome"] == "completed", (rep["outcome"], rep.get("outcome_detail"),
                                                                   err[-2000:])
    assert set(gcs.companion_hb) == {M.MAV_TYPE_ONBOARD_CONTROLLER}
    orders = {o["order"]: o["t_s"] for o in rep["operator"]["orders"]}
    log = np.load(run / "flight_log.npz")
    t, pos, vel = log["t_s"], log["pos_ned_m"], log["vel_ned_mps"]
    speed = np.hypot(vel[:, 0], vel[:, 1])
    held = (t > orders["pause"] + 5.0) & (t < orders["resume"])
    print(json.dumps({"speed_at_pause": float(speed[np.searchsorted(t, orders["pause"])]),
                      "held_speed_max": float(speed[held].max()), "held_drift_m": float(np.ptp(pos[held, :2], 0).max()),
                      "time_to_goal_s": rep["time_to_goal_s"], "max_swing_rad": rep["max_swing_rad"],
                      "texts": [x[2] for x in gcs.texts]}, indent=1))
    assert speed[np.searchsorted(t, orders["pause"])] > 0.5 and held.sum() > 100
    assert speed[held].max() < 0.3 and np.ptp(pos[held, :2], axis=0).max() < 0.3
    assert rep["collisions"] == 0


PX4, PX4_WHY = sitl_external.find_px4()


@pytest.mark.skipif(PX4 is None, reason=PX4_WHY)
def test_px4_says_its_statustext_to_an_onboard_controller_only_beside_a_gcs(tmp_path):
    """The measurement behind the companion's identity, on one PX4 SIH boot: its onboard link, our heartbeat as an
    onboard controller for 20 s, then as a GCS for 12 s; an arm asked every 3 s from 5 s on (refused while PX4's
    estimator settles, and PX4 says why). STATUSTEXT arrive only once a GCS is heard on that link."""
    from pymavlink.dialects.v20 import common as M

    instance = 7
    proc = sitl_external.start_px4_sih(tmp_path, instance)
    conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{14540 + instance}", source_system=1, source_component=191)
    texts: dict[str, list[str]] = {"onboard": [], "gcs": []}
    acks: dict[str, list[int]] = {"onboard": [], "gcs": []}
    try:
        assert conn.wait_heartbeat(timeout=60) is not None
        t0 = time.monotonic()
        last_hb = last_arm = 0.0
        while (now := time.monotonic()) - t0 < 32.0:
            as_type = "onboard" if now - t0 < 20.0 else "gcs"
            if now - last_hb >= 1.0:
                conn.mav.heartbeat_send(M.MAV_TYPE_ONBOARD_CONTROLLER if as_type == "onboard" else M.MAV_TYPE_GCS,
                                        M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE)
                last_hb = now
            if now - t0 > 5.0 and now - last_arm >= 3.0:
                conn.mav.command_long_send(conn.target_system, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0,
                                           0)
                last_arm = now
            m = conn.recv_match(type=["STATUSTEXT", "COMMAND_ACK"], blocking=True, timeout=0.2)
            if m is not None and m.get_type() == "STATUSTEXT":
                texts[as_type].append(m.text)
            elif m is not None and m.command == M.MAV_CMD_COMPONENT_ARM_DISARM:
                acks[as_type].append(m.result)
    finally:
        conn.close()
        _stop(proc)
    print(json.dumps({"texts": texts, "arm_answers": acks}, indent=1))
    assert acks["onboard"] and texts["onboard"] == []  # answered, said nothing
    assert texts["gcs"]  # the same link, a GCS heard on it: PX4 says its reasons
