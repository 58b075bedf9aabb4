"""The bundled vehicle's compiled physics loop (numba): ``n`` physics steps of wind → inner attitude loop (SMC)
→ rotor mixer → RK4 of the 8-DOF model → ground and cable contact, in place on the state. The Python object
around it (targets, wind field, views of the state): :class:`sim_bridge.physics.VehicleSim`.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from numba import njit

from companion.core.kernel_cache import use_kernel_cache
from companion.core.model import _deriv, _rk4
from companion.core.wind import eq49_signal
from sim_bridge.contact import _cable_contact, _hold_on_ground
from sim_bridge.inner_loop import _mix, _rate_torque, _smc_torque
from sim_bridge.wind_drag import _drag_disturbance

# before the first kernel (see companion.core.kernel_cache)
use_kernel_cache(Path(__file__), *(Path(__file__).with_name(f) for f in ("inner_loop.py", "wind_drag.py",
                                                                      "contact.py")))


@njit(cache=True)
def _body_rates(x, w):  # pragma: no cover - compiled
    """Body rates FRD (rad/s) of state ``x`` from its Euler angles and their rates, into ``w``."""
    phi = x[3]
    th = x[4]
    w[0] = x[11] - math.sin(th) * x[13]
    w[1] = math.cos(phi) * x[12] + math.sin(phi) * math.cos(th) * x[13]
    w[2] = -math.sin(phi) * x[12] + math.cos(phi) * math.cos(th) * x[13]


@njit(cache=True)
def _tilt_priority(tgt_euler, psi, tilt):  # pragma: no cover - compiled
    """The attitude the SMC flies for the target Euler angles ``tgt_euler`` (rad) at the current heading ``psi``
    (rad), into ``tilt``. Tilt priority (as PX4's attitude control): keep the commanded thrust direction
    b3 = R_d·e3 at the *current* heading, so a yaw error (e.g. yaw torque saturated in strong wind) never tilts
    the thrust the wrong way; the yaw channel still tracks ψ_d."""
    sf = math.sin(tgt_euler[0])
    cf = math.cos(tgt_euler[0])
    st = math.sin(tgt_euler[1])
    ct = math.cos(tgt_euler[1])
    sp = math.sin(tgt_euler[2])
    cp = math.cos(tgt_euler[2])
    b0 = cf * st * cp + sf * sp
    b1 = cf * st * sp - sf * cp
    b2 = cf * ct
    sy = math.sin(psi)
    cy = math.cos(psi)
    v0 = cy * b0 + sy * b1  # b3 in the current heading frame: [cφ·sθ, −sφ, cφ·cθ]
    v1 = -sy * b0 + cy * b1
    tilt[0] = math.asin(min(1.0, max(-1.0, -v1)))
    tilt[1] = math.atan2(v0, b2)
    tilt[2] = tgt_euler[2]


@njit(cache=True)
def _physics_steps(
    x, t, n, dt, p, p_free, wind_k, wtab, tab_dt, drag_k, tgt_euler, tgt_euler_rate, rates_only, tgt_rates,
    thrust, gp, a_mat, a_inv, f_max, air_mode, armed, landed, pl, f_out, tau_out, d_out, a_out,
):  # pragma: no cover - compiled
    """``n`` physics steps in place on ``x``: wind → attitude SMC → mixer → RK4 → ground and cable contact.

    Wind: eq. 49 times ``wind_k`` on all six channels, or (``wtab`` non-empty: the wind velocity table, NED m/s,
    a sample every ``tab_dt`` s from t = 0) drag ``drag_k`` = [k_airframe, k_payload] (N per (m/s)²) on the
    airframe and on the payload, held over each step. ``pl`` = [slack (1.0/0.0), payload x, y, z]: the
    payload's ground contact, updated in place; while slack the airframe flies with ``p_free`` (the parameters
    with m = 0). Returns (t, landed, ok). ``f_out``, ``tau_out``, ``d_out`` receive the last step's rotor
    thrusts, body torques and disturbance (first six channels), ``a_out`` the airframe's acceleration ξ̈ at
    the final state under them (0 on the ground), for the IMU.
    """
    inertia = p[3:6]
    tau = np.empty(3)
    u = np.empty(4)
    d6 = np.empty(6)
    d8 = np.zeros(8)
    physical = wtab.shape[0] > 1
    d = d8 if physical else d6
    w = np.empty(3)
    tilt = np.empty(3)
    for _ in range(n):
        slack = pl[0] > 0.5
        hover = (p[0] + (0.0 if slack else p[1])) * p[2]
        if physical:
            _drag_disturbance(x, t, wtab, tab_dt, drag_k, p[7], slack, landed, d8)
        else:
            wv = 0.0 if (landed or wind_k == 0.0) else wind_k * eq49_signal(t)
            for i in range(6):
                d6[i] = wv
        if armed:
            if rates_only:
                _body_rates(x, w)
                _rate_torque(w, tgt_rates, inertia, gp[12], tau)
            else:
                _tilt_priority(tgt_euler, x[5], tilt)
                _smc_torque(x[3:6], x[11:14], tilt, tgt_euler_rate, inertia, gp, tau)
            _mix(thrust, tau, a_inv, f_max, 0 if landed else air_mode, f_out)
        else:
            for i in range(4):
                f_out[i] = 0.0
        for r in range(4):
            u[r] = 0.0
            for c in range(4):
                u[r] += a_mat[r, c] * f_out[c]
        tau_out[0] = u[1]
        tau_out[1] = u[2]
        tau_out[2] = u[3]
        if landed and u[0] <= hover + 1e-9:
            _hold_on_ground(x, p, pl)
            t += dt
            continue
        landed = False
        y = _rk4(x, u, d, p_free if slack else p, dt, 1)
        for i in range(16):
            if not math.isfinite(y[i]):
                return t, landed, False
        for i in range(16):
            x[i] = y[i]
        _cable_contact(x, p, pl)
        if x[2] >= 0.0 and x[10] >= 0.0:
            # touch-down: no bounce, no sliding, airframe level
            x[2] = 0.0
            for i in (3, 4, 8, 9, 10, 11, 12, 13):
                x[i] = 0.0
            landed = True
        t += dt
    for i in range(6):
        d_out[i] = d[i]
    if landed:
        for i in range(3):
            a_out[i] = 0.0
    else:
        k = np.empty(16)
        _deriv(x, u, d, p_free if pl[0] > 0.5 else p, k)
        for i in range(3):
            a_out[i] = k[8 + i]
    return t, landed, True
