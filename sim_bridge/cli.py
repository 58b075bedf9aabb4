"""Command line of the bundled vehicle: ``slungpilot sitl`` and ``python -m sim_bridge``."""

from __future__ import annotations

import argparse
import dataclasses
import logging
import os
import sys

from companion.config import dataclass_from_table, read_toml
from companion.core.kernel_cache import skip_numba_blas_probe
from companion.core.vehicle_params import VehicleParams, load_vehicle_params
from companion.core.wind import WindConfig
from companion.errors import ConfigError
from companion.mavlink_io.signing import load_key_file
from sim_bridge.imu import ImuNoise
from sim_bridge.sitl_config import SitlConfig
from sim_bridge.vehicle import SitlVehicle
from sim_bridge.world_cli import add_world_arguments, attached_scanner, scanner_from_args

log = logging.getLogger(__name__)

RT_PRIORITY_MAX = 99


def request_fifo(priority: int) -> bool:
    """Run this process ``SCHED_FIFO`` at ``priority`` (1..99), as PX4 runs its tasks on Linux; children fall
    back to normal scheduling. Returns False (and says why in the log) when refused: no CAP_SYS_NICE and
    ``ulimit -r`` below ``priority``, or not Linux."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, os.sched_param(priority))
    except (OSError, AttributeError) as exc:
        log.warning("SCHED_FIFO %d refused (%s; needs CAP_SYS_NICE or `ulimit -r` >= %d): the vehicle runs at "
                    "normal priority", priority, exc, priority)
        return False
    log.info("vehicle loop runs SCHED_FIFO at priority %d", priority)
    return True


def add_sitl_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the SITL vehicle's options to ``parser``."""
    g = parser.add_argument_group("SITL vehicle")
    _vehicle_arguments(g)
    _wind_arguments(g)
    _autopilot_arguments(g)
    _home_arguments(g)
    _link_arguments(g)
    _extra_arguments(g)
    add_world_arguments(parser)


def _vehicle_arguments(g: argparse._ArgumentGroup) -> None:
    """Which vehicle: instance, clock, control period, airframe and payload."""
    g.add_argument("--instance", type=int, default=0,
                   help="instance i: ports +i, vehicle sysid 1+i, payload sysid 2 (i=0) or 200+i")
    g.add_argument("--lockstep", action="store_true",
                   help="advance one control period per SET_ATTITUDE_TARGET on the onboard link (docs/sitl.md)")
    g.add_argument("--control-period-ms", type=int, default=4, help="control period, ms (multiple of 1 ms)")
    g.add_argument("--vehicle", metavar="FILE", help="vehicle TOML ([vehicle] table, config/vehicle.toml format)")
    g.add_argument("--payload-mass", "--payload-mass-kg", type=float, dest="payload_mass",
                   help="the TRUE payload mass m, kg (overrides --vehicle; the rotors' maximum thrust stays the "
                        "vehicle's max_thrust_n)")
    g.add_argument("--cable-length", "--cable-length-m", type=float, dest="cable_length",
                   help="the TRUE cable length l, m (overrides --vehicle)")


def _wind_arguments(g: argparse._ArgumentGroup) -> None:
    """The simulated wind (eq. 49, none, or turbulence from a file)."""
    g.add_argument("--wind", choices=["paper", "none", "turbulence"], default="paper",
                   help="wind model: eq. 49, none, or physical drag of a mean wind + Dryden turbulence + gust "
                        "(its settings from --wind-file)")
    g.add_argument("--wind-scale", type=float, default=1.0, help="wind scale factor (eq. 49)")
    g.add_argument("--wind-file", metavar="FILE",
                   help="TOML with a [wind] table (mission format: model, mean_speed_mps, direction_deg, intensity, "
                        "seed, gusts, drag areas; companion.core.wind.WindConfig); overrides --wind/--wind-scale")


def _autopilot_arguments(g: argparse._ArgumentGroup) -> None:
    """The autopilot's parameters: hover thrust, offboard timeout and loss hold, take-off altitude."""
    g.add_argument("--thr-hover", type=float, help="MPC_THR_HOVER (default 1/thrust_to_weight = 0.4)")
    g.add_argument("--airmode", type=int, choices=(0, 1, 2), default=2,
                   help="MC_AIRMODE: the mixer lifts the collective for torque in flight: 0 never (PX4's default), "
                        "1 for roll/pitch, 2 for yaw too (default 2: eq. 49 puts more yaw torque on the airframe than "
                        "hover thrust leaves; at 0 its heading wanders ~23 deg)")
    g.add_argument("--offboard-timeout", type=float, default=1.0,
                   help="COM_OF_LOSS_T: offboard setpoint loss timeout, s (sim time; PX4's default 1.0)")
    g.add_argument("--offboard-loss-hold", type=float, default=5.0,
                   help="COM_FAIL_ACT_T: after offboard loss hold this long, then land, s (PX4's default 5)")
    g.add_argument("--takeoff-alt", type=float, default=2.5, help="MIS_TAKEOFF_ALT, m above home")


def _home_arguments(g: argparse._ArgumentGroup) -> None:
    """Where home is (geodetic)."""
    g.add_argument("--home-lat", type=float, default=47.397742, help="home latitude, deg")
    g.add_argument("--home-lon", type=float, default=8.545594, help="home longitude, deg")
    g.add_argument("--home-alt", type=float, default=488.0, help="home altitude AMSL, m")
    g.add_argument("--home", metavar="LAT,LON,ALT",
                   help="home (and the local NED frame's origin, GPS_GLOBAL_ORIGIN): latitude, longitude (deg) and "
                        "altitude AMSL (m) in one flag; overrides --home-lat/--home-lon/--home-alt")


def _link_arguments(g: argparse._ArgumentGroup) -> None:
    """The two MAVLink links and the system ids, and how long to run."""
    g.add_argument("--address", default="127.0.0.1", help="address the vehicle binds to")
    g.add_argument("--onboard-port", type=int, help="onboard link bind port (default 14580+i)")
    g.add_argument("--onboard-remote", default=None, metavar="HOST:PORT",
                   help="where onboard telemetry goes until someone talks (default 127.0.0.1:14540+i; a given "
                        "port is used as is)")
    g.add_argument("--gcs-port", type=int, help="GCS link bind port (default 18570+i)")
    g.add_argument("--gcs-remote", default="127.0.0.1:14550", help="where GCS telemetry goes first")
    g.add_argument("--sysid", type=int, help="vehicle system id (default 1+i)")
    g.add_argument("--compid", type=int, default=1, help="vehicle component id")
    g.add_argument("--payload-sysid", type=int, help="payload system id (default 2, or 200+i for i>0)")
    g.add_argument("--duration", type=float, help="stop after this many simulated seconds")
    g.add_argument("--onboard-peer", metavar="HOST:PORT",
                   help="lock the onboard link to this peer from the start (default: the first sender)")
    g.add_argument("--gcs-peer", metavar="HOST:PORT", help="lock the GCS link to this peer from the start")


def _extra_arguments(g: argparse._ArgumentGroup) -> None:
    """A serial onboard link, scheduling, signing, pre-arm checks and the IMU's noise."""
    g.add_argument("--serial", metavar="DEVICE:BAUD",
                   help="the onboard link on this serial device instead of UDP (e.g. /dev/ttyUSB0:921600, or one end "
                        "of a pty pair: docs/companion.md); the GCS link stays UDP")
    g.add_argument("--rt-priority", type=int, default=0, metavar="N",
                   help="run the vehicle's loop SCHED_FIFO at priority N (1..99), as PX4 runs its tasks on Linux "
                        "(needs CAP_SYS_NICE or `ulimit -r` >= N, else it runs at normal priority and says so); "
                        "`fly --sitl --rt-priority N` passes it on. Real time only (ignored with --lockstep)")
    g.add_argument("--signing-key", metavar="FILE",
                   help="MAVLink 2 signing on both links with this key file (64 hex characters, or a passphrase "
                        "hashed with SHA-256 as MAVProxy does); unsigned, forged and replayed input is rejected")
    g.add_argument("--no-prearm-checks", action="store_true",
                   help="report SYS_STATUS as ArduCopter with ARMING_CHECK 0: the pre-arm bit present, not enabled, "
                        "never healthy (arming itself is unchanged)")
    g.add_argument("--imu-noise-scale", type=float, default=1.0,
                   help="multiplier of the IMU noise and bias random walk (SIM_IMU_NSCALE; 0 = ideal)")
    g.add_argument("--imu-seed", type=int, default=0, help="seed of the IMU noise generator")


def _hostport(text: str, flag: str, shift: int) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    try:
        return host or "127.0.0.1", int(port) + shift
    except ValueError:
        raise ConfigError(f"{flag}: expected HOST:PORT, got {text!r}") from None


def _home(args: argparse.Namespace) -> tuple[float, float, float]:
    """(latitude deg, longitude deg, altitude AMSL m) from --home or --home-lat/--home-lon/--home-alt."""
    if not getattr(args, "home", None):
        return args.home_lat, args.home_lon, args.home_alt
    try:
        lat, lon, alt = (float(p) for p in args.home.split(","))
    except ValueError:
        raise ConfigError(f"--home: expected LAT,LON,ALT (deg, deg, m), got {args.home!r}") from None
    if not (abs(lat) <= 90.0 and abs(lon) <= 180.0 and -500.0 <= alt <= 10_000.0):
        raise ConfigError(f"--home: latitude in ±90°, longitude in ±180°, altitude in [-500, 10000] m, got {args.home}")
    return lat, lon, alt


def _wind_from_args(args: argparse.Namespace) -> WindConfig:
    """The wind: ``--wind-file``'s [wind] table if given, else --wind/--wind-scale."""
    wind_file = getattr(args, "wind_file", None)
    if wind_file:
        data = read_toml(wind_file)
        if set(data) - {"wind"}:
            raise ConfigError(f"{wind_file}: expected only a [wind] table, got {sorted(data)}")
        return dataclass_from_table(WindConfig, data.get("wind", {}), where=f"{wind_file}: [wind]")
    return dataclass_from_table(WindConfig, {"model": args.wind, "scale": args.wind_scale}, where="--wind-scale:")


def _serial_spec(text: str) -> tuple[str, int]:
    from sim_bridge.link import parse_serial_spec

    try:
        return parse_serial_spec(text)
    except ValueError as exc:
        raise ConfigError(f"--serial: {exc}") from None


def config_from_args(args: argparse.Namespace) -> SitlConfig:
    """Build and validate the :class:`SitlConfig`; raises :class:`ConfigError` naming the flag or key."""
    i = args.instance
    if not 0 <= i <= 54:
        raise ConfigError(f"--instance: must be in 0..54, got {i}")
    params = load_vehicle_params(args.vehicle) if args.vehicle else VehicleParams()
    declared_hover_n = params.hover_thrust_n
    over = {}
    if args.payload_mass is not None:
        over["m"] = args.payload_mass
    if args.cable_length is not None:
        over["l"] = args.cable_length
    if over:
        params = dataclass_from_table(VehicleParams, over, where="--payload-mass/--cable-length:", base=params)
    wind = _wind_from_args(args)
    key = load_key_file(args.signing_key) if args.signing_key else None
    cfg = SitlConfig(
        params=params,
        wind=wind,
        lockstep=args.lockstep,
        control_period_us=int(args.control_period_ms) * 1000,
        thr_hover=args.thr_hover,
        offboard_timeout_s=args.offboard_timeout,
        fail_act_t_s=args.offboard_loss_hold,
        air_mode=args.airmode,
        onboard_peer=_hostport(args.onboard_peer, "--onboard-peer", 0) if args.onboard_peer else None,
        gcs_peer=_hostport(args.gcs_peer, "--gcs-peer", 0) if args.gcs_peer else None,
        onboard_serial=_serial_spec(args.serial) if getattr(args, "serial", None) else None,
        signing_key=key,
        prearm_checks=not args.no_prearm_checks,
        imu=ImuNoise(scale=args.imu_noise_scale, seed=args.imu_seed),
        takeoff_alt_m=args.takeoff_alt,
        home=_home(args),
        onboard_bind=(args.address, args.onboard_port if args.onboard_port is not None else 14580 + i),
        onboard_remote=(_hostport(args.onboard_remote, "--onboard-remote", 0) if args.onboard_remote
                        else ("127.0.0.1", 14540 + i)),
        gcs_bind=(args.address, args.gcs_port if args.gcs_port is not None else 18570 + i),
        gcs_remote=_hostport(args.gcs_remote, "--gcs-remote", 0),
        sysid=args.sysid if args.sysid is not None else 1 + i,
        compid=args.compid,
        payload_sysid=args.payload_sysid if args.payload_sysid is not None else (2 if i == 0 else 200 + i),
        duration_s=args.duration,
        thrust_ref_n=declared_hover_n if "m" in over else None,  # the thrust calibration is the declared vehicle's
    )
    try:
        cfg.validate()
        if not (0.0 < cfg.offboard_timeout_s <= 60.0):
            raise ValueError("offboard_timeout: must be in (0, 60] s")
    except ValueError as exc:
        raise ConfigError(f"sitl options: {exc}") from None
    return dataclasses.replace(cfg)


def run_sitl(args: argparse.Namespace) -> int:
    """Run the vehicle until SIGINT/SIGTERM or --duration; prints ``SITL READY ...`` once bound."""
    skip_numba_blas_probe()  # before the first kernel: the settings' eq. 49 check already runs one
    cfg = config_from_args(args)
    scanner = scanner_from_args(args)  # a bad world file or LiDAR flag is refused before anything starts

    def ready(v: SitlVehicle) -> None:
        bind = cfg.onboard_bind
        onboard = f"serial:{cfg.onboard_serial[0]}" if cfg.onboard_serial else f"{bind[0]}:{bind[1]}"
        print(f"SITL READY onboard={onboard} "
              f"gcs={cfg.gcs_bind[0]}:{cfg.gcs_bind[1]} sysid={cfg.sysid}", flush=True)

    if not 0 <= args.rt_priority <= RT_PRIORITY_MAX:
        raise ConfigError(f"--rt-priority: must be in 0..{RT_PRIORITY_MAX} (0 = normal scheduling)")
    try:
        vehicle = SitlVehicle(cfg)  # start-up work (model kernels) at normal priority
        with attached_scanner(vehicle, scanner, args):
            if args.rt_priority and not args.lockstep:  # lockstep runs flat out: FIFO would starve the rest
                request_fifo(args.rt_priority)
            return vehicle.run(ready_cb=ready)
    except OSError as exc:
        raise ConfigError(f"cannot open the SITL links (ports, --serial device): {exc}") from None
    except KeyboardInterrupt:
        return 0


def main(argv: list[str] | None = None) -> int:
    """``python -m sim_bridge``: the same as ``slungpilot sitl``."""
    parser = argparse.ArgumentParser(prog="python -m sim_bridge", description="The bundled SITL vehicle.")
    parser.add_argument("-v", "--verbose", action="count", default=0)
    add_sitl_arguments(parser)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING - 10 * min(args.verbose, 2),
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        return run_sitl(args)
    except ConfigError as exc:
        print(f"sim_bridge: error: {exc}", file=sys.stderr)
        return exc.exit_code
