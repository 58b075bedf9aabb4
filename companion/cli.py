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
