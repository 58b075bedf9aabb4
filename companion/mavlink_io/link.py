"""MAVLink 2 over UDP for the companion: a thin asyncio shell around pymavlink's generated codec.

Connection URLs as MAVSDK and mavutil users know them:

* ``udpin://0.0.0.0:14540`` — bind that port and talk to the vehicle that sends to it (the default; PX4's
  SITL sends its onboard link to 127.0.0.1:14540);
* ``udpout://127.0.0.1:14580`` — send to that address from an ephemeral local port.

Lock-on (as MAVSDK and MAVProxy do): once the app has found the vehicle (its first autopilot HEARTBEAT) it
calls :meth:`MavlinkLink.lock_to_last_sender`; from then on only datagrams from that address are read, and
setpoints go only there. Datagrams from any other address are counted (``foreign_sender``) and dropped
before decoding: they can neither steer the companion nor re-target its setpoints. Before the lock, a udpin
link reads everyone but sends nothing.

Every datagram in and out is also written to a ``.tlog`` (8-byte big-endian microsecond UNIX time stamp +
raw frame, the format ground stations write and ``mavlogdump.py`` reads). Undecodable input is counted and
logged at most once a second per kind; it never raises into the flight loop.

Hot path: a datagram made only of complete, unsigned, CRC-valid MAVLink 2 frames (what a vehicle sends) is
decoded by :func:`companion.mavlink_io.codec.decode_lite`; anything else goes through pymavlink's own parser.
``on_datagram_done`` (optional) is called after the messages of each datagram were handled.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import select
import socket
import struct
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import urlparse

from pymavlink.dialects.v20 import common as mavlink2

from companion.disk_writer import DiskWriter
from companion.errors import ConfigError, LinkError
from companion.mavlink_io import signing
from companion.mavlink_io.codec import STX_V2 as _STX_V2
from companion.mavlink_io.codec import FrameError, check_crc, crc_extra_of, decode_lite

log = logging.getLogger(__name__)

MAV_COMP_ID_ONBOARD_COMPUTER = 191
_MIN_FRAME = 12  # MAVLink 2 header + CRC


@dataclass(frozen=True)
class LinkUrl:
    """A parsed connection URL: ``mode`` is "udpin" (bind and answer) or "udpout" (send to)."""

    mode: str
    host: str
    port: int

    @classmethod
    def parse(cls, url: str) -> LinkUrl:
        """Parse ``udpin://host:port`` / ``udpout://host:port``; raise :class:`ConfigError` otherwise."""
        u = urlparse(url)
        if u.scheme not in ("udpin", "udpout", "udp"):
            raise ConfigError(f"--connect {url!r}: scheme must be udpin:// or udpout://")
        try:
            port = u.port
        except ValueError:
            port = None
        if not u.hostname or port is None or not 0 < port < 65536:
            raise ConfigError(f"--connect {url!r}: expected udpin://HOST:PORT or udpout://HOST:PORT")
        mode = "udpin" if u.scheme in ("udpin", "udp") else "udpout"
        return cls(mode, u.hostname, port)


_TLOG_STAMP = struct.Struct(">Q")


class TlogWriter:
    """Append-only .tlog: each record is a big-endian uint64 UNIX time in µs followed by the frame bytes.

    Records collect in memory and go to a :class:`~companion.disk_writer.DiskWriter` thread every
    ``HANDOVER_S`` or ``HANDOVER_BYTES``, whichever comes first: the event loop never waits for the disk.
    """

    HANDOVER_S = 0.25
    HANDOVER_BYTES = 64 * 1024

    def __init__(self, path: Path) -> None:
        self.path = path
        self._writer = DiskWriter("tlog")
        self._writer.create(path)
        self._buf = bytearray()
        self._handed_at = time.monotonic()
        self._closed = False

    def write(self, frame: bytes) -> None:
        if self._closed:
            return
        self._buf += _TLOG_STAMP.pack(int(time.time() * 1e6))
        self._buf += frame
        mono = time.monotonic()
        if len(self._buf) >= self.HANDOVER_BYTES or mono - self._handed_at >= self.HANDOVER_S:
            self._hand_over(mono)

    def _hand_over(self, mono: float) -> None:
        if self._buf:
            self._writer.append(self.path, bytes(self._buf))
            self._buf.clear()
        self._handed_at = mono

    def close(self) -> None:
        if not self._closed:
            self._hand_over(time.monotonic())
            self._closed = True
            self._writer.close()


_STX_V1 = 0xFE


def tlog_frames(path: Path) -> list[tuple[float, bytes]]:
    """(UNIX time s, one MAVLink frame) for every frame of a .tlog (records: 8-byte big-endian µs + bytes;
    :class:`TlogWriter` writes one frame a record, other tools may write several). A torn or unknown tail ends
    the record; a torn last record is dropped."""
    data = path.read_bytes()
    out: list[tuple[float, bytes]] = []
    i = 0
    while i + _TLOG_STAMP.size <= len(data):
        (t_us,) = _TLOG_STAMP.unpack_from(data, i)
        i += _TLOG_STAMP.size
        while i < len(data):  # the record runs until the next frame start we can size; frames are self-delimiting
            stx = data[i]
            if stx == _STX_V2 and i + 3 <= len(data):
                n = _MIN_FRAME + data[i + 1] + (signing.SIGNATURE_LEN if data[i + 2] & signing.IFLAG_SIGNED else 0)
            elif stx == _STX_V1 and i + 2 <= len(data):
                n = 8 + data[i + 1]
            else:
                break
            if i + n > len(data):
                return out
            out.append((t_us * 1e-6, data[i : i + n]))
            i += n
            if i + _TLOG_STAMP.size <= len(data) and data[i] not in (_STX_V1, _STX_V2):
                break  # the next record's time stamp
        else:
            break
    return out


def tlog_messages(path: Path) -> Iterator[tuple[float, Any]]:
    """(UNIX time s, decoded message) for every frame of a .tlog the codec decodes (signed ones read without
    their signature, which is not checked here); others are skipped."""
    for t_s, frame in tlog_frames(path):
        if frame[0] == _STX_V2 and frame[2] & signing.IFLAG_SIGNED:
            frame = frame[: -signing.SIGNATURE_LEN]
        try:
            yield t_s, decode_lite(frame)
        except FrameError:
            continue


RCVBUF_BYTES = 4 << 20  # asked of the kernel (it grants up to net.core.rmem_max)
DRAIN_MAX = 512  # datagrams read per wake-up at most, so a flood cannot starve the event loop either


class MavlinkLink:
    """One MAVLink 2 UDP endpoint. Decoded messages go to ``handler(msg)``; sending via ``self.mav``.

    ``self.mav`` is pymavlink's generated ``MAVLink`` object; use ``link.mav.<msg>_send(...)`` so that
    sequence numbers are kept.
    """

    def __init__(
        self,
        url: str,
        handler: Callable[[Any], None],
        *,
        src_system: int = 1,
        src_component: int = MAV_COMP_ID_ONBOARD_COMPUTER,
        tlog: Path | None = None,
        sock: socket.socket | None = None,
        signing_key: bytes | None = None,
    ) -> None:
        self.url = LinkUrl.parse(url)
        # MAVLink 2 signing (companion.mavlink_io.signing): every frame out signed, every frame in checked
        self.verifier = None if signing_key is None else signing.SigningVerifier(signing_key)
        self.signer = None if signing_key is None else signing.LinkSigner(signing_key, link_id=0)
        self._sock = sock  # an already bound socket to use instead of binding the URL's port (udpin)
        self.handler = handler
        self.mav = mavlink2.MAVLink(self, srcSystem=src_system, srcComponent=src_component)
        self.mav.robust_parsing = True
        self.rejected: Counter[str] = Counter()
        self.received = 0
        self.sent = 0
        self._last_log: dict[str, float] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._open = False
        self._remote: tuple[str, int] | None = None if self.url.mode == "udpin" else (self.url.host, self.url.port)
        self._locked: tuple[str, int] | None = None
        self.last_sender: tuple[str, int] | None = None  # address of the datagram being handled
        self.last_rx_wall = 0.0  # monotonic time of the last datagram accepted from the vehicle's address
        self._tlog = TlogWriter(tlog) if tlog else None
        self.on_datagram_done: Callable[[], None] | None = None  # called after each datagram's messages
        #: set: the unsigned frames of the fast path (CRC checked) go here as bytes instead of to ``handler``
        self.frame_handler: Callable[[bytes], None] | None = None

    def _bind(self) -> socket.socket:
        """The link's socket: bound to the URL's port (udpin), an ephemeral local one (udpout), or the one given;
        non-blocking, with a large receive buffer."""
        sock = self._sock
        try:
            if sock is None:
                sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                if self.url.mode == "udpin":
                    sock.bind((self.url.host, self.url.port))
                else:
                    sock.bind(("127.0.0.1" if self.url.host.startswith("127.") else "0.0.0.0", 0))
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RCVBUF_BYTES)
            sock.setblocking(False)
        except OSError as exc:
            if sock is not None and sock is not self._sock:
                sock.close()
            raise LinkError(f"cannot open {self.url.mode}://{self.url.host}:{self.url.port}: {exc}") from None
        self._sock = sock
        self._open = True
        return sock

    async def open(self) -> None:
        """Bind the socket (udpin) or create the sending socket (udpout), and read it on the running loop.

        The socket is read with ``loop.add_reader``, draining up to :data:`DRAIN_MAX` datagrams per wake-up:
        asyncio's datagram transport reads one datagram per loop iteration, and under a flood into our port the
        kernel buffer then overflows and drops the vehicle's own datagrams along with the attacker's.
        """
        sock = self._bind()
        self._loop = asyncio.get_running_loop()
        self._loop.add_reader(sock.fileno(), self._drain)

    def open_blocking(self) -> None:
        """Bind the socket for a caller without an event loop, which reads it with :meth:`poll`."""
        self._bind()

    def poll(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` (s) for datagrams and handle what the socket holds; False if none came."""
        sock = self._sock
        if sock is None:
            return False
        ready, _, _ = select.select((sock,), (), (), timeout_s)
        if not ready:
            return False
        self._drain()
        return True

    def close(self) -> None:
        """Close the socket and the tlog."""
        if self._sock is not None and self._open:
            if self._loop is not None:
                with contextlib.suppress(Exception):
                    self._loop.remove_reader(self._sock.fileno())
            self._sock.close()
            self._loop = None
            self._open = False
        if self._tlog is not None:
            self._tlog.close()

    def _drain(self) -> None:
        """Read what the socket holds (at most :data:`DRAIN_MAX` datagrams) and handle each."""
        sock = self._sock
        for _ in range(DRAIN_MAX):
            try:
                data, addr = sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:  # e.g. ICMP port unreachable on loopback
                self._count("socket_error", str(exc))
                return
            self._on_datagram(data, addr)

    async def __aenter__(self) -> MavlinkLink:
        await self.open()
        return self

    async def __aexit__(self, *exc: object) -> None:
        self.close()

    def lock_to_last_sender(self) -> None:
        """Accept datagrams only from the sender of the datagram being handled (the vehicle), and send there
        (udpin; a udpout link keeps sending to its URL)."""
        if self.last_sender is None:
            return
        self._locked = self.last_sender
        if self.url.mode == "udpin":
            self._remote = self.last_sender
        log.info("locked onto the vehicle at %s:%d", *self._locked)

    @property
    def locked(self) -> tuple[str, int] | None:
        """The vehicle's address once locked on."""
        return self._locked

    @property
    def connected(self) -> bool:
        """True once we know where to send (udpout always; udpin once locked onto the vehicle)."""
        return self._remote is not None

    # pymavlink calls this to send a packed frame
    def write(self, frame: bytes) -> None:
        """File-like hook for pymavlink: send one frame to the remote (dropped before we know it); signed when
        signing is on."""
        if not self._open or self._remote is None:
            return
        frame = bytes(frame)
        if self.signer is not None and frame[:1] == b"\xfd":
            frame = self.signer.sign(frame, crc_extra_of(frame[7] | (frame[8] << 8) | (frame[9] << 16)))
            self.verifier.note_sent(self.signer.timestamp)
        try:
            self._sock.sendto(frame, self._remote)
        except (BlockingIOError, InterruptedError):
            self._count("send_dropped", "socket buffer full")
            return
        except OSError as exc:  # e.g. ICMP port unreachable from an earlier datagram
            self._count("socket_error", str(exc))
            return
        self.sent += 1
        if self._tlog is not None:
            self._tlog.write(frame)

    def _count(self, kind: str, detail: str = "") -> None:
        self.rejected[kind] += 1
        now = time.monotonic()
        if now - self._last_log.get(kind, -1e9) >= 1.0:
            self._last_log[kind] = now
            log.warning("MAVLink input rejected (%s, %d so far) %s", kind, self.rejected[kind], detail)

    def _on_datagram(self, data: bytes, addr: tuple[str, int]) -> None:
        if self._locked is not None and addr != self._locked:
            self._count("foreign_sender", f"from {addr[0]}:{addr[1]}")
            return
        self.last_sender = addr
        self.last_rx_wall = time.monotonic()
        msgs = self._split_signed(data) if self.verifier is not None else self._split_fast(data)
        if msgs is None:  # anything unusual: pymavlink's own parser, exactly as it always did
            self._on_datagram_pymavlink(data, addr)
            return
        for frame, msg in msgs:
            self.received += 1
            if self._tlog is not None:  # one record per frame, even when a datagram carries several
                self._tlog.write(frame)
            try:
                if msg is None:
                    self.frame_handler(frame)
                else:
                    self.handler(msg)
            except Exception:  # a bug in a handler must not kill the socket; log it loudly
                log.exception("handler failed on message %d", frame[7] | (frame[8] << 8) | (frame[9] << 16))
        if self.on_datagram_done is not None:
            self.on_datagram_done()

    def _split_fast(self, data: bytes) -> list[tuple[bytes, Any]] | None:
        """Decode a datagram made only of complete, unsigned MAVLink 2 frames of known, CRC-valid messages
        (what a vehicle sends); None for anything else (garbage, MAVLink 1, signed, cut short, unknown id,
        bad CRC, or bytes left in pymavlink's parser from an earlier datagram)."""
        n = len(data)
        if n == 0 or self.mav.buf_len() > 0:
            return None
        out = []
        i = 0
        while i < n:
            if data[i] != _STX_V2 or i + _MIN_FRAME > n or data[i + 2] != 0:
                return None
            end = i + _MIN_FRAME + data[i + 1]
            if end > n:
                return None
            frame = data[i:end]
            if self.frame_handler is not None:  # the caller decodes the checked frame itself: no message object
                if not check_crc(frame, frame[7] | (frame[8] << 8) | (frame[9] << 16)):
                    return None
                out.append((frame, None))
                i = end
                continue
            try:
                msg = decode_lite(frame)
            except Exception:  # FrameError, or a value pymavlink's constructor refuses
                return None
            out.append((frame, msg))
            i = end
        return out

    def _split_signed(self, data: bytes) -> list[tuple[bytes, Any]]:
        """With signing on: (frame as received, message) for the datagram's frames whose signature and timestamp
        check out; unsigned, forged and replayed frames and anything unframed are counted and dropped."""
        out = []
        i, n = 0, len(data)
        while i < n:
            if data[i] != _STX_V2 or i + _MIN_FRAME > n:
                self._count("unsigned" if data[i] == 0xFE else "garbage")
                return out
            flags = data[i + 2]
            total = _MIN_FRAME + data[i + 1] + (signing.SIGNATURE_LEN if flags & signing.IFLAG_SIGNED else 0)
            frame = data[i : i + total]
            i += total
            if len(frame) < total:
                self._count("truncated")
                return out
            if flags != signing.IFLAG_SIGNED:
                self._count("unsigned" if flags == 0 else "bad_flags")
                continue
            kind = self.verifier.check(frame)
            if kind is not None:
                self._count(kind, f"signed frame from system {frame[5]}")
                continue
            try:  # decoded without its signature, recorded with it (a .tlog frame is the frame as received)
                out.append((frame, decode_lite(frame[: -signing.SIGNATURE_LEN])))
            except Exception as exc:  # bad CRC or unknown id inside a valid signature: count, never raise
                self._count("undecodable", repr(exc)[:120])
        return out

    def _on_datagram_pymavlink(self, data: bytes, addr: tuple[str, int]) -> None:
        try:
            msgs = self.mav.parse_buffer(data)
        except Exception as exc:  # pymavlink raises plain MAVError / struct.error on some garbage
            self._count("undecodable", repr(exc)[:120])
            return
        if not msgs:
            self._count("no_frame")
            return
        good = False
        for msg in msgs:
            if msg.get_type() == "BAD_DATA":
                self._count("bad_data", getattr(msg, "reason", ""))
                continue
            good = True
            self.received += 1
            if self._tlog is not None:  # one record per frame, even when a datagram carries several
                self._tlog.write(bytes(msg.get_msgbuf()))
            try:
                self.handler(msg)
            except Exception:  # a bug in a handler must not kill the socket; log it loudly
                log.exception("handler failed on %s", msg.get_type())
        if good and self.on_datagram_done is not None:
            self.on_datagram_done()
