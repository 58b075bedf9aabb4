"""The swing estimator's measurement timeline: measurements kept as time-ordered events for ``history_s``.

An in-order measurement waits ``reorder_s`` for others that belong before it, then is fused in time order. A late
one (older than the newest fused) is inserted at its time, the event after it is fused again in full, and the
rest are corrected linearly with their stored gains and transitions (:meth:`EventTimeline._replay`). Older than
the history's start it is dropped and counted (``dropped_late``). Times in s on the vehicle's clock.

A mixin of :class:`~companion.estimation.swing_estimator.SwingEstimator`, whose filter step (``_apply``), settings
(``cfg``) and input histories it uses.
"""

from __future__ import annotations

import bisect
import heapq
import math

import numpy as np

from companion.estimation.swing_ekf_parts import IDENTITY, Event


class EventTimeline:
    """The events of :class:`~companion.estimation.swing_estimator.SwingEstimator`: ``_base`` (the state before
    the first kept event), ``_events`` (fused, time order), ``_pending`` (waiting ``reorder_s``)."""

    def _add_event(self, t_s: float, kind: str, z, sigma) -> None:
        """One measurement (``kind`` imu, fix or vel; value ``z`` and 1σ ``sigma``, 3 each) valid at ``t_s``."""
        t = float(t_s)
        zz = np.asarray(z, dtype=np.float64).reshape(3)
        sg = np.broadcast_to(np.asarray(sigma, dtype=np.float64), (3,)).copy()
        if not (math.isfinite(t) and np.all(np.isfinite(zz)) and np.all(np.isfinite(sg)) and np.all(sg > 0.0)):
            raise ValueError(f"{kind} measurement at t={t_s!r}: non-finite value or sigma")
        if t < self._base.t:
            self.dropped_late += 1
            return

        ev = Event(t=t, seq=self._seq, kind=kind, z=zz, sigma=sg)
        self._seq += 1
        evs = self._events
        if not evs or t >= evs[-1].t:  # in order: wait ``reorder_s`` for others that belong before it
            heapq.heappush(self._pending, (t, ev.seq, ev))
            self._flush(t - self.cfg.reorder_s)
            return
        else:  # late: insert at its time and replay what follows
            i = bisect.bisect_right([e.t for e in evs], t)
            evs.insert(i, ev)
            prev = evs[i - 1] if i > 0 else self._base
            self._apply(ev, prev.x, prev.P, prev.t)
            nxt = evs[i + 1]  # its interval changed: process it again in full
            x_old, P_old = nxt.x, nxt.P
            self._apply(nxt, ev.x, ev.P, ev.t)
            self._replay(i + 2, nxt.x - x_old, nxt.P - P_old)
        self._version += 1
        self._prune()

    def _flush(self, t_upto: float) -> None:
        """Apply the waiting measurements up to ``t_upto``, in time order."""
        pend = self._pending
        if not pend or pend[0][0] > t_upto:
            return
        evs = self._events
        while pend and pend[0][0] <= t_upto:
            ev = heapq.heappop(pend)[2]
            prev = evs[-1] if evs else self._base
            self._apply(ev, prev.x, prev.P, prev.t)
            evs.append(ev)
        self._version += 1
        self._prune()

    def _prune(self) -> None:
        evs = self._events
        t_cut = evs[-1].t - self.cfg.history_s
        k = 0
        while k < len(evs) - 1 and evs[k].t < t_cut:
            k += 1
        if k:
            self._base = evs[k - 1]
            del evs[:k]
        keep = self._base.t - 0.1
        self._att.prune(keep)
        self._thr.prune(keep)
        self._pos.prune(keep)

    def _replay(self, start: int, dx: np.ndarray, dP: np.ndarray) -> None:
        """Events[start:] again after the one before them changed by (dx, dP) because of a late measurement. With
        their stored gains and transitions T = (I − K·H)·Φ the change carries through linearly: x_k += M_k·dx,
        P_k += M_k·dP·M_kᵀ with M_k = T_k···T_start — exact for the linearized filter with those gains (the
        covariance of any gain, Joseph's form), and a few µs per event instead of running the filter again."""
        M = IDENTITY
        for e in self._events[start:]:
            M = e.T @ M
            e.x = e.x + M @ dx
            P = e.P + M @ dP @ M.T
            e.P = 0.5 * (P + P.T)

    @property
    def t_processed_s(self) -> float:
        """Time of the newest processed measurement (or the start)."""
        return self._events[-1].t if self._events else self._base.t

    def _frontier(self) -> Event:
        return self._events[-1] if self._events else self._base
