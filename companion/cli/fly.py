"""``slungpilot fly``: load a mission, optionally start the bundled vehicle, fly, write the run folder.

Run folder (default ``runs/<UTC time>-<mission>-<planner>-<controller>/``): ``report.json``,
``summary.txt``, ``flight.tlog`` (every MAVLink frame in and out), ``flight_log.npz`` (per-tick arrays),
``plan.png``, ``timeseries.png``, ``trajectory3d.png``; with ``--sitl`` also ``vehicle.toml`` and
``sitl.log`` (the vehicle's own log), ``recording.rrd`` (the Rerun recording; ``--view`` shows it live).
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import os
import socket
import sys
from typing import Any

from companion.autopilots.profile import profile_by_name
from companion.cli.fly_args import DEFAULT_MISSION, EXIT_CODES
from companion.cli.viz_cmds import flight_view
from companion.config import resolve_mission
from companion.core.mission import Mission, load_mission
from companion.errors import ConfigError, LinkError
from companion.flight.scheduling import RT_PRIORITY_MAX
from companion.flight.setup import FlightSetup
from companion.launch.fly import DEFAULT_GAINS, FlyResult, effective_config, fly_mission, load_gains, new_run_dir
from companion.launch.spec import FlySpec, ZenohSpec
from companion.mavlink_io.signing import load_key_file
from companion.zenoh_io.session import zenoh_config_from_args
from companion.zenoh_io.telemetry_options import parse_rates

__all__ = ["DEFAULT_GAINS", "FlyResult", "fly_async", "load_gains", "mission_from_args", "new_run_dir", "run_fly",
           "spec_from_args"]

log = logging.getLogger(__name__)

AUTOPILOT_MISSION = "autopilot"  # --mission autopilot: fly the mission uploaded to the autopilot



def mission_from_args(args: argparse.Namespace) -> Mission:
    """The mission file with CLI overrides applied; ConfigError (exit 2) when it is broken."""
    base = getattr(args, "base_mission", None)
    if args.mission == AUTOPILOT_MISSION:  # the route comes from the autopilot; the rest from the base mission
        mission = load_mission(resolve_mission(base or str(DEFAULT_MISSION)))
    elif base is not None:
        raise ConfigError("--base-mission: only with --mission autopilot")
    else:
        mission = load_mission(resolve_mission(args.mission))
    changes: dict[str, Any] = {}
    if args.planner:
        changes["planner"] = args.planner
    if args.controller:
        changes["controller"] = args.controller
    if args.no_land:
        changes["land"] = False
    return mission.with_(**changes) if changes else mission


def _env_float(name: str) -> float | None:
    """A float from the environment (fault-injection hooks of the fault suite); None when unset."""
    raw = os.environ.get(name)
    if raw is None or raw == "":
        return None
    try:
        return float(raw)
    except ValueError:
        raise ConfigError(f"{name}: expected a number, got {raw!r}") from None


def check_ports_free(args: argparse.Namespace) -> None:
    """Fail before anything starts, with one line, when a port this flight must listen on is taken."""
    from companion.mavlink_io.link import LinkUrl

    checks: list[tuple[int, str, int, str]] = []
    if not args.sitl:
        url = LinkUrl.parse(args.connect)
        if url.mode in ("udpin", "tcpin"):
            kind = socket.SOCK_DGRAM if url.mode == "udpin" else socket.SOCK_STREAM
            checks.append((kind, url.host, url.port, f"MAVLink port {url.port} ({args.connect})"))
    if not args.no_zenoh and args.zenoh_config is None:
        for ep in args.zenoh_listen:
            proto, _, hostport = ep.partition("/")
            host, _, port = hostport.rpartition(":")
            if proto == "tcp" and port.isdigit():
                checks.append((socket.SOCK_STREAM, host.strip("[]"), int(port), f"Zenoh port {port} ({ep})"))
    for kind, host, port, what in checks:
        with socket.socket(socket.AF_INET, kind) as s:
            try:
                s.bind((host, port))
            except OSError as exc:
                raise LinkError(f"{what} is in use ({exc.strerror}): another slungpilot fly or autopilot link? "
                                "Give it --instance N (ports +N), or other --connect/--zenoh-listen ports") from None


def apply_instance(args: argparse.Namespace) -> None:
    """``--instance N`` and the defaults it shifts; ``--connect`` with ``--sitl`` is refused."""
    n = args.instance
    if not 0 <= n <= 54:
        raise ConfigError(f"--instance: must be in 0..54, got {n}")
    if args.sitl and args.connect is not None:
        raise ConfigError("--connect: not with --sitl (the bundled vehicle is started on free local ports; "
                          "to fly a vehicle you started yourself, leave out --sitl)")
    if getattr(args, "serial", False) and not args.sitl:
        raise ConfigError("--serial: only with --sitl (a serial autopilot: --connect serial://DEVICE:BAUD)")
    if args.connect is None:
        args.connect = f"udpin://0.0.0.0:{14540 + n}"
    if args.payload_sysid is None:
        args.payload_sysid = 200 + n if (args.sitl and n > 0) else 2
    if not args.no_zenoh and args.zenoh_config is None and not args.zenoh_listen and not args.zenoh_connect:
        args.zenoh_listen = [f"tcp/127.0.0.1:{7447 + n}"]


def spec_from_args(args: argparse.Namespace, mission: Mission) -> FlySpec:
    """The typed flight run the parsed flags describe (``--instance`` applied; ports checked free)."""
    apply_instance(args)
    check_ports_free(args)
    profile_name = args.profile or ("bundled" if args.sitl else None)
    try:
        profile = profile_by_name(profile_name, args.hover_thrust) if profile_name else None
        if args.hover_thrust is not None:
            profile_by_name("px4", args.hover_thrust)  # validates the value even when the profile comes later
    except ValueError as exc:
        raise ConfigError(f"--hover-thrust/--profile: {exc}") from None
    setup = FlightSetup(
        connect=args.connect, rate_hz=args.rate_hz, lockstep=args.lockstep or (args.sitl and not args.realtime),
        profile=profile, hover_thrust_norm=args.hover_thrust, gains=load_gains(args.gains),
        payload_sysid=args.payload_sysid, swing_input=args.swing_input, heartbeat_timeout_s=args.heartbeat_timeout,
        ready_timeout_s=args.ready_timeout, land_on_abort=not args.no_land_on_abort,
        allow_param_writes=not args.no_param_writes, start_here=args.start_here, rt_priority=args.rt_priority,
        signing_key=None if args.signing_key is None else load_key_file(args.signing_key),
        accept_unsigned=tuple(args.accept_unsigned), gcs_sysid=args.gcs_sysid,
        inject_tick_error_at_s=_env_float("SLUNGPILOT_INJECT_TICK_ERROR_AT_S"),
        perception={"auto": None, "on": True, "off": False}[getattr(args, "perception", "auto")],
        scored_cable_m=getattr(args, "true_cable_length_m", None) if args.sitl else None,
    )
    setup.validate(RT_PRIORITY_MAX)
    sitl_args: list[str] = []
    if args.instance:
        sitl_args += ["--instance", str(args.instance)]
    if args.signing_key is not None:
        sitl_args += ["--signing-key", str(args.signing_key)]
    sitl_args += _true_payload_args(args)
    if getattr(args, "sitl_airmode", None) is not None:
        if not args.sitl:
            raise ConfigError("--sitl-airmode: only with --sitl (a real autopilot's MC_AIRMODE is its own parameter)")
        sitl_args += ["--airmode", str(args.sitl_airmode)]
    world = _world_from_args(args)
    zspec = None
    if not args.no_zenoh:
        zcfg = zenoh_config_from_args(args, "companion")  # flag errors before anything starts
        try:
            rates = parse_rates(getattr(args, "zenoh_rates", None))
        except ValueError as exc:
            raise ConfigError(f"--zenoh-rates: {exc}") from None
        zspec = ZenohSpec(zcfg, prefix=args.zenoh_prefix, vehicle_id=args.vehicle_id, rates=rates)
    if getattr(args, "no_recording", False) and getattr(args, "view", None):
        raise ConfigError("--view needs the recording: drop --no-recording")
    return FlySpec(
        setup=setup, sitl=args.sitl, sitl_args=tuple(sitl_args), sitl_serial=getattr(args, "serial", False),
        run_dir=args.run_dir, report=args.report,
        plots=not args.no_plots, narrate=not getattr(args, "quiet", False), zenoh=zspec,
        view=(lambda m, d: flight_view(args, m, d)) if not getattr(args, "no_recording", False) else None,
        config_facts=effective_config, autopilot_mission=args.mission == AUTOPILOT_MISSION, world=world,
        vehicle_fork=getattr(args, "vehicle_fork", None) if args.sitl else None,
    )


def _world_from_args(args: argparse.Namespace) -> Any:
    """``--world``: the simulated world (read and checked now: a broken file is exit 2 before anything starts), or
    None; only with ``--sitl`` (a real vehicle flies in the real world)."""
    if getattr(args, "world", None) is None:
        return None
    if not args.sitl:
        raise ConfigError("--world: only with --sitl (the bundled vehicle is the one that flies in a world)")
    from companion.core.world import load_world

    return load_world(args.world)


def _true_payload_args(args: argparse.Namespace) -> list[str]:
    """The bundled vehicle's flags for ``--true-payload-mass-kg`` / ``--true-cable-length-m`` (only with --sitl)."""
    out: list[str] = []
    for flag, value in (("--payload-mass-kg", getattr(args, "true_payload_mass_kg", None)),
                        ("--cable-length-m", getattr(args, "true_cable_length_m", None))):
        if value is None:
            continue
        if not args.sitl:
            raise ConfigError(f"--true{flag[1:]}: only with --sitl (a real vehicle carries what it carries)")
        if not (value > 0.0 and value < 100.0):
            raise ConfigError(f"--true{flag[1:]}: must be in (0, 100), got {value}")
        out += [flag, repr(float(value))]
    return out


async def fly_async(args: argparse.Namespace, mission: Mission) -> FlyResult:
    """Fly ``mission`` as the parsed ``args`` say; always writes the run folder, even after Ctrl-C."""
    return await fly_mission(spec_from_args(args, mission), mission)


def exit_code(outcome: str, reached_goal: bool) -> int:
    """The process exit code for a flight's outcome (see :data:`EXIT_CODES`)."""
    code = EXIT_CODES.get(outcome, 1)
    return 1 if code == 0 and not reached_goal else code


def run_fly(args: argparse.Namespace) -> int:
    """CLI entry: the flight's outcome as an exit code (:data:`EXIT_CODES`); 2 on config errors."""
    from companion.report.run_folder import summary_text

    mission = mission_from_args(args)
    result = asyncio.run(fly_async(args, mission))
    print(summary_text(result.report))
    if result.outcome != "completed":
        detail = result.report.get("outcome_detail") or ""
        where = f" on {result.report.get('connect')}" if result.outcome in ("no_vehicle", "link_lost") else ""
        print(f"slungpilot fly: {result.outcome}{where}: {detail}", file=sys.stderr)
    return exit_code(result.outcome, bool(result.report.get("reached_goal")))
