"""The bundled vehicle's mission service (sim_bridge/mission_server.py) against real peers: a pymavlink client over
loopback UDP doing what a ground station does (upload, download, clear; mission, fence and rally lists), every
kind of bad input a real link or client produces, two clients at once, an upload abandoned half-way; MAVProxy
uploading a QGC WPL 110 file; and the pure state machine on its own clock for retries and timeouts."""

from __future__ import annotations

import math
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as M

from sim_bridge.mavclient import MavClient, spawn_vehicle, stop_vehicle
from sim_bridge.mission_server import RETRY_S, TIMEOUT_S, MissionServer, Peer

pytestmark = pytest.mark.shares_cores  # lockstep processes, no deadline: they may share the cores (conftest.py)

HOME = (47.397742, 8.545594, 488.0)
MISSION, FENCE, RALLY = M.MAV_MISSION_TYPE_MISSION, M.MAV_MISSION_TYPE_FENCE, M.MAV_MISSION_TYPE_RALLY
REL, GLOBAL_INT, MFRAME = M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_FRAME_GLOBAL_INT, M.MAV_FRAME_MISSION


def item(seq, cmd, lat=HOME[0], lon=HOME[1], z=10.0, frame=REL, p=(0.0, 0.0, 0.0, 0.0), mtype=MISSION,
         current=0, **over):
    """MISSION_ITEM_INT fields (target: the vehicle); lat/lon in degrees."""
    f = {"target_system": 1, "target_component": 1, "seq": seq, "frame": frame, "command": cmd, "current": current,
         "autocontinue": 1, "param1": p[0], "param2": p[1], "param3": p[2], "param4": p[3],
         "x": round(lat * 1e7), "y": round(lon * 1e7), "z": z, "mission_type": mtype}
    f.update(over)
    return f


def four_waypoints() -> list[dict]:
    """Take-off, a waypoint with a 3 s hold, a waypoint, land."""
    return [item(0, M.MAV_CMD_NAV_TAKEOFF, z=3.0, current=1), item(1, M.MAV_CMD_NAV_WAYPOINT, 47.39784, 8.54570,
                                                                   p=(3.0, 0.5, 0.0, math.nan)),
            item(2, M.MAV_CMD_NAV_WAYPOINT, 47.39790, 8.54580, 4.0), item(3, M.MAV_CMD_NAV_LAND, 47.39790, 8.54580,
                                                                          0.0)]


def fence_items() -> list[dict]:
    """An inclusion square of four vertices and an exclusion circle of 5 m radius."""
    corners = [(47.3970, 8.5450), (47.3970, 8.5462), (47.3985, 8.5462), (47.3985, 8.5450)]
    poly = [item(i, M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, la, lo, 0.0, GLOBAL_INT, (4.0, 0, 0, 0), FENCE)
            for i, (la, lo) in enumerate(corners)]
    return [*poly, item(4, M.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, 47.39785, 8.54565, 0.0, GLOBAL_INT,
                        (5.0, 0, 0, 0), FENCE)]


def next_of(c: MavClient, types: tuple[str, ...], timeout_s: float = 3.0):
    """The vehicle's next message of one of ``types``."""
    end = time.monotonic() + timeout_s
    while (left := end - time.monotonic()) > 0:
        for m in c.poll(left):
            if m.get_type() in types and m.get_srcSystem() == 1:
                return m
    raise TimeoutError(f"none of {types} within {timeout_s} s")


def upload(c: MavClient, items: list[dict], mtype: int = MISSION, count: int | None = None) -> int:
    """Answer the vehicle's requests until its MISSION_ACK; returns the ACK's result."""
    c.mav.mission_count_send(1, 1, len(items) if count is None else count, mtype)
    while True:
        m = next_of(c, ("MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"))
        if m.get_type() == "MISSION_ACK":
            return m.type
        assert m.mission_type == mtype
        c.mav.mission_item_int_send(**items[m.seq])


def download(c: MavClient, mtype: int = MISSION, as_int: bool = True) -> list:
    """The stored list (MISSION_ITEM_INT or, with ``as_int`` False, MISSION_ITEM messages), ACKed."""
    c.mav.mission_request_list_send(1, 1, mtype)
    n = next_of(c, ("MISSION_COUNT",)).count
    out = []
    for seq in range(n):
        (c.mav.mission_request_int_send if as_int else c.mav.mission_request_send)(1, 1, seq, mtype)
        m = next_of(c, ("MISSION_ITEM_INT" if as_int else "MISSION_ITEM",))
        assert m.seq == seq and m.mission_type == mtype
        out.append(m)
    if n:
        c.mav.mission_ack_send(1, 1, M.MAV_MISSION_ACCEPTED, mtype)
    return out


def same(got, sent: dict) -> bool:
    """A downloaded MISSION_ITEM_INT carries what was uploaded (NaN params as NaN)."""
    keys = ("seq", "frame", "command", "autocontinue", "x", "y", "z", "param1", "param2", "param3", "param4")
    return all(getattr(got, k) == sent[k] or (isinstance(sent[k], float) and math.isnan(sent[k])
                                               and math.isnan(getattr(got, k))) for k in keys)


@pytest.fixture(scope="module")
def vehicle():
    """One lockstep vehicle (idle: no client steps it, so it costs no CPU) and its onboard link's client (the
    link keeps its first peer) for the whole module; yields (client, GCS port)."""
    proc, port, gcs_port = spawn_vehicle("--lockstep", "--wind", "none")
    try:
        with MavClient(port) as c:
            c.heartbeat()
            yield c, gcs_port
    finally:
        assert stop_vehicle(proc) == 0


@pytest.fixture
def client(vehicle):
    """The module's client with nothing left over from the test before (what came within 0.2 s read away)."""
    c = vehicle[0]
    while c.poll(0.2):
        pass
    return c


def test_round_trip_of_mission_fence_and_rally_then_clear(client):
    mission, fence = four_waypoints(), fence_items()
    rally = [item(0, M.MAV_CMD_NAV_RALLY_POINT, 47.3979, 8.5457, 15.0, mtype=RALLY)]
    assert upload(client, mission) == M.MAV_MISSION_ACCEPTED
    cur = next_of(client, ("MISSION_CURRENT",))  # every link is told the mission changed
    assert (cur.seq, cur.total) == (0, 4)
    assert upload(client, fence, FENCE) == M.MAV_MISSION_ACCEPTED
    assert upload(client, rally, RALLY) == M.MAV_MISSION_ACCEPTED
    got = download(client)
    assert len(got) == 4 and all(same(g, s) for g, s in zip(got, mission, strict=True))
    assert [g.current for g in got] == [1, 0, 0, 0]
    got = download(client, FENCE)
    assert len(got) == 5 and all(same(g, s) for g, s in zip(got, fence, strict=True))
    assert same(download(client, RALLY)[0], rally[0])
    client.mav.mission_clear_all_send(1, 1, MISSION)
    ack = next_of(client, ("MISSION_ACK",))
    assert (ack.type, ack.mission_type) == (M.MAV_MISSION_ACCEPTED, MISSION)
    assert download(client) == [] and len(download(client, FENCE)) == 5  # separate stores
    client.mav.mission_clear_all_send(1, 1, M.MAV_MISSION_TYPE_ALL)
    assert next_of(client, ("MISSION_ACK",)).type == M.MAV_MISSION_ACCEPTED
    assert download(client, FENCE) == [] and download(client, RALLY) == []
    assert upload(client, mission) == M.MAV_MISSION_ACCEPTED
    assert upload(client, []) == M.MAV_MISSION_ACCEPTED  # a count of 0 clears, as PX4
    assert download(client) == []


def test_float_messages_as_px4_answers_them(client):
    """MISSION_REQUEST (deprecated) gets a MISSION_ITEM in degrees and MAV_FRAME_GLOBAL_RELATIVE_ALT; a float
    MISSION_ITEM upload is stored in the _INT frame; a float item in an _INT frame is refused (PX4)."""
    assert upload(client, four_waypoints()) == M.MAV_MISSION_ACCEPTED
    got = download(client, as_int=False)
    assert [g.frame for g in got] == [M.MAV_FRAME_GLOBAL_RELATIVE_ALT] * 4
    assert got[1].x == pytest.approx(47.39784, abs=1e-5) and got[1].y == pytest.approx(8.54570, abs=1e-5)
    client.mav.mission_count_send(1, 1, 1, MISSION)
    assert next_of(client, ("MISSION_REQUEST_INT",)).seq == 0
    client.mav.mission_item_send(1, 1, 0, M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_CMD_NAV_WAYPOINT, 0, 1,
                                 0, 0, 0, 0, 47.3981, 8.5461, 7.0, MISSION)
    assert next_of(client, ("MISSION_ACK",)).type == M.MAV_MISSION_ACCEPTED
    (g,) = download(client)
    # a float32 latitude near 47° is good to 3.8e-6° (0.4 m): why MISSION_ITEM is deprecated
    assert g.frame == REL and abs(g.x - 473981000) <= 40 and abs(g.y - 85461000) <= 40 and g.z == 7.0
    client.mav.mission_count_send(1, 1, 1, MISSION)
    next_of(client, ("MISSION_REQUEST_INT",))
    client.mav.mission_item_send(1, 1, 0, REL, M.MAV_CMD_NAV_WAYPOINT, 0, 1, 0, 0, 0, 0, 47.3981, 8.5461, 7.0,
                                 MISSION)
    assert next_of(client, ("MISSION_ACK",)).type == M.MAV_MISSION_UNSUPPORTED_FRAME


BAD_ITEMS = [
    ("nan altitude", {"z": math.nan}, M.MAV_MISSION_INVALID_PARAM7),
    ("infinite altitude", {"z": math.inf}, M.MAV_MISSION_INVALID_PARAM7),
    ("latitude 91°", {"x": 910_000_000}, M.MAV_MISSION_INVALID_PARAM5_X),
    ("longitude -181°", {"y": -1_810_000_000}, M.MAV_MISSION_INVALID_PARAM6_Y),
    ("infinite hold time", {"param1": math.inf}, M.MAV_MISSION_INVALID_PARAM1),
    ("body frame", {"frame": M.MAV_FRAME_BODY_NED}, M.MAV_MISSION_UNSUPPORTED_FRAME),
    ("terrain frame", {"frame": M.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT}, M.MAV_MISSION_UNSUPPORTED_FRAME),
    ("spline waypoint", {"command": M.MAV_CMD_NAV_SPLINE_WAYPOINT}, M.MAV_MISSION_UNSUPPORTED),
    ("fence vertex in a mission", {"command": M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION},
     M.MAV_MISSION_UNSUPPORTED),
]


@pytest.mark.parametrize(("what", "change", "result"), BAD_ITEMS, ids=[b[0] for b in BAD_ITEMS])
def test_a_bad_item_is_refused_with_its_result_and_the_old_mission_kept(client, what, change, result):
    old = four_waypoints()
    assert upload(client, old) == M.MAV_MISSION_ACCEPTED
    new = four_waypoints()
    new[2].update(change)
    assert upload(client, new) == result
    assert "refused" in next_of(client, ("STATUSTEXT",)).text
    got = download(client)
    assert len(got) == 4 and all(same(g, s) for g, s in zip(got, old, strict=True))


def test_nan_coordinates_in_a_float_item_and_a_10000_item_mission(client):
    client.mav.mission_count_send(1, 1, 1, MISSION)
    next_of(client, ("MISSION_REQUEST_INT",))
    client.mav.mission_item_send(1, 1, 0, M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_CMD_NAV_WAYPOINT, 0, 1, 0, 0, 0,
                                 0, math.nan, 8.5461, 7.0, MISSION)
    assert next_of(client, ("MISSION_ACK",)).type == M.MAV_MISSION_INVALID_PARAM5_X
    assert upload(client, [], count=10_000) == M.MAV_MISSION_NO_SPACE
    assert upload(client, [], FENCE, count=257) == M.MAV_MISSION_NO_SPACE
    poly = fence_items()[:3]  # announces 4 vertices, sends 3
    for p in poly:
        p["param1"] = 4.0
    assert upload(client, poly, FENCE) == M.MAV_MISSION_INVALID_PARAM1


def test_out_of_sequence_and_duplicate_items_are_requested_again(client):
    items = four_waypoints()
    client.mav.mission_count_send(1, 1, 4, MISSION)
    assert next_of(client, ("MISSION_REQUEST_INT",)).seq == 0
    client.mav.mission_item_int_send(**items[2])  # ahead of its turn: ignored, item 0 asked for again
    assert next_of(client, ("MISSION_REQUEST_INT", "MISSION_ACK")).seq == 0
    client.mav.mission_item_int_send(**items[0])
    assert next_of(client, ("MISSION_REQUEST_INT",)).seq == 1
    client.mav.mission_item_int_send(**items[0])  # a duplicate: ignored, item 1 asked for again
    assert next_of(client, ("MISSION_REQUEST_INT", "MISSION_ACK")).seq == 1
    for seq in (1, 2):
        client.mav.mission_item_int_send(**items[seq])
        assert next_of(client, ("MISSION_REQUEST_INT",)).seq == seq + 1
    client.mav.mission_item_int_send(**items[3])
    assert next_of(client, ("MISSION_ACK",)).type == M.MAV_MISSION_ACCEPTED
    client.mav.mission_item_int_send(**items[3])  # the last item again (our ACK lost, for the client): ACK again
    assert next_of(client, ("MISSION_ACK",)).type == M.MAV_MISSION_ACCEPTED
    got = download(client)
    assert len(got) == 4 and all(same(g, s) for g, s in zip(got, items, strict=True))


def test_an_upload_abandoned_half_way_times_out_and_the_old_mission_stays(client):
    old = four_waypoints()[:2]
    assert upload(client, old) == M.MAV_MISSION_ACCEPTED
    new = four_waypoints()
    client.mav.mission_count_send(1, 1, 4, MISSION)
    for seq in (0, 1):
        assert next_of(client, ("MISSION_REQUEST_INT",)).seq == seq
        client.mav.mission_item_int_send(**new[seq])
    t0 = time.monotonic()
    requests = []
    while True:  # silence: the vehicle asks again for item 2, then gives up
        m = next_of(client, ("MISSION_REQUEST_INT", "MISSION_ACK"), timeout_s=TIMEOUT_S + 3.0)
        if m.get_type() == "MISSION_ACK":
            break
        requests.append(m.seq)
    assert m.type == M.MAV_MISSION_OPERATION_CANCELLED
    assert time.monotonic() - t0 >= TIMEOUT_S - 0.5
    assert len(requests) >= 3 and set(requests) == {2}
    assert "timed out" in next_of(client, ("STATUSTEXT",)).text
    got = download(client)
    assert len(got) == 2 and all(same(g, s) for g, s in zip(got, old, strict=True))


@pytest.mark.slow
def test_in_real_time_too_an_abandoned_upload_is_retried_then_cancelled():
    """The real-time runner drives the retries and the timeout from its control periods (lockstep: its
    wall-clock duties, above)."""
    proc, port, _ = spawn_vehicle("--wind", "none")
    try:
        with MavClient(port) as c:
            c.heartbeat()
            c.mav.mission_count_send(1, 1, 2, FENCE)
            assert next_of(c, ("MISSION_REQUEST_INT",)).seq == 0
            c.mav.mission_item_int_send(**fence_items()[0])
            seen = []
            kinds = ("MISSION_REQUEST_INT", "MISSION_ACK")
            while (m := next_of(c, kinds, TIMEOUT_S + 3.0)).get_type() != "MISSION_ACK":
                seen.append(m.seq)
            assert m.type == M.MAV_MISSION_OPERATION_CANCELLED and m.mission_type == FENCE
            assert len(seen) >= 3 and set(seen) == {1}
            assert download(c, FENCE) == []
    finally:
        assert stop_vehicle(proc) == 0


def test_a_second_client_is_denied_while_a_transfer_runs(vehicle, client):
    with MavClient(vehicle[1], sysid=254, compid=191) as other:  # the GCS link (its first peer)
        other.heartbeat()
        items = four_waypoints()
        client.mav.mission_count_send(1, 1, 4, MISSION)
        assert next_of(client, ("MISSION_REQUEST_INT",)).seq == 0
        client.mav.mission_item_int_send(**items[0])
        assert next_of(client, ("MISSION_REQUEST_INT",)).seq == 1
        for start in (lambda: other.mav.mission_count_send(1, 1, 2, MISSION),
                      lambda: other.mav.mission_request_list_send(1, 1, MISSION),
                      lambda: other.mav.mission_clear_all_send(1, 1, MISSION),
                      lambda: other.mav.mission_item_int_send(**items[1])):
            start()
            assert next_of(other, ("MISSION_ACK",)).type == M.MAV_MISSION_DENIED
        for seq in (1, 2, 3):
            client.mav.mission_item_int_send(**items[seq])
            next_of(client, ("MISSION_REQUEST_INT", "MISSION_ACK"))
        got = download(other)  # now free: the other client reads what the first one wrote
        assert len(got) == 4 and all(same(g, s) for g, s in zip(got, items, strict=True))


def test_mission_planner_component_set_current_and_home(client):
    client.mav.mission_count_send(1, M.MAV_COMP_ID_MISSIONPLANNER, 0, MISSION)  # PX4 answers the planner's id too
    assert next_of(client, ("MISSION_ACK",)).type == M.MAV_MISSION_ACCEPTED
    assert upload(client, four_waypoints()) == M.MAV_MISSION_ACCEPTED
    while client.poll(0.2):  # the MISSION_CURRENTs of the two uploads
        pass
    client.mav.mission_set_current_send(1, 1, 2)
    assert next_of(client, ("MISSION_CURRENT",)).seq == 2
    client.mav.mission_set_current_send(1, 1, 9)
    assert "not in the mission" in next_of(client, ("STATUSTEXT",)).text
    assert next_of(client, ("MISSION_CURRENT",)).seq == 2
    assert client.command(M.MAV_CMD_DO_SET_MISSION_CURRENT, 3) == M.MAV_RESULT_ACCEPTED
    assert next_of(client, ("MISSION_CURRENT",)).seq == 3
    assert client.command(M.MAV_CMD_DO_SET_MISSION_CURRENT, 4) == M.MAV_RESULT_DENIED
    assert client.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN) == M.MAV_RESULT_ACCEPTED
    o = next_of(client, ("GPS_GLOBAL_ORIGIN",))
    assert (o.latitude, o.longitude, o.altitude) == (round(HOME[0] * 1e7), round(HOME[1] * 1e7), 488000)
    assert client.command(M.MAV_CMD_GET_HOME_POSITION) == M.MAV_RESULT_ACCEPTED
    h = next_of(client, ("HOME_POSITION",))
    assert (h.latitude, h.longitude, h.altitude) == (o.latitude, o.longitude, o.altitude)
    assert client.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION) == M.MAV_RESULT_ACCEPTED
    caps = next_of(client, ("AUTOPILOT_VERSION",)).capabilities
    assert caps & M.MAV_PROTOCOL_CAPABILITY_MISSION_INT and caps & M.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE


def test_home_flag_moves_home_origin_and_global_position_together():
    proc, port, _ = spawn_vehicle("--lockstep", "--wind", "none", "--home", "46.5,7.25,1200")
    try:
        with MavClient(port) as c:
            c.heartbeat()
            c.wait_marker()
            for _ in range(10):
                c.step(thrust=0.0)  # on the ground, disarmed: 40 ms of telemetry
            gp, lp = c.last["GLOBAL_POSITION_INT"], c.last["LOCAL_POSITION_NED"]
            assert c.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_HOME_POSITION) == M.MAV_RESULT_ACCEPTED
            h = next_of(c, ("HOME_POSITION",))
            c.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN)
            o = next_of(c, ("GPS_GLOBAL_ORIGIN",))
        assert (o.latitude, o.longitude, o.altitude) == (465000000, 72500000, 1200000)
        assert (h.latitude, h.longitude, h.altitude) == (465000000, 72500000, 1200000)
        assert abs(lp.x) < 0.01 and abs(lp.y) < 0.01
        assert abs(gp.lat - 465000000) <= 1 and abs(gp.lon - 72500000) <= 1
        assert abs(gp.alt - (1200000 - round(lp.z * 1000))) <= 1 and abs(gp.relative_alt + round(lp.z * 1000)) <= 1
    finally:
        assert stop_vehicle(proc) == 0
    bad = subprocess.run([sys.executable, "-m", "sim_bridge", "--home", "95,7,100"], capture_output=True, text=True,
                         timeout=60)
    assert bad.returncode != 0 and "--home" in bad.stderr


# ---------------------------------------------------------------------------------------------- the pure machine
class _Msg:
    """A message as the vehicle's link hands it over (pymavlink's attributes and get_type())."""

    def __init__(self, mtype: str, **fields) -> None:
        self._t = mtype
        self.__dict__.update(fields)

    def get_type(self) -> str:
        return self._t


def test_retries_and_timeout_on_the_machines_own_clock():
    s = MissionServer()
    gcs = Peer("gcs", 255, 190)
    out = s.handle(_Msg("MISSION_COUNT", count=2, mission_type=MISSION), gcs, 100.0)
    assert [o.name for o in out] == ["mission_request_int"] and s.busy
    assert s.tick(100.0 + RETRY_S * 0.5) == []
    again = s.tick(100.0 + RETRY_S * 1.1)
    assert [(o.name, o.fields["seq"]) for o in again] == [("mission_request_int", 0)]
    assert all(o.name == "mission_request_int" for o in s.tick(100.0 + TIMEOUT_S - 0.01))
    out = s.tick(100.0 + TIMEOUT_S + 0.01)
    assert [o.name for o in out] == ["mission_ack", "statustext"] and not s.busy
    assert out[0].fields["type"] == M.MAV_MISSION_OPERATION_CANCELLED and out[0].peer == gcs


def test_a_download_that_stops_half_way_frees_the_machine_and_a_cancel_ends_an_upload():
    s = MissionServer()
    a, b = Peer("onboard", 255, 190), Peer("gcs", 254, 191)
    s.stores[MISSION] = s.stores[MISSION]  # empty at start
    s.handle(_Msg("MISSION_COUNT", count=1, mission_type=MISSION), a, 0.0)
    s.handle(_Msg("MISSION_ITEM_INT", **item(0, M.MAV_CMD_NAV_WAYPOINT)), a, 0.1)
    assert len(s.items()) == 1
    s.handle(_Msg("MISSION_REQUEST_LIST", mission_type=MISSION), a, 1.0)
    assert s.busy
    out = s.handle(_Msg("MISSION_COUNT", count=1, mission_type=MISSION), b, 2.0)
    assert out[0].fields["type"] == M.MAV_MISSION_DENIED
    assert [o.name for o in s.tick(1.0 + TIMEOUT_S + 0.1)] == ["statustext"] and not s.busy  # no ACK: PX4
    s.handle(_Msg("MISSION_REQUEST_LIST", mission_type=MISSION), a, 5.0)
    s.handle(_Msg("MISSION_REQUEST_INT", seq=0, mission_type=MISSION), a, 5.1)
    assert s.busy  # every item sent, no ACK from the client: the next partner may start at once (PX4)
    out = s.handle(_Msg("MISSION_REQUEST_LIST", mission_type=MISSION), b, 5.2)
    assert [(o.name, o.fields["count"]) for o in out] == [("mission_count", 1)] and s.partner == b
    s.handle(_Msg("MISSION_ACK", type=M.MAV_MISSION_ACCEPTED, mission_type=MISSION), b, 5.3)
    s.handle(_Msg("MISSION_COUNT", count=3, mission_type=MISSION), b, 10.0)
    s.handle(_Msg("MISSION_ACK", type=M.MAV_MISSION_OPERATION_CANCELLED, mission_type=MISSION), b, 10.1)
    assert not s.busy and len(s.items()) == 1


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("mavproxy.py", path=str(Path(sys.executable).parent)) is None,
                    reason="MAVProxy is not installed in this environment")
def test_mavproxy_uploads_a_qgc_wpl_file(tmp_path):
    """MAVProxy's wp module (a real ground-station router) loads a QGC WPL 110 file into the vehicle."""
    lines = ["QGC WPL 110",
             f"0\t1\t0\t16\t0\t0\t0\t0\t{HOME[0]}\t{HOME[1]}\t{HOME[2]}\t1",  # home, as Mission Planner writes it
             f"1\t0\t3\t22\t0\t0\t0\t0\t{HOME[0]}\t{HOME[1]}\t3.000000\t1",
             "2\t0\t3\t16\t2.000000\t0\t0\t0\t47.397840\t8.545700\t4.000000\t1",
             "3\t0\t3\t16\t0\t0\t0\t0\t47.397900\t8.545800\t4.000000\t1",
             "4\t0\t2\t20\t0\t0\t0\t0\t0\t0\t0\t1"]
    wpl = tmp_path / "mission.waypoints"
    wpl.write_text("\n".join(lines) + "\n")
    exe = str(Path(sys.executable).parent / "mavproxy.py")
    vproc, port, gcs_port = spawn_vehicle("--lockstep", "--wind", "none")
    with MavClient(port) as c:
        c.heartbeat()
        proc = subprocess.Popen([sys.executable, exe, "--master", f"udpout:127.0.0.1:{gcs_port}",
                                 "--non-interactive", "--daemon", "--nowait", "--default-modules", "wp",
                                 "--target-system", "1", "--target-component", "1",  # else it loads for system 0
                                 "--state-basedir", str(tmp_path), "--cmd", f"wp load {wpl}"],
                                stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                text=True, cwd=tmp_path)
        try:
            got = []
            end = time.monotonic() + 40.0
            while time.monotonic() < end and len(got) != 5:
                time.sleep(1.0)
                c.mav.mission_request_list_send(1, 1, MISSION)
                m = next_of(c, ("MISSION_COUNT", "MISSION_ACK"))  # ACK DENIED while MAVProxy uploads
                if m.get_type() == "MISSION_COUNT" and m.count:
                    c.mav.mission_ack_send(1, 1, M.MAV_MISSION_ACCEPTED, MISSION)
                    got = download(c)
        finally:
            proc.terminate()
            out = proc.communicate(timeout=20)[0]
            assert stop_vehicle(vproc) == 0
    assert len(got) == 5, out[-3000:]
    assert "Sent all 5 waypoints" in out and "Got MISSION_ACK: TYPE_MISSION: ACCEPTED" in out
    assert [g.command for g in got] == [16, 22, 16, 16, 20]
    assert got[2].param1 == 2.0 and got[2].frame == REL and abs(got[2].x - 473978400) <= 2
    assert got[4].frame == MFRAME
