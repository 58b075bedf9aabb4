"""fly --sitl's launcher: free ports without races, retry when another process took the vehicle's port."""

import asyncio
import contextlib
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from companion.core.mission import load_mission
from companion.launch.sitl import SitlProcess

pytestmark = pytest.mark.paired  # wall clock, light: may run beside one other such test (tests/conftest.py)

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


_HOLDER = """
import asyncio, sys
from pathlib import Path
from companion.launch.sitl import SitlProcess
from companion.core.mission import load_mission

async def main():
    sitl = SitlProcess(load_mission(Path(sys.argv[1])), Path(sys.argv[2]))
    await sitl.__aenter__()  # never left: the test kills this process
    print(sitl.proc.pid, flush=True)
    await asyncio.sleep(120)

asyncio.run(main())
"""


def test_the_vehicle_dies_with_the_process_that_started_it_even_by_sigkill(tmp_path):
    """The launcher's process SIGKILLed (no __aexit__ runs): its lockstep vehicle, in a session of its own and
    waiting for step markers, is gone within 5 s instead of waiting for ever (issue 25)."""
    psutil = pytest.importorskip("psutil")
    holder = subprocess.Popen([sys.executable, "-c", _HOLDER, str(FOREST), str(tmp_path)], stdout=subprocess.PIPE,
                              text=True, start_new_session=True)
    vehicle = None
    try:
        vehicle = psutil.Process(int(holder.stdout.readline()))
        assert vehicle.ppid() == holder.pid and vehicle.status() != psutil.STATUS_ZOMBIE
        holder.kill()
        holder.wait(5)
        with contextlib.suppress(psutil.NoSuchProcess, psutil.TimeoutExpired):
            vehicle.wait(5)
        with contextlib.suppress(psutil.NoSuchProcess):
            assert vehicle.status() == psutil.STATUS_ZOMBIE, f"the vehicle outlived its launcher: {vehicle}"
    finally:
        holder.kill()
        holder.wait(5)
        holder.stdout.close()
        if vehicle is not None:
            with contextlib.suppress(psutil.Error):
                vehicle.kill()
