"""The ``slungpilot`` command line: one entry point, one subcommand per job.

This is the only module in ``companion`` that may reach into ``sim_bridge`` (to start the bundled vehicle
or benchmark it); everything else in the companion talks to a vehicle over MAVLink only.
"""

from __future__ import annotations

import argparse
import logging
import sys

from companion.errors import SlungpilotError

log = logging.getLogger(__name__)


def _cmd_bench(args: argparse.Namespace) -> int:
    if args.target == "model":
        from companion import bench_model

        print("slungpilot bench model: RK4 (1 kHz step) of the 8-DOF quadrotor-payload model, numba kernels")
        res = bench_model.run(seconds=args.seconds)
        print(f"  cold start (compile or load cache): {res.pop('cold_start_s'):8.3f} s")
        for k, v in res.items():
            print(f"  {k:32s} {v:14,.0f}")
        return 0
    raise SlungpilotError(f"bench target {args.target!r} is not available in this build")


def _cmd_fly(args: argparse.Namespace) -> int:
    from companion.fly import run_fly

    return run_fly(args)


def _cmd_sitl(args: argparse.Namespace) -> int:
    from sim_bridge.cli import run_sitl

    return run_sitl(args)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every subcommand; ``--help`` on each explains it."""
    parser = argparse.ArgumentParser(
        prog="slungpilot",
        description=(
            "Companion-computer autopilot for a quadrotor carrying a cable-suspended payload: "
            "swing-aware APF planning and sliding-mode control, sent as SET_ATTITUDE_TARGET over MAVLink."
        ),
    )
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv: debug)")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    from companion.fly import add_fly_arguments

    fly = sub.add_parser(
        "fly",
        help="fly a mission: plan around obstacles with the live swing envelope, stream SET_ATTITUDE_TARGET",
        description=(
            "Fly a mission file against an autopilot over MAVLink/UDP (PX4, ArduPilot) or, with --sitl, against "
            "the bundled vehicle started on free local ports (lockstep: as fast as possible, deterministic). "
            "Waits for the heartbeat, streams setpoints, arms, switches to OFFBOARD, climbs, flies to the goal, "
            "holds, lands, and writes a run folder: report.json, plots, flight.tlog. Ctrl-C holds, lands and "
            "still writes the report. Exit 0 when the goal was reached, 1 when not, 2 on a broken mission file."
        ),
    )
    add_fly_arguments(fly)
    fly.set_defaults(func=_cmd_fly)

    from sim_bridge.cli import add_sitl_arguments

    sitl = sub.add_parser(
        "sitl",
        help="run the bundled SITL vehicle (PX4-like MAVLink on UDP 14580/18570 → 14540/14550)",
        description=(
            "The bundled software-in-the-loop vehicle: flies the paper's quadrotor-payload model with its own "
            "attitude loop and eq. 49 wind, and speaks MAVLink 2 like PX4's SITL (HEARTBEAT, telemetry, commands, "
            "OFFBOARD via SET_ATTITUDE_TARGET, params). See docs/sitl.md for messages and the lockstep handshake."
        ),
    )
    add_sitl_arguments(sitl)
    sitl.set_defaults(func=_cmd_sitl)

    bench = sub.add_parser(
        "bench",
        help="print performance numbers (model, sitl, fly, zenoh)",
        description="Benchmarks that print numbers; nothing is asserted. Run on an idle machine.",
    )
    bench.add_argument("target", choices=["model"], help="model: RK4 steps/s of the dynamics kernel")
    bench.add_argument("--seconds", type=float, default=3.0, help="measuring time per benchmark (s)")
    bench.set_defaults(func=_cmd_bench)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the process exit code (2 for configuration errors)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        return int(args.func(args) or 0)
    except SlungpilotError as exc:
        print(f"slungpilot: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("slungpilot: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
