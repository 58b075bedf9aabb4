"""MAVSDK (pip's ``mavsdk`` 4, the C++ library behind its Python binding) as a ground station uploads a mission and a
geofence to the bundled vehicle over real UDP on loopback and reads them back: ``mission_raw`` for the mission
(take-off, four waypoints, one with a hold, RTL or land), ``geofence`` for an inclusion polygon, an exclusion
polygon and an exclusion circle, read back both with ``mission_raw.download_geofence`` (the raw items) and
``geofence.download_geofence``. The vehicle as in tests/test_mavsdk.py: real time, MAVSDK listening where the
vehicle sends. Each test is bounded (asyncio.wait_for)."""

from __future__ import annotations

import asyncio
import math

import pytest

mavsdk = pytest.importorskip("mavsdk.asyncio", reason="mavsdk (the test extra) is not installed")

from mavsdk.asyncio.plugins.geofence import GeofenceAsync  # noqa: E402
from mavsdk.asyncio.plugins.mission_raw import MissionRawAsync  # noqa: E402
from mavsdk.plugins.geofence import Circle, FenceType, GeofenceData, Point, Polygon  # noqa: E402
from mavsdk.plugins.mission_raw import MissionItem, MissionRawError  # noqa: E402
from mavsdk_drone import Drone  # noqa: E402
from pymavlink.dialects.v20 import common as M  # noqa: E402

pytestmark = [pytest.mark.slow, pytest.mark.paired]  # a real-time vehicle and MAVSDK's server per test

HOME = (47.397742, 8.545594, 488.0)
TEST_BUDGET_S = 60.0
REL, MFRAME = M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_FRAME_MISSION


@pytest.fixture
def drone():
    d = Drone()
    yield d
    d.close()


def _wp(seq: int, cmd: int, lat: float, lon: float, alt_m: float, frame: int = REL, p1: float = 0.0,
        p4: float = math.nan, mission_type: int = M.MAV_MISSION_TYPE_MISSION) -> MissionItem:
    return MissionItem(seq, frame, cmd, int(seq == 0), 1, p1, 0.0, 0.0, p4, round(lat * 1e7), round(lon * 1e7),
                       alt_m, mission_type)


def operator_mission(end: int) -> list[MissionItem]:
    """Take-off to 3 m, four waypoints north-east of home (the second held 2 s), then ``end`` (RTL or land)."""
    pts = [(47.397800, 8.545650), (47.397850, 8.545700), (47.397900, 8.545700), (47.397900, 8.545800)]
    items = [_wp(0, M.MAV_CMD_NAV_TAKEOFF, HOME[0], HOME[1], 3.0)]
    items += [_wp(i + 1, M.MAV_CMD_NAV_WAYPOINT, la, lo, 3.0 + 0.5 * i, p1=2.0 if i == 1 else 0.0)
              for i, (la, lo) in enumerate(pts)]
    if end == M.MAV_CMD_NAV_RETURN_TO_LAUNCH:
        items.append(MissionItem(5, MFRAME, end, 0, 1, 0.0, 0.0, 0.0, 0.0, 0, 0, 0.0, M.MAV_MISSION_TYPE_MISSION))
    else:
        items.append(_wp(5, end, pts[-1][0], pts[-1][1], 0.0))
    return items


def _same(a: MissionItem, b: MissionItem) -> bool:
    fa = (a.seq, a.frame, a.command, a.autocontinue, a.param1, a.param2, a.param3, a.x, a.y, a.z, a.mission_type)
    fb = (b.seq, b.frame, b.command, b.autocontinue, b.param1, b.param2, b.param3, b.x, b.y, b.z, b.mission_type)
    return fa == fb and (a.param4 == b.param4 or (math.isnan(a.param4) and math.isnan(b.param4)))


def test_mission_raw_uploads_downloads_and_clears_a_four_waypoint_mission(drone):
    async def run():
        mission = MissionRawAsync(await drone.connect())
        for end in (M.MAV_CMD_NAV_RETURN_TO_LAUNCH, M.MAV_CMD_NAV_LAND):
            items = operator_mission(end)
            await mission.upload_mission(items)
            got = await mission.download_mission()
            assert len(got) == 6 and all(_same(g, s) for g, s in zip(got, items, strict=True)), got
            assert got[2].param1 == 2.0 and got[-1].command == end
        progress = mission.subscribe_mission_progress()  # MISSION_CURRENT, reported when it changes
        first = asyncio.ensure_future(anext(progress))
        await asyncio.sleep(0.5)
        await mission.set_current_mission_item(3)  # MAV_CMD_DO_SET_MISSION_CURRENT
        p = await first
        assert (p.current, p.total) == (3, 6)
        await progress.aclose()
        await mission.clear_mission()
        assert await mission.download_mission() == []
        bad = operator_mission(M.MAV_CMD_NAV_LAND)
        bad[3].z = math.nan  # refused by the vehicle (MAV_MISSION_INVALID_PARAM7): MAVSDK says so
        with pytest.raises(MissionRawError):
            await mission.upload_mission(bad)

    asyncio.run(asyncio.wait_for(run(), TEST_BUDGET_S))


def test_geofence_with_exclusion_zones_uploads_and_reads_back(drone):
    async def run():
        system = await drone.connect()
        fence, raw = GeofenceAsync(system), MissionRawAsync(system)
        square = [Point(47.3970, 8.5450), Point(47.3970, 8.5465), Point(47.3985, 8.5465), Point(47.3985, 8.5450)]
        hole = [Point(47.39775, 8.54560), Point(47.39775, 8.54570), Point(47.39785, 8.54565)]
        data = GeofenceData([Polygon(square, FenceType.INCLUSION), Polygon(hole, FenceType.EXCLUSION)],
                            [Circle(Point(47.39800, 8.54600), 4.0, FenceType.EXCLUSION)])
        await fence.upload_geofence(data)
        items = await raw.download_geofence()
        assert [i.command for i in items] == [M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION] * 4 + [
            M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION] * 3 + [M.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION]
        assert [i.param1 for i in items] == [4.0] * 4 + [3.0] * 3 + [4.0]
        assert all(i.mission_type == M.MAV_MISSION_TYPE_FENCE for i in items)
        assert (items[0].x, items[0].y) == (473970000, 85450000) and (items[7].x, items[7].y) == (473980000, 85460000)
        back = await fence.download_geofence()
        assert [p.fence_type for p in back.polygons] == [FenceType.INCLUSION, FenceType.EXCLUSION]
        assert [c for q in back.polygons[0].points for c in (q.latitude_deg, q.longitude_deg)] == pytest.approx(
            [c for q in square for c in (q.latitude_deg, q.longitude_deg)], abs=1e-7)
        (c,) = back.circles
        assert (c.radius, c.fence_type) == (pytest.approx(4.0), FenceType.EXCLUSION)
        assert await raw.download_mission() == []  # the mission list is another store
        await fence.clear_geofence()
        assert await raw.download_geofence() == []

    asyncio.run(asyncio.wait_for(run(), TEST_BUDGET_S))
