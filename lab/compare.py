"""The physical bound a planner is measured against, and the figure that compares planners on it.

Bound (issue 12): keeping the swing below 0.3 rad allows a lateral (more precisely: any horizontal)
acceleration of about g·tan(0.3) ≈ 3.0 m/s²; a point mass that may accelerate that hard covers a straight
distance D from rest to rest in 2·sqrt(D / (g·tan 0.3)) at best (bang-bang: accelerate half the way,
brake the other half). No obstacle, no jerk limit, no tracking lag: a lower bound on the time to goal.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

BOUND_SWING_RAD = 0.3
G_MPS2 = 9.81


def bound_time_s(distance_m: float, swing_rad: float = BOUND_SWING_RAD, g_mps2: float = G_MPS2) -> float:
    """Bang-bang rest-to-rest time (s) over ``distance_m`` at the lateral acceleration g·tan(swing)."""
    a = g_mps2 * math.tan(swing_rad)
    return 2.0 * math.sqrt(max(distance_m, 0.0) / a)


def plot_comparison(results: Sequence[Mapping[str, Any]], planners: Sequence[str], scenarios: Sequence[str],
                    path: Path, title: str = "") -> Path:
    """Box plots, one colour per planner and one group per scenario: time to goal over the bound (successes),
    max swing, min clearance and path length (successes), every mission of the same seeds; dashed lines at the
    bound and 1.6× it, the swing targets 0.2 / 0.25 rad, zero clearance."""
    fig, axs = plt.subplots(1, 4, figsize=(4.2 * 4, 4.4))
    panels = (("time_over_bound", "time to goal / bound", True, (1.0, 1.6)),
              ("max_swing_rad", "max swing (rad)", False, (0.2, 0.25)),
              ("min_clearance_m", "min clearance (m)", False, (0.0,)),
              ("path_length_m", "path length (m)", True, ()))
    n_p = len(planners)
    width = 0.8 / n_p
    for ax, (key, name, ok_only, lines) in zip(axs, panels, strict=True):
        for i, pl in enumerate(planners):
            data, pos = [], []
            for k, sc in enumerate(scenarios):
                vals = [r.get(key) for r in results if r.get("planner") == pl and r.get("scenario", "static") == sc
                        and (r.get("class") == "success" or not ok_only)]
                data.append([v for v in vals if v is not None and math.isfinite(v)] or [math.nan])
                pos.append(k + (i - (n_p - 1) / 2.0) * width)
            bp = ax.boxplot(data, positions=pos, widths=0.85 * width, patch_artist=True, showfliers=True,
                            flierprops={"markersize": 2})
            for box in bp["boxes"]:
                box.set_facecolor(f"C{i}")
                box.set_alpha(0.6)
            ax.plot([], [], color=f"C{i}", lw=6, alpha=0.6, label=pl)
        ax.set_xticks(np.arange(len(scenarios)), list(scenarios))
        ax.set_xlim(-0.6, len(scenarios) - 0.4)
        for y in lines:
            ax.axhline(y, color="gray", lw=0.7, ls="--")
        ax.set_title(name, fontsize=10)
        ax.grid(alpha=0.3, axis="y")
    axs[0].legend(loc="upper left", fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
