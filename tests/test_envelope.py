"""Envelope (eqs. 3-4, 20-21) and swing-from-payload inversion, against hand-computed values."""

import math

import numpy as np
import pytest

from companion.core.envelope import envelope_radii_m, full_cable_r_max_m, payload_pos_ned_m, r_max_m
from companion.core.model import VehicleParams
from companion.estimation.estimate import swing_from_payload

P = VehicleParams()


def test_payload_hangs_below_at_rest():
    np.testing.assert_allclose(payload_pos_ned_m(np.array([1.0, 2.0, -3.0]), 0.0, 0.0, 1.0), [1.0, 2.0, -2.0])


def test_payload_position_hand_computed():
    # alpha = 30 deg, beta = 0: offset l*[sin 30, 0, cos 30]
    p = payload_pos_ned_m(np.zeros(3), math.radians(30), 0.0, 2.0)
    np.testing.assert_allclose(p, [1.0, 0.0, math.sqrt(3.0)], atol=1e-12)
    # beta = 30 deg, alpha = 0: offset l*[0, -sin 30, cos 30]
    p = payload_pos_ned_m(np.zeros(3), 0.0, math.radians(30), 2.0)
    np.testing.assert_allclose(p, [0.0, -1.0, math.sqrt(3.0)], atol=1e-12)


def test_r1_r2_and_rmax_switch():
    r1, r2 = envelope_radii_m(0.0, 0.0, P)
    assert r1 == 0.0 and r2 == pytest.approx(0.28)
    assert r_max_m(0.0, 0.0, P) == pytest.approx(0.28)
    # small swing: payload inside the airframe circle -> r2
    assert r_max_m(0.1, 0.1, P) == pytest.approx(0.28)
    # alpha = 0.5 rad, beta = 0.2: r1 = l*sqrt((cos .2 sin .5)^2 + sin^2 .2)
    exp = math.sqrt((math.cos(0.2) * math.sin(0.5)) ** 2 + math.sin(0.2) ** 2)
    assert envelope_radii_m(0.5, 0.2, P)[0] == pytest.approx(exp)
    assert r_max_m(0.5, 0.2, P) == pytest.approx(exp)
    assert full_cable_r_max_m(P) == 1.0
    assert full_cable_r_max_m(VehicleParams(l=0.2)) == pytest.approx(0.28)


@pytest.mark.parametrize("al,be,dal,dbe", [(0.3, -0.2, 0.5, -1.0), (-1.0, 0.7, -2.0, 0.3), (0.0, 0.0, 0.1, 0.2)])
def test_swing_from_payload_inverts_eqs_3_4(al, be, dal, dbe):
    l = 1.3
    pos = np.array([1.0, -2.0, -4.0])
    vel = np.array([0.3, 0.1, -0.2])
    ca, sa, cb, sb = math.cos(al), math.sin(al), math.cos(be), math.sin(be)
    pay = payload_pos_ned_m(pos, al, be, l)
    pay_vel = vel + l * np.array([ca * cb * dal - sa * sb * dbe, -cb * dbe, -sa * cb * dal - ca * sb * dbe])
    np.testing.assert_allclose(swing_from_payload(pos, pay, vel, pay_vel, l), [al, be, dal, dbe], atol=1e-9)


def test_swing_from_payload_refuses_degenerate():
    with pytest.raises(ValueError):
        swing_from_payload(np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3), 1.0)
