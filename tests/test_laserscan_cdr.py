"""ROS 2 LaserScan as rmw_zenoh carries it, against an independent encoder (rosbags): CDR bytes decoded field by
field, turned from FLU to FRD, and the same through a real Zenoh put on loopback under rmw_zenoh's key; the
project's own scan stream through Zenoh too; bad samples refused and counted."""

from __future__ import annotations

import math
import struct
import time

import numpy as np
import pytest
import zenoh
from rosbags.typesys import Stores, get_typestore

from companion.cli.bench_zenoh import free_tcp_port
from companion.perception.laserscan import decode_cdr, scan_of
from companion.zenoh_io import schema as ts
from companion.zenoh_io.scan_input import ScanInput, ros_key, scan_from_json
from companion.zenoh_io.session import zenoh_config

STORE = get_typestore(Stores.ROS2_HUMBLE)
LS = STORE.types["sensor_msgs/msg/LaserScan"]
HEADER = STORE.types["std_msgs/msg/Header"]
TIME = STORE.types["builtin_interfaces/msg/Time"]
TYPE = "sensor_msgs/msg/LaserScan"


def _msg(frame_id: str = "laser", n: int = 360, stamp=(12, 345_000_000), ranges=None, intensities=None):
    r = np.linspace(0.5, 11.0, n).astype(np.float32) if ranges is None else np.asarray(ranges, dtype=np.float32)
    inten = np.arange(len(r), dtype=np.float32) if intensities is None else np.asarray(intensities, np.float32)
    return LS(header=HEADER(stamp=TIME(sec=stamp[0], nanosec=stamp[1]), frame_id=frame_id),
              angle_min=-math.pi, angle_max=math.pi, angle_increment=2 * math.pi / len(r), time_increment=1e-4,
              scan_time=0.1, range_min=0.12, range_max=12.0, ranges=r, intensities=inten)


@pytest.mark.parametrize("frame_id", ["", "l", "las", "laser", "base_scan_front_left"])  # every alignment
@pytest.mark.parametrize("little_endian", [True, False])
def test_cdr_from_rosbags_decodes_field_by_field(frame_id, little_endian):
    m = _msg(frame_id, n=37 + len(frame_id))
    raw = bytes(STORE.serialize_cdr(m, TYPE, little_endian=little_endian))
    d = decode_cdr(raw)
    assert d.frame_id == frame_id and d.stamp_s == pytest.approx(12.345)
    for f in ("angle_min", "angle_max", "angle_increment", "time_increment", "scan_time", "range_min", "range_max"):
        assert d.__getattribute__(f) == np.float32(getattr(m, f)), f
    assert (d.ranges == m.ranges).all() and (d.intensities == m.intensities).all()


def test_rep117_markers_and_flu_to_frd():
    """NaN unknown, +inf and beyond range_max free, −inf and below range_min unknown; the ray ROS puts at +90°
    (left, counter-clockwise) is the FRD ray at 270° (left, clockwise)."""
    r = [2.0, math.nan, math.inf, -math.inf, 13.0, 0.05, 3.0, 4.0]
    m = LS(header=HEADER(stamp=TIME(sec=1, nanosec=0), frame_id="laser"), angle_min=0.0, angle_max=7 * math.pi / 4,
           angle_increment=math.pi / 4, time_increment=0.0, scan_time=0.1, range_min=0.1, range_max=12.0,
           ranges=np.array(r, np.float32), intensities=np.array([], np.float32))
    s = scan_of(decode_cdr(bytes(STORE.serialize_cdr(m, TYPE))))
    assert s.ranges_m[0] == 2.0 and s.ranges_m[6] == 3.0
    assert np.isnan(s.ranges_m[[1, 3, 5]]).all() and np.isinf(s.ranges_m[[2, 4]]).all()
    assert np.degrees(s.angles_rad[2]) == pytest.approx(270.0)  # ROS +90° (left)
    assert np.degrees(s.angles_rad[6]) == pytest.approx(90.0)  # ROS 270° = −90° (right)
    assert s.frame == "body_frd" and s.source == "ros2" and s.system_id is None


@pytest.mark.parametrize(("raw", "why"), [
    (b"", "encapsulation"), (b"\x00\x07\x00\x00" + bytes(64), "encapsulation"),
    (None, "truncated"), ("neg", "negative"), ("huge", "frame_id"),
])
def test_bad_laserscans_are_refused_naming_the_field(raw, why):
    if raw is None:
        raw = bytes(STORE.serialize_cdr(_msg(), TYPE))[:200]
    elif raw == "neg":
        raw = bytes(STORE.serialize_cdr(_msg(ranges=[1.0, -2.0, 3.0], intensities=[]), TYPE))
    elif raw == "huge":
        raw = b"\x00\x01\x00\x00" + bytes(8) + struct.pack("<I", 1 << 30)
    with pytest.raises(ValueError, match=why):
        scan_of(decode_cdr(raw))


def _drain_until(inp: ScanInput, got: list, n: int, timeout_s: float = 10.0) -> None:
    end = time.monotonic() + timeout_s
    while len(got) + sum(inp.refused.values()) < n and time.monotonic() < end:
        inp.drain()
        time.sleep(0.01)


def test_laserscan_and_the_projects_scan_through_real_zenoh():
    """A ROS 2 LaserScan put under rmw_zenoh's key (domain 0, topic /robot/scan, rosbags' RIHS01 type hash, an
    attachment as rmw_zenoh sends one) and a slungpilot.scan sample reach the sink as scans; the ROS one off the
    vehicle's clock, the project's on it. Broken samples on both are counted, never handed on."""
    ep = f"tcp/127.0.0.1:{free_tcp_port()}"
    got: list = []
    with zenoh.open(zenoh_config("companion", listen=[ep])) as comp, \
            zenoh.open(zenoh_config("listener", connect=[ep])) as peer:
        inp = ScanInput(comp, lambda s, clock: got.append((s, clock)), vehicle_id="3", ros_topic="/robot/scan")
        key = ros_key(0, "/robot/scan", STORE.hash_rihs01(TYPE))
        assert key.startswith("0/robot/scan/sensor_msgs::msg::dds_::LaserScan_/RIHS01_")
        time.sleep(0.5)  # the subscriptions reach the peer
        attachment = struct.pack("<qq16s", 7, time.time_ns(), bytes(range(16)))  # seq, timestamp, gid
        m = _msg("laser", n=360)
        peer.put(key, bytes(STORE.serialize_cdr(m, TYPE)), attachment=attachment)
        _drain_until(inp, got, 1)
        ranges = np.full(360, math.inf)
        ranges[10:14] = 3.2
        ranges[200] = math.nan
        peer.put(ts.scan_key("slungpilot", "3"),
                 ts.encode_scan(0, "3", 2.5, time.time(), 2_500_000, 0.0, math.radians(1.0), 0.1, 12.0, ranges))
        _drain_until(inp, got, 2)
        assert len(got) == 2
        ros = next(s for s, clock in got if not clock)
        own = next(s for s, clock in got if clock)
        assert ros.source == "ros2" and ros.t_s == pytest.approx(12.345)
        assert np.allclose(ros.ranges_m, np.asarray(m.ranges, dtype=float))
        assert own.source == "zenoh" and own.t_s == 2.5 and (own.ranges_m[10:14] == 3.2).all()
        assert np.isnan(own.ranges_m[200]) and np.isinf(own.ranges_m[0])
        peer.put(key, b"\x00\x01\x00\x00\x05")  # truncated CDR
        peer.put(ts.scan_key("slungpilot", "3"), b'{"schema": "slungpilot.scan"}')  # no header
        _drain_until(inp, got, 4)
        assert len(got) == 2 and sum(inp.refused.values()) == 2, inp.refused
        assert inp.facts()["received"] == {"ros2": 2, "slungpilot": 2}
        inp.close()


def test_the_projects_scan_decodes_with_its_clock_and_frame():
    ranges = np.array([1.0, math.inf, math.nan, 2.0])
    raw = ts.encode_scan(3, "1", 4.0, 0.0, 4_000_000, -math.pi / 2, math.pi / 2, 0.1, 12.0, ranges)
    s = scan_from_json(raw)
    assert s.t_s == 4.0 and np.degrees(s.angles_rad).tolist() == pytest.approx([270.0, 0.0, 90.0, 180.0])
    assert s.ranges_m[0] == 1.0 and np.isinf(s.ranges_m[1]) and np.isnan(s.ranges_m[2])
    with pytest.raises(ValueError, match="frame"):
        scan_from_json(raw.replace(b'"body_frd"', b'"body_flu"'))
