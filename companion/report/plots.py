"""Post-flight figures like the paper's (headless matplotlib, Agg backend), written as PNG.

* ``plan.png`` — 2-D plan view (Figs. 11–12): trunks (mission ones brown, trunks added live over Zenoh orange and
  hatched, labelled with their publisher) with their safe-distance rings and a drawn crown, quadrotor and
  payload tracks, the envelope circle R_max drawn along the way, start and goal; a legend names each.
* ``timeseries.png`` — position, attitude and swing angles over mission time (Figs. 6, 8, 9), 0 at the
  mission's first tick (the log's first row), not at the autopilot's boot.
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
from matplotlib.lines import Line2D
from matplotlib.patches import Circle, Patch

from companion.core.obstacles import Obstacle

CROWN_M = 0.6  # the paper's figures draw each tree's crown around its trunk; ours is drawn r + 0.6 m (picture only)
RGB_MISSION = "saddlebrown"
RGB_LIVE = "darkorange"


def _short_source(source: str) -> str:
    """``slungpilot/1/obstacles/in/lidar`` → ``lidar`` (the publisher's name, the key's last chunk)."""
    return source.rstrip("/").rsplit("/", 1)[-1] or source


def _legs_and_fence(ax, start, goal, waypoints: Sequence = (), fence=None) -> None:
    """A multi-leg mission's planned legs (start → waypoints → goal, dashed), its waypoints (circles; squares
    where the flight holds, labelled with name and hold) and the fence's zones (inclusion dashed green, exclusion
    hatched red)."""
    if waypoints:
        pts = np.array([start[:2], *[w.pos_ned_m[:2] for w in waypoints], goal[:2]], dtype=np.float64)
        ax.plot(pts[:, 1], pts[:, 0], color="purple", lw=0.8, ls="--", alpha=0.7, label="legs (as planned)", zorder=3)
        for k, w in enumerate(waypoints):
            hold = w.hold_s > 0.0
            ax.plot(w.pos_ned_m[1], w.pos_ned_m[0], "s" if hold else "o", color="purple", ms=7, mfc="none", zorder=5,
                    label=("waypoint (square: hold)" if k == 0 else None))
            text = f"{k + 1} {w.name}" + (f" (hold {w.hold_s:g} s)" if hold else "")
            ax.annotate(text, (w.pos_ned_m[1], w.pos_ned_m[0]), xytext=(6, -10), textcoords="offset points",
                        fontsize=7, color="purple", zorder=6)
    if fence is None:
        return
    for z in fence.polygons:
        v = np.array(z.vertices_ne_m + z.vertices_ne_m[:1], dtype=np.float64)
        if z.inclusion:
            ax.plot(v[:, 1], v[:, 0], color="green", ls="--", lw=1.0, zorder=2)
        else:
            ax.fill(v[:, 1], v[:, 0], facecolor="none", edgecolor="red", hatch="xx", lw=1.0, zorder=2)
    for c in fence.circles:
        ax.add_patch(Circle((c.center_ne_m[1], c.center_ne_m[0]), c.radius_m, fill=False, zorder=2, lw=1.0,
                            **({"ls": "--", "color": "green"} if c.inclusion else {"hatch": "xx", "color": "red"})))
    ax.plot([], [], color="green", ls="--", label="fence: inclusion zone")
    ax.plot([], [], color="red", lw=1.0, label="fence: exclusion zone (hatched)")


def _plan(ax, a: Mapping[str, np.ndarray], obstacles: Sequence[Obstacle], start, goal, title: str,
          waypoints: Sequence = (), fence=None) -> None:
    live_sources: list[str] = []
    for o in obstacles:
        live = o.source != "mission"
        colour = RGB_LIVE if live else RGB_MISSION
        ax.add_patch(Circle((o.y_m, o.x_m), o.radius_m, facecolor=colour, edgecolor="black" if live else colour,
                            hatch="///" if live else None, alpha=0.85, zorder=3))
        ax.add_patch(Circle((o.y_m, o.x_m), o.radius_m + o.safe_distance_m, fill=False, ls="--",
                            color=colour, lw=0.8, zorder=3))
        ax.add_patch(Circle((o.y_m, o.x_m), o.radius_m + CROWN_M, color="green", alpha=0.12, zorder=1))
        if live:
            name = _short_source(o.source)
            if name not in live_sources:
                live_sources.append(name)
            ax.annotate(f"live: {name}", (o.y_m, o.x_m), xytext=(6, 6), textcoords="offset points", fontsize=7,
                        color=RGB_LIVE, zorder=6)
    pos = a["pos_ned_m"]
    pay = a["payload_pos_ned_m"]
    ax.plot(pos[:, 1], pos[:, 0], color="tab:blue", lw=1.6, label="quadrotor", zorder=4)
    ok = np.all(np.isfinite(pay), axis=1)
    ax.plot(pay[ok, 1], pay[ok, 0], color="tab:red", lw=1.0, label="payload", zorder=4)
    if "ref_pos_ned_m" in a:
        ref = a["ref_pos_ned_m"]
        okr = np.all(np.isfinite(ref), axis=1)
        ax.plot(ref[okr, 1], ref[okr, 0], color="gray", lw=0.8, ls=":", label="reference", zorder=4)
    handles_extra: list = []
    if "r_max_m" in a and len(pos):
        r = a["r_max_m"]
        step = max(1, len(pos) // 25)
        for i in range(0, len(pos), step):
            if np.isfinite(r[i]):
                ax.add_patch(Circle((pos[i, 1], pos[i, 0]), r[i], fill=False, color="tab:blue", alpha=0.25,
                                    lw=0.6, zorder=2))
        handles_extra.append(Line2D([], [], ls="none", marker="o", mfc="none", mec="tab:blue", alpha=0.5, ms=9,
                                    label=f"swing envelope R_max (every {step}-th tick)"))
    _legs_and_fence(ax, start, goal, waypoints, fence)
    ax.plot(start[1], start[0], "k^", ms=8, label="start", zorder=5)
    ax.plot(goal[1], goal[0], "k*", ms=12, label="goal", zorder=5)
    ax.set_xlabel("east y (m)")
    ax.set_ylabel("north x (m)")
    ax.set_aspect("equal")
    ax.grid(alpha=0.3)
    ax.set_title(title)
    handles, _ = ax.get_legend_handles_labels()
    handles += handles_extra
    if any(o.source == "mission" for o in obstacles):
        handles.append(Patch(facecolor=RGB_MISSION, alpha=0.85, label="trunk (mission file)"))
    if live_sources:
        handles.append(Patch(facecolor=RGB_LIVE, edgecolor="black", hatch="///", alpha=0.85,
                             label="trunk added live: " + ", ".join(live_sources)))
    if obstacles:
        handles.append(Line2D([], [], ls="--", color=RGB_MISSION, lw=0.8, label="safe distance (radius + d_s)"))
        handles.append(Patch(facecolor="green", alpha=0.12, label=f"crown (radius + {CROWN_M} m, drawing only)"))
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8, borderaxespad=0.0)


def plot_plan(a: Mapping[str, np.ndarray], obstacles, start, goal, path: Path, title: str = "",
              waypoints: Sequence = (), fence=None) -> Path:
    """Plan view (Figs. 11–12) to ``path``; a multi-leg mission's ``waypoints`` and ``fence`` drawn too."""
    fig, ax = plt.subplots(figsize=(9, 8))
    _plan(ax, a, obstacles, start, goal, title or "plan view", waypoints, fence)
    fig.tight_layout()
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return path


def plot_timeseries(a: Mapping[str, np.ndarray], path: Path, title: str = "") -> Path:
    """Position, attitude and swing over mission time (Figs. 6, 8, 9) to ``path``."""
    fig = timeseries_figure(a, title)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def timeseries_figure(a: Mapping[str, np.ndarray], title: str = ""):
    """The figure of :func:`plot_timeseries` (the caller closes it)."""
    t = np.asarray(a["t_s"], dtype=np.float64)
    t = t - t[0] if len(t) else t  # mission time: the log starts at the mission's first tick, not at boot
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
    axs[2].set_xlabel("mission time (s, from the mission's first tick)")
    axs[2].legend(loc="best", fontsize=8)
    for ax in axs:
        ax.grid(alpha=0.3)
    if title:
        axs[0].set_title(title)
    fig.tight_layout()
    return fig


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


def plot_flight(a: Mapping[str, np.ndarray], obstacles, start, goal, out_dir: Path, title: str = "",
                waypoints: Sequence = (), fence=None) -> list[Path]:
    """All three figures into ``out_dir``; returns their paths. ``waypoints`` (:class:`~companion.core.mission.
    Waypoint` s) and ``fence`` (:class:`~companion.core.fence.Fence`) are marked on the plan view."""
    out_dir.mkdir(parents=True, exist_ok=True)
    return [
        plot_plan(a, obstacles, start, goal, out_dir / "plan.png", title, waypoints, fence),
        plot_timeseries(a, out_dir / "timeseries.png", title),
        plot_3d(a, obstacles, out_dir / "trajectory3d.png", title),
    ]
