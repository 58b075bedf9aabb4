"""Suite-wide set-up.

Several tests press Ctrl-C on real child processes (SIGINT to a command or its process group) and check that the
command stops, holds or lands. A child inherits an *ignored* SIGINT from whoever started it, and a POSIX shell
without job control starts every background command (``pytest &`` in a script) with SIGINT and SIGQUIT ignored:
the children would then ignore the test's Ctrl-C and those tests fail for a reason that is not the code's. So the
suite restores the defaults for itself, and through it for every child it starts.

The suite starts about a thousand Python processes (vehicles, companions, workers). Where the environment sets
``PYTHONDONTWRITEBYTECODE`` (this project's CI machines do), each of them would compile every module it imports
again: the suite writes bytecode caches for itself and its children all the same (``__pycache__`` is ignored by
git; docs/measurements.md has the minutes this saves).
"""

from __future__ import annotations

import os
import re
import signal
import sys
from pathlib import Path

#: set by tests/run_suite.py for the phase that runs on xdist workers: each worker is interrupted when the phase's
#: pytest goes (the runner has it killed with the runner; a worker's teardown then stops what its test started)
WORKERS_DIE_WITH_PYTEST = "SLUNGPILOT_WORKERS_DIE_WITH_PYTEST"


def pytest_configure(config: object) -> None:
    sys.dont_write_bytecode = False
    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    if signal.getsignal(signal.SIGQUIT) == signal.SIG_IGN:
        signal.signal(signal.SIGQUIT, signal.SIG_DFL)
    if os.environ.get(WORKERS_DIE_WITH_PYTEST) and hasattr(config, "workerinput"):
        from companion import proclife

        proclife.die_with_parent(os.getppid(), signal.SIGINT)


#: Source text that shows a test file starts processes (a vehicle, a companion, a router, a proxy, a ground station).
#: Such tests are ``serial`` by default: the README's test command runs them after the rest has run on both cores (`-m
#: "not serial"`), because real-time flights, rates and deadlines need the machine to themselves. A serial test that
#: checks only outcomes (no rate, jitter or deadline at stake) and mostly waits on the wall clock (measured: most at
#: half a core or less, a few of 4-12 s at one core) says so with ``pytest.mark.paired``: those run two at a time (`-n 2
#: -m "serial and paired"`), the others one at a time (`-m "serial and not paired"`). (tests/run_suite.py runs all
#: serial tests one at a time beside the rest, at SCHED_IDLE.) A file (or a test) that starts processes but does not
#: depend on the wall clock (lockstep flights, no deadline, no upper bound on a duration) says so with
#: ``pytest.mark.shares_cores`` and runs on both cores; a test marked ``serial`` by hand stays serial inside such a
#: file. (Lockstep flights beside others have lost their vehicle for 1.01-1.02 s on a loaded machine, 2026-12-03 and
#: 12-04; the lockstep limit is 1.5 s since: docs/measurements.md.)
_STARTS_PROCESSES = ("subprocess", "spawn_vehicle", "Popen", "SitlProcess", "fly_mission", "run_fly", "_cli(",
                     "mavsdk_drone", "_operator_helpers", "lab.procs", "run_evaluate", "evaluate(")


_LAB_IMPORT = re.compile(r"^from lab(?:\.(\w+))? import ([\w, ()]+)", re.MULTILINE)


def starts_processes(path: Path) -> bool:
    """Whether a test file starts processes: its own text shows it (:data:`_STARTS_PROCESSES`), or a ``lab`` module
    it imports does (``from lab import faults`` flies through real processes without saying so here)."""
    text = path.read_text(encoding="utf-8", errors="replace")
    if any(s in text for s in _STARTS_PROCESSES):
        return True
    lab = path.parent.parent / "lab"
    for sub, names in _LAB_IMPORT.findall(text):
        modules = [sub] if sub else [n.strip(" ()") for n in names.split(",")]
        for mod in modules:
            src = lab / f"{mod}.py"
            if src.is_file() and any(s in src.read_text(encoding="utf-8") for s in _STARTS_PROCESSES):
                return True
    return False


def pytest_collection_modifyitems(config: object, items: list) -> None:
    """Mark every test of a file that starts processes ``serial`` unless it is marked ``shares_cores`` (see
    :func:`starts_processes`)."""
    import pytest

    starts: dict[Path, bool] = {}
    for item in items:
        path = Path(item.path)
        if path not in starts:
            starts[path] = starts_processes(path)
        if starts[path] and item.get_closest_marker("shares_cores") is None:
            item.add_marker(pytest.mark.serial)
