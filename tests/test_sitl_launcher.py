"""fly --sitl's launcher: free ports without races, retry when another process took the vehicle's port."""

import asyncio
import contextlib
import socket
import subprocess
import sys
import time
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


# ------------------------------------------------------------------------------------ a vehicle forked ahead
_FORKED = """
import asyncio, json, os, socket, sys
from pathlib import Path
from companion.core.mission import load_mission
from companion.errors import LinkError
from companion.launch.sitl import SitlProcess
from sim_bridge.prefork import PreforkedVehicle, can_fork

async def main(case):
    assert can_fork()
    fork = PreforkedVehicle()
    sitl = SitlProcess(load_mission(Path(sys.argv[1])), Path(sys.argv[2]), fork=fork,
                       extra_args=["--airmode", "3"] if case == "refused" else [])
    if case == "killed":
        await sitl.__aenter__()  # never left: the test kills this process
        print(json.dumps({"vehicle": sitl.proc.pid, "spare": PreforkedVehicle().pid}), flush=True)
        await asyncio.sleep(120)
    if case == "refused":
        try:
            async with sitl:
                return {"error": None}
        except LinkError as exc:
            return {"error": str(exc)}
    if case == "dead":
        os.kill(fork.pid, 9)
        os.waitid(os.P_PID, fork.pid, os.WEXITED | os.WNOWAIT)  # dead, not yet reaped
        async with sitl:
            try:
                os.waitpid(fork.pid, os.WNOHANG)
                reaped = False
            except ChildProcessError:
                reaped = True
            return {"ready": sitl.ready_line, "fresh": sitl.proc.pid != fork.pid, "reaped": reaped}
    squatter = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    squatter.bind(("127.0.0.1", sitl.vehicle_port))  # the forked vehicle cannot bind: a fresh one takes over
    async with sitl:
        return {"ready": sitl.ready_line, "port_changed": sitl.vehicle_port != squatter.getsockname()[1],
                "forked_pid_used": sitl.proc.pid == fork.pid}

print(json.dumps(asyncio.run(main(sys.argv[3]))), flush=True)
"""


def _forked(tmp_path: Path, case: str) -> dict:
    out = subprocess.run([sys.executable, "-c", _FORKED, str(FOREST), str(tmp_path), case], capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 0, out.stderr[-3000:]
    import json

    return json.loads(out.stdout.splitlines()[-1])


def test_a_forked_vehicle_that_cannot_bind_its_port_is_replaced_by_a_fresh_one(tmp_path):
    r = _forked(tmp_path, "taken")
    assert r["ready"].startswith("SITL READY") and r["port_changed"] and not r["forked_pid_used"]


def test_a_forked_vehicle_found_dead_is_reaped_and_replaced_by_a_fresh_one(tmp_path):
    r = _forked(tmp_path, "dead")
    assert r["ready"].startswith("SITL READY") and r["fresh"] and r["reaped"], r


def test_a_forked_vehicle_that_refuses_its_arguments_says_why(tmp_path):
    r = _forked(tmp_path, "refused")
    assert "exited before it was ready: argument --airmode: invalid choice: 3" in r["error"], r["error"]


def test_a_forked_vehicle_and_an_unlaunched_one_die_with_their_process_even_by_sigkill(tmp_path):
    """As the exec'd vehicle above: the launcher SIGKILLed, its forked vehicle (flying) and a spare fork (waiting
    for its arguments) are gone within 5 s."""
    psutil = pytest.importorskip("psutil")
    holder = subprocess.Popen([sys.executable, "-c", _FORKED, str(FOREST), str(tmp_path), "killed"],
                              stdout=subprocess.PIPE, text=True, start_new_session=True)
    kids = []
    try:
        import json

        pids = json.loads(holder.stdout.readline())
        kids = [psutil.Process(pids["vehicle"]), psutil.Process(pids["spare"])]
        end = time.monotonic() + 5.0  # the spare names itself once it runs
        while not all(k.name() == "sim_bridge" for k in kids) and time.monotonic() < end:
            time.sleep(0.02)
        assert all(k.name() == "sim_bridge" and k.ppid() == holder.pid for k in kids)
        assert " ".join(kids[0].cmdline()).startswith("python -m sim_bridge --onboard-port ")  # as ps shows it
        holder.kill()
        holder.wait(5)
        _gone, alive = psutil.wait_procs(kids, timeout=5)
        assert alive == [] or all(k.status() == psutil.STATUS_ZOMBIE for k in alive), alive
    finally:
        holder.kill()
        holder.wait(5)
        holder.stdout.close()
        for k in kids:
            with contextlib.suppress(psutil.Error):
                k.kill()
