"""What tests/conftest.py sets up for the whole suite: default Ctrl-C handling, and bytecode written by the suite and
every process it starts even where the environment sets PYTHONDONTWRITEBYTECODE."""

from __future__ import annotations

import signal
import subprocess
import sys

import pytest

pytestmark = pytest.mark.shares_cores  # one short child process, no wall clock


def test_the_suite_and_its_children_write_bytecode():
    assert sys.dont_write_bytecode is False
    out = subprocess.run([sys.executable, "-c", "import os, sys; print(sys.dont_write_bytecode, "
                          "os.environ.get('PYTHONDONTWRITEBYTECODE'))"], capture_output=True, text=True, timeout=30)
    assert out.stdout.split() == ["False", "None"], out


def test_ctrl_c_is_not_ignored_by_the_suite_or_its_children():
    assert signal.getsignal(signal.SIGINT) is not signal.SIG_IGN
    out = subprocess.run([sys.executable, "-c", "import signal; print(signal.getsignal(signal.SIGINT) is "
                          "signal.SIG_IGN)"], capture_output=True, text=True, timeout=30)
    assert out.stdout.strip() == "False", out
