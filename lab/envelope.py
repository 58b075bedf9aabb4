"""``slungpilot evaluate --envelope``: where the payload envelope ends — payload mass × cable length × wind.

Every cell of the grid flies the same random forests (seeds ``seed0 .. seed0 + n - 1``, 4 trunks per 100 m² in
a 6 m corridor by default) with the cell's payload and wind; the vehicle's own mass stays Table 1's. The cell's
flight altitude is the lowest that keeps the hanging payload :data:`GROUND_CLEARANCE_M` above the ground (never
below the forest's 2 m), and the trunks stand :data:`TRUNK_ABOVE_M` above it, so every cell is a flight *under
the canopy* and no cell's result is a payload dragged over the ground.

Per cell: the clean rate (goal reached, no collision), the ``no_route`` and refusal rates, collisions, max swing
(median, worst), the flights over the cell's swing bound, in how many of them the wind alone hung the payload
beyond it (its drag angle, :mod:`companion.report.wind_truth`: no controller meets the bound there) and in how
many the payload under an airframe held still in the same wind would have swung beyond it too
(:func:`~companion.report.wind_truth.held_swing_rad`: the others the controller lost), time over the physical bound
(:mod:`lab.compare`) and ``diverged`` flights.
Output in ``--out``: ``envelope.md`` (the table), ``envelope.json``, ``results.jsonl`` and ``envelope.png`` (heat maps).
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from companion.core.mission import Mission
from companion.core.wind import WindConfig
from lab.forests import ForestSpec, generate_forest
from lab.pool import run_jobs
from lab.runner import Job

log = logging.getLogger(__name__)

MASSES_KG = (0.1, 0.25, 0.5, 0.8)
CABLES_M = (0.5, 1.0, 2.0, 3.0)
WINDS = ("calm", "paper", "light", "moderate")
#: what each grid mission declares of the drags (:func:`cell_mission`)
DRAG_DECLARATIONS = ("declared", "identified", "none")
GROUND_CLEARANCE_M = 1.0  # the payload hangs at least this far above the ground in every cell (m)
TRUNK_ABOVE_M = 3.0  # trunks stand this far above the flight altitude (m): a flight under the canopy
#: the swing each wind may cost (rad): the issue's bound, up to light turbulence 0.25, moderate 0.35
SWING_BOUND_RAD = {"calm": 0.25, "paper": 0.25, "light": 0.25, "moderate": 0.35}
#: the turbulence cells: intensity and mean wind (m/s), as the issue's grid asks
TURBULENCE = {"light": ("light", 3.0), "moderate": ("moderate", 6.0)}
#: the payloads are of one density: the drag area C_d·A grows as m^(2/3) from the wind model's default for Table 1's
#: 0.25 kg payload (a 0.1 kg payload has 0.54x its area, 0.8 kg 2.2x); one area for every mass would make the light
#: payloads sails (0.1 kg trailing 0.2 rad in a steady 6 m/s before any gust)
REFERENCE_PAYLOAD_KG = 0.25


@dataclass(frozen=True)
class Cell:
    """One grid cell: payload mass (kg), cable length (m), wind name (:data:`WINDS`)."""

    mass_kg: float
    cable_m: float
    wind: str

    @property
    def key(self) -> str:
        """``m0.25|l1|paper``: the cell's part of a job key."""
        return f"m{self.mass_kg:g}|l{self.cable_m:g}|{self.wind}"


def wind_config(name: str, seed: int = 0, altitude_m: float = 3.0, payload_kg: float = REFERENCE_PAYLOAD_KG
                ) -> WindConfig:
    """The wind of a grid column: ``calm``, ``paper`` (eq. 49) or a physical wind (:mod:`companion.core.turbulence`:
    a mean wind across the corridor, from the east, with Dryden turbulence of the named intensity at the flight's
    altitude, seeded per forest, dragging a payload of ``payload_kg`` by :data:`REFERENCE_PAYLOAD_KG`'s density)."""
    if name == "calm":
        return WindConfig("none", 0.0)
    if name == "paper":
        return WindConfig("paper", 1.0)
    if name not in TURBULENCE:
        raise ValueError(f"wind: must be one of {', '.join(WINDS)}, got {name!r}")
    intensity, mean = TURBULENCE[name]
    area = WindConfig().payload_drag_area_m2 * (payload_kg / REFERENCE_PAYLOAD_KG) ** (2.0 / 3.0)
    w = WindConfig("turbulence", 1.0, mean_speed_mps=mean, direction_deg=90.0, intensity=intensity,
                   altitude_m=altitude_m, seed=seed, payload_drag_area_m2=area)
    w.validate()
    return w


def cell_spec(cell: Cell, base: ForestSpec) -> ForestSpec:
    """The forest generator's spec for ``cell``: altitude and trunk height from the cable length."""
    altitude = max(base.altitude_m, cell.cable_m + GROUND_CLEARANCE_M)
    return base.with_(altitude_m=altitude, trunk_height_m=max(base.trunk_height_m, altitude + TRUNK_ABOVE_M))


def cell_mission(cell: Cell, seed: int, base: ForestSpec, drags: str = "declared") -> Mission:
    """The forest of ``seed`` flown with the cell's payload and wind. ``drags`` (:data:`DRAG_DECLARATIONS`):
    ``declared``, the mission declares the payload's and the airframe's drag coefficients as it declares the mass
    and cable (``[payload] drag_n_per_mps2`` and ``airframe_drag_n_per_mps2``, the world's own where the wind drags,
    0 in calm air and eq. 49, which drag nothing); ``identified``, the airframe's only, the vehicle's own (the
    companion identifies the payload's); ``none``, neither (the companion assumes a typical airframe's)."""
    if drags not in DRAG_DECLARATIONS:
        raise ValueError(f"drags: one of {', '.join(DRAG_DECLARATIONS)}, got {drags!r}")
    spec = cell_spec(cell, base)
    m = generate_forest(seed, spec)
    vehicle = replace(m.vehicle, m=cell.mass_kg, l=cell.cable_m)
    vehicle.validate()
    wind = wind_config(cell.wind, seed, spec.altitude_m, cell.mass_kg)
    payload = m.payload
    if wind.is_physical:
        k_airframe, k_payload = map(float, wind.drag_coefficients())
        payload = replace(payload, drag_n_per_mps2=k_payload if drags == "declared" else 0.0,
                          airframe_drag_n_per_mps2=k_airframe if drags != "none" else 0.0)
    return m.with_(vehicle=vehicle, wind=wind, payload=payload,
                   name=f"{m.name}-m{cell.mass_kg:g}-l{cell.cable_m:g}-{cell.wind}")


def build_jobs(cells: list[Cell], n: int, seed0: int, base: ForestSpec, mode: str, out: Path,
               drags: str = "declared") -> list[Job]:
    """One job per (cell, seed); ``drags`` as :func:`cell_mission`."""
    jobs = []
    for c in cells:
        for seed in range(seed0, seed0 + n):
            run_dir = out / "runs" / f"m{c.mass_kg:g}" / f"l{c.cable_m:g}" / c.wind / f"s{seed}"
            jobs.append(Job(key=f"{c.key}|{seed}", mission=cell_mission(c, seed, base, drags),
                            run_dir=run_dir, mode=mode, plots=False, keep_run_dir=False))
    return jobs


def _cell_summary(rs: list[dict[str, Any]], bound_rad: float) -> dict[str, Any]:
    """Rates and swing/time figures of one cell's results."""
    n = len(rs)
    cls = [r.get("class") for r in rs]
    swings = [r["max_swing_rad"] for r in rs if r.get("max_swing_rad") is not None]
    over = [r["time_over_bound"] for r in rs if r.get("time_over_bound") is not None]
    drag = [r["wind_drag_angle_max_rad"] for r in rs if r.get("wind_drag_angle_max_rad") is not None]
    held = [r["held_swing_max_rad"] for r in rs if r.get("held_swing_max_rad") is not None]
    return {
        "n": n,
        "clean_rate": cls.count("success") / n if n else None,
        "no_route": cls.count("no_route"),
        "refused": sum(1 for r in rs if r.get("outcome") == "refused"),
        "collisions": sum(1 for c in cls if c == "collision"),
        "diverged": sum(1 for r in rs if r.get("outcome") == "diverged" or r.get("class") == "lost_control"),
        "stuck": cls.count("stuck"),
        "errors": cls.count("error"),
        "max_swing_median_rad": float(np.median(swings)) if swings else None,
        "max_swing_worst_rad": max(swings) if swings else None,
        "swing_bound_rad": bound_rad,
        "over_swing_bound": sum(1 for s in swings if s > bound_rad),
        # flights over the bound in which the wind alone hung the payload beyond it (companion.report.wind_truth)
        "over_swing_bound_wind": sum(1 for r in rs if (r.get("max_swing_rad") or 0.0) > bound_rad
                                     and (r.get("wind_drag_angle_max_rad") or 0.0) > bound_rad),
        "wind_drag_angle_worst_rad": max(drag) if drag else None,
        # flights over the bound in which the payload under a still airframe would have swung beyond it too
        "over_swing_bound_held": sum(1 for r in rs if (r.get("max_swing_rad") or 0.0) > bound_rad
                                     and (r.get("held_swing_max_rad") or 0.0) > bound_rad),
        "held_swing_worst_rad": max(held) if held else None,
        "time_over_bound_median": float(np.median(over)) if over else None,
    }


def summarise(results: list[dict[str, Any]], cells: list[Cell]) -> dict[str, dict[str, Any]]:
    """Per cell key: :func:`_cell_summary`."""
    by: dict[str, list[dict[str, Any]]] = {c.key: [] for c in cells}
    for r in results:
        by.setdefault(r["key"].rsplit("|", 1)[0], []).append(r)
    return {c.key: _cell_summary(by[c.key], SWING_BOUND_RAD[c.wind]) for c in cells}


def _fmt(v: Any, digits: int = 2, pct: bool = False) -> str:
    if v is None:
        return "—"
    return f"{100.0 * v:.0f} %" if pct else f"{v:.{digits}f}"


def table_markdown(cells: list[Cell], per: dict[str, dict[str, Any]]) -> str:
    """The grid as a Markdown table, one row per cell."""
    rows = ["| mass kg | cable m | wind | clean | no_route | refused | collisions | diverged | max swing median / "
            "worst rad (bound) | over the bound (the wind alone beyond it / held still beyond it) | the wind alone, "
            "worst rad | held still, worst rad | time over bound |", "|" + "---|" * 13]
    for c in cells:
        s = per[c.key]
        rows.append(
            f"| {c.mass_kg:g} | {c.cable_m:g} | {c.wind} | {_fmt(s['clean_rate'], pct=True)} of {s['n']} | "
            f"{s['no_route']} | {s['refused']} | {s['collisions']} | {s['diverged']} | "
            f"{_fmt(s['max_swing_median_rad'])} / {_fmt(s['max_swing_worst_rad'])} ({s['swing_bound_rad']:g}) | "
            f"{s['over_swing_bound']} ({s['over_swing_bound_wind']} / {s['over_swing_bound_held']}) | "
            f"{_fmt(s['wind_drag_angle_worst_rad'])} | {_fmt(s['held_swing_worst_rad'])} | "
            f"{_fmt(s['time_over_bound_median'])} |")
    return "\n".join(rows) + "\n"


def envelope(cells: list[Cell], n: int, *, seed0: int = 0, base: ForestSpec | None = None, mode: str = "mavlink",
             workers: int = 2, out: Path, progress: bool = True, drags: str = "declared") -> dict[str, Any]:
    """Fly the grid and write ``envelope.md``, ``envelope.json``, ``results.jsonl`` and ``envelope.png``;
    ``drags`` as :func:`cell_mission`."""
    base = base or ForestSpec(density_per_100m2=4.0, width_m=6.0)
    out.mkdir(parents=True, exist_ok=True)
    jobs = build_jobs(cells, n, seed0, base, mode, out, drags)
    wall0 = time.monotonic()
    results = run_jobs(jobs, workers, progress)
    wall = time.monotonic() - wall0
    with (out / "results.jsonl").open("w") as fh:
        for r in results:
            fh.write(json.dumps(r) + "\n")
    per = summarise(results, cells)
    summary = {"mode": mode, "n_per_cell": n, "seed0": seed0, "density_per_100m2": base.density_per_100m2,
               "width_m": base.width_m, "length_m": base.length_m,
               "payload_drag": drags, "wall_s": wall, "missions": len(results),
               "cells": [{"mass_kg": c.mass_kg, "cable_m": c.cable_m, "wind": c.wind, **per[c.key]} for c in cells]}
    (out / "envelope.json").write_text(json.dumps(summary, indent=2) + "\n")
    from lab.figures import plot_envelope

    png = plot_envelope(summary, out / "envelope.png")
    drag = {"declared": "drags declared", "identified": "payload drag identified",
            "none": "no drag declared"}[drags]
    head = (f"# Payload envelope: {n} forests per cell ({base.density_per_100m2:g} trunks/100 m², "
            f"{base.width_m:g} m corridor, {mode} mode, {drag}), "
            f"{len(results)} flights in {wall:.0f} s\n\n")
    (out / "envelope.md").write_text(head + table_markdown(cells, per) + f"\n![envelope]({png.name})\n")
    return summary


def parse_grid(masses: str | None, cables: str | None, winds: str | None) -> list[Cell]:
    """Cells from comma-separated lists (None: the issue's grid); raises ValueError naming a bad value."""
    ms = [float(v) for v in masses.split(",")] if masses else list(MASSES_KG)
    ls = [float(v) for v in cables.split(",")] if cables else list(CABLES_M)
    ws = [w.strip() for w in winds.split(",")] if winds else list(WINDS)
    for w in ws:
        if w not in WINDS:
            raise ValueError(f"--envelope-winds: unknown wind {w!r} (known: {', '.join(WINDS)})")
    for v in ms:
        if not 0.0 < v <= 5.0:
            raise ValueError(f"--envelope-masses: {v} kg is outside (0, 5]")
    for v in ls:
        if not 0.1 <= v <= 10.0:
            raise ValueError(f"--envelope-cables: {v} m is outside [0.1, 10]")
    return [Cell(m, cable, w) for m in ms for cable in ls for w in ws]
