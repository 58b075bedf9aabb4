"""The disk writer thread: the caller never waits for the disk, and nothing handed over is lost or reordered.

A stalled disk is made with a real FIFO where a file is to be written: ``open()`` of a FIFO for writing blocks in
the kernel until a reader comes, exactly like a write stuck behind a busy disk, with no mock in the way.
"""

from __future__ import annotations

import io
import os
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from companion.config import shipped_missions
from companion.core.mission import load_mission
from companion.disk_writer import DiskWriter
from companion.mavlink_io.link import TlogWriter
from companion.report.journal import JOURNAL, PARTIAL, Journal, read_journal
from companion.report.metrics import FlightLog

pytestmark = pytest.mark.paired  # wall clock, light: may run beside one other such test (tests/conftest.py)

CALL_BOUND_S = 10.0  # only a hang would take this long: the calls under test return in microseconds


def _returns(fn, *args) -> bool:
    """Run ``fn(*args)`` on a thread; True if it returned (a call blocked on the disk would not)."""
    t = threading.Thread(target=fn, args=args, daemon=True)
    t.start()
    t.join(CALL_BOUND_S)
    return not t.is_alive()


def _until_taken(w: DiskWriter, n: int) -> None:
    """Wait until the writer thread has taken its n-th batch (it is then inside its writes)."""
    deadline = time.monotonic() + CALL_BOUND_S
    while w.taken < n:
        assert time.monotonic() < deadline, "the writer thread never took its batch"
        time.sleep(0.001)


def _drain_fifo(path: Path) -> bytes:
    """Be the reader the blocked writer waits for; returns what it wrote."""
    with path.open("rb") as fh:
        return fh.read()


def test_appends_keep_their_order_and_a_replaced_file_keeps_its_newest_contents(tmp_path):
    w = DiskWriter()
    w.create(tmp_path / "log.bin")
    for i in range(200):
        w.append(tmp_path / "log.bin", f"{i};".encode())
        w.replace(tmp_path / "state.json", f"{i}".encode())
    assert w.close()
    assert (tmp_path / "log.bin").read_bytes() == "".join(f"{i};" for i in range(200)).encode()
    assert (tmp_path / "state.json").read_text() == "199"
    assert not (tmp_path / "state.json.tmp").exists()
    assert w.errors == 0 and w.batches >= 1


def test_a_stalled_disk_does_not_hold_the_caller_and_loses_nothing(tmp_path):
    os.mkfifo(tmp_path / "state.json.tmp")  # the writer thread's open() of it blocks until a reader comes
    w = DiskWriter()
    w.create(tmp_path / "log.bin")
    w.replace(tmp_path / "state.json", b"first")
    handed_s = time.monotonic()  # "first" was handed over before this
    _until_taken(w, 1)
    # the thread is now stuck in the kernel; every hand-over still returns at once
    for i in range(50):
        assert _returns(w.append, tmp_path / "log.bin", b"%d;" % i)
        assert _returns(w.replace, tmp_path / "state.json", b"newest %d" % i)
    assert w.pending()
    stalled_s = time.monotonic() - handed_s  # "first" is written only after the drain below
    assert _drain_fifo(tmp_path / "state.json.tmp") == b"first"  # the stall ends
    assert w.close()
    assert (tmp_path / "log.bin").read_bytes() == b"".join(b"%d;" % i for i in range(50))
    assert (tmp_path / "state.json").read_bytes() == b"newest 49"
    assert w.lag_s_max >= stalled_s  # the stall shows in the writer's lag


def test_disk_errors_are_counted_not_raised(tmp_path):
    w = DiskWriter()
    w.replace(tmp_path / "gone" / "state.json", b"x")  # its folder does not exist
    w.append(tmp_path / "never-created.bin", b"x")
    assert w.close()
    assert w.errors == 2 and "state.json" in (w.last_error or "")  # appends are written before replaces


def test_close_gives_up_on_a_disk_that_never_answers_and_says_so(tmp_path):
    os.mkfifo(tmp_path / "state.json.tmp")
    w = DiskWriter()
    w.replace(tmp_path / "state.json", b"x")
    assert not w.close(timeout_s=0.2)  # stuck: the caller gets control back
    _drain_fifo(tmp_path / "state.json.tmp")  # release the thread so it does not outlive the test
    assert w.close()


@pytest.fixture
def flog() -> FlightLog:
    log = FlightLog()
    rng = np.random.default_rng(7)
    for k in range(30):
        log.append(0.004 * k, rng.normal(size=3), rng.normal(size=3), rng.normal(size=3), rng.normal(size=4),
                   rng.normal(size=3))
    return log


def test_journal_flushes_while_its_disk_is_stalled_and_the_rows_read_back(tmp_path, flog):
    os.mkfifo(tmp_path / (PARTIAL + ".tmp"))
    j = Journal(tmp_path, flog, load_mission(shipped_missions()["forest"]))
    assert _returns(j.flush, {"outcome": "running", "k": 0})
    _until_taken(j.writer, 1)
    for k in range(1, 3):
        assert _returns(j.flush, {"outcome": "running", "k": k})
    assert _drain_fifo(tmp_path / (PARTIAL + ".tmp")).startswith(b'{"outcome": "running", "k": 0}')
    assert j.close({"outcome": "completed"})
    back = FlightLog()
    assert read_journal(tmp_path, back) == len(flog)
    np.testing.assert_array_equal(np.asarray(back.pos), np.asarray(flog.pos))
    assert back.phase == flog.phase
    assert (tmp_path / PARTIAL).read_text().startswith('{"outcome": "completed"')
    assert j.summary()["lag_s_max"] > 0.0 and j.summary()["errors"] == 0
    assert (tmp_path / JOURNAL).stat().st_size > 0


def test_tlog_records_reach_the_file_in_order(tmp_path):
    t = TlogWriter(tmp_path / "flight.tlog")
    frames = [bytes([0xFD, k % 256]) * (1 + k % 40) for k in range(3000)]  # past the hand-over size
    for f in frames:
        t.write(f)
    t.close()
    raw = io.BytesIO((tmp_path / "flight.tlog").read_bytes())
    for f in frames:
        assert len(raw.read(8)) == 8
        assert raw.read(len(f)) == f
    assert raw.read() == b""


@pytest.mark.slow
def test_a_flight_goes_on_while_its_journal_cannot_write(tmp_path):
    """The journal's first write blocks (a FIFO with no reader where the provisional report is written): the
    companion still connects, arms, climbs and takes over; the journal catches up once the disk answers."""
    from lab.procs import Proc, fly_argv, read_report

    run_dir = tmp_path / "run"
    run_dir.mkdir()
    os.mkfifo(run_dir / (PARTIAL + ".tmp"))
    fly = Proc.start(fly_argv(run_dir, "--sitl", "--no-zenoh"))
    try:
        fly.wait_for("takeover → mission")  # the loop flew the whole start with its journal stuck
        assert (run_dir / PARTIAL).exists() is False
        _drain_fifo(run_dir / (PARTIAL + ".tmp"))  # the disk answers
        assert fly.finish(180) == 0, fly.stderr[-3000:]
    finally:
        fly.kill_all()
    rep = read_report(run_dir)
    assert rep["outcome"] == "completed"
    assert rep["journal"]["errors"] == 0 and rep["journal"]["lag_s_max"] > 0.0
    back = FlightLog()
    assert read_journal(run_dir, back) > 0
