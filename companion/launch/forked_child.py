"""A child process forked by this process itself (not started by asyncio), used as an ``asyncio.subprocess.Process``
is: ``pid``, ``stdout`` (a StreamReader on its pipe), ``returncode``, ``wait()``, ``send_signal``/``terminate``/
``kill``. The bundled vehicle forked ahead of its command line (``sim_bridge.prefork``) is run through it."""

from __future__ import annotations

import asyncio
import os
import signal
from typing import Any

#: how often :meth:`ForkedChild.wait` looks when the kernel cannot tell it (no pidfd), s
POLL_S = 0.005


class ForkedChild:
    """Our child ``pid`` with its stdout on ``stdout_fd``; create with :meth:`attach` inside the event loop."""

    def __init__(self, pid: int, stdout: asyncio.StreamReader, transport: Any) -> None:
        self.pid = pid
        self.stdout = stdout
        self._transport = transport
        self._rc: int | None = None

    @classmethod
    async def attach(cls, pid: int, stdout_fd: int) -> ForkedChild:
        """Read the child's stdout through the running loop (this object owns ``stdout_fd`` from now on)."""
        loop = asyncio.get_running_loop()
        reader = asyncio.StreamReader(loop=loop)
        pipe = os.fdopen(stdout_fd, "rb", buffering=0)
        transport, _ = await loop.connect_read_pipe(lambda: asyncio.StreamReaderProtocol(reader, loop=loop), pipe)
        return cls(pid, reader, transport)

    @property
    def returncode(self) -> int | None:
        """The exit code (negative: killed by that signal), None while it runs."""
        if self._rc is None:
            self._reap(block=False)
        return self._rc

    def _reap(self, block: bool) -> None:
        try:
            pid, status = os.waitpid(self.pid, 0 if block else os.WNOHANG)
        except ChildProcessError:  # reaped already (cannot happen unless someone waits for any child)
            self._rc = -signal.SIGKILL if self._rc is None else self._rc
        else:
            if pid == 0:
                return
            self._rc = os.waitstatus_to_exitcode(status)
        self._transport.close()

    async def wait(self) -> int:
        """Wait for the child to exit; its exit code."""
        while self.returncode is None:
            await self._exited()
        return self._rc  # type: ignore[return-value]

    async def _exited(self) -> None:
        """Until the kernel says the child has exited (its pidfd turns readable), or :data:`POLL_S` where there are
        no pidfds."""
        try:
            pidfd = os.pidfd_open(self.pid)
        except (AttributeError, OSError):
            await asyncio.sleep(POLL_S)
            return
        loop = asyncio.get_running_loop()
        done = loop.create_future()
        loop.add_reader(pidfd, lambda: done.done() or done.set_result(None))
        try:
            await done
        finally:
            loop.remove_reader(pidfd)
            os.close(pidfd)

    def send_signal(self, sig: int) -> None:
        """Signal the child; ProcessLookupError once it has exited."""
        if self.returncode is not None:
            raise ProcessLookupError(self.pid)
        os.kill(self.pid, sig)

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)
