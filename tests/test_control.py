"""Attitude from force, payload reaction, feed-forward sign (closed loop against the bundled physics)."""

import math

import numpy as np
import pytest

from companion.control import (
    CONTROLLER_NAMES,
    ControllerConfig,
    PositionController,
    attitude_from_force,
    feedforward_acc,
    limit_force,
    load_controller_config,
    make_position_controller,
    payload_reaction_n,
)
from companion.control.params import FeedForwardGains
from companion.core.model import accelerations, rotation_body_to_ned
from companion.core.rotations import euler_from_quat
from companion.core.vehicle_params import VehicleParams
from companion.core.wind import WindConfig
from companion.errors import ConfigError
from sim_bridge.physics import VehicleSim

P = VehicleParams()


def test_hover_force_is_level():
    q, t, e = attitude_from_force(np.array([0.0, 0.0, -P.hover_thrust_n]), 0.3)
    assert t == pytest.approx(P.hover_thrust_n)
    np.testing.assert_allclose(e, [0.0, 0.0, 0.3], atol=1e-12)
    np.testing.assert_allclose(euler_from_quat(q), e, atol=1e-12)


@pytest.mark.parametrize("f,yaw", [([3.0, -2.0, -14.0], 0.0), ([-4.0, 1.0, -12.0], 1.0), ([0.5, 5.0, -20.0], -2.5)])
def test_thrust_vector_matches_desired_force(f, yaw):
    f = np.array(f)
    _q, t, e = attitude_from_force(f, yaw)
    # model convention: thrust in NED is -R_F [0, 0, T]
    np.testing.assert_allclose(-rotation_body_to_ned(*e) @ np.array([0.0, 0.0, t]), f, atol=1e-9)
    assert e[2] == pytest.approx(yaw)


def test_pitch_forward_for_north_force():
    # accelerate north (+x): nose down, i.e. negative pitch in FRD/NED
    _, _, e = attitude_from_force(np.array([2.0, 0.0, -14.7]), 0.0)
    assert e[1] < 0.0 and abs(e[0]) < 1e-12


def test_limits():
    f = limit_force(np.array([30.0, 0.0, -10.0]), 0.5, 2.0, 30.0)
    assert math.atan2(math.hypot(f[0], f[1]), -f[2]) == pytest.approx(0.5)
    f = limit_force(np.array([0.0, 0.0, 5.0]), 0.5, 2.0, 30.0)  # asks to push down: minimum lift
    assert f[2] == pytest.approx(-2.0)
    f = limit_force(np.array([20.0, 0.0, -40.0]), 0.6, 2.0, 30.0)
    assert np.linalg.norm(f) == pytest.approx(30.0) and f[0] == 0.0


def test_payload_reaction_matches_model():
    """(M+m)ξ̈ = F + f + (M+m)g e_z with f from payload_reaction_n and ξ̈, s̈ from the Lagrangian model."""
    q = np.array([0.0, 0.0, -2.0, 0.1, -0.2, 0.3, 0.4, -0.3])
    qd = np.array([0.5, -0.2, 0.1, 0.2, 0.1, -0.1, 1.2, -0.8])
    u = np.array([16.0, 0.0, 0.0, 0.0])
    qdd = accelerations(q, qd, u, np.zeros(6), P)
    f = payload_reaction_n(np.array([q[6], q[7], qd[6], qd[7]]), qdd[6:8], P.m, P.l)
    thrust = -rotation_body_to_ned(*q[3:6]) @ np.array([0.0, 0.0, u[0]])
    lhs = (P.M + P.m) * qdd[:3]
    np.testing.assert_allclose(lhs, thrust + f + np.array([0.0, 0.0, (P.M + P.m) * P.g]), atol=1e-9)


def test_feedforward_signs_by_hand():
    ff = FeedForwardGains(a1=0.1, a2=0.1, a3=0.0, k_angle=8.0, k_rate=2.0)
    # payload swung to +x (alpha > 0) and moving +x: accelerate +x
    u = feedforward_acc(np.array([0.1, 0.0, 0.5, 0.0]), np.array([-1.0, 0.0]), ff, 1.0)
    assert u[0] == pytest.approx(8.0 * 0.1 + 2.0 * 0.5 + 0.1 * 1.0)
    # beta > 0 puts the payload at -y: accelerate -y
    u = feedforward_acc(np.array([0.0, 0.1, 0.0, 0.5]), np.array([0.0, -1.0]), ff, 1.0)
    assert u[1] == pytest.approx(-(8.0 * 0.1 + 2.0 * 0.5 + 0.1 * 1.0))


def _hover_swing(ff_sign: float, controller: str, seconds: float = 5.0) -> np.ndarray:
    """Hover at 5 m with an initial swing (no wind), SMC position loop closed on the real physics."""
    x0 = np.zeros(16)
    x0[2] = -5.0
    x0[6], x0[7] = 0.15, -0.1
    sim = VehicleSim(P, wind=WindConfig("none", 0.0), x0=x0)
    sim.armed = True
    sim.landed = False
    cfg = ControllerConfig()
    ctl = make_position_controller(controller, cfg, P)
    if controller == "smc_ff":
        ctl.ff_sign = ff_sign
    from companion.control import SwingAccelEstimator

    est = SwingAccelEstimator(cfg.feedforward.rate_filter_s)
    ref = np.array([0.0, 0.0, -5.0])
    amp = []
    for _ in range(int(seconds / 0.004)):
        sw = sim.swing
        sacc = est.update(sim.t_s, sw[2:4])
        out = ctl.update(sim.pos_ned_m, sim.vel_ned_mps, ref, np.zeros(3), np.zeros(3), sw, sacc, 0.004)
        f = limit_force(out.force_ned_n, 0.6, 0.2 * P.hover_thrust_n, 2.2 * P.hover_thrust_n)
        q, t, _ = attitude_from_force(f, 0.0)
        sim.set_attitude_target(q, t)
        sim.step(4)
        amp.append(max(abs(sw[0]), abs(sw[1])))
    return np.array(amp)


def test_feedforward_sign_damps_and_flipped_sign_grows():
    good = _hover_swing(+1.0, "smc_ff")
    bad = _hover_swing(-1.0, "smc_ff", seconds=3.0)
    smc = _hover_swing(+1.0, "smc")
    last = slice(-250, None)  # last second
    assert good[last].max() < 0.03  # damped from 0.15 rad within 5 s
    assert bad.max() > 0.3  # diverges within 3 s
    assert smc[last].max() > 0.1  # without feed-forward the swing stays


def test_controller_config_file_and_errors(tmp_path):
    assert load_controller_config() == ControllerConfig()
    p = tmp_path / "c.toml"
    p.write_text("[smc]\nc = [1.0, 1.0]\n")
    with pytest.raises(ConfigError, match=r"\[smc\] c: expected"):
        load_controller_config(p)
    p.write_text("[feedforward]\na1 = 0.7\n")
    with pytest.raises(ConfigError, match=r"\[feedforward\] a1: must be < 0.5"):
        load_controller_config(p)
    p.write_text("[gainz]\n")
    with pytest.raises(ConfigError, match="unknown table 'gainz'"):
        load_controller_config(p)


def test_unknown_controller():
    with pytest.raises(ValueError, match="controller"):
        make_position_controller("lqr", ControllerConfig(), P)


def test_feedforward_is_bounded():
    """A large swing asks eq. 48 for far more than max_mps2: the horizontal feed-forward is scaled down to the
    bound, its direction kept; a small swing is untouched."""
    from dataclasses import replace

    cfg = ControllerConfig()
    ctl = make_position_controller("smc_ff", cfg, P)
    z3 = np.zeros(3)
    big = ctl.update(z3, z3, z3, z3, z3, np.array([0.6, -0.4, 2.0, -1.5]), np.zeros(2), 0.004).ff_acc_mps2
    assert math.hypot(big[0], big[1]) == pytest.approx(cfg.feedforward.max_mps2)
    free = make_position_controller("smc_ff", replace(cfg, feedforward=replace(cfg.feedforward, max_mps2=1e9)), P)
    raw = free.update(z3, z3, z3, z3, z3, np.array([0.6, -0.4, 2.0, -1.5]), np.zeros(2), 0.004).ff_acc_mps2
    assert math.hypot(raw[0], raw[1]) > 3.0 * cfg.feedforward.max_mps2
    np.testing.assert_allclose(big[:2] / np.linalg.norm(big[:2]), raw[:2] / np.linalg.norm(raw[:2]))
    small = np.array([0.02, 0.01, 0.0, 0.0])
    np.testing.assert_allclose(ctl.update(z3, z3, z3, z3, z3, small, np.zeros(2), 0.004).ff_acc_mps2,
                               free.update(z3, z3, z3, z3, z3, small, np.zeros(2), 0.004).ff_acc_mps2)


@pytest.mark.parametrize("name", CONTROLLER_NAMES)
def test_every_controller_declares_what_it_does(name):
    """The PositionController protocol in full, and each declaration true of what update() does: only a
    feed-forward controller answers a swing with a feed-forward, only one that softens_with_lag answers a lower
    gain_scale with a different force."""
    ctl = make_position_controller(name, ControllerConfig(), P)
    assert isinstance(ctl, PositionController) and ctl.gain_scale == 1.0
    assert ctl.softens_with_lag is name.startswith("smc") and ctl.swing_feedforward is (name == "smc_ff")
    args = (np.zeros(3), np.zeros(3), np.array([1.0, -0.5, -2.0]), np.zeros(3), np.zeros(3),
            np.array([0.1, -0.05, 0.2, 0.1]), np.array([0.3, -0.1]), 0.004)
    stiff = make_position_controller(name, ControllerConfig(), P).update(*args)
    assert bool(np.any(stiff.ff_acc_mps2 != 0.0)) is ctl.swing_feedforward
    ctl.gain_scale = 0.25
    soft = ctl.update(*args)
    assert bool(np.any(soft.force_ned_n != stiff.force_ned_n)) is ctl.softens_with_lag



def _hover_offset_m(ki: float, ref_speed_mps: float = 0.0, seconds: float = 30.0) -> float:
    """Fly a point mass (M + m) under a steady 1 N push along +y with the SMC (no payload swing): the final
    position error (m) along y while the reference hovers at the origin (or moves along x at ``ref_speed_mps``)."""
    from companion.control.params import SmcGains
    from companion.control.position import SmcPositionController

    vp = VehicleParams()
    mt = vp.M + vp.m
    ctl = SmcPositionController(SmcGains(ki=ki), vp, None, 6.0)
    dt = 0.004
    pos, vel = np.zeros(3), np.zeros(3)
    for k in range(int(seconds / dt)):
        ref = np.array([ref_speed_mps * k * dt, 0.0, 0.0])
        out = ctl.update(pos, vel, ref, np.array([ref_speed_mps, 0.0, 0.0]), np.zeros(3), None, None, dt)
        acc = (out.force_ned_n + np.array([0.0, 1.0, 0.0])) / mt + np.array([0.0, 0.0, vp.g])
        vel = vel + acc * dt
        pos = pos + vel * dt
    return float(pos[1])


def test_integral_action_removes_a_steady_winds_offset_at_a_hover():
    without = _hover_offset_m(0.0)
    assert without > 0.1  # the sliding mode alone leaves a steady offset downwind
    assert abs(_hover_offset_m(0.5, seconds=60.0)) < 0.01 * without


def test_integral_action_rests_while_the_reference_moves():
    assert _hover_offset_m(0.5, ref_speed_mps=1.0) == pytest.approx(_hover_offset_m(0.0, ref_speed_mps=1.0))
