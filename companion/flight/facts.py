"""What a flight's pilot knows for the report: outcome, transitions, what the vehicle and the estimator did, and for
a multi-leg mission the flight core's own record of each waypoint (``waypoints_flown``: when it was passed or
reached, vehicle time in s). The runner adds its own (loop timing, the link's counters, the journal)."""

from __future__ import annotations

from typing import Any

from companion.estimation.swing_feed import SwingFeed
from companion.flight.pilot import Pilot


def pilot_facts(p: Pilot) -> dict[str, Any]:
    """The pilot's part of the report."""
    st = p.state
    legs = p.core.legs
    return ({} if legs is None else {"waypoints_flown": legs.facts()}) | {
        "outcome": p.outcome,
        "outcome_detail": p.seq.detail,
        "final_phase": p.phase,
        "abort_reason": p.abort_reason,
        "transitions": [
            {"t_s": t.now_s, "wall_s": t.wall_s, "from": t.from_state, "to": t.to_state, "reason": t.reason}
            for t in p.seq.transitions
        ],
        "rejected_telemetry": dict(st.rejected),
        "vehicle_statustext": st.statustext[-20:],
        "swing_sources": p.record.swing_sources,
        "swing_estimator": estimator_facts(p.swing_feed),
        "loop_lag": p.core.margin.facts(p.profile.nominal_loop_lag_s),
        "autopilot": {"family": p.profile.autopilot, "system_id": st.vehicle_sysid,
                      "component_id": st.vehicle_compid, "mav_autopilot": st.autopilot,
                      "mav_type": st.vehicle_type, "version": st.autopilot_version},
        "autopilot_params": p.params,
        "mission_frame": p.frame.facts(),
        "arrival": dict(p.core.arrival),
        "planning": p.core.planner.facts(),  # the planner's counters: for the shaped one, its waits for the wind
        "lift_off": p.core.lift_gate.facts(),  # how long the climb held the payload on the ground for the wind
        # the payload's drag coefficient declared and identified in flight (N per (m/s)²), or why not
        "payload_drag": p.core.drag_id.facts(p.core.params.m, p.core.params.g),
        # scans mapped, refused by reason, returns dropped, the map's counts (None: perception never started)
        "perception": p.sensing.facts(),
    }


def estimator_facts(feed: SwingFeed) -> dict[str, Any] | None:
    """What the swing estimator ran on, when it ran."""
    if feed.ran is None:
        return None
    last = feed.last_seen
    return {"inputs": dict(feed.counts), "rejected": None if last is None else last.rejected,
            "dropped_late": feed.ran.dropped_late, "rejected_total": feed.ran.rejected_total,
            "swing_resets": feed.ran.resets, "q_swing_scale": round(feed.ran.q_swing_scale, 3),
            # each taut payload fix against the estimate of its own time (what the controller flew on then)
            "error_at_fixes": feed.fix_error_summary(),
            "sources_last_second": None if last is None else list(last.sources),
            "fade_last": None if last is None else last.fade,
            # what it learnt of the drags (the airframe's N per m/s, the payload's N per (m/s)²)
            "drag_n_per_mps": None if last is None else round(last.drag_n_per_mps, 4),
            "payload_drag_n_per_mps2": None if last is None else round(last.payload_drag_n_per_mps2, 5),
            "filters": feed.ran.selection_facts()}


def status_facts(p: Pilot) -> dict[str, Any]:
    """The pilot's part of the 1 Hz status sample: mode, armed, phase, progress, loop lag."""
    st = p.state
    progress = None
    if st.pos_ned_m is not None:
        goal = p.mission.goal_ned_m
        progress = {"distance_to_goal_m": float(((st.pos_ned_m[0] - goal[0]) ** 2
                                                 + (st.pos_ned_m[1] - goal[1]) ** 2) ** 0.5),
                    "core_phase": p.core.phase}
        if p.core.legs is not None:  # a multi-leg mission: the point it heads for (0-based; the goal is last)
            progress |= {"target": p.core.legs.index, "target_name": p.core.legs.current.name}
    return {
        "mode": st.mode_name, "armed": st.armed, "phase": p.phase, "outcome": p.outcome,
        "progress": progress,
        "loop_lag_ms": None if p.core.loop_lag.lag_s is None else round(p.core.loop_lag.lag_s * 1e3, 1),
        "ff_lag_trust": round(p.core.lag_trust, 3),
    }
