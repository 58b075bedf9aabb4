"""Suite-wide set-up.

Several tests press Ctrl-C on real child processes (SIGINT to a command or its process group) and check that the
command stops, holds or lands. A child inherits an *ignored* SIGINT from whoever started it, and a POSIX shell
without job control starts every background command (``pytest &`` in a script) with SIGINT and SIGQUIT ignored:
the children would then ignore the test's Ctrl-C and those tests fail for a reason that is not the code's. So the
suite restores the defaults for itself, and through it for every child it starts.
"""

from __future__ import annotations

import signal


def pytest_configure(config: object) -> None:
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    if signal.getsignal(signal.SIGQUIT) == signal.SIG_IGN:
        signal.signal(signal.SIGQUIT, signal.SIG_DFL)


#: Source text that shows a test file starts processes (a vehicle, a companion, a router, a proxy, a ground station).
#: Such tests run on the wall clock, lockstep ones included (a vehicle that does not answer within a second is lost),
#: so the README's test command runs them one at a time after the rest has run on both cores: `-m serial` / `-m "not
#: serial"`. Two lockstep flights beside another worker's flights lost their vehicle for 1.01 s once (2026-12-03).
_STARTS_PROCESSES = ("subprocess", "spawn_vehicle", "Popen", "SitlProcess", "fly_mission", "run_fly", "_cli(",
                     "mavsdk_drone", "_operator_helpers", "lab.procs", "run_evaluate", "evaluate(")


def pytest_collection_modifyitems(config: object, items: list) -> None:
    """Mark every test of a file that starts processes ``serial`` (see :data:`_STARTS_PROCESSES`)."""
    import pytest

    starts: dict[object, bool] = {}
    for item in items:
        path = item.path
        if path not in starts:
            text = path.read_text(encoding="utf-8", errors="replace")
            starts[path] = any(s in text for s in _STARTS_PROCESSES)
        if starts[path]:
            item.add_marker(pytest.mark.serial)
