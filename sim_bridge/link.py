"""One MAVLink 2 link over UDP (asyncio), with strict framing and counted rejections.

Each datagram is cut into frames here (UDP keeps frame boundaries, so nothing is carried over between
datagrams): bytes before a frame marker are *garbage*, a MAVLink 1 frame (0xFE) is *mavlink1*, a frame longer
than what is left is *truncated*, unknown incompatibility flags or a signed frame is *bad_flags*, then
:func:`companion.mavlink_io.codec.decode_lite` (pymavlink's ``MAVLink.decode``, precompiled) checks CRC and
length (*bad_crc*) and knows the id (*unknown_id*). Only decoded MAVLink 2 messages reach the handler.

Peer lock (as PX4's UDP link: it takes the first client and keeps it): telemetry goes to the configured remote
until someone talks; the first sender (or ``peer``, if configured) becomes the link's peer for good. Datagrams
from any other address are dropped whole and counted as *foreign_sender*; they never re-target the link.

Signing (optional, :mod:`companion.mavlink_io.signing`): every outgoing frame is signed; incoming unsigned
frames are *unsigned* (except RADIO_STATUS, ADSB_VEHICLE and COLLISION, as PX4), bad signatures
*bad_signature*, old timestamps *replay*. With signing on, a datagram from another address is accepted when
its frames verify (a peer that restarted on a new port); the first verified frame re-targets the link.

Serial (``sitl --serial DEVICE:BAUD``, :class:`SerialPort`): the onboard link on a serial device (a TELEM port, or
one end of a pseudo-terminal pair). The stream is cut into frames by the companion's
:class:`~companion.mavlink_io.framing.StreamFramer` (garbage counted as *garbage*), and the frames of each read
are handled as one datagram from :data:`SERIAL_PEER`, the link's peer from the start.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import select
import time
from collections.abc import Callable
from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

from companion.mavlink_io import signing
from companion.mavlink_io.codec import (
    CRC_SET_ATTITUDE_TARGET,
    ID_SET_ATTITUDE_TARGET,
    P_SET_ATTITUDE_TARGET,
    FrameError,
    crc_extra_of,
    crc_mcrf4xx,
    decode_lite,
    frame_msgid,
)

log = logging.getLogger(__name__)

REJECT_KINDS = (
    "garbage",
    "bad_crc",
    "truncated",
    "unknown_id",
    "mavlink1",
    "bad_flags",
    "other_target",
    "nonfinite",
    "bad_quaternion",
    "thrust_range",
    "bad_param",
    "bad_setpoint",
    "foreign_sender",
    "unsigned",
    "bad_signature",
    "replay",
)

#: message ids accepted unsigned on a signing link (PX4's list in mavlink_sign_control.cpp)
UNSIGNED_OK = frozenset({mavlink2.MAVLINK_MSG_ID_RADIO_STATUS, mavlink2.MAVLINK_MSG_ID_ADSB_VEHICLE,
                         mavlink2.MAVLINK_MSG_ID_COLLISION})

BATCH_MAX_BYTES = 1400  # stay below a typical Ethernet MTU
_V2_HEADER = 10
_V1_HEADER = 6
_SAT_SIZE = P_SET_ATTITUDE_TARGET.size  # SET_ATTITUDE_TARGET without its extension (thrust_body)
_SAT_UNPACK = P_SET_ATTITUDE_TARGET.unpack
_SAT_CRC_EXTRA = bytes((CRC_SET_ATTITUDE_TARGET,))
_PAD = [bytes(k) for k in range(_SAT_SIZE + 1)]


class RejectCounters:
    """Counts rejected input by kind; logs one warning per kind at most once per wall second."""

    def __init__(self) -> None:
        self.counts: dict[str, int] = dict.fromkeys(REJECT_KINDS, 0)
        self._last_log: dict[str, float] = {}

    def reject(self, kind: str, detail: str = "") -> None:
        """Count one rejected input of ``kind`` (one of :data:`REJECT_KINDS`)."""
        self.counts[kind] = self.counts.get(kind, 0) + 1
        now = time.monotonic()
        if now - self._last_log.get(kind, -1e9) >= 1.0:
            self._last_log[kind] = now
            log.warning("rejected input (%s, %d so far)%s", kind, self.counts[kind], f": {detail}" if detail else "")

    @property
    def total(self) -> int:
        """All rejections so far."""
        return sum(self.counts.values())


class MavUdpLink(asyncio.DatagramProtocol):
    """A UDP MAVLink 2 endpoint: ``link.mav`` sends as the vehicle; ``link.sender(sys, comp)`` as others.

    ``on_message(link, msg)`` is called for every decoded message, in arrival order.
    """

    def __init__(
        self,
        name: str,
        remote: tuple[str, int],
        sysid: int,
        compid: int,
        counters: RejectCounters,
        on_message: Callable[[MavUdpLink, mavlink2.MAVLink_message], None],
        peer: tuple[str, int] | None = None,
        link_id: int = 0,
    ) -> None:
        self.name = name
        self.remote = peer or remote
        self.locked = peer is not None
        self.link_id = link_id
        self.signer: signing.LinkSigner | None = None
        self.verifier: signing.SigningVerifier | None = None
        self.last_signed = False  # whether the message being handled arrived signed and verified
        self.counters = counters
        self.on_message = on_message
        self.transport: asyncio.DatagramTransport | None = None
        self.mav = self.sender(sysid, compid)
        self.rx_messages = 0
        self._batch: bytearray | None = None
        self.scheduler: Any = None  # the vehicle's per-link telemetry schedule (rates are per link, as PX4)
        # hot path: a datagram that is exactly one unsigned SET_ATTITUDE_TARGET from the locked peer goes here as
        # its unpacked fields (codec.P_SET_ATTITUDE_TARGET), with no message object; None: the general path
        self.on_attitude_fields: Callable[[MavUdpLink, tuple], None] | None = None
        self.tx_errors = 0

    def sender(self, sysid: int, compid: int) -> mavlink2.MAVLink:
        """A pymavlink ``MAVLink`` encoder with its own sequence numbers that writes to this link."""
        return mavlink2.MAVLink(self, srcSystem=sysid, srcComponent=compid)  # pymavlink calls self.write

    # asyncio callbacks -------------------------------------------------------------------------------
    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]

    def error_received(self, exc: Exception) -> None:
        # e.g. ICMP port unreachable when nobody listens on the remote: normal for a SITL
        self.tx_errors += 1

    def set_signing(self, verifier: signing.SigningVerifier | None) -> None:
        """Turn signing on with ``verifier``'s key (shared by the vehicle's links) or off (None)."""
        self.verifier = verifier
        self.signer = None if verifier is None else signing.LinkSigner(verifier.key, self.link_id)

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        n = len(data)
        if (n > 12 and data[7] == ID_SET_ATTITUDE_TARGET and data[0] == 0xFD and data[2] == 0 and data[8] == 0
                and data[9] == 0 and n == data[1] + 12 and n <= _SAT_SIZE + 12 and self.locked
                and self.verifier is None and addr == self.remote and self.on_attitude_fields is not None
                and crc_mcrf4xx(data[1:-2] + _SAT_CRC_EXTRA) == data[-2] | (data[-1] << 8)):
            self.rx_messages += 1
            try:
                self.on_attitude_fields(self, _SAT_UNPACK(data[10:-2] + _PAD[_SAT_SIZE + 12 - n]))
            except Exception:  # a handler bug must not kill the vehicle; say it loudly
                log.exception("error while handling SET_ATTITUDE_TARGET")
            return
        addr = (addr[0], addr[1])
        foreign = self.locked and addr != self.remote
        if foreign and self.verifier is None:
            self.counters.reject("foreign_sender", f"datagram from {addr[0]}:{addr[1]} on {self.name} "
                                 f"(locked to {self.remote[0]}:{self.remote[1]})")
            return
        msgs = self._frames(data)
        if foreign:  # signing on: only verified frames get here; they prove the peer moved
            if not msgs:
                self.counters.reject("foreign_sender", f"unverified datagram from {addr[0]}:{addr[1]}")
                return
            log.warning("%s: signed peer moved from %s:%d to %s:%d", self.name, *self.remote, *addr)
        if not self.locked or foreign:
            self.remote = addr
            self.locked = True
        for msg, signed in msgs:
            self.rx_messages += 1
            self.last_signed = signed
            try:
                self.on_message(self, msg)
            except Exception:  # a handler bug must not kill the vehicle; say it loudly
                log.exception("error while handling %s", msg.get_type())
        self.last_signed = False

    # sending ------------------------------------------------------------------------------------------
    def begin_batch(self) -> None:
        """Collect outgoing frames into few datagrams (several MAVLink frames per datagram, as PX4 does)
        until :meth:`flush`."""
        if self._batch is None:
            self._batch = bytearray()

    def flush(self) -> None:
        """Send what :meth:`begin_batch` collected and return to one datagram per frame."""
        buf, self._batch = self._batch, None
        if buf:
            self._sendto(buf)

    def send_bytes(self, buf: bytes) -> None:
        """Send one frame (or raw bytes) to the peer (silently dropped before the socket exists); signed
        when signing is on."""
        if self.signer is not None and buf and buf[0] == mavlink2.PROTOCOL_MARKER_V2:
            msgid = buf[7] | (buf[8] << 8) | (buf[9] << 16)
            buf = self.signer.sign(bytes(buf), crc_extra_of(msgid))
            self.verifier.note_sent(self.signer.timestamp)
        if self._batch is not None:
            if len(self._batch) + len(buf) > BATCH_MAX_BYTES:
                self._sendto(self._batch)
                self._batch = bytearray()
            self._batch += buf
            return
        self._sendto(buf)

    write = send_bytes  # the ``file.write`` that pymavlink's encoders (``self.mav``, senders) call

    def _sendto(self, buf: bytes | bytearray) -> None:
        if self.transport is not None:
            try:
                self.transport.sendto(buf, self.remote)  # the batch is not reused after a flush
            except OSError:
                self.tx_errors += 1

    # framing ------------------------------------------------------------------------------------------
    def _frames(self, data: bytes) -> list[tuple[mavlink2.MAVLink_message, bool]]:
        """Decoded messages of one datagram with whether each arrived signed (and verified)."""
        out: list[tuple[mavlink2.MAVLink_message, bool]] = []
        i = 0
        n = len(data)
        garbage = False
        while i < n:
            b = data[i]
            if b != mavlink2.PROTOCOL_MARKER_V2 and b != mavlink2.PROTOCOL_MARKER_V1:
                garbage = True
                i += 1
                continue
            if i + 3 > n:
                self.counters.reject("truncated", f"{n - i} bytes of header from {self.name}")
                break
            plen = data[i + 1]
            if b == mavlink2.PROTOCOL_MARKER_V1:
                total = _V1_HEADER + plen + 2
                if i + total > n:
                    self.counters.reject("truncated", f"MAVLink 1 frame cut short on {self.name}")
                    break
                self.counters.reject("mavlink1", f"MAVLink 1 frame on {self.name} (MAVLink 2 only)")
                i += total
                continue
            flags = data[i + 2]
            total = _V2_HEADER + plen + 2 + (13 if flags & mavlink2.MAVLINK_IFLAG_SIGNED else 0)
            if i + total > n:
                self.counters.reject("truncated", f"frame needs {total} bytes, {n - i} left on {self.name}")
                break
            frame = data[i : i + total]
            i += total
            signed = False
            if flags == signing.IFLAG_SIGNED and self.verifier is not None:
                kind = self.verifier.check(frame)
                if kind is not None:
                    self.counters.reject(kind, f"signed frame from system {frame[5]} on {self.name}")
                    continue
                frame = frame[: -signing.SIGNATURE_LEN]
                signed = True
            elif flags != 0:
                self.counters.reject("bad_flags", f"incompat_flags 0x{flags:02x}"
                                     + ("" if self.verifier is not None else " (signing is off)"))
                continue
            elif self.verifier is not None and frame_msgid(frame) not in UNSIGNED_OK:
                self.counters.reject("unsigned", f"unsigned frame (id {frame_msgid(frame)}) on signed {self.name}")
                continue
            try:
                msg = decode_lite(frame)
            except FrameError as exc:
                self.counters.reject(exc.kind, f"{exc} on {self.name}")
                continue
            except Exception as exc:  # struct.error, a constructor refusing a value, ...: never fatal
                self.counters.reject("bad_crc", f"{exc} on {self.name}")
                continue
            out.append((msg, signed))
        if garbage:
            self.counters.reject("garbage", f"bytes outside MAVLink frames on {self.name}")
        return out


async def open_link(
    name: str,
    bind: tuple[str, int],
    remote: tuple[str, int],
    sysid: int,
    compid: int,
    counters: RejectCounters,
    on_message: Callable[[MavUdpLink, mavlink2.MAVLink_message], None],
    peer: tuple[str, int] | None = None,
    link_id: int = 0,
) -> MavUdpLink:
    """Bind a UDP socket at ``bind`` and return the link (raises OSError if the port is taken)."""
    loop = asyncio.get_running_loop()
    _, proto = await loop.create_datagram_endpoint(
        lambda: MavUdpLink(name, remote, sysid, compid, counters, on_message, peer, link_id), local_addr=bind
    )
    return proto


SERIAL_PEER = ("serial", 0)  # the "address" of whatever is at the other end of the vehicle's serial device
_SERIAL_WRITE_WAIT_S = 0.1


class SerialPort:
    """The onboard link on a serial device (a flight controller's TELEM port; in tests one end of a pty pair):
    what :class:`MavUdpLink` needs of a transport (``sendto``, ``close``) and a ``recvfrom`` that waits up to
    ``recv_timeout_s`` (s) and returns the complete frames read (framed by
    :class:`companion.mavlink_io.framing.StreamFramer`; garbage counted as *garbage*), else raises
    BlockingIOError. A device that goes away (EIO, end of file) is logged once and no longer read."""

    def __init__(self, device: str, baud: int, counters: RejectCounters, recv_timeout_s: float = 0.0) -> None:
        import serial  # pyserial: only a serial link needs it

        from companion.mavlink_io.framing import StreamFramer

        self.device = device
        self.counters = counters
        self.recv_timeout_s = recv_timeout_s
        self._port = serial.Serial(device, baud, timeout=0, exclusive=True)  # raises SerialException (an OSError)
        self._fd = self._port.fileno()
        os.set_blocking(self._fd, False)
        self._framer = StreamFramer()
        self.dead = False

    def fileno(self) -> int:
        return self._fd

    def recvfrom(self, _bufsize: int = 0) -> tuple[bytes, tuple[str, int]]:
        """The frames that arrived (several at once as one "datagram"), from :data:`SERIAL_PEER`."""
        if self.dead:
            time.sleep(self.recv_timeout_s)
            raise BlockingIOError
        if self.recv_timeout_s > 0 and not select.select((self._fd,), (), (), self.recv_timeout_s)[0]:
            raise BlockingIOError
        try:
            data = os.read(self._fd, 65536)
        except (BlockingIOError, InterruptedError):
            raise BlockingIOError from None
        except OSError as exc:
            data = b""
            log.warning("serial %s: %s", self.device, exc.strerror or exc)
        if not data:
            self.dead = True
            log.warning("serial %s is gone: the onboard link is down (offboard loss acts as configured)", self.device)
            raise BlockingIOError
        fr = self._framer
        runs = fr.garbage_runs
        frames = fr.feed(data)
        for _ in range(fr.garbage_runs - runs):
            self.counters.reject("garbage", f"bytes outside MAVLink frames on serial {self.device}")
        if not frames:
            raise BlockingIOError
        return b"".join(frames), SERIAL_PEER

    def sendto(self, buf: bytes | bytearray, _addr: object = None) -> None:
        """Write every byte (waiting up to 0.1 s for room); raises OSError when the device is gone or full."""
        if self.dead:
            raise OSError("serial device gone")
        view = memoryview(buf)
        deadline = time.monotonic() + _SERIAL_WRITE_WAIT_S
        while view:
            try:
                view = view[os.write(self._fd, view):]
            except (BlockingIOError, InterruptedError):
                left = deadline - time.monotonic()
                if left <= 0:
                    raise OSError(f"serial {self.device}: no room for {len(view)} bytes") from None
                select.select((), (self._fd,), (), left)

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self._port.close()


def serial_link(port: SerialPort, sysid: int, compid: int, counters: RejectCounters,
                on_message: Callable[[MavUdpLink, mavlink2.MAVLink_message], None], link_id: int = 0) -> MavUdpLink:
    """The onboard link over ``port``: locked to :data:`SERIAL_PEER` from the start (one other end)."""
    link = MavUdpLink("onboard", SERIAL_PEER, sysid, compid, counters, on_message, SERIAL_PEER, link_id)
    link.transport = port  # type: ignore[assignment]  # sendto(buf, addr) is all a link asks of it
    return link


def parse_serial_spec(text: str) -> tuple[str, int]:
    """``DEVICE:BAUD`` → (device, baud bit/s); ValueError naming what is wrong."""
    device, sep, baud = text.rpartition(":")
    if not sep or not device:
        raise ValueError(f"expected DEVICE:BAUD (e.g. /dev/ttyUSB0:921600), got {text!r}")
    if not baud.isdigit() or not 50 <= int(baud) <= 12_000_000:
        raise ValueError(f"baud rate {baud!r} is not a number in 50..12000000")
    return device, int(baud)
