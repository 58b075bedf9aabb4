"""Fly one :class:`~companion.launch.spec.FlySpec`: start the bundled vehicle when asked, open Zenoh and the
recording, run the pilot under the lockstep or the real-time runner, and always write the run folder (even after
Ctrl-C or an error: then the error is raised after the folder is written)."""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
import math
import signal
import threading
import time
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from companion.config import shipped_config
from companion.control.params import ControllerConfig, load_controller_config
from companion.core.mission import Mission
from companion.core.payload_check import check_payload_clears_ground, thrust_margin
from companion.errors import ConfigError
from companion.flight.lockstep import LockstepRunner
from companion.flight.pilot import Pilot
from companion.flight.realtime import RealtimeRunner
from companion.flight.runner import Runner, Wiring
from companion.flight.scheduling import pin_to_one_cpu, restore_affinity
from companion.launch.narrate import Narrator
from companion.launch.spec import DEFAULT_GAINS_NAME, FlySpec
from companion.proclife import signals_handled
from companion.report.run_folder import write_run

log = logging.getLogger(__name__)

DEFAULT_GAINS = shipped_config(DEFAULT_GAINS_NAME)


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


def fly_mission_sync(spec: FlySpec, mission: Mission) -> FlyResult:
    """:func:`fly_mission` for callers without an event loop (``lab``'s workers)."""
    return asyncio.run(fly_mission(spec, mission))


async def fly_mission(spec: FlySpec, mission: Mission) -> FlyResult:
    """Fly ``mission`` as ``spec`` says; always writes the run folder, even after Ctrl-C."""
    spec.setup.validate()
    run_dir = spec.run_dir or new_run_dir(mission)
    run_dir.mkdir(parents=True, exist_ok=True)
    unfit = _payload_refusal(spec, mission, run_dir)  # before anything starts or takes off
    if unfit is not None:
        return unfit
    setup = replace(spec.setup, tlog_path=run_dir / "flight.tlog", run_dir=run_dir)
    wall0 = time.monotonic()
    zt_holder: list[Any] = []
    runner: Runner | None = None
    error: BaseException | None = None
    refusal: Any = None  # the autopilot's mission refused before take-off (fly --mission autopilot)
    am_facts: dict[str, Any] | None = None
    sitl: Any = None  # the bundled vehicle's process (fly --sitl)
    view = spec.view(mission, run_dir) if spec.view is not None else None
    with contextlib.ExitStack() as sync_stack:
        async with contextlib.AsyncExitStack() as stack:
            wiring = Wiring(provisional=lambda r: run_options(r, spec, run_dir, zt_holder))
            if view is not None:
                sync_stack.enter_context(view)
                wiring.sinks.append(view.sink)
            if spec.zenoh is not None:
                wiring.on_connected = _zenoh_hook(spec, mission, sync_stack, zt_holder, view)
            if spec.sitl:
                warming = _warm_planner_beside(mission)  # before the pin: on the other CPU, while the vehicle starts
                if setup.lockstep and spec.pin_lockstep:  # the vehicle inherits it; undone when the flight ends
                    cpu, old_affinity = pin_to_one_cpu()
                    stack.callback(restore_affinity, old_affinity)
                    if cpu is not None:
                        log.info("lockstep: companion and vehicle pinned to CPU %d", cpu)
                setup, sitl = await _start_sitl(spec, setup, mission, run_dir, stack)
                if warming is not None:
                    warming.join()
            if spec.narrate:
                wiring.sinks.append(Narrator(lockstep=setup.lockstep))
            if spec.autopilot_mission:  # before the pilot: its route and fence are what the autopilot holds
                mission, refusal, am_facts, setup = _fetch_autopilot_mission(spec, setup, mission, run_dir)
            pilot = Pilot(mission, setup)
            try:
                if setup.lockstep:
                    runner = LockstepRunner(pilot, wiring)
                    if refusal is None:
                        _run_blocking(runner)
                else:
                    runner = RealtimeRunner(pilot, wiring)
                    if refusal is None:
                        await _run_async(runner)
            except Exception as exc:  # still write what we have, then re-raise
                error = exc
    assert runner is not None
    report = _write_report(runner, spec, mission, run_dir, zt_holder, view, time.monotonic() - wall0, error,
                           refusal, am_facts, None if sitl is None else sitl.facts())
    if error is not None:
        raise error
    return FlyResult(runner.outcome if refusal is None else refusal.outcome, report, run_dir)


def _fetch_autopilot_mission(spec: FlySpec, setup: Any, mission: Mission,
                             run_dir: Path) -> tuple[Mission, Any, dict[str, Any], Any]:
    """``--mission autopilot``: the mission to fly, the refusal (None when it can be flown), the report's facts and
    the set-up with its mission frame pinned to the download's home (:mod:`companion.launch.autopilot_mission`)."""
    from companion.launch.autopilot_mission import Refusal, fetch_autopilot_mission, pinned_setup

    bundled = spec.sitl or (setup.profile is not None and setup.profile.name == "bundled")
    try:
        flown, facts = fetch_autopilot_mission(setup, mission, bundled=bundled, run_dir=run_dir)
    except Refusal as r:
        log.error("the autopilot's mission is not flown: %s", r.detail)
        return mission, r, {"refused": r.detail, **r.facts}, setup
    return flown, None, facts, pinned_setup(setup, facts)


def _warm_planner_beside(mission: Mission) -> threading.Thread | None:
    """Load the shaped planner's compiled kernels (:func:`companion.planning.candidates.warm_up`) in a thread
    while the bundled vehicle starts; the thread is started before the lockstep pin, so it runs on the other CPU.
    The pilot's own warm-up then finds them loaded (~0.4 s off ``fly --sitl --planner shaped``)."""
    if mission.planner != "shaped":
        return None

    def warm() -> None:
        try:
            from companion.planning.candidates import warm_up

            warm_up()
        except Exception:  # the pilot warms up again, and reports what fails there
            log.exception("warming the shaped planner up beside the vehicle's start failed")

    thread = threading.Thread(target=warm, name="planner-warm-up", daemon=True)
    thread.start()
    return thread


async def _start_sitl(spec: FlySpec, setup: Any, mission: Mission, run_dir: Path,
                      stack: contextlib.AsyncExitStack) -> tuple[Any, Any]:
    """Start the bundled vehicle on free local ports; the set-up with its link, and the vehicle's process."""
    from companion.launch.sitl import SitlProcess

    extra = ["--control-period-ms", str(round(1000.0 / setup.rate_hz)), *spec.sitl_args]
    if spec.world is not None:  # written into the run folder: the flight's record of the world it flew in
        from companion.core.world import world_to_toml

        wfile = run_dir / "world.toml"
        wfile.write_text(world_to_toml(spec.world.name, spec.world.trunks))
        extra += ["--world", str(wfile.resolve())]
    if setup.rt_priority and not setup.lockstep:  # the simulated autopilot at the same priority, as PX4's
        extra += ["--rt-priority", str(setup.rt_priority)]
    sitl = await stack.enter_async_context(SitlProcess(mission, run_dir, lockstep=setup.lockstep, extra_args=extra,
                                                       serial=spec.sitl_serial, fork=spec.vehicle_fork))
    return replace(setup, connect=sitl.companion_url, sock=sitl.companion_sock), sitl


def _payload_refusal(spec: FlySpec, mission: Mission, run_dir: Path) -> FlyResult | None:
    """Outcome ``refused`` (the run folder written, nothing started) when the declared payload leaves the vehicle
    too little thrust margin, or would hang too close to the ground on the route
    (:mod:`companion.core.payload_check`); None when it may fly."""
    from companion.report.metrics import FlightLog

    margin = thrust_margin(mission.companion_params())
    detail = None if margin.ok else margin.detail()
    if detail is None:
        try:
            check_payload_clears_ground(mission)
        except ConfigError as exc:
            detail = f"refused before take-off: {exc}"
    if detail is None:
        return None
    log.error("%s", detail)
    flog = FlightLog(planner=mission.planner, controller=mission.controller, mission=mission.name,
                     obstacles=mission.obstacles)
    extra = {"outcome": "refused", "outcome_detail": detail, "final_phase": "not_started",
             "thrust_margin": margin.as_dict()}
    return FlyResult("refused", write_run(flog, mission, extra, run_dir, spec.report, plots=False), run_dir)


def _run_blocking(runner: LockstepRunner) -> None:
    """The lockstep runner on this thread; Ctrl-C and SIGTERM abort the mission (hold, land) meanwhile."""
    def on_signal(signum: int, _frame: Any) -> None:
        runner.request_abort("terminated (SIGTERM)" if signum == signal.SIGTERM else "operator abort (Ctrl-C)")

    with signals_handled(on_signal, signal.SIGINT, signal.SIGTERM):  # off the main thread: its owner stops it
        runner.run()


async def _run_async(runner: RealtimeRunner) -> None:
    loop = asyncio.get_running_loop()
    with contextlib.suppress(NotImplementedError, RuntimeError):
        loop.add_signal_handler(signal.SIGINT, runner.request_abort)
        loop.add_signal_handler(signal.SIGTERM, runner.request_abort, "terminated (SIGTERM)")
    try:
        await runner.run()
    finally:
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.remove_signal_handler(signal.SIGINT)
            loop.remove_signal_handler(signal.SIGTERM)


def _zenoh_hook(spec: FlySpec, mission: Mission, stack: contextlib.ExitStack, zt_holder: list[Any],
                view: Any) -> Any:
    """``on_connected``: open the Zenoh streams under the vehicle id (default: the autopilot's system id)."""
    from companion.zenoh_io.telemetry import ZenohTelemetry
    from companion.zenoh_io.telemetry_options import TelemetryOptions
    from companion.zenoh_io.telemetry_sink import ZenohTelemetrySink

    z = spec.zenoh
    assert z is not None

    def connect(run: Runner) -> None:
        vid = z.vehicle_id or str(run.pilot.state.vehicle_sysid)
        zt = ZenohTelemetry(z.config, TelemetryOptions(prefix=z.prefix, vehicle_id=vid, **z.rates))
        stack.enter_context(zt)
        zt_holder.append(zt)
        if spec.config_facts is not None:
            zt.set_config_provider(lambda: spec.config_facts(run))
        run.sinks.append(ZenohTelemetrySink(zt, mission.vehicle.l, status_fn=status_of))
        if view is not None:
            view.sink.current_obstacles = lambda: zt.last_obstacles
        scans = _scan_input(zt, run, z.prefix, vid)
        zt_holder.append(scans)

        def ingest(t_s: float) -> None:  # live obstacles, then the scans that wait (issue 26)
            zt.ingest(t_s)
            scans.drain()

        run.use_obstacle_input(zt.obstacle_source(mission.obstacles), ingest)

    return connect


def _scan_input(zt: Any, run: Runner, prefix: str, vid: str) -> Any:
    """The scans on Zenoh (the project's stream and ROS 2's LaserScan) into the pilot's perception map."""
    from companion.zenoh_io.scan_input import ScanInput

    return ScanInput(zt.session, run.pilot.on_scan, prefix=prefix, vehicle_id=vid)


def _write_report(runner: Runner, spec: FlySpec, mission: Mission, run_dir: Path, zt_holder: list[Any], view: Any,
                  wall: float, error: BaseException | None, refusal: Any = None,
                  am_facts: dict[str, Any] | None = None, sitl_facts: dict[str, Any] | None = None) -> dict[str, Any]:
    extra = runner.run_facts()
    if sitl_facts is not None:  # the bundled vehicle as the flight's end found it: gone quiet, or gone
        extra["sitl_vehicle"] = sitl_facts
    if error is not None:
        extra["outcome"] = "error"
        extra["outcome_detail"] = str(error)
    elif refusal is not None:  # refused before take-off: nothing flown
        extra["outcome"] = refusal.outcome
        extra["outcome_detail"] = refusal.detail
    if am_facts is not None:
        extra["autopilot_mission"] = am_facts
        _home_shift(am_facts, runner)
    extra.update(run_options(runner, spec, run_dir, zt_holder, final=True))
    extra["wall_time_s"] = wall
    flog = runner.pilot.record.log
    flog.wall_time_s = wall
    seen = runner.obstacles_seen
    if spec.world is not None:  # the trunks that really stood there: the truth, whatever the flight knew of them
        flog.obstacles = tuple(spec.world.trunks)
        extra["obstacle_truth"] = f"world:{spec.world.name}"
    elif seen:
        flog.obstacles = seen  # live obstacles count for clearance and collisions too
    if view is not None:
        extra["recording"] = view.stats()
    return write_run(flog, mission, extra, run_dir, spec.report, plots=spec.plots)


def _home_shift(am_facts: dict[str, Any], runner: Runner) -> None:
    """``--mission autopilot``: how far (m, the autopilot's local NED) the mission frame the flight fixed lies from
    the home its route was placed about (``home_shift_m``; the autopilot moved home in between: the route flew
    shifted by that much; north and east 0 once the frame is pinned to that home), warned about above 0.5 m
    horizontally; with a pinned frame also ``home_moved_m``: how far the autopilot's own home moved by then (the
    route's north and east did not follow it)."""
    home = (am_facts.get("home") or {}).get("local_ned_m")
    frame = runner.pilot.frame
    if home is None or not frame.fixed:
        return
    shift = [float(o - h) for o, h in zip(frame.origin_ned_m, home, strict=True)]
    am_facts["home_shift_m"] = shift
    if frame.home_at_fix_ned_m is not None:  # pinned: how far the autopilot moved home, the route did not follow
        am_facts["home_moved_m"] = [float(a - h) for a, h in zip(frame.home_at_fix_ned_m, home, strict=True)]
    if math.hypot(*shift[:2]) > 0.5:
        log.warning("the autopilot moved home %.2f m after its mission was downloaded: the route flew shifted by "
                    "that much (report: autopilot_mission.home_shift_m)", math.hypot(*shift[:2]))


def run_options(run: Runner, spec: FlySpec, run_dir: Path, zt_holder: list[Any], final: bool = False) -> dict[str, Any]:
    """The run's settings for the report (``final``) and the journal's provisional report (each second)."""
    s, m, profile = run.setup, run.pilot.mission, run.pilot.profile
    out: dict[str, Any] = {
        "swing_input": s.swing_input,
        "profile": profile.name,
        "hover_thrust_norm": profile.hover_thrust_norm,
        "lockstep": s.lockstep,
        "simulated": spec.sitl,  # the bundled vehicle was started by this flight, in the mission's world and wind
        "connect": s.connect,
        "run_dir": str(run_dir),
        "tlog": str(run_dir / "flight.tlog"),
        "vehicle": m.vehicle.as_dict(),
        "thrust_margin": thrust_margin(m.companion_params()).as_dict(),
    }
    declared = m.companion_params()
    true_payload = _true_payload(spec.sitl_args) if spec.sitl else {}
    if true_payload:  # the bundled vehicle flies another payload than the mission declares (issue 28)
        out["payload_declared"] = {"mass_kg": declared.m, "cable_length_m": declared.l}
        out["payload_true"] = true_payload
    # identified after the flight only (the provisional report each second gives what is already computed)
    ident = run.pilot.identification
    out["payload"] = ident.watch.facts(declared.m, declared.l, run=final and spec.identify_payload)
    if ident.used is not None:  # identified before the cruise ([payload] identify = true): what was flown
        out["payload"]["flown"] = ident.used
    if true_payload:
        out["payload"]["true"] = true_payload
    for line in out["payload"].get("mismatch", []) if final else []:
        log.warning("the payload is not what the mission declares: %s", line)
    if spec.sitl:  # the vehicle this flight started flies the mission's wind; any other, its own
        out["wind"] = dataclasses.asdict(m.wind) if m.wind.is_physical else {"model": m.wind.model,
                                                                             "scale": m.wind.scale}
    if zt_holder:
        zt = zt_holder[0]
        prefix = spec.zenoh.prefix if spec.zenoh is not None else "slungpilot"
        out["zenoh"] = {"keys_prefix": f"{prefix}/{zt.options.vehicle_id}", "published": dict(zt.seq),
                        "obstacles_in_accepted": zt.store.accepted_count,
                        "obstacles_in_rejected": zt.store.rejected_count,
                        "obstacles_in_unchanged": zt.unchanged, "obstacles_in_superseded": zt.superseded,
                        "obstacles_in_ring_full": zt.ring_full}
        if len(zt_holder) > 1:
            out["zenoh"]["scans_in"] = zt_holder[1].facts()
    return out


def _true_payload(sitl_args: tuple[str, ...]) -> dict[str, float]:
    """The bundled vehicle's true payload from its flags (``--payload-mass-kg``, ``--cable-length-m``), if given."""
    keys = {"--payload-mass-kg": "mass_kg", "--cable-length-m": "cable_length_m"}
    args = list(sitl_args)
    return {keys[a]: float(args[i + 1]) for i, a in enumerate(args[:-1]) if a in keys}


def status_of(run: Runner) -> dict[str, Any]:
    """The 1 Hz status sample: mode, armed, link health, mission progress, rejected-input counters."""
    from companion.flight.facts import status_facts

    out = status_facts(run.pilot)
    out["link"] = {"heartbeats": run.pilot.state.heartbeats, "received": run.link.received, "sent": run.link.sent,
                   "vehicle_time_s": run.pilot.state.t_s}
    out["rejected_input"] = {"mavlink": dict(run.link.rejected)}
    out["ticks"] = run.stats.ticks
    return out


def effective_config(run: Runner) -> dict[str, Any]:
    """What the ``config`` queryable answers: the effective mission, vehicle and controller parameters."""
    m, s = run.pilot.mission, run.setup
    return {
        "mission": {"name": m.name, "start_ned_m": list(map(float, m.start_ned_m)),
                    "goal_ned_m": list(map(float, m.goal_ned_m)), "planner": m.planner, "controller": m.controller,
                    "timeout_s": m.timeout_s, "hold_s": m.hold_s, "land": m.land, "source": m.source_path,
                    "wind": {"model": m.wind.model, "scale": m.wind.scale},
                    "obstacles": [o.as_dict() for o in m.obstacles]},
        "vehicle": m.vehicle.as_dict(),
        "controller": dataclasses.asdict(run.pilot.core.cfg),
        "profile": {"name": run.pilot.profile.name, "hover_thrust_norm": run.pilot.profile.hover_thrust_norm},
        "rate_hz": s.rate_hz, "lockstep": s.lockstep, "connect": s.connect, "swing_input": s.swing_input,
    }
