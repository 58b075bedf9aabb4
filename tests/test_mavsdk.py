"""MAVSDK (pip's ``mavsdk``, the C++ library behind its Python binding) flies the bundled vehicle over real UDP
on loopback, in real time, the way MAVSDK's own examples do (takeoff_and_land.py; the offboard examples of
MAVSDK-Python: offboard_attitude.py, offboard_position_ned.py, offboard_velocity_ned.py,
offboard_position_velocity_ned.py), with shorter pauses. Each test is bounded (asyncio.timeout)."""

from __future__ import annotations

import asyncio
import math

import pytest

mavsdk = pytest.importorskip("mavsdk.asyncio", reason="mavsdk (the test extra) is not installed")

from mavsdk.asyncio.plugins.action import ActionAsync  # noqa: E402
from mavsdk.asyncio.plugins.offboard import OffboardAsync  # noqa: E402
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync  # noqa: E402
from mavsdk.plugins.offboard import Attitude, OffboardError, PositionNedYaw, VelocityNedYaw  # noqa: E402
from mavsdk.plugins.telemetry import FlightMode  # noqa: E402
from mavsdk_drone import Drone  # noqa: E402

pytestmark = [pytest.mark.slow, pytest.mark.paired]  # every test here flies a mission or a peer against the vehicle

HOME = (47.397742, 8.545594, 488.0)
TEST_BUDGET_S = 60.0


@pytest.fixture
def drone():
    d = Drone()
    yield d
    d.close()


async def _wait_ready(tel: TelemetryAsync) -> None:
    async for health in tel.subscribe_health():
        if health.is_global_position_ok and health.is_home_position_ok:
            return


async def _first(gen):
    async for item in gen:
        return item


async def _until(tel_gen, cond, what: str):
    async for item in tel_gen:
        if cond(item):
            return item
    raise AssertionError(what)


def test_discovers_exactly_one_autopilot_and_reads_telemetry(drone):
    async def run():
        system = await drone.connect()
        await asyncio.sleep(1.5)  # the payload (system 2) has announced itself meanwhile
        systems = await drone.mavsdk.get_systems()
        found = {await s.get_system_id(): (await s.has_autopilot(), await s.component_ids()) for s in systems}
        assert found[1] == (True, [1])
        assert found[2] == (False, [35])  # the payload: seen, but not an autopilot
        assert [sid for sid, (ap, _) in found.items() if ap] == [1]
        assert await system.get_system_id() == 1
        tel = TelemetryAsync(system)
        await _wait_ready(tel)
        pos = await _first(tel.subscribe_position())
        assert pos.latitude_deg == pytest.approx(HOME[0], abs=1e-6)
        assert pos.longitude_deg == pytest.approx(HOME[1], abs=1e-6)
        assert pos.relative_altitude_m == pytest.approx(0.0, abs=0.01)
        home = await _first(tel.subscribe_home())
        assert (home.latitude_deg, home.longitude_deg) == pytest.approx(HOME[:2], abs=1e-6)
        assert home.absolute_altitude_m == pytest.approx(HOME[2], abs=0.01)
        att = await _first(tel.subscribe_attitude_euler())
        assert abs(att.roll_deg) < 0.5 and abs(att.pitch_deg) < 0.5
        assert await _first(tel.subscribe_armed()) is False
        assert await _first(tel.subscribe_flight_mode()) == FlightMode.HOLD  # AUTO.LOITER
        health = await _first(tel.subscribe_health())
        assert health.is_armable and health.is_local_position_ok
        assert health.is_gyrometer_calibration_ok and health.is_accelerometer_calibration_ok

    asyncio.run(asyncio.wait_for(run(), TEST_BUDGET_S))


def test_arm_takeoff_and_land(drone):
    async def run():
        system = await drone.connect()
        tel, action = TelemetryAsync(system), ActionAsync(system)
        await _wait_ready(tel)
        await action.arm()
        await action.takeoff()
        pos = await _until(tel.subscribe_position(), lambda p: p.relative_altitude_m > 2.3, "no climb")
        assert pos.relative_altitude_m < 3.0  # MIS_TAKEOFF_ALT 2.5 m
        await asyncio.sleep(2)
        assert await _first(tel.subscribe_flight_mode()) == FlightMode.HOLD  # takeoff done → loiter, as PX4
        assert await _first(tel.subscribe_in_air()) is True
        await action.land()
        await _until(tel.subscribe_armed(), lambda armed: not armed, "not disarmed after landing")
        pos = await _first(tel.subscribe_position())
        assert pos.relative_altitude_m == pytest.approx(0.0, abs=0.05)

    asyncio.run(asyncio.wait_for(run(), TEST_BUDGET_S))


def test_offboard_attitude(drone):
    async def run():
        system = await drone.connect()
        tel, action, offboard = TelemetryAsync(system), ActionAsync(system), OffboardAsync(system)
        await _wait_ready(tel)
        await action.arm()
        await offboard.set_attitude(Attitude(0.0, 0.0, 0.0, 0.0))  # one setpoint, then start (MAVSDK's way)
        await offboard.start()
        assert await _until(tel.subscribe_flight_mode(), lambda m: m == FlightMode.OFFBOARD, "not OFFBOARD")
        await offboard.set_attitude(Attitude(0.0, 0.0, 0.0, 0.7))  # go up at 70 % thrust
        await asyncio.sleep(1.5)
        await offboard.set_attitude(Attitude(30.0, 0.0, 0.0, 0.6))  # roll 30° at 60 % thrust
        att = await _until(tel.subscribe_attitude_euler(), lambda a: abs(a.roll_deg - 30.0) < 2.0, "no roll")
        await asyncio.sleep(1.0)
        await offboard.set_attitude(Attitude(-30.0, 0.0, 0.0, 0.6))
        att = await _until(tel.subscribe_attitude_euler(), lambda a: abs(a.roll_deg + 30.0) < 2.0, "no roll")
        assert abs(att.pitch_deg) < 3.0
        await offboard.set_attitude(Attitude(0.0, 0.0, 0.0, 0.6))
        await asyncio.sleep(1.0)
        pos = await _first(tel.subscribe_position())
        assert pos.relative_altitude_m > 3.0
        await offboard.stop()  # MAVSDK switches to Hold
        assert await _until(tel.subscribe_flight_mode(), lambda m: m == FlightMode.HOLD, "not HOLD")
        assert await _first(tel.subscribe_armed()) is True

    asyncio.run(asyncio.wait_for(run(), TEST_BUDGET_S))


def test_offboard_position_ned(drone):
    async def run():
        system = await drone.connect()
        tel, action, offboard = TelemetryAsync(system), ActionAsync(system), OffboardAsync(system)
        await _wait_ready(tel)
        await action.arm()
        await offboard.set_position_ned(PositionNedYaw(0.0, 0.0, 0.0, 0.0))
        await offboard.start()
        await asyncio.sleep(1.0)
        pv = await _first(tel.subscribe_position_velocity_ned())
        assert pv.position.down_m == pytest.approx(0.0, abs=0.01)  # a setpoint at the ground keeps it there
        await offboard.set_position_ned(PositionNedYaw(0.0, 0.0, -5.0, 0.0))
        await _until(tel.subscribe_position_velocity_ned(), lambda p: abs(p.position.down_m + 5.0) < 0.2,
                     "did not climb to 5 m")
        await offboard.set_position_ned(PositionNedYaw(5.0, 0.0, -5.0, 90.0))  # 5 m north, face east
        pv = await _until(tel.subscribe_position_velocity_ned(),
                          lambda p: abs(p.position.north_m - 5.0) < 0.3 and abs(p.velocity.north_m_s) < 0.2,
                          "did not reach 5 m north")
        assert abs(pv.position.east_m) < 0.3 and abs(pv.position.down_m + 5.0) < 0.3
        att = await _until(tel.subscribe_attitude_euler(), lambda a: abs(a.yaw_deg - 90.0) < 3.0, "no yaw")
        await offboard.set_position_ned(PositionNedYaw(5.0, 5.0, -5.0, 90.0))  # and 5 m east
        await _until(tel.subscribe_position_velocity_ned(),
                     lambda p: abs(p.position.east_m - 5.0) < 0.3 and abs(p.position.north_m - 5.0) < 0.3,
                     "did not reach 5 m east")
        assert abs(att.roll_deg) < 10.0
        await offboard.stop()
        assert await _until(tel.subscribe_flight_mode(), lambda m: m == FlightMode.HOLD, "not HOLD")

    asyncio.run(asyncio.wait_for(run(), TEST_BUDGET_S))


def test_offboard_velocity_ned_and_position_velocity_mix(drone):
    async def run():
        system = await drone.connect()
        tel, action, offboard = TelemetryAsync(system), ActionAsync(system), OffboardAsync(system)
        await _wait_ready(tel)
        await action.arm()
        await offboard.set_velocity_ned(VelocityNedYaw(0.0, 0.0, 0.0, 0.0))
        await offboard.start()
        await offboard.set_velocity_ned(VelocityNedYaw(0.0, 0.0, -2.0, 0.0))  # go up 2 m/s
        pv = await _until(tel.subscribe_position_velocity_ned(), lambda p: p.position.down_m < -4.0, "no climb")
        assert pv.velocity.down_m_s == pytest.approx(-2.0, abs=0.3)
        await offboard.set_velocity_ned(VelocityNedYaw(2.0, 0.0, 0.0, 90.0))  # north 2 m/s, face east
        await asyncio.sleep(3.0)
        pv = await _first(tel.subscribe_position_velocity_ned())
        assert pv.velocity.north_m_s == pytest.approx(2.0, abs=0.3)
        assert abs(pv.velocity.down_m_s) < 0.3 and abs(pv.velocity.east_m_s) < 0.3
        att = await _first(tel.subscribe_attitude_euler())
        assert att.yaw_deg == pytest.approx(90.0, abs=5.0)
        await offboard.set_velocity_ned(VelocityNedYaw(0.0, 0.0, 0.0, 180.0))  # stop, face south
        await _until(tel.subscribe_position_velocity_ned(), lambda p: math.hypot(p.velocity.north_m_s,
                                                                                 p.velocity.east_m_s) < 0.2,
                     "did not stop")
        # position with velocity feed-forward (offboard_position_velocity_ned.py): hold altitude, fly east
        here = (await _first(tel.subscribe_position_velocity_ned())).position
        await offboard.set_position_velocity_ned(PositionNedYaw(here.north_m, 3.0, here.down_m, 180.0),
                                                 VelocityNedYaw(0.0, 1.0, 0.0, 180.0))
        pv = await _until(tel.subscribe_position_velocity_ned(), lambda p: abs(p.position.east_m - 3.0) < 0.3,
                          "did not reach 3 m east")
        assert abs(pv.position.down_m - here.down_m) < 0.3
        await offboard.stop()
        await action.land()
        assert await _until(tel.subscribe_flight_mode(), lambda m: m == FlightMode.LAND, "not LAND")

    asyncio.run(asyncio.wait_for(run(), TEST_BUDGET_S))


def test_offboard_start_without_setpoint_is_refused_by_mavsdk_and_stale_one_by_the_vehicle():
    d = Drone("--offboard-timeout", "1.0")
    try:
        async def run():
            system = await d.connect()
            tel, action, offboard = TelemetryAsync(system), ActionAsync(system), OffboardAsync(system)
            await _wait_ready(tel)
            await action.arm()
            with pytest.raises(OffboardError):  # MAVSDK itself: no setpoint set
                await offboard.start()
            assert await _first(tel.subscribe_flight_mode()) == FlightMode.HOLD

        asyncio.run(asyncio.wait_for(run(), TEST_BUDGET_S))
    finally:
        d.close()
