"""Where the flight's record places the payload (``companion.flight.flight_record``): on the cable the companion flies
(the mission's, or the identified one once a hop has run), or on the true cable where the set-up knows it (the
bundled vehicle's ``--true-cable-length-m``), so that the report's clearance and collisions are the payload's own."""

from __future__ import annotations

import numpy as np
import pytest

from companion.config import resolve_mission
from companion.core.mission import load_mission
from companion.estimation.estimate import Estimate
from companion.estimation.vehicle_state import VehicleState
from companion.flight.flight_record import FlightRecord


def _hang_m(true_cable_m: float | None, flown_cable_m: float) -> float:
    """The logged payload's distance from the airframe after one row with a cable sensor sample of 0.2/−0.1 rad."""
    mission = load_mission(resolve_mission("forest"))
    state = VehicleState(cable_length_m=mission.vehicle.l)
    state.cable_length_m = flown_cable_m  # what an identification's conclusion sets
    state.t_s = state.swing_sensor_t_s = 1.0
    state.swing_sensor = np.array([0.2, -0.1, 0.0, 0.0])
    record = FlightRecord(mission, state, true_cable_m)
    pos = np.array([1.0, 2.0, -2.0])
    record.append(Estimate(1.0, pos, np.zeros(3), np.zeros(3), np.zeros(3)), None, np.zeros(3))
    return float(np.linalg.norm(record.log.arr("payload_pos")[-1] - pos))


def test_the_payload_hangs_on_the_cable_flown():
    assert _hang_m(None, 1.0) == pytest.approx(1.0)  # the mission's
    assert _hang_m(None, 1.6) == pytest.approx(1.6)  # identified after a hop, and flown


def test_the_true_cable_wins_where_the_set_up_knows_it():
    assert _hang_m(1.3, 1.0) == pytest.approx(1.3)
    assert _hang_m(1.3, 1.6) == pytest.approx(1.3)
