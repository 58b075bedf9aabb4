"""MAVLink 2 for the companion: a thin shell around pymavlink's generated codec over any transport.

Connection URLs (:class:`~companion.mavlink_io.transport.LinkUrl`): ``udpin://0.0.0.0:14540`` (bind, answer the
vehicle that sends to it: the default, PX4's onboard link), ``udpout://HOST:PORT`` (send there),
``serial:///dev/ttyACM0:921600`` (a TELEM port), ``tcp://HOST:PORT`` (connect), ``tcpin://HOST:PORT`` (listen).

Lock-on (as MAVSDK and MAVProxy do): once the app has found the vehicle (its first autopilot HEARTBEAT) it calls
:meth:`MavlinkLink.lock_to_last_sender`. UDP: from then on only that address is read and sent to; other senders
are counted (``foreign_sender``) and dropped before decoding (before the lock, udpin reads all and sends nothing).
A stream has one other end (the wire, or the one peer tcpin lets in): the lock notes the autopilot's system id
and drops nothing by sender, as a router multiplexes the payload's and a GCS's systems onto it (the pilot reads
only the locked system's and the payload's telemetry).

Streams are cut into frames by :class:`~companion.mavlink_io.framing.StreamFramer` (partial frames held across
reads; garbage skipped, counted as ``garbage`` runs and ``garbage_bytes``), and each frame is then handled as a
one-frame datagram. A stream that dies (a serial device unplugged, its pseudo-terminal's other side gone, a TCP
reset) is counted once as ``link_closed``, stops being read, and is reopened every :data:`REOPEN_S`; meanwhile
the link is not ``connected``, nothing is sent, and the flight's own telemetry watch ends it as ``link_lost``.

Every frame in and out also goes to a ``.tlog`` (:mod:`companion.mavlink_io.tlog`). Undecodable input is counted
and logged at most once a second per kind; it never raises into the flight loop. Hot path: a datagram of complete,
unsigned, CRC-valid MAVLink 2 frames (what a vehicle sends) is cut and decoded by
:mod:`companion.mavlink_io.datagrams` (with signing on, only the frames that check out); anything else by
pymavlink's own parser. ``on_datagram_done`` (optional) is called after the
messages of each datagram (stream: each frame) were handled.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import select
import socket
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

from companion.errors import LinkError
from companion.mavlink_io import signing
from companion.mavlink_io.codec import STX_V2 as _STX_V2
from companion.mavlink_io.codec import crc_extra_of
from companion.mavlink_io.datagrams import split_signed, split_unsigned
from companion.mavlink_io.framing import StreamFramer
from companion.mavlink_io.tlog import TlogWriter, tlog_frames, tlog_messages
from companion.mavlink_io.transport import DRAIN_MAX, RCVBUF_BYTES, LinkUrl, TransportError, make_transport

__all__ = ["DRAIN_MAX", "MAV_COMP_ID_ONBOARD_COMPUTER", "RCVBUF_BYTES", "REOPEN_S", "LinkUrl", "MavlinkLink",
           "TlogWriter", "tlog_frames", "tlog_messages"]

log = logging.getLogger(__name__)

MAV_COMP_ID_ONBOARD_COMPUTER = 191
REOPEN_S = 1.0  # a dead stream is opened again this often


class MavlinkLink:
    """One MAVLink 2 endpoint over UDP, serial or TCP. Decoded messages go to ``handler(msg)``; sending via
    ``self.mav``.

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
        accept_unsigned: tuple[int, ...] = (),
    ) -> None:
        self.url = LinkUrl.parse(url)
        self.transport = make_transport(self.url, sock)  # ``sock``: an already bound UDP socket (udpin)
        self._stream = self.url.stream
        self._framer = StreamFramer() if self._stream else None
        # MAVLink 2 signing (companion.mavlink_io.signing): every frame out signed, every frame in checked
        # (``accept_unsigned``: systems whose unsigned frames are read all the same, counted in the verifier)
        self.verifier = None if signing_key is None else signing.SigningVerifier(signing_key, accept_unsigned)
        self.signer = None if signing_key is None else signing.LinkSigner(signing_key, link_id=0)
        self.handler = handler
        self.mav = mavlink2.MAVLink(self, srcSystem=src_system, srcComponent=src_component)
        self.mav.robust_parsing = True
        self.rejected: Counter[str] = Counter()
        self.received = 0
        self.sent = 0
        self._last_log: dict[str, float] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._open = False
        self._reader_fd = -1  # the descriptor the event loop watches (-1: none)
        self._down_since: float | None = None  # monotonic time a stream died (None: alive)
        self._next_reopen = 0.0
        self._reopen_timer: asyncio.TimerHandle | None = None
        self._remote: tuple[str, int] | None = None if self.url.mode in ("udpin", "serial", "tcp", "tcpin") \
            else (self.url.host, self.url.port)
        self._locked: tuple[Any, Any] | None = None  # UDP: the vehicle's address (datagrams from others dropped)
        self._stream_lock: tuple[Any, Any] | None = None  # stream: (the other end, the autopilot's system id)
        self.last_sender: tuple[Any, Any] | None = None  # UDP: (host, port); stream: (peer, system id) of the frame
        self.last_rx_wall = 0.0  # monotonic time of the last datagram accepted from the vehicle's address
        self._tlog = TlogWriter(tlog) if tlog else None
        self.on_datagram_done: Callable[[], None] | None = None  # called after each datagram's messages
        #: set: the unsigned frames of the fast path (CRC checked) go here as bytes instead of to ``handler``
        self.frame_handler: Callable[[bytes], None] | None = None
        self._deliver = self._on_stream if self._stream else self._on_datagram

    # ------------------------------------------------------------------ opening, reading, closing
    async def open(self) -> None:
        """Open the transport and read it on the running loop (``loop.add_reader`` on its descriptor).

        A UDP socket is drained of up to :data:`DRAIN_MAX` datagrams per wake-up: asyncio's datagram transport
        reads one datagram per loop iteration, and under a flood into our port the kernel buffer then overflows and
        drops the vehicle's own datagrams along with the attacker's.
        """
        self.transport.open()
        self._open = True
        self._loop = asyncio.get_running_loop()
        self._watch()

    def open_blocking(self) -> None:
        """Open the transport for a caller without an event loop, which reads it with :meth:`poll`."""
        self.transport.open()
        self._open = True

    def poll(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` (s) for input and handle what the transport holds; False if none came (a dead
        stream: waits, and is reopened when due)."""
        if not self._open:
            return False
        if self._down_since is not None:
            if time.monotonic() >= self._next_reopen:
                self._try_reopen()
            if self._down_since is not None:
                time.sleep(timeout_s)
                return False
        ready, _, _ = select.select((self.transport.fileno(),), (), (), timeout_s)
        if not ready:
            return False
        self._drain()
        return True

    def close(self) -> None:
        """Close the transport and the tlog."""
        if self._reopen_timer is not None:
            self._reopen_timer.cancel()
            self._reopen_timer = None
        if self._open:
            self._unwatch()
            self.transport.close()
            self._loop = None
            self._open = False
        if self._tlog is not None:
            self._tlog.close()

    def _drain(self) -> None:
        """Handle what the transport holds (UDP: at most :data:`DRAIN_MAX` datagrams)."""
        try:
            self.transport.read(self._deliver)
        except TransportError as exc:
            self._count(exc.kind, str(exc))
            if exc.dead:
                self._went_down(str(exc))
        if self._stream and self._loop is not None:
            self._watch()  # a tcpin link's descriptor changes when its peer comes or goes

    def _watch(self) -> None:
        """Have the event loop watch the transport's current descriptor (none while the stream is down)."""
        fd = self.transport.fileno() if self._down_since is None else -1
        if fd == self._reader_fd or self._loop is None:
            return
        self._unwatch()
        if fd >= 0:
            self._loop.add_reader(fd, self._drain)
            self._reader_fd = fd

    def _unwatch(self) -> None:
        if self._reader_fd >= 0 and self._loop is not None:
            with contextlib.suppress(Exception):
                self._loop.remove_reader(self._reader_fd)
        self._reader_fd = -1

    def _went_down(self, why: str) -> None:
        """A stream died: stop reading it, say so once, and try to reopen it every :data:`REOPEN_S`."""
        now = time.monotonic()
        self._down_since = now
        self._next_reopen = now + REOPEN_S
        if self._framer is not None:
            self._framer.clear()
        log.warning("MAVLink link lost (%s); nothing is sent until it is back; reopening it every %.0f s",
                    why, REOPEN_S)
        self._unwatch()
        if self._loop is not None:
            self._reopen_timer = self._loop.call_later(REOPEN_S, self._try_reopen)

    def _try_reopen(self) -> None:
        """Open a dead stream again (a re-plugged device, a vehicle back on TCP); else try again later."""
        self._reopen_timer = None
        if not self._open or self._down_since is None:
            return
        try:
            self.transport.open()
        except LinkError:
            self._next_reopen = time.monotonic() + REOPEN_S
            if self._loop is not None:
                self._reopen_timer = self._loop.call_later(REOPEN_S, self._try_reopen)
            return
        log.warning("MAVLink link back after %.1f s: %s", time.monotonic() - self._down_since,
                    self.transport.describe())
        self._down_since = None
        self._watch()

    async def __aenter__(self) -> MavlinkLink:
        await self.open()
        return self

    async def __aexit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ the peer
    def lock_to_last_sender(self) -> None:
        """UDP: accept datagrams only from the sender of the datagram being handled (the vehicle), and send there
        (udpin; a udpout link keeps sending to its URL). Stream: note the autopilot's system id (module
        docstring: nothing is dropped by sender on a stream)."""
        if self.last_sender is None:
            return
        if self._stream:
            self._stream_lock = self.last_sender
            log.info("locked onto the autopilot (system %d) on %s", self.last_sender[1], self.transport.describe())
            return
        self._locked = self.last_sender
        if self.url.mode == "udpin":
            self._remote = self.last_sender
        log.info("locked onto the vehicle at %s:%d", *self._locked)

    @property
    def locked(self) -> tuple[Any, Any] | None:
        """UDP: the vehicle's address once locked on; stream: (the other end, the autopilot's system id)."""
        return self._stream_lock if self._stream else self._locked

    @property
    def connected(self) -> bool:
        """True once we know where to send: udpout always, udpin once locked onto the vehicle, a stream while it
        is open and has its other end."""
        if self._stream:
            return self._open and self._down_since is None and self.transport.peer is not None
        return self._remote is not None

    # pymavlink calls this to send a packed frame
    def write(self, frame: bytes) -> None:
        """File-like hook for pymavlink: send one frame to the remote (dropped before we know it); signed when
        signing is on."""
        if not self._open or self._down_since is not None or (self._remote is None and not self._stream):
            return
        frame = bytes(frame)
        if self.signer is not None and frame[:1] == b"\xfd":
            frame = self.signer.sign(frame, crc_extra_of(frame[7] | (frame[8] << 8) | (frame[9] << 16)))
            self.verifier.note_sent(self.signer.timestamp)
        try:
            self.transport.write(frame, self._remote)
        except TransportError as exc:
            self._count(exc.kind, str(exc))
            if exc.dead:
                self._went_down(str(exc))
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

    # ------------------------------------------------------------------ input
    def _on_stream(self, data: bytes, peer: Any) -> None:
        """A chunk of a stream: its complete frames, each handled as a one-frame datagram from (peer, system id)."""
        framer = self._framer
        runs, nbytes = framer.garbage_runs, framer.garbage_bytes
        frames = framer.feed(data)
        if framer.garbage_runs != runs:
            self.rejected["garbage_bytes"] += framer.garbage_bytes - nbytes
            self.rejected["garbage"] += framer.garbage_runs - runs - 1
            self._count("garbage", f"{framer.garbage_bytes - nbytes} bytes outside MAVLink frames on "
                        f"{self.transport.describe()}")
        for frame in frames:  # the sender's system id: byte 5 of MAVLink 2, byte 3 of MAVLink 1
            self._on_datagram(frame, (peer, frame[5] if frame[0] == _STX_V2 else frame[3]))

    def _on_datagram(self, data: bytes, addr: tuple[Any, Any]) -> None:
        """Handle the frames of a datagram (or of one stream frame: never locked out, a stream has one other end)."""
        if self._locked is not None and addr != self._locked:
            self._count("foreign_sender", f"from {addr[0]}:{addr[1]}")
            return
        self.last_sender = addr
        self.last_rx_wall = time.monotonic()
        if self.verifier is not None:
            msgs = split_signed(data, self.verifier, self._count)
        elif self.mav.buf_len() > 0:  # bytes left in pymavlink's parser from an earlier datagram: it goes on
            msgs = None
        else:
            msgs = split_unsigned(data, frames_only=self.frame_handler is not None)
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
