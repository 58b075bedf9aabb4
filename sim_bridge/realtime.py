"""The bundled vehicle's real-time runner: physics on the monotonic wall clock, both links on asyncio.

Every control period (``cfg.control_period_us`` of wall time) the vehicle flies one period and sends its due
telemetry, batched per link; input is handled as it arrives. A machine that stalls more than 50 periods skips
ahead instead of racing. The vehicle logic is :class:`sim_bridge.vehicle.SitlVehicle`'s, shared with the
lockstep runner (:mod:`sim_bridge.lockstep`).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import signal
import time
from typing import Any

from sim_bridge.link import MavUdpLink, SerialPort, open_link, serial_link

log = logging.getLogger(__name__)


async def _realtime_loop(v: Any, stop: asyncio.Event) -> None:
    period = v.cfg.control_period_us * 1e-6
    t0 = time.monotonic()
    done = 0
    while not v.stop_requested:
        due = int((time.monotonic() - t0) / period)
        if due - done > 50:  # far behind (machine stalled): skip ahead instead of racing
            log.warning("real-time loop %d periods behind; skipping ahead", due - done)
            t0 += (due - done - 1) * period
            due = done + 1
        links = v._links()
        for lk in links:
            lk.begin_batch()
        while done < due:
            v.advance()
            done += 1
        for lk in links:
            lk.flush()
        await asyncio.sleep(max(0.0, t0 + (done + 1) * period - time.monotonic()))
    stop.set()  # --duration reached


def _serial_onboard(v: Any, loop: asyncio.AbstractEventLoop) -> MavUdpLink:
    """The onboard link on the serial device of ``sitl --serial``, read whenever its descriptor is readable."""
    cfg = v.cfg
    port = SerialPort(*cfg.onboard_serial, v.counters)
    link = serial_link(port, cfg.sysid, cfg.compid, v.counters, v.on_message)

    def readable() -> None:
        try:
            data, addr = port.recvfrom()
        except BlockingIOError:
            if port.dead:
                loop.remove_reader(port.fileno())
            return
        link.datagram_received(data, addr)

    loop.add_reader(port.fileno(), readable)
    return link


async def run_realtime(v: Any, ready_cb=None) -> int:
    """Bind both links on the running loop (the onboard one: UDP, or the serial device of ``sitl --serial``) and fly
    ``v`` in real time until SIGINT/SIGTERM or its ``duration_s``; returns 0. Raises OSError when a port is taken."""
    cfg = v.cfg
    stop = asyncio.Event()
    v.warm_up()
    loop = asyncio.get_running_loop()
    if cfg.onboard_serial is not None:
        onboard = _serial_onboard(v, loop)
    else:
        onboard = await open_link("onboard", cfg.onboard_bind, cfg.onboard_remote, cfg.sysid, cfg.compid,
                                  v.counters, v.on_message, cfg.onboard_peer, link_id=0)
    gcs = await open_link("gcs", cfg.gcs_bind, cfg.gcs_remote, cfg.sysid, cfg.compid,
                          v.counters, v.on_message, cfg.gcs_peer, link_id=1)
    v.attach_links(onboard, gcs)
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError):  # not the main thread
            loop.add_signal_handler(sig, stop.set)
    if ready_cb is not None:
        ready_cb(v)
    v.start()
    task = asyncio.create_task(_realtime_loop(v, stop))
    try:
        await stop.wait()
    finally:
        task.cancel()
        if cfg.onboard_serial is not None:
            loop.remove_reader(onboard.transport.fileno())
        for lk in (onboard, gcs):
            if lk.transport is not None:
                lk.transport.close()
    return 0
