"""Real autopilots in software: PX4 SITL with the SIH quadrotor and ArduCopter SITL with its simulated slung
payload, started from binaries built from their own sources (docs/autopilots.md says how), for the integration
runs of ``tests/test_real_autopilots.py`` and the fault scenarios of :mod:`lab.faults`.

Where the binaries are: ``$SLUNGPILOT_PX4_BUILD`` (PX4's ``build/px4_sitl_default`` folder) and
``$SLUNGPILOT_ARDUPILOT`` (an ArduPilot checkout with ``build/sitl/bin/arducopter``). The integration runs are
opt-in: without the variable the tests skip and say so, so the CI run (which must stay under 15 minutes on two
cores) never starts a real autopilot by accident. :func:`find_px4` / :func:`find_arducopter` say why.

Each start is from a fresh state (its own working folder). Only parameters that configure the *simulation*
are set here (the payload's mass, cable length and system id); everything the vehicle needs, the companion sets
itself and says so (e.g. ArduCopter's GUID_OPTIONS).
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

from companion import proclife


def find_px4() -> tuple[Path | None, str]:
    """(PX4's build folder, "") or (None, why it is not usable)."""
    if not os.environ.get("SLUNGPILOT_PX4_BUILD"):
        return None, "SLUNGPILOT_PX4_BUILD is not set (PX4 SIH integration runs are opt-in; docs/autopilots.md)"
    build = Path(os.environ["SLUNGPILOT_PX4_BUILD"])
    if not (build / "bin" / "px4").is_file() or not (build / "etc").is_dir():
        return None, f"no PX4 SITL build at {build} (set SLUNGPILOT_PX4_BUILD; docs/autopilots.md)"
    return build, ""


def find_arducopter() -> tuple[Path | None, str]:
    """(the ArduPilot checkout, "") or (None, why it is not usable)."""
    if not os.environ.get("SLUNGPILOT_ARDUPILOT"):
        return None, "SLUNGPILOT_ARDUPILOT is not set (ArduCopter SITL integration runs are opt-in; docs/autopilots.md)"
    root = Path(os.environ["SLUNGPILOT_ARDUPILOT"])
    if not (root / "build" / "sitl" / "bin" / "arducopter").is_file():
        return None, f"no ArduCopter SITL at {root}/build/sitl/bin/arducopter (set SLUNGPILOT_ARDUPILOT)"
    return root, ""


def start_px4_sih(workdir: Path, instance: int, *, speed_factor: float = 1.0) -> subprocess.Popen:
    """PX4 SITL + SIH quadrotor, instance ``instance``: system id 1+I, its onboard link sends to
    127.0.0.1:14540+I (the companion listens there). In its own session; stop with SIGTERM to the group."""
    build, why = find_px4()
    if build is None:
        raise FileNotFoundError(why)
    run = workdir / f"px4-{instance}"
    shutil.rmtree(run, ignore_errors=True)
    run.mkdir(parents=True)
    for stale in (Path(f"/tmp/px4_lock-{instance}"), Path(f"/tmp/px4-sock-{instance}")):
        stale.unlink(missing_ok=True)
    env = {**os.environ, "PX4_SYS_AUTOSTART": "10040", "PX4_SIMULATOR": "sihsim", "PX4_SIM_MODEL": "sihsim_quadx",
           "PX4_SIM_SPEED_FACTOR": f"{speed_factor:g}"}
    log = (run / "px4.log").open("w")
    return subprocess.Popen([str(build / "bin" / "px4"), "-d", "-i", str(instance), "-w", str(run),
                             str(build / "etc")], cwd=run, env=env, stdout=log, stderr=subprocess.STDOUT,
                            stdin=subprocess.DEVNULL, start_new_session=True, preexec_fn=proclife.preexec())


ARDUCOPTER_HOME = "-35.363261,149.165230,584,353"  # ArduPilot's CMAC default


def start_arducopter(workdir: Path, port: int, *, instance: int = 0, payload: bool = True, mass_kg: float = 0.25,
                     cable_m: float = 1.0, speedup: float = 1.0, home: str = ARDUCOPTER_HOME,
                     payload_drag: float = 1.0) -> subprocess.Popen:
    """ArduCopter SITL (quad) sending MAVLink 2 to 127.0.0.1:``port``, system id 1+I; with ``payload`` its
    simulated slung payload (system 2, component 35; only instance 0 can have one: it dials SERIAL2 of -I0)."""
    root, why = find_arducopter()
    if root is None:
        raise FileNotFoundError(why)
    run = workdir / f"arducopter-{instance}"
    shutil.rmtree(run, ignore_errors=True)
    run.mkdir(parents=True)
    parm = run / "simulation.parm"
    lines = [f"SIM_SLUP_ENABLE {1 if payload else 0}"]
    if payload:
        lines += [f"SIM_SLUP_WEIGHT {mass_kg:g}", f"SIM_SLUP_LINELEN {cable_m:g}", "SIM_SLUP_SYSID 2",
                  f"SIM_SLUP_DRAG {payload_drag:g}"]
    parm.write_text("\n".join(lines) + "\n")
    defaults = f"{root / 'Tools/autotest/default_params/copter.parm'},{parm}"
    log = (run / "arducopter.log").open("w")
    return subprocess.Popen([str(root / "build/sitl/bin/arducopter"), "--model", "quad", "--speedup", f"{speedup:g}",
                             "-I", str(instance), "--wipe", "--home", home, "--defaults",
                             defaults, "--sysid", str(1 + instance), "--serial0", f"udpclient:127.0.0.1:{port}"],
                            cwd=run, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                            start_new_session=True, preexec_fn=proclife.preexec())
