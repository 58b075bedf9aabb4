"""Post-flight figures like the paper's (headless matplotlib, Agg backend), written as PNG.

* ``plan.png`` — 2-D plan view (Figs. 11–12): obstacles with their safe-distance rings, quadrotor and
  payload tracks, the envelope circle R_max drawn along the way, start and goal.
* ``timeseries.png`` — position, attitude and swing angles over time (Figs. 6, 8, 9).
* ``trajectory3d.png`` — the 3-D trajectory of quadrotor and payload with the trunks (Figs. 7, 10).

Input is a mapping of per-tick arrays (``t_s``, ``pos_ned_m`` (N,3), ``payload_pos_ned_m`` (N,3),
``euler_rad`` (N,3), ``swing`` (N,4, NaN where unknown), ``ref_pos_ned_m`` (N,3), ``r_max_m`` (N,),
optional ``euler_cmd_rad`` (N,3)), as :meth:`companion.report.metrics.FlightLog.arrays` returns it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Circle

from companion.core.obstacles import Obstacle


def _plan(ax, a: Mapping[str, np.ndarray], obstacles: Sequence[Obstacle], start, goal, title: str) -> None:
    for o in obstacles:
        ax.add_patch(Circle((o.y_m, o.x_m), o.radius_m, color="saddlebrown", alpha=0.85, zorder=3))
        ax.add_patch(Circle((o.y_m, o.x_m), o.radius_m + o.safe_distance_m, fill=False, ls="--",
                            color="saddlebrown", lw=0.8, zorder=3))
        ax.add_patch(Circle((o.y_m, o.x_m), o.radius_m + 0.6, color="green", alpha=0.12, zorder=1))
    pos = a["pos_ned_m"]
    pay = a["payload_pos_ned_m"]
    ax.plot(pos[:, 1], pos[:, 0], color="tab:blue", lw=1.6, label="quadrotor", zorder=4)
    ok = np.all(np.isfinite(pay), axis=1)
    ax.plot(pay[ok, 1], pay[ok, 0], color="tab:red", lw=1.0, label="payload", zorder=4)
    if "ref_pos_ned_m" in a:
        ref = a["ref_pos_ned_m"]
        okr = np.all(np.isfinite(ref), axis=1)
        ax.plot(ref[okr, 1], ref[okr, 0], color="gray", lw=0.8, ls=":", label="reference", zorder=4)
    if "r_max_m" in a and len(pos):
        r = a["r_max_m"]
        step = max(1, len(pos) // 25)
        for i in range(0, len(pos), step):
            if np.isfinite(r[i]):
                ax.add_patch(Circle((pos[i, 1], pos[i, 0]), r[i], fill=False, color="tab:blue", alpha=0.25,
                                    lw=0.6, zorder=2))
    ax.plot(start[1], start[0], "k^", ms=8, label="start", zorder=5)
    ax.plot(goal[1], goal[0], "k*", ms=12, label="goal", zorder=5)
    ax.set_xlabel("east y (m)")
    ax.set_ylabel("north x (m)")
    ax.set_aspect("equal")
    ax.grid(alpha=0.3)
    ax.set_title(title)
    ax.legend(loc="best", fontsize=8)


def plot_plan(a: Mapping[str, np.ndarray], obstacles, start, goal, path: Path, title: str = "") -> Path:
    """Plan view (Figs. 11–12) to ``path``."""
    fig, ax = plt.subplots(figsize=(6, 8))
    _plan(ax, a, obstacles, start, goal, title or "plan view")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_timeseries(a: Mapping[str, np.ndarray], path: Path, title: str = "") -> Path:
    """Position, attitude and swing over time (Figs. 6, 8, 9) to ``path``."""
    t = a["t_s"]
    fig, axs = plt.subplots(3, 1, figsize=(9, 9), sharex=True)
    for i, (lbl, c) in enumerate((("x", "tab:blue"), ("y", "tab:orange"), ("altitude −z", "tab:green"))):
        sgn = -1.0 if i == 2 else 1.0
        axs[0].plot(t, sgn * a["pos_ned_m"][:, i], color=c, label=lbl)
        if "ref_pos_ned_m" in a:
            axs[0].plot(t, sgn * a["ref_pos_ned_m"][:, i], color=c, ls=":", lw=0.9)
    axs[0].set_ylabel("position (m)")
    axs[0].legend(loc="best", fontsize=8, ncol=3)
    for i, lbl in enumerate(("φ roll", "θ pitch", "ψ yaw")):
        axs[1].plot(t, np.degrees(a["euler_rad"][:, i]), label=lbl)
    if "euler_cmd_rad" in a:
        for i in range(2):
            axs[1].plot(t, np.degrees(a["euler_cmd_rad"][:, i]), ls=":", lw=0.8, color=f"C{i}")
    axs[1].set_ylabel("attitude (deg)")
    axs[1].legend(loc="best", fontsize=8, ncol=3)
    sw = a["swing"]
    axs[2].plot(t, sw[:, 0], label="α")
    axs[2].plot(t, sw[:, 1], label="β")
    for lim in (0.05, -0.05):
        axs[2].axhline(lim, color="gray", lw=0.6, ls="--")
    axs[2].set_ylabel("swing (rad)")
    axs[2].set_xlabel("time (s)")
    axs[2].legend(loc="best", fontsize=8)
    for ax in axs:
        ax.grid(alpha=0.3)
    if title:
        axs[0].set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def draw_trunks_3d(ax, obstacles: Sequence[Obstacle], n: int = 24, lw: float = 0.6) -> None:
    """Wire-frame cylinders (ground to top) for the trunks on a 3-D axis in north/east/altitude."""
    th = np.linspace(0.0, 2.0 * np.pi, n)
    for o in obstacles:
        for h in (0.0, o.height_m):
            ax.plot(o.x_m + o.radius_m * np.cos(th), o.y_m + o.radius_m * np.sin(th), np.full_like(th, h),
                    color="saddlebrown", lw=lw)
        for k in range(0, n, max(1, n // 4)):
            ax.plot([o.x_m + o.radius_m * np.cos(th[k])] * 2, [o.y_m + o.radius_m * np.sin(th[k])] * 2,
                    [0.0, o.height_m], color="saddlebrown", lw=lw)


def plot_3d(a: Mapping[str, np.ndarray], obstacles, path: Path, title: str = "") -> Path:
    """3-D trajectory (Figs. 7, 10), altitude up, to ``path``."""
    fig = plt.figure(figsize=(8, 6))
    ax = fig.add_subplot(projection="3d")
    pos = a["pos_ned_m"]
    pay = a["payload_pos_ned_m"]
    ax.plot(pos[:, 0], pos[:, 1], -pos[:, 2], color="tab:blue", label="quadrotor")
    ok = np.all(np.isfinite(pay), axis=1)
    ax.plot(pay[ok, 0], pay[ok, 1], -pay[ok, 2], color="tab:red", label="payload")
    draw_trunks_3d(ax, obstacles)
    ax.set_xlabel("north x (m)")
    ax.set_ylabel("east y (m)")
    ax.set_zlabel("altitude (m)")
    ax.legend(loc="best", fontsize=8)
    if title:
        ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_flight(a: Mapping[str, np.ndarray], obstacles, start, goal, out_dir: Path, title: str = "") -> list[Path]:
    """All three figures into ``out_dir``; returns their paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    return [
        plot_plan(a, obstacles, start, goal, out_dir / "plan.png", title),
        plot_timeseries(a, out_dir / "timeseries.png", title),
        plot_3d(a, obstacles, out_dir / "trajectory3d.png", title),
    ]
