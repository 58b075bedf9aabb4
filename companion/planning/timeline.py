"""The planned motion as a time line: unshaped rows in, shaped reference rows out, spliced on every replan.

Time is a uniform grid of step ``h`` from ``t0``; absolute row k is time t0 + k·h. The time line keeps the
*unshaped* motion u (rows [p, v, a], horizontal NED) from a little history before now to the end of the
current plan, followed by rest at its final point, and the shaped reference computed from it
(:func:`companion.planning.shaping.shape_reference`: airframe p, v, a, jerk and the nominal swing).

A replan replaces u from a row ``k_r`` a few steps ahead of now; the reference at rows before
k_r − 2 depends only on u up to k_r − 1 (the cascade is causal, the central differences look two rows
ahead), so the reference the vehicle is flying does not jump: the shaped motion is continuous in
position, velocity and acceleration across replans, whatever the new plan is.
"""

from __future__ import annotations

import math

import numpy as np

from companion.planning.shaping import REF_COLS, cascade_lag, shape_reference


class Timeline:
    """Unshaped plan and shaped reference on a uniform time grid (see module docstring)."""

    def __init__(self, t0_s: float, pos_m: np.ndarray, h_s: float, widths: tuple[int, int, int],
                 omega_rad_s: float, g_mps2: float) -> None:
        self.t0_s = float(t0_s)
        self.h_s = float(h_s)
        self.widths = widths
        self.omega = float(omega_rad_s)
        self.g = float(g_mps2)
        self.history = cascade_lag(widths) + 8
        self.base = -self.history  # absolute index of row 0
        rest = np.zeros((self.history + self.history + 4, 6))
        rest[:, 0:2] = np.asarray(pos_m, dtype=np.float64)[:2]
        self.u = rest
        self.ref = shape_reference(self.u, widths, h_s, omega_rad_s, g_mps2)
        self._flat = self.ref.ravel().tolist()

    # -- time <-> rows --------------------------------------------------------------------------------
    def index(self, t_s: float) -> int:
        """Absolute row at or before time ``t_s``."""
        return math.floor((t_s - self.t0_s) / self.h_s + 1e-9)

    def time_of(self, k: int) -> float:
        """Time (s) of absolute row ``k``."""
        return self.t0_s + k * self.h_s

    @property
    def end_index(self) -> int:
        """Absolute index one past the last stored row (beyond it: rest at the last row)."""
        return self.base + len(self.u)

    def unshaped_at(self, k: int) -> np.ndarray:
        """Unshaped row [p, v, a] (6,) at absolute row ``k`` (rest at the end beyond the stored rows)."""
        i = k - self.base
        if i >= len(self.u):
            row = self.u[-1].copy()
            row[2:] = 0.0
            return row
        return self.u[max(i, 0)].copy()

    # -- splice ---------------------------------------------------------------------------------------
    def splice(self, k_r: int, rows: np.ndarray, k_now: int) -> None:
        """Replace the unshaped motion from absolute row ``k_r`` by ``rows`` (m, 6), followed by rest at its
        last point; drop history older than the cascade needs before ``k_now``; recompute the reference."""
        self.install(*self.preview(k_r, rows, k_now))

    def install(self, u: np.ndarray, ref: np.ndarray, base: int) -> None:
        """Make a :meth:`preview` the plan. The reference is also kept as one flat list of floats: sampling it
        costs no numpy call per tick, and one list (not one per row) keeps the garbage collector's
        full passes — which scan every surviving container — out of the control loop."""
        self.u, self.ref, self.base = u, ref, base
        self._flat = ref.ravel().tolist()

    def preview(self, k_r: int, rows: np.ndarray, k_now: int) -> tuple[np.ndarray, np.ndarray, int]:
        """What :meth:`splice` would store, without storing it: (u, ref, base)."""
        keep_from = max(0, (k_now - self.history) - self.base)
        cut = k_r - self.base
        head = self.u[keep_from:cut]
        if cut > len(self.u):  # the plan ended before k_r: rest rows fill the gap
            fill = np.repeat(self.unshaped_at(self.end_index)[None, :], cut - len(self.u), axis=0)
            head = np.concatenate([self.u[keep_from:], fill])
        tail = np.repeat(rows[-1:], self.history + 4, axis=0)
        tail[:, 2:] = 0.0
        u = np.concatenate([head, rows, tail])
        ref = shape_reference(u, self.widths, self.h_s, self.omega, self.g)
        return u, ref, self.base + keep_from

    # -- sampling -------------------------------------------------------------------------------------
    def sample(self, t_s: float) -> list[float]:
        """The reference row (REF_COLS floats) at time ``t_s``, linearly interpolated (at rest past the end)."""
        x = (t_s - self.t0_s) / self.h_s - self.base
        flat = self._flat
        n = len(flat) // REF_COLS
        if x >= n - 3:
            j = (n - 3) * REF_COLS
            return flat[j: j + 2] + [0.0] * (REF_COLS - 2)
        i = max(math.floor(x), 0)
        f = min(max(x - i, 0.0), 1.0)
        j = i * REF_COLS
        a, b = flat[j: j + REF_COLS], flat[j + REF_COLS: j + 2 * REF_COLS]
        return [a[c] + f * (b[c] - a[c]) for c in range(REF_COLS)]

    def future(self, k_from: int, ref: np.ndarray | None = None, base: int | None = None) -> tuple[np.ndarray, int]:
        """Reference rows from absolute row ``k_from`` to the end (of ``ref``/``base`` if given) and the absolute
        index of the first one."""
        ref = self.ref if ref is None else ref
        base = self.base if base is None else base
        i = max(k_from - base, 0)
        return ref[i: len(ref) - 2], base + i
