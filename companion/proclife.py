"""Nothing we start outlives us: child processes that die with their parent, whatever kills the parent.

A parent's clean stop (``finally``, ``__aexit__``) stops its children, but SIGKILL (or an OOM kill, or a
crash in C) runs none of it, and a child in its own session or process group (so that a terminal's Ctrl-C
reaches the parent only) is then reparented to init and lives on. On Linux the kernel can send the child a
signal when its parent goes: ``prctl(PR_SET_PDEATHSIG, sig)``, set in the child. Two details:

* the signal fires when the *thread* that forked the child exits, not the process: start children from a
  thread that lives as long as they should (the main thread, or the asyncio event loop's thread);
* a parent that died between the fork and the ``prctl`` call sends nothing, so right after setting it the
  child checks that its parent is still the one that started it, and exits otherwise.

Every launcher uses this module: :func:`preexec` as ``preexec_fn`` of ``subprocess.Popen``/``run`` or
``asyncio.create_subprocess_exec`` (it runs in the child between fork and exec, and the setting survives the
exec), :func:`die_with_parent` in a pool worker's initializer (``multiprocessing``/``concurrent.futures``),
where the worker's parent pid is passed in; :func:`sigterm_as_interrupt` where a command must stop its
children cleanly on SIGTERM as it does on Ctrl-C. Elsewhere than Linux both do nothing (the parent's clean stop
is all there is).
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import logging
import os
import signal
import sys
from collections.abc import Callable, Iterator
from typing import NoReturn

log = logging.getLogger(__name__)

PR_SET_PDEATHSIG = 1  # <linux/prctl.h>
PR_SET_NAME = 15


def _prctl() -> Callable[..., int] | None:
    """libc's ``prctl`` (Linux), else None."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        fn = libc.prctl
    except (OSError, AttributeError):
        return None
    fn.argtypes = [ctypes.c_int, ctypes.c_ulong, ctypes.c_ulong, ctypes.c_ulong, ctypes.c_ulong]
    fn.restype = ctypes.c_int
    return fn


_PRCTL = _prctl()


def supported() -> bool:
    """Whether children can be tied to their parent here (Linux)."""
    return _PRCTL is not None


def die_with_parent(parent_pid: int, sig: int = signal.SIGKILL) -> None:
    """In a child: receive ``sig`` when the parent thread that started us exits; exit at once (``os._exit``)
    when ``parent_pid`` is already gone (we were reparented before the request was in place)."""
    if _PRCTL is None:
        return
    if _PRCTL(PR_SET_PDEATHSIG, int(sig), 0, 0, 0) != 0:
        log.warning("prctl(PR_SET_PDEATHSIG) failed (errno %d): this process may outlive its parent",
                    ctypes.get_errno())
        return
    if os.getppid() != parent_pid:
        os._exit(1)


def set_name(name: str) -> None:
    """This process's name as ``ps -e``, ``top`` and ``pgrep`` show it (Linux keeps 15 bytes); a forked child that
    is not the program its command line names says what it is. Does nothing elsewhere."""
    if _PRCTL is None:
        return
    buf = ctypes.create_string_buffer(name.encode()[:15])
    _PRCTL(PR_SET_NAME, ctypes.cast(buf, ctypes.c_void_p).value or 0, 0, 0, 0)


def set_command_line(argv: list[str]) -> bool:
    """Rewrite this process's command line as ``ps``, ``htop`` and ``/proc/PID/cmdline`` show it, in place and cut
    to the length of the one it started with (the kernel's argument area; what ``setproctitle`` does on Linux): a
    forked child that runs another program says which. Python's own ``sys.argv`` is a copy and unchanged. False
    where it cannot (not Linux, or the area is not where ``/proc/self/stat`` says)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        with open("/proc/self/stat", "rb") as f:
            stat = f.read()
        with open("/proc/self/cmdline", "rb") as f:
            current = f.read()
        fields = stat[stat.rindex(b")") + 2:].split()
        start, end = int(fields[45]), int(fields[46])  # arg_start, arg_end: fields 48 and 49 of proc(5)
    except (OSError, ValueError, IndexError):
        return False
    size = end - start
    if size < 2 or size != len(current):
        return False
    data = "\0".join(argv).encode()[: size - 1]
    ctypes.memmove(start, data + b"\0" * (size - len(data)), size)
    return True


def preexec(sig: int = signal.SIGKILL) -> Callable[[], None] | None:
    """A ``preexec_fn`` that ties the child to this process (see :func:`die_with_parent`), or None where that
    is not supported. Call it in the thread that starts the child. The function runs between fork and exec:
    it imports nothing, logs nothing and takes no lock (only the libc call resolved here and ``getppid``)."""
    prctl = _PRCTL
    if prctl is None:
        return None
    parent = os.getpid()
    signum = int(sig)

    def tie_to_parent() -> None:
        prctl(PR_SET_PDEATHSIG, signum, 0, 0, 0)  # a failure cannot be reported from here: the child still runs
        if os.getppid() != parent:
            os._exit(1)

    return tie_to_parent


@contextlib.contextmanager
def signals_handled(handler: Callable[[int, object], None] | int, *signums: int) -> Iterator[None]:
    """Within: ``signums`` go to ``handler`` (a function or ``signal.SIG_IGN``); the old handlers come back after.
    Does nothing outside the main thread (only the main thread may set handlers; there its owner stops it)."""
    try:
        old = {s: signal.signal(s, handler) for s in signums}
    except ValueError:  # not the main thread
        yield
        return
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def sigterm_as_interrupt() -> contextlib.AbstractContextManager[None]:
    """Within: SIGTERM raises ``KeyboardInterrupt`` in the main thread, as Ctrl-C does, so that a command's
    clean stop on Ctrl-C (which stops its children) runs for ``kill PID`` too; Python's default for SIGTERM
    is to die at once and leave them. Does nothing outside the main thread."""
    def interrupt(_signum: int, _frame: object) -> None:
        raise KeyboardInterrupt("terminated (SIGTERM)")

    return signals_handled(interrupt, signal.SIGTERM)


def exit_now(code: int) -> NoReturn:
    """End this process with ``code`` once its work is done: what it printed and logged flushed, then
    ``os._exit``, without the interpreter's module teardown (numba and llvmlite take 0.1-0.8 s to unload). Only
    for a command whose files are written and whose children and threads are stopped."""
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)
