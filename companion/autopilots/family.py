"""What one autopilot family means by modes, thrust, readiness and set-up: the tables the companion, its
state tracking and the bundled vehicle share. Pure: no I/O.

An :class:`AutopilotFamily` answers, in the flight sequence's words:

* which DO_SET_MODE numbers make ``offboard`` (the companion flies), ``hold`` and ``land``, and which word a
  HEARTBEAT ``custom_mode`` stands for (:meth:`AutopilotFamily.mode_class`);
* which parameter holds the normalized hover thrust, and its default;
* the set-up requests once the vehicle is known (message rates, parameters to read), and the follow-ups their
  answers call for (:meth:`AutopilotFamily.followup`: e.g. ArduPilot's GUID_OPTIONS, or a fallback to
  REQUEST_DATA_STREAM where SET_MESSAGE_INTERVAL was refused);
* the order of arming and taking over, and how the companion announces itself (its HEARTBEAT type).

The families live in :mod:`companion.autopilots.px4` and :mod:`companion.autopilots.ardupilot`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_RESULT_ACCEPTED = 0
MAV_TYPE_GCS = 6
MAV_TYPE_ONBOARD_CONTROLLER = 18

ConfigureItem = tuple[str, float]


@dataclass(frozen=True)
class SetupOptions:
    """What the set-up depends on besides the family: control rate (Hz), whether the swing sensor and the IMU are
    wanted, whether the hover thrust is known already, and whether the companion may write parameters."""

    rate_hz: float = 250.0
    swing_sensor: bool = True
    imu: bool = True
    read_hover_thrust: bool = True
    allow_param_writes: bool = True


@dataclass(frozen=True)
class AutopilotFamily:
    """One autopilot family's tables (see the module docstring)."""

    name: str
    modes: Mapping[str, tuple[int, int]]  # sequence word → (custom main mode, sub mode) for DO_SET_MODE
    classify: Callable[[int], str]  # HEARTBEAT custom_mode → sequence word
    hover_param: str
    default_hover_thrust: float
    takeover_before_arm: bool
    heartbeat_type: int
    setup: Callable[[SetupOptions], tuple[ConfigureItem, ...]]
    followups: Callable[[Mapping[str, float], SetupOptions], tuple[tuple[ConfigureItem, ...], str | None]] = field(
        default=lambda answers, opts: ((), None))
    notes: str = ""
    prearm_bit: bool = True  # readiness from SYS_STATUS health's MAV_SYS_STATUS_PREARM_CHECK (PX4, ArduPilot)

    def mode_params(self, what: str) -> list[float]:
        """DO_SET_MODE params [base_mode, custom_mode, custom_sub_mode] for ``offboard``, ``hold`` or ``land``."""
        try:
            main, sub = self.modes[what]
        except KeyError:
            raise ValueError(f"mode: unknown mode {what!r} (known: {', '.join(self.modes)})") from None
        return [float(MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(main), float(sub)]

    def mode_class(self, custom_mode: int) -> str:
        """A HEARTBEAT custom_mode in the flight sequence's words (``offboard``, ``hold``, ``land``,
        ``takeoff`` or ``other``)."""
        return self.classify(int(custom_mode))

    def followup(self, answers: Mapping[str, float], opts: SetupOptions) -> tuple[tuple[ConfigureItem, ...],
                                                                                  str | None]:
        """More set-up the first answers call for, or a reason to refuse the vehicle (then no items)."""
        return self.followups(answers, opts)


def interval_us(rate_hz: float) -> float:
    """SET_MESSAGE_INTERVAL's interval (µs) for a rate in Hz."""
    return 1e6 / rate_hz if rate_hz > 0 else -1.0


def refused(answers: Mapping[str, float], key: str) -> bool:
    """Whether ``key`` was refused (a MAV_RESULT other than ACCEPTED) or never answered (NaN)."""
    v = answers.get(key)
    return v is None or (isinstance(v, float) and math.isnan(v)) or int(v) != MAV_RESULT_ACCEPTED
