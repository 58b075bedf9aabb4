"""The bundled vehicle forked ahead of its command line: ``python -m sim_bridge ARGS`` without paying, when it is
needed, for the interpreter's start, the imports and the loading of the compiled kernels (~0.44 s of CPU, most of a
vehicle's start; docs/sitl.md, *Starting the vehicle ahead*).

:class:`PreforkedVehicle` forks a child at once. The child ties itself to this process
(:func:`companion.proclife.die_with_parent`: SIGKILL when the forking thread ends), takes a session of its own, loads
the vehicle unless this process did so first (:func:`preload`, then the child inherits it warm), and waits on a pipe
for its arguments. :meth:`PreforkedVehicle.launch` sends them: the child's stdin becomes /dev/null, its stdout the
pipe made at the fork (the caller reads ``SITL READY`` there), its stderr the file named, its CPUs this process's
CPUs at launch, and it runs :func:`sim_bridge.cli.main` as ``python -m sim_bridge`` would, then exits without the
interpreter's teardown. An unused child is killed by :meth:`discard`, and exits by itself when its pipe closes
(this process's exit).

Fork only where it is safe: :func:`can_fork` (Linux, one Python thread). Elsewhere the caller starts
``python -m sim_bridge`` as before.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
import signal
import sys
import threading
import warnings
from pathlib import Path

from companion import proclife

_preloaded = False


#: set to 0 to start every vehicle as ``python -m sim_bridge`` (e.g. to compare, or where forking misbehaves)
ENV_SWITCH = "SLUNGPILOT_FORK_VEHICLE"


def can_fork() -> bool:
    """Whether a vehicle can be forked from here: Linux (the child must die with us), no other Python thread (a
    thread's locks, e.g. logging's, would be held for ever in the child; numpy's native BLAS pool holds none the child
    needs: the vehicle uses no BLAS), and not switched off (:data:`ENV_SWITCH`)."""
    return (os.environ.get(ENV_SWITCH, "1") != "0" and hasattr(os, "fork") and proclife.supported()
            and threading.active_count() == 1)


def preload() -> None:
    """Import the vehicle and load its compiled kernels in this process (a default vehicle, two physics steps), so
    that children forked afterwards start warm. Once per process."""
    global _preloaded
    if _preloaded:
        return
    from companion.core.kernel_cache import skip_numba_blas_probe
    from sim_bridge import cli
    from sim_bridge.vehicle import SitlVehicle

    skip_numba_blas_probe()  # the vehicle's kernels use no BLAS
    parser = argparse.ArgumentParser()
    cli.add_sitl_arguments(parser)
    SitlVehicle(cli.config_from_args(parser.parse_args([]))).warm_up()
    _preloaded = True


class PreforkedVehicle:
    """A child forked now that becomes the vehicle when :meth:`launch` gives it its arguments (module docstring)."""

    def __init__(self) -> None:
        cmd_r, self._cmd_w = os.pipe()
        self.stdout_fd, out_w = os.pipe()
        parent = os.getpid()
        sys.stdout.flush()
        sys.stderr.flush()
        with warnings.catch_warnings():  # Python 3.12+ warns of any OS thread (numpy's BLAS pool): see can_fork
            warnings.filterwarnings("ignore", "This process .* is multi-threaded", DeprecationWarning)
            self.pid = os.fork()
        if self.pid == 0:  # the child: never returns
            os.close(self._cmd_w)
            os.close(self.stdout_fd)
            _child(cmd_r, out_w, parent)
        os.close(cmd_r)
        os.close(out_w)
        self.launched = False

    def launch(self, args: list[str], stderr_path: Path) -> int:
        """Make the child ``python -m sim_bridge *args`` with stderr into ``stderr_path``; returns the read end of
        its stdout (the caller closes it). Raises OSError when the child is gone."""
        if self.launched:
            raise RuntimeError("this vehicle was launched already")
        self.launched = True
        cmd = {"args": list(args), "stderr": str(stderr_path), "cpus": sorted(os.sched_getaffinity(0))}
        try:
            os.write(self._cmd_w, (json.dumps(cmd) + "\n").encode())
        except OSError:  # the child is gone (its pipe has no reader): reap it
            os.close(self.stdout_fd)
            with contextlib.suppress(ChildProcessError):
                os.waitpid(self.pid, 0)
            raise
        finally:
            os.close(self._cmd_w)
        return self.stdout_fd

    def discard(self) -> None:
        """End an unlaunched child at once (it holds nothing yet; it may still be loading the vehicle) and reap it.
        Nothing for a launched one: its owner stops it."""
        if self.launched:
            return
        self.launched = True
        os.close(self._cmd_w)
        os.close(self.stdout_fd)
        with contextlib.suppress(ProcessLookupError):
            os.kill(self.pid, signal.SIGKILL)
        with contextlib.suppress(ChildProcessError):
            os.waitpid(self.pid, 0)


def _child(cmd_r: int, out_w: int, parent: int) -> None:
    """The forked child (see the module docstring); ends the process, whatever happens."""
    code = 1
    try:
        os.setsid()  # a terminal's Ctrl-C reaches the companion only, which stops the vehicle last
        proclife.die_with_parent(parent)
        proclife.set_name("sim_bridge")
        signal.signal(signal.SIGINT, signal.default_int_handler)  # a pool worker ignores it; the vehicle may not
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        if not _preloaded:
            preload()
        line = _read_line(cmd_r)
        if not line:  # discarded, or the parent is gone
            code = 0
            return
        cmd = json.loads(line)
        proclife.set_command_line(["python", "-m", "sim_bridge", *cmd["args"]])  # as ps shows it (cut to fit)
        _redirect(out_w, cmd["stderr"])
        if hasattr(os, "sched_setaffinity"):
            os.sched_setaffinity(0, cmd["cpus"])
        root = logging.getLogger()
        for h in root.handlers[:]:  # the parent's handlers: the vehicle configures its own
            root.removeHandler(h)
        from sim_bridge.cli import main

        sys.argv = ["python -m sim_bridge", *cmd["args"]]
        try:
            code = main(cmd["args"])
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    except BaseException:  # the child must end here, never return into the parent's code
        import traceback

        traceback.print_exc()
    finally:
        proclife.exit_now(code)


def _read_line(fd: int) -> bytes:
    """One line from ``fd`` (blocking), empty at end of file."""
    buf = b""
    while not buf.endswith(b"\n"):
        chunk = os.read(fd, 65536)
        if not chunk:
            return b""
        buf += chunk
    return buf


def _redirect(out_w: int, stderr_path: str) -> None:
    """stdin from /dev/null, stdout into the pipe, stderr into ``stderr_path`` (created or truncated)."""
    null = os.open(os.devnull, os.O_RDONLY)
    err = os.open(stderr_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    for fd, target in ((null, 0), (out_w, 1), (err, 2)):
        os.dup2(fd, target)
        os.close(fd)
