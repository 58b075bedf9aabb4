"""One Rerun recording fed through a bounded queue by a logging thread.

Why a thread: a single ``rr.log`` call costs 100–250 µs of the caller's CPU in rerun-sdk 0.41 on the
development VM (most of it inside the SDK's native call), more than the companion's whole control tick
(≈ 40 µs). So the control loop only appends one tuple per tick to a deque (≈ 1–2 µs including building it);
a daemon thread wakes every ``flush_s`` of wall time, drains the deque and hands the batch to a *handler*
that turns it into column sends (``send_columns`` costs ≈ 5–15 µs per row at 50 rows per call). The queue is
bounded: when it is full the item is dropped and counted (``dropped``), so a slow viewer or disk can never
block or grow the control loop. Handler errors are counted and logged at most once a second, never raised.

The handler is any callable ``handler(recording, items)`` (with an optional ``finish(recording)`` called once at
close for what it still buffers); :mod:`companion.viz.flight` and :mod:`companion.viz.fleet` provide them.
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import rerun as rr

log = logging.getLogger(__name__)

MAX_QUEUE = 50_000  # items (≈ 17 s of lockstep flight at 3000 ticks/s wall, ≈ 200 s at 250 Hz real time)


class Recorder:
    """A Rerun recording stream plus its logging thread. ``open()`` / ``close()`` or ``with``.

    ``sinks``: Rerun sinks (``rr.FileSink``, ``rr.GrpcSink``); ``blueprint``: the default layout (stored in the
    file too); ``setup(recording)`` runs once in the caller's thread before the thread starts (static data).
    """

    def __init__(
        self,
        application_id: str,
        handler: Callable[[rr.RecordingStream, list[Any]], None],
        sinks: Sequence[Any],
        *,
        blueprint: Any = None,
        setup: Callable[[rr.RecordingStream], None] | None = None,
        recording_id: str | None = None,
        max_queue: int = MAX_QUEUE,
        flush_s: float = 0.1,
    ) -> None:
        self.application_id = application_id
        self.handler = handler
        self.sinks = list(sinks)
        self.blueprint = blueprint
        self.setup = setup
        self.recording_id = recording_id
        self.max_queue = max_queue
        self.flush_s = flush_s
        self.recording: rr.RecordingStream | None = None
        self.queued = 0
        self.dropped = 0
        self.batches = 0
        self.handler_errors = 0
        self.worker_cpu_s = 0.0
        self._q: collections.deque[Any] = collections.deque()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._last_error_log = -1e9

    # -- lifecycle ---------------------------------------------------------------------------------------
    def open(self) -> Recorder:
        if self.recording is not None:
            return self
        rec = rr.RecordingStream(self.application_id, recording_id=self.recording_id)
        # Only the timelines the handlers set (mission/vehicle/wall time), not the SDK's log_time / log_tick.
        rr.set_log_time_enabled(False, recording=rec)
        rr.set_log_tick_enabled(False, recording=rec)
        rec.set_sinks(*self.sinks, default_blueprint=self.blueprint)
        self.recording = rec
        if self.setup is not None:
            self.setup(rec)
        self._thread = threading.Thread(target=self._run, name=f"rerun-{self.application_id}", daemon=True)
        self._thread.start()
        return self

    def close(self, timeout_s: float = 10.0) -> None:
        """Log what is queued, flush every sink (the file is complete afterwards) and disconnect. Idempotent."""
        th, self._thread = self._thread, None
        if th is not None:
            self._stop.set()
            th.join(timeout_s)
            if th.is_alive():
                log.warning("rerun: the logging thread did not finish within %.0f s", timeout_s)
        rec, self.recording = self.recording, None
        finish = getattr(self.handler, "finish", None)
        if rec is not None and finish is not None:
            try:
                finish(rec)  # whatever the handler still buffers
            except Exception as exc:
                self.handler_errors += 1
                log.warning("rerun: the last buffered rows were not logged: %r", exc)
        if rec is not None:
            try:
                rec.flush(timeout_sec=timeout_s)
            except Exception as exc:  # a viewer that went away must not fail the flight's report
                log.warning("rerun: flushing the recording failed: %s", exc)
            rec.disconnect()

    def __enter__(self) -> Recorder:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- producer side (the control loop) -------------------------------------------------------------
    def put(self, item: Any) -> bool:
        """Queue one item for the handler; False (and ``dropped`` + 1) when the queue is full. Never blocks."""
        q = self._q
        if len(q) >= self.max_queue:
            self.dropped += 1
            return False
        q.append(item)
        self.queued += 1
        return True

    @property
    def pending(self) -> int:
        return len(self._q)

    def stats(self) -> dict[str, Any]:
        """Counters: items queued and dropped, batches handled, handler errors, the thread's CPU time (s)."""
        return {"queued": self.queued, "dropped": self.dropped, "batches": self.batches,
                "handler_errors": self.handler_errors, "worker_cpu_s": round(self.worker_cpu_s, 4)}

    # -- the logging thread -----------------------------------------------------------------------------
    def _run(self) -> None:
        q = self._q
        while True:
            stopping = self._stop.wait(self.flush_s)
            n = len(q)
            if n:
                items = [q.popleft() for _ in range(n)]
                c0 = time.thread_time()
                try:
                    assert self.recording is not None
                    self.handler(self.recording, items)
                except Exception as exc:
                    self.handler_errors += 1
                    now = time.monotonic()
                    if now - self._last_error_log >= 1.0:
                        self._last_error_log = now
                        log.warning("rerun: a batch of %d items was not logged: %r (%d so far)", n, exc,
                                    self.handler_errors, exc_info=self.handler_errors == 1)
                self.worker_cpu_s += time.thread_time() - c0
                self.batches += 1
            if stopping and not q:
                return
