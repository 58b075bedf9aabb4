"""``slungpilot fly``: load a mission, optionally start the bundled vehicle, fly, write the run folder.

Run folder (default ``runs/<UTC time>-<mission>-<planner>-<controller>/``): ``report.json``,
``summary.txt``, ``flight.tlog`` (every MAVLink frame in and out), ``flight_log.npz`` (per-tick arrays),
``plan.png``, ``timeseries.png``, ``trajectory3d.png``; with ``--sitl`` also ``vehicle.toml`` and
``sitl.log`` (the vehicle's own log), ``recording.rrd`` (the Rerun recording; ``--view`` shows it live).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import dataclasses
import logging
import os
import signal
import socket
import sys
import time
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from companion.autopilots.profile import profile_by_name
from companion.cli.fly_args import DEFAULT_GAINS, EXIT_CODES
from companion.cli.narrate import Narrator
from companion.cli.viz_cmds import flight_view
from companion.config import resolve_mission
from companion.control.params import ControllerConfig, load_controller_config
from companion.core.mission import Mission, load_mission
from companion.errors import ConfigError, LinkError
from companion.flight.app import FlightApp, FlyOptions
from companion.flight.scheduling import RT_PRIORITY_MAX
from companion.mavlink_io.signing import load_key_file
from companion.report.run_folder import write_run
from companion.zenoh_io.session import zenoh_config_from_args
from companion.zenoh_io.telemetry import TelemetryOptions, ZenohTelemetry, ZenohTelemetrySink, parse_rates

log = logging.getLogger(__name__)



@dataclass
class FlyResult:
    """What a flight produced."""

    outcome: str
    report: dict[str, Any]
    run_dir: Path


def load_gains(path: Path | None) -> ControllerConfig:
    """Controller/planner gains from TOML (defaults when the file is absent and was not asked for)."""
    if path is None or (path == DEFAULT_GAINS and not path.exists()):
        return ControllerConfig()
    return load_controller_config(path)


def mission_from_args(args: argparse.Namespace) -> Mission:
    """The mission file with CLI overrides applied; ConfigError (exit 2) when it is broken."""
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


def new_run_dir(mission: Mission, root: Path = Path("runs")) -> Path:
    """A fresh run folder ``runs/<UTC time to the ms>-<mission>-<planner>-<controller>[-k]``: created here,
    exclusively, so two flights started at the same moment never share one."""
    stamp = datetime.now(UTC).strftime("%Y%m%d-%H%M%S-%f")[:-3]
    base = f"{stamp}-{mission.name}-{mission.planner}-{mission.controller}"
    root.mkdir(parents=True, exist_ok=True)
    for k in range(1000):
        d = root / (base if k == 0 else f"{base}-{k + 1}")
        try:
            d.mkdir()
            return d
        except FileExistsError:
            continue
    raise ConfigError(f"{root}: cannot create a new run folder for {base}")


def check_ports_free(args: argparse.Namespace) -> None:
    """Fail before anything starts, with one line, when a port this flight must listen on is taken."""
    from companion.mavlink_io.link import LinkUrl

    checks: list[tuple[int, str, int, str]] = []
    if not args.sitl:
        url = LinkUrl.parse(args.connect)
        if url.mode == "udpin":
            checks.append((socket.SOCK_DGRAM, url.host, url.port, f"MAVLink port {url.port} ({args.connect})"))
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
    if args.connect is None:
        args.connect = f"udpin://0.0.0.0:{14540 + n}"
    if args.payload_sysid is None:
        args.payload_sysid = 200 + n if (args.sitl and n > 0) else 2
    if not args.no_zenoh and args.zenoh_config is None and not args.zenoh_listen and not args.zenoh_connect:
        args.zenoh_listen = [f"tcp/127.0.0.1:{7447 + n}"]


async def fly_async(args: argparse.Namespace, mission: Mission) -> FlyResult:
    """Fly ``mission`` as the parsed ``args`` say; always writes the run folder, even after Ctrl-C."""
    apply_instance(args)
    check_ports_free(args)
    if args.run_dir is not None:
        run_dir = args.run_dir
        run_dir.mkdir(parents=True, exist_ok=True)
    else:
        run_dir = new_run_dir(mission)
    profile_name = args.profile or ("bundled" if args.sitl else None)
    try:
        profile = profile_by_name(profile_name, args.hover_thrust) if profile_name else None
        if args.hover_thrust is not None:
            profile_by_name("px4", args.hover_thrust)  # validates the value even when the profile comes later
    except ValueError as exc:
        raise ConfigError(f"--hover-thrust/--profile: {exc}") from None
    gains = load_gains(args.gains)
    opts = FlyOptions(
        connect=args.connect, rate_hz=args.rate_hz, lockstep=args.lockstep or (args.sitl and not args.realtime),
        profile=profile, hover_thrust_norm=args.hover_thrust, gains=gains, payload_sysid=args.payload_sysid,
        swing_input=args.swing_input, heartbeat_timeout_s=args.heartbeat_timeout,
        ready_timeout_s=args.ready_timeout, land_on_abort=not args.no_land_on_abort,
        tlog_path=run_dir / "flight.tlog", run_dir=run_dir, allow_param_writes=not args.no_param_writes,
        start_here=args.start_here, rt_priority=args.rt_priority,
        signing_key=None if args.signing_key is None else load_key_file(args.signing_key),
        inject_tick_error_at_s=_env_float("SLUNGPILOT_INJECT_TICK_ERROR_AT_S"),
    )
    if opts.rate_hz <= 0 or opts.rate_hz > 2000:
        raise ConfigError(f"--rate-hz: must be in (0, 2000], got {opts.rate_hz}")
    if not 0 <= opts.rt_priority <= RT_PRIORITY_MAX:
        raise ConfigError(f"--rt-priority: must be in 0..{RT_PRIORITY_MAX} (0 = normal scheduling), got "
                          f"{opts.rt_priority}")
    wall0 = time.monotonic()
    stack = contextlib.AsyncExitStack()
    view = flight_view(args, mission, run_dir)  # recording.rrd, and the live viewer with --view
    zt_holder: list[ZenohTelemetry] = []
    if not args.no_zenoh:
        zcfg = zenoh_config_from_args(args, "companion")  # flag errors before anything starts
        try:
            rates = parse_rates(getattr(args, "zenoh_rates", None))
        except ValueError as exc:
            raise ConfigError(f"--zenoh-rates: {exc}") from None

        async def connect_zenoh(app: FlightApp) -> None:
            """Open the Zenoh streams under the vehicle id (default: the autopilot's MAVLink system id)."""
            vid = args.vehicle_id or str(app.state.vehicle_sysid)
            zt = ZenohTelemetry(zcfg, TelemetryOptions(prefix=args.zenoh_prefix, vehicle_id=vid, **rates))
            await stack.enter_async_context(zt)
            zt_holder.append(zt)
            zt.set_config_provider(lambda: effective_config(app, args))
            app.sinks.append(ZenohTelemetrySink(zt, mission.vehicle.l, status_fn=status_of))
            if view is not None:
                view.sink.current_obstacles = lambda: zt.last_obstacles
            app.obstacle_source = zt.obstacle_source(mission.obstacles)
            app.obstacle_ingest = zt.ingest

        opts.on_connected = connect_zenoh
    app: FlightApp | None = None
    error: BaseException | None = None
    async with stack:
        if view is not None:
            stack.enter_context(view)
            opts.sinks.append(view.sink)
        if args.sitl:
            from companion.cli.sitl_launcher import SitlProcess

            period_args = ["--control-period-ms", str(round(1000.0 / opts.rate_hz))]
            if args.instance:
                period_args += ["--instance", str(args.instance)]
            if args.signing_key is not None:
                period_args += ["--signing-key", str(args.signing_key)]
            if opts.rt_priority and not opts.lockstep:  # the simulated autopilot at the same priority, as PX4's
                period_args += ["--rt-priority", str(opts.rt_priority)]
            sitl = await stack.enter_async_context(
                SitlProcess(mission, run_dir, lockstep=opts.lockstep, extra_args=period_args)
            )
            opts.connect = sitl.companion_url
            opts.sock = sitl.companion_sock
        opts.provisional = lambda a: run_options(a, args, mission, run_dir, zt_holder)
        if not getattr(args, "quiet", False):
            opts.sinks.append(Narrator(lockstep=opts.lockstep))
        app = FlightApp(mission, opts)
        loop = asyncio.get_running_loop()
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.add_signal_handler(signal.SIGINT, app.request_abort)
            loop.add_signal_handler(signal.SIGTERM, app.request_abort, "terminated (SIGTERM)")
        try:
            await app.run()
        except Exception as exc:  # still write what we have, then re-raise
            error = exc
        finally:
            with contextlib.suppress(NotImplementedError, RuntimeError):
                loop.remove_signal_handler(signal.SIGINT)
                loop.remove_signal_handler(signal.SIGTERM)
    wall = time.monotonic() - wall0
    extra = app.run_facts()
    if error is not None:
        extra["outcome"] = "error"
        extra["outcome_detail"] = str(error)
    extra.update(run_options(app, args, mission, run_dir, zt_holder))
    extra["wall_time_s"] = wall
    app.log.wall_time_s = wall
    seen = app.obstacles_seen
    if seen:
        app.log.obstacles = seen  # live obstacles count for clearance and collisions too
    if view is not None:
        extra["recording"] = view.stats()
    report = write_run(app.log, mission, extra, run_dir, args.report, plots=not args.no_plots)
    if error is not None:
        raise error
    return FlyResult(app.outcome, report, run_dir)


def run_options(app: FlightApp, args: argparse.Namespace, mission: Mission, run_dir: Path,
                zt_holder: list[ZenohTelemetry]) -> dict[str, Any]:
    """The run's settings for the report (and the journal's provisional report)."""
    out: dict[str, Any] = {
        "swing_input": app.opts.swing_input,
        "profile": app.profile.name,
        "hover_thrust_norm": app.profile.hover_thrust_norm,
        "lockstep": app.opts.lockstep,
        "connect": app.opts.connect,
        "run_dir": str(run_dir),
        "tlog": str(run_dir / "flight.tlog"),
        "vehicle": mission.vehicle.as_dict(),
    }
    if app.profile.name == "bundled":  # the mission's wind is the bundled vehicle's simulation; a real one has its own
        out["wind"] = {"model": mission.wind.model, "scale": mission.wind.scale}
    if zt_holder:
        zt = zt_holder[0]
        out["zenoh"] = {"keys_prefix": f"{args.zenoh_prefix}/{zt.options.vehicle_id}", "published": dict(zt.seq),
                        "obstacles_in_accepted": zt.store.accepted_count,
                        "obstacles_in_rejected": zt.store.rejected_count,
                        "obstacles_in_unchanged": zt.unchanged, "obstacles_in_superseded": zt.superseded,
                        "obstacles_in_ring_full": zt.ring_full}
    return out


def status_of(app: FlightApp) -> dict[str, Any]:
    """The 1 Hz status sample: mode, armed, link health, mission progress, rejected-input counters."""
    est = app.state
    progress = None
    if est.pos_ned_m is not None:
        goal = app.mission.goal_ned_m
        progress = {"distance_to_goal_m": float(((est.pos_ned_m[0] - goal[0]) ** 2
                                                 + (est.pos_ned_m[1] - goal[1]) ** 2) ** 0.5),
                    "core_phase": app.core.phase}
    return {
        "mode": est.mode_name, "armed": est.armed, "phase": app.phase, "outcome": app.outcome,
        "link": {"heartbeats": est.heartbeats, "received": app.link.received, "sent": app.link.sent,
                 "vehicle_time_s": est.t_s},
        "progress": progress,
        "rejected_input": {"mavlink": dict(app.link.rejected)},
        "ticks": app.stats.ticks,
        "loop_lag_ms": None if app.core.loop_lag.lag_s is None else round(app.core.loop_lag.lag_s * 1e3, 1),
        "ff_lag_trust": round(app.core.lag_trust, 3),
    }


def effective_config(app: FlightApp, args: argparse.Namespace) -> dict[str, Any]:
    """What the ``config`` queryable answers: the effective mission, vehicle and controller parameters."""
    m = app.mission
    return {
        "mission": {"name": m.name, "start_ned_m": list(map(float, m.start_ned_m)),
                    "goal_ned_m": list(map(float, m.goal_ned_m)), "planner": m.planner, "controller": m.controller,
                    "timeout_s": m.timeout_s, "hold_s": m.hold_s, "land": m.land, "source": m.source_path,
                    "wind": {"model": m.wind.model, "scale": m.wind.scale},
                    "obstacles": [o.as_dict() for o in m.obstacles]},
        "vehicle": m.vehicle.as_dict(),
        "controller": dataclasses.asdict(app.core.cfg),
        "profile": {"name": app.profile.name, "hover_thrust_norm": app.profile.hover_thrust_norm},
        "rate_hz": app.opts.rate_hz, "lockstep": app.opts.lockstep, "connect": app.opts.connect,
        "swing_input": app.opts.swing_input,
    }


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
