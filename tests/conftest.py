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
