"""``fly --mission autopilot``: fetch the mission and fence the operator uploaded to the autopilot, before the
flight is built.

The flight sequence is not touched: before the pilot exists, :func:`fetch_autopilot_mission` opens the flight's
own link (the same URL, socket and signing key, over UDP, serial or TCP; the bundled vehicle's lockstep loop answers
while it waits for its first step), waits for the autopilot's HEARTBEAT, asks for HOME_POSITION (and
GPS_GLOBAL_ORIGIN, for the report), downloads MAV_MISSION_TYPE_MISSION and then MAV_MISSION_TYPE_FENCE with the pure
:class:`~companion.mavlink_io.mission_client.MissionDownload`, closes the link and converts the items with
:func:`companion.core.autopilot_mission.mission_from_items`. The pilot then flies the resulting mission with the
usual runner. Anything not understood is a :class:`Refusal` before take-off (the run folder and its report are
still written, nothing is flown): ``no_vehicle`` without a HEARTBEAT, ``not_ready`` without a home, ``refused``
for a download that fails or a mission or fence that cannot be flown, each with the reason.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from companion.core.autopilot_mission import Home, mission_from_items
from companion.core.mission import Mission
from companion.flight.setup import FlightSetup
from companion.mavlink_io import telemetry as tm
from companion.mavlink_io.link import MavlinkLink
from companion.mavlink_io.mission_client import (
    MAV_MISSION_TYPE_FENCE,
    MAV_MISSION_TYPE_MISSION,
    MissionDownload,
    Outgoing,
    RequestItem,
    RequestList,
    SendAck,
)

log = logging.getLogger(__name__)

MAV_AUTOPILOT_INVALID = 8
MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_CMD_REQUEST_MESSAGE = 512
MAV_MISSION_UNSUPPORTED = 3
HOME_TIMEOUT_S = 10.0  # to get HOME_POSITION once the vehicle is found (asked again each second)


@dataclass
class Refusal(Exception):
    """The autopilot's mission cannot be flown: the flight's ``outcome`` and the reason (``detail``)."""

    outcome: str
    detail: str
    facts: dict[str, Any] = field(default_factory=dict)  # what was learnt before the refusal, for the report

    def __str__(self) -> str:
        return f"{self.outcome}: {self.detail}"


@dataclass
class Fetched:
    """What was downloaded: the vehicle, home, the items of each type and the facts for the report."""

    autopilot: int = 0
    sysid: int = 0
    compid: int = 0
    home: Home | None = None
    origin: tuple[float, float, float] | None = None
    items: list[Any] = field(default_factory=list)
    fence_items: list[Any] = field(default_factory=list)
    facts: dict[str, Any] = field(default_factory=dict)


class _Session:
    """The download's link: events of the vehicle (once known) queue up for the steps below."""

    def __init__(self, setup: FlightSetup, tlog: Path | None) -> None:
        sock = setup.sock.dup() if setup.sock is not None else None  # the flight keeps its own socket open
        self.link = MavlinkLink(setup.connect, self._on_message, tlog=tlog, sock=sock, signing_key=setup.signing_key)
        self.events: list[Any] = []
        self.got = Fetched()

    def _on_message(self, msg: Any) -> None:
        ev = tm.decode(msg)
        if ev is None:
            return
        if not self.got.sysid:
            if isinstance(ev, tm.Heartbeat) and ev.autopilot != MAV_AUTOPILOT_INVALID:
                self.got.sysid, self.got.compid, self.got.autopilot = ev.src_system, ev.src_component, ev.autopilot
                self.link.lock_to_last_sender()
            return
        if ev.src_system != self.got.sysid:
            return
        if isinstance(ev, tm.HomePosition):  # the latest, whenever it comes
            self.got.home = Home(ev.pos_ned_m, ev.lat_deg, ev.lon_deg, ev.alt_amsl_m)
        elif isinstance(ev, tm.GpsGlobalOrigin):
            self.got.origin = (ev.lat_deg, ev.lon_deg, ev.alt_amsl_m)
        else:
            self.events.append(ev)

    def wait(self, until_s: float) -> list[Any]:
        """Read the link until ``until_s`` (monotonic s) or the first datagram; the vehicle's new events."""
        self.link.poll(max(0.0, min(0.05, until_s - time.monotonic())))
        out, self.events = self.events, []
        return out

    def send(self, out: list[Outgoing]) -> None:
        mav, ts, tc = self.link.mav, self.got.sysid, self.got.compid
        for o in out:
            if isinstance(o, RequestList):
                mav.mission_request_list_send(ts, tc, o.mission_type)
            elif isinstance(o, RequestItem):
                mav.mission_request_int_send(ts, tc, o.seq, o.mission_type)
            elif isinstance(o, SendAck):
                mav.mission_ack_send(ts, tc, o.result, o.mission_type)

    def request_message(self, msgid: int) -> None:
        self.link.mav.command_long_send(self.got.sysid, self.got.compid, MAV_CMD_REQUEST_MESSAGE, 0, msgid,
                                        0, 0, 0, 0, 0, 0)


def _find_vehicle(s: _Session, timeout_s: float) -> None:
    end = time.monotonic() + timeout_s
    while not s.got.sysid:
        if time.monotonic() >= end:
            raise Refusal("no_vehicle", f"no autopilot HEARTBEAT within {timeout_s:g} s on {s.link.url}: cannot "
                                        "download its mission")
        s.wait(end)


def _get_home(s: _Session, timeout_s: float) -> None:
    """HOME_POSITION (asked each second, GPS_GLOBAL_ORIGIN with it); Refusal ``not_ready`` without it."""
    end = time.monotonic() + timeout_s
    asked = 0.0
    while s.got.home is None:
        now = time.monotonic()
        if now >= end:
            raise Refusal("not_ready", f"the autopilot sent no HOME_POSITION within {timeout_s:g} s: the mission "
                                       "cannot be placed (does it have a position estimate?)")
        if now - asked >= 1.0:
            asked = now
            s.request_message(242)
            if s.got.origin is None:
                s.request_message(49)
        s.wait(end)


def _download(s: _Session, d: MissionDownload) -> list[Any]:
    """Run one download to its end over the session; its items, or Refusal ``refused`` naming what failed (an
    autopilot without a fence service answers UNSUPPORTED: no fence)."""
    s.send(d.start(time.monotonic()))
    while not d.finished:
        for ev in s.wait(d.deadline_s):
            s.send(d.on_event(ev, time.monotonic()))
        s.send(d.on_time(time.monotonic()))
    s.got.facts[d.name] = d.facts()
    if d.state == "failed":
        if d.mission_type == MAV_MISSION_TYPE_FENCE and d.nack == MAV_MISSION_UNSUPPORTED:
            log.info("the autopilot has no fence service: no fence")
            return []
        raise Refusal("refused", d.error)
    log.info("downloaded the autopilot's %s: %d items (%d duplicates, %d out of order, %d requests re-sent)",
             d.name, len(d.items), d.duplicates, d.out_of_order, d.resent)
    return list(d.items)


def download(setup: FlightSetup, *, tlog: Path | None = None, max_items: int = 1000, timeout_s: float = 1.5,
             retries: int = 5, home_timeout_s: float = HOME_TIMEOUT_S) -> Fetched:
    """Find the autopilot on ``setup``'s link and download its home, mission and fence (see module docstring):
    ``max_items`` per type at most, ``timeout_s`` (s) between ``retries`` re-sent requests; Refusal otherwise."""
    s = _Session(setup, tlog)
    s.link.open_blocking()
    t0 = time.monotonic()
    try:
        _find_vehicle(s, setup.heartbeat_timeout_s)
        _get_home(s, home_timeout_s)
        for mtype in (MAV_MISSION_TYPE_MISSION, MAV_MISSION_TYPE_FENCE):
            items = _download(s, MissionDownload(mtype, max_items=max_items, timeout_s=timeout_s, retries=retries))
            if mtype == MAV_MISSION_TYPE_MISSION:
                s.got.items = items
            else:
                s.got.fence_items = items
        s.got.facts["wall_s"] = round(time.monotonic() - t0, 3)  # HEARTBEAT to the fence's ACK
        return s.got
    except Refusal as r:
        r.facts = _facts(s.got, bundled=False)
        raise
    finally:
        s.link.close()


def _facts(got: Fetched, bundled: bool) -> dict[str, Any]:
    """The report's facts of a download (as far as it went)."""
    h = got.home
    return {
        "download": got.facts, "autopilot": got.autopilot, "sysid": got.sysid, "items": len(got.items),
        "fence_items": len(got.fence_items),
        "home": None if h is None else {"local_ned_m": list(h.pos_ned_m), "lat_deg": h.lat_deg,
                                        "lon_deg": h.lon_deg, "alt_amsl_m": h.alt_amsl_m},
        "origin": list(got.origin) if got.origin is not None else None,
        "earth_model": earth_model_for(got.autopilot, bundled),
    }


def earth_model_for(autopilot: int, bundled: bool) -> str:
    """The earth model the vehicle's local frame uses (:data:`companion.core.autopilot_mission.EARTH_MODELS`)."""
    if bundled:
        return "wgs84"
    return "ardupilot" if autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA else "px4"


def fetch_autopilot_mission(setup: FlightSetup, base: Mission, *, bundled: bool = False,
                            run_dir: Path | None = None, **download_args: Any) -> tuple[Mission, dict[str, Any]]:
    """The mission to fly (``base`` with the autopilot's route and fence) and the facts for the report; raises
    :class:`Refusal` for anything that cannot be flown. ``bundled``: the vehicle is the bundled simulator."""
    tlog = run_dir / "mission_download.tlog" if run_dir is not None else None
    got = download(setup, tlog=tlog, **download_args)
    assert got.home is not None
    facts = _facts(got, bundled)
    try:
        mission, notes = mission_from_items(got.items, got.fence_items, got.home, base,
                                            earth_model=facts["earth_model"],
                                            skip_home_item=got.autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA)
    except ValueError as exc:
        raise Refusal("refused", f"autopilot mission: {exc}", facts) from None
    facts["notes"] = notes
    facts["waypoints"] = [[*map(float, w.pos_ned_m)] for w in mission.waypoints] + [[*map(float, mission.goal_ned_m)]]
    for n in notes:
        log.info("autopilot mission: %s", n)
    return mission, facts


def pinned_setup(setup: FlightSetup, facts: dict[str, Any]) -> FlightSetup:
    """``setup`` with the mission frame pinned to the home the route was placed about (``facts``' home, local NED
    m): an autopilot that moves home after the download (PX4 SIH while its estimator settles) no longer shifts the
    route off the points on the earth. ``start_here`` (fly from where the vehicle stands) is left as asked."""
    home = (facts.get("home") or {}).get("local_ned_m")
    if home is None or setup.start_here:
        return setup
    return replace(setup, mission_origin_ned_m=(float(home[0]), float(home[1]), float(home[2])))
