"""The terminal narration of a flight: one line per phase, and progress while cruising.

A telemetry sink of the flight runner (``on_transition`` for the flight sequence's state changes, ``on_tick``
for the flight core's phases and progress). In lockstep on a terminal the progress is one line rewritten in
place; in real time a progress line every 2 s of flight. ``slungpilot -q fly`` leaves it out.
"""

from __future__ import annotations

import math
import sys
import time
from typing import Any, TextIO


class Narrator:
    """Prints what the flight is doing to ``out`` (stdout by default)."""

    def __init__(self, out: TextIO | None = None, *, lockstep: bool = False) -> None:
        self.out = out or sys.stdout
        self.lockstep = lockstep
        self.live = lockstep and self.out.isatty()  # one progress line, rewritten in place
        self._phase = ""
        self._cruise_t0: float | None = None
        self._next_progress_s = 0.0
        self._next_live_wall = 0.0
        self._live_shown = False

    def _say(self, text: str) -> None:
        if self._live_shown:
            self.out.write("\r\x1b[2K")
            self._live_shown = False
        self.out.write(text + "\n")
        self.out.flush()

    def on_transition(self, t: Any, app: Any) -> None:
        st = app.state
        to = t.to_state
        if to == "configure":
            self._say(f"connected: system {st.vehicle_sysid}, {app.profile.autopilot} autopilot "
                      f"(profile {app.profile.name}), mode {st.mode_name}, via {app.setup.connect}")
        elif to == "wait_ready":
            self._say(f"set up: telemetry at {app.setup.rate_hz:g} Hz asked, hover thrust "
                      f"{app.profile.hover_thrust_norm:.2f}; waiting until the autopilot is ready to arm")
        elif to == "prestream":
            self._say("ready: streaming setpoints before arming")
        elif to == "arm":
            self._say("arming")
        elif to == "takeover":
            self._say("armed; taking over" if t.from_state == "arm" else "taking over")
        elif to == "mission":
            z = -float(app.mission.start_ned_m[2])
            self._say(f"in control ({t.reason}); climbing to {z:.1f} m")
        elif to in ("hold", "land", "descend"):
            verb = {"hold": "holding", "land": "landing", "descend": "descending on our own setpoints"}[to]
            self._say(f"{verb}: {t.reason}")
        elif to == "done":
            what = app.pilot.seq.final_phase
            self._say(f"{what}: outcome {app.outcome} ({app.pilot.seq.detail})")

    def on_tick(self, est: Any, cmd: Any, app: Any) -> None:
        phase = app.pilot.core.phase if app.pilot.seq.state.value == "mission" else ""
        if phase != self._phase:
            self._phase_changed(phase, est, app)
        if phase != "cruise":
            return
        goal = app.mission.goal_ned_m
        dist = math.hypot(float(est.pos_ned_m[0]) - goal[0], float(est.pos_ned_m[1]) - goal[1])
        swing = "—" if est.swing is None else f"{max(abs(est.swing[0]), abs(est.swing[1])):.2f} rad"
        text = (f"cruising: {dist:5.1f} m to go, {math.hypot(est.vel_ned_mps[0], est.vel_ned_mps[1]):.1f} m/s, "
                f"swing {swing}, t = {est.t_s - (self._cruise_t0 or est.t_s):.1f} s")
        if self.live:
            now = time.monotonic()
            if now >= self._next_live_wall:
                self._next_live_wall = now + 0.1
                self.out.write("\r\x1b[2K" + text)
                self.out.flush()
                self._live_shown = True
        elif not self.lockstep and est.t_s >= self._next_progress_s:
            self._next_progress_s = est.t_s + 2.0
            self._say(text)

    def _phase_changed(self, phase: str, est: Any, app: Any) -> None:
        self._phase = phase
        goal = app.mission.goal_ned_m
        if phase == "cruise":
            self._cruise_t0 = est.t_s
            self._next_progress_s = est.t_s + 2.0
            dist = math.hypot(float(est.pos_ned_m[0]) - goal[0], float(est.pos_ned_m[1]) - goal[1])
            self._say(f"cruising to ({goal[0]:.1f}, {goal[1]:.1f}) with planner {app.mission.planner}: "
                      f"{dist:.1f} m to go")
        elif phase == "hold":
            took = est.t_s - (self._cruise_t0 or est.t_s)
            self._say(f"goal reached after {took:.2f} s; holding {app.mission.hold_s:g} s")
