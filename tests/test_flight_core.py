"""FlightCore per-tick glue and the vehicle profiles (thrust newtons -> normalized)."""

import numpy as np
import pytest

from companion.autopilots.profile import VehicleProfile, profile_by_name
from companion.core.mission import Mission
from companion.core.obstacles import Obstacle
from companion.estimation.estimate import Estimate
from companion.flight.core import FlightCore


def _mission(planner="safe", controller="smc_ff"):
    return Mission("t", np.array([0.0, 0.0, -2.0]), np.array([4.0, 0.0, -2.0]), planner, controller, 30.0,
                   obstacles=(Obstacle(2.0, 1.5, 0.3),), hold_s=1.0)


def _est(t, pos, swing=(0.0, 0.0, 0.0, 0.0)):
    return Estimate(t, np.array(pos, float), np.zeros(3), np.zeros(3), np.zeros(3),
                    None if swing is None else np.array(swing, float), "cable_sensor" if swing else "none")


def test_profiles():
    b = profile_by_name("bundled")
    assert b.thrust_to_norm(14.715, 14.715) == pytest.approx(0.4)
    assert b.thrust_to_norm(100.0, 14.715) == 1.0 and b.thrust_to_norm(-1.0, 14.715) == 0.0
    assert profile_by_name("px4").thrust_to_norm(7.0, 14.0) == pytest.approx(0.25)
    assert profile_by_name("px4", 0.6).hover_thrust_norm == 0.6
    with pytest.raises(ValueError, match="profile"):
        profile_by_name("betaflight")
    with pytest.raises(ValueError, match="hover_thrust_norm"):
        VehicleProfile("px4", 1.5).validate()


def test_on_ground_climbs_first_with_hover_ish_thrust():
    core = FlightCore(_mission())
    cmd = core.update(_est(0.0, [0.0, 0.0, 0.0]))
    assert core.phase == "climb" and cmd.phase == "climb"
    for k in range(1, 50):
        cmd = core.update(_est(0.004 * k, [0.0, 0.0, 0.0]))
    assert cmd.ref_vel_ned_mps[2] < 0.0  # reference rises
    assert cmd.thrust_n > core.params.hover_thrust_n  # pushing up
    assert abs(cmd.euler_cmd_rad[0]) < 1e-6 and abs(cmd.euler_cmd_rad[1]) < 1e-6
    assert cmd.thrust_norm == pytest.approx(0.4 * cmd.thrust_n / core.params.hover_thrust_n)


def test_phases_cruise_hold_done():
    core = FlightCore(_mission())
    cmd = core.update(_est(0.0, [0.0, 0.0, -2.0]))
    assert core.phase == "cruise"
    assert cmd.ref_vel_ned_mps[0] >= 0.0
    core.update(_est(0.1, [3.95, 0.0, -2.0]))
    assert core.phase == "cruise"  # within the tolerance, but not yet for the dwell time
    core.update(_est(0.45, [3.97, 0.0, -2.0]))
    assert core.phase == "hold" and core.t_arrived_s == 0.1  # arrived when it first got there
    core.update(_est(0.6, [4.0, 0.0, -2.0]))
    assert core.phase == "hold"
    cmd = core.update(_est(1.2, [4.0, 0.0, -2.0]))
    assert core.phase == "done" and cmd.phase == "done" and not core.timed_out


def test_timeout():
    core = FlightCore(_mission())
    core.update(_est(0.0, [0.0, 0.0, -2.0]))
    core.update(_est(31.0, [0.0, 0.0, -2.0]))
    assert core.phase == "done" and core.timed_out


def test_no_swing_sensor_uses_full_cable_and_no_feedforward():
    core = FlightCore(_mission())
    cmd = core.update(_est(0.0, [0.0, 0.0, -2.0], swing=None))
    assert cmd.envelope_mode == "full_cable" and cmd.r_max_m == pytest.approx(1.0)
    assert np.all(cmd.ff_accel == 0.0)
    core2 = FlightCore(_mission())
    cmd2 = core2.update(_est(0.0, [0.0, 0.0, -2.0], swing=(0.4, 0.0, 1.0, 0.0)))
    assert cmd2.envelope_mode == "swing" and cmd2.r_max_m == pytest.approx(np.sin(0.4))
    assert cmd2.ff_accel[0] > 0.0  # payload out to +x and moving +x: accelerate +x


@pytest.mark.parametrize("planner", ["traditional", "improved", "safe", "none"])
@pytest.mark.parametrize("controller", ["smc_ff", "smc", "pid"])
def test_every_combination_gives_a_finite_unit_quaternion(planner, controller):
    core = FlightCore(_mission(planner, controller))
    for k in range(20):
        cmd = core.update(_est(0.004 * k, [0.5 + 0.01 * k, 0.1, -2.0], swing=(0.05, -0.02, 0.1, 0.1)))
    assert np.isfinite(cmd.thrust_n) and np.linalg.norm(cmd.q_ned_frd_wxyz) == pytest.approx(1.0)
    assert 0.0 <= cmd.thrust_norm <= 1.0


def test_profiles_carry_the_mode_family():
    from companion.autopilots.profile import profile_for_autopilot

    px4 = profile_by_name("px4")
    assert px4.mode_params("offboard") == [1.0, 6.0, 0.0]
    assert px4.mode_params("hold") == [1.0, 4.0, 3.0] and px4.mode_params("land") == [1.0, 4.0, 6.0]
    assert px4.is_offboard(6 << 16) and not px4.is_offboard((4 << 16) | (3 << 24))
    assert profile_by_name("bundled").mode_params("offboard") == px4.mode_params("offboard")
    ap = profile_for_autopilot(3)
    assert ap.name == "ardupilot" and ap.mode_params("offboard") == [1.0, 20.0, 0.0]
    assert ap.is_offboard(20) and not ap.is_offboard(9)
    assert profile_for_autopilot(12, 0.45).name == "px4" and profile_for_autopilot(12, 0.45).hover_thrust_norm == 0.45
    with pytest.raises(ValueError, match="mode"):
        px4.mode_params("acro")


def test_a_payload_on_the_ground_is_lifted_straight_up_before_the_vehicle_moves_sideways():
    """From the ground, a mission starting lower than a cable's length + 0.3 m climbs to that first; from the air,
    or for missions starting higher, the climb ends at the start altitude."""
    from companion.flight.core import LIFT_MARGIN_M, climb_altitude_ned_m

    assert climb_altitude_ned_m(0.0, 0.0, 1.0) == -(1.0 + LIFT_MARGIN_M)  # Group 1: start on the ground
    assert climb_altitude_ned_m(0.0, -2.0, 1.0) == -2.0  # the forest: 2 m is higher anyway
    assert climb_altitude_ned_m(-3.0, -1.0, 1.0) == -1.0  # already flying with the payload up: no detour


def test_arrival_tolerance_follows_the_autopilots_reported_accuracy():
    """0.1 m where the autopilot reports nothing; its 1σ horizontal accuracy where that is coarser."""
    from companion.flight.core import ARRIVE_DWELL_S, FlightCore

    def est(acc):
        return Estimate(t_s=0.0, pos_ned_m=np.zeros(3), vel_ned_mps=np.zeros(3), euler_rad=np.zeros(3),
                        rates_frd_rad_s=np.zeros(3), pos_accuracy_m=acc)

    assert FlightCore.arrival_tolerance_m(est(None)) == 0.1
    assert FlightCore.arrival_tolerance_m(est(0.02)) == 0.1
    assert FlightCore.arrival_tolerance_m(est(0.2)) == pytest.approx(0.2)
    assert ARRIVE_DWELL_S > 0.0


def test_estimate_with_position_keeps_every_other_field():
    """The tick's cheap copy of an estimate at another position equals dataclasses.replace, field for field (a
    field added to Estimate and forgotten in with_position fails here)."""
    from dataclasses import fields, replace

    est = Estimate(1.5, np.array([1.0, 2.0, -3.0]), np.array([0.1, 0.2, 0.3]), np.array([0.01, 0.02, 0.03]),
                   np.array([0.4, 0.5, 0.6]), np.array([0.1, -0.1, 0.2, -0.2]), "estimate", 0.7, 0.33, 0.05)
    for f in fields(Estimate):  # every field differs from its default, so a dropped one shows
        assert f.default is not getattr(est, f.name) or f.name == "pos_ned_m"
    moved = est.with_position(np.array([9.0, 8.0, 7.0]))
    want = replace(est, pos_ned_m=np.array([9.0, 8.0, 7.0]))
    for f in fields(Estimate):
        assert np.array_equal(getattr(moved, f.name), getattr(want, f.name)), f.name


def test_after_setpoint_measures_the_loop_lag_the_next_setpoint_uses():
    """The app sends each setpoint before FlightCore.after_setpoint, which measures the loop lag from this tick's
    attitude and the commands of the ticks before: a vehicle whose attitude is our command of 60 ticks ago reads as
    a lag of 60 ticks (240 ms, within the measurement's 2-tick steps), and the next setpoint fades the feed-forward,
    that lag being far beyond the bundled profile's clean-link 80 ms."""
    core = FlightCore(_mission())
    assert core.lag_trust == 1.0
    delay = 60
    sent: list[np.ndarray] = []
    for k in range(1500):
        att = sent[-delay] if len(sent) >= delay else np.zeros(3)
        e = Estimate(0.004 * k, np.array([0.0, 0.3 * np.sin(0.02 * k), -2.0]), np.zeros(3), att.copy(), np.zeros(3),
                     np.array([0.05, -0.02, 0.1, 0.1]), "cable_sensor")
        cmd = core.setpoint(e)
        core.after_setpoint(e, cmd)
        sent.append(np.array(cmd.euler_cmd_rad))
    assert core.loop_lag.updates > 0
    assert abs(core.loop_lag.lag_s - delay * 0.004) <= 0.008 + 1e-12, core.loop_lag.lag_s
    assert core.lag_trust < 1.0  # the setpoint after the measurement faded the feed-forward


def test_the_first_tick_steps_the_reference_by_the_control_period():
    """Before a second estimate gives a time step, the core steps by its period_s (the jerk-limited climb's first
    acceleration is jerk × dt): not by a fixed 4 ms."""
    acc = {}
    for period in (0.004, 0.02):
        core = FlightCore(_mission(), period_s=period)
        acc[period] = float(core.update(_est(0.0, [0.0, 0.0, 0.0])).ref_acc_ned_mps2[2])
    assert acc[0.004] < 0.0 and acc[0.02] == pytest.approx(5.0 * acc[0.004])

