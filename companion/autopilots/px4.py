"""PX4 (and the bundled vehicle, which speaks PX4's dialect): modes, hover thrust, set-up.

* Modes: OFFBOARD (main 6) flies our setpoints; AUTO.LOITER (4/3) holds; AUTO.LAND (4/6) lands; the custom mode
  is ``main << 16 | sub << 24`` (``companion.autopilots.px4_modes``).
* Hover thrust: ``MPC_THR_HOVER``, default 0.5 (the bundled vehicle: 0.4 = 1/thrust-to-weight).
* Arming before OFFBOARD, which PX4 accepts only while setpoints already stream (COM_OF_LOSS_T fresh).
* We announce ourselves as what we are, an onboard controller (MAV_TYPE_ONBOARD_CONTROLLER, component 191).
  PX4 sends its STATUSTEXT (the reasons behind a refused arm, a failsafe) only on a link that heard a GCS
  heartbeat (``is_gcs_connected()``, src/modules/mavlink/streams/STATUSTEXT.hpp in v1.15): measured 2026-12-03,
  none on its onboard link alone, all of them once a ground station shares that link (through MAVProxy or
  mavlink-router, as beside a real GCS). No stream request changes that; the companion's own readiness
  conditions say what it waits for instead (docs/autopilots.md).
* Readiness: SYS_STATUS with the pre-arm check bit (PX4 sets it present and healthy once arming is allowed).
"""

from __future__ import annotations

from companion.autopilots import px4_modes as pm
from companion.autopilots.family import MAV_TYPE_ONBOARD_CONTROLLER, AutopilotFamily, SetupOptions, interval_us

MODES = {
    "offboard": (pm.MAIN_OFFBOARD, 0),
    "hold": (pm.MAIN_AUTO, pm.SUB_AUTO_LOITER),
    "land": (pm.MAIN_AUTO, pm.SUB_AUTO_LAND),
    "takeoff": (pm.MAIN_AUTO, pm.SUB_AUTO_TAKEOFF),
}
_CLASS = {(main, sub): word for word, (main, sub) in MODES.items()}


def classify(custom_mode: int) -> str:
    """PX4 HEARTBEAT custom_mode → ``offboard``/``hold``/``land``/``takeoff``/``other``."""
    m = pm.Px4Mode.from_custom_mode(custom_mode)
    return _CLASS.get((m.main, m.sub), "other")


def setup(opts: SetupOptions) -> tuple[tuple[str, float], ...]:
    """Message rates (attitude and position at the control rate), the IMU for the swing estimator, the home
    position, the estimator's accuracy (for the arrival tolerance; optional), the version, the hover thrust."""
    fast = interval_us(opts.rate_hz)
    items = [
        ("message_interval:ATTITUDE", fast),
        ("message_interval:LOCAL_POSITION_NED", fast),
        ("message_interval:EXTENDED_SYS_STATE", 1e5),
        ("message_interval:SYS_STATUS", 2e5),
        ("message_interval:HOME_POSITION", 1e6),
        ("message_interval:ESTIMATOR_STATUS", 2e5),
    ]
    if opts.imu:
        items.append(("message_interval:HIGHRES_IMU", fast))
    if opts.swing_sensor:
        items.append(("message_interval:DEBUG_FLOAT_ARRAY", fast))
    items.append(("request_message:AUTOPILOT_VERSION", float("nan")))
    if opts.read_hover_thrust:
        items.append(("param_read:MPC_THR_HOVER", float("nan")))
    return tuple(items)


PX4 = AutopilotFamily(
    name="px4", modes=MODES, classify=classify, hover_param="MPC_THR_HOVER", default_hover_thrust=0.5,
    takeover_before_arm=False, heartbeat_type=MAV_TYPE_ONBOARD_CONTROLLER, setup=setup,
    notes="PX4: OFFBOARD after arming, setpoints streaming first; STATUSTEXT only on a link a GCS shares",
)
