"""The typed set-up of one flight: everything the pilot and its runner need besides the mission itself.

Built by the command line from its flags (``companion.cli.fly``) and by ``lab`` in code; frozen, so what a flight
was set up with is what it flew with. Run-time wiring (live obstacle input, telemetry sinks, the journal's extra
facts) is not set-up: the runners take it as arguments.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from companion.autopilots.profile import VehicleProfile
from companion.control import ControllerConfig
from companion.errors import ConfigError
from companion.estimation import SWING_INPUTS
from companion.flight.sequence_types import SequenceConfig


@dataclass(frozen=True)
class FlightSetup:
    """How to fly: the link, the control rate and scheduling, the autopilot profile, the timeouts.

    ``connect``: a connection URL (``udpin://0.0.0.0:14540``, ``udpout://HOST:PORT``); ``rate_hz``: control ticks per
    second; ``lockstep``: the vehicle's simulated time advances only when the companion answers (the bundled vehicle);
    ``profile``: the autopilot's thrust and mode tables (None: chosen from its HEARTBEAT); ``hover_thrust_norm``:
    overrides the profile's hover thrust (0..1); ``gains``: the controller's configuration (None: the shipped one);
    ``payload_sysid``: the MAVLink system id of the payload's own position stream; ``swing_input``: where the swing
    comes from (:data:`SWING_INPUTS`); timeouts in seconds; ``tlog_path``: the ``.tlog`` to write; ``run_dir``:
    where the journal is flushed each second; ``start_here``: fly the mission from where the vehicle stands;
    ``signing_key``: MAVLink 2 signing (sign everything, accept only signed frames); ``rt_priority`` > 0: the
    control thread runs SCHED_FIFO in real time; ``inject_tick_error_at_s``: the fault suite's failing tick from
    this vehicle time on (None in normal use); ``perception``: map trunks from the vehicle's range scans
    (``OBSTACLE_DISTANCE``, Zenoh scans) into the planner's obstacles — None (default): on by itself when the
    vehicle's first scan arrives (a flight with no scans flies exactly as without it), True: from the start,
    False: never (scans are ignored). ``accept_unsigned``: with signing, the systems whose unsigned frames are read
    all the same (a payload that cannot sign); ``gcs_sysid``: the only ground station whose commands (pause,
    resume, land, return) the companion obeys (None: any, unless signing is on, when none is obeyed);
    ``mission_origin_ned_m``: the mission frame's origin pinned (the autopilot's local NED, m; north and east,
    heights still follow home): the home an autopilot's mission was placed about at its download (None: the frame
    follows home until the vehicle is ready). ``scored_cable_m``: the cable length (m) the flight's record places the
    payload at, for its clearance and collisions: the bundled vehicle's true cable where it differs from the
    mission's (``fly --sitl --true-cable-length-m``; None: the one flown, the mission's or the identified one after a
    hop). The pilot flies the mission's (or the identified) either way.
    """

    connect: str = "udpin://0.0.0.0:14540"
    rate_hz: float = 250.0
    lockstep: bool = False
    profile: VehicleProfile | None = None
    hover_thrust_norm: float | None = None
    gains: ControllerConfig | None = None
    payload_sysid: int | None = 2
    swing_input: str = "auto"
    heartbeat_timeout_s: float = 60.0
    ready_timeout_s: float = 90.0
    prestream_s: float = 1.0
    land_on_abort: bool = True
    land_timeout_s: float = 45.0
    tlog_path: Path | None = None
    run_dir: Path | None = None
    wall_timeout_s: float | None = None
    sock: Any = None  # an already bound UDP socket (socket.socket) for the link (fly --sitl reserves one)
    sequence: SequenceConfig | None = None  # the flight sequence's timeouts (defaults otherwise)
    allow_param_writes: bool = True  # False: refuse a vehicle whose parameters would have to change (ArduPilot)
    start_here: bool = False
    signing_key: bytes | None = None
    rt_priority: int = 0
    inject_tick_error_at_s: float | None = None
    perception: bool | None = None
    accept_unsigned: tuple[int, ...] = ()
    gcs_sysid: int | None = None
    mission_origin_ned_m: tuple[float, float, float] | None = None
    scored_cable_m: float | None = None

    @property
    def period_s(self) -> float:
        """The control period (s)."""
        return 1.0 / self.rate_hz

    def validate(self, rt_priority_max: int = 99) -> None:
        """Raise :class:`ConfigError` naming the option that is out of range."""
        if not 0 < self.rate_hz <= 2000:
            raise ConfigError(f"--rate-hz: must be in (0, 2000], got {self.rate_hz}")
        if not 0 <= self.rt_priority <= rt_priority_max:
            raise ConfigError(f"--rt-priority: must be in 0..{rt_priority_max} (0 = normal scheduling), got "
                              f"{self.rt_priority}")
        if self.accept_unsigned and self.signing_key is None:
            raise ConfigError("--accept-unsigned: only with --signing-key (without signing every frame is read)")
        for sysid in (*self.accept_unsigned, *(() if self.gcs_sysid is None else (self.gcs_sysid,))):
            if not 1 <= sysid <= 255:
                raise ConfigError(f"--accept-unsigned/--gcs-sysid: a MAVLink system id is 1..255, got {sysid}")
        if self.gcs_sysid is not None and self.gcs_sysid in self.accept_unsigned:
            raise ConfigError(f"--gcs-sysid {self.gcs_sysid} is also in --accept-unsigned: its commands could then "
                              "be forged; a ground station the companion obeys must sign")
        if self.swing_input not in SWING_INPUTS:
            raise ConfigError(f"--swing-input: one of {', '.join(SWING_INPUTS)}, got {self.swing_input!r}")
