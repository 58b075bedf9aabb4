"""The Lagrangian model: conservation, equilibrium, bad input, parameter loading."""

import math

import numpy as np
import pytest

from companion.core.model import (
    accelerations,
    dynamics,
    energy_j,
    rk4_batch,
    rk4_step,
)
from companion.core.vehicle_params import VehicleParams, load_vehicle_params
from companion.errors import ConfigError, ModelError

P = VehicleParams()


def _spinning_swinging_state() -> np.ndarray:
    x = np.zeros(16)
    x[3:6] = [0.3, -0.2, 0.5]  # attitude
    x[6:8] = [0.4, -0.3]  # swing
    x[8:11] = [1.0, -0.5, 0.2]  # translation
    x[11:14] = [2.0, -1.0, 5.0]  # body spinning
    x[14:16] = [1.0, 0.5]  # payload swinging
    return x


def test_energy_conserved_in_free_fall_with_spin_and_swing():
    x = _spinning_swinging_state()
    e0 = energy_j(x, P)
    y = rk4_step(x, np.zeros(4), np.zeros(6), P, 1e-3, 10_000)  # 10 s
    drift = abs(energy_j(y, P) - e0)
    assert drift < 1e-6, drift
    # and it really moved: fell ~490 m, so the potential changed by far more than the tolerance
    assert y[2] > 400.0


def test_energy_not_conserved_when_coriolis_term_is_wrong():
    """Guard that the energy test can fail: a model with a sign error in one velocity term drifts."""
    from companion.core import model

    x = _spinning_swinging_state()
    e0 = energy_j(x, P)
    pk = P.packed()
    y = x.copy()
    k1 = np.empty(16)
    dt = 1e-3
    for _ in range(2000):  # explicit Euler-free: RK4 with a corrupted derivative
        def f(s):
            out = np.empty(16)
            model._deriv(s, np.zeros(4), np.zeros(6), pk, out)
            # corrupt: flip the sign of the payload's centripetal contribution to β̈
            out[15] += 2.0 * P.l * math.sin(s[7]) * math.cos(s[7]) * s[14] ** 2 * 0.5
            return out
        k1 = f(y)
        k2 = f(y + 0.5 * dt * k1)
        k3 = f(y + 0.5 * dt * k2)
        k4 = f(y + dt * k3)
        y = y + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    assert abs(energy_j(y, P) - e0) > 1e-3


def test_hover_thrust_holds_everything_at_rest():
    x = np.zeros(16)
    x[2] = -3.0
    y = rk4_step(x, [P.hover_thrust_n, 0, 0, 0], np.zeros(6), P, 1e-3, 5000)
    np.testing.assert_allclose(y, x, atol=1e-12)
    qdd = accelerations(x[:8], x[8:], [P.hover_thrust_n, 0, 0, 0], np.zeros(6), P)
    np.testing.assert_allclose(qdd, 0.0, atol=1e-12)


def test_payload_hangs_down_and_is_stable():
    """A displaced payload accelerates back towards the vertical (not an inverted pendulum)."""
    q = np.zeros(8)
    q[6] = 0.1
    q[7] = -0.1
    qdd = accelerations(q, np.zeros(8), [P.hover_thrust_n, 0, 0, 0], np.zeros(6), P)
    assert qdd[6] < 0.0 and qdd[7] > 0.0


def test_thrust_points_up_and_tilt_accelerates_forward():
    """Pitch nose-down (θ < 0) with hover thrust accelerates north (+x); extra thrust climbs (−z)."""
    q = np.zeros(8)
    q[4] = -0.1
    qdd = accelerations(q, np.zeros(8), [P.hover_thrust_n / math.cos(0.1), 0, 0, 0], np.zeros(6), P)
    assert qdd[0] > 0.5
    qdd = accelerations(np.zeros(8), np.zeros(8), [2 * P.hover_thrust_n, 0, 0, 0], np.zeros(6), P)
    assert qdd[2] == pytest.approx(-P.g, rel=1e-9)


def test_body_torque_maps_through_r_eta():
    """Roll torque at non-zero pitch: the body-x torque must show up as φ̈ and ψ̈ via R_η⁻¹ (not only φ̈)."""
    q = np.zeros(8)
    q[4] = 0.5
    qdd = accelerations(q, np.zeros(8), [P.hover_thrust_n, 0.0, 0.0, 0.01], np.zeros(6), P)
    # pure yaw torque in the body frame at pitch 0.5 rad: ψ̈ = τz/(Izz cosθ), φ̈ = tanθ·τz/Izz
    assert qdd[5] == pytest.approx(0.01 / P.Izz / math.cos(0.5), rel=1e-9)
    assert qdd[3] == pytest.approx(math.tan(0.5) * 0.01 / P.Izz, rel=1e-9)


def test_dynamics_matches_rk4_and_scipy_can_integrate_it():
    from scipy.integrate import solve_ivp

    x0 = _spinning_swinging_state()
    u = np.array([P.hover_thrust_n * 1.1, 0.001, -0.002, 0.0005, 0.1, 0.1, 0.1, 0.01, 0.01, 0.01])
    sol = solve_ivp(dynamics, (0.0, 1.0), x0, args=(u, P), rtol=1e-10, atol=1e-12)
    y = rk4_step(x0, u[:4], u[4:], P, 1e-3, 1000)
    np.testing.assert_allclose(sol.y[:, -1], y, atol=1e-6)


def test_batch_equals_single():
    x = _spinning_swinging_state()
    X = np.stack([x, x * 0.5])
    U = np.array([[14.0, 0.0, 0.0, 0.0], [15.0, 0.01, 0.0, 0.0]])
    D = np.zeros((2, 6))
    Y = rk4_batch(X, U, D, P, 1e-3, 100)
    for k in range(2):
        np.testing.assert_array_equal(Y[k], rk4_step(X[k], U[k], D[k], P, 1e-3, 100))


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_input_raises(bad):
    q = np.zeros(8)
    q[6] = bad
    with pytest.raises(ModelError, match="non-finite"):
        accelerations(q, np.zeros(8), [1, 0, 0, 0], np.zeros(6), P)
    with pytest.raises(ModelError, match="non-finite"):
        rk4_step(np.zeros(16), [bad, 0, 0, 0], np.zeros(6), P)


def test_pitch_singularity_raises():
    x = np.zeros(16)
    x[4] = math.pi / 2
    with pytest.raises(ModelError, match="singularity"):
        rk4_step(x, [1, 0, 0, 0], np.zeros(6), P)


def test_defaults_are_table1():
    assert (P.M, P.m, P.g, P.Ixx, P.Iyy, P.Izz, P.Ip, P.l, P.r_uav, P.L_uav) == (
        1.25, 0.25, 9.81, 0.0087, 0.0087, 0.016, 1e-6, 1.0, 0.10, 0.18)


def test_shipped_vehicle_toml_loads_as_table1():
    assert load_vehicle_params("config/vehicle.toml") == P


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("[vehicle]\nmass = 1.0\n", "unknown key 'mass'"),
        ("[vehicle]\nm = 'heavy'\n", "m: expected float"),
        ("[vehicle]\nm = -0.25\n", "m: must be > 0"),
        ("[vehicle]\nl = 0.0\n", "l: must be > 0"),
        ("[vehicle]\nIzz = 1.0\n", "Izz: principal moments"),
        ("[vehicle]\nm = nan\n", "m: must be finite"),
        ("[vehicle\nm = 1\n", "not valid TOML"),
        ("[vehicles]\nm = 1.0\n", "unknown table or key 'vehicles'"),
    ],
)
def test_broken_vehicle_toml_names_file_and_key(tmp_path, text, match):
    f = tmp_path / "vehicle.toml"
    f.write_text(text)
    with pytest.raises(ConfigError, match=match) as exc:
        load_vehicle_params(f)
    assert str(f) in str(exc.value)
