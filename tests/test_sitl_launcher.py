"""fly --sitl's launcher: free ports without races, retry when another process took the vehicle's port."""

import asyncio
import socket
from pathlib import Path

from companion.cli.sitl_launcher import SitlProcess
from companion.core.mission import load_mission

FOREST = Path(__file__).resolve().parents[1] / "config" / "missions" / "forest.toml"


def test_vehicle_port_taken_meanwhile_is_retried_and_companion_port_is_reserved(tmp_path):
    async def main() -> tuple[str, int, int]:
        sitl = SitlProcess(load_mission(FOREST), tmp_path)
        squatter = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        squatter.bind(("127.0.0.1", sitl.vehicle_port))  # another process wins the race for that port
        taken = sitl.vehicle_port
        try:
            async with sitl:
                ready, port = sitl.ready_line, sitl.vehicle_port
                # the companion's port is held by our socket, so nobody else can bind it
                probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                try:
                    probe.bind(("127.0.0.1", sitl.companion_port))
                    reserved = 0
                except OSError:
                    reserved = 1
                finally:
                    probe.close()
        finally:
            squatter.close()
        return ready, port if port != taken else -1, reserved

    ready, port, reserved = asyncio.run(main())
    assert ready.startswith("SITL READY") and f":{port} " in ready
    assert port > 0 and reserved == 1
