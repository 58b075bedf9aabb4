"""Signing beside real autopilots (issue 27): every frame a signing link drops is counted by its sender (system,
component) and kind, and ``--accept-unsigned SYSID`` lets one system's unsigned frames in (ArduCopter forwards its
slung payload, system 2, unsigned), counted too. Real UDP sockets on 127.0.0.1; the companion's own link."""

from __future__ import annotations

import socket
import time

import pytest
from pymavlink.dialects.v20 import common as M

from companion.errors import ConfigError
from companion.flight.setup import FlightSetup
from companion.mavlink_io import signing as sg
from companion.mavlink_io.link import MavlinkLink

pytestmark = pytest.mark.shares_cores  # lockstep processes, no deadline: they may share the cores (conftest.py)

KEY = bytes(range(32))
WRONG = bytes(32 * [7])


class _Sink:
    def __init__(self) -> None:
        self.frames: list[bytes] = []

    def write(self, buf) -> None:
        self.frames.append(bytes(buf))


def _frame(sysid: int, compid: int, what: str, key: bytes | None = None, link_id: int = 0) -> bytes:
    """One MAVLink 2 frame from (sysid, compid): a HEARTBEAT or a GLOBAL_POSITION_INT, signed with ``key``."""
    mav = M.MAVLink(_Sink(), srcSystem=sysid, srcComponent=compid)
    if what == "heartbeat":
        mav.heartbeat_send(2, 12, 0, 0, 3)
    else:
        mav.global_position_int_send(1000, 473977420, 85455940, 489000, 1000, 0, 0, 0, 0)
    frame = mav.file.frames[0]
    if key is None:
        return frame
    return sg.LinkSigner(key, link_id).sign(frame, M.mavlink_map[frame[7]].crc_extra)


def _through_link(frames: list[bytes], accept_unsigned: tuple[int, ...]) -> tuple[list[tuple[int, int, str]], dict]:
    """Send ``frames`` (one datagram each) to a signing MavlinkLink on a free loopback port; what it read, and its
    signing summary."""
    got: list[tuple[int, int, str]] = []
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))  # our own bound socket, so that the port is known
    port = sock.getsockname()[1]
    link = MavlinkLink(f"udpin://127.0.0.1:{port}", lambda m: got.append((m.get_srcSystem(), m.get_srcComponent(),
                                                                            m.get_type())),
                       sock=sock, signing_key=KEY, accept_unsigned=accept_unsigned)
    link.open_blocking()
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            for f in frames:
                tx.sendto(f, ("127.0.0.1", port))
            end = time.monotonic() + 2.0
            while time.monotonic() < end and link.received + sum(link.rejected.values()) < len(frames):
                link.poll(0.05)
    finally:
        link.close()
    return got, link.verifier.summary()


def _mix() -> list[bytes]:
    vehicle_hb = _frame(1, 1, "heartbeat", KEY)
    return [
        vehicle_hb,                                  # the vehicle, signed: read
        vehicle_hb,                                  # the same again: replay
        *[_frame(2, 35, "gpi") for _ in range(3)],   # the payload, unsigned
        _frame(3, 1, "heartbeat"),                   # another system, unsigned
        _frame(4, 1, "heartbeat", WRONG),            # signed with another key
    ]


def test_dropped_frames_are_counted_by_sender_and_kind():
    got, summ = _through_link(_mix(), accept_unsigned=())
    assert got == [(1, 1, "HEARTBEAT")]
    assert summ["dropped_by_sender"] == {"1/1": {"replay": 1}, "2/35": {"unsigned": 3}, "3/1": {"unsigned": 1},
                                         "4/1": {"bad_signature": 1}}
    assert summ["dropped"] == 6 and summ["accepted_unsigned"] == {} and summ["accept_unsigned_systems"] == []


def test_accept_unsigned_lets_that_system_in_and_says_how_many():
    got, summ = _through_link(_mix(), accept_unsigned=(2,))
    assert got == [(1, 1, "HEARTBEAT")] + [(2, 35, "GLOBAL_POSITION_INT")] * 3
    assert summ["accepted_unsigned"] == {"2": 3} and summ["accept_unsigned_systems"] == [2]
    assert "2/35" not in summ["dropped_by_sender"] and summ["dropped_by_sender"]["3/1"] == {"unsigned": 1}


def test_a_spoofer_cannot_grow_the_tally_without_bound():
    v = sg.SigningVerifier(KEY)
    for s in range(1, 200):
        assert v.admit(_frame(s, 1, "heartbeat")) == "unsigned"
    summ = v.summary()
    assert len(summ["dropped_by_sender"]) == sg.MAX_SENDERS + 1 and summ["dropped"] == 199
    assert summ["dropped_by_sender"]["other"] == {"unsigned": 199 - sg.MAX_SENDERS}


def test_accept_unsigned_needs_signing_and_an_obeyed_gcs_must_sign():
    with pytest.raises(ConfigError, match="only with --signing-key"):
        FlightSetup(accept_unsigned=(2,)).validate()
    with pytest.raises(ConfigError, match="must sign"):
        FlightSetup(signing_key=KEY, accept_unsigned=(2, 255), gcs_sysid=255).validate()
    with pytest.raises(ConfigError, match=r"1\.\.255"):
        FlightSetup(signing_key=KEY, accept_unsigned=(0,)).validate()
    FlightSetup(signing_key=KEY, accept_unsigned=(2,), gcs_sysid=255).validate()


class _Relay:
    """A UDP relay between a vehicle and the companion that also injects frames of its own towards the companion,
    from the same address (as ArduPilot forwards its payload's stream on the companion's link)."""

    def __init__(self, companion_port: int) -> None:
        self.vside = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.vside.bind(("127.0.0.1", 0))
        self.cside = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.cside.bind(("127.0.0.1", 0))
        self.companion = ("127.0.0.1", companion_port)
        self.vehicle: tuple[str, int] | None = None
        self.injected = 0
        self.stop = False

    def run(self, inject) -> None:
        import select

        next_inject = time.monotonic()
        while not self.stop:
            ready, _, _ = select.select((self.vside, self.cside), (), (), 0.01)
            for s in ready:
                data, addr = s.recvfrom(65536)
                if s is self.vside:
                    self.vehicle = addr
                    self.cside.sendto(data, self.companion)
                elif self.vehicle is not None:
                    self.vside.sendto(data, self.vehicle)
            if self.vehicle is not None and time.monotonic() >= next_inject:
                next_inject += 0.1
                for f in inject():
                    self.cside.sendto(f, self.companion)
                    self.injected += 1


@pytest.mark.slow
def test_signed_flight_with_an_unsigned_payload_sender(tmp_path):
    """The bundled vehicle signing (lockstep) behind a relay that adds, from the vehicle's address, an unsigned
    sender the user lets in (system 7, ``--accept-unsigned 7``), an unsigned one not let in (9) and one signing
    with another key (4): the flight completes, and the report counts each by sender."""
    import json
    import subprocess
    import sys
    import threading
    from pathlib import Path

    from lab.procs import free_udp_port

    root = Path(__file__).resolve().parents[1]
    key = tmp_path / "key.hex"
    key.write_text(KEY.hex() + "\n")
    comp = free_udp_port()
    relay = _Relay(comp)
    sim = subprocess.Popen([sys.executable, "-m", "sim_bridge", "--lockstep", "--signing-key", str(key),
                            "--onboard-port", str(free_udp_port()), "--onboard-remote",
                            f"127.0.0.1:{relay.vside.getsockname()[1]}", "--gcs-port", str(free_udp_port()),
                            "--gcs-remote", f"127.0.0.1:{free_udp_port()}"],
                           cwd=root, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    thread = threading.Thread(target=relay.run, args=(lambda: [_frame(7, 35, "gpi"), _frame(9, 1, "heartbeat"),
                                                               _frame(4, 1, "heartbeat", WRONG)],), daemon=True)
    try:
        assert sim.stdout is not None and sim.stdout.readline().startswith("SITL READY")
        thread.start()
        run = tmp_path / "run"
        out = subprocess.run([sys.executable, "-m", "companion.cli", "-q", "fly", "--connect",
                              f"udpin://127.0.0.1:{comp}", "--lockstep", "--profile", "bundled", "--signing-key",
                              str(key), "--accept-unsigned", "7", "--no-zenoh", "--no-recording", "--no-plots",
                              "--run-dir", str(run)], capture_output=True, text=True, timeout=300, cwd=root)
    finally:
        relay.stop = True
        sim.terminate()
        sim.wait(10)
        thread.join(5)
    rep = json.loads((run / "report.json").read_text())
    assert out.returncode == 0 and rep["outcome"] == "completed", (rep["outcome"], out.stderr[-2000:])
    sig = rep["link"]["signing"]
    print(json.dumps(sig, indent=1), relay.injected)
    # the relay injects the three kinds in turn for as long as the flight lasts (how many depends on the machine):
    # each counted where it belongs, as many of each, none lost
    accepted = sig["accepted_unsigned"]["7"]
    assert sig["accept_unsigned_systems"] == [7] and accepted > 20
    dropped = sig["dropped_by_sender"]
    assert set(dropped["9/1"]) == {"unsigned"} and abs(dropped["9/1"]["unsigned"] - accepted) <= 1
    assert abs(dropped["4/1"]["bad_signature"] - accepted) <= 1
    assert "1/1" not in dropped  # nothing of the vehicle's own was dropped
