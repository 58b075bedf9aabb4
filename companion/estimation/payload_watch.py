"""The payload as the flight's own IMU saw it: identification over the cruise.

The cruise is the excitation :func:`~companion.estimation.payload_id.identify_payload` needs (the reference
accelerates from a hover, turns round trunks and brakes at the goal); the watch keeps the vehicle's specific force
(HIGHRES_IMU or SCALED_IMU, body FRD, m/s²) and attitude (ATTITUDE, ZYX Euler, rad) from the cruise's start for
:data:`WINDOW_S` of vehicle time, thinned to :data:`IMU_STEP_S` (the fit low-passes at 3 Hz), and identifies on
demand. One identification costs ~1–2 s of CPU (a grid search over the cable length), so it never runs inside a
control tick: the report asks for it once the flight is over (``slungpilot fly``), next to the declared payload.

Wind makes the fit's residual coloured, and the least-squares σ then far too small (eq. 49: the mass 0.29 kg
± 0.004 for a true 0.25); the σ given here are multiplied by √τ, τ the residual's integrated autocorrelation time,
which covered the truth in every flight measured (docs/swing-estimation.md, *Identified in flight*).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from companion.estimation.payload_id import PayloadId, identify_payload

WINDOW_S = 30.0  # vehicle time (s) from the cruise's start
IMU_STEP_S = 0.019  # specific force kept at most every ~20 ms (50 Hz), attitude every ~10 ms
MAX_SAMPLES = 2000  # of each stream
MIN_SAMPLES = 50  # what identify_payload needs
#: trusted when the corrected 1σ is within these fractions of the value (and the swing signal above the residual)
OK_REL_SIGMA_MASS = 0.3
OK_REL_SIGMA_CABLE = 0.2
#: an identified value more than this many corrected σ plus this fraction of the declared value from it: a mismatch
MISMATCH_SIGMA = 2.0
MISMATCH_REL = 0.1


class PayloadWatch:
    """IMU and attitude samples from the cruise's start, and their identification (cached).

    ``vehicle_mass_kg``: the airframe's mass M without payload (kg); ``g_mps2``: gravity (m/s²)."""

    def __init__(self, vehicle_mass_kg: float, g_mps2: float = 9.81, window_s: float = WINDOW_S) -> None:
        self.vehicle_mass_kg = vehicle_mass_kg
        self.g_mps2 = g_mps2
        self.window_s = window_s
        self.t0_s: float | None = None  # the cruise's start (vehicle time, s)
        self._imu: list[tuple[float, float, float, float]] = []
        self._att: list[tuple[float, float, float, float]] = []
        self._result: PayloadId | None = None
        self._error: str | None = None

    def start(self, t_s: float) -> None:
        """The cruise started at vehicle time ``t_s`` (s): keep samples from here (the first call counts)."""
        if self.t0_s is None:
            self.t0_s = t_s

    def _wanted(self, t_s: float, buf: list, step_s: float) -> bool:
        t0 = self.t0_s
        return (t0 is not None and math.isfinite(t_s) and t0 <= t_s <= t0 + self.window_s
                and len(buf) < MAX_SAMPLES and (not buf or t_s >= buf[-1][0] + step_s))

    def on_imu(self, t_s: float, accel_frd_mps2: tuple[float, float, float]) -> None:
        """A specific-force sample (body FRD, m/s²) at vehicle time ``t_s`` (s)."""
        if self._wanted(t_s, self._imu, IMU_STEP_S) and all(math.isfinite(a) for a in accel_frd_mps2):
            self._imu.append((t_s, *accel_frd_mps2))

    def on_attitude(self, t_s: float, euler_rad: tuple[float, float, float]) -> None:
        """An attitude sample (ZYX Euler, rad) at vehicle time ``t_s`` (s)."""
        if self._wanted(t_s, self._att, 0.5 * IMU_STEP_S) and all(math.isfinite(a) for a in euler_rad):
            self._att.append((t_s, *euler_rad))

    def identify(self) -> PayloadId | None:
        """The identified payload over what was kept (computed once, ~1–2 s of CPU); None when it could not run
        (:meth:`facts` says why)."""
        if self._result is not None or self._error is not None:
            return self._result
        if self.t0_s is None:
            self._error = "the cruise never started"
        elif len(self._imu) < MIN_SAMPLES or len(self._att) < 2:
            self._error = (f"too few samples: {len(self._imu)} IMU, {len(self._att)} attitude in the cruise's first "
                           f"{self.window_s:.0f} s (the vehicle sends no HIGHRES_IMU / SCALED_IMU?)")
        else:
            imu = np.asarray(self._imu)
            att = np.asarray(self._att)
            t = imu[:, 0]
            inside = (t >= att[0, 0]) & (t <= att[-1, 0])
            t = t[inside]
            euler = np.column_stack([np.interp(t, att[:, 0], np.unwrap(att[:, k]) if k == 3 else att[:, k])
                                     for k in (1, 2, 3)])
            try:
                self._result = identify_payload(t, imu[inside, 1:4], euler, self.vehicle_mass_kg, self.g_mps2)
            except ValueError as exc:
                self._error = f"identification refused its samples: {exc}"
            except Exception as exc:  # a bug must cost the identification, never the flight (it may run in a thread)
                self._error = f"identification failed: {exc!r}"
        return self._result

    def judged(self) -> tuple[PayloadId | None, float, float, Verdict]:
        """The identification already computed, its corrected 1σ (kg, m: the least-squares σ times √τ) and the
        verdict on each value; without a result (None, nan, nan) and a verdict that trusts nothing and says why."""
        r = self._result
        if r is None:
            return None, math.nan, math.nan, Verdict(False, False, self._error or "not identified yet")
        k = math.sqrt(r.residual_tau)
        sig_m, sig_l = r.payload_mass_sigma_kg * k, r.cable_length_sigma_m * k
        return r, sig_m, sig_l, verdict(r, sig_m, sig_l)

    def facts(self, declared_mass_kg: float, declared_cable_m: float, run: bool = True) -> dict[str, Any]:
        """The report's ``payload`` section: declared, identified (with 1σ, ``ok`` and why not), and which
        identified values disagree with the declared ones. ``run``: identify now if not yet done (else only a
        result already computed is given)."""
        out: dict[str, Any] = {"declared": {"mass_kg": declared_mass_kg, "cable_length_m": declared_cable_m}}
        if run:
            self.identify()
        r, sig_m, sig_l, v = self.judged()
        if r is None:
            out["identified"] = None
            out["identified_detail"] = v.why
            return out
        out["identified"] = {
            "mass_kg": _r(r.payload_mass_kg), "mass_sigma_kg": _r(sig_m),
            "cable_length_m": _r(r.cable_length_m), "cable_length_sigma_m": _r(sig_l),
            "ok": v.ok, "mass_ok": v.mass_ok, "cable_ok": v.cable_ok, "reason": v.why,
            "window_s": _r(r.window_s), "samples": r.n_samples,
            "swing_signal_mps2": _r(r.swing_signal_mps2), "residual_mps2": _r(r.residual_mps2),
            "residual_tau_samples": _r(r.residual_tau),
        }
        out["mismatch"] = mismatches(r, sig_m if v.mass_ok else math.inf, sig_l if v.cable_ok else math.inf,
                                     declared_mass_kg, declared_cable_m)
        return out


@dataclass(frozen=True, slots=True)
class Verdict:
    """Which identified values to trust (each on its own corrected σ), and why not the others ("" when both)."""

    mass_ok: bool
    cable_ok: bool
    why: str = ""

    @property
    def ok(self) -> bool:
        return self.mass_ok and self.cable_ok


def verdict(r: PayloadId, sig_m: float, sig_l: float) -> Verdict:
    """Whether to trust the mass and the cable length of an identification with corrected σ ``sig_m`` (kg) and
    ``sig_l`` (m). The fit's own excitation and mass tests assume a white residual; here the corrected σ judge each
    value, with the swing signal at least the residual. A cable length the swing pins down is trusted even when the
    mass (which the wind's force on the airframe blurs) is not."""
    if r.reason and not r.reason.startswith(("too little excitation", "mass not determined")):
        return Verdict(False, False, r.reason)
    if not r.swing_signal_mps2 >= r.residual_mps2:
        return Verdict(False, False, f"too little excitation: swing signal {r.swing_signal_mps2:.3f} m/s² below the "
                                     f"residual {r.residual_mps2:.3f} m/s²")
    mass_ok = r.payload_mass_kg > 0.0 and sig_m <= OK_REL_SIGMA_MASS * r.payload_mass_kg
    cable_ok = sig_l <= OK_REL_SIGMA_CABLE * r.cable_length_m
    unsure = [w for w, ok in ((f"mass ± {sig_m:.3f} kg", mass_ok), (f"cable ± {sig_l:.2f} m", cable_ok)) if not ok]
    if not unsure:
        return Verdict(mass_ok, cable_ok)
    return Verdict(mass_ok, cable_ok,
                   f"too uncertain: {', '.join(unsure)} (residual correlated over {r.residual_tau:.0f} samples)")


def mismatches(r: PayloadId, sig_m: float, sig_l: float, declared_mass_kg: float,
               declared_cable_m: float) -> list[str]:
    """The identified values further from the declared ones than :data:`MISMATCH_SIGMA` of their corrected σ plus
    :data:`MISMATCH_REL` of the declared value, each as a sentence (an untrusted value: σ = inf, never)."""
    out = []
    for what, got, sigma, want, unit in (("payload mass", r.payload_mass_kg, sig_m, declared_mass_kg, "kg"),
                                         ("cable length", r.cable_length_m, sig_l, declared_cable_m, "m")):
        if abs(got - want) > MISMATCH_SIGMA * sigma + MISMATCH_REL * want:
            out.append(f"{what}: identified {got:.3f} ± {sigma:.3f} {unit}, declared {want:.3f} {unit}")
    return out


def _r(x: float) -> float | None:
    return round(float(x), 4) if math.isfinite(x) else None
