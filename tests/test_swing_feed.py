"""SwingFeed (pure): ArduPilot's payload fixes are differenced against the vehicle's own position *at the fix's
time*. Real MAVLink frames (packed and parsed by pymavlink), no vehicle."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from companion.core.vehicle_params import VehicleParams
from companion.estimation.swing_feed import SwingFeed
from companion.mavlink_io.telemetry import decode

LAT0, LON0, ALT0 = 47.397742, 8.545594, 488.0
M_PER_DEG_LON = 111_320.0 * math.cos(math.radians(LAT0))


def _gpi(sysid: int, compid: int, t_s: float, east_m: float, alt_m: float):
    """A GLOBAL_POSITION_INT from ``sysid`` as it comes off the wire, decoded."""
    tx = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    msg = mavlink2.MAVLink_global_position_int_message(
        int(t_s * 1e3), int(LAT0 * 1e7), round((LON0 + east_m / M_PER_DEG_LON) * 1e7), int(alt_m * 1e3), 0,
        0, 500, 0, 0)
    rx = mavlink2.MAVLink(None)
    return decode(rx.parse_char(msg.pack(tx)))


def test_a_payload_fix_is_paired_with_the_vehicle_position_at_its_own_time():
    """The vehicle flies east at 5 m/s with the payload hanging 1 m straight below; ArduCopter sends the payload's
    fix 80 ms after the vehicle's. Differenced against the newest vehicle fix it would be 0.4 m off (0.4 rad of
    false swing); paired with the vehicle's position interpolated at its time it is exact."""
    feed = SwingFeed(VehicleParams(), "estimate_fixes")
    state = SimpleNamespace(vehicle_sysid=1, payload_sysid=2)
    feed.ingest(_gpi(1, 1, 10.00, 0.0, ALT0), state)
    feed.ingest(_gpi(2, 35, 10.08, 5.0 * 0.08, ALT0 - 1.0), state)
    assert feed.take_fresh_offsets() == []  # not yet bracketed by a vehicle fix
    feed.ingest(_gpi(1, 1, 10.10, 5.0 * 0.10, ALT0), state)
    (t, off, vel), = feed.take_fresh_offsets()
    assert t == 10.08
    np.testing.assert_allclose(off, [0.0, 0.0, 1.0], atol=0.02)
    np.testing.assert_allclose(vel, [0.0, 5.0, 0.0])
    assert feed.payload_offset is not None and feed.payload_offset[0] == 10.08
    assert feed.take_fresh_offsets() == []


def test_unpaired_payload_fixes_are_dropped_and_counted():
    feed = SwingFeed(VehicleParams(), "estimate_fixes")
    state = SimpleNamespace(vehicle_sysid=1, payload_sysid=2)
    for k in range(20):  # the vehicle's own fixes never come
        feed.ingest(_gpi(2, 35, 1.0 + 0.1 * k, 0.0, ALT0 - 1.0), state)
    assert feed.counts["payload_fix_unpaired"] == 4 and feed.take_fresh_offsets() == []


def _airborne_feed() -> tuple[SwingFeed, SimpleNamespace]:
    """An ``estimate_fixes`` feed whose estimator has started: the vehicle 3 m up, armed, at rest, t = 5 s."""
    feed = SwingFeed(VehicleParams(), "estimate_fixes")
    v0 = np.zeros(3)
    state = SimpleNamespace(vehicle_sysid=1, payload_sysid=2, swing_sensor=None, vel_ned_mps=v0, armed=True,
                            on_ground=False, pos_ned_m=np.array([0.0, 0.0, -3.0]), t_s=5.0,
                            euler_rad=np.zeros(3), rates_frd_rad_s=np.zeros(3))
    feed.maybe_start(state)
    return feed, state


def test_a_diverged_estimator_is_dropped_counted_and_started_again():
    """An estimator whose state went non-finite (numerical divergence on inputs its model cannot explain) gives no
    swing, is counted and logged, and a fresh one starts at the next tick while the vehicle is still airborne."""
    from companion.estimation.estimate import Estimate

    feed, state = _airborne_feed()
    v0 = np.zeros(3)
    assert feed.estimator is not None
    est = Estimate(t_s=5.0, pos_ned_m=state.pos_ned_m, vel_ned_mps=v0, euler_rad=v0, rates_frd_rad_s=v0,
                   swing=None, swing_source="none")
    assert feed.choose(est).swing_source == "estimate"
    first = feed.estimator
    assert first.selected == "full"  # with fixes: the two-model estimator (two_model.py), flying on the full filter
    first.active._base.x[:] = np.nan  # what an overflow leaves behind
    out = feed.choose(est)
    assert out.swing is None and out.swing_source == "none"
    assert feed.counts["estimator_failed"] == 1 and feed.estimator is None and feed.last is None
    feed.maybe_start(state)
    assert feed.estimator is not None and feed.estimator is not first
    assert feed.choose(est).swing_source == "estimate"
    feed.estimator.active._base.x[0] = 3.0  # finite but impossible (ArduCopter SITL's IMU-only estimate reached 1e46)
    assert feed.choose(est).swing is None and feed.counts["estimator_failed"] == 2


def test_each_payload_fix_is_scored_against_the_estimate_of_its_own_time():
    """The report's error_at_fixes: a fix 0.2 m east of straight-below (β ≈ −0.2 rad) against an estimate that
    still says "hanging still" at the fix's time is an error of ≈ 0.2 rad; scored once, at t_fix, not at arrival."""
    from companion.estimation.estimate import Estimate
    from companion.estimation.swing_model import swing_from_offset

    feed, state = _airborne_feed()
    v0 = np.zeros(3)
    for k in range(100):  # the controller's estimates, every 4 ms from 5.0 s
        t = 5.0 + 0.004 * k
        feed.choose(Estimate(t_s=t, pos_ned_m=state.pos_ned_m, vel_ned_mps=v0, euler_rad=v0, rates_frd_rad_s=v0,
                             swing=None, swing_source="none"))
    at_fix = feed.estimator.estimate(5.2).swing[:2]
    feed.ingest(_gpi(1, 1, 5.1, 0.0, ALT0), state)
    feed.ingest(_gpi(2, 35, 5.2, 0.2, ALT0 - 0.98), state)
    assert feed.fix_errors_rad == []  # not paired yet
    feed.ingest(_gpi(1, 1, 5.3, 0.0, ALT0), state)
    (err,) = feed.fix_errors_rad
    a, b = swing_from_offset(feed.payload_offset[1])
    assert b < -0.19
    assert abs(err - math.hypot(at_fix[0] - a, at_fix[1] - b)) < 0.02
    summary = feed.fix_error_summary()
    assert summary["fixes"] == 1 and summary["rms_rad"] == summary["max_rad"] == err
