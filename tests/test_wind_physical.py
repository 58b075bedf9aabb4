"""Physical wind (issue 28): Dryden turbulence against its specification, the drag forces, their generalised
forces in the 8-DOF model, determinism, and the wall that keeps the wind out of the companion."""

from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np
import pytest

from companion.core.model import accelerations
from companion.core.turbulence import (
    FT_M,
    KNOT_MPS,
    TABLE_DT_S,
    DrydenParams,
    DrydenSampler,
    WindField,
    dryden_low_altitude,
    gust_speed,
)
from companion.core.vehicle_params import VehicleParams
from companion.core.wind import WindConfig, drag_force, generalized_drag
from sim_bridge.physics import VehicleSim
from sim_bridge.wind_drag import _drag_disturbance

ROOT = Path(__file__).resolve().parents[1]
P = VehicleParams()


def _samples(seed: int = 3, chunks: int = 100) -> tuple[DrydenParams, float, np.ndarray]:
    p = DrydenParams(1.5, 1.5, 0.8, 5.0, 5.0, 3.0)
    s = DrydenSampler(p, 5.0, seed)
    return p, 5.0, np.concatenate([s.chunk() for _ in range(chunks)])


def _autocorr(x: np.ndarray, lag: int) -> float:
    return float(np.mean(x[:-lag] * x[lag:])) if lag else float(np.mean(x * x))


def test_low_altitude_sigma_and_scales_follow_mil_f_8785c():
    # at h = 10 ft (the model's floor; 3 m is below it): k = 0.177 + 0.00823 = 0.18523
    d = dryden_low_altitude(15.0 * KNOT_MPS, 3.0)
    k = 0.177 + 0.000823 * 10.0
    assert d.sigma_w == pytest.approx(0.1 * 15.0 * KNOT_MPS)
    assert d.sigma_u == pytest.approx(d.sigma_w / k**0.4) == pytest.approx(1.516, abs=2e-3)
    assert d.L_w == pytest.approx(10.0 * FT_M)
    assert d.L_u == d.L_v == pytest.approx(10.0 / k**1.2 * FT_M) == pytest.approx(23.05, abs=0.01)
    hi = dryden_low_altitude(15.0 * KNOT_MPS, 100.0 * FT_M)  # 100 ft: longer scales, σ_u closer to σ_w
    assert hi.L_u > d.L_u and hi.L_w == pytest.approx(100.0 * FT_M) and hi.sigma_u < d.sigma_u


def test_long_sample_has_the_spec_sigma_and_autocorrelation():
    p, v, x = _samples()
    tu, tv, tw = p.L_u / v, p.L_v / v, p.L_w / v
    for i, (sig, tau, kind) in enumerate(((p.sigma_u, tu, "u"), (p.sigma_v, tv, "v"), (p.sigma_w, tw, "v"))):
        assert np.std(x[:, i]) == pytest.approx(sig, rel=0.05)
        for lag_s in (0.25 * tau, tau, 2.0 * tau):
            lag = round(lag_s / TABLE_DT_S)
            t = lag * TABLE_DT_S
            want = sig**2 * math.exp(-t / tau) * (1.0 if kind == "u" else 1.0 - t / (2.0 * tau))
            assert _autocorr(x[:, i], lag) == pytest.approx(want, abs=0.06 * sig**2), (i, lag_s)
    # the lateral spectrum's zero crossing: R_v(2T) = 0 (the first-order u stays positive there)
    lag = round(2.0 * tv / TABLE_DT_S)
    assert abs(_autocorr(x[:, 1], lag)) < 0.06 * p.sigma_v**2 < _autocorr(x[:, 0], lag)


def test_same_seed_same_bits_other_seed_other_wind():
    cfg = WindConfig("turbulence", mean_speed_mps=3.0, intensity="light", seed=7, gust_amplitude_mps=2.0)
    a, b = WindField(cfg), WindField(cfg)
    a.velocity(25.0)  # looking far ahead first must not change the bits
    for t in (0.0, 3.21, 12.5, 24.99):
        assert np.array_equal(a.velocity(t), b.velocity(t))
    c = WindField(WindConfig("turbulence", mean_speed_mps=3.0, intensity="light", seed=8))
    assert not np.array_equal(a.velocity(5.0), c.velocity(5.0))


def test_mean_wind_blows_from_direction_deg_and_gust_is_one_minus_cosine():
    calm = WindField(WindConfig("turbulence", mean_speed_mps=4.0, direction_deg=270.0))  # a westerly: air moves east
    assert calm.velocity(1.0) == pytest.approx([0.0, 4.0, 0.0], abs=1e-12)
    north = WindField(WindConfig("turbulence", mean_speed_mps=4.0, direction_deg=0.0))
    assert north.velocity(1.0) == pytest.approx([-4.0, 0.0, 0.0], abs=1e-12)
    assert gust_speed(0.9, 3.0, 10.0, 1.0, 5.0) == 0.0
    assert gust_speed(2.0, 3.0, 10.0, 1.0, 5.0) == pytest.approx(1.5)  # half way up (x = d/2)
    assert gust_speed(9.0, 3.0, 10.0, 1.0, 5.0) == pytest.approx(3.0)
    g = WindField(WindConfig("turbulence", mean_speed_mps=5.0, direction_deg=180.0, gust_amplitude_mps=3.0,
                             gust_length_m=10.0, gust_start_s=1.0))
    assert g.velocity(2.0) == pytest.approx([6.5, 0.0, 0.0], abs=1e-9)


def test_drag_force_sign_magnitude_and_zero_in_still_air():
    k = WindConfig("turbulence").drag_coefficients()
    assert k[0] == pytest.approx(0.5 * 1.225 * 0.04) and k[1] == pytest.approx(0.5 * 1.225 * 0.01)
    f = drag_force(k[0], [0.0, 5.0, 0.0], np.zeros(3))
    assert f == pytest.approx([0.0, k[0] * 25.0, 0.0])  # pushed downwind, ½ρC_dA·v²
    assert drag_force(k[0], np.zeros(3), [2.0, 0.0, 0.0])[0] == pytest.approx(-k[0] * 4.0)  # opposes motion
    assert np.all(drag_force(k[0], [1.0, 2.0, 0.5], [1.0, 2.0, 0.5]) == 0.0)
    sim = VehicleSim(P, wind=WindConfig("turbulence"), x0=np.r_[0, 0, -3.0, np.zeros(13)])
    sim.armed = True
    sim.set_euler_target(np.zeros(3), P.hover_thrust_n)
    sim.step(50)
    assert np.all(sim.disturbance == 0.0)  # calm, at rest: no force at all


def _positions(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    al, be = q[6], q[7]
    r = P.l * np.array([math.sin(al) * math.cos(be), -math.sin(be), math.cos(al) * math.cos(be)])
    return q[:3].copy(), q[:3] + r


def test_generalised_forces_equal_finite_difference_virtual_work():
    rng = np.random.default_rng(1)
    for _ in range(20):
        q = rng.uniform(-0.6, 0.6, 8)
        fa, fp = rng.normal(size=3), rng.normal(size=3)
        want = np.zeros(8)
        for j in range(8):
            h = 1e-6
            dq = np.zeros(8)
            dq[j] = h
            a1, p1 = _positions(q + dq)
            a0, p0 = _positions(q - dq)
            want[j] = fa @ (a1 - a0) / (2 * h) + fp @ (p1 - p0) / (2 * h)  # δW = Σ F·δp
        got = generalized_drag(q[6], q[7], P.l, fa, fp)
        assert got == pytest.approx(want, abs=1e-7)
        assert np.all(got[3:6] == 0.0)  # no torque: neither point moves with the attitude


def test_compiled_drag_equals_the_pure_mapping():
    rng = np.random.default_rng(2)
    k = np.array([0.03, 0.008])
    tab = rng.normal(size=(10, 3)) * 3.0
    for _ in range(10):
        x = rng.uniform(-0.5, 0.5, 16)
        t = rng.uniform(0.0, 0.08)
        d = np.empty(8)
        _drag_disturbance(x, t, tab, TABLE_DT_S, k, P.l, False, False, d)
        i = int(t / TABLE_DT_S)
        f = t / TABLE_DT_S - i
        w = (1 - f) * tab[i] + f * tab[i + 1]
        al, be, dal, dbe = x[6], x[7], x[14], x[15]
        jac = P.l * np.array([[math.cos(al) * math.cos(be), -math.sin(al) * math.sin(be)], [0.0, -math.cos(be)],
                              [-math.sin(al) * math.cos(be), -math.cos(al) * math.sin(be)]])
        vp = x[8:11] + jac @ np.array([dal, dbe])
        want = generalized_drag(al, be, P.l, drag_force(k[0], w, x[8:11]), drag_force(k[1], w, vp))
        assert d == pytest.approx(want, rel=1e-12, abs=1e-14)


def test_payload_drag_swings_the_payload_airframe_drag_turns_nothing():
    q, qd, u = np.zeros(8), np.zeros(8), np.array([P.hover_thrust_n, 0.0, 0.0, 0.0])
    on_payload = accelerations(q, qd, u, generalized_drag(0.0, 0.0, P.l, np.zeros(3), [0.5, 0.0, 0.0]), P)
    assert on_payload[6] > 0.1  # pushed north, the payload swings north (α > 0)
    on_airframe = accelerations(q, qd, u, generalized_drag(0.0, 0.0, P.l, [0.5, 0.0, 0.0], np.zeros(3)), P)
    assert np.all(on_airframe[3:6] == 0.0)  # through the centre of mass: no angular acceleration
    assert on_airframe[0] > 0.0 and on_airframe[6] < 0.0  # the airframe goes, the payload lags behind
    # the same total force on the payload alone swings it more than on the airframe (it acts below the pivot)
    assert abs(on_payload[6]) > abs(on_airframe[6])


def test_wind_field_drives_the_bundled_physics_deterministically():
    cfg = WindConfig("turbulence", mean_speed_mps=6.0, direction_deg=270.0, intensity="moderate", seed=4)
    ends = []
    for _ in range(2):
        sim = VehicleSim(P, wind=cfg, x0=np.r_[0, 0, -3.0, np.zeros(13)])
        sim.armed = True
        sim.set_euler_target(np.zeros(3), P.hover_thrust_n)
        sim.step(1500)
        ends.append(sim.x.copy())
    assert np.array_equal(ends[0], ends[1])
    assert ends[0][1] > 0.3  # blown east by the westerly (level attitude held, no position control)


#: the companion's deciding parts: none of them may know the simulated wind
DECIDING = ("companion/flight", "companion/planning", "companion/control", "companion/estimation")


def test_the_companion_is_never_told_the_wind():
    for pkg in DECIDING:
        for f in (ROOT / pkg).rglob("*.py"):
            tree = ast.parse(f.read_text(), str(f))
            for node in ast.walk(tree):
                if isinstance(node, ast.ImportFrom):
                    assert node.module not in ("companion.core.wind", "companion.core.turbulence"), f
                if isinstance(node, ast.Import):
                    assert not any(a.name.startswith(("companion.core.wind", "companion.core.turbulence"))
                                   for a in node.names), f
                if isinstance(node, ast.Attribute):
                    assert node.attr != "wind", f"{f}:{node.lineno} reads .wind"


def test_mission_file_round_trip_keeps_the_whole_wind_table(tmp_path):
    from companion.core.mission import load_mission, mission_to_toml

    base = load_mission(ROOT / "config" / "missions" / "forest.toml")
    wind = WindConfig("turbulence", mean_speed_mps=6.0, direction_deg=90.0, intensity="moderate", seed=12,
                      gust_amplitude_mps=2.5, payload_drag_area_m2=0.02)
    f = tmp_path / "m.toml"
    f.write_text(mission_to_toml(base.with_(wind=wind)))
    assert load_mission(f).wind == wind
    f.write_text(mission_to_toml(base))
    assert load_mission(f).wind == base.wind and "intensity" not in f.read_text()  # eq. 49 files as before


def test_evaluate_wind_options_name_the_wind_and_seed_it_per_forest():
    import argparse

    from companion.errors import ConfigError
    from lab.evaluate import add_evaluate_arguments
    from lab.forests import ForestSpec, generate_forest
    from lab.wind_options import wind_from_args, with_wind

    p = argparse.ArgumentParser()
    add_evaluate_arguments(p)
    assert wind_from_args(p.parse_args([])) is None
    assert wind_from_args(p.parse_args(["--wind", "calm"])) == WindConfig("none", 0.0)
    assert wind_from_args(p.parse_args(["--wind", "paper", "--wind-scale", "2"])) == WindConfig("paper", 2.0)
    w = wind_from_args(p.parse_args(["--wind", "moderate"]))
    assert (w.model, w.intensity, w.mean_speed_mps, w.direction_deg) == ("turbulence", "moderate", 6.0, 90.0)
    assert wind_from_args(p.parse_args(["--wind", "light", "--wind-mean-mps", "4"])).mean_speed_mps == 4.0
    with pytest.raises(ConfigError, match="--wind-mean-mps"):
        wind_from_args(p.parse_args(["--wind-mean-mps", "4"]))
    with pytest.raises(ConfigError, match="mean_speed_mps"):
        wind_from_args(p.parse_args(["--wind", "severe", "--wind-mean-mps", "99"]))
    m = generate_forest(5, ForestSpec())
    assert with_wind(m, w, 5).wind.seed == 5 and with_wind(m, w, 6).wind.seed == 6 and with_wind(m, None, 5) is m


def test_inprocess_flies_the_true_payload_and_the_wind_without_telling_the_core():
    from companion.core.mission import load_mission
    from lab.inprocess import fly_inprocess

    m = load_mission(ROOT / "config" / "missions" / "forest.toml")
    m = m.with_(wind=WindConfig("turbulence", mean_speed_mps=3.0, direction_deg=90.0, intensity="light", seed=2),
                timeout_s=8.0, hold_s=0.5)
    heavy = VehicleParams(m=0.35)  # 40 % heavier than the 0.25 kg the core is told
    a = fly_inprocess(m, true_vehicle=heavy)
    b = fly_inprocess(m, true_vehicle=heavy)
    assert np.array_equal(a.arr("pos"), b.arr("pos"))  # seeded turbulence: the same flight twice
    c = fly_inprocess(m)  # the declared payload: another flight
    assert not np.array_equal(a.arr("pos"), c.arr("pos"))
