"""Multi-run comparison figures (headless matplotlib, PNG) for ``experiments`` and ``evaluate``.

Inputs are the per-tick arrays of :func:`companion.report.run_folder.log_arrays` as saved in each run folder's
``flight_log.npz`` (``t_s``, ``pos_ned_m``, ``payload_pos_ned_m``, ``swing``, ``r_max_m`` …), keyed by the
run's label (controller or planner name).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Circle

from companion.core.obstacles import Obstacle
from companion.report.plots import draw_trunks_3d

Arrays = Mapping[str, np.ndarray]
DPI = 90


def load_arrays(run_dir: Path) -> dict[str, np.ndarray]:
    """The per-tick arrays of a run folder (``flight_log.npz``)."""
    with np.load(run_dir / "flight_log.npz") as z:
        return {k: z[k] for k in z.files}


def _save(fig: Any, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def plot_swing_comparison(runs: Mapping[str, Arrays], path: Path, title: str = "") -> Path:
    """α and β over time, one row per run (Figs. 6, 8, 9: the swing panels), with the ±0.05 rad band."""
    fig, axs = plt.subplots(len(runs), 1, figsize=(8, 2.2 * len(runs) + 0.6), sharex=True, squeeze=False)
    for ax, (label, a) in zip(axs[:, 0], runs.items(), strict=True):
        ax.plot(a["t_s"], a["swing"][:, 0], label="α", lw=1.0)
        ax.plot(a["t_s"], a["swing"][:, 1], label="β", lw=1.0)
        for lim in (0.05, -0.05):
            ax.axhline(lim, color="gray", lw=0.6, ls="--")
        ax.set_ylabel(f"{label}\nswing (rad)")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
    axs[-1, 0].set_xlabel("time (s)")
    if title:
        axs[0, 0].set_title(title)
    return _save(fig, path)


def plot_estimate_vs_truth(runs: Mapping[str, Arrays], path: Path, title: str = "") -> Path:
    """The swing estimate (dashed) against the vehicle's cable sensor (solid), α and β, one row per run; the
    estimate is NaN before the estimator started (it starts after the take-off climb)."""
    fig, axs = plt.subplots(len(runs), 1, figsize=(8, 2.4 * len(runs) + 0.6), sharex=True, squeeze=False)
    for ax, (label, a) in zip(axs[:, 0], runs.items(), strict=True):
        t, s, e = a["t_s"], a["swing"], a["swing_estimate"]
        for k, (name, colour) in enumerate((("α", "C0"), ("β", "C1"))):
            ax.plot(t, s[:, k], color=colour, lw=1.0, label=f"{name} true")
            ax.plot(t, e[:, k], color=colour, lw=1.0, ls="--", label=f"{name} estimate")
        ax.set_ylabel(f"{label}\nswing (rad)")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=7, ncol=2)
    axs[-1, 0].set_xlabel("time (s)")
    if title:
        axs[0, 0].set_title(title)
    return _save(fig, path)


def plot_position_comparison(runs: Mapping[str, Arrays], goal: Sequence[float], path: Path, title: str = "") -> Path:
    """x, y and altitude over time for every run, with the goal as dashed lines (Fig. 6's position panel)."""
    fig, axs = plt.subplots(3, 1, figsize=(8, 6.5), sharex=True)
    for i, lbl in enumerate(("north x (m)", "east y (m)", "altitude (m)")):
        sgn = -1.0 if i == 2 else 1.0
        for k, (label, a) in enumerate(runs.items()):
            axs[i].plot(a["t_s"], sgn * a["pos_ned_m"][:, i], color=f"C{k}", lw=1.1, label=label)
        axs[i].axhline(sgn * goal[i], color="k", lw=0.7, ls="--")
        axs[i].set_ylabel(lbl)
        axs[i].grid(alpha=0.3)
    axs[0].legend(loc="best", fontsize=8)
    axs[-1].set_xlabel("time (s)")
    if title:
        axs[0].set_title(title)
    return _save(fig, path)


def _draw_plan(ax: Any, a: Arrays, obstacles: Sequence[Obstacle], start, goal, title: str) -> None:
    for o in obstacles:
        ax.add_patch(Circle((o.y_m, o.x_m), o.radius_m, color="saddlebrown", alpha=0.85, zorder=3))
        ax.add_patch(Circle((o.y_m, o.x_m), o.radius_m + o.safe_distance_m, fill=False, ls="--",
                            color="saddlebrown", lw=0.7, zorder=3))
    pos, pay = a["pos_ned_m"], a["payload_pos_ned_m"]
    r = a.get("r_max_m")
    if r is not None:
        for i in range(0, len(pos), max(1, len(pos) // 30)):
            if np.isfinite(r[i]):
                ax.add_patch(Circle((pos[i, 1], pos[i, 0]), r[i], fill=False, color="tab:blue", alpha=0.2, lw=0.5))
    ax.plot(pos[:, 1], pos[:, 0], color="tab:blue", lw=1.4, label="quadrotor", zorder=4)
    ok = np.all(np.isfinite(pay), axis=1)
    ax.plot(pay[ok, 1], pay[ok, 0], color="tab:red", lw=0.9, label="payload", zorder=4)
    ax.plot(start[1], start[0], "k^", ms=7, zorder=5)
    ax.plot(goal[1], goal[0], "k*", ms=11, zorder=5)
    ax.set_aspect("equal")
    ax.grid(alpha=0.3)
    ax.set_xlabel("east y (m)")
    ax.set_title(title, fontsize=10)


def plot_plan_comparison(runs: Mapping[str, Arrays], obstacles: Sequence[Obstacle], start, goal, path: Path,
                         titles: Mapping[str, str] | None = None) -> Path:
    """Plan views side by side, one per run (Figs. 11–12), same axes; envelope circles along the track."""
    ys = np.concatenate([a["pos_ned_m"][:, 1] for a in runs.values()] + [np.array([start[1], goal[1]])])
    xs = np.concatenate([a["pos_ned_m"][:, 0] for a in runs.values()] + [np.array([start[0], goal[0]])])
    ys, xs = ys[np.isfinite(ys)], xs[np.isfinite(xs)]
    ylim = (min(-2.5, float(ys.min()) - 0.5), max(2.5, float(ys.max()) + 0.5))  # east, drawn horizontally
    xlim = (float(xs.min()) - 1.0, float(xs.max()) + 1.0)
    width = 0.8 + 0.55 * (ylim[1] - ylim[0])  # equal aspect: panel width follows the east extent
    fig, axs = plt.subplots(1, len(runs), figsize=(width * len(runs), 6.2), sharey=True, squeeze=False)
    for ax, (label, a) in zip(axs[0], runs.items(), strict=True):
        _draw_plan(ax, a, obstacles, start, goal, (titles or {}).get(label, label))
        ax.set_xlim(*ylim)
        ax.set_ylim(*xlim)
    axs[0, 0].set_ylabel("north x (m)")
    axs[0, 0].legend(loc="lower left", fontsize=8)
    return _save(fig, path)


def plot_3d_comparison(runs: Mapping[str, Arrays], obstacles: Sequence[Obstacle], path: Path, title: str = "") -> Path:
    """3-D quadrotor (solid) and payload (dotted) trajectories of every run in one view (Figs. 7, 10)."""
    fig = plt.figure(figsize=(7.5, 5.5))
    ax = fig.add_subplot(projection="3d")
    draw_trunks_3d(ax, obstacles, n=20, lw=0.5)
    for k, (label, a) in enumerate(runs.items()):
        pos, pay = a["pos_ned_m"], a["payload_pos_ned_m"]
        ax.plot(pos[:, 0], pos[:, 1], -pos[:, 2], color=f"C{k}", lw=1.2, label=f"{label} quadrotor")
        ok = np.all(np.isfinite(pay), axis=1)
        ax.plot(pay[ok, 0], pay[ok, 1], -pay[ok, 2], color=f"C{k}", lw=0.8, ls=":", label=f"{label} payload")
    ax.set_xlabel("north x (m)")
    ax.set_ylabel("east y (m)")
    ax.set_zlabel("altitude (m)")
    ax.legend(loc="upper left", fontsize=7)
    if title:
        ax.set_title(title)
    return _save(fig, path)


def plot_success_vs_density(summary: Mapping[str, Any], path: Path) -> Path:
    """Success rate (%) against density (trunks/100 m²), one line per planner, from an evaluate summary."""
    fig, ax = plt.subplots(figsize=(6, 4))
    dens = [float(d) for d in summary["densities"]]
    for k, (p, per) in enumerate(summary["per_density"].items()):
        rates = [100.0 * (per[f"{d:g}"]["success_rate"] or 0.0) for d in dens]
        ax.plot(dens, rates, marker="o", color=f"C{k}", label=p)
    ax.set_xlabel("density (trunks per 100 m²)")
    ax.set_ylabel("success rate (%)")
    ax.set_ylim(-3, 103)
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=9)
    ax.set_title(f"{summary['n_per_planner_and_density']} forests per point, {summary['mode']} mode", fontsize=10)
    return _save(fig, path)


def plot_envelope(summary: Mapping[str, Any], path: Path) -> Path:
    """Heat maps of ``evaluate --envelope``: per wind (columns), payload mass × cable length of the clean rate,
    the worst max swing (rad), the largest angle the wind alone hung the payload at and the largest swing of the
    payload under an airframe held still in the same wind (rad, :mod:`companion.report.wind_truth`; empty without a
    physical wind) and the median time over the physical bound (rows)."""
    cells = summary["cells"]
    winds = list(dict.fromkeys(c["wind"] for c in cells))
    masses = sorted({c["mass_kg"] for c in cells})
    cables = sorted({c["cable_m"] for c in cells})
    rows = (("clean_rate", "clean rate", "RdYlGn", (0.0, 1.0)),
            ("max_swing_worst_rad", "worst max swing (rad)", "magma_r", (0.0, 0.5)),
            ("wind_drag_angle_worst_rad", "the wind alone: drag angle (rad)", "magma_r", (0.0, 0.5)),
            ("held_swing_worst_rad", "held still: worst swing (rad)", "magma_r", (0.0, 0.5)),
            ("time_over_bound_median", "time / bound (median)", "viridis_r", (1.0, 3.0)))
    fig, axes = plt.subplots(len(rows), len(winds), figsize=(3.2 * len(winds), 2.8 * len(rows)), squeeze=False)
    for j, w in enumerate(winds):
        for i, (key, label, cmap, (lo, hi)) in enumerate(rows):
            grid = np.full((len(masses), len(cables)), np.nan)
            for c in cells:
                if c["wind"] == w and c.get(key) is not None:
                    grid[masses.index(c["mass_kg"]), cables.index(c["cable_m"])] = c[key]
            ax = axes[i][j]
            im = ax.imshow(grid, cmap=cmap, vmin=lo, vmax=hi, origin="lower", aspect="auto")
            for (a, b), v in np.ndenumerate(grid):
                dark = not np.isnan(v) and sum(im.cmap(im.norm(v))[:3]) < 1.2  # white figures on dark cells
                ax.text(b, a, "—" if np.isnan(v) else f"{v:.2f}", ha="center", va="center", fontsize=7,
                        color="white" if dark else "black")
            ax.set_xticks(range(len(cables)), [f"{v:g}" for v in cables])
            ax.set_yticks(range(len(masses)), [f"{v:g}" for v in masses])
            ax.set_xlabel("cable (m)")
            ax.set_ylabel("payload (kg)")
            ax.set_title(f"{w}: {label}", fontsize=9)
            fig.colorbar(im, ax=ax, fraction=0.046)
    return _save(fig, path)
