"""The ``sitl`` flags of the world and its LiDAR (``--world``, ``--lidar-*``, ``--zenoh-scan*``), and attaching the
LiDAR to a vehicle for the length of its run (with the Zenoh session, when asked, opened and closed around it).

Without ``--world`` nothing is attached: the vehicle runs exactly as it did before worlds existed (a lockstep
flight's log stays bit-identical). docs/sitl.md, *A world and its LiDAR*.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
from collections.abc import Iterator
from typing import Any

from companion.errors import ConfigError, LinkError
from sim_bridge.lidar import Lidar, LidarConfig
from sim_bridge.scan_sender import LAYOUTS, LIDAR_COMPID, ScanSender, ZenohScanPublisher
from sim_bridge.world import load_world

log = logging.getLogger(__name__)

DEFAULT_SCAN_ENDPOINT = "tcp/127.0.0.1:7447"  # where the companion listens by default (docs/zenoh.md)
_LIDAR_FLAGS = ("lidar_range_m", "lidar_rate_hz", "lidar_step_deg", "lidar_noise_m", "lidar_dropout", "lidar_seed",
                "lidar_compid", "lidar_mavlink")


def add_world_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the world and LiDAR options to ``parser``."""
    d = LidarConfig()
    g = parser.add_argument_group("world and LiDAR")
    g.add_argument("--world", metavar="FILE|NAME",
                   help="the trunks that stand in the simulated world (a world TOML, or a shipped one: forest, "
                        "forest_crossing); the vehicle's 2-D LiDAR sees them (docs/sitl.md)")
    g.add_argument("--no-lidar", action="store_true", help="a world without the LiDAR (nothing is sent)")
    g.add_argument("--lidar-range-m", type=float, default=None, help=f"maximum range, m (default {d.range_max_m:g})")
    g.add_argument("--lidar-rate-hz", type=float, default=None, help=f"scans per second (default {d.rate_hz:g})")
    g.add_argument("--lidar-step-deg", type=float, default=None,
                   help=f"angle between rays, deg; must divide 360 (default {d.step_deg:g})")
    g.add_argument("--lidar-noise-m", type=float, default=None, help=f"1σ range noise, m (default {d.noise_m:g})")
    g.add_argument("--lidar-dropout", type=float, default=None,
                   help=f"probability that a ray returns nothing, 0..1 (default {d.dropout:g})")
    g.add_argument("--lidar-seed", type=int, default=None, help="seed of the LiDAR's noise (default 0)")
    g.add_argument("--lidar-compid", type=int, default=None,
                   help=f"MAVLink component id the scans are sent from (default {LIDAR_COMPID}, "
                        "MAV_COMP_ID_OBSTACLE_AVOIDANCE; the system id is the vehicle's)")
    g.add_argument("--lidar-mavlink", choices=LAYOUTS, default=None,
                   help="OBSTACLE_DISTANCE layout: split = every ray, 72 per message (default); sectors = one "
                        "message of 72 × 5° sectors, as PX4 and ArduPilot read it")
    g.add_argument("--lidar-gcs", action="store_true", help="send the scans on the GCS link too (default onboard only)")
    g.add_argument("--zenoh-scan", action="store_true",
                   help="also publish each raw scan on Zenoh at <prefix>/<sysid>/scan (docs/zenoh.md)")
    g.add_argument("--zenoh-scan-connect", action="append", default=[], metavar="ENDPOINT",
                   help=f"Zenoh endpoint to connect to for --zenoh-scan (repeatable; default {DEFAULT_SCAN_ENDPOINT}, "
                        "where the companion listens)")
    g.add_argument("--zenoh-scan-prefix", default="slungpilot", help="key prefix for --zenoh-scan")


def lidar_config_from_args(args: argparse.Namespace) -> LidarConfig:
    """The :class:`LidarConfig` of the flags; :class:`ConfigError` naming the flag on a bad value."""
    d = LidarConfig()
    cfg = LidarConfig(
        range_max_m=d.range_max_m if args.lidar_range_m is None else args.lidar_range_m,
        rate_hz=d.rate_hz if args.lidar_rate_hz is None else args.lidar_rate_hz,
        step_deg=d.step_deg if args.lidar_step_deg is None else args.lidar_step_deg,
        noise_m=d.noise_m if args.lidar_noise_m is None else args.lidar_noise_m,
        dropout=d.dropout if args.lidar_dropout is None else args.lidar_dropout,
        seed=d.seed if args.lidar_seed is None else args.lidar_seed,
    )
    try:
        cfg.validate()
    except ValueError as exc:
        flag = {"range_max_m": "--lidar-range-m", "rate_hz": "--lidar-rate-hz", "step_deg": "--lidar-step-deg",
                "noise_m": "--lidar-noise-m", "dropout": "--lidar-dropout"}.get(str(exc).split(":")[0], "--lidar")
        raise ConfigError(f"{flag}: {exc}") from None
    return cfg


def scanner_from_args(args: argparse.Namespace) -> ScanSender | None:
    """The vehicle's scanner for these flags, or None (no world, or ``--no-lidar``). Raises :class:`ConfigError`
    on a bad world file or flag, before anything is bound."""
    world_flag = getattr(args, "world", None)
    if world_flag is None:
        given = [f for f in _LIDAR_FLAGS if getattr(args, f, None) is not None]
        given += [f for f in ("no_lidar", "zenoh_scan", "lidar_gcs") if getattr(args, f, False)]
        if given:
            raise ConfigError(f"--{given[0].replace('_', '-')}: needs --world (there is nothing to scan without one)")
        return None
    world = load_world(world_flag)
    if args.no_lidar:
        log.info("world %s (%d trunks), no LiDAR", world.name, len(world.trunks))
        return None
    lidar = Lidar(lidar_config_from_args(args))
    compid = LIDAR_COMPID if args.lidar_compid is None else args.lidar_compid
    if compid == getattr(args, "compid", None):
        raise ConfigError(f"--lidar-compid: {compid} is the autopilot's component id (--compid); the LiDAR numbers "
                          "its own frames, so it needs a component of its own")
    try:
        sender = ScanSender(lidar, world, compid=compid, layout=args.lidar_mavlink or "split", gcs=args.lidar_gcs)
    except ValueError as exc:
        raise ConfigError(f"--lidar-{str(exc).split(':')[0]}: {exc}") from None
    log.info("world %s: %d trunks; LiDAR %d rays, %g Hz, %g m", world.name, len(world.trunks), lidar.cfg.n_rays,
             lidar.cfg.rate_hz, lidar.cfg.range_max_m)
    return sender


def _zenoh_config(endpoints: list[str]) -> Any:
    import zenoh

    cfg = zenoh.Config()
    for key, value in (("mode", "peer"), ("scouting/multicast/enabled", False), ("listen/endpoints", []),
                       ("connect/endpoints", endpoints or [DEFAULT_SCAN_ENDPOINT]),
                       ("connect/retry", {"period_init_ms": 250, "period_max_ms": 1000})):
        try:
            cfg.insert_json5(key, json.dumps(value))
        except Exception as exc:
            raise ConfigError(f"--zenoh-scan-connect: zenoh refused {value!r}: {exc}") from None
    return cfg


@contextlib.contextmanager
def attached_scanner(vehicle: Any, scanner: ScanSender | None, args: argparse.Namespace) -> Iterator[None]:
    """``with attached_scanner(vehicle, scanner_from_args(args), args): vehicle.run()``: the world's LiDAR on the
    vehicle while it runs; with ``--zenoh-scan`` a Zenoh session (peer, connecting to the companion) opened for
    that time and closed after."""
    vehicle.scanner = scanner
    if scanner is None or not args.zenoh_scan:
        yield
        return
    try:
        import zenoh
    except ImportError:
        raise ConfigError("--zenoh-scan: the zenoh package is not installed") from None
    try:
        session = zenoh.open(_zenoh_config(args.zenoh_scan_connect))
    except ConfigError:
        raise
    except Exception as exc:
        raise LinkError(f"--zenoh-scan: cannot open a Zenoh session: {exc}") from None
    with session:
        try:
            scanner.publisher = ZenohScanPublisher(session, args.zenoh_scan_prefix, str(vehicle.sysid))
        except Exception as exc:  # e.g. a prefix zenoh refuses as a key
            raise ConfigError(f"--zenoh-scan-prefix: {args.zenoh_scan_prefix!r}: {exc}") from None
        log.info("raw scans on Zenoh at %s", scanner.publisher.key)
        try:
            yield
        finally:
            scanner.publisher.undeclare()
            scanner.publisher = None
