"""Where a flight is, in one typed model: the sequence's states, the flight core's phases, the orders the sequence
gives the core, and the phases a finished flight ends in.

The two state machines stay apart (the sequence decides what the companion does with the vehicle; the core
flies the mission), but every value that passes between them or out of them is one of these enums, never a bare
string. They are ``StrEnum`` so that reports, logs and the Zenoh status keep their plain words (``"cruise"``).
:func:`flight_phase` is the one place that merges them into what the flight reports as its phase.
"""

from __future__ import annotations

from enum import StrEnum


class State(StrEnum):
    """Where the flight sequence is (``companion.flight.sequence``)."""

    CONNECT = "connect"
    CONFIGURE = "configure"
    WAIT_READY = "wait_ready"
    PRESTREAM = "prestream"
    ARM = "arm"
    TAKEOVER = "takeover"
    MISSION = "mission"
    HOLD = "hold"
    LAND = "land"
    DESCEND = "descend"
    DONE = "done"


class CorePhase(StrEnum):
    """Where the flight core is during the mission (``companion.flight.core``)."""

    CLIMB = "climb"  # vertical, to the mission's start altitude
    IDENTIFY = "identify"  # a hop that identifies an unknown payload, then a hover until it is identified
    CRUISE = "cruise"  # the planner towards the goal
    HOLD = "hold"  # at the goal for the mission's hold time
    NO_ROUTE = "no_route"  # the planner found no route: holding where it stopped
    DONE = "done"  # hold finished, no route, or timeout (``FlightCore.result`` says which)
    HOLD_HERE = "hold_here"  # the sequence stopped the mission: hover where the reference is
    DESCEND = "descend"  # the sequence stopped the mission: the companion's own gentle descent


class CoreOrder(StrEnum):
    """What the sequence tells the flight core when it stops the mission (given once, on entering a state)."""

    HOLD_HERE = "hold_here"
    DESCEND = "descend"
    PAUSE = "pause"  # the ground station's pause: brake at the reference's limits, hold where it stops
    RESUME = "resume"  # the ground station's pause ended: fly the mission on (companion.flight.operator)


class FinalPhase(StrEnum):
    """Where a finished flight ended, beyond the sequence's own states."""

    LANDED = "landed"
    LAND_TIMEOUT = "land_timeout"
    HOLDING = "holding"  # left holding in the vehicle's hold mode (the mission said not to land)
    LINK_LOST = "link_lost"
    PREEMPTED = "preempted"


#: What the flight reports as its phase: a sequence state, a core phase during the mission, or a final phase.
Phase = State | CorePhase | FinalPhase


def flight_phase(state: State, final_phase: State | FinalPhase, core_phase: CorePhase) -> Phase:
    """The flight's phase: the final phase once done, the core's phase during the mission, else the state."""
    if state is State.DONE:
        return final_phase
    if state is State.MISSION:
        return core_phase
    return state
