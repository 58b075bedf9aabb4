"""``python -m sim_bridge``: start the bundled SITL vehicle (see ``--help`` and docs/sitl.md)."""

import logging
import os
import sys

from sim_bridge.cli import main

try:
    code = main()
except SystemExit as exc:  # argparse: --help, bad flags
    code = exc.code
if not isinstance(code, int):
    if code is not None:
        print(code, file=sys.stderr)
    code = 0 if code is None else 1
# The vehicle writes no files; after flushing what it printed and logged, skip the interpreter's module
# teardown (numba/llvmlite take ~0.35 s to unload), which every lockstep run and test would otherwise wait for.
logging.shutdown()
sys.stdout.flush()
sys.stderr.flush()
os._exit(code)
