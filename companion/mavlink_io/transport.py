"""The byte carriers under a MAVLink link: UDP datagrams, a serial device, a TCP connection.

:class:`companion.mavlink_io.link.MavlinkLink` keeps the MAVLink logic (framing, signing, lock-on, the .tlog);
a transport only moves bytes. Every transport has the same small surface (:class:`Transport`): ``open()``,
``fileno()`` (what to wait on; it may change, e.g. a TCP listener once a client is in), ``read(deliver)``
(hand what is waiting to ``deliver(data, sender)``: one call per datagram, or one per chunk of a stream),
``write(data, dest)``, ``close()``, ``describe()``. Failures are :class:`TransportError`: ``kind`` is the count
the link keeps (``socket_error``, ``send_dropped``, ``link_closed``) and ``dead`` says the transport must be
opened again before it carries anything (a serial device that went away, a TCP connection reset).

Connection URLs (:class:`LinkUrl`), as MAVSDK and mavutil users know them:

* ``udpin://0.0.0.0:14540`` (bind and answer whoever talks), ``udpout://127.0.0.1:14580`` (send there);
* ``serial:///dev/ttyACM0:921600`` (a flight controller's TELEM port; pyserial, raw 8N1, no flow control);
* ``tcp://127.0.0.1:5760`` (connect, e.g. ArduPilot SITL's SERIAL0 or mavlink-router's TCP server);
* ``tcpin://0.0.0.0:5760`` (listen for one peer at a time; while it is connected the port is closed, so nobody
  else gets in; when it goes the port listens again).

Streams carry no frame boundaries: :class:`companion.mavlink_io.framing.StreamFramer` cuts them.
Nothing here knows MAVLink.
"""

from __future__ import annotations

import contextlib
import os
import select
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol
from urllib.parse import urlparse

from companion.errors import ConfigError, LinkError

RCVBUF_BYTES = 4 << 20  # asked of the kernel (it grants up to net.core.rmem_max)
DRAIN_MAX = 512  # datagrams read per wake-up at most, so a flood cannot starve the event loop either
READ_MAX = 65536  # bytes read from a stream per wake-up
WRITE_WAIT_S = 0.1  # longest a stream write waits for room in a full kernel buffer before dropping the rest
BAUD_RANGE = (50, 12_000_000)
_SCHEMES = ("udpin", "udpout", "udp", "serial", "tcp", "tcpin")
_FORMS = "udpin://HOST:PORT, udpout://HOST:PORT, serial://DEVICE:BAUD, tcp://HOST:PORT or tcpin://HOST:PORT"

Deliver = Callable[[bytes, Any], None]


class TransportError(Exception):
    """A transport failed: ``kind`` is the link's count for it; ``dead``: it must be opened again."""

    def __init__(self, kind: str, detail: str, dead: bool = False) -> None:
        super().__init__(detail)
        self.kind = kind
        self.dead = dead


@dataclass(frozen=True)
class LinkUrl:
    """A parsed connection URL. ``mode``: udpin, udpout, serial, tcp (connect) or tcpin (listen); ``host`` and
    ``port`` for the network ones, ``device`` and ``baud`` (bit/s) for serial."""

    mode: str
    host: str = ""
    port: int = 0
    device: str = ""
    baud: int = 0

    @property
    def stream(self) -> bool:
        """True for byte streams (serial, TCP): frames must be cut out of them."""
        return self.mode in ("serial", "tcp", "tcpin")

    def __str__(self) -> str:
        if self.mode == "serial":
            return f"serial://{self.device}:{self.baud}"
        return f"{self.mode}://{self.host}:{self.port}"

    @classmethod
    def parse(cls, url: str) -> LinkUrl:
        """Parse one of the URL forms of the module docstring; raise :class:`ConfigError` naming what is wrong."""
        scheme, sep, rest = url.partition("://")
        if not sep or scheme not in _SCHEMES:
            raise ConfigError(f"--connect {url!r}: unknown link {scheme + sep or url!r}; expected {_FORMS}")
        if scheme == "serial":
            return cls._parse_serial(url, rest)
        u = urlparse(url)
        try:
            port = u.port
        except ValueError:
            port = None
        if not u.hostname or port is None or not 0 < port < 65536:
            raise ConfigError(f"--connect {url!r}: expected {scheme}://HOST:PORT (port 1..65535)")
        mode = "udpin" if scheme == "udp" else scheme
        return cls(mode, u.hostname, port)

    @classmethod
    def _parse_serial(cls, url: str, rest: str) -> LinkUrl:
        device, sep, baud_text = rest.rpartition(":")
        if not sep:
            raise ConfigError(f"--connect {url!r}: expected serial://DEVICE:BAUD, e.g. serial:///dev/ttyACM0:921600 "
                              "(the baud rate is not optional)")
        if not device:
            raise ConfigError(f"--connect {url!r}: no serial device before ':{baud_text}'")
        if not baud_text.isdigit():
            raise ConfigError(f"--connect {url!r}: baud rate {baud_text!r} is not a number")
        baud = int(baud_text)
        if not BAUD_RANGE[0] <= baud <= BAUD_RANGE[1]:
            raise ConfigError(f"--connect {url!r}: baud rate {baud} outside {BAUD_RANGE[0]}..{BAUD_RANGE[1]}")
        return cls("serial", device=device, baud=baud)


class Transport(Protocol):
    """What a link needs of its byte carrier (see the module docstring)."""

    stream: bool  #: True: bytes with no frame boundaries (frames are cut by the link)
    peer: Any  #: where writes go: an address (UDP), a description (streams); None: nowhere yet

    def open(self) -> None: ...

    def fileno(self) -> int: ...

    def read(self, deliver: Deliver) -> None: ...

    def write(self, data: bytes, dest: Any) -> None: ...

    def close(self) -> None: ...

    def describe(self) -> str: ...


class UdpTransport:
    """UDP: udpin binds the URL's port (or uses the bound socket given), udpout an ephemeral local one; each
    datagram is delivered with its sender's address; writes go to ``dest``."""

    stream = False

    def __init__(self, url: LinkUrl, sock: socket.socket | None = None) -> None:
        self.url = url
        self._given = sock
        self.sock: socket.socket | None = None
        self.peer = None if url.mode == "udpin" else (url.host, url.port)

    def open(self) -> None:
        """Bind; non-blocking, with a large receive buffer. :class:`LinkError` when the port is taken."""
        sock = self._given
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
            if sock is not None and sock is not self._given:
                sock.close()
            raise LinkError(f"cannot open {self.url}: {exc}") from None
        self.sock = sock

    def fileno(self) -> int:
        return self.sock.fileno() if self.sock is not None else -1

    def read(self, deliver: Deliver) -> None:
        """Deliver each waiting datagram (at most :data:`DRAIN_MAX`) with its sender's (host, port)."""
        recv = self.sock.recvfrom
        for _ in range(DRAIN_MAX):
            try:
                data, addr = recv(65535)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:  # e.g. ICMP port unreachable on loopback
                raise TransportError("socket_error", str(exc)) from None
            deliver(data, addr)

    def write(self, data: bytes, dest: Any) -> None:
        try:
            self.sock.sendto(data, dest)
        except (BlockingIOError, InterruptedError):
            raise TransportError("send_dropped", "socket buffer full") from None
        except OSError as exc:  # e.g. ICMP port unreachable from an earlier datagram
            raise TransportError("socket_error", str(exc)) from None

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()
            self.sock = None

    def describe(self) -> str:
        return str(self.url)


class _FdStream:
    """Shared by the stream transports: non-blocking reads and whole writes on one file descriptor."""

    stream = True
    peer: Any = None
    _fd = -1

    def fileno(self) -> int:
        return self._fd

    def _read_fd(self, deliver: Deliver, recv: Callable[[int], bytes]) -> None:
        """Deliver what one read returns; end of file and errors other than 'nothing yet' kill the transport."""
        try:
            data = recv(READ_MAX)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:  # EIO: the device or the pty's other side went away; ECONNRESET
            what = self.describe()
            raise TransportError("link_closed", f"{what}: {exc.strerror or exc}", dead=self._lost()) from None
        if not data:
            what = self.describe()
            raise TransportError("link_closed", f"{what}: closed by the other end", dead=self._lost())
        deliver(data, self.peer)

    def _write_all(self, data: bytes, send: Callable[[memoryview], int]) -> None:
        """Write every byte, waiting up to :data:`WRITE_WAIT_S` for room; what does not fit then is dropped (the
        other end's framer resynchronises on the next frame)."""
        view = memoryview(data)
        deadline = 0.0
        while view:
            try:
                view = view[send(view):]
                continue
            except (BlockingIOError, InterruptedError):
                pass
            except OSError as exc:
                what = self.describe()
                raise TransportError("link_closed", f"{what}: {exc.strerror or exc}", dead=self._lost()) from None
            now = time.monotonic()
            deadline = deadline or now + WRITE_WAIT_S
            if now >= deadline:
                raise TransportError("send_dropped", f"{self.describe()}: {len(view)} bytes found no room")
            select.select((), (self._fd,), (), deadline - now)

    def _lost(self) -> bool:
        """The other end went: close; True when the transport must be opened again (False: it waits by itself)."""
        self.close()
        return True

    def close(self) -> None:  # pragma: no cover - each subclass closes its own
        raise NotImplementedError

    def describe(self) -> str:  # pragma: no cover
        raise NotImplementedError


class SerialTransport(_FdStream):
    """A serial device through pyserial (opened exclusively, raw 8N1 at the URL's baud rate, no flow control),
    then read and written on its file descriptor directly."""

    def __init__(self, url: LinkUrl) -> None:
        self.url = url
        self._port: Any = None

    def open(self) -> None:
        """Open the device; :class:`LinkError` naming it when it is missing, busy or refuses the baud rate."""
        import serial  # pyserial: only a serial link needs it

        try:
            port = serial.Serial(self.url.device, self.url.baud, timeout=0, exclusive=True)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise LinkError(f"cannot open {self.url}: {exc}") from None
        self._port = port
        self._fd = port.fileno()
        os.set_blocking(self._fd, False)
        self.peer = self.url.device

    def read(self, deliver: Deliver) -> None:
        fd = self._fd
        self._read_fd(deliver, lambda n: os.read(fd, n))

    def write(self, data: bytes, dest: Any = None) -> None:
        fd = self._fd
        self._write_all(data, lambda v: os.write(fd, v))

    def close(self) -> None:
        if self._port is not None:
            with contextlib.suppress(Exception):  # a device that vanished may fail its own close
                self._port.close()
            self._port = None
        self._fd = -1
        self.peer = None

    def describe(self) -> str:
        return str(self.url)


class TcpTransport(_FdStream):
    """TCP with Nagle off (a setpoint must not wait for company). ``tcp``: connect to the URL; ``tcpin``: listen
    there and take one peer; while it is connected the listening socket is closed, so a second client is refused
    by the kernel; when the peer goes the port listens again."""

    def __init__(self, url: LinkUrl, connect_timeout_s: float = 5.0, reconnect_timeout_s: float = 0.2) -> None:
        self.url = url
        self.connect_timeout_s = connect_timeout_s  # the first connection (s); later ones wait reconnect_timeout_s
        self.reconnect_timeout_s = reconnect_timeout_s  # short: a reconnection is tried inside a flying loop
        self._conn: socket.socket | None = None
        self._listener: socket.socket | None = None
        self._opened = False

    def open(self) -> None:
        """Connect (tcp) or listen (tcpin); :class:`LinkError` when refused or the port is taken."""
        addr = (self.url.host, self.url.port)
        try:
            if self.url.mode == "tcp":
                timeout = self.reconnect_timeout_s if self._opened else self.connect_timeout_s
                self._take(socket.create_connection(addr, timeout=timeout))
            else:
                self._listen()
        except OSError as exc:
            raise LinkError(f"cannot open {self.url}: {exc.strerror or exc}") from None
        self._opened = True

    def _listen(self) -> None:
        s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.bind((self.url.host, self.url.port))
            s.listen(1)
        except OSError:
            s.close()
            raise
        s.setblocking(False)
        self._listener, self._fd = s, s.fileno()

    def _take(self, conn: socket.socket) -> None:
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        conn.setblocking(False)
        self._conn, self._fd = conn, conn.fileno()
        host, port = conn.getpeername()[:2]
        self.peer = f"{host}:{port}"

    def read(self, deliver: Deliver) -> None:
        """Deliver what the peer sent; a listener with no peer takes the one knocking (nothing to deliver)."""
        if self._conn is None:
            if self._listener is None:
                return
            try:
                conn, _ = self._listener.accept()
            except (BlockingIOError, InterruptedError):
                return
            self._listener.close()
            self._listener = None
            self._take(conn)
            return
        self._read_fd(deliver, self._conn.recv)

    def write(self, data: bytes, dest: Any = None) -> None:
        if self._conn is None:
            raise TransportError("send_dropped", f"{self.url}: no peer connected")
        self._write_all(data, self._conn.send)

    def _lost(self) -> bool:
        """The peer went: a listener listens again at once (not dead then), a client must reconnect."""
        self.close()
        if self.url.mode == "tcpin":
            with contextlib.suppress(OSError):
                self._listen()
                return False
        return True

    def close(self) -> None:
        for s in (self._conn, self._listener):
            if s is not None:
                s.close()
        self._conn = self._listener = None
        self._fd = -1
        self.peer = None

    @property
    def listening(self) -> bool:
        """True while a tcpin transport waits for its peer."""
        return self._listener is not None

    def describe(self) -> str:
        return f"{self.url}" + (f" (peer {self.peer})" if self.peer and self.url.mode == "tcpin" else "")


def make_transport(url: LinkUrl, sock: socket.socket | None = None) -> Transport:
    """The transport for ``url`` (``sock``: an already bound UDP socket for udpin), not opened yet."""
    if url.mode == "serial":
        return SerialTransport(url)
    if url.mode in ("tcp", "tcpin"):
        return TcpTransport(url)
    return UdpTransport(url, sock)
