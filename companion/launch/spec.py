"""What a whole flight run is: the flight's own set-up plus what surrounds it (the bundled vehicle, Zenoh, the
recording, the narration, the run folder and its report)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from companion.flight.setup import FlightSetup

DEFAULT_GAINS_NAME = "controller.toml"


@dataclass(frozen=True)
class ZenohSpec:
    """The Zenoh side of a flight: the session's ``config`` (a ``zenoh.Config``), the key prefix, the vehicle id
    (None: the autopilot's MAVLink system id) and per-stream publication rates (Hz)."""

    config: Any
    prefix: str = "slungpilot"
    vehicle_id: str | None = None
    rates: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class FlySpec:
    """One flight run.

    ``setup``: the flight itself (link, rate, lockstep, profile, timeouts; with ``sitl`` its ``connect`` and
    ``sock`` are filled in when the vehicle starts); ``sitl``: start the bundled vehicle (``sitl_args``: extra flags
    for it); ``run_dir``: the run folder (None: a new one under ``runs/``); ``report``: also write the report here;
    ``plots``: the run folder's figures; ``narrate``: the terminal narration; ``zenoh``: publish and listen on
    Zenoh (None: not at all); ``view``: a recording/live-view session factory ``view(mission, run_dir)`` (None: no
    recording); ``config_facts(run)``: the effective configuration for Zenoh's ``config`` queryable;
    ``pin_lockstep``: with ``sitl`` in lockstep, run the companion and the vehicle on one CPU (the one the companion
    runs on when the flight starts; :func:`companion.flight.scheduling.pin_to_one_cpu`).
    """

    setup: FlightSetup
    sitl: bool = False
    sitl_args: tuple[str, ...] = ()
    run_dir: Path | None = None
    report: Path | None = None
    plots: bool = True
    narrate: bool = True
    zenoh: ZenohSpec | None = None
    view: Callable[[Any, Path], Any] | None = None
    config_facts: Callable[[Any], dict[str, Any]] | None = None
    pin_lockstep: bool = True
    sitl_serial: bool = False  #: with ``sitl``: the vehicle's onboard link over a pseudo-terminal pair, not UDP
    #: fly the mission the operator uploaded to the autopilot (``--mission autopilot``): downloaded before the
    #: flight, its route and fence replace the given mission's (:mod:`companion.launch.autopilot_mission`)
    autopilot_mission: bool = False
    #: with ``sitl``: the simulated world (:class:`companion.core.world.World`) the vehicle is started in
    #: (``--world``); the report then scores clearance and collisions against its trunks, the truth
    world: Any = None
    #: identify the payload from the cruise's first seconds after the flight (~0.6 s of CPU) and report it next to
    #: the declared one (:mod:`companion.estimation.payload_watch`); ``lab`` turns it off for its many flights
    identify_payload: bool = True
    #: with ``sitl``: the vehicle's process forked ahead of the flight (:class:`companion.launch.sitl.VehicleFork`),
    #: started instead of a fresh ``python -m sim_bridge``; its creator discards it when the flight did not use it
    vehicle_fork: Any = None
