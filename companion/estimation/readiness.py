"""Whether the autopilot is ready to arm, as real autopilots report it, and in words what is still missing.

PX4 and ArduPilot set SYS_STATUS's pre-arm check bit (``MAV_SYS_STATUS_PREARM_CHECK``) in *health* once arming is
allowed; PX4 v1.15 never sets it in *present* (streams/SYS_STATUS.hpp), so a set health bit is enough. ArduCopter
with its pre-arm checks switched off (``ARMING_CHECK 0``, usual on benches and in simulation) reports the bit
*present* but not *enabled*, and never healthy: then the autopilot's other signals decide — its HEARTBEAT state
STANDBY (booted, calibrated, disarmed and armable) and a position estimate (LOCAL_POSITION_NED, which ArduPilot
sends only once its EKF has an origin) — and the arming attempt's answer has the last word (the flight sequence
retries a refused arm and names the refusal). Pure: reads the fields of a
:class:`~companion.estimation.vehicle_state.VehicleState`.
"""

from __future__ import annotations

from typing import Any

MAV_SYS_STATUS_PREARM_CHECK = 0x10000000
MAV_STATE_STANDBY = 3
MAV_STATE_ACTIVE = 4
MAV_STATE_NAMES = {0: "UNINIT", 1: "BOOT", 2: "CALIBRATING", 3: "STANDBY", 4: "ACTIVE", 5: "CRITICAL",
                   6: "EMERGENCY", 7: "POWEROFF", 8: "FLIGHT_TERMINATION"}


def prearm_checks_disabled(st: Any) -> bool:
    """The pre-arm bit present in SYS_STATUS but not enabled: the autopilot runs no pre-arm checks."""
    return bool(st.sys_status_seen and st.sensors_present & MAV_SYS_STATUS_PREARM_CHECK
                and not st.sensors_enabled & MAV_SYS_STATUS_PREARM_CHECK)


def unmet(st: Any, prearm_bit: bool = True) -> tuple[str, ...]:
    """The readiness conditions ``st`` (a VehicleState) does not meet yet, in words; empty: ready to arm.
    ``prearm_bit``: the family reports readiness in SYS_STATUS (PX4, ArduPilot); without it, the HEARTBEAT state
    (STANDBY or ACTIVE) decides."""
    if not prearm_bit or prearm_checks_disabled(st):
        out = []
        if st.system_status not in (MAV_STATE_STANDBY, MAV_STATE_ACTIVE):
            name = MAV_STATE_NAMES.get(st.system_status, str(st.system_status))
            out.append(f"HEARTBEAT state {name}, not STANDBY")
        if prearm_bit and st.pos_ned_m is None:
            out.append("no position estimate (LOCAL_POSITION_NED; pre-arm checks are off, so this stands in)")
        return tuple(out)
    if not st.sys_status_seen:
        return ("no SYS_STATUS from the autopilot (its pre-arm report)",)
    if not st.sensors_health & MAV_SYS_STATUS_PREARM_CHECK:
        return ("pre-arm checks not passed (SYS_STATUS health bit clear)",)
    return ()
