"""Zenoh sessions for slungpilot: the ``--zenoh-*`` flags (named as in zenoh's own examples), the session
config with the project's defaults, and opening a session with clear errors.

Defaults: peer mode, multicast scouting off; the companion (and a router) listen on ``tcp/127.0.0.1:7447``,
``slungpilot listen`` connects there, so the two find each other with no flags.
"""

from __future__ import annotations

import argparse
import json
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import zenoh

from companion.errors import ConfigError, LinkError

DEFAULT_PREFIX = "slungpilot"
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
ROLES = ("companion", "listener", "router")
TX_QUEUE_BATCHES = 16
_NAME = re.compile(r"^[A-Za-z0-9_.\-]+$")


def add_zenoh_arguments(parser: argparse.ArgumentParser, role: str) -> None:
    """Add the ``--zenoh-*`` flags (named as in zenoh's own examples) for ``role``; the companion also gets
    ``--vehicle-id`` and ``--no-zenoh``, companion and listener ``--zenoh-prefix``."""
    if role not in ROLES:
        raise ValueError(f"role: must be one of {ROLES}, got {role!r}")
    g = parser.add_argument_group("zenoh")
    default_mode = "router" if role == "router" else "peer"
    g.add_argument("--zenoh-mode", choices=["peer", "client", "router"], default=None,
                   help=f"Zenoh session mode (default {default_mode}, or the --zenoh-config file's)")
    g.add_argument("--zenoh-connect", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to connect to, e.g. tcp/192.168.1.5:7447 (repeatable)"
                   + (f"; default {DEFAULT_ENDPOINT} unless --zenoh-listen is given" if role == "listener" else ""))
    g.add_argument("--zenoh-listen", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to listen on (repeatable)"
                   + (f"; default {DEFAULT_ENDPOINT} unless --zenoh-connect is given" if role != "listener" else ""))
    g.add_argument("--zenoh-config", type=Path, metavar="FILE",
                   help="a zenoh JSON5 config file; when given, only the flags above that are set override it")
    g.add_argument("--zenoh-multicast-scouting", action="store_true",
                   help="enable UDP multicast scouting (off by default: endpoints are explicit)")
    if role in ("companion", "listener"):
        g.add_argument("--zenoh-prefix", default=DEFAULT_PREFIX, help=f"key prefix (default {DEFAULT_PREFIX})")
    if role == "companion":
        g.add_argument("--vehicle-id", default=None,
                       help="vehicle id in the keys <prefix>/<id>/... (default: the MAVLink system id)")
        g.add_argument("--no-zenoh", action="store_true", help="no Zenoh session at all")
        g.add_argument("--zenoh-rates", default=None, metavar="STREAM=HZ,...",
                       help="downsample the published streams at the source, e.g. swing=25,state=10,setpoint=5 "
                            "(defaults: swing every control tick, state 50, setpoint 50, status 1 Hz; 0 = every "
                            "tick); for fleets (README: bandwidth for 1000 vehicles)")


def zenoh_config(
    role: str, *, mode: str | None = None, connect: Sequence[str] = (), listen: Sequence[str] = (),
    config_file: Path | None = None, multicast_scouting: bool = False,
) -> zenoh.Config:
    """A session config for ``role`` with the project's defaults (see :func:`add_zenoh_arguments`).

    Without a config file: multicast scouting off; the companion and the router listen on
    ``tcp/127.0.0.1:7447`` unless endpoints are given, the listener connects there unless endpoints are
    given; connect retries back off to at most 1 s. Raises :class:`ConfigError` on bad values.
    """
    if role not in ROLES:
        raise ValueError(f"role: must be one of {ROLES}, got {role!r}")
    if config_file is not None:
        try:
            cfg = zenoh.Config.from_file(str(config_file))
        except Exception as exc:  # zenoh raises its own error types for I/O and syntax
            raise ConfigError(f"{config_file}: not a usable zenoh config: {exc}") from None
    else:
        cfg = zenoh.Config()
        if not connect and not listen:
            if role == "listener":
                connect = [DEFAULT_ENDPOINT]
            else:
                listen = [DEFAULT_ENDPOINT]
        _insert(cfg, "scouting/multicast/enabled", multicast_scouting, "--zenoh-multicast-scouting")
        _insert(cfg, "connect/retry", {"period_init_ms": 250, "period_max_ms": 1000}, "--zenoh-connect")
        # 16 batches (not 2) for data: a briefly descheduled TX thread must not make DROP lose samples.
        _insert(cfg, "transport/link/tx/queue/size/data", TX_QUEUE_BATCHES, "--zenoh-config")
        _insert(cfg, "listen/endpoints", list(listen), "--zenoh-listen")
        _insert(cfg, "connect/endpoints", list(connect), "--zenoh-connect")
    if config_file is not None:
        if multicast_scouting:
            _insert(cfg, "scouting/multicast/enabled", True, "--zenoh-multicast-scouting")
        if listen:
            _insert(cfg, "listen/endpoints", list(listen), "--zenoh-listen")
        if connect:
            _insert(cfg, "connect/endpoints", list(connect), "--zenoh-connect")
    if mode is None and config_file is None:
        mode = "router" if role == "router" else "peer"
    if mode is not None:
        _insert(cfg, "mode", mode, "--zenoh-mode")
    return cfg


def zenoh_config_from_args(args: argparse.Namespace, role: str) -> zenoh.Config:
    """The session config from the flags :func:`add_zenoh_arguments` added."""
    return zenoh_config(
        role, mode=args.zenoh_mode, connect=args.zenoh_connect, listen=args.zenoh_listen,
        config_file=args.zenoh_config, multicast_scouting=args.zenoh_multicast_scouting,
    )


def _insert(cfg: zenoh.Config, key: str, value: Any, flag: str) -> None:
    for ep in value if key.endswith("endpoints") else ():
        if not isinstance(ep, str) or "/" not in ep:
            raise ConfigError(f"{flag}: {ep!r} is not an endpoint like tcp/127.0.0.1:7447")
    try:
        cfg.insert_json5(key, json.dumps(value))
    except Exception as exc:
        raise ConfigError(f"{flag}: zenoh refused {value!r}: {exc}") from None


def open_session(cfg: zenoh.Config) -> zenoh.Session:
    """``zenoh.open`` with failures (port in use, unreachable router in client mode) as :class:`LinkError`."""
    zenoh.try_init_log_from_env()
    try:
        return zenoh.open(cfg)
    except Exception as exc:
        hint = ""
        if "Address already in use" in str(exc):
            hint = " (another companion on this port? give --zenoh-listen another port, or use a router)"
        raise LinkError(f"zenoh: cannot open a session: {exc}{hint}") from None


def check_key_part(what: str, value: str) -> str:
    """A prefix chunk or vehicle id: letters, digits, ``_ . -`` (prefix may have ``/``); no wildcards."""
    parts = value.split("/") if what == "prefix" else [value]
    if not value or not all(_NAME.match(p) for p in parts):
        raise ConfigError(f"{what}: {value!r} must be letters, digits, '_', '.', '-'")
    if what == "vehicle_id" and value == "world":
        raise ConfigError("vehicle_id: 'world' is reserved for <prefix>/world/obstacles")
    return value
