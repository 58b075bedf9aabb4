"""The bundled vehicle's lockstep runner: a plain blocking loop, no event loop.

Simulated time advances only when the onboard client answers a marker (docs/sitl.md): receive a datagram
→ handle its frames (a SET_ATTITUDE_TARGET from the onboard link flies one control period and sends that
period's telemetry and the SYSTEM_TIME marker, see :meth:`SitlVehicle._lockstep_step`) → receive the next.
The onboard socket blocks in the kernel with a short receive timeout (``SO_RCVTIMEO``, one system call per
datagram; a serial onboard link, ``sitl --serial``, waits in ``select`` as long); the GCS socket is non-blocking
and drained whenever ``poll`` (asked at most once a millisecond) says it has input. On the wall clock, at least
every :data:`DUTY_PERIOD_S`, the vehicle re-sends a marker nobody answered and heartbeats while
idle (:meth:`SitlVehicle.wall_clock_duties`). SIGINT/SIGTERM end the loop within one receive timeout.
"""

from __future__ import annotations

import contextlib
import logging
import select
import signal
import socket
import struct
import time
from typing import Any

from sim_bridge.link import MavUdpLink, SerialPort, serial_link

log = logging.getLogger(__name__)

RECV_TIMEOUT_S = 0.01  # longest the loop blocks before it looks at the GCS link, the clock and the stop flag
DUTY_PERIOD_S = 0.05  # wall-clock duties at least this often (also while datagrams keep coming)
GCS_POLL_S = 0.001  # the GCS socket is looked at once per this much wall time (and after every receive timeout)
_RECV_MAX = 65536


def _bind(addr: tuple[str, int]) -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.bind(addr)
    except OSError:
        sock.close()
        raise
    return sock


def _open_onboard(v: Any) -> Any:
    """The onboard link's receiver: its UDP socket blocking up to :data:`RECV_TIMEOUT_S` per ``recvfrom``, or the
    serial device (``sitl --serial``) that waits as long."""
    cfg = v.cfg
    if cfg.onboard_serial is not None:
        return SerialPort(*cfg.onboard_serial, v.counters, recv_timeout_s=RECV_TIMEOUT_S)
    sock = _bind(cfg.onboard_bind)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO, struct.pack("ll", 0, round(RECV_TIMEOUT_S * 1e6)))
    return sock


def _stop_on_signals(v: Any) -> dict:
    """SIGINT/SIGTERM set ``v.stop_requested``; returns the previous handlers (empty off the main thread)."""

    def handler(signum: int, frame: Any) -> None:
        v.stop_requested = True

    old = {}
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(ValueError):  # not the main thread: the caller sets stop_requested itself
            old[sig] = signal.signal(sig, handler)
    return old


def run_lockstep(v: Any, ready_cb=None) -> int:
    """Bind both links and run ``v`` in lockstep until SIGINT/SIGTERM or its ``duration_s``; returns 0.
    Raises OSError when a port is taken."""
    cfg = v.cfg
    v.warm_up()
    onboard_sock = _open_onboard(v)
    try:
        gcs_sock = _bind(cfg.gcs_bind)
    except OSError:
        onboard_sock.close()
        raise
    old_handlers: dict = {}
    try:
        gcs_sock.setblocking(False)
        if cfg.onboard_serial is not None:
            onboard = serial_link(onboard_sock, cfg.sysid, cfg.compid, v.counters, v.on_message)
        else:
            onboard = MavUdpLink("onboard", cfg.onboard_remote, cfg.sysid, cfg.compid, v.counters, v.on_message,
                                 cfg.onboard_peer, link_id=0)
            onboard.transport = onboard_sock  # a socket's sendto is all a link needs
        gcs = MavUdpLink("gcs", cfg.gcs_remote, cfg.sysid, cfg.compid, v.counters, v.on_message, cfg.gcs_peer,
                         link_id=1)
        gcs.transport = gcs_sock
        v.attach_links(onboard, gcs)
        old_handlers = _stop_on_signals(v)
        if ready_cb is not None:
            ready_cb(v)
        v.start()
        _loop(v, onboard_sock, onboard, gcs_sock, gcs)
    finally:
        for sig, h in old_handlers.items():
            signal.signal(sig, h)
        onboard_sock.close()
        gcs_sock.close()
    return 0


def _loop(v: Any, onboard_sock: Any, onboard: MavUdpLink, gcs_sock: socket.socket,
          gcs: MavUdpLink) -> None:
    """Receive → handle until ``v.stop_requested``; the hot path is one ``recvfrom`` and one ``poll(0)``."""
    recv = onboard_sock.recvfrom
    on_onboard = onboard.datagram_received
    gcs_poll = select.poll()
    gcs_poll.register(gcs_sock, select.POLLIN)
    gcs_waiting = gcs_poll.poll
    monotonic = time.monotonic
    next_duty = next_gcs = 0.0
    while not v.stop_requested:
        try:
            data, addr = recv(_RECV_MAX)
        except (BlockingIOError, InterruptedError):  # the receive timeout: nothing for RECV_TIMEOUT_S
            pass
        except ConnectionRefusedError:  # the ICMP answer to an earlier datagram nobody took
            pass
        else:
            on_onboard(data, addr)
        now = monotonic()
        if now >= next_gcs:  # a system call saved on most steps: the GCS waits at most GCS_POLL_S more
            next_gcs = now + GCS_POLL_S
            if gcs_waiting(0):
                _drain(gcs_sock, gcs)
        if now >= next_duty:
            next_duty = now + DUTY_PERIOD_S
            v.wall_clock_duties(now)


def _drain(sock: socket.socket, link: MavUdpLink) -> None:
    """Handle every datagram waiting on a non-blocking socket."""
    while True:
        try:
            data, addr = sock.recvfrom(_RECV_MAX)
        except (BlockingIOError, InterruptedError):
            return
        except ConnectionRefusedError:
            continue
        link.datagram_received(data, addr)
