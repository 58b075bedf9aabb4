"""Summary, Markdown and figure of ``evaluate --perception`` (:mod:`lab.perception_eval`).

Per scenario × planner: the clean rate (goal reached, no collision) blind and mapped; on the seeds clean both ways,
the time to goal blind / mapped of the same forest (median, p90, max); the map's scores pooled over the blind
flights (:mod:`lab.perception_score`): precision = matched / (matched + false positives), recall = matched
sightable / sightable, centre error (m; median, p90) and radius error (m, map − truth; median and median |·|); the
flights that touched a crossing trunk. The issue's targets are checked on the result.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

TARGET_CLEAN = 29 / 30  # blind clean rate
TARGET_RATIO = 1.25  # median time blind / mapped
TARGET_CENTRE_M = 0.05  # median centre error (m)


def _q(values: list[float]) -> dict[str, float | None]:
    v = np.array([x for x in values if x is not None and math.isfinite(x)], dtype=np.float64)
    if v.size == 0:
        return {"n": 0, "median": None, "p90": None, "max": None}
    return {"n": int(v.size), "median": float(np.median(v)), "p90": float(np.percentile(v, 90)),
            "max": float(v.max())}


def _map_scores(blind: list[dict[str, Any]]) -> dict[str, Any]:
    """Pooled map scores of the blind flights that were scored."""
    sc = [r["perception"] for r in blind if isinstance(r.get("perception"), dict) and "matched" in r["perception"]]
    matched = sum(s["matched"] for s in sc)
    fp = sum(s["false_positives"] for s in sc)
    sight = sum(s["sightable"] for s in sc)
    found = sum(s["matched_sightable"] for s in sc)
    centre = [c for s in sc for c in s["centre_err_m"]]
    radius = [c for s in sc for c in s["radius_err_m"]]
    return {"flights_scored": len(sc), "true_trunks": sum(s["true_trunks"] for s in sc), "sightable": sight,
            "matched": matched, "false_positives": fp, "mover_tracks": sum(s["mover_tracks"] for s in sc),
            "precision": matched / (matched + fp) if matched + fp else None,
            "recall": found / sight if sight else None,
            "centre_err_m": _q(centre), "radius_err_m": _q(radius), "radius_abs_err_m": _q([abs(x) for x in radius]),
            "centre_err_fresh_m": _q([c for s in sc for c in s.get("centre_err_fresh_m", [])]),
            "centre_err_stale_m": _q([c for s in sc for c in s.get("centre_err_stale_m", [])]),
            "clock_t0_s": _q([s.get("clock_t0_s") for s in sc])}


def summarise_cell(rs: list[dict[str, Any]]) -> dict[str, Any]:
    """One scenario × planner: blind and mapped outcomes, time ratios, map scores."""
    by = {arm: {r["seed"]: r for r in rs if r["arm"] == arm} for arm in ("blind", "mapped")}
    out: dict[str, Any] = {}
    for arm, rr in by.items():
        cls = [r["class"] for r in rr.values()]
        out[arm] = {"n": len(cls), "clean": cls.count("success"),
                    "counts": {c: cls.count(c) for c in sorted(set(cls))},
                    "collisions_moving": sum(1 for r in rr.values() if (r.get("collisions_moving") or 0) > 0),
                    "time_to_goal_s": _q([r["time_to_goal_s"] for r in rr.values() if r["class"] == "success"]),
                    "min_clearance_m": _q([r.get("min_clearance_m") for r in rr.values()]),
                    "failures": sorted((s, r["class"], r.get("run_dir")) for s, r in rr.items()
                                       if r["class"] != "success")}
    ratios = {s: by["blind"][s]["time_to_goal_s"] / by["mapped"][s]["time_to_goal_s"]
              for s in by["blind"] if s in by["mapped"] and by["blind"][s]["class"] == "success"
              and by["mapped"][s]["class"] == "success"}
    out["time_ratio"] = _q(list(ratios.values()))
    out["time_ratio_worst"] = sorted(ratios.items(), key=lambda kv: -kv[1])[:3]
    out["map"] = _map_scores(list(by["blind"].values()))
    return out


def summarise_perception(results: list[dict[str, Any]], planners: list[str], scenarios: list[str]) -> dict[str, Any]:
    """Per scenario × planner (:func:`summarise_cell`) and the targets' verdicts."""
    cells = {sc: {p: summarise_cell([r for r in results if r["scenario"] == sc and r["planner"] == p])
                  for p in planners} for sc in scenarios}
    return {"planners": planners, "scenarios": scenarios, "cells": cells, "targets": _targets(cells)}


def _targets(cells: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    """The issue's targets per scenario × planner: clean blind, time ratio, centre error, crossing collisions."""
    out = []
    for sc, per in cells.items():
        for p, c in per.items():
            b = c["blind"]
            ratio, centre = c["time_ratio"]["median"], c["map"]["centre_err_m"]["median"]
            out.append({"scenario": sc, "planner": p,
                        "clean_blind": f"{b['clean']}/{b['n']}", "clean_ok": b["n"] > 0
                        and b["clean"] >= math.ceil(TARGET_CLEAN * b["n"] - 1e-9),
                        "ratio": ratio, "ratio_ok": ratio is not None and ratio <= TARGET_RATIO,
                        "centre_m": centre, "centre_ok": centre is not None and centre <= TARGET_CENTRE_M,
                        "crossing_collisions": b["collisions_moving"] + c["mapped"]["collisions_moving"],
                        "crossing_ok": sc != "moving" or b["collisions_moving"] == 0})
    return out


def _f(v: Any, digits: int = 2, pct: bool = False) -> str:
    if v is None:
        return "—"
    return f"{100.0 * v:.1f} %" if pct else f"{v:.{digits}f}"


def summary_markdown(s: dict[str, Any]) -> str:
    """The human-readable summary."""
    sp = s["spec"]
    lines = [
        "# slungpilot evaluate --perception: random forests, blind (LiDAR only) against mapped", "",
        f"{s['missions']} lockstep MAVLink flights in {s['wall_s']:.0f} s with {s['workers']} workers. Forests: "
        f"{sp['length_m']:g} m × {sp['width_m']:g} m at {sp['density_per_100m2']:g} trunks/100 m², seeds "
        f"{s['seed0']}..{s['seed0'] + s['n'] - 1}, controller {sp['controller']}, timeout {sp['timeout_s']:g} s; "
        f"moving scenario: {s['movers']} crossing trunks. Blind = the mission without trunks, the vehicle in a "
        "world holding them (bundled 2-D LiDAR, 12 m, 10 Hz, 1°); mapped = the mission with them.", "",
        "Recall counts the static trunks that came within range (near side ≤ 12 m), ≥ 3 rays wide and in 2-D "
        "line of sight of the flown path for ≥ 0.5 s; a map trunk matches a true one within 0.3 m (centre); "
        "radius error = fitted radius (not inflated) − true radius; fresh = map trunks seen within 1 s of the "
        "map's last scan, stale = unseen longer (their filter predicts them on).", "",
        "| scenario | planner | clean blind | clean mapped | time blind/mapped (median, p90, max) | precision "
        "| recall | centre err median/p90 (m) | fresh / stale median (m) | radius err median, median abs (m) "
        "| crossing hits blind/mapped |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for sc, per in s["cells"].items():
        for p, c in per.items():
            b, m, r, mp = c["blind"], c["mapped"], c["time_ratio"], c["map"]
            lines.append(
                f"| {sc} | {p} | {b['clean']}/{b['n']} | {m['clean']}/{m['n']} | {_f(r['median'])}, "
                f"{_f(r['p90'])}, {_f(r['max'])} | {_f(mp['precision'], pct=True)} | {_f(mp['recall'], pct=True)} "
                f"| {_f(mp['centre_err_m']['median'], 3)} / {_f(mp['centre_err_m']['p90'], 3)} | "
                f"{_f(mp['centre_err_fresh_m']['median'], 3)} / {_f(mp['centre_err_stale_m']['median'], 3)} | "
                f"{_f(mp['radius_err_m']['median'], 3)}, {_f(mp['radius_abs_err_m']['median'], 3)} | "
                f"{b['collisions_moving']}/{m['collisions_moving']} |")
    lines += ["", "## Targets (issue 26)", "",
              "| scenario | planner | ≥ 29/30 clean blind | time ratio ≤ 1.25 | centre err ≤ 0.05 m | "
              "0 crossing collisions (blind) |", "|---|---|---|---|---|---|"]
    ok = {True: "met", False: "**missed**"}
    for t in s["targets"]:
        lines.append(f"| {t['scenario']} | {t['planner']} | {t['clean_blind']} {ok[t['clean_ok']]} | "
                     f"{_f(t['ratio'])} {ok[t['ratio_ok']]} | {_f(t['centre_m'], 3)} {ok[t['centre_ok']]} | "
                     f"{ok[t['crossing_ok']]} |")
    lines += ["", "## Failures (run folders kept)", ""]
    for sc, per in s["cells"].items():
        for p, c in per.items():
            for arm in ("blind", "mapped"):
                for seed, cls, rd in c[arm]["failures"]:
                    lines.append(f"- {sc} {p} {arm} seed {seed}: {cls} ({rd})")
    return "\n".join(lines) + "\n"


def plot_perception(results: list[dict[str, Any]], out_png: Path) -> Path | None:
    """Time to goal blind against mapped per forest (one marker per planner and scenario), and the centre errors."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(10, 4.2))
    keyed = {(r["scenario"], r["planner"], r["seed"], r["arm"]): r for r in results}
    for sc, p in sorted({(r["scenario"], r["planner"]) for r in results}):
        pts = []
        for (sc2, p2, s, arm), r in keyed.items():
            m = keyed.get((sc, p, s, "mapped"))
            if (sc2, p2, arm) == (sc, p, "blind") and m and r["time_to_goal_s"] and m["time_to_goal_s"]:
                pts.append((m["time_to_goal_s"], r["time_to_goal_s"]))
        if pts:
            a = np.array(pts)
            ax0.plot(a[:, 0], a[:, 1], "o" if sc == "static" else "^", label=f"{p} ({sc})", alpha=0.7)
    lim = ax0.get_xlim()
    ax0.plot(lim, lim, "k-", lw=0.8, label="blind = mapped")
    ax0.plot(lim, [1.25 * x for x in lim], "k--", lw=0.8, label="1.25 × mapped")
    ax0.set_xlabel("time to goal, mapped (s)")
    ax0.set_ylabel("time to goal, blind (s)")
    ax0.legend(fontsize=7)
    errs = [c for r in results if isinstance(r.get("perception"), dict)
            for c in r["perception"].get("centre_err_m", [])]
    if errs:
        ax1.hist(errs, bins=30, color="tab:green")
    ax1.axvline(0.05, color="k", ls="--", lw=0.8)
    ax1.set_xlabel("centre error of matched map trunks (m)")
    ax1.set_ylabel("trunks")
    fig.tight_layout()
    fig.savefig(out_png, dpi=110)
    plt.close(fig)
    return out_png


def write_outputs(results: list[dict[str, Any]], summary: dict[str, Any], out: Path) -> None:
    """results.jsonl, summary.json, summary.md, perception.png into ``out``."""
    with (out / "results.jsonl").open("w") as fh:
        for r in results:
            fh.write(json.dumps(r) + "\n")
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    (out / "summary.md").write_text(summary_markdown(summary))
    if results:
        plot_perception(results, out / "perception.png")
