"""The swing estimator's process and measurement models are the project's Lagrangian model, reduced."""

import math

import numpy as np
import pytest
from scipy.linalg import expm

from companion.core.model import accelerations, rotation_body_to_ned
from companion.core.rotations import quat_from_euler
from companion.core.vehicle_params import VehicleParams
from companion.estimation.swing_model import (
    N_STATE,
    accel_force_jacobian,
    dynamics,
    imu_specific_force,
    payload_offset_from_global,
    payload_offset_jacobian,
    payload_offset_m,
    rotate_by_rates,
    rotation_from_euler,
    rotation_from_quat,
    swing_from_offset,
    thrust_axis_by_rates,
    thrust_force_ned_n,
    translation_swing_accel,
)

PARAMS = (VehicleParams(), VehicleParams(m=0.4, l=0.6, Ip=0.01, M=2.0))


def _random_case(rng):
    q = rng.uniform(-1.0, 1.0, 8)
    q[3:5] *= 0.5
    qd = rng.uniform(-2.0, 2.0, 8)
    u = np.array([rng.uniform(5.0, 25.0), *rng.uniform(-0.5, 0.5, 3)])
    d = rng.uniform(-1.0, 1.0, 6)
    return q, qd, u, d


@pytest.mark.parametrize("p", PARAMS)
def test_kernel_equals_the_8dof_model(p):
    """α̈, β̈ and ξ̈ of the reduced kernel equal companion.core.model.accelerations on random states."""
    rng = np.random.default_rng(7)
    worst = 0.0
    for _ in range(200):
        q, qd, u, d = _random_case(rng)
        ref = accelerations(q, qd, u, d, p)
        fx, fy, fz = thrust_force_ned_n(rotation_from_euler(*q[3:6]), u[0])
        got = translation_swing_accel(q[6], q[7], qd[6], qd[7], fx + d[0], fy + d[1], fz + d[2],
                                      p.M, p.m, p.g, p.Ip, p.l)
        worst = max(worst, float(np.max(np.abs(np.array(got) - ref[[6, 7, 0, 1, 2]]))))
    assert worst < 1e-9


@pytest.mark.parametrize("p", PARAMS)
def test_dynamics_state_layout_and_thrust_error(p):
    """dynamics(): α̇, β̇ pass through, v̇ = ξ̈, the random walks have no drift, δT adds to the thrust."""
    rng = np.random.default_rng(3)
    q, qd, u, d = _random_case(rng)
    q[3:6] = u[1:4]
    x = np.zeros(N_STATE)
    x[0:2], x[2:4] = q[6:8], qd[6:8]
    x[7:10] = d[:3]
    x[13] = 1.5
    xd = dynamics(0.0, x, u, p)
    ref = accelerations(q, qd, np.array([u[0] + 1.5, *u[1:]]), d, p)
    np.testing.assert_allclose(xd[0:2], qd[6:8])
    np.testing.assert_allclose(xd[2:4], ref[6:8], atol=1e-9)
    np.testing.assert_allclose(xd[4:7], ref[0:3], atol=1e-9)
    assert np.all(xd[7:] == 0.0)


def test_force_jacobian_is_exact():
    p = PARAMS[1]
    rng = np.random.default_rng(5)
    for _ in range(20):
        al, be, dal, dbe = rng.uniform(-1, 1, 4)
        f = rng.uniform(-10, 10, 3)
        J = accel_force_jacobian(al, be, p.M, p.m, p.Ip, p.l)
        base = np.array(translation_swing_accel(al, be, dal, dbe, *f, p.M, p.m, p.g, p.Ip, p.l))
        for j in range(3):
            f2 = f.copy()
            f2[j] += 1.0  # affine in f: a unit step is exact
            step = np.array(translation_swing_accel(al, be, dal, dbe, *f2, p.M, p.m, p.g, p.Ip, p.l)) - base
            np.testing.assert_allclose(step, J[:, j], atol=1e-9)


def test_imu_measurement_is_the_airframe_newton_equation():
    """f_b = Rᵀ(ξ̈ − g·e_z) + b, and M·R·(f_b − b) = F + d + tension along the cable (nothing else pushes it;
    with a point payload, Ip = 0, the cable carries no moment)."""
    p = VehicleParams(Ip=0.0)
    rng = np.random.default_rng(11)
    for _ in range(50):
        q, qd, u, d = _random_case(rng)
        x = np.zeros(N_STATE)
        x[0:2], x[2:4], x[7:10], x[10:13] = q[6:8], qd[6:8], d[:3], rng.normal(0, 0.1, 3)
        R = rotation_from_euler(*u[1:4])
        f_b = imu_specific_force(x, R, u[0], p)
        a = accelerations(np.r_[q[:3], u[1:4], q[6:8]], qd, u, d, p)[0:3]
        np.testing.assert_allclose(f_b, R.T @ (a - [0, 0, p.g]) + x[10:13], atol=1e-9)
        cable = p.M * (R @ (f_b - x[10:13])) - np.array(thrust_force_ned_n(R, u[0])) - d[:3]
        r = np.array(payload_offset_m(q[6], q[7], p.l))
        assert np.linalg.norm(np.cross(cable, r)) < 1e-8 * max(1.0, np.linalg.norm(cable))  # along the cable
        assert cable @ r > 0.0  # pulls the airframe towards the payload (taut cable)


def test_payload_offset_geometry():
    p = PARAMS[1]
    for al, be in ((0.0, 0.0), (0.3, -0.2), (-1.0, 0.7)):
        r = np.array(payload_offset_m(al, be, p.l))
        assert math.isclose(np.linalg.norm(r), p.l)
        a2, b2 = swing_from_offset(r * 3.0)
        assert math.isclose(a2, al, abs_tol=1e-12) and math.isclose(b2, be, abs_tol=1e-12)
        J = payload_offset_jacobian(al, be, p.l)
        eps = 1e-7
        num = np.column_stack([(np.array(payload_offset_m(al + eps, be, p.l)) - r) / eps,
                               (np.array(payload_offset_m(al, be + eps, p.l)) - r) / eps])
        np.testing.assert_allclose(J, num, atol=1e-6)
    with pytest.raises(ValueError):
        swing_from_offset([0.0, 0.0, 0.0])


def test_rotations():
    e = (0.2, -0.3, 2.0)
    np.testing.assert_allclose(rotation_from_euler(*e), rotation_body_to_ned(*e), atol=1e-15)
    np.testing.assert_allclose(rotation_from_quat(quat_from_euler(*e)), rotation_body_to_ned(*e), atol=1e-12)
    R = rotation_from_euler(*e)
    w = (0.5, -1.2, 0.7)
    K = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    np.testing.assert_allclose(rotate_by_rates(R, w, 0.05), R @ expm(K * 0.05), atol=1e-12)
    np.testing.assert_allclose(thrust_axis_by_rates(R.tolist(), w, 0.05), (R @ expm(K * 0.05))[:, 2], atol=1e-12)


def test_offset_from_two_global_positions():
    """ArduPilot's convention: the payload's and the vehicle's GLOBAL_POSITION_INT, differenced, in NED."""
    lat, lon, alt = -35.363261, 149.165230, 584.0
    # 1 m north, 0.5 m east, 0.9 m below, built with the same WGS-84 radii
    r_n = 6378137.0 * (1 - 6.69437999014e-3) / (1 - 6.69437999014e-3 * math.sin(math.radians(lat)) ** 2) ** 1.5
    r_e = 6378137.0 / math.sqrt(1 - 6.69437999014e-3 * math.sin(math.radians(lat)) ** 2)
    dlat = math.degrees(1.0 / (r_n + alt))
    dlon = math.degrees(0.5 / ((r_e + alt) * math.cos(math.radians(lat))))
    off = payload_offset_from_global(lat + dlat, lon + dlon, alt - 0.9, lat, lon, alt)
    np.testing.assert_allclose(off, [1.0, 0.5, 0.9], atol=1e-6)
    # GLOBAL_POSITION_INT's quantization (1e-7 deg, 1 mm) is ~1 cm horizontally: the offset's resolution
    q = payload_offset_from_global(lat + 1e-7, lon, alt, lat, lon, alt)
    assert 0.010 < q[0] < 0.012


def test_a_force_on_the_payload_obeys_newton_on_both_bodies():
    """The payload force p enters as generalized forces (p on ξ, Jᵀ·p on s): with Ip = 0 the airframe and the
    payload each obey Newton's law with one cable tension along the cable between them."""
    p = VehicleParams(Ip=0.0)
    rng = np.random.default_rng(5)
    for _ in range(50):
        al, be = rng.uniform(-0.8, 0.8, 2)
        dal, dbe = rng.uniform(-2.0, 2.0, 2)
        f = rng.uniform(-5.0, 5.0, 3) + np.array([0.0, 0.0, -14.0])
        push = rng.uniform(-1.0, 1.0, 3)
        dda, ddb, ax, ay, az = translation_swing_accel(al, be, dal, dbe, *f, p.M, p.m, p.g, p.Ip, p.l, *push)
        xi_dd = np.array([ax, ay, az])
        eps = 1e-6  # r̈ = J·s̈ + J̇·ṡ, J̇·ṡ by a central difference along ṡ
        J = payload_offset_jacobian(al, be, p.l)
        Jdot = (payload_offset_jacobian(al + eps * dal, be + eps * dbe, p.l)
                - payload_offset_jacobian(al - eps * dal, be - eps * dbe, p.l)) / (2 * eps)
        r_dd = J @ [dda, ddb] + Jdot @ [dal, dbe]
        g = np.array([0.0, 0.0, p.g])
        cable_on_airframe = p.M * (xi_dd - g) - f  # what pulls the airframe besides f and gravity
        cable_on_payload = p.m * (xi_dd + r_dd - g) - push
        np.testing.assert_allclose(cable_on_airframe, -cable_on_payload, atol=1e-6)  # one tension, both ends
        r = np.array(payload_offset_m(al, be, p.l))
        assert np.linalg.norm(np.cross(cable_on_airframe, r)) < 1e-6 * max(1.0, np.linalg.norm(cable_on_airframe))


def test_drag_states_enter_the_airframe_and_payload_forces():
    """x[14] = c drags the airframe by −c·(v_N, v_E, 0); x[15] = k drags the payload by −k·|v_p|·v_p; both are
    random walks (no drift) and move the accelerometer's prediction."""
    from companion.estimation.swing_model import I_DRAG, I_PDRAG, airframe_force_ned_n, payload_force_ned_n

    p = PARAMS[0]
    x = np.zeros(N_STATE)
    x[0:4] = (0.1, -0.05, 0.3, 0.2)
    x[4:7] = (2.0, -1.0, 0.1)
    R = rotation_from_euler(0.05, -0.1, 0.3)
    T = p.hover_thrust_n
    base = np.array(airframe_force_ned_n(x, R, T))
    x[I_DRAG] = 0.8
    np.testing.assert_allclose(np.array(airframe_force_ned_n(x, R, T)) - base, [-1.6, 0.8, 0.0], atol=1e-12)
    J = payload_offset_jacobian(x[0], x[1], p.l)
    v_p = x[4:7] + J @ x[2:4]
    x[I_PDRAG] = 0.05
    np.testing.assert_allclose(payload_force_ned_n(x, p.l), -0.05 * np.linalg.norm(v_p) * v_p, atol=1e-12)
    xd = dynamics(0.0, x, [T, 0.05, -0.1, 0.3], p)
    assert xd[I_DRAG] == 0.0 and xd[I_PDRAG] == 0.0
    x0 = x.copy()
    x0[I_DRAG] = x0[I_PDRAG] = 0.0
    assert np.linalg.norm(imu_specific_force(x, R, T, p) - imu_specific_force(x0, R, T, p)) > 0.3
