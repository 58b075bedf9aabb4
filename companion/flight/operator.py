"""The ground station's say in the companion's flight: pause, resume and abort, answered. Pure: no I/O.

A ground station beside the companion (QGroundControl, Mission Planner, MAVProxy, a script) addresses the companion
by its MAVLink identity: the vehicle's system id, component 191 (MAV_COMP_ID_ONBOARD_COMPUTER), as MAVLink
recommends for a companion. :class:`OperatorDesk` decides what each COMMAND_LONG / COMMAND_INT means for the
flight and what to answer (COMMAND_ACK, with a STATUSTEXT saying why when it is not ACCEPTED):

===========================================  ===========================================================
command                                      what the companion does
===========================================  ===========================================================
MAV_CMD_DO_PAUSE_CONTINUE, param1 = 0        pause: the reference brakes at its acceleration and jerk limits
                                             (no step for the payload) and holds where it stops (the core's
                                             ``hold_here(brake=True)``); the mission clock runs on
MAV_CMD_DO_PAUSE_CONTINUE, param1 = 1        continue: fly the mission on from where it paused
MAV_CMD_NAV_LAND                             abort: land where it is (the autopilot's land mode; until it is
                                             confirmed the core brakes as for a pause and holds)
MAV_CMD_NAV_RETURN_TO_LAUNCH                 abort: hold (the swing settles), then land where it is. The
                                             companion plans its route one way only, through what it saw:
                                             it flies no return; an operator who wants the autopilot's own
                                             return switches its mode (the companion then lets go)
anything else addressed to the companion     UNSUPPORTED
===========================================  ===========================================================

Pause and continue make sense only while the companion flies the mission (TEMPORARILY_REJECTED before, and
after it ends); land and return also while it holds after a failsafe; while landing they are ACCEPTED and
change nothing. Commands to component 0 (everyone) are left to the autopilot, which answers them: the
companion answers only what is addressed to it. Who may command: with ``gcs_sysid`` that system only; without it,
anyone, unless signing is on (then no one: a signed link names the ground station it obeys). Commands from
anyone else are answered DENIED, said in a STATUSTEXT and counted by sender.

:class:`OperatorReactions` is the flight sequence's side (a base class of
:class:`~companion.flight.sequence.FlightSequence`): the orders, applied at the next step.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

from companion.flight.phase import CoreOrder, State
from companion.flight.sequence_types import Observation, Stream

MAV_COMP_ID_ONBOARD_COMPUTER = 191
MAV_CMD_NAV_RETURN_TO_LAUNCH = 20
MAV_CMD_NAV_LAND = 21
MAV_CMD_DO_PAUSE_CONTINUE = 193
ACCEPTED, TEMPORARILY_REJECTED, DENIED, UNSUPPORTED = 0, 1, 2, 3
SEV_WARNING, SEV_NOTICE, SEV_INFO = 4, 5, 6
_NAMES = {MAV_CMD_DO_PAUSE_CONTINUE: "pause/continue", MAV_CMD_NAV_LAND: "land",
          MAV_CMD_NAV_RETURN_TO_LAUNCH: "return"}


class Order(StrEnum):
    """What the ground station asked the flight to do."""

    PAUSE = "pause"
    RESUME = "resume"
    LAND = "land"
    RETURN = "return"


@dataclass(frozen=True, slots=True)
class Answer:
    """What to answer one command: COMMAND_ACK ``result`` (MAV_RESULT) for ``command`` to (``to_system``,
    ``to_component``); ``text`` a STATUSTEXT at ``severity`` (MAV_SEVERITY) when there is something to say;
    ``order`` for the flight sequence, if any."""

    command: int
    result: int
    to_system: int
    to_component: int
    text: str = ""
    severity: int = SEV_INFO
    order: Order | None = None


class OperatorDesk:
    """Decides each command addressed to the companion (module docstring); counts what it answered."""

    def __init__(self, gcs_sysid: int | None = None, signing: bool = False) -> None:
        self.gcs_sysid = gcs_sysid
        self.signing = signing
        self.denied: Counter[tuple[int, int]] = Counter()  # (system, component) -> commands denied
        self.answered: Counter[str] = Counter()  # "land:accepted", ...

    def on_command(self, ev: Any, own_sysid: int | None, state: State, paused: bool) -> Answer | None:
        """The answer to one COMMAND_LONG/COMMAND_INT event, or None when it is not addressed to the companion
        (system ``own_sysid``, component 191)."""
        if own_sysid is None or ev.target_system not in (0, own_sysid) or \
                ev.target_component != MAV_COMP_ID_ONBOARD_COMPUTER:
            return None
        ans = self._decide(ev, state, paused)
        label = {ACCEPTED: "accepted", TEMPORARILY_REJECTED: "temporarily_rejected", DENIED: "denied",
                 UNSUPPORTED: "unsupported"}.get(ans.result, str(ans.result))
        self.answered[f"{_NAMES.get(ev.command, ev.command)}:{label}"] += 1
        return ans

    def _who_may(self, src: int) -> str:
        """Why system ``src`` may not command the companion ("" when it may)."""
        if self.gcs_sysid is not None:
            return "" if src == self.gcs_sysid else f"obeys system {self.gcs_sysid} only"
        return "signing is on and no --gcs-sysid names the GCS to obey" if self.signing else ""

    def _decide(self, ev: Any, state: State, paused: bool) -> Answer:
        src, comp, cmd = ev.src_system, ev.src_component, ev.command

        def answer(result: int, text: str = "", severity: int = SEV_INFO, order: Order | None = None) -> Answer:
            return Answer(cmd, result, src, comp, text, severity, order)

        if cmd not in _NAMES:
            return answer(UNSUPPORTED, f"companion: command {cmd} unsupported", SEV_WARNING)
        why = self._who_may(src)
        if why:
            self.denied[(src, comp)] += 1
            return answer(DENIED, f"companion: denied {_NAMES[cmd]} from {src}: {why}", SEV_WARNING)
        if cmd == MAV_CMD_DO_PAUSE_CONTINUE:
            order = Order.RESUME if round(ev.params[0]) == 1 else Order.PAUSE if round(ev.params[0]) == 0 else None
            if order is None:
                return answer(DENIED, f"companion: pause/continue param1 {ev.params[0]:g} is not 0 or 1", SEV_WARNING)
            if state is not State.MISSION:
                return answer(TEMPORARILY_REJECTED, f"companion: cannot {order} in phase {state}", SEV_WARNING)
            if paused is (order is Order.PAUSE):
                return answer(ACCEPTED, f"companion: already {'paused' if paused else 'flying'}")
            text = "companion: paused, holding" if order is Order.PAUSE else "companion: resuming the mission"
            return answer(ACCEPTED, text, SEV_NOTICE, order)
        order = Order.LAND if cmd == MAV_CMD_NAV_LAND else Order.RETURN
        if state in (State.LAND, State.DESCEND):
            return answer(ACCEPTED, "companion: already landing")
        if state not in (State.MISSION, State.HOLD):
            return answer(TEMPORARILY_REJECTED, f"companion: cannot {order} in phase {state}", SEV_WARNING)
        text = "companion: landing here" if order is Order.LAND else "companion: return: holding, then landing here"
        return answer(ACCEPTED, text, SEV_NOTICE, order)

    def summary(self) -> dict[str, Any]:
        """For the report: whom the companion obeys, what it answered, the denied commands by sender."""
        return {"gcs_sysid": self.gcs_sysid, "answered": dict(sorted(self.answered.items())),
                "denied_by_sender": {f"{s}/{c}": n for (s, c), n in sorted(self.denied.items())}}


class OperatorReactions:
    """The flight sequence's reactions to the ground station's orders (a base class of ``FlightSequence``, which
    provides ``state``, ``outcome``, ``detail``, ``_go``, ``_core_order`` and ``_hold_stream``)."""

    paused: bool = False
    _orders: tuple[tuple[Order, str], ...] = ()  # replaced, never changed in place
    orders_done: tuple[tuple[float, Order], ...] = ()  # (the sequence clock's now_s, order) carried out

    def order(self, order: Order, why: str) -> None:
        """Queue a ground station's ``order`` (``why``: for the record) for the next step."""
        self._orders = (*self._orders, (order, why))

    def _apply_orders(self, obs: Observation) -> None:
        """Carry out the queued orders that still make sense now (the desk checked them against the state they
        arrived in)."""
        orders, self._orders = self._orders, ()
        for order, why in orders:
            s: Any = self
            if order in (Order.PAUSE, Order.RESUME):
                if s.state is State.MISSION and self.paused is (order is Order.RESUME):
                    self.paused = order is Order.PAUSE
                    s._core_order = CoreOrder.PAUSE if self.paused else CoreOrder.RESUME
                    self.orders_done = (*self.orders_done, (obs.now_s, order))
                continue
            if s.state not in (State.MISSION, State.HOLD):
                continue
            if s.outcome == "running":
                s.outcome, s.detail = "aborted", why
            self.paused = False
            self.orders_done = (*self.orders_done, (obs.now_s, order))
            if order is Order.LAND:
                s._go(obs, State.LAND, why)
            else:
                s._hold_stream = Stream.CORE
                s._go(obs, State.HOLD, why)
            if s._hold_stream is Stream.CORE:  # brake as for a pause and hold there until the mode is on
                s._core_order = CoreOrder.PAUSE
