"""The ``fly`` command's options and exit codes, apart from the flight itself so ``--help`` answers at once."""

from __future__ import annotations

import argparse
from pathlib import Path

from companion.autopilots.profile import PROFILE_NAMES
from companion.cli.viz_cmds import add_view_arguments
from companion.config import shipped_config
from companion.estimation import SWING_INPUTS
from companion.zenoh_io.session import add_zenoh_arguments

DEFAULT_MISSION = shipped_config("missions/forest.toml")
DEFAULT_GAINS = shipped_config("controller.toml")
PLANNERS = ("traditional", "improved", "safe", "shaped", "none")
CONTROLLERS = ("smc_ff", "smc", "pid")

#: ``slungpilot fly`` exit codes by outcome (also in --help and the README); 2 is a broken file or flag.
EXIT_CODES = {
    "completed": 0,
    "timeout": 1, "no_route": 1,
    "no_vehicle": 3, "link_lost": 3,
    "not_ready": 4, "refused": 4,
    "preempted": 5,
    "stale_telemetry": 6, "invalid_estimate": 6, "tick_errors": 6, "diverged": 6,
    "aborted": 130,
}
EXIT_HELP = ("exit codes: 0 goal reached; 1 mission not completed (timeout, no route); 2 broken mission file or "
             "flag; 3 no vehicle or link lost; 4 the autopilot was not ready or refused to arm / give control; "
             "5 preempted (someone else took the vehicle); 6 failsafe (stale telemetry, invalid estimate, failing "
             "control ticks, the vehicle diverging from the reference); 130 interrupted (Ctrl-C/SIGTERM: held and "
             "landed); 1 for anything else")



def add_fly_arguments(p: argparse.ArgumentParser) -> None:
    """The ``fly`` options."""
    _mission_and_link_arguments(p)
    _bundled_vehicle_arguments(p)
    _flight_arguments(p)
    _trust_arguments(p)
    _loop_arguments(p)
    _output_arguments(p)
    add_zenoh_arguments(p, "companion")
    add_view_arguments(p)


def _mission_and_link_arguments(p: argparse.ArgumentParser) -> None:
    """The mission and the autopilot link (where, and which instance)."""
    p.add_argument("--mission", default=str(DEFAULT_MISSION), metavar="FILE|NAME|autopilot",
                   help="mission TOML file, or the name of a shipped mission (`slungpilot missions` lists them; "
                        "default: forest, the paper's Table 2 forest), or `autopilot`: download and fly the mission "
                        "and geofence the operator uploaded to the autopilot (take-off, waypoints with holds, land "
                        "or return; anything else is refused before take-off), with --base-mission's planner, "
                        "controller, vehicle, payload and obstacles")
    p.add_argument("--base-mission", default=None, metavar="FILE|NAME",
                   help="with --mission autopilot: the mission file that gives everything but the route and the "
                        "fence (planner, controller, vehicle, payload, wind, obstacles; default: forest)")
    p.add_argument("--connect", default=None,
                   help="autopilot link: udpin://HOST:PORT (listen; default udpin://0.0.0.0:14540, PX4's onboard "
                        "link, +N with --instance N), udpout://HOST:PORT, serial:///dev/ttyACM0:921600 (a TELEM "
                        "port), tcp://HOST:PORT (connect) or tcpin://HOST:PORT (listen; docs/companion.md, Links); "
                        "not with --sitl (it picks free ports)")
    p.add_argument("--instance", type=int, default=0, metavar="N",
                   help="run the N-th of several companions on one machine: the default MAVLink port 14540+N and "
                        "Zenoh port 7447+N, and with --sitl the bundled vehicle's instance N (system id 1+N), "
                        "as `slungpilot sitl --instance N`")


def _bundled_vehicle_arguments(p: argparse.ArgumentParser) -> None:
    """The bundled SITL vehicle: start it, its clock, its link, what it really carries, its world."""
    p.add_argument("--sitl", action="store_true",
                   help="start the bundled SITL vehicle on free local ports (lockstep unless --realtime)")
    p.add_argument("--realtime", action="store_true", help="with --sitl: fly in real time to watch it live")
    p.add_argument("--serial", action="store_true",
                   help="with --sitl: the vehicle's onboard link over a pseudo-terminal pair (serial://, nominal "
                        "921600 baud: a pty has no rate limit; socat if on PATH, else lab/pty_pair.py) instead of UDP")
    p.add_argument("--true-payload-mass-kg", type=float, default=None, metavar="KG",
                   help="with --sitl: the payload the bundled vehicle really carries, kg (the mission's is what the "
                        "companion is told; a mis-declared payload)")
    p.add_argument("--true-cable-length-m", type=float, default=None, metavar="M",
                   help="with --sitl: the bundled vehicle's real cable length, m (the mission's is the declared one)")
    p.add_argument("--sitl-airmode", type=int, choices=(0, 1, 2), default=None, metavar="0|1|2",
                   help="with --sitl: the bundled vehicle's MC_AIRMODE (PX4's: 0 never lifts the collective for "
                        "torque, as a stock PX4; 1 for roll/pitch; 2, the default, also for yaw, which eq. 49 needs "
                        "above scale 1.02; docs/sitl.md)")
    p.add_argument("--world", default=None, metavar="FILE|NAME",
                   help="with --sitl: the trunks that stand in the simulated world (a world TOML, or a shipped one: "
                        "forest, forest_crossing), which the vehicle's LiDAR sees; the report scores clearance "
                        "against them (docs/sitl.md)")


def _flight_arguments(p: argparse.ArgumentParser) -> None:
    """How the flight is flown: perception, lockstep, planner, controller, gains, vehicle profile, start."""
    p.add_argument("--perception", choices=("auto", "on", "off"), default="auto",
                   help="map trunks from the vehicle's range scans (OBSTACLE_DISTANCE, Zenoh scans) for the planner: "
                        "auto (default) starts at the first scan, off ignores scans (docs/companion.md)")
    p.add_argument("--lockstep", action="store_true",
                   help="the vehicle is a lockstep simulator (driven by its SYSTEM_TIME step markers)")
    p.add_argument("--planner", choices=PLANNERS, help="override the mission's")
    p.add_argument("--controller", choices=CONTROLLERS, help="override the mission's")
    p.add_argument("--gains", type=Path, default=DEFAULT_GAINS, help="controller/planner gains TOML")
    p.add_argument("--profile", choices=PROFILE_NAMES, default=None,
                   help="vehicle profile: thrust mapping (newtons → 0..1) and flight-mode family (default: "
                        "bundled with --sitl, else chosen from the autopilot's HEARTBEAT: px4 or ardupilot)")
    p.add_argument("--hover-thrust", type=float, default=None,
                   help="normalized hover thrust of your vehicle (PX4 MPC_THR_HOVER); overrides the profile's")
    p.add_argument("--start-here", action="store_true",
                   help="fly the mission from where the vehicle stands (its start point moved under it); without "
                        "it, mission coordinates are relative to home and a vehicle more than 1 m from the "
                        "mission's start is refused")


def _trust_arguments(p: argparse.ArgumentParser) -> None:
    """What the companion trusts and changes: MAVLink signing, the ground station, parameter writes."""
    p.add_argument("--signing-key", type=Path, default=None, metavar="FILE",
                   help="MAVLink 2 signing with the key in FILE (64 hex characters, or a passphrase hashed as MAVProxy "
                        "does; `slungpilot keygen FILE` makes one): everything sent is signed, unsigned, forged and "
                        "replayed frames are dropped and counted; with --sitl the bundled vehicle gets the same key. "
                        "docs/companion.md: sharing it with PX4/ArduPilot (SETUP_SIGNING)")
    p.add_argument("--accept-unsigned", type=int, action="append", default=[], metavar="SYSID",
                   help="with --signing-key: read this system's unsigned frames all the same (repeatable; e.g. 2, "
                        "ArduCopter SITL's slung payload, which ArduPilot forwards unsigned); the report counts them")
    p.add_argument("--gcs-sysid", type=int, default=None, metavar="N",
                   help="obey pause/resume/land/return commands from this ground station's system id only (others "
                        "are answered DENIED and counted); with --signing-key, without it no GCS is obeyed")
    p.add_argument("--no-param-writes", action="store_true",
                   help="never change an autopilot parameter: refuse the vehicle instead (ArduCopter needs "
                        "GUID_OPTIONS bit 3, which the companion otherwise sets; see docs/autopilots.md)")


def _loop_arguments(p: argparse.ArgumentParser) -> None:
    """The control loop (rate, priority) and its swing inputs."""
    p.add_argument("--rate-hz", type=float, default=250.0, help="outer-loop rate (Hz)")
    p.add_argument("--rt-priority", type=int, default=0, metavar="N",
                   help="run the control thread SCHED_FIFO at priority N (1..99) while flying, as PX4 runs its "
                        "loops on Linux, so other processes cannot preempt a tick; needs CAP_SYS_NICE or "
                        "`ulimit -r` >= N, else the flight goes on at normal priority and the report says so. "
                        "Real time only (ignored in lockstep, which has no deadlines). Recommended on a shared or "
                        "busy computer (default 0: normal scheduling)")
    p.add_argument("--payload-sysid", type=int, default=None,
                   help="MAVLink system id of the payload's own stream (default 2; 200+N with --sitl --instance N)")
    p.add_argument("--swing-input", choices=SWING_INPUTS, default="auto",
                   help="swing measurement to use: auto = cable-angle sensor (DEBUG_FLOAT_ARRAY 'SWING'), else the "
                        "payload's position stream, else none (no feed-forward, full-cable envelope)")


def _output_arguments(p: argparse.ArgumentParser) -> None:
    """Where the run goes, what it writes, how it ends, and how long to wait for the autopilot."""
    p.add_argument("--run-dir", type=Path, default=None, help="where to write the run folder")
    p.add_argument("--report", type=Path, default=None, help="also write the JSON report to this file")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    p.add_argument("--no-land", action="store_true", help="hold at the goal instead of landing")
    p.add_argument("--no-land-on-abort", action="store_true", help="on Ctrl-C hold instead of landing")
    p.add_argument("--heartbeat-timeout", type=float, default=60.0,
                   help="seconds to wait for the autopilot's first HEARTBEAT (default 60)")
    p.add_argument("--ready-timeout", type=float, default=90.0,
                   help="seconds to wait for telemetry and the autopilot's ready-to-arm (default 90: PX4 SITL "
                        "can take ~40 s after boot)")
