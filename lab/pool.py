"""Fly a batch of :class:`lab.runner.Job` in parallel and stop cleanly on Ctrl-C.

Three ways to run the jobs, all with the same per-job function (:func:`lab.evaljob.run_eval_job`) and so the
same per-job results:

* ``workers <= 1``: one after the other in this process;
* a local pool of ``workers`` spawned processes (``concurrent.futures.ProcessPoolExecutor``);
* a Dask distributed cluster (``cluster="tcp://host:8786"``, or ``cluster="local"`` for a
  ``LocalCluster`` of ``workers`` processes on 127.0.0.1). Dask is imported only here and only then.

Whatever kills this process, SIGKILL included, its workers die with it and their vehicles with them
(:mod:`companion.proclife`; docs/companion.md, "Process lifetime"); a local Dask cluster's processes exit
when the pipe from their parent closes (Dask's own watch).

Ctrl-C (issue 14): the pool's workers ignore SIGINT and sit in their own process groups, so a terminal's
Ctrl-C reaches this process only and this process decides. On the first SIGINT the pending jobs are cancelled,
every process below this one is frozen (SIGSTOP, repeated until no new child appears, so nothing can fork
past it) and then killed (SIGKILL): the workers, the bundled vehicles they started in their own sessions,
a local Dask cluster's nannies and workers. The results that had arrived are raised with :class:`Interrupted`
(a ``KeyboardInterrupt``) for the caller to write a partial summary. A remote Dask cluster's tasks that are
already running cannot be stopped from the client (Dask cancels only pending ones); they finish on their
workers and their results are dropped.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import logging
import multiprocessing
import os
import signal
import sys
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

from companion import proclife
from lab.evaljob import run_eval_job
from lab.runner import Job

log = logging.getLogger(__name__)


class Interrupted(KeyboardInterrupt):
    """Ctrl-C during a batch: ``results`` holds the jobs that had finished (in job order), ``total`` the
    batch size."""

    def __init__(self, results: list[dict[str, Any]], total: int) -> None:
        super().__init__(f"interrupted after {len(results)} of {total} missions")
        self.results = results
        self.total = total


class Progress:
    """A one-line progress bar on a stream (stderr), redrawn in place; nothing when ``enabled`` is False."""

    def __init__(self, total: int, stream: Any = None, enabled: bool = True, width: int = 30) -> None:
        self.total = max(1, total)
        self.done = 0
        self.counts: dict[str, int] = {}
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self.width = width
        self.t0 = time.monotonic()

    def update(self, cls: str) -> None:
        self.done += 1
        self.counts[cls] = self.counts.get(cls, 0) + 1
        if not self.enabled:
            return
        frac = self.done / self.total
        bar = "#" * round(frac * self.width)
        el = time.monotonic() - self.t0
        eta = el / frac - el if frac > 0 else 0.0
        counts = " ".join(f"{k}={v}" for k, v in sorted(self.counts.items()))
        self.stream.write(f"\r[{bar:<{self.width}}] {self.done}/{self.total} {counts} eta {eta:5.0f} s ")
        if self.done == self.total:
            self.stream.write("\n")
        self.stream.flush()


def _worker_init(level: int, parent_pid: int, counter: Any = None) -> None:
    """Pool worker set-up: tied to the pool's process ``parent_pid`` (it dies with it, SIGKILL included, and
    so do the vehicles it started: :mod:`companion.proclife`), logging, and out of the terminal's reach
    (SIGINT ignored, own process group), so that Ctrl-C is the parent's to handle. (A MAVLink flight still
    installs its own SIGINT handler while it flies; the own process group is what keeps a terminal's Ctrl-C
    away from it.)"""
    proclife.die_with_parent(parent_pid)
    if counter is not None:  # worker k on CPU k (mod the CPUs): its lockstep pairs then never share one
        with counter.get_lock():
            k = counter.value
            counter.value += 1
        cpus = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
        if len(cpus) > 1:
            with contextlib.suppress(OSError):
                os.sched_setaffinity(0, {cpus[k % len(cpus)]})
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger().setLevel(level)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    with contextlib.suppress(OSError):
        os.setpgid(0, 0)


def _children_map() -> dict[int, list[int]]:
    """Parent pid → child pids, from /proc (Linux); empty where there is no /proc."""
    kids: dict[int, list[int]] = {}
    proc = Path("/proc")
    if not proc.is_dir():
        return kids
    for d in proc.iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
        except OSError:
            continue
        # pid (comm) state ppid ...: comm may hold spaces and parentheses, so split after the last ')'
        ppid = int(stat[stat.rindex(")") + 2:].split()[1])
        kids.setdefault(ppid, []).append(int(d.name))
    return kids


def descendants(root: int | None = None) -> set[int]:
    """Every process below ``root`` (default: this process), whatever session or process group it is in."""
    root = os.getpid() if root is None else root
    kids = _children_map()
    out: set[int] = set()
    todo = [root]
    while todo:
        for c in kids.get(todo.pop(), []):
            if c not in out:
                out.add(c)
                todo.append(c)
    return out


def _resource_tracker_pid() -> int | None:
    """multiprocessing's resource tracker (a child of ours): spared, it exits by itself when we do, and killed
    it would be restarted and print a traceback for every semaphore it no longer knows."""
    from multiprocessing import resource_tracker

    return getattr(resource_tracker._resource_tracker, "_pid", None)


def kill_descendants(extra: list[int] | None = None) -> int:
    """Freeze (SIGSTOP) every process below this one until no new one appears, then SIGKILL them all (but
    multiprocessing's resource tracker); returns how many were killed. ``extra``: pids to include even if /proc
    cannot be read (the pool's workers)."""
    spare = {_resource_tracker_pid()}
    frozen: set[int] = set()
    for _ in range(20):
        new = (descendants() | set(extra or ())) - frozen - spare
        if not new:
            break
        for pid in new:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.kill(pid, signal.SIGSTOP)
        frozen |= new
    for pid in frozen:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.kill(pid, signal.SIGKILL)
    return len(frozen)


def _no_sigint() -> contextlib.AbstractContextManager[None]:
    """A second Ctrl-C must not interrupt the clean-up of the first."""
    return proclife.signals_handled(signal.SIG_IGN, signal.SIGINT)


def run_jobs(jobs: list[Job], workers: int, progress: bool = True, log_level: int = logging.ERROR,
             cluster: str | None = None, fn: Callable[[Job], dict[str, Any]] = run_eval_job
             ) -> list[dict[str, Any]]:
    """Fly ``jobs`` and return their results in job order: in ``workers`` spawned processes, in this process
    when ``workers`` <= 1, or on the Dask cluster at ``cluster`` (``"local"``: a LocalCluster of ``workers``
    processes). Raises :class:`Interrupted` on Ctrl-C with the results that had finished."""
    bar = Progress(len(jobs), enabled=progress)
    results: list[dict[str, Any]] = []

    def take(r: dict[str, Any]) -> None:
        bar.update(r["class"])
        results.append(r)

    def ordered() -> list[dict[str, Any]]:
        order = {j.key: i for i, j in enumerate(jobs)}
        return sorted(results, key=lambda r: order[r["key"]])

    try:
        if cluster:
            _run_dask(jobs, cluster, workers, fn, take)
        elif workers <= 1:
            _run_serial(jobs, fn, take)
        else:
            _run_pool(jobs, workers, log_level, fn, take)
    except KeyboardInterrupt:
        if progress:
            sys.stderr.write("\n")
        raise Interrupted(ordered(), len(jobs)) from None
    return ordered()


def _run_serial(jobs: list[Job], fn: Callable[[Job], dict[str, Any]], take: Callable[[dict], None]) -> None:
    for j in jobs:
        r = fn(j)
        if r.get("outcome") == "aborted":  # a MAVLink flight takes the Ctrl-C itself: it held, landed, returned
            raise KeyboardInterrupt
        take(r)


def _run_pool(jobs: list[Job], workers: int, log_level: int, fn: Callable[[Job], dict[str, Any]],
              take: Callable[[dict], None]) -> None:
    ctx = multiprocessing.get_context("spawn")
    # the workers are started from this thread (submit, spawn context), which lives as long as the pool
    pool = cf.ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_worker_init,
                                  initargs=(log_level, os.getpid(), ctx.Value("i", 0)))
    futs: list[cf.Future] = []
    try:
        futs = [pool.submit(fn, j) for j in jobs]
        for f in cf.as_completed(futs):
            take(f.result())
    except BaseException:
        with _no_sigint():
            t0 = time.monotonic()
            for f in futs:
                f.cancel()
            workers_pids = list(getattr(pool, "_processes", {}) or {})
            n = kill_descendants(workers_pids)
            pool.shutdown(wait=True, cancel_futures=True)
            log.info("stopped: %d processes killed in %.2f s", n, time.monotonic() - t0)
        raise
    pool.shutdown(wait=True)


def check_cluster(cluster: str | None) -> None:
    """Refuse ``--cluster`` up front (ConfigError, exit 2) when Dask's ``distributed`` is not installed."""
    import importlib.util

    from companion.errors import ConfigError

    if cluster and importlib.util.find_spec("distributed") is None:
        raise ConfigError("--cluster: needs Dask's 'distributed' (pip install 'slungpilot[cluster]')")


def _dask_job(fn: Callable[[Job], dict[str, Any]], job: Job, level: int) -> dict[str, Any]:
    """One job on a Dask worker, with the flight's own loggers as quiet as in a pool worker (:func:`_worker_init`)."""
    for name in ("companion", "lab", "sim_bridge"):
        logging.getLogger(name).setLevel(level)
    return fn(job)


def _run_dask(jobs: list[Job], address: str, workers: int, fn: Callable[[Job], dict[str, Any]],
              take: Callable[[dict], None]) -> None:
    from dask.distributed import Client, LocalCluster, as_completed

    # Dask sets its loggers to INFO on import; follow this command's -v instead
    logging.getLogger("distributed").setLevel(logging.getLogger().getEffectiveLevel())
    local = None
    if address == "local":
        local = LocalCluster(n_workers=max(1, workers), threads_per_worker=1, processes=True, host="127.0.0.1",
                             dashboard_address=None, silence_logs=logging.ERROR)
        client = Client(local)
    else:
        client = Client(address, timeout=30)
    futs: list[Any] = []
    try:
        level = logging.getLogger().getEffectiveLevel()
        batch = uuid.uuid4().hex[:12]  # task keys unique on a scheduler other batches may share
        futs = [client.submit(_dask_job, fn, j, max(level, logging.ERROR), key=f"slungpilot-{j.key}-{batch}",
                              pure=False) for j in jobs]
        for f in as_completed(futs):
            take(f.result())
    except BaseException:
        with _no_sigint():
            logging.getLogger("distributed").setLevel(logging.ERROR)  # the workers we kill are no news
            with contextlib.suppress(Exception):
                client.cancel(futs, force=True)
            if local is not None:  # its workers (and the vehicles they started) are ours: stop them now
                kill_descendants()
        raise
    finally:
        with _no_sigint():
            with contextlib.suppress(Exception):
                client.close(timeout=5)
            if local is not None:
                with contextlib.suppress(Exception):
                    local.close(timeout=5)
