"""The autopilot's mission and fence as the companion flies them (pure): each frame and command converted to the
mission frame (NED m from home), every refusal naming the item, the fence's items parsed, and the fence geometry the
checks and the planners use (inside/outside, signed distances, straight legs with a margin, exclusion zones as
covering circles)."""

from __future__ import annotations

import math
import random

import numpy as np
import pytest

from companion.core.autopilot_mission import Home, Placement, earth_radii_m, mission_from_items
from companion.core.fence import (
    Fence,
    FenceCircle,
    FencePolygon,
    covering_circles,
    exclusion_obstacles,
    fence_from_items,
    fence_margin_m,
    inside_circle,
    inside_polygon,
    polygon_problem,
    segment_clear,
    zone_margin_m,
)
from companion.core.mission import Mission
from companion.core.obstacles import Obstacle
from companion.mavlink_io.telemetry import MissionItemInt

HOME = Home((1.0, -2.0, -0.5), 47.397742, 8.545594, 488.0)
REL, AMSL, LOCAL, MISSION_FRAME = 6, 5, 1, 2
WP, RTL, LAND, TAKEOFF = 16, 20, 21, 22
BASE = Mission(name="base", start_ned_m=np.array([0.0, 0.0, -2.0]), goal_ned_m=np.array([10.0, 0.0, -2.0]),
               planner="safe", controller="smc_ff", timeout_s=40.0)


def _latlon(n: float, e: float, model: str = "px4") -> tuple[int, int]:
    r_n, r_e = earth_radii_m(model, HOME.lat_deg, HOME.alt_amsl_m)
    lat = HOME.lat_deg + math.degrees(n / r_n)
    lon = HOME.lon_deg + math.degrees(e / (r_e * math.cos(math.radians(HOME.lat_deg))))
    return round(lat * 1e7), round(lon * 1e7)


def _item(seq: int, cmd: int, n: float = 0.0, e: float = 0.0, z: float = 3.0, frame: int = REL,
          params=(0.0, 0.0, 0.0, math.nan), model: str = "px4", mtype: int = 0) -> MissionItemInt:
    if frame == LOCAL:
        x, y = round((n + HOME.pos_ned_m[0]) * 1e4), round((e + HOME.pos_ned_m[1]) * 1e4)
    elif frame == MISSION_FRAME or (n == 0.0 and e == 0.0 and cmd in (TAKEOFF, LAND, RTL)):  # "where it is"
        x = y = 0
    else:
        x, y = _latlon(n, e, model)
    return MissionItemInt(1, 1, 0, seq, frame, cmd, 0, 1, tuple(params), x, y, z, mtype)


def _four_waypoints(frame: int = REL, z: float = 3.0) -> list[MissionItemInt]:
    pts = [(4.0, 1.0, 2.0), (8.0, -1.0, 0.0), (12.0, 2.0, 0.0), (16.0, 0.0, 3.0)]
    return [_item(0, TAKEOFF, z=z, frame=frame)] + [
        _item(k + 1, WP, n, e, z, frame, params=(hold, 0.0, 0.0, math.nan)) for k, (n, e, hold) in enumerate(pts)]


# ------------------------------------------------------------------------------------------------ conversion
def test_global_relative_alt_take_off_four_waypoints_and_land():
    items = [*_four_waypoints(), _item(5, LAND, frame=REL, z=0.0)]
    m, notes = mission_from_items(items, [], HOME, BASE)
    assert np.allclose(m.start_ned_m, [0.0, 0.0, -3.0])
    assert [w.hold_s for w in m.waypoints] == [2.0, 0.0, 0.0]
    got = np.array([w.pos_ned_m for w in m.waypoints] + [m.goal_ned_m])
    assert np.allclose(got, [[4, 1, -3], [8, -1, -3], [12, 2, -3], [16, 0, -3]], atol=0.02)  # 1e-7 deg ≈ 1 cm
    assert m.land and m.hold_s == 1.0 and m.fence is None and m.name == "autopilot"
    assert m.planner == "safe" and m.controller == "smc_ff"  # the rest is the base mission's
    assert [w.name for w in m.waypoints] == ["item 1", "item 2", "item 3"]
    assert m.timeout_s >= 30.0 + 16.0 / 0.5 and notes == []


def test_no_land_holds_where_the_autopilot_s_mission_would_land():
    m, notes = mission_from_items([*_four_waypoints(), _item(5, LAND, z=0.0)], [], HOME, BASE.with_(land=False))
    assert not m.land and any("MAV_CMD_NAV_LAND, but the flight is not to land" in n for n in notes)


def test_global_amsl_altitudes_are_relative_to_home():
    items = [_item(0, TAKEOFF, z=488.0 + 2.5, frame=AMSL), _item(1, WP, 5.0, 0.0, 488.0 + 4.0, AMSL)]
    m, notes = mission_from_items(items, [], HOME, BASE)
    assert m.start_ned_m[2] == pytest.approx(-2.5) and m.goal_ned_m[2] == pytest.approx(-4.0)
    assert not m.land and any("holds at the end" in n for n in notes)


def test_local_ned_items_are_moved_to_the_home_frame():
    items = [_item(0, TAKEOFF, z=HOME.pos_ned_m[2] - 3.0, frame=LOCAL),
             _item(1, WP, 6.0, -3.0, HOME.pos_ned_m[2] - 2.0, LOCAL)]
    m, _ = mission_from_items(items, [], HOME, BASE)
    assert np.allclose(m.start_ned_m, [0.0, 0.0, -3.0]) and np.allclose(m.goal_ned_m, [6.0, -3.0, -2.0])


def test_return_to_launch_flies_back_above_the_start_and_lands():
    items = [*_four_waypoints(), _item(5, RTL, frame=MISSION_FRAME, z=0.0)]
    m, _ = mission_from_items(items, [], HOME, BASE)
    assert np.allclose(m.goal_ned_m, m.start_ned_m) and m.land and len(m.waypoints) == 4


def test_land_at_a_position_flies_there_at_the_previous_altitude():
    items = [*_four_waypoints(), _item(5, LAND, 20.0, 5.0, z=0.0)]
    m, _ = mission_from_items(items, [], HOME, BASE)
    assert np.allclose(m.goal_ned_m, [20.0, 5.0, -3.0], atol=0.02) and m.land and len(m.waypoints) == 4


def test_land_at_the_last_waypoint_s_position_adds_no_leg():
    m, _ = mission_from_items([*_four_waypoints(), _item(5, LAND, 16.2, 0.1, z=0.0)], [], HOME, BASE)
    assert len(m.waypoints) == 3 and np.allclose(m.goal_ned_m, [16.0, 0.0, -3.0], atol=0.02) and m.land


def test_without_take_off_the_first_waypoint_gives_the_start_altitude():
    m, notes = mission_from_items([_item(0, WP, 5.0, 0.0, 4.0)], [], HOME, BASE)
    assert m.start_ned_m[2] == pytest.approx(-4.0) and any("no MAV_CMD_NAV_TAKEOFF" in n for n in notes)


def test_ardupilot_item_zero_is_home_and_not_flown():
    home_item = _item(0, WP, 0.0, 0.0, 488.0, AMSL)
    items = [home_item, *_four_waypoints()]  # (seq as sent: 0 is home, 1 the take-off, ...; not checked here)
    m, notes = mission_from_items(items, [], HOME, BASE, earth_model="ardupilot", skip_home_item=True)
    assert any("item 0 is the autopilot's home" in n for n in notes) and len(m.waypoints) == 3


def test_a_leading_waypoint_on_the_ground_at_home_is_a_wpl_home_line_and_not_flown():
    items = [_item(0, WP, 0.3, -0.2, 488.0, AMSL), *_four_waypoints()]
    m, notes = mission_from_items(items, [], HOME, BASE)
    assert len(m.waypoints) == 3 and any("WPL file's home line" in n for n in notes)
    low = [*_four_waypoints()[:1], _item(1, WP, 0.3, -0.2, 0.0)]  # not first: a waypoint on the ground, refused
    with pytest.raises(ValueError, match=r"item 1: altitude 0\.00 m above home is at or below the ground"):
        mission_from_items(low, [], HOME, BASE)


def test_each_autopilot_family_places_a_point_with_its_own_earth():
    it = [_item(0, WP, 1000.0, 1000.0, 3.0, model="px4")]
    px4, _ = mission_from_items(it, [], HOME, BASE, earth_model="px4")
    ap, _ = mission_from_items(it, [], HOME, BASE, earth_model="ardupilot")
    assert np.allclose(px4.goal_ned_m[:2], [1000.0, 1000.0], atol=0.02)
    assert ap.goal_ned_m[0] / px4.goal_ned_m[0] == pytest.approx(6378100.0 / 6371000.0, rel=1e-6)


# ------------------------------------------------------------------------------------------------ refusals
@pytest.mark.parametrize("items, message", [
    (lambda: [*_four_waypoints()[:3], _item(3, 183, params=(1, 1500, 0, 0))],
     "item 3: MAV_CMD_DO_SET_SERVO (183) is not supported; supported: MAV_CMD_NAV_WAYPOINT (16)"),
    (lambda: [*_four_waypoints()[:2], _item(2, WP, 3.0, 0.0, math.nan)], "item 2: a coordinate is not a number"),
    (lambda: [*_four_waypoints()[:1], _item(1, WP, 3.0, 0.0, -1.0)], "item 1: altitude -1.00 m above home is at"),
    (lambda: [*_four_waypoints()[:1], _item(1, WP, 3.0, 0.0, 0.0, frame=AMSL)], "item 1: altitude -488.00 m"),
    (lambda: [], "no items (upload a mission"),
    (lambda: _four_waypoints()[:1], "no waypoint to fly to"),
    (lambda: [*_four_waypoints()[:1], _item(1, WP, 3.0, 0.0, 3.0, frame=10)],
     "item 1: frame 10 (10) is not supported; supported: MAV_FRAME_GLOBAL (0)"),
    (lambda: [*_four_waypoints()[:2], _item(2, LAND, z=0.0), _item(3, WP, 1.0, 1.0)],
     "item 3: MAV_CMD_NAV_WAYPOINT after MAV_CMD_NAV_LAND (item 2): nothing after the landing is flown"),
    (lambda: [*_four_waypoints()[1:2], _item(2, TAKEOFF)], "item 2: MAV_CMD_NAV_TAKEOFF must be the first item"),
    (lambda: [_item(0, WP, 12_000.0, 0.0)], "item 0: 12.0 km from home, beyond 10 km"),
    (lambda: [_item(0, WP, 3.0, 0.0, params=(math.nan, 0, 0, 0))], "item 0: MAV_CMD_NAV_WAYPOINT hold time"),
])
def test_what_cannot_be_flown_is_refused_naming_the_item(items, message):
    with pytest.raises(ValueError) as e:
        mission_from_items(items(), [], HOME, BASE)
    assert message in str(e.value)


def test_a_waypoint_inside_an_obstacle_ring_is_refused_naming_it():
    base = BASE.with_(obstacles=(Obstacle(8.0, -1.0, 0.3),))
    with pytest.raises(ValueError, match=r"item 2 \(\d.\d\d, -1.00\) m is 0.0\d m from obstacle 0"):
        mission_from_items(_four_waypoints(), [], HOME, base)


# ------------------------------------------------------------------------------------------------ fence items
def _fence_items(start_seq: int = 0) -> list[MissionItemInt]:
    square = [(-5.0, -5.0), (25.0, -5.0), (25.0, 5.0), (-5.0, 5.0)]
    out = [_item(start_seq + k, 5001, n, e, 0.0, REL, params=(4, 0, 0, 0), mtype=1) for k, (n, e) in
           enumerate(square)]
    out.append(_item(start_seq + 4, 5004, 10.0, 3.0, 0.0, REL, params=(1.0, 0, 0, 0), mtype=1))
    out.append(_item(start_seq + 5, 5000, 0.0, 0.0, 0.0, REL, mtype=1))
    return out


def test_fence_items_become_polygons_and_circles_and_the_return_point_is_noted():
    place = Placement(HOME)
    fence, notes = fence_from_items(_fence_items(), place.ne)
    assert len(fence.polygons) == 1 and fence.polygons[0].inclusion
    assert np.allclose(fence.polygons[0].vertices_ne_m, [(-5, -5), (25, -5), (25, 5), (-5, 5)], atol=0.02)
    (c,) = fence.circles
    assert not c.inclusion and c.radius_m == 1.0 and np.allclose(c.center_ne_m, (10.0, 3.0), atol=0.02)
    assert notes and "return point is ignored" in notes[0]


@pytest.mark.parametrize("mutate, message", [
    (lambda its: its[:2] + its[4:], "fence item 0: MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION: a polygon of 4"),
    (lambda its: [_item(0, 5002, 0, 0, 0, params=(2, 0, 0, 0), mtype=1)] * 2, "at least 3 vertices, param1 says 2"),
    (lambda its: [its[0], its[2], its[1], its[3]], "self-intersecting (edge 0 crosses edge 2)"),
    (lambda its: [*its[:4], _item(4, 5004, 1, 1, 0, params=(math.nan, 0, 0, 0), mtype=1)],
     "fence item 4: MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION: centre or radius is not a finite number"),
    (lambda its: [*its[:4], _item(4, 16, 1, 1, mtype=1)], "fence item 4: command 16 is not a fence item"),
    (lambda its: [*its[:3], _item(3, 5001, 1, 1, math.nan, params=(4, 0, 0, 0), mtype=1)],
     "item 3: a coordinate is not a number"),
])
def test_bad_fence_items_are_refused_naming_the_item(mutate, message):
    with pytest.raises(ValueError) as e:
        fence_from_items(mutate(_fence_items()), Placement(HOME).ne)
    assert message in str(e.value)


def test_the_mission_carries_the_fence_and_refuses_points_outside_it():
    m, _ = mission_from_items(_four_waypoints()[:3], _fence_items(), HOME, BASE)
    assert m.fence is not None and len(m.fence.polygons) == 1 and len(m.fence.circles) == 1
    far = [*_four_waypoints()[:2], _item(2, WP, 30.0, 0.0)]
    with pytest.raises(ValueError, match=r"item 2 \(30.0\d, 0.0\d\) m is outside the fence's inclusion polygon 0"):
        mission_from_items(far, _fence_items(), HOME, BASE)
    into = [*_four_waypoints()[:2], _item(2, WP, 10.0, 3.2)]
    with pytest.raises(ValueError, match=r"item 2 .* is inside the fence's exclusion circle 0"):
        mission_from_items(into, _fence_items(), HOME, BASE)


def test_a_straight_leg_through_an_exclusion_zone_is_noted_not_refused():
    fence = [_item(0, 5004, 6.0, 0.0, 0.0, params=(0.5, 0, 0, 0), mtype=1)]  # on the leg item 1 -> item 2
    m, notes = mission_from_items(_four_waypoints(), fence, HOME, BASE)
    assert m.fence is not None and len(m.waypoints) == 3
    assert [n for n in notes if "straight leg" in n] == [
        "the straight leg from item 1 to item 2 would come within 0.28 m of the fence's boundary (or cross it): "
        "the planner must route around it"]


def test_a_fence_that_excludes_the_start_is_refused_naming_the_start():
    circle = [_item(0, 5004, 0.0, 0.0, 0.0, params=(2.0, 0, 0, 0), mtype=1)]
    with pytest.raises(ValueError, match=r"the start \(home at take-off altitude\) \(0.00, 0.00\) m is inside"):
        mission_from_items(_four_waypoints(), circle, HOME, BASE)


# ------------------------------------------------------------------------------------------------ geometry
SQUARE = FencePolygon(((0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (0.0, 10.0)), inclusion=True)
U_SHAPE = FencePolygon(((0, 0), (10, 0), (10, 10), (7, 10), (7, 3), (3, 3), (3, 10), (0, 10)), inclusion=True)


def test_inside_and_signed_distance_to_the_boundary():
    assert inside_polygon(SQUARE, (5.0, 5.0)) and not inside_polygon(SQUARE, (11.0, 5.0))
    assert zone_margin_m(SQUARE, (2.0, 5.0)) == pytest.approx(2.0)
    assert zone_margin_m(SQUARE, (13.0, 14.0)) == pytest.approx(-5.0)
    out = FencePolygon(SQUARE.vertices_ne_m, inclusion=False)
    assert zone_margin_m(out, (2.0, 5.0)) == pytest.approx(-2.0) and zone_margin_m(out, (-3.0, 5.0)) == 3.0
    c = FenceCircle((0.0, 0.0), 2.0, inclusion=False)
    assert inside_circle(c, (1.0, 1.0)) and zone_margin_m(c, (3.0, 4.0)) == pytest.approx(3.0)
    assert zone_margin_m(FenceCircle((0.0, 0.0), 2.0, True), (0.5, 0.0)) == pytest.approx(1.5)
    assert fence_margin_m(Fence((SQUARE,), (FenceCircle((5.0, 5.0), 1.0, False),)), (5.0, 7.0)) == pytest.approx(1.0)
    assert fence_margin_m(Fence(), (0.0, 0.0)) == math.inf


def test_segment_clear_keeps_the_margin_inside_inclusions_and_away_from_exclusions():
    f = Fence((SQUARE,))
    assert segment_clear(f, (1.0, 1.0), (9.0, 9.0), margin_m=0.5)
    assert not segment_clear(f, (1.0, 1.0), (9.0, 9.0), margin_m=1.5)  # the ends are nearer than that
    u = Fence((U_SHAPE,))
    assert not segment_clear(u, (1.5, 8.0), (8.5, 8.0))  # both ends inside, the leg crosses the notch
    assert segment_clear(u, (1.5, 1.5), (8.5, 1.5), margin_m=1.0)
    assert not segment_clear(u, (1.5, 1.5), (8.5, 1.5), margin_m=1.6)  # passes 1.5 m from the notch's bottom
    keep_out = Fence(circles=(FenceCircle((5.0, 0.0), 1.0, False),))
    assert not segment_clear(keep_out, (0.0, 0.0), (10.0, 0.0))
    assert segment_clear(keep_out, (0.0, 1.6), (10.0, 1.6), margin_m=0.5)
    assert not segment_clear(keep_out, (0.0, 1.4), (10.0, 1.4), margin_m=0.5)
    stay_in = Fence(circles=(FenceCircle((0.0, 0.0), 5.0, True),))
    assert segment_clear(stay_in, (-3.0, 0.0), (3.0, 0.0), 1.0) and not segment_clear(stay_in, (-3, 0), (4.5, 0), 1.0)


@pytest.mark.parametrize("poly, problem", [
    (FencePolygon(((0, 0), (1, 1)), True), "2 vertices (at least 3 needed)"),
    (FencePolygon(((0, 0), (1, 1), (2, 2)), True), "no area"),
    (FencePolygon(((0, 0), (2, 2), (2, 0), (0, 2)), True), "self-intersecting"),
    (FencePolygon(((0, 0), (math.nan, 1), (2, 0)), True), "not a finite number"),
    (SQUARE, None), (U_SHAPE, None),
])
def test_unusable_polygons_are_named(poly, problem):
    got = polygon_problem(poly)
    assert (got is None) if problem is None else (problem in got)


@pytest.mark.parametrize("zone", [U_SHAPE, FencePolygon(((0, 0), (40, 3), (10, 60)), False),
                                  FenceCircle((3.0, 4.0), 80.0, False)])
def test_covering_circles_contain_the_zone(zone):
    circles = covering_circles(zone)
    assert 0 < len(circles) <= 400
    rng = random.Random(27)
    if isinstance(zone, FenceCircle):
        pts = [(zone.center_ne_m[0] + zone.radius_m * math.sqrt(rng.random()) * math.cos(a),
                zone.center_ne_m[1] + zone.radius_m * math.sqrt(rng.random()) * math.sin(a))
               for a in (rng.uniform(0, 2 * math.pi) for _ in range(3000))]
        pts += [(zone.center_ne_m[0] + zone.radius_m * math.cos(a), zone.center_ne_m[1] + zone.radius_m * math.sin(a))
                for a in np.linspace(0, 2 * math.pi, 500)]
    else:
        ns = [v[0] for v in zone.vertices_ne_m]
        es = [v[1] for v in zone.vertices_ne_m]
        pts = [p for p in ((rng.uniform(min(ns), max(ns)), rng.uniform(min(es), max(es))) for _ in range(5000))
               if inside_polygon(zone, p)] + list(zone.vertices_ne_m)
    for p in pts:
        assert any(math.hypot(p[0] - n, p[1] - e) <= r + 1e-9 for n, e, r in circles), p


def test_exclusion_zones_become_fence_obstacles_and_inclusion_zones_do_not():
    f = Fence((SQUARE,), (FenceCircle((20.0, 0.0), 1.5, False),))
    (o,) = exclusion_obstacles(f)
    assert (o.x_m, o.y_m, o.radius_m, o.source) == (20.0, 0.0, 1.5, "fence") and o.height_m == Obstacle.MAX_HEIGHT_M
    o.validate()
