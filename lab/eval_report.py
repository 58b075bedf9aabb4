"""An evaluation's results summarised (:mod:`lab.evaluate`): outcome rates and distributions per scenario ×
planner × density, the summary files (``results.jsonl``, ``summary.json``, ``summary.md``, the figures) and the
Markdown of ``summary.md``. Times in s, lengths in m, angles in rad.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from lab.compare import plot_comparison
from lab.forests import ForestSpec

CLASSES = ("success", "collision", "no_route", "stuck", "lost_control", "error")


def _quantiles(values: list[float]) -> dict[str, float | None]:
    v = np.array([x for x in values if x is not None and math.isfinite(x)], dtype=np.float64)
    if v.size == 0:
        return {"n": 0, "median": None, "p90": None, "p10": None, "min": None, "max": None}
    return {
        "n": int(v.size), "median": float(np.median(v)), "p90": float(np.percentile(v, 90)),
        "p10": float(np.percentile(v, 10)), "min": float(v.min()), "max": float(v.max()),
    }


def summarise(results: list[dict[str, Any]]) -> dict[str, Any]:
    """Rates and distributions of a list of :func:`lab.runner.run_job` results (all share one planner)."""
    n = len(results)
    counts = {c: sum(1 for r in results if r["class"] == c) for c in CLASSES}
    ok = [r for r in results if r["class"] == "success"]
    return {
        "n": n,
        "counts": counts,
        "success_rate": counts["success"] / n if n else None,
        "collision_rate": counts["collision"] / n if n else None,
        "stuck_rate": counts["stuck"] / n if n else None,
        "no_route_rate": counts["no_route"] / n if n else None,
        "lost_control_rate": counts["lost_control"] / n if n else None,
        "error_rate": counts["error"] / n if n else None,
        "collisions_moving": sum(1 for r in results if (r.get("collisions_moving") or 0) > 0),
        "time_to_goal_s": _quantiles([r["time_to_goal_s"] for r in ok]),
        "time_over_bound": _quantiles([r.get("time_over_bound") for r in ok]),
        "bound_s": _quantiles([r.get("bound_s") for r in results]),
        "max_swing_rad": _quantiles([r["max_swing_rad"] for r in results]),
        "min_clearance_m": _quantiles([r["min_clearance_m"] for r in results]),
        "path_length_m": _quantiles([r.get("path_length_m") for r in ok]),
        "failures": sorted(
            ({"seed": r["seed"], "density": r["density"], "class": r["class"], "mission_file": r["mission_file"],
              "scenario": r.get("scenario", "static")}
             for r in results if r["class"] != "success"),
            key=lambda f: (f["scenario"], f["density"], f["seed"]),
        ),
    }


def write_summary(results: list[dict[str, Any]], planned: int, wall: float, out: Path, *, mode: str, n: int,
                   seed0: int, planners: list[str], densities: list[float], workers: int, spec: ForestSpec,
                   scenarios: tuple[str, ...], movers: int, cluster: str | None,
                   memory: dict[str, Any] | None = None) -> dict[str, Any]:
    """results.jsonl, summary.json, summary.md and the figures of ``results`` (``planned`` missions were asked
    for; fewer means the run was interrupted and the summary says so)."""
    for r in results:
        p, d, s, sc = r["key"].split("|")
        r["planner"], r["density"], r["seed"], r["scenario"] = p, float(d), int(s), sc
    with (out / "results.jsonl").open("w") as fh:
        for r in results:
            fh.write(json.dumps(r) + "\n")
    interrupted = len(results) < planned
    summary: dict[str, Any] = {
        "mode": mode,
        "mode_text": ("full lockstep MAVLink flights against the bundled vehicle (slungpilot fly --sitl)"
                      if mode == "mavlink" else "in-process flights (same FlightCore and physics, no MAVLink)"),
        "n_per_planner_and_density": n, "seed0": seed0, "planners": planners, "densities": densities,
        "workers": workers, "cluster": cluster, "spec": asdict(spec), "scenarios": list(scenarios), "movers": movers,
        "missions": len(results), "missions_planned": planned, "interrupted": interrupted,
        "interrupted_text": (f"interrupted after {len(results)} of {planned} missions (Ctrl-C): partial results"
                             if interrupted else None),
        "wall_s": wall,
        "missions_per_min": len(results) / wall * 60.0 if wall > 0 else None,
        "memory": memory,
        "per_planner": {p: summarise([r for r in results if r["planner"] == p]) for p in planners},
        "per_scenario": {sc: {p: summarise([r for r in results if r["planner"] == p and r["scenario"] == sc])
                              for p in planners} for sc in scenarios},
        "per_density": {
            p: {f"{d:g}": summarise([r for r in results if r["planner"] == p and r["density"] == d])
                for d in densities}
            for p in planners
        },
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    png = cmp_png = None
    if results:  # nothing to draw before the first mission finished
        from lab.figures import plot_success_vs_density

        png = plot_success_vs_density(summary, out / "success_vs_density.png")
        cmp_png = plot_comparison(results, planners, list(scenarios), out / "comparison.png",
                                  f"{n} seeds from {seed0}, {mode} mode; bound: bang-bang at g·tan(0.3)"
                                  + (f"; {summary['interrupted_text']}" if interrupted else ""))
    (out / "summary.md").write_text(summary_markdown(summary, png, cmp_png))
    return summary


def _f(v: Any, digits: int = 2, pct: bool = False) -> str:
    if v is None:
        return "—"
    return f"{100.0 * v:.1f} %" if pct else f"{v:.{digits}f}"


SCENARIO_TEXT = {
    "static": "the forest",
    "moving": "the forest plus {movers} trunks crossing the path at 0.5–1.5 m/s",
    "fenced": "the forest with the goal ringed by trunks (no route exists; the right outcome is no_route)",
}


def _where(s: dict[str, Any]) -> str:
    c = s.get("cluster")
    if not c:
        return f"{s['workers']} workers"
    return f"a local Dask cluster of {s['workers']} workers" if c == "local" else f"the Dask cluster at {c}"


def _memory_line(m: dict[str, Any]) -> str:
    """RSS at start and end (parent) and per worker after its first and last job."""
    ws = m.get("workers") or {}
    parts = [f"{w['first_mb']:.0f} → {w['last_mb']:.0f} MB over {w['jobs']} jobs" for w in ws.values()]
    return (f"Memory (RSS): this process {_f(m.get('parent_start_mb'), 0)} → {_f(m.get('parent_end_mb'), 0)} MB; "
            f"workers after their first → last job: {'; '.join(parts) or '—'}.")


def summary_markdown(s: dict[str, Any], png: Path | None = None, cmp_png: Path | None = None) -> str:
    """The human-readable summary (Markdown): what was flown, the table per scenario × planner, the success rate
    per density, the figures and the failing seeds."""
    per_sc = s.get("per_scenario") or {"static": s["per_planner"]}
    lines = [*_intro_lines(s), *_table_lines(per_sc)]
    b_all = [t.get("bound_s", {}).get("median") for per in per_sc.values() for t in per.values()]
    b_all = [b for b in b_all if b is not None]
    if b_all:
        lines += ["", f"Bound for this corridor: {b_all[0]:.2f} s (1.6 × bound = {1.6 * b_all[0]:.2f} s)."]
    if len(s["densities"]) > 1:
        lines += ["", "Success rate by density (trunks/100 m²):", "",
                  "| planner | " + " | ".join(f"{d:g}" for d in s["densities"]) + " |",
                  "|---|" + "---|" * len(s["densities"])]
        for p, per in s["per_density"].items():
            lines.append(f"| {p} | " + " | ".join(_f(t["success_rate"], pct=True) for t in per.values()) + " |")
    if cmp_png is not None:
        lines += ["", f"![time over the bound, swing, clearance and path length]({cmp_png.name})"]
    if png is not None:
        lines += ["", f"![success rate against density]({png.name})"]
    return "\n".join([*lines, *_failure_lines(per_sc)]) + "\n"


def _intro_lines(s: dict[str, Any]) -> list[str]:
    """The title, the run (mode, throughput, memory), the forests, the scenarios and the outcome classes."""
    sp = s["spec"]
    var = ("wind U(0,1.3), payload U(0.1,0.5) kg, cable U(0.5,1.5) m" if sp["vary"] else
           f"wind scale {sp['wind_scale']:g}, payload {sp['payload_kg']:g} kg, cable {sp['cable_m']:g} m")
    scenarios = s.get("scenarios", ["static"])
    return [
        "# slungpilot evaluate: random forests" + (" (PARTIAL)" if s.get("interrupted") else ""),
        "",
        *([f"**Partial: {s['interrupted_text']}.** Only the missions that finished are counted below.", ""]
          if s.get("interrupted") else []),
        f"Mode: **{s['mode']}** — {s['mode_text']}. {s['missions']} missions in {s['wall_s']:.0f} s wall with "
        f"{_where(s)}: **{_f(s['missions_per_min'], 1)} missions/min**.",
        "",
        *([_memory_line(s["memory"]), ""] if s.get("memory") else []),
        f"Forests: corridor {sp['length_m']:g} m × {sp['width_m']:g} m at {sp['altitude_m']:g} m altitude, "
        f"trunk radii {sp['r_min_m']:g}–{sp['r_max_m']:g} m, densities {', '.join(f'{d:g}' for d in s['densities'])}"
        f" trunks/100 m², trap: {sp['trap']}, {var}; seeds {s['seed0']}.."
        f"{s['seed0'] + s['n_per_planner_and_density'] - 1}"
        f" (the same for every planner), controller {sp['controller']}, timeout {sp['timeout_s']:g} s.",
        "",
        "Scenarios (each its own class, same seeds): " + "; ".join(
            f"**{sc}** = {SCENARIO_TEXT[sc].format(movers=s.get('movers', 2))}" for sc in scenarios) + ".",
        "",
        "Success = goal reached and zero collisions; collision = any obstacle clearance < 0 (airframe circle or "
        "payload; moving obstacles where they are at that instant); no route = the planner established that "
        "no route exists and held; stuck = no collision but the goal not reached before the timeout (local "
        "minimum); lost = the payload swung past ±π/2 (loss of control, not a planning failure). "
        "Bound = 2·sqrt(D/(g·tan 0.3)): the straight distance D flown bang-bang at the acceleration that keeps "
        "the swing under 0.3 rad; time/bound over the successes.",
        "",
    ]


def _table_lines(per_sc: dict[str, dict[str, Any]]) -> list[str]:
    """One table row per scenario × planner: outcome rates and the quantiles of times, swing, clearance, path."""
    lines = [
        "| scenario | planner | n | success | collision | no route | stuck | lost | error | time to goal median / p90"
        " (s) | time / bound median / p90 | max swing median / p90 (rad) | min clearance p10 / median / min (m) | "
        "path length median (m) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for sc, per in per_sc.items():
        for p, t in per.items():
            tg, tb, sw, mc, pl = (t["time_to_goal_s"], t.get("time_over_bound") or {}, t["max_swing_rad"],
                                  t["min_clearance_m"], t.get("path_length_m") or {})
            lines.append(
                f"| {sc} | {p} | {t['n']} | {_f(t['success_rate'], pct=True)} | {_f(t['collision_rate'], pct=True)} | "
                f"{_f(t.get('no_route_rate'), pct=True)} | {_f(t['stuck_rate'], pct=True)} | "
                f"{_f(t['lost_control_rate'], pct=True)} | {_f(t['error_rate'], pct=True)} | "
                f"{_f(tg['median'])} / {_f(tg['p90'])} | {_f(tb.get('median'))} / {_f(tb.get('p90'))} | "
                f"{_f(sw['median'], 3)} / {_f(sw['p90'], 3)} | {_f(mc['p10'], 3)} / {_f(mc['median'], 3)} / "
                f"{_f(mc['min'], 3)} | {_f(pl.get('median'))} |"
            )
    return lines


def _failure_lines(per_sc: dict[str, dict[str, Any]]) -> list[str]:
    """The failing seeds, per scenario × planner × outcome class, grouped by density."""
    lines = ["", "## Failures", "",
             "Each keeps its run folder with the mission file; replay one with "
             "`slungpilot fly --sitl --mission <out>/runs/[<scenario>/]<planner>/d<density>/s<seed>/mission.toml`.",
             ""]
    any_fail = False
    for sc, per in per_sc.items():
        for p, t in per.items():
            for cls in ("collision", "no_route", "stuck", "lost_control", "error"):
                fails = [f for f in t["failures"] if f["class"] == cls]
                if not fails:
                    continue
                any_fail = True
                by_d: dict[float, list[int]] = {}
                for f in fails:
                    by_d.setdefault(f["density"], []).append(f["seed"])
                seeds = "; ".join(f"d{d:g}: seeds {', '.join(str(k) for k in ks)}" for d, ks in sorted(by_d.items()))
                expected = " (expected: no route exists)" if sc == "fenced" and cls == "no_route" else ""
                lines.append(f"- **{p}** ({sc}) {cls}{expected} ({len(fails)}): {seeds}")
    if not any_fail:
        lines.append("None.")
    return lines
