"""The wind options of ``slungpilot evaluate`` (issue 28): a named wind for every forest of a run.

``--wind calm|paper|light|moderate|severe``: no wind, eq. 49 (times ``--wind-scale``), or the physical wind of
:mod:`companion.core.turbulence` — Dryden turbulence of that intensity on a mean wind of ``--wind-mean-mps``
(default by name: :data:`DEFAULT_MEAN_MPS`, as the issue's grid: light at 3 m/s, moderate at 6 m/s; severe at
9 m/s) blowing from ``--wind-from-deg`` (default 90: from the east, across the corridor, which runs north).
The turbulence is seeded with the forest's seed: every planner meets the same gusts in the same forest.
"""

from __future__ import annotations

import argparse
import dataclasses

from companion.core.mission import Mission
from companion.core.wind import WindConfig
from companion.errors import ConfigError

WIND_NAMES = ("paper", "calm", "light", "moderate", "severe")
#: mean wind (m/s) of each turbulence intensity unless ``--wind-mean-mps`` says otherwise
DEFAULT_MEAN_MPS = {"light": 3.0, "moderate": 6.0, "severe": 9.0}


def add_wind_arguments(p: argparse.ArgumentParser) -> None:
    """``--wind``, ``--wind-mean-mps``, ``--wind-from-deg`` (``--wind-scale`` is evaluate's own)."""
    p.add_argument("--wind", choices=WIND_NAMES, default=None,
                   help="wind of every forest: paper (eq. 49 x --wind-scale, the default), calm, or a mean wind with "
                        "Dryden turbulence (light, moderate, severe; MIL-F-8785C), seeded per forest")
    p.add_argument("--wind-mean-mps", type=float, default=None,
                   help="mean wind for light/moderate/severe, m/s (default 3, 6, 9)")
    p.add_argument("--wind-from-deg", type=float, default=90.0,
                   help="direction the mean wind blows FROM, degrees clockwise from north (default 90: a crosswind)")


def wind_from_args(args: argparse.Namespace) -> WindConfig | None:
    """The named wind, or None when ``--wind`` is not given (the forests' own eq. 49 x --wind-scale)."""
    name = getattr(args, "wind", None)
    if name is None:
        if getattr(args, "wind_mean_mps", None) is not None:
            raise ConfigError("--wind-mean-mps: only with --wind light|moderate|severe")
        return None
    if name == "calm":
        return WindConfig("none", 0.0)
    if name == "paper":
        return WindConfig("paper", float(args.wind_scale))
    mean = DEFAULT_MEAN_MPS[name] if args.wind_mean_mps is None else float(args.wind_mean_mps)
    try:
        return _validated(WindConfig("turbulence", 1.0, mean_speed_mps=mean, direction_deg=float(args.wind_from_deg),
                                     intensity=name))
    except ValueError as exc:
        raise ConfigError(f"--wind-mean-mps/--wind-from-deg: {exc}") from None


def _validated(w: WindConfig) -> WindConfig:
    w.validate()
    return w


def with_wind(mission: Mission, wind: WindConfig | None, seed: int) -> Mission:
    """``mission`` flown in ``wind`` (its turbulence seeded with ``seed``); unchanged when ``wind`` is None."""
    if wind is None:
        return mission
    return mission.with_(wind=dataclasses.replace(wind, seed=seed) if wind.is_physical else wind)
