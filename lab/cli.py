"""Subcommands ``experiments`` and ``evaluate`` for the ``slungpilot`` CLI (wired in ``companion/cli/main.py``),
also runnable as ``python -m lab experiments|evaluate``."""

from __future__ import annotations

import argparse
from typing import Any


def _cmd_experiments(args: argparse.Namespace) -> int:
    from lab.experiments import run_experiments_cli

    return run_experiments_cli(args)


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from lab.evaluate import run_evaluate

    return run_evaluate(args)


def add_experiments_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add ``experiments`` to an ``add_subparsers()`` object; sets ``func``."""
    from lab.experiments import add_experiments_arguments

    p = subparsers.add_parser(
        "experiments",
        help="rerun the paper's two experiments through the MAVLink loop and write a report with figures",
        description=(
            "Group 1 (pid, smc, smc_ff on config/missions/group1.toml) and Group 2 (traditional, improved, safe on "
            "config/missions/forest.toml with smc_ff), each a lockstep `fly --sitl` flight with eq. 49 wind, two at "
            "a time. Writes report.md (our numbers next to the paper's, with the disagreements spelled out), "
            "experiments.json, comparison figures and one run folder per flight."
        ),
    )
    add_experiments_arguments(p)
    p.set_defaults(func=_cmd_experiments)
    return p


def add_evaluate_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add ``evaluate`` to an ``add_subparsers()`` object; sets ``func``."""
    from lab.evaluate import add_evaluate_arguments

    p = subparsers.add_parser(
        "evaluate",
        help="fly N seeded random forests per planner in parallel and summarise success, collisions, local minima",
        description=(
            "Generates random forests from seeds (corridor 20 m x 6 m, trunk radii 0.15-0.35 m, a density in trunks "
            "per 100 m2, optional traps and wind/payload/cable variations), flies each with every planner in "
            "worker processes (default: full lockstep MAVLink flights; --mode inprocess for the faster in-process "
            "runner with the same FlightCore), and writes summary.md/json, results.jsonl, a success-vs-density "
            "plot and the replayable mission file of every failure."
        ),
    )
    add_evaluate_arguments(p)
    p.set_defaults(func=_cmd_evaluate)
    return p


def build_parser() -> argparse.ArgumentParser:
    """A stand-alone parser with both subcommands (``python -m lab``)."""
    parser = argparse.ArgumentParser(prog="python -m lab", description="slungpilot reproduction and evaluation")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    add_experiments_parser(sub)
    add_evaluate_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """``python -m lab``: same exit codes as ``slungpilot`` (2 for configuration errors)."""
    from companion.launch.dispatch import dispatch

    return dispatch(build_parser().parse_args(argv))
