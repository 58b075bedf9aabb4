"""``python -m sim_bridge``: start the bundled SITL vehicle (see ``--help`` and docs/sitl.md)."""

import sys

from companion.proclife import exit_now
from sim_bridge.cli import main

try:
    code = main()
except SystemExit as exc:  # argparse: --help, bad flags
    code = exc.code
if not isinstance(code, int):
    if code is not None:
        print(code, file=sys.stderr)
    code = 0 if code is None else 1
# The vehicle writes no files: skip the interpreter's module teardown, which every lockstep run would wait for.
exit_now(code)
