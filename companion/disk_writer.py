"""Files written by a thread of their own, so that a slow disk never stalls the control loop.

A write to a local file usually takes microseconds, but not always: while another process wrote a few hundred MB
(a ``git clone`` on the same disk), the journal's ``os.replace`` of its provisional report blocked the event loop
for 0.5-0.8 s in flooded real-time flights (faulthandler tracebacks taken 80 ms into each stall all stood in
``journal._write_atomic``: the rename waited in the kernel, probably for ext4's journal, which the other
process's writes kept busy; a rename over an existing file also starts writing the new file out). A flight
during such I/O ended ``preempted`` after a 1.1 s stall: the vehicle's own offboard failsafe fired while no
setpoint went out. PX4's logger
and ArduPilot's do their file I/O on a low-priority thread for the same reason.

:class:`DiskWriter` takes bytes from the caller and returns at once; its thread does the ``write``, ``flush``
and ``os.replace`` calls. Appends to a file keep their order; a replaced file keeps only its newest contents
(an older version still waiting is dropped). Everything handed over is written by :meth:`DiskWriter.close`
unless the disk takes longer than its timeout. Errors (disk full, folder removed) are counted and logged at
most once a second, never raised into the caller. ``lag_s_max`` is the longest time from handing a write over
to its being written: what a ``kill -9`` could lose beyond the hand-over interval.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO

log = logging.getLogger(__name__)


class DiskWriter:
    """One writer thread for any number of files (see the module docstring). Thread-safe."""

    def __init__(self, name: str = "disk-writer") -> None:
        self._cond = threading.Condition()
        self._files: dict[Path, BinaryIO] = {}  # owned by the writer thread once created
        self._appends: list[tuple[Path, bytes]] = []
        self._replaces: dict[Path, bytes] = {}
        self._oldest_s: float | None = None  # monotonic time of the oldest write not yet taken
        self._closing = False
        self.taken = 0  # times the thread took what waited (it may still be writing the last of them)
        self.batches = 0  # times it finished writing what it took
        self.errors = 0
        self.last_error: str | None = None
        self.lag_s_max = 0.0  # longest time from handing a write over to its being written (s)
        self._last_log = -float("inf")
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def create(self, path: Path) -> None:
        """Open ``path`` for appending, truncated (here, at once: call it before the flight)."""
        path.parent.mkdir(parents=True, exist_ok=True)
        fh = path.open("wb")
        with self._cond:
            self._files[path] = fh

    def append(self, path: Path, data: bytes) -> None:
        """Queue ``data`` for the end of ``path`` (made by :meth:`create`); returns at once."""
        self._put(lambda: self._appends.append((path, data)))

    def replace(self, path: Path, data: bytes) -> None:
        """Queue ``path``'s new contents (written to ``path.tmp``, then renamed over it); returns at once."""
        self._put(lambda: self._replaces.__setitem__(path, data))

    def _put(self, add: Callable[[], None]) -> None:
        with self._cond:
            if self._closing:
                return
            add()
            if self._oldest_s is None:
                self._oldest_s = time.monotonic()
            self._cond.notify()

    def pending(self) -> bool:
        """True while something handed over is not written yet."""
        with self._cond:
            return bool(self._appends or self._replaces or self.taken != self.batches)

    def close(self, timeout_s: float = 30.0) -> bool:
        """Write everything handed over, close the files, stop the thread; False if the disk took longer than
        ``timeout_s`` (the thread then goes on in the background and the files stay open). Idempotent."""
        with self._cond:
            self._closing = True
            self._cond.notify()
        self._thread.join(timeout_s)
        if self._thread.is_alive():
            log.error("the disk has not taken the last writes in %.0f s; leaving them to a background thread",
                      timeout_s)
            return False
        return True

    def _run(self) -> None:
        while True:
            with self._cond:
                while not (self._appends or self._replaces or self._closing):
                    self._cond.wait()
                appends, self._appends = self._appends, []
                replaces, self._replaces = self._replaces, {}
                oldest_s, self._oldest_s = self._oldest_s, None
                closing = self._closing and not appends and not replaces
                self.taken += not closing
            if closing:
                for fh in self._files.values():
                    self._guard("close", fh.name, fh.close)
                return
            self._write(appends, replaces)
            with self._cond:
                self.batches += 1
                if oldest_s is not None:
                    self.lag_s_max = max(self.lag_s_max, time.monotonic() - oldest_s)

    def _write(self, appends: list[tuple[Path, bytes]], replaces: dict[Path, bytes]) -> None:
        touched: dict[Path, BinaryIO] = {}
        for path, data in appends:
            fh = self._files.get(path)
            if fh is None:
                self._error(f"{path}: append to a file that was not created")
                continue
            if self._guard("write", path, fh.write, data):
                touched[path] = fh
        for path, fh in touched.items():
            self._guard("flush", path, fh.flush)
        for path, data in replaces.items():
            tmp = path.with_suffix(path.suffix + ".tmp")
            if self._guard("write", tmp, tmp.write_bytes, data):
                self._guard("rename", path, os.replace, tmp, path)

    def _guard(self, what: str, path: object, fn: Callable[..., object], *args: object) -> bool:
        try:
            fn(*args)
        except (OSError, ValueError) as exc:  # ValueError: I/O on a file closed under us
            self._error(f"{what} {path}: {exc}")
            return False
        return True

    def _error(self, msg: str) -> None:
        self.errors += 1
        self.last_error = msg
        now = time.monotonic()
        if now - self._last_log >= 1.0:
            self._last_log = now
            log.error("disk writer: %s (%d errors so far)", msg, self.errors)
