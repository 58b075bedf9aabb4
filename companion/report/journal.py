"""Logs that survive ``kill -9``: the per-tick flight log and a provisional report, flushed to the run folder
at least once a second while flying, so a companion killed at any moment loses at most a second (plus however
long the disk is stalled: the writes happen on a :class:`~companion.disk_writer.DiskWriter` thread, so a slow
disk delays the journal, never the control loop; ``lag_s_max`` in the report's ``journal`` says by how much).

Files (next to what :func:`companion.report.run_folder.write_run` writes at the end):

* ``mission.toml``: the mission as flown (written when the journal opens);
* ``flight_log.journal``: the per-tick rows, appended in chunks, each chunk one ``numpy.save`` array of
  shape (rows, :data:`N_COLUMNS`) float64 (columns in :data:`COLUMNS`; phase and envelope mode as codes);
  a chunk cut short by a kill is ignored on reading;
* ``report.partial.json``: the run facts so far (outcome ``running`` until the end, transitions, link
  health) and the log's ``obstacle_clock_t0_s`` once set (the mission clock's zero the report places moving
  obstacles by), rewritten atomically at each flush.

:func:`rebuild_run` turns them back into ``report.json``, ``summary.txt``, ``flight_log.npz`` and the plots
(``slungpilot report RUN_DIR``).
"""

from __future__ import annotations

import io
import json
import logging
from pathlib import Path
from typing import Any

import numpy as np

from companion.core.mission import Mission, load_mission, mission_to_toml
from companion.disk_writer import DiskWriter
from companion.report.metrics import FlightLog

log = logging.getLogger(__name__)

JOURNAL = "flight_log.journal"
PARTIAL = "report.partial.json"
MISSION = "mission.toml"

#: (FlightLog field, width) in row order
COLUMNS = (("t", 1), ("pos", 3), ("vel", 3), ("euler", 3), ("swing", 4), ("swing_used", 4), ("payload_pos", 3),
           ("ref_pos", 3),
           ("ref_vel", 3), ("ref_acc", 3), ("euler_cmd", 3), ("thrust_n", 1), ("ff_accel", 3), ("force_att", 2),
           ("force_rep", 2), ("r_max_m", 1), ("phase", 1), ("envelope_mode", 1))
N_COLUMNS = sum(w for _, w in COLUMNS)
PHASE_CODES = ("", "climb", "cruise", "hold", "done", "hold_here", "descend", "takeoff", "identify")
ENVELOPE_CODES = ("", "swing", "full_cable")


def _code(table: tuple[str, ...], value: str) -> float:
    try:
        return float(table.index(value))
    except ValueError:
        return -1.0


def _rows(flog: FlightLog, start: int, stop: int) -> np.ndarray:
    """Rows ``start:stop`` of the flight log as a float64 array (N, N_COLUMNS)."""
    cols = []
    for name, width in COLUMNS:
        col = getattr(flog, name)[start:stop]
        if name == "phase":
            cols.append(np.array([_code(PHASE_CODES, v) for v in col], dtype=np.float64)[:, None])
        elif name == "envelope_mode":
            cols.append(np.array([_code(ENVELOPE_CODES, v) for v in col], dtype=np.float64)[:, None])
        elif width == 1:
            cols.append(np.asarray(col, dtype=np.float64)[:, None])
        else:
            cols.append(np.asarray(col, dtype=np.float64).reshape(-1, width))
    return np.hstack(cols)


class Journal:
    """Hands the rows of ``flog`` not yet handed over, and the provisional report, to its disk writer thread
    whenever :meth:`flush` runs. The rows and the JSON are made here (the caller's thread, where ``flog`` grows);
    only the file I/O is the writer's."""

    def __init__(self, run_dir: Path, flog: FlightLog, mission: Mission) -> None:
        self.run_dir = run_dir
        self.flog = flog
        run_dir.mkdir(parents=True, exist_ok=True)
        (run_dir / MISSION).write_text(mission_to_toml(mission))
        self.writer = DiskWriter("journal")
        self.writer.create(run_dir / JOURNAL)
        self._handed = 0
        self._closed = False
        self.flushes = 0

    def flush(self, provisional: dict[str, Any]) -> None:
        """Hand over the new rows and the provisional report; never waits for the disk."""
        if self._closed:
            return
        n = len(self.flog)
        if n > self._handed:
            buf = io.BytesIO()
            np.save(buf, _rows(self.flog, self._handed, n), allow_pickle=False)
            self.writer.append(self.run_dir / JOURNAL, buf.getvalue())
            self._handed = n
        if self.flog.obstacle_clock_t0_s is not None:
            provisional = {**provisional, "obstacle_clock_t0_s": self.flog.obstacle_clock_t0_s}
        self.writer.replace(self.run_dir / PARTIAL, (json.dumps(provisional, default=_jsonable) + "\n").encode())
        self.flushes += 1

    def close(self, provisional: dict[str, Any] | None = None, timeout_s: float = 30.0) -> bool:
        """Flush (with ``provisional`` if given), wait up to ``timeout_s`` for the disk, close; False if the
        disk did not take everything in time. Idempotent."""
        if self._closed:
            return True
        if provisional is not None:
            self.flush(provisional)
        self._closed = True
        return self.writer.close(timeout_s)

    def summary(self) -> dict[str, Any]:
        """For the report: flushes handed over, written batches, the longest wait for the disk (s), errors."""
        w = self.writer
        return {"flushes": self.flushes, "batches": w.batches, "lag_s_max": round(w.lag_s_max, 4),
                "errors": w.errors, "last_error": w.last_error}


def _jsonable(v: Any) -> Any:
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    return str(v)


def read_journal(run_dir: Path, flog: FlightLog) -> int:
    """Append the journal's rows to ``flog``; returns the number of rows read (a torn last chunk is skipped)."""
    path = run_dir / JOURNAL
    n = 0
    with path.open("rb") as fh:
        while True:
            try:
                chunk = np.load(fh, allow_pickle=False)
            except (EOFError, ValueError, OSError):
                break
            if chunk.ndim != 2 or chunk.shape[1] != N_COLUMNS:
                break
            for row in chunk:
                i = 0
                vals = {}
                for name, width in COLUMNS:
                    vals[name] = row[i] if width == 1 else row[i : i + width].copy()
                    i += width
                flog.t.append(float(vals["t"]))
                for name in ("pos", "vel", "euler", "swing", "swing_used", "payload_pos", "ref_pos", "ref_vel",
                             "ref_acc", "euler_cmd", "ff_accel", "force_att", "force_rep"):
                    getattr(flog, name).append(vals[name])
                flog.thrust_n.append(float(vals["thrust_n"]))
                flog.r_max_m.append(float(vals["r_max_m"]))
                pc, ec = int(vals["phase"]), int(vals["envelope_mode"])
                flog.phase.append(PHASE_CODES[pc] if 0 <= pc < len(PHASE_CODES) else "")
                flog.envelope_mode.append(ENVELOPE_CODES[ec] if 0 <= ec < len(ENVELOPE_CODES) else "")
            n += len(chunk)
    return n


def rebuild_run(run_dir: Path, *, plots: bool = True) -> dict[str, Any]:
    """Rebuild ``report.json``, ``summary.txt``, ``flight_log.npz`` and the plots of a run from its journal.

    A run that was still going when its companion died keeps the last provisional facts, with the outcome
    ``interrupted`` (the companion stopped without writing its report) and ``reached_goal`` false. Moving
    obstacles are placed by the partial report's ``obstacle_clock_t0_s``; a run folder without it (written before
    the journal kept it) scores them at their file positions, as its report did then.
    """
    from companion.report.run_folder import write_run

    mission = load_mission(run_dir / MISSION)
    extra: dict[str, Any] = {}
    partial = run_dir / PARTIAL
    if partial.exists():
        try:
            extra = json.loads(partial.read_text())
        except json.JSONDecodeError:
            log.warning("%s is damaged; rebuilding without it", partial)
    if extra.get("outcome", "running") == "running":
        extra["outcome"] = "interrupted"
        extra["outcome_detail"] = "the companion stopped without writing its report; rebuilt from the journal"
    extra["rebuilt_from_journal"] = True
    clock = extra.get("obstacle_clock_t0_s")
    flog = FlightLog(planner=mission.planner, controller=mission.controller, mission=mission.name,
                     obstacles=mission.obstacles,
                     obstacle_clock_t0_s=float(clock) if isinstance(clock, int | float) else None)
    rows = read_journal(run_dir, flog)
    extra["journal_rows"] = rows
    return write_run(flog, mission, extra, run_dir, plots=plots)
