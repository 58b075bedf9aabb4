"""JSON schemas of the Zenoh telemetry streams: names, version, and the builders that encode samples.

Every sample is one JSON object that starts with the same header::

    {"schema": "slungpilot.swing", "version": 1, "seq": 17, "vehicle_id": "1",
     "t_s": 12.344, "wall_s": 1732230000.123456, ...stream fields...}

``t_s`` is the simulated / vehicle time in seconds (the app's clock; lockstep sim time in the bundled
simulator), ``wall_s`` the publisher's Unix wall time in seconds, ``seq`` a per-stream counter that starts at
0 and grows by one per published sample, so a subscriber detects loss from gaps. Non-finite numbers are sent
as ``null`` (JSON has no NaN). The Zenoh encoding of each sample is ``application/json`` with the schema
``<name>/v<version>`` (see :func:`encoding_schema`). Field lists per stream are in ``docs/zenoh.md``.

The swing and state builders format the JSON text directly (they run in the 250 Hz control loop); the
others go through :func:`json.dumps` after :func:`sanitize`.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

SCHEMA_VERSION = 1

SWING = "slungpilot.swing"
STATE = "slungpilot.state"
SETPOINT = "slungpilot.setpoint"
STATUS = "slungpilot.status"
OBSTACLES = "slungpilot.obstacles"
CONFIG = "slungpilot.config"
OBSTACLES_IN = "slungpilot.obstacles_in"
#: The raw 2-D range scan of the vehicle's LiDAR, published by the vehicle (the bundled one: ``sitl --world``)
#: at ``<prefix>/<vehicle_id>/scan``; not one of the companion's own :data:`STREAMS`. See :func:`encode_scan`.
SCAN = "slungpilot.scan"
SCAN_KEY_NAME = "scan"

STREAMS: dict[str, str] = {
    "swing": SWING,
    "state": STATE,
    "setpoint": SETPOINT,
    "status": STATUS,
    "obstacles": OBSTACLES,
    "config": CONFIG,
}

HEADER_KEYS = ("schema", "version", "seq", "vehicle_id", "t_s", "wall_s")
HEADER_KEYS_SET = frozenset(HEADER_KEYS)


def encoding_schema(name: str, version: int = SCHEMA_VERSION) -> str:
    """The schema string put on the Zenoh encoding: ``"slungpilot.swing/v1"``."""
    return f"{name}/v{version}"


def _num(x: float) -> str:
    """A float as JSON text; non-finite values become ``null``."""
    x = float(x)
    return repr(x) if math.isfinite(x) else "null"


def _vec(v: Sequence[float] | np.ndarray | None) -> str:
    if v is None:
        return "null"
    return "[" + ",".join(_num(x) for x in v) + "]"


def sanitize(obj: Any) -> Any:
    """Make ``obj`` JSON-ready: numpy arrays/scalars to lists/floats, non-finite floats to None,
    tuples to lists, dataclass-like objects with ``as_dict()`` to dicts; other types to ``str``."""
    if obj is None or isinstance(obj, bool | int | str):
        return obj
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, np.ndarray):
        return [sanitize(x) for x in obj.tolist()]
    if isinstance(obj, np.generic):
        return sanitize(obj.item())
    if isinstance(obj, Mapping):
        return {str(k): sanitize(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [sanitize(x) for x in obj]
    as_dict = getattr(obj, "as_dict", None)
    if callable(as_dict):
        return sanitize(as_dict())
    return str(obj)


def header(name: str, seq: int, vehicle_id: str, t_s: float, wall_s: float) -> dict[str, Any]:
    """The common header as a dict (for the ``json.dumps`` builders)."""
    return {
        "schema": name, "version": SCHEMA_VERSION, "seq": int(seq), "vehicle_id": vehicle_id,
        "t_s": sanitize(float(t_s)), "wall_s": float(wall_s),
    }


def _header_text(name: str, seq: int, vid_json: str, t_s: float, wall_s: float) -> str:
    return (
        f'{{"schema":"{name}","version":{SCHEMA_VERSION},"seq":{seq},"vehicle_id":{vid_json},'
        f'"t_s":{_num(t_s)},"wall_s":{wall_s!r}'
    )


def encode_swing(
    seq: int, vehicle_id: str, t_s: float, wall_s: float,
    swing4: Sequence[float] | np.ndarray | None, r_max_m: float, envelope_mode: str,
    source: str | None = None, truth4: Sequence[float] | None = None, sigma_rad: float | None = None,
    fade: float | None = None,
) -> bytes:
    """One swing sample: α, β (rad), α̇, β̇ (rad/s) or nulls when ``swing4`` is None (no estimate),
    ``valid``, the envelope radius ``r_max_m`` (m) and ``envelope_mode``; where known also ``source`` (what the
    swing came from: cable_sensor, estimate, payload_position, none), the vehicle's own measurement ``truth``
    ([α, β, α̇, β̇], when the swing is an estimate and the vehicle can measure it: the bundled one),
    the estimate's ``sigma_rad`` (1σ) and ``fade`` (0..1, the feed-forward share it carries)."""
    if swing4 is None:
        sw = '"alpha_rad":null,"beta_rad":null,"alpha_rate_radps":null,"beta_rate_radps":null,"valid":false'
    else:
        a, b, da, db = (float(x) for x in swing4)
        sw = (
            f'"alpha_rad":{_num(a)},"beta_rad":{_num(b)},"alpha_rate_radps":{_num(da)},'
            f'"beta_rate_radps":{_num(db)},"valid":true'
        )
    extra = ""
    if source is not None:
        extra += f',"source":{json.dumps(str(source))}'
    if truth4 is not None:
        extra += ',"truth":[' + ",".join(_num(x) for x in truth4) + "]"
    if sigma_rad is not None:
        extra += f',"sigma_rad":{_num(sigma_rad)}'
    if fade is not None:
        extra += f',"fade":{_num(fade)}'
    text = (
        _header_text(SWING, seq, json.dumps(vehicle_id), t_s, wall_s)
        + f',{sw},"r_max_m":{_num(r_max_m)},"envelope_mode":{json.dumps(str(envelope_mode))}{extra}}}'
    )
    return text.encode()


def encode_state(
    seq: int, vehicle_id: str, t_s: float, wall_s: float,
    pos_ned_m: Sequence[float] | np.ndarray, vel_ned_mps: Sequence[float] | np.ndarray,
    euler_rad: Sequence[float] | np.ndarray, payload_pos_ned_m: Sequence[float] | np.ndarray | None,
) -> bytes:
    """One state sample: position (m) and velocity (m/s) in NED, attitude roll/pitch/yaw (rad),
    payload position in NED (m) or null."""
    text = (
        _header_text(STATE, seq, json.dumps(vehicle_id), t_s, wall_s)
        + f',"pos_ned_m":{_vec(pos_ned_m)},"vel_ned_mps":{_vec(vel_ned_mps)},"euler_rad":{_vec(euler_rad)},'
        f'"payload_pos_ned_m":{_vec(payload_pos_ned_m)}}}'
    )
    return text.encode()


def encode_dict(seq: int, vehicle_id: str, t_s: float, wall_s: float, body: Mapping[str, Any], name: str) -> bytes:
    """A sample of schema ``name``: header plus the (sanitized) ``body`` fields; body keys that collide
    with header keys are refused with ``ValueError``."""
    clash = set(HEADER_KEYS) & set(body)
    if clash:
        raise ValueError(f"{sorted(clash)[0]}: is a header key and cannot be a body field")
    d = header(name, seq, vehicle_id, t_s, wall_s)
    d.update(sanitize(body))
    return json.dumps(d, separators=(",", ":"), allow_nan=False).encode()


def obstacles_body(obstacles: Sequence[Any], rejected_count: int, store_version: int) -> dict[str, Any]:
    """Body of an ``obstacles`` sample: the set in use (each with its ``source``), the distinct sources,
    the count of rejected live samples so far and the store version."""
    items = [o.as_dict() for o in obstacles]
    return {
        "obstacles": items,
        "count": len(items),
        "sources": sorted({it["source"] for it in items}),
        "rejected_count": int(rejected_count),
        "store_version": int(store_version),
    }


def scan_key(prefix: str, vehicle_id: str) -> str:
    """The key expression of a vehicle's raw scan: ``"slungpilot/1/scan"``."""
    return f"{prefix}/{vehicle_id}/{SCAN_KEY_NAME}"


def encode_scan(
    seq: int, vehicle_id: str, t_s: float, wall_s: float, time_usec: int, angle_min_rad: float,
    angle_increment_rad: float, range_min_m: float, range_max_m: float, ranges_m: Sequence[float] | np.ndarray,
) -> bytes:
    """One raw scan sample (schema :data:`SCAN`): the header, then

    * ``time_usec`` (int, µs): the vehicle's boot time when the scan was taken (the clock of its MAVLink
      telemetry's ``time_boot_ms`` / ``time_usec``); ``t_s`` is the same instant in seconds;
    * ``frame`` = ``"body_frd"``: ray ``i`` lies in the airframe's x-y plane at the angle
      ``angle_min_rad + i * angle_increment_rad`` (rad) from the airframe's forward axis, positive clockwise
      seen from above (towards body +y, as MAVLink's BODY_FRD); the scan plane tilts with the airframe;
    * ``angle_min_rad``, ``angle_increment_rad`` (rad), ``range_min_m``, ``range_max_m`` (m);
    * ``ranges_m``: one per ray, the range (m) of the nearest return, or ``null`` when there is none;
    * ``valid``: one bool per ray; ``false`` = the ray was not measured (a dropout), its range is ``null`` and
      says nothing; ``true`` with a ``null`` range = measured, nothing within ``range_max_m`` (free to there).

    ``ranges_m`` given here: a float per ray, ``+inf`` = no return within range, NaN = not measured (dropout);
    :func:`scan_ranges` turns a decoded sample back into that array.
    """
    r = np.asarray(ranges_m, dtype=np.float64)
    rng = ",".join(repr(float(x)) if math.isfinite(x) else "null" for x in r.tolist())
    valid = ",".join("false" if math.isnan(x) else "true" for x in r.tolist())
    text = (
        _header_text(SCAN, seq, json.dumps(vehicle_id), t_s, wall_s)
        + f',"time_usec":{int(time_usec)},"frame":"body_frd","angle_min_rad":{_num(angle_min_rad)},'
        f'"angle_increment_rad":{_num(angle_increment_rad)},"range_min_m":{_num(range_min_m)},'
        f'"range_max_m":{_num(range_max_m)},"ranges_m":[{rng}],"valid":[{valid}]}}'
    )
    return text.encode()


def scan_ranges(sample: Mapping[str, Any]) -> np.ndarray:
    """The ranges (m) of a decoded scan sample as floats: ``+inf`` = no return within range, NaN = not measured
    (``valid`` false). Raises ``ValueError`` when ``ranges_m`` and ``valid`` are missing or differ in length."""
    rng, valid = sample.get("ranges_m"), sample.get("valid")
    if not isinstance(rng, list) or not isinstance(valid, list) or len(rng) != len(valid):
        raise ValueError("ranges_m: expected two lists of the same length, ranges_m and valid")
    out = [math.nan if not v else (math.inf if x is None else float(x)) for x, v in zip(rng, valid, strict=True)]
    return np.array(out, dtype=np.float64)


def decode(raw: bytes | str) -> dict[str, Any]:
    """Parse a sample and check its header; raises ``ValueError`` naming what is wrong."""
    d = json.loads(raw)
    if not isinstance(d, dict):
        raise ValueError("sample: not a JSON object")
    for k in HEADER_KEYS:
        if k not in d:
            raise ValueError(f"{k}: missing header key")
    if d["version"] != SCHEMA_VERSION:
        raise ValueError(f"version: {d['version']!r} is not {SCHEMA_VERSION}")
    return d
