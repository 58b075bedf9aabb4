"""MAVLink 2 signing (companion.mavlink_io.signing) against pymavlink's own implementation, and the bundled
vehicle's peer lock and signing over real UDP: unsigned, forged, replayed and foreign input is rejected and
counted, including a forced disarm in flight."""

from __future__ import annotations

import hashlib
import math
import os
import stat
import time

import pytest
from pymavlink.dialects.v20 import common as M

from companion.errors import ConfigError
from companion.mavlink_io import signing as sg
from sim_bridge.mavclient import MavClient, spawn_vehicle, stop_vehicle

pytestmark = pytest.mark.shares_cores  # lockstep processes, no deadline: they may share the cores (conftest.py)

KEY = bytes(range(32))
TICK = 1 | 2 | 4 | 64 | 128


class _Sink:
    def __init__(self) -> None:
        self.frames: list[bytes] = []

    def write(self, buf) -> None:
        self.frames.append(bytes(buf))


def _signed_pymavlink(key: bytes, link_id: int, ts: int) -> M.MAVLink:
    mav = M.MAVLink(_Sink(), srcSystem=7, srcComponent=42)
    mav.signing.secret_key = key
    mav.signing.link_id = link_id
    mav.signing.timestamp = ts
    mav.signing.sign_outgoing = True
    return mav


def _messages(mav: M.MAVLink) -> None:
    mav.heartbeat_send(6, 8, 0, 0, 4)
    mav.command_long_send(1, 1, 400, 0, 0, 21196, 0, 0, 0, 0, 0)
    mav.attitude_send(123, 0.1, -0.2, 3.0, 0.0, 0.0, 0.0)
    mav.set_attitude_target_send(5, 1, 1, 7, [1, 0, 0, 0], 0, 0, 0, 0.4)


def test_signed_frames_are_byte_identical_to_pymavlink():
    ts0 = sg.timestamp_from_unix(time.time())
    ref = _signed_pymavlink(KEY, 3, ts0)
    _messages(ref)
    plain = M.MAVLink(_Sink(), srcSystem=7, srcComponent=42)
    _messages(plain)
    assert len(ref.file.frames) == len(plain.file.frames) == 4
    for k, (signed, unsigned) in enumerate(zip(ref.file.frames, plain.file.frames, strict=True)):
        msgid = unsigned[7] | unsigned[8] << 8 | unsigned[9] << 16
        ours = sg.sign_frame(unsigned, KEY, 3, ts0 + k, M.mavlink_map[msgid].crc_extra)
        assert ours == signed  # pymavlink stamps with its timestamp, then adds 1
        core, link_id, ts, sig = sg.split_signed(ours)
        assert (link_id, ts) == (3, ts0 + k) and sig == sg.signature(KEY, core, 3, ts0 + k)


def test_timestamp_epoch_is_2015_in_10us_units():
    assert sg.timestamp_from_unix(1_420_070_400.0) == 0
    assert sg.timestamp_from_unix(1_420_070_401.5) == 150_000


def test_pymavlink_accepts_ours_and_we_accept_pymavlinks_and_reject_forged_replayed_old():
    ts0 = sg.timestamp_from_unix(time.time())
    signer = sg.LinkSigner(KEY, 5)
    plain = M.MAVLink(_Sink(), srcSystem=9, srcComponent=1)
    _messages(plain)
    ours = [sg.sign_frame(f, KEY, 5, ts0 + k, M.mavlink_map[f[7] | f[8] << 8].crc_extra)
            for k, f in enumerate(plain.file.frames)]
    rx = M.MAVLink(None)
    rx.signing.secret_key = KEY
    got = [m.get_type() for f in ours for m in (rx.parse_buffer(f) or [])]
    assert got == ["HEARTBEAT", "COMMAND_LONG", "ATTITUDE", "SET_ATTITUDE_TARGET"]
    # pymavlink-signed frames through our verifier
    ref = _signed_pymavlink(KEY, 2, ts0)
    _messages(ref)
    v = sg.SigningVerifier(KEY)
    assert [v.check(f) for f in ref.file.frames] == [None] * 4
    assert v.check(ref.file.frames[1]) == "replay"  # the same frame again
    forged = bytearray(ref.file.frames[2])
    forged[12] ^= 0x01  # a payload bit
    assert v.check(bytes(forged)) == "bad_signature"
    wrong_key = _signed_pymavlink(bytes(32 * [1]), 2, ts0 + 100)
    _messages(wrong_key)
    assert v.check(wrong_key.file.frames[0]) == "bad_signature"
    # a forged frame with a future timestamp does not poison the stream (pymavlink's check would)
    assert v.stream_timestamps[(7, 42, 2)] == ts0 + 3
    # a new stream more than a minute older than what we know is a replay
    old = _signed_pymavlink(KEY, 9, ts0 - sg.NEW_STREAM_MAX_AGE - 10)
    _messages(old)
    assert v.check(old.file.frames[0]) == "replay"
    assert signer.next_timestamp() < signer.next_timestamp()  # monotonic


def test_key_file_hex_or_passphrase_as_mavproxy(tmp_path):
    f = tmp_path / "k.txt"
    f.write_text(KEY.hex() + "\n")
    assert sg.load_key_file(f) == KEY
    f.write_text("correct horse battery staple\n")
    assert sg.load_key_file(f) == hashlib.sha256(b"correct horse battery staple").digest()
    f.write_text("   \n")
    with pytest.raises(ConfigError, match="empty key file"):
        sg.load_key_file(f)
    with pytest.raises(ConfigError, match="cannot read"):
        sg.load_key_file(tmp_path / "missing")
    new = tmp_path / "new.key"
    key = sg.write_new_key_file(new)
    assert sg.load_key_file(new) == key and len(key) == 32
    assert stat.S_IMODE(os.stat(new).st_mode) == 0o600
    with pytest.raises(FileExistsError):
        sg.write_new_key_file(new)


# ------------------------------------------------------------------------------------------------ real UDP
def _sign_client(c: MavClient, key: bytes, link_id: int = 0) -> None:
    c.mav.signing.secret_key = key
    c.mav.signing.link_id = link_id
    c.mav.signing.timestamp = sg.timestamp_from_unix(time.time())
    c.mav.signing.sign_outgoing = True
    c._parser.signing.secret_key = key  # and verify what the vehicle sends


def _read_param(c: MavClient, name: str) -> float:
    c.mav.param_request_read_send(1, 1, name.encode(), -1)
    return c.wait_for("PARAM_VALUE", lambda m: m.param_id == name).param_value


def _fly_to(c: MavClient, alt_m: float, steps: int) -> None:
    z = vz = 0.0
    for _ in range(steps):
        c.step(thrust=min(0.9, max(0.05, 0.4 + 0.12 * (z + alt_m) + 0.12 * vz)))
        lp = c.last["LOCAL_POSITION_NED"]
        z, vz = lp.z, lp.vz


def _armed(c: MavClient) -> bool:
    assert c.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_HEARTBEAT) == M.MAV_RESULT_ACCEPTED
    return bool(c.wait_for("HEARTBEAT").base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED)


def test_foreign_sender_cannot_disarm_or_retarget_without_signing():
    proc, port, _ = spawn_vehicle("--lockstep", "--wind", "none")
    try:
        with MavClient(port) as c, MavClient(port) as intruder:
            c.heartbeat()
            c.wait_marker(10.0)
            for _ in range(5):
                c.step(thrust=0.0)
            assert c.set_mode(6) == M.MAV_RESULT_ACCEPTED and c.arm() == M.MAV_RESULT_ACCEPTED
            _fly_to(c, 2.0, 600)
            for _ in range(20):  # forced disarm, heartbeats and a mode change from another local socket
                intruder.mav.command_long_send(1, 1, 400, 0, 0, 21196, 0, 0, 0, 0, 0)
                intruder.mav.command_long_send(1, 1, 176, 0, 1, 3, 0, 0, 0, 0, 0)
                intruder.heartbeat()
            _fly_to(c, 2.0, 50)
            assert _armed(c) and c.last["HEARTBEAT"].custom_mode == 6 << 16
            assert -c.last["LOCAL_POSITION_NED"].z > 1.5
            assert intruder.poll(0.3) == []  # no telemetry, no ACK went to the intruder
            assert _read_param(c, "RJ_FOREIGN_SENDE") == 60
    finally:
        assert stop_vehicle(proc) == 0


def test_signing_rejects_unsigned_forged_and_replayed_disarm_in_flight(tmp_path):
    keyfile = tmp_path / "sitl.key"
    sg.write_new_key_file(keyfile)
    key = sg.load_key_file(keyfile)
    proc, port, _ = spawn_vehicle("--lockstep", "--wind", "none", "--signing-key", str(keyfile))
    try:
        with MavClient(port) as c:
            _sign_client(c, key)
            c.heartbeat()
            c.wait_marker(10.0)
            assert c.last["SYSTEM_TIME"].get_msgbuf()[2] & sg.IFLAG_SIGNED  # the vehicle signs what it sends
            # a signed disarm on the ground, captured for a replay later
            raw: list[bytes] = []
            orig_write = c.mav.file.write
            c.mav.file.write = lambda buf: (raw.append(bytes(buf)), orig_write(buf))
            assert c.arm(False, force=True) == M.MAV_RESULT_ACCEPTED
            c.mav.file.write = orig_write
            disarm_frame = raw[0]
            for _ in range(5):
                c.step(thrust=0.0)
            assert c.set_mode(6) == M.MAV_RESULT_ACCEPTED and c.arm() == M.MAV_RESULT_ACCEPTED
            _fly_to(c, 2.0, 600)
            plain = M.MAVLink(None, 255, 190)  # same socket, same ids, unsigned
            forger = M.MAVLink(None, 255, 190)
            forger.signing.secret_key = bytes(32)
            forger.signing.link_id = 0
            forger.signing.timestamp = sg.timestamp_from_unix(time.time()) + 10**6
            forger.signing.sign_outgoing = True
            for _ in range(10):
                c.sock.sendto(plain.command_long_encode(1, 1, 400, 0, 0, 21196, 0, 0, 0, 0, 0).pack(plain),
                              c.vehicle_addr)
                c.sock.sendto(forger.command_long_encode(1, 1, 400, 0, 0, 21196, 0, 0, 0, 0, 0).pack(forger),
                              c.vehicle_addr)
                c.sock.sendto(disarm_frame, c.vehicle_addr)
            _fly_to(c, 2.0, 50)
            assert _armed(c)
            counts = {k: _read_param(c, f"RJ_{k}") for k in ("UNSIGNED", "BAD_SIGNATURE", "REPLAY")}
            assert counts == {"UNSIGNED": 10, "BAD_SIGNATURE": 10, "REPLAY": 10}
            # a signed forced disarm from the locked peer is honoured (it falls: that is what it asked for)
            assert c.arm(False, force=True) == M.MAV_RESULT_ACCEPTED
    finally:
        assert stop_vehicle(proc) == 0


def test_setup_signing_turns_signing_on_and_off():
    proc, port, _ = spawn_vehicle("--lockstep", "--wind", "none")
    try:
        with MavClient(port) as c:
            c.heartbeat()
            c.wait_marker(10.0)
            ts = sg.timestamp_from_unix(time.time())
            c.mav.setup_signing_send(1, 1, list(KEY), ts)
            time.sleep(0.3)
            # unsigned requests are now refused; signed ones answered
            c.mav.param_request_read_send(1, 1, b"RJ_UNSIGNED", -1)
            with pytest.raises(TimeoutError):
                c.wait_for("PARAM_VALUE", timeout_s=0.5)
            _sign_client(c, KEY)
            assert _read_param(c, "RJ_UNSIGNED") >= 1
            c.mav.setup_signing_send(1, 1, [0] * 32, 0)  # all-zero key, timestamp 0: off
            time.sleep(0.3)
            c.mav.signing.sign_outgoing = False
            c._parser.signing.secret_key = None  # the vehicle sends unsigned again
            assert _read_param(c, "RJ_UNSIGNED") >= 1
            assert math.isfinite(_read_param(c, "MPC_THR_HOVER"))
    finally:
        assert stop_vehicle(proc) == 0


def test_configured_peer_is_locked_from_the_start():
    """--onboard-peer: the vehicle talks only to that address, even if someone else talks first."""
    with MavClient(0) as owner:
        peer_port = owner.sock.getsockname()[1]
        proc, port, _ = spawn_vehicle("--lockstep", "--wind", "none", "--onboard-peer", f"127.0.0.1:{peer_port}")
        try:
            owner.vehicle_addr = ("127.0.0.1", port)
            with MavClient(port) as first:
                first.heartbeat()
                first.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)  # arm: dropped
                assert owner.wait_marker(5.0) == 0  # the markers went to the configured peer all along
                assert [m for m in first.poll(0.3) if m.get_type() != "BAD_DATA"] == []
                assert not _armed(owner)
                assert _read_param(owner, "RJ_FOREIGN_SENDE") >= 2
        finally:
            assert stop_vehicle(proc) == 0
