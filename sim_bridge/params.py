"""The bundled vehicle's parameter table for the MAVLink PARAM protocol.

Names follow PX4 where PX4 has the parameter (MPC_THR_HOVER, COM_OF_LOSS_T, MIS_TAKEOFF_ALT); the
simulator's own knobs start with ``SIM_``, the inner-loop SMC gains with ``SMC_`` and the read-only
counters of rejected input with ``RJ_``. Values travel as float (MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT:
integers are sent as their float value, not bytewise). Ranges are enforced: an out-of-range PARAM_SET is
answered with the unchanged value (the PARAM protocol's way to say no) and counted as ``bad_param``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink2

REAL32 = mavlink2.MAV_PARAM_TYPE_REAL32
INT32 = mavlink2.MAV_PARAM_TYPE_INT32

_GAIN_NAMES = {"c": "C", "k": "K", "k_sat": "KSAT", "boundary": "BND", "max_tilt_rad": "TILT", "rate_gain": "RATE_K"}
_AXES = ("R", "P", "Y")


@dataclass
class Param:
    """One parameter: value with range; ``reboot`` means it takes effect at the next (re)start of the
    simulated vehicle (MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN); ``getter`` makes it a read-only live value."""

    name: str
    value: float
    lo: float
    hi: float
    is_int: bool = False
    reboot: bool = False
    doc: str = ""
    getter: Callable[[], float] | None = None

    @property
    def readonly(self) -> bool:
        return self.getter is not None

    @property
    def mav_type(self) -> int:
        return INT32 if self.is_int else REAL32

    def current(self) -> float:
        return float(self.getter()) if self.getter is not None else self.value


class ParamTable:
    """Ordered parameters with lookup by name (≤ 16 chars) and index."""

    def __init__(self, params: list[Param]) -> None:
        for p in params:
            if len(p.name) > 16:
                raise ValueError(f"{p.name}: parameter names are at most 16 characters")
        self._list = list(params)
        self._by_name = {p.name: p for p in self._list}
        self.on_change: Callable[[Param], None] | None = None
        #: the owner's veto of a value within bounds: (name, value) -> None to accept, or why it is refused
        self.check: Callable[[str, float], str | None] | None = None

    def __len__(self) -> int:
        return len(self._list)

    def __iter__(self):
        return iter(self._list)

    def index_of(self, name: str) -> int:
        return self._list.index(self._by_name[name])

    def by_index(self, i: int) -> Param | None:
        return self._list[i] if 0 <= i < len(self._list) else None

    def get(self, name: str) -> Param | None:
        return self._by_name.get(name)

    def value(self, name: str) -> float:
        return self._by_name[name].current()

    def set(self, name: str, value: float) -> tuple[bool, str]:
        """Set ``name`` to ``value``; returns (accepted, reason if not)."""
        p = self._by_name.get(name)
        if p is None:
            return False, f"unknown parameter {name!r}"
        if p.readonly:
            return False, f"{name} is read-only"
        if not math.isfinite(value):
            return False, f"{name}: value must be finite"
        if p.is_int:
            value = float(round(value))
        if not p.lo <= value <= p.hi:
            return False, f"{name}: {value:g} outside [{p.lo:g}, {p.hi:g}]"
        why = self.check(name, value) if self.check is not None else None
        if why is not None:
            return False, f"{name} {value:g} refused: {why}"
        p.value = float(value)
        if self.on_change is not None:
            self.on_change(p)
        return True, ""


def gain_params(gains) -> list[Param]:
    """Parameters ``SMC_<FIELD>[_R|_P|_Y]`` for every field of an ``InnerLoopGains`` dataclass."""
    out = []
    for f in dataclasses.fields(gains):
        v = getattr(gains, f.name)
        short = _GAIN_NAMES.get(f.name, f.name.upper())
        if isinstance(v, tuple):
            for ax, vi in zip(_AXES, v, strict=False):
                out.append(Param(f"SMC_{short}_{ax}", float(vi), 1e-6, 1e4, doc=f"inner loop {f.name}[{ax}]"))
        else:
            out.append(Param(f"SMC_{short}", float(v), 1e-6, 1e4, doc=f"inner loop {f.name}"))
    return out


def gains_from_params(table: ParamTable, gains):
    """A copy of ``gains`` (frozen dataclass) with the values of its ``SMC_*`` parameters."""
    kw = {}
    for f in dataclasses.fields(gains):
        v = getattr(gains, f.name)
        short = _GAIN_NAMES.get(f.name, f.name.upper())
        if isinstance(v, tuple):
            kw[f.name] = tuple(table.value(f"SMC_{short}_{ax}") for ax in _AXES[: len(v)])
        else:
            kw[f.name] = table.value(f"SMC_{short}")
    return dataclasses.replace(gains, **kw)


def build_param_table(
    *,
    thr_hover: float,
    offboard_timeout_s: float,
    wind_model: str,
    wind_scale: float,
    payload_mass_kg: float,
    cable_length_m: float,
    takeoff_alt_m: float,
    gains,
    counters: dict[str, int],
    obl_action: int = 0,
    fail_act_t_s: float = 5.0,
    imu_noise_scale: float = 1.0,
    air_mode: int = 2,
) -> ParamTable:
    """The vehicle's table: tunables, inner-loop gains, read-only rejection counters ``RJ_<KIND>``."""
    params = [
        Param("MPC_THR_HOVER", thr_hover, 0.05, 0.95, doc="normalized thrust that hovers (thrust = n·T_hover/this)"),
        Param("COM_OF_LOSS_T", offboard_timeout_s, 0.01, 60.0, doc="offboard setpoint loss timeout, s (sim time)"),
        Param("COM_OBL_RC_ACT", obl_action, 0, 4, is_int=True,
              doc="offboard loss action, PX4's values 0 position, 1 altitude, 2 manual, 3 return, 4 land; no RC "
                  "here, so each holds for COM_FAIL_ACT_T and then lands (5 hold, 6 terminate, 7 disarm refused)"),
        Param("COM_FAIL_ACT_T", fail_act_t_s, 0.0, 25.0, doc="hold this long after offboard loss, then land, s"),
        Param("MIS_TAKEOFF_ALT", takeoff_alt_m, 0.5, 100.0, doc="takeoff altitude above home, m"),
        Param("MC_AIRMODE", air_mode, 0, 2, is_int=True,
              doc="the mixer raises the collective for torque in flight: 0 never (PX4's default), 1 for roll/pitch, "
                  "2 for yaw too (the bundled default: eq. 49's yaw torque needs it)"),
        Param("SIM_WIND_MODEL", 1.0 if wind_model == "paper" else 0.0, 0, 1, is_int=True, doc="0 none, 1 eq. 49"),
        Param("SIM_WIND_SCALE", wind_scale, 0.0, 10.0, doc="wind scale factor (1 = the paper)"),
        Param("SIM_IMU_NSCALE", imu_noise_scale, 0.0, 100.0, doc="IMU noise and bias-walk multiplier (0 ideal)"),
        Param("SIM_PLD_MASS", payload_mass_kg, 0.001, 10.0, reboot=True, doc="payload mass m, kg (next start)"),
        Param("SIM_CABLE_LEN", cable_length_m, 0.05, 20.0, reboot=True, doc="cable length l, m (next start)"),
        *gain_params(gains),
    ]
    for kind in counters:
        short = kind.upper()[:13]
        params.append(Param(f"RJ_{short}", 0.0, 0, 2**31 - 1, is_int=True, doc=f"rejected input: {kind}",
                            getter=lambda k=kind: counters[k]))
    return ParamTable(params)


def param_id_str(raw) -> str:
    """PARAM_* ``param_id`` (bytes or str, NUL-padded to 16) as a clean string."""
    if isinstance(raw, bytes | bytearray):
        raw = raw.decode("ascii", errors="replace")
    return str(raw).split("\x00", 1)[0]
