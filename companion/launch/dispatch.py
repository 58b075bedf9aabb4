"""How every slungpilot entry point runs a parsed command: logging set-up, errors as one line, exit codes."""

from __future__ import annotations

import argparse
import logging
import sys

from companion.errors import SlungpilotError


def dispatch(args: argparse.Namespace, prog: str = "slungpilot") -> int:
    """Set up logging from ``-v`` and run ``args.func``; errors become one line on stderr and an exit code
    (2 for configuration errors, 130 for Ctrl-C). Shared by every entry point (``python -m lab`` …)."""
    level = logging.WARNING - 10 * min(getattr(args, "verbose", 0), 2)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        return int(args.func(args) or 0)
    except SlungpilotError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # output piped into e.g. `head`
        return 0
