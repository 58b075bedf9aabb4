"""The fault suite's lossy UDP proxy on its own: real sockets on loopback, a real subprocess."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

from lab.procs import free_udp_port

ROOT = Path(__file__).resolve().parents[1]


def _sock() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    s.settimeout(5.0)
    return s


def test_a_vehicle_that_dials_out_from_an_ephemeral_port_gets_the_answers():
    """``--vehicle first`` (ArduCopter SITL's udpclient): the proxy answers whoever sent the first vehicle-side
    datagram; what the companion sent before that has nowhere to go and is counted apart; both directions delayed,
    counted on exit."""
    companion, vehicle = _sock(), _sock()
    vside = free_udp_port()
    proxy = subprocess.Popen(
        [sys.executable, "-m", "lab.udp_proxy", "--vehicle", "first", "--companion",
         f"127.0.0.1:{companion.getsockname()[1]}", "--listen-vehicle-side", str(vside), "--delay-ms", "20"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proxy.stdout is not None
        ready = proxy.stdout.readline()
        assert ready.startswith("PROXY READY")
        companion.sendto(b"too early", ("127.0.0.1", int(ready.split()[2])))
        time.sleep(0.2)  # released after its 20 ms, before the vehicle has spoken
        vehicle.sendto(b"telemetry", ("127.0.0.1", vside))
        data, proxy_addr = companion.recvfrom(100)
        assert data == b"telemetry"
        companion.sendto(b"setpoint", proxy_addr)
        data, _ = vehicle.recvfrom(100)
        assert data == b"setpoint"
    finally:
        proxy.send_signal(signal.SIGTERM)
        out, _ = proxy.communicate(timeout=10)
        companion.close()
        vehicle.close()
    counts = json.loads(out.strip().splitlines()[-1])
    assert counts["to_companion"] == 1 and counts["to_vehicle"] == 1 and counts["dropped"] == 0
    assert counts["no_vehicle"] == 1
