"""End to end: a ground station uploads a mission and a fence to the bundled vehicle, the companion downloads and
flies them (``fly --mission autopilot``, lockstep).

The ground station is a plain pymavlink client on the vehicle's GCS port (its mission protocol: MISSION_COUNT,
MISSION_REQUEST_INT → MISSION_ITEM_INT, MISSION_ACK), as QGroundControl or MAVSDK's mission_raw would talk to it:
a take-off, four waypoints through the paper's forest (one with a hold) and a landing, in
MAV_FRAME_GLOBAL_RELATIVE_ALT_INT about the vehicle's own home; a fence with an inclusion polygon and an exclusion
circle. The companion flies the route with the forest mission's planner and obstacles and never leaves the fence."""

from __future__ import annotations

import asyncio
import math

import numpy as np
import pytest
from _operator_helpers import (
    DEFAULT_HOME,
    FENCE_SQUARE,
    KEEP_OUT,
    ROUTE,
    MissionGcs,
    fence_margins_m,
    mavsdk_upload,
    route_fence,
)
from pymavlink.dialects.v20 import common as M

from companion.autopilots.profile import profile_by_name
from companion.config import shipped_missions
from companion.core.autopilot_mission import earth_radii_m
from companion.core.mission import load_mission
from companion.flight.setup import FlightSetup
from companion.launch.fly import fly_mission
from companion.launch.sitl import SitlProcess
from companion.launch.spec import FlySpec

pytestmark = [pytest.mark.slow, pytest.mark.shares_cores]



def _items(home: tuple[float, float, float], keep_out: tuple[float, float, float] = KEEP_OUT
           ) -> tuple[list[tuple], list[tuple]]:
    """The mission and fence items about ``home`` (the bundled vehicle's earth: WGS-84's local radii), the fence's
    exclusion circle at ``keep_out`` (north m, east m, radius m)."""
    r_n, r_e = earth_radii_m("wgs84", home[0], home[2])

    def ll(n: float, e: float) -> tuple[int, int]:
        return (round((home[0] + math.degrees(n / r_n)) * 1e7),
                round((home[1] + math.degrees(e / (r_e * math.cos(math.radians(home[0]))))) * 1e7))

    rel = M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    mission = [(rel, M.MAV_CMD_NAV_TAKEOFF, (0, 0, 0, math.nan), 0, 0, 2.0)]
    mission += [(rel, M.MAV_CMD_NAV_WAYPOINT, (hold, 0, 0, math.nan), *ll(n, e), alt) for n, e, alt, hold in ROUTE]
    mission.append((rel, M.MAV_CMD_NAV_LAND, (0, 0, 0, math.nan), 0, 0, 0.0))
    fence = [(rel, M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, (4, 0, 0, 0), *ll(n, e), 0.0) for n, e in FENCE_SQUARE]
    fence.append((rel, M.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, (keep_out[2], 0, 0, 0), *ll(*keep_out[:2]), 0.0))
    return mission, fence


async def _fly(tmp_path, keep_out_home: bool = False):
    """Upload (``keep_out_home``: a fence whose exclusion circle covers home) and fly; the FlyResult."""
    base = load_mission(shipped_missions()["forest"])
    async with SitlProcess(base, tmp_path / "sitl", lockstep=True, extra_args=["--control-period-ms", "4"]) as sitl:
        gcs = MissionGcs(sitl.gcs_port)
        mission_items, fence_items = _items(gcs.home(), (0.0, 0.0, 1.0) if keep_out_home else KEEP_OUT)
        assert gcs.upload(M.MAV_MISSION_TYPE_MISSION, mission_items) == M.MAV_MISSION_ACCEPTED
        assert gcs.upload(M.MAV_MISSION_TYPE_FENCE, fence_items) == M.MAV_MISSION_ACCEPTED
        gcs.sock.close()
        setup = FlightSetup(connect=sitl.companion_url, sock=sitl.companion_sock, lockstep=True,
                            profile=profile_by_name("bundled"))
        spec = FlySpec(setup=setup, run_dir=tmp_path / "run", plots=False, narrate=False, autopilot_mission=True)
        return await fly_mission(spec, base)


def test_a_ground_station_s_mission_and_fence_are_flown_through_the_forest(tmp_path):
    result = asyncio.run(_fly(tmp_path))
    report = result.report
    assert result.outcome == "completed", report.get("outcome_detail")
    am = report["autopilot_mission"]
    assert am["items"] == 6 and am["fence_items"] == 5 and am["earth_model"] == "wgs84"
    assert am["home_shift_m"] == [0.0, 0.0, 0.0]  # the flight's frame is the home the route was placed about
    assert np.allclose(am["waypoints"], [[n, e, -alt] for n, e, alt, _ in ROUTE], atol=0.02)
    n, margin = fence_margins_m(np.load(result.run_dir / "flight_log.npz"), route_fence())
    assert n > 0 and margin > 0.0, margin  # vehicle and payload stayed inside
    assert report["collisions"] == 0 and report["reached_goal"]
    legs = report["waypoints"]  # the multi-leg flight's report per waypoint
    assert [w["name"] for w in legs] == ["item 1", "item 2", "item 3", "goal"]
    assert all(w["reached_at_s"] is not None for w in legs) and legs[1]["closest_m"] < 0.3  # the held one too


def test_a_fence_that_excludes_the_start_is_refused_before_take_off(tmp_path):
    result = asyncio.run(_fly(tmp_path, keep_out_home=True))
    report = result.report
    assert result.outcome == "refused"
    assert "the start (home at take-off altitude) (0.00, 0.00) m is inside the fence's exclusion circle 0" in \
        report["outcome_detail"]
    assert report["loop"]["ticks"] == 0 and not report["reached_goal"]  # nothing flown
    assert report["autopilot_mission"]["fence_items"] == 5


async def _fly_mavsdk(tmp_path):
    """MAVSDK as the ground station on the vehicle's GCS link: mission_raw uploads the mission, the geofence plugin
    the fence; then the companion flies (MAVSDK stays connected, as a ground station would)."""
    from companion.launch.sitl import free_udp_port

    base = load_mission(shipped_missions()["forest"])
    gcs_port = free_udp_port()
    extra = ["--control-period-ms", "4", "--gcs-remote", f"127.0.0.1:{gcs_port}"]
    async with SitlProcess(base, tmp_path / "sitl", lockstep=True, extra_args=extra) as sitl:
        home = DEFAULT_HOME  # the vehicle's (its GCS link locks onto its first client: MAVSDK's, here)
        drone = await mavsdk_upload(f"udpin://127.0.0.1:{gcs_port}", home)
        try:
            setup = FlightSetup(connect=sitl.companion_url, sock=sitl.companion_sock, lockstep=True,
                                profile=profile_by_name("bundled"))
            spec = FlySpec(setup=setup, run_dir=tmp_path / "run", plots=False, narrate=False, autopilot_mission=True)
            return await fly_mission(spec, base)
        finally:
            drone.destroy()


def test_mavsdk_as_the_ground_station_uploads_what_the_companion_flies(tmp_path):
    pytest.importorskip("mavsdk.asyncio", reason="mavsdk (the test extra) is not installed")
    result = asyncio.run(asyncio.wait_for(_fly_mavsdk(tmp_path), 120.0))
    report = result.report
    assert result.outcome == "completed", report.get("outcome_detail")
    am = report["autopilot_mission"]
    assert am["items"] == 6 and am["fence_items"] == 5
    assert (am["home"]["lat_deg"], am["home"]["lon_deg"], am["home"]["alt_amsl_m"]) == pytest.approx(DEFAULT_HOME)
    assert np.allclose(am["waypoints"], [[n, e, -alt] for n, e, alt, _ in ROUTE], atol=0.02)
    assert report["collisions"] == 0 and [w["reached_at_s"] is not None for w in report["waypoints"]] == [True] * 4


async def _download_signed(tmp_path):
    """The bundled vehicle with a signing key and nothing uploaded; the companion, signed with the same key."""
    import secrets

    from companion.mavlink_io.signing import load_key_file

    key_file = tmp_path / "key"
    key_file.write_text(secrets.token_hex(32) + "\n")
    base = load_mission(shipped_missions()["forest"])
    extra = ["--control-period-ms", "4", "--signing-key", str(key_file)]
    async with SitlProcess(base, tmp_path / "sitl", lockstep=True, extra_args=extra) as sitl:
        setup = FlightSetup(connect=sitl.companion_url, sock=sitl.companion_sock, lockstep=True,
                            profile=profile_by_name("bundled"), signing_key=load_key_file(key_file))
        spec = FlySpec(setup=setup, run_dir=tmp_path / "run", plots=False, narrate=False, autopilot_mission=True)
        return await fly_mission(spec, base)


def test_the_download_is_signed_like_the_flight(tmp_path):
    """Signing on (the vehicle drops unsigned frames): the download still gets home and both lists (empty here),
    so the refusal is the empty mission's, not a silent link."""
    result = asyncio.run(_download_signed(tmp_path))
    report = result.report
    assert result.outcome == "refused" and "no items (upload a mission" in report["outcome_detail"]
    dl = report["autopilot_mission"]["download"]
    assert dl["mission"]["state"] == dl["fence"]["state"] == "done" and report["autopilot_mission"]["home"]
