"""The ``slungpilot`` command line: one entry point, one subcommand per job.

This is the only module in ``companion`` that may reach into ``sim_bridge`` (to start the bundled vehicle
or benchmark it); everything else in the companion talks to a vehicle over MAVLink only.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from companion import __version__
from companion.errors import ConfigError, SlungpilotError
from companion.launch.dispatch import dispatch

log = logging.getLogger(__name__)


def _cmd_bench(args: argparse.Namespace) -> int:
    if args.target == "model":
        from companion.cli import bench_model

        print("slungpilot bench model: RK4 (1 kHz step) of the 8-DOF quadrotor-payload model, numba kernels")
        res = bench_model.run(seconds=args.seconds)
        print(f"  cold start (compile or load cache): {res.pop('cold_start_s'):8.3f} s")
        for k, v in res.items():
            print(f"  {k:32s} {v:14,.0f}")
        return 0
    if args.target == "fly":
        from companion.cli import bench_fly

        return bench_fly.print_bench(args.repeats, args.against, args.planner)
    if args.target == "sitl":
        from sim_bridge.bench import run_bench_sitl

        print("slungpilot bench sitl: lockstep vehicle (1 kHz physics) driven by a 250 Hz hover client over UDP")
        res = run_bench_sitl(args.seconds)
        for k, v in res.items():
            print(f"  {k:32s} {v}")
        return 0
    if args.target == "view":
        from companion.cli import bench_view

        return bench_view.print_bench(60.0 if args.seconds == 3.0 else args.seconds)
    if args.target == "zenoh":
        from companion.cli.zenoh_cmds import cmd_bench_zenoh

        return cmd_bench_zenoh(args.seconds)
    if args.target == "faults":
        import json
        import tempfile

        from lab.faults import SCENARIOS, run_fault_bench

        print("slungpilot bench faults: each fault against real processes on loopback (see tests/test_faults.py)")
        names = args.only.split(",") if args.only else list(SCENARIOS)
        with tempfile.TemporaryDirectory(prefix="slungpilot-faults-") as tmp:
            for name in names:
                r = run_fault_bench(Path(tmp), [name])[name]
                print(f"  {name}: " + json.dumps(r, default=str))
        return 0
    if args.target == "perception":
        from lab.bench_perception import print_bench as bench_perception

        return bench_perception()
    raise SlungpilotError(f"bench target {args.target!r} is not available in this build")


def _cmd_report(args: argparse.Namespace) -> int:
    from companion.report.journal import rebuild_run
    from companion.report.run_folder import summary_text

    if not (args.run_dir / "flight_log.journal").exists():
        raise ConfigError(f"{args.run_dir}: no flight_log.journal here (not a run folder of slungpilot fly?)")
    rep = rebuild_run(args.run_dir, plots=not args.no_plots)
    print(summary_text(rep))
    return 0


def _cmd_missions(args: argparse.Namespace) -> int:
    from companion.config import shipped_missions
    from companion.core.mission import load_mission

    for name, path in shipped_missions().items():
        m = load_mission(path)
        print(f"{name:12s} {len(m.obstacles):3d} obstacles, start {list(map(float, m.start_ned_m))} → goal "
              f"{list(map(float, m.goal_ned_m))} (NED m), planner {m.planner}, controller {m.controller}  {path}")
    return 0


def _cmd_fly(args: argparse.Namespace) -> int:
    from companion.cli.fly import run_fly

    return run_fly(args)


def _cmd_sitl(args: argparse.Namespace) -> int:
    from sim_bridge.cli import run_sitl

    return run_sitl(args)


def _add_fly(sub: Any) -> None:
    from companion.cli.fly_args import EXIT_HELP, add_fly_arguments

    fly = sub.add_parser(
        "fly", help=COMMANDS["fly"],
        description=(
            "Fly a mission file against an autopilot over MAVLink/UDP (PX4, ArduPilot) or, with --sitl, against "
            "the bundled vehicle started on free local ports (lockstep: as fast as possible, deterministic). "
            "Waits for the heartbeat, streams setpoints, arms, switches to OFFBOARD, climbs, flies to the goal, "
            "holds, lands, and writes a run folder: report.json, plots, flight.tlog. Ctrl-C holds, lands and "
            "still writes the report. Any failure (vehicle lost, someone else takes it, stale telemetry, failing "
            "ticks) ends in a hold, a landing or letting go as docs/companion.md describes, never a fall. "
            + EXIT_HELP
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_fly_arguments(fly)
    fly.set_defaults(func=_cmd_fly)


def _add_sitl(sub: Any) -> None:
    from sim_bridge.cli import add_sitl_arguments

    sitl = sub.add_parser(
        "sitl", help=COMMANDS["sitl"],
        description=(
            "The bundled software-in-the-loop vehicle: flies the paper's quadrotor-payload model with its own "
            "attitude loop and eq. 49 wind, and speaks MAVLink 2 like PX4's SITL (HEARTBEAT, telemetry, commands, "
            "OFFBOARD via SET_ATTITUDE_TARGET, params). See docs/sitl.md for messages and the lockstep handshake."
        ),
    )
    add_sitl_arguments(sitl)
    sitl.set_defaults(func=_cmd_sitl)


def _add_zenoh_tool(name: str) -> Callable[[Any], None]:
    def add(sub: Any) -> None:
        from companion.cli import zenoh_cmds

        {"listen": zenoh_cmds.add_listen_parser, "obstacles": zenoh_cmds.add_obstacles_parser,
         "zenoh-router": zenoh_cmds.add_router_parser}[name](sub)

    return add


def _add_viz_tool(name: str) -> Callable[[Any], None]:
    def add(sub: Any) -> None:
        from companion.cli import viz_cmds

        {"replay": viz_cmds.add_replay_parser, "view": viz_cmds.add_view_parser}[name](sub)

    return add


def _add_lab(name: str) -> Callable[[Any], None]:
    def add(sub: Any) -> None:
        from lab import cli as lab_cli

        {"experiments": lab_cli.add_experiments_parser, "evaluate": lab_cli.add_evaluate_parser}[name](sub)

    return add


def _add_report(sub: Any) -> None:
    report = sub.add_parser(
        "report", help=COMMANDS["report"],
        description="While flying, `fly` flushes the per-tick log (flight_log.journal) and a provisional report "
                    "(report.partial.json) to the run folder once a second. This rebuilds report.json, summary.txt, "
                    "flight_log.npz and the plots from them: a companion killed at any moment loses at most a "
                    "second. A run that never finished gets the outcome 'interrupted'.")
    report.add_argument("run_dir", type=Path, metavar="RUN_DIR", help="the run folder")
    report.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    report.set_defaults(func=_cmd_report)


def _add_keygen(sub: Any) -> None:
    keygen = sub.add_parser(
        "keygen", help=COMMANDS["keygen"],
        description="Write a new random 32-byte MAVLink 2 signing key as 64 hex characters into FILE (readable by "
                    "its owner only). Use it with `fly --signing-key FILE` (and `sitl --signing-key FILE`), and give "
                    "the same key to the autopilot with SETUP_SIGNING (docs/companion.md).")
    keygen.add_argument("file", type=Path, metavar="FILE", help="where to write the key (must not exist)")
    keygen.set_defaults(func=_cmd_keygen)


def _cmd_keygen(args: argparse.Namespace) -> int:
    from companion.mavlink_io.signing import write_new_key_file

    if args.file.exists():
        raise ConfigError(f"{args.file}: exists already; keys are not overwritten")
    write_new_key_file(args.file)
    print(f"wrote a new signing key to {args.file}")
    return 0


def _add_fleet(sub: Any) -> None:
    from companion.cli.fleet import add_fleet_arguments, run_fleet

    fleet = sub.add_parser(
        "fleet", help=COMMANDS["fleet"],
        description="N bundled vehicles and N companions flying at once through one Zenoh router (companions as "
                    "clients), with each vehicle's swing stream counted for loss; `slungpilot view --zenoh-connect "
                    "ENDPOINT` shows them all. Ctrl-C: every companion holds and lands.")
    add_fleet_arguments(fleet)
    fleet.set_defaults(func=run_fleet)


def _add_missions(sub: Any) -> None:
    missions = sub.add_parser("missions", help=COMMANDS["missions"],
                              description="The missions that ship with slungpilot, by name, with where they fly.")
    missions.set_defaults(func=_cmd_missions)


def _add_bench(sub: Any) -> None:
    bench = sub.add_parser(
        "bench", help=COMMANDS["bench"],
        description="Benchmarks that print numbers; nothing is asserted. Run on an idle machine.",
    )
    bench.add_argument(
        "target", choices=["model", "sitl", "fly", "zenoh", "faults", "view", "perception"],
        help="model: RK4 steps/s of the dynamics kernel; sitl: lockstep real-time factor of the bundled vehicle; "
             "fly: the forest mission end to end (real-time factor, tick p50/p99); zenoh: 250 Hz swing stream "
             "latency/loss between two processes and the cost per publish; faults: the fault suite's scenarios "
             "(vehicle killed, fuzz, tick exceptions, companion killed or paused, Zenoh flood, jitter) with their "
             "figures; "
             "view: the 3-D view's recording cost per tick and per minute of flight (--seconds of flight, "
             "default 60); perception: the cost per 360-ray scan of each stage (assembly, points, clusters, map) "
             "with 5, 20 and 50 trunks in view",
    )
    bench.add_argument("--only", default="", help="faults: comma-separated scenario names (default: all)")
    bench.add_argument("--seconds", type=float, default=3.0, help="measuring time per benchmark (s)")
    bench.add_argument("--repeats", type=int, default=2, help="fly: how many flights")
    bench.add_argument("--against", type=Path, default=None, metavar="DIR",
                       help="fly: also fly another checkout of slungpilot (PYTHONPATH=DIR), interleaved run by run")
    bench.add_argument("--planner", default=None, help="fly: override the forest mission's planner")
    bench.set_defaults(func=_cmd_bench)


#: Every subcommand: its one-line help (the listing of ``slungpilot --help``).
COMMANDS = {
    "fly": "fly a mission: plan around obstacles with the live swing envelope, stream SET_ATTITUDE_TARGET",
    "sitl": "run the bundled SITL vehicle (PX4-like MAVLink on UDP 14580/18570 → 14540/14550)",
    "listen": "watch the Zenoh streams (rate, loss, latest values per key)",
    "obstacles": "feed live obstacles over Zenoh",
    "zenoh-router": "run a Zenoh router (joins peers that cannot see each other)",
    "experiments": "rerun the paper's two experiments over MAVLink; Markdown report with tables and figures",
    "evaluate": "fly N random forests per planner in parallel and summarise success, collisions, times",
    "report": "rebuild a run folder's report, summary and plots from its journal (e.g. after kill -9)",
    "missions": "list the shipped missions (use their names with fly --mission)",
    "keygen": "write a new MAVLink 2 signing key file (for fly/sitl --signing-key)",
    "fleet": "fly N bundled vehicles with N companions at once through one Zenoh router",
    "replay": "open a run folder's recording.rrd in Rerun's viewer (web viewer on 127.0.0.1 without a display)",
    "view": "show every vehicle on the Zenoh network live in Rerun's viewer",
    "bench": "print performance numbers (model, sitl, fly, zenoh, faults, view, perception)",
}
_ADDERS: dict[str, Callable[[Any], None]] = {
    "fly": _add_fly, "sitl": _add_sitl, "listen": _add_zenoh_tool("listen"),
    "obstacles": _add_zenoh_tool("obstacles"), "zenoh-router": _add_zenoh_tool("zenoh-router"),
    "experiments": _add_lab("experiments"), "evaluate": _add_lab("evaluate"), "report": _add_report,
    "missions": _add_missions, "keygen": _add_keygen, "fleet": _add_fleet, "bench": _add_bench,
    "replay": _add_viz_tool("replay"),
    "view": _add_viz_tool("view"),
}


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The argument parser; ``--help`` on each subcommand explains it.

    Only the subcommand named in ``argv`` gets its full parser (and imports what it needs); the others appear
    by name and help line only, so ``slungpilot --help`` answers at once. ``argv`` None builds them all.
    """
    parser = argparse.ArgumentParser(
        prog="slungpilot",
        description=(
            "Companion-computer autopilot for a quadrotor carrying a cable-suspended payload: "
            "swing-aware APF planning and sliding-mode control, sent as SET_ATTITUDE_TARGET over MAVLink."
        ),
    )
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv: debug)")
    parser.add_argument("-q", "--quiet", action="store_true",
                        help="no narration of the flight (phases and progress); the summary and errors remain")
    parser.add_argument("--version", action="version", version=f"slungpilot {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    wanted = None if argv is None else next((a for a in argv if a in COMMANDS), "")
    for name, help_line in COMMANDS.items():
        if wanted is None or name == wanted:
            _ADDERS[name](sub)
        else:
            sub.add_parser(name, help=help_line)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the process exit code (2 for configuration errors)."""
    argv = sys.argv[1:] if argv is None else argv
    args = build_parser(argv).parse_args(argv)
    args.vehicle_fork = _fork_vehicle_ahead(args)
    if args.command == "fly":  # before any kernel loads: fly runs only our kernels, none of which uses BLAS
        from companion.core.kernel_cache import skip_numba_blas_probe

        skip_numba_blas_probe()
    try:
        return dispatch(args)
    finally:
        if args.vehicle_fork is not None:
            args.vehicle_fork.discard()


def _fork_vehicle_ahead(args: argparse.Namespace) -> Any:
    """``fly --sitl``: the bundled vehicle forked now (``sim_bridge.prefork``), so that its imports and kernels load
    on the other CPU while the companion loads its own (~0.4 s of the command's start); None for other commands,
    or where forking is not safe (then ``fly`` starts ``python -m sim_bridge`` as before)."""
    if args.command != "fly" or not getattr(args, "sitl", False):
        return None
    from sim_bridge import prefork

    return prefork.PreforkedVehicle() if prefork.can_fork() else None


def run() -> None:
    """The ``slungpilot`` command: :func:`main`, then exit. A command is done when :func:`main` returns (its run
    folder written, its vehicle and workers stopped, its Zenoh session closed), so after flushing what it printed
    and logged it leaves without the interpreter's module teardown (numba, llvmlite, matplotlib, rerun: 0.1-0.8 s
    of every ``fly``, docs/measurements.md); the ordinary exit when a thread or child process is still running."""
    try:
        code = main()
    except SystemExit as exc:  # argparse: --help, bad flags
        sys.exit(exc.code)
    import multiprocessing
    import threading

    from companion.proclife import exit_now

    if not isinstance(code, int) or multiprocessing.active_children() or any(
            t.is_alive() and not t.daemon for t in threading.enumerate() if t is not threading.main_thread()):
        sys.exit(code)
    exit_now(code)


if __name__ == "__main__":
    run()
