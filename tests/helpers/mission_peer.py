"""Test helper process: an autopilot's mission service over real UDP (pymavlink), misbehaving on request.

Usage: python mission_peer.py COMPANION_PORT SPEC.json

It sends HEARTBEAT (MAV_AUTOPILOT_PX4 unless ``autopilot`` says otherwise) to 127.0.0.1:COMPANION_PORT every
0.2 s, answers MAV_CMD_REQUEST_MESSAGE for HOME_POSITION and GPS_GLOBAL_ORIGIN, and serves MISSION_REQUEST_LIST /
MISSION_REQUEST_INT for the mission and the fence of SPEC. SPEC: ``{"home": [lat, lon, alt_amsl], "mission":
[items], "fence": [items], "mode": ..., "count": n (claimed instead of the real count), "stall_at": k (item k and
later are never sent), "no_home": true}`` with items ``{"frame", "command", "params": [4], "x", "y", "z"}`` (NaN as
the string "nan"). Modes: ``normal``; ``duplicate`` (every item sent twice); ``out_of_order`` (the first request for
each item k is answered with item k+1 first, then k). Every MISSION_ACK received is printed as ``ACK <type>
<result>`` and every request as ``REQ <type> <seq>`` (stdout, flushed).
"""

import json
import socket
import sys
import time

from pymavlink.dialects.v20 import common as M


class _Out:
    def __init__(self, sock: socket.socket, addr: tuple[str, int]) -> None:
        self.sock, self.addr = sock, addr

    def write(self, buf: bytes) -> None:
        self.sock.sendto(bytes(buf), self.addr)


def _num(v):
    return float("nan") if v == "nan" else v


def main() -> None:
    port = int(sys.argv[1])
    with open(sys.argv[2]) as f:
        spec = json.load(f)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(0.05)
    out = _Out(sock, ("127.0.0.1", port))
    mav = M.MAVLink(out, srcSystem=1, srcComponent=1)
    parser = M.MAVLink(None)
    lists = {0: spec.get("mission", []), 1: spec.get("fence", [])}
    mode = spec.get("mode", "normal")
    lat, lon, alt = spec.get("home", [47.397742, 8.545594, 488.0])
    asked: set[tuple[int, int]] = set()
    next_hb = 0.0
    print("PEER READY", flush=True)

    def send_item(mtype: int, seq: int) -> None:
        it = lists[mtype][seq]
        p = [_num(v) for v in it.get("params", [0, 0, 0, 0])]
        mav.mission_item_int_send(255, 191, seq, it["frame"], it["command"], 0, 1, *p, int(it["x"]), int(it["y"]),
                                  _num(it["z"]), mtype)

    while True:
        now = time.monotonic()
        if now >= next_hb:
            next_hb = now + 0.2
            mav.heartbeat_send(M.MAV_TYPE_QUADROTOR, spec.get("autopilot", M.MAV_AUTOPILOT_PX4), 0, 0,
                               M.MAV_STATE_STANDBY)
        try:
            data, addr = sock.recvfrom(65536)
        except TimeoutError:
            continue
        out.addr = addr
        for m in parser.parse_buffer(data) or []:
            t = m.get_type()
            if t == "COMMAND_LONG" and m.command == M.MAV_CMD_REQUEST_MESSAGE and not spec.get("no_home"):
                if int(m.param1) == 242:
                    mav.home_position_send(round(lat * 1e7), round(lon * 1e7), round(alt * 1000), 0.0, 0.0, 0.0,
                                           [1, 0, 0, 0], 0, 0, 0, 0)
                elif int(m.param1) == 49:
                    mav.gps_global_origin_send(round(lat * 1e7), round(lon * 1e7), round(alt * 1000), 0)
            elif t == "MISSION_REQUEST_LIST":
                n = len(lists.get(m.mission_type, []))
                if m.mission_type == 0 and "count" in spec:
                    n = spec["count"]
                mav.mission_count_send(255, 191, n, m.mission_type)
            elif t == "MISSION_REQUEST_INT":
                mtype, seq = m.mission_type, m.seq
                print(f"REQ {mtype} {seq}", flush=True)
                if mtype == 0 and seq >= spec.get("stall_at", 1 << 30):
                    continue
                if seq >= len(lists.get(mtype, [])):
                    continue
                if mode == "out_of_order" and (mtype, seq) not in asked and seq + 1 < len(lists[mtype]):
                    send_item(mtype, seq + 1)
                asked.add((mtype, seq))
                send_item(mtype, seq)
                if mode == "duplicate":
                    send_item(mtype, seq)
            elif t == "MISSION_ACK":
                print(f"ACK {m.mission_type} {m.type}", flush=True)


if __name__ == "__main__":
    main()
