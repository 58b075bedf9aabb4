"""10,000 random and mutated datagrams leave the bundled vehicle flying and answering (lockstep, real UDP)."""

from __future__ import annotations

import math
import random
import re
import time

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from sim_bridge.mavclient import MavClient, spawn_vehicle, stop_vehicle, vehicle_stderr

M = mavlink2
N_DATAGRAMS = 10_000
STEP_EVERY = 40


def _frame(msg, sysid: int = 255, mavlink1: bool = False) -> bytes:
    enc = M.MAVLink(None, sysid, 190)
    return bytes(msg.pack(enc, force_mavlink1=mavlink1))


def _bad_datagrams(rng: random.Random, good: list[bytes]) -> list[tuple[str, bytes]]:
    enc = M.MAVLink(None, 255, 190)
    sat = enc.set_attitude_target_encode
    crafted = {
        "nonfinite": [_frame(sat(0, 1, 1, 7, [1, 0, 0, 0], 0, 0, 0, math.nan)),
                      _frame(sat(0, 1, 1, 0, [1, 0, 0, 0], math.inf, 0, 0, 0.4))],
        "bad_quaternion": [_frame(sat(0, 1, 1, 7, [1.01, 0, 0, 0], 0, 0, 0, 0.4)),
                           _frame(sat(0, 1, 1, 7, [0, 0, 0, 0], 0, 0, 0, 0.4))],
        "thrust_range": [_frame(sat(0, 1, 1, 7, [1, 0, 0, 0], 0, 0, 0, 1.5)),
                         _frame(sat(0, 1, 1, 7, [1, 0, 0, 0], 0, 0, 0, -0.1))],
        "other_target": [_frame(sat(0, 7, 1, 7, [1, 0, 0, 0], 0, 0, 0, 0.9)),
                         _frame(enc.command_long_encode(9, 1, 400, 0, 0, 21196, 0, 0, 0, 0, 0))],
        "mavlink1": [_frame(enc.heartbeat_encode(6, 8, 0, 0, 4), mavlink1=True)],
        "unknown_id": [bytes([0xFD, 4, 0, 0, 1, 255, 190, 0x60, 0xEA, 0, 1, 2, 3, 4, 0x12, 0x34])],
        "bad_flags": [bytes([0xFD, 0, 0x02, 0, 1, 255, 190, 0, 0, 0, 0, 0])],
    }
    out: list[tuple[str, bytes]] = []
    for i in range(N_DATAGRAMS):
        r = i % 10
        if r < 3:
            out.append(("garbage", bytes(rng.getrandbits(8) for _ in range(rng.randint(1, 280)))))
        elif r < 5:  # one bit flipped somewhere after the marker of a valid frame
            f = bytearray(rng.choice(good))
            k = rng.randrange(1, len(f))
            f[k] ^= 1 << rng.randrange(8)
            out.append(("mutated", bytes(f)))
        elif r < 6:
            f = rng.choice(good)
            out.append(("truncated", f[: rng.randrange(1, len(f))]))
        else:
            kind = rng.choice(sorted(crafted))
            out.append((kind, rng.choice(crafted[kind])))
    return out


def test_random_and_mutated_datagrams_leave_vehicle_flying_and_answering():
    rng = random.Random(20240607)
    enc = M.MAVLink(None, 255, 190)
    good = [
        _frame(enc.set_attitude_target_encode(0, 1, 1, 7, [1, 0, 0, 0], 0, 0, 0, 0.4)),
        _frame(enc.command_long_encode(1, 1, 400, 0, 0, 21196, 0, 0, 0, 0, 0)),  # forced disarm, if intact!
        _frame(enc.param_set_encode(1, 1, b"MPC_THR_HOVER", 0.9, M.MAV_PARAM_TYPE_REAL32)),
        _frame(enc.heartbeat_encode(6, 8, 0, 0, 4)),
    ]
    bad = _bad_datagrams(rng, good)
    proc, port, _ = spawn_vehicle("--lockstep", "--wind", "paper")
    try:
        with MavClient(port) as c:
            c.heartbeat()
            c.wait_marker(10.0)
            for _ in range(5):
                c.step(thrust=0.0)
            assert c.set_mode(6) == M.MAV_RESULT_ACCEPTED and c.arm() == M.MAV_RESULT_ACCEPTED
            z, vz = 0.0, 0.0

            def hover_step():
                nonlocal z, vz
                c.step(thrust=min(0.9, max(0.05, 0.4 + 0.12 * (z + 2.0) + 0.12 * vz)))
                lp = c.last["LOCAL_POSITION_NED"]
                z, vz = lp.z, lp.vz

            for _ in range(1000):  # climb to 2 m
                hover_step()
            t_wall = time.monotonic()
            for i, (_, data) in enumerate(bad):
                c.sock.sendto(data, c.vehicle_addr)
                if i % STEP_EVERY == STEP_EVERY - 1:
                    hover_step()
            for _ in range(250):
                hover_step()
            elapsed = time.monotonic() - t_wall
            # still flying, armed, in OFFBOARD, at its altitude
            assert c.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_HEARTBEAT) == M.MAV_RESULT_ACCEPTED
            hb = c.wait_for("HEARTBEAT")
            assert hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED and hb.custom_mode == 6 << 16
            assert abs(z + 2.0) < 0.5
            # and answering the PARAM protocol, with the rejections counted
            counts = {}
            for name in ("RJ_GARBAGE", "RJ_BAD_CRC", "RJ_TRUNCATED", "RJ_MAVLINK1", "RJ_UNKNOWN_ID",
                         "RJ_OTHER_TARGET", "RJ_NONFINITE", "RJ_BAD_QUATERNIO", "RJ_THRUST_RANGE", "RJ_BAD_FLAGS"):
                c.mav.param_request_read_send(1, 1, name.encode(), -1)
                counts[name] = c.wait_for("PARAM_VALUE", lambda m, n=name: m.param_id == n).param_value
            c.mav.param_request_read_send(1, 1, b"MPC_THR_HOVER", -1)
            assert c.wait_for("PARAM_VALUE", lambda m: m.param_id == "MPC_THR_HOVER").param_value == pytest.approx(0.4)
    finally:
        assert stop_vehicle(proc) == 0
    assert all(v > 0 for v in counts.values()), counts
    assert sum(counts.values()) <= 2 * N_DATAGRAMS  # a garbage datagram may also end in a truncated frame
    # one log line per kind at most once per second
    lines = re.findall(r"rejected input \((\w+)", vehicle_stderr(proc))
    for kind in set(lines):
        assert lines.count(kind) <= elapsed + 2, (kind, lines.count(kind), elapsed)
