"""The pilot's payload identification: what the IMU saw, when it is due, and what the flight does with it.

Every flight keeps the cruise's IMU and attitude for the report's identified payload
(:mod:`companion.estimation.payload_watch`, identified after the flight). A mission whose payload is unknown
(``[payload] identify = true``) hops first (phase ``identify``, :mod:`companion.flight.core_hop`); once the hop's
window is over the identification is *due*: the runner runs :meth:`PayloadWatch.identify` beside the control loop
(inline in lockstep, in a thread in real time, where the compiled fit does not hold the GIL) and then calls
:meth:`Identification.conclude`, which hands the flight core the payload found (the values the mission does not
give), or the declared one when the verdict does not trust it, and says to land when the vehicle cannot lift it
with margin; the swing estimator restarts on the identified model and the vehicle state takes its cable length
(payload fixes into angles).
"""

from __future__ import annotations

import logging
from dataclasses import replace
from typing import Any

from companion.core.mission import Mission
from companion.core.payload_check import thrust_margin
from companion.core.vehicle_params import VehicleParams
from companion.estimation.payload_watch import WINDOW_S, PayloadWatch
from companion.estimation.swing_feed import SwingFeed
from companion.estimation.vehicle_state import VehicleState
from companion.flight.core import FlightCore
from companion.flight.core_hop import HOP_WINDOW_S
from companion.flight.phase import CorePhase
from companion.mavlink_io.telemetry import TelemetryEvent


class Identification:
    """One flight's identification: feed it the vehicle's messages and each tick's core phase and time."""

    def __init__(self, mission: Mission) -> None:
        self.mission = mission
        self.hop = mission.payload.identify
        self.watch = PayloadWatch(mission.vehicle.M, mission.vehicle.g, HOP_WINDOW_S if self.hop else WINDOW_S)
        self.due = False  # the hop's window is over: the runner should run the identification now
        self.concluded = False
        self.used: dict[str, Any] | None = None  # what the flight did with it (the report's ``payload.flown``)
        self.flown: VehicleParams | None = None  # the identified payload the flight goes on with (None: declared)

    def on_event(self, kind: str, ev: TelemetryEvent) -> None:
        """A message from the vehicle, accepted by the vehicle state (``kind``: its type name)."""
        if kind == "ATTITUDE":
            self.watch.on_attitude(ev.t_boot_s, ev.euler_rad)
        elif kind == "HIGHRES_IMU":
            self.watch.on_imu(ev.t_s, ev.accel_frd_mps2)
        elif kind == "SCALED_IMU":
            self.watch.on_imu(ev.t_boot_s, ev.accel_frd_mps2)

    def on_tick(self, phase: CorePhase, t_s: float) -> None:
        """The core's phase at vehicle time ``t_s`` (s): the window starts with the hop (or the cruise)."""
        if phase == (CorePhase.IDENTIFY if self.hop else CorePhase.CRUISE):
            self.watch.start(t_s)
        t0 = self.watch.t0_s
        if self.hop and not self.concluded and t0 is not None and t_s >= t0 + self.watch.window_s:
            self.due = True

    def conclude(self, core: FlightCore, feed: SwingFeed | None = None,
                 state: VehicleState | None = None) -> str | None:
        """The identification ran (:meth:`PayloadWatch.identify`): fly on with what it found, or with the declared
        payload (the core, the swing ``feed``'s estimator and the vehicle ``state``'s cable length); returns why the
        flight must end instead (a payload the vehicle cannot lift with margin), or None."""
        self.due, self.concluded = False, True
        self.watch.identify()
        r, _, _, v = self.watch.judged()
        declared = self.mission.companion_params()
        p = self.mission.payload
        use_m = r is not None and v.mass_ok and p.mass_kg is None
        use_l = r is not None and v.cable_ok and p.cable_length_m is None
        vp = replace(declared, m=r.payload_mass_kg if use_m else declared.m,
                     l=r.cable_length_m if use_l else declared.l)
        self.flown = vp if (use_m or use_l) else None
        if v.why:
            logging.getLogger(__name__).warning("the payload was not (all) identified (%s): flying with %.3f kg on "
                                                "%.2f m", v.why, vp.m, vp.l)
        core.end_identify(self.flown)
        if self.flown is not None and feed is not None and state is not None:
            feed.use_payload(self.flown)
            state.cable_length_m = self.flown.l
        self.used = {"mass_kg": round(vp.m, 4), "cable_length_m": round(vp.l, 4), "mass_identified": use_m,
                     "cable_identified": use_l, "hop_m": core.hop_length_m, "reason": v.why}
        margin = thrust_margin(vp)
        if not margin.ok:
            return (f"the identified payload ({vp.m:.3f} kg) needs {margin.fraction:.2f} of the vehicle's maximum "
                    f"thrust (limit {margin.limit:.2f})")
        return None

