"""The bundled vehicle's IMU: specific force from the physics (derived, checked against Newton's law for the
airframe), the seeded noise and bias model's statistics, and HIGHRES_IMU over real UDP at hover."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as M

from companion.core.model import accelerations, rotation_body_to_ned
from companion.core.rotations import quat_from_euler
from companion.core.vehicle_params import VehicleParams
from companion.core.wind import WindConfig
from sim_bridge.imu import ImuModel, ImuNoise
from sim_bridge.mavclient import MavClient, spawn_vehicle, stop_vehicle
from sim_bridge.physics import VehicleSim

pytestmark = pytest.mark.shares_cores  # lockstep processes, no deadline: they may share the cores (conftest.py)
P = VehicleParams()


def _airborne(alpha: float = 0.0, beta: float = 0.0) -> VehicleSim:
    x0 = np.zeros(16)
    x0[2] = -3.0
    x0[6], x0[7] = alpha, beta
    sim = VehicleSim(P, WindConfig("none", 0.0), x0=x0)
    sim.armed = True
    return sim


def test_hover_with_hanging_payload_reads_minus_g_not_thrust_over_mass():
    """At rest in the air the airframe's acceleration is zero, so f = Rᵀ(0 − g·e_z) = [0, 0, −g]: the rotors
    push (M+m)·g up, the cable pulls m·g down, and the accelerometer feels (M+m)·g/M − m·g/M = g."""
    sim = _airborne()
    sim.set_attitude_target(quat_from_euler(0, 0, 0), P.hover_thrust_n)
    sim.step(2000)
    f = sim.specific_force_frd_mps2
    np.testing.assert_allclose(f, [0.0, 0.0, -P.g], atol=1e-6)
    assert abs(f[2] + (P.M + P.m) * P.g / P.M) > 1.9  # thrust / M alone would read −11.77 m/s²
    np.testing.assert_allclose(sim.accel_ned_mps2, 0.0, atol=1e-6)


def test_specific_force_is_newtons_law_for_the_airframe_while_swinging():
    """M·f_ned = rotor thrust + disturbance + cable pull, the pull being m·(g·e_z − a_payload) with the
    payload's acceleration from the model's generalized accelerations (an independent route)."""
    sim = _airborne(0.3, -0.2)
    sim.wind = WindConfig("paper", 1.0)
    sim.set_attitude_target(quat_from_euler(0.1, -0.05, 0.2), 1.1 * P.hover_thrust_n)
    for _ in range(5):
        sim.step(37)
        x = sim.x
        u = np.array([sim.thrust_n, *sim.torque_nm])
        qdd = accelerations(x[:8], x[8:], u, sim.disturbance, P)
        al, be, dal, dbe = x[6], x[7], x[14], x[15]
        ca, sa, cb, sb = math.cos(al), math.sin(al), math.cos(be), math.sin(be)
        jac = P.l * np.array([[ca * cb, -sa * sb], [0.0, -cb], [-sa * cb, -ca * sb]])
        jdot_sdot = P.l * np.array([-sa * cb * dal**2 - 2 * ca * sb * dal * dbe - sa * cb * dbe**2, sb * dbe**2,
                                    -ca * cb * (dal**2 + dbe**2) + 2 * sa * sb * dal * dbe])
        a_payload = qdd[:3] + jac @ qdd[6:8] + jdot_sdot
        pull = P.m * (np.array([0.0, 0.0, P.g]) - a_payload)
        forces = sim.thrust_vector_ned_n + sim.disturbance[:3] + pull
        f_ned = rotation_body_to_ned(*x[3:6]) @ sim.specific_force_frd_mps2
        np.testing.assert_allclose(P.M * f_ned, forces, atol=1e-9 * P.hover_thrust_n + 1e-9)
        assert np.linalg.norm(pull[:2]) > 0.01  # the cable does pull sideways here


def test_on_the_ground_it_reads_minus_g():
    sim = VehicleSim(P, WindConfig("none"))
    np.testing.assert_allclose(sim.specific_force_frd_mps2, [0.0, 0.0, -P.g])


def _samples(noise: ImuNoise, n: int) -> tuple[np.ndarray, np.ndarray]:
    imu = ImuModel(noise)
    acc = np.empty((n, 3))
    gyr = np.empty((n, 3))
    for k in range(n):
        acc[k], gyr[k] = imu.sample(k * 4000, np.zeros(3), np.zeros(3))
    return acc, gyr


def test_white_noise_matches_its_density_and_scale():
    dt = 0.004
    nd = ImuNoise(accel_bias_random_walk=0.0, gyro_bias_random_walk=0.0, seed=7, sample_dt_s=dt)
    acc, gyr = _samples(nd, 20_000)
    np.testing.assert_allclose(acc.std(axis=0), nd.accel_noise_density / math.sqrt(dt), rtol=0.03)
    np.testing.assert_allclose(gyr.std(axis=0), nd.gyro_noise_density / math.sqrt(dt), rtol=0.03)
    assert np.all(np.abs(acc.mean(axis=0)) < 4 * nd.accel_noise_density / math.sqrt(dt) / math.sqrt(20_000))
    acc10, _ = _samples(ImuNoise(accel_bias_random_walk=0.0, gyro_bias_random_walk=0.0, seed=7, scale=10.0), 5000)
    np.testing.assert_allclose(acc10, 10.0 * acc[:5000], rtol=1e-12)  # same draws, ten times larger


def test_bias_random_walk_matches_its_density():
    dt = 0.004
    nb = ImuNoise(accel_noise_density=0.0, gyro_noise_density=0.0, seed=3, sample_dt_s=dt)
    acc, gyr = _samples(nb, 20_000)
    np.testing.assert_allclose(np.diff(acc, axis=0).std(axis=0), nb.accel_bias_random_walk * math.sqrt(dt),
                               rtol=0.03)
    np.testing.assert_allclose(np.diff(gyr, axis=0).std(axis=0), nb.gyro_bias_random_walk * math.sqrt(dt),
                               rtol=0.03)


def test_noise_is_seeded_and_repeatable_and_zero_scale_is_ideal():
    a1, g1 = _samples(ImuNoise(seed=11), 500)
    a2, g2 = _samples(ImuNoise(seed=11), 500)
    a3, _ = _samples(ImuNoise(seed=12), 500)
    assert np.array_equal(a1, a2) and np.array_equal(g1, g2) and not np.array_equal(a1, a3)
    a0, g0 = _samples(ImuNoise(scale=0.0), 50)
    assert not a0.any() and not g0.any()
    imu = ImuModel(ImuNoise(seed=1))
    assert imu.sample(8000, np.zeros(3), np.zeros(3)) is imu.sample(8000, np.zeros(3), np.zeros(3))


def test_highres_imu_over_udp_at_hover_and_rates_per_link():
    proc, port, gcs_port = spawn_vehicle("--lockstep", "--wind", "none", "--imu-noise-scale", "0")
    try:
        with MavClient(port) as c, MavClient(gcs_port) as g:
            g.heartbeat()  # a ground station on the GCS link (PX4's normal mode)
            c.heartbeat()
            c.wait_marker(10.0)
            for _ in range(5):
                c.step(thrust=0.0)
            assert c.set_mode(6) == M.MAV_RESULT_ACCEPTED and c.arm() == M.MAV_RESULT_ACCEPTED
            z = vz = 0.0
            imu = []
            c.on_message = lambda m: imu.append(m) if m.get_type() == "HIGHRES_IMU" else None
            for k in range(2500):  # 10 s: climb to 2 m (the payload lifts off at 1 m), then hover
                c.step(thrust=min(0.9, max(0.05, 0.4 + 0.12 * (z + 2.0) + 0.12 * vz)))
                lp = c.last["LOCAL_POSITION_NED"]
                z, vz = lp.z, lp.vz
                if k == 1499:
                    imu.clear()
            assert len(imu) == 50 * 4  # 50 Hz on the onboard link (PX4's onboard mode)
            zacc = np.array([m.zacc for m in imu])
            assert zacc.mean() == pytest.approx(-P.g, abs=0.05)  # not −(M+m)·g/M = −11.77
            assert abs(np.array([m.xacc for m in imu]).mean()) < 0.05
            assert imu[-1].time_usec == c.sim_time_ms * 1000 - (c.sim_time_ms * 1000) % 20_000
            assert imu[-1].fields_updated & 0x3F == 0x3F
            assert imu[-1].pressure_alt == pytest.approx(488.0 + 2.0, abs=0.2)
            # SCALED_IMU only on request (PX4 streams it on USB links only)
            assert c.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_SCALED_IMU) == M.MAV_RESULT_ACCEPTED
            sc = c.wait_for("SCALED_IMU")
            assert sc.zacc == pytest.approx(-P.g / 9.80665 * 1000.0, abs=10)  # milli-g
            seen = [m.get_type() for _ in range(400) for m in g.poll(0.001)]
            assert "HIGHRES_IMU" not in seen and seen.count("HEARTBEAT") >= 10 and "ATTITUDE" in seen
    finally:
        assert stop_vehicle(proc) == 0
