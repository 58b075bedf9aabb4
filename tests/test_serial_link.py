"""Serial links (issue 27), piece by piece: URLs, stream framing, the companion's link on real pseudo-terminal pairs
(socat when it is on PATH, else lab/pty_pair.py's relay; the link tests run on both), signing, a vanished device.
Whole flights over serial: tests/test_serial_flight.py.

Real parts only: real ptys, real processes, real kill signals. A pty's baud rate is nominal (no 921600 bit/s limit).
"""

from __future__ import annotations

import asyncio
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as M

from companion.errors import ConfigError, LinkError
from companion.mavlink_io.framing import StreamFramer
from companion.mavlink_io.link import MavlinkLink
from companion.mavlink_io.transport import LinkUrl
from lab.pty_pair import PtyPair

pytestmark = pytest.mark.paired  # wall clock, light: may run beside one other such test (tests/conftest.py)

ROOT = Path(__file__).resolve().parents[1]
TOOLS = ["socat", "relay"] if shutil.which("socat") else ["relay"]


class _Frames:
    def __init__(self) -> None:
        self.frames: list[bytes] = []

    def write(self, b: bytes) -> None:
        self.frames.append(bytes(b))


def _vehicle_frames(n: int, sysid: int = 1) -> list[bytes]:
    """``n`` rounds of what an autopilot sends: HEARTBEAT, ATTITUDE, a STATUSTEXT (three frame sizes)."""
    sink = _Frames()
    mav = M.MAVLink(sink, srcSystem=sysid, srcComponent=1)
    for k in range(n):
        mav.heartbeat_send(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4, 0, 0, M.MAV_STATE_STANDBY)
        mav.attitude_send(k, 0.1, -0.2, 0.3, 0.0, 0.0, 0.0)
        mav.statustext_send(M.MAV_SEVERITY_INFO, b"round %d" % k)
    return sink.frames


# ------------------------------------------------------------------------------------------------ URLs
@pytest.mark.parametrize(("url", "match"), [
    ("serial:///dev/ttyACM0:fast", "'fast' is not a number"),
    ("serial:///dev/ttyACM0", "baud rate is not optional"),
    ("serial://:921600", "no serial device"),
    ("serial:///dev/ttyACM0:10", "outside 50"),
    ("ftp://host:1", "unknown link 'ftp://'"),
    ("/dev/ttyACM0", "unknown link"),
    ("tcp://host", "tcp://HOST:PORT"),
])
def test_bad_urls_are_refused_with_what_is_wrong(url, match):
    with pytest.raises(ConfigError, match=match):
        LinkUrl.parse(url)


def test_url_forms():
    assert LinkUrl.parse("serial:///dev/ttyACM0:921600") == LinkUrl("serial", device="/dev/ttyACM0", baud=921600)
    assert LinkUrl.parse("serial://COM3:57600").device == "COM3"
    assert LinkUrl.parse("tcp://127.0.0.1:5760") == LinkUrl("tcp", "127.0.0.1", 5760)
    assert LinkUrl.parse("tcpin://0.0.0.0:5760").mode == "tcpin"
    assert LinkUrl.parse("udp://0.0.0.0:14540").mode == "udpin"
    assert LinkUrl.parse("serial:///dev/x:9600").stream and not LinkUrl.parse("udpout://h:1").stream


def test_fly_refuses_a_bad_serial_url_in_one_line(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "companion.cli", "fly", "--connect", "serial:///dev/ttyACM0:abc",
                           "--no-zenoh", "--run-dir", str(tmp_path / "run")],
                          capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert proc.returncode == 2 and "'abc' is not a number" in proc.stderr and "Traceback" not in proc.stderr


def test_a_missing_device_is_a_link_error_naming_it(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "companion.cli", "fly", "--connect",
                           f"serial://{tmp_path}/nothing:921600", "--no-zenoh", "--run-dir", str(tmp_path / "run")],
                          capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert proc.returncode == 3, proc.stderr
    assert f"cannot open serial://{tmp_path}/nothing:921600" in proc.stderr and "Traceback" not in proc.stderr


def test_fly_serial_is_for_the_bundled_vehicle_only(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "companion.cli", "fly", "--serial", "--no-zenoh", "--run-dir",
                           str(tmp_path / "run")], capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert proc.returncode == 2 and "--serial: only with --sitl" in proc.stderr and "Traceback" not in proc.stderr


def test_sitl_refuses_a_bad_serial_spec():
    proc = subprocess.run([sys.executable, "-m", "sim_bridge", "--serial", "/dev/ttyUSB0"],
                          capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert proc.returncode == 2 and "--serial: expected DEVICE:BAUD" in proc.stderr


# ------------------------------------------------------------------------------------------------ framing
def test_frames_cut_anywhere_with_garbage_between_all_come_out_in_order():
    frames = _vehicle_frames(100)
    rng = random.Random(5)
    stream = bytearray()
    injected = 0
    for f in frames:
        if rng.random() < 0.2:  # line noise, with false start markers in it
            junk = bytes(rng.choice((0xFD, 0xFE, rng.randrange(256))) for _ in range(rng.randint(1, 30)))
            stream += junk
            injected += len(junk)
        stream += f
    framer = StreamFramer()
    out: list[bytes] = []
    i = 0
    while i < len(stream):
        k = rng.randint(1, 64)
        out += framer.feed(bytes(stream[i : i + k]))
        i += k
    assert out == frames
    assert framer.garbage_bytes == injected and framer.garbage_runs > 0 and framer.held == 0


def test_ardupilot_dialect_frames_are_frames_not_garbage():
    """ArduPilot's own messages (not in the common dialect) are framed, as UDP delivers them, not counted as noise."""
    from pymavlink.dialects.v20 import ardupilotmega as APM

    sink = _Frames()
    apm = APM.MAVLink(sink, srcSystem=1, srcComponent=1)
    apm.ahrs2_send(0.1, 0.2, 0.3, 10.0, 1, 2)
    apm.attitude_send(1, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0)
    framer = StreamFramer()
    assert framer.feed(b"".join(sink.frames)) == sink.frames and framer.garbage_bytes == 0


def test_a_partial_frame_waits_and_an_unknown_id_is_garbage():
    (f,) = _vehicle_frames(1)[:1]
    framer = StreamFramer()
    assert framer.feed(f[:7]) == [] and framer.held == 7 and framer.garbage_bytes == 0
    assert framer.feed(f[7:]) == [f]
    bogus = bytearray(f)
    bogus[7:10] = b"\xff\xff\x00"  # message id 65535: not in the dialect, cannot be told from noise
    assert framer.feed(bytes(bogus) + f) == [f] and framer.garbage_bytes == len(bogus)


# ------------------------------------------------------------------------------------------------ the link on a pty
def _open_raw(path: Path) -> int:
    import tty

    fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
    tty.setraw(fd)
    return fd


@pytest.mark.parametrize("tool", TOOLS)
def test_companion_link_reads_a_pty_with_garbage_and_writes_back(tmp_path, tool):
    """Frames written in odd pieces with garbage between arrive whole and in order; garbage is counted; what the
    companion sends reaches the other end; after the lock the link is connected."""
    frames = _vehicle_frames(30)
    got: list = []
    with PtyPair(tmp_path / "fc", tmp_path / "cc", use_socat=tool == "socat"):
        link = MavlinkLink(f"serial://{tmp_path}/cc:921600", got.append)
        link.open_blocking()
        fc = _open_raw(tmp_path / "fc")
        try:
            assert link.connected  # a stream has its other end from the start
            blob = b"\x00garbage\x01" + b"".join(frames[:40]) + b"\x55" * 7 + b"".join(frames[40:])
            for i in range(0, len(blob), 37):
                os.write(fc, blob[i : i + 37])
            end = time.monotonic() + 5
            while len(got) < len(frames) and time.monotonic() < end:
                link.poll(0.05)
            assert [m.get_type() for m in got] == [M.MAVLink(None).decode(bytearray(f)).get_type() for f in frames]
            assert link.rejected["garbage"] == 2 and link.rejected["garbage_bytes"] == 9 + 7
            link.lock_to_last_sender()
            assert link.locked == (str(tmp_path / "cc"), 1)
            link.mav.heartbeat_send(M.MAV_TYPE_ONBOARD_CONTROLLER, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            time.sleep(0.2)
            back = StreamFramer().feed(os.read(fc, 4096))
            assert len(back) == 1 and back[0][7] == M.MAVLINK_MSG_ID_HEARTBEAT and link.sent == 1
        finally:
            os.close(fc)
            link.close()


@pytest.mark.parametrize("tool", TOOLS)
def test_a_vanished_device_is_link_closed_then_reopened_when_it_is_back(tmp_path, tool):
    """Kill the pair (SIGKILL: the device vanishes): counted once, not connected, nothing sent, no exception, no
    busy loop; a new pair at the same path: the link reopens it by itself."""
    got: list = []
    pair = PtyPair(tmp_path / "fc", tmp_path / "cc", use_socat=tool == "socat").start()
    link = MavlinkLink(f"serial://{tmp_path}/cc:921600", got.append)
    link.open_blocking()
    try:
        pair.stop(signal.SIGKILL)
        polls, t0 = 0, time.monotonic()
        while time.monotonic() - t0 < 0.5:
            link.poll(0.05)
            polls += 1
        assert link.rejected["link_closed"] == 1 and not link.connected
        assert polls <= 12  # waited, not spun
        link.mav.heartbeat_send(M.MAV_TYPE_ONBOARD_CONTROLLER, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        assert link.sent == 0
        for p in (tmp_path / "fc", tmp_path / "cc"):
            p.unlink(missing_ok=True)
        pair = PtyPair(tmp_path / "fc", tmp_path / "cc", use_socat=tool == "socat").start()
        end = time.monotonic() + 5
        while not link.connected and time.monotonic() < end:
            link.poll(0.05)
        assert link.connected and link.rejected["link_closed"] == 1
        fc = _open_raw(tmp_path / "fc")
        os.write(fc, b"".join(_vehicle_frames(1)))
        end = time.monotonic() + 5
        while len(got) < 3 and time.monotonic() < end:
            link.poll(0.05)
        os.close(fc)
        assert len(got) == 3
    finally:
        link.close()
        pair.stop()


async def _until(cond, timeout_s: float = 5.0) -> None:
    end = time.monotonic() + timeout_s
    while not cond() and time.monotonic() < end:
        await asyncio.sleep(0.01)


def test_the_asyncio_reader_sees_frames_a_dead_device_and_its_return(tmp_path):
    """The real-time runner's path: ``loop.add_reader`` on the device; the device killed is counted, not raised;
    a new device at the path is reopened by the loop's own timer and read."""
    got: list = []
    seen: dict = {}

    async def main() -> MavlinkLink:
        nonlocal pair
        link = MavlinkLink(f"serial://{tmp_path}/cc:921600", got.append)
        async with link:
            fc = _open_raw(tmp_path / "fc")
            os.write(fc, b"".join(_vehicle_frames(5)))
            await _until(lambda: len(got) == 15)
            os.close(fc)
            pair.stop(signal.SIGKILL)
            await _until(lambda: link.rejected["link_closed"] == 1)
            await asyncio.sleep(0.2)
            seen["down"] = (len(got), link.rejected["link_closed"], link.connected)
            for p in (tmp_path / "fc", tmp_path / "cc"):
                p.unlink(missing_ok=True)
            pair = PtyPair(tmp_path / "fc", tmp_path / "cc").start()
            await _until(lambda: link.connected)
            fc = _open_raw(tmp_path / "fc")
            os.write(fc, b"".join(_vehicle_frames(1)))
            await _until(lambda: len(got) == 18)
            os.close(fc)
        return link

    pair = PtyPair(tmp_path / "fc", tmp_path / "cc").start()
    try:
        link = asyncio.run(main())
    finally:
        pair.stop()
    assert seen["down"] == (15, 1, False)
    assert len(got) == 18 and link.rejected["link_closed"] == 1


def test_signing_on_a_serial_link(tmp_path):
    """Signed frames in odd pieces are read; unsigned ones from the same wire are dropped and counted; what the
    companion writes is signed."""
    from companion.mavlink_io import signing as sg

    key = bytes(range(32))
    signer = M.MAVLink(_Frames(), srcSystem=1, srcComponent=1)
    signer.signing.secret_key = key
    signer.signing.link_id = 0
    signer.signing.timestamp = sg.timestamp_from_unix(time.time())
    signer.signing.sign_outgoing = True
    for k in range(10):
        signer.attitude_send(k, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0)
    signed = signer.file.frames
    unsigned = _vehicle_frames(1)[1]  # an ATTITUDE, unsigned
    got: list = []
    with PtyPair(tmp_path / "fc", tmp_path / "cc"):
        link = MavlinkLink(f"serial://{tmp_path}/cc:921600", got.append, signing_key=key)
        link.open_blocking()
        fc = _open_raw(tmp_path / "fc")
        try:
            blob = b"".join(signed[:5]) + unsigned + b"".join(signed[5:])
            for i in range(0, len(blob), 29):
                os.write(fc, blob[i : i + 29])
            end = time.monotonic() + 5
            while len(got) < 10 and time.monotonic() < end:
                link.poll(0.05)
            assert [m.time_boot_ms for m in got] == list(range(10)) and link.rejected["unsigned"] == 1
            link.mav.heartbeat_send(M.MAV_TYPE_ONBOARD_CONTROLLER, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            time.sleep(0.2)
            (back,) = StreamFramer().feed(os.read(fc, 4096))
            assert back[2] & sg.IFLAG_SIGNED and sg.SigningVerifier(key).check(back) is None
        finally:
            os.close(fc)
            link.close()


def test_a_device_in_use_is_refused(tmp_path):
    with PtyPair(tmp_path / "fc", tmp_path / "cc"):
        first = MavlinkLink(f"serial://{tmp_path}/cc:921600", print)
        first.open_blocking()
        try:
            with pytest.raises(LinkError, match="cannot open serial://"):
                MavlinkLink(f"serial://{tmp_path}/cc:921600", print).open_blocking()
        finally:
            first.close()
