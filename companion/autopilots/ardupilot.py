"""ArduPilot (ArduCopter): modes, hover thrust, set-up, and the parameter it needs for attitude control.

* Modes (ArduCopter's custom modes): GUIDED_NOGPS (20) flies SET_ATTITUDE_TARGET; BRAKE (17) stops and holds;
  LAND (9). GUIDED (4) also takes attitude targets, and LOITER (5) also holds: both are recognised.
* Hover thrust: ``MOT_THST_HOVER`` (learned in flight; default 0.35).
* ArduCopter switches to its guided mode first, then arms (the other order arms in a mode that flies its own
  stick inputs).
* ``GUID_OPTIONS`` bit 3 (value 8, "SetAttitudeTarget interprets Thrust As Thrust"): clear by default, and then
  ArduCopter reads SET_ATTITUDE_TARGET's thrust as a climb rate (0.5 = hold altitude) — a companion sending thrust
  would climb to a stall. The set-up reads it and, where clear, sets it (``--no-param-writes``: refuses the
  vehicle instead, with what to set).
* Streams: ArduPilot sends nothing until asked. SET_MESSAGE_INTERVAL (answered by COMMAND_ACK) per message;
  where it is refused, REQUEST_DATA_STREAM for the stream groups instead (ATTITUDE in EXTRA1,
  LOCAL_POSITION_NED in POSITION, SYS_STATUS in EXTENDED_STATUS).
* Its simulated slung payload (SIM_SLUP_*) is its own MAVLink system (autopilot INVALID) sending
  GLOBAL_POSITION_INT at 10 Hz; see ``companion.estimation.vehicle_state``.
* We announce ourselves as an onboard controller: ArduPilot sends its STATUSTEXT to every active channel,
  whatever heard there (measured 2026-12-03: 23 in 40 s to an onboard-controller link, the arming refusals
  among them).
"""

from __future__ import annotations

from collections.abc import Mapping

from companion.autopilots.family import MAV_TYPE_ONBOARD_CONTROLLER, AutopilotFamily, SetupOptions, interval_us, refused

GUIDED = 4
LOITER = 5
LAND = 9
BRAKE = 17
GUIDED_NOGPS = 20
MODES = {"offboard": (GUIDED_NOGPS, 0), "hold": (BRAKE, 0), "land": (LAND, 0)}
_CLASS = {GUIDED_NOGPS: "offboard", GUIDED: "offboard", BRAKE: "hold", LOITER: "hold", LAND: "land"}
GUID_OPTIONS_THRUST_AS_THRUST = 8  # bit 3
# MAV_DATA_STREAM ids and the messages they carry that we need
DATA_STREAMS = {"message_interval:ATTITUDE": 10, "message_interval:LOCAL_POSITION_NED": 6,
                "message_interval:SYS_STATUS": 2, "message_interval:EXTENDED_SYS_STATE": 2}


def classify(custom_mode: int) -> str:
    """ArduCopter HEARTBEAT custom_mode → ``offboard``/``hold``/``land``/``other``."""
    return _CLASS.get(int(custom_mode), "other")


def setup(opts: SetupOptions) -> tuple[tuple[str, float], ...]:
    """Message rates, the version, GUID_OPTIONS and the hover thrust."""
    fast = interval_us(opts.rate_hz)
    items = [
        ("message_interval:ATTITUDE", fast),
        ("message_interval:LOCAL_POSITION_NED", fast),
        ("message_interval:EXTENDED_SYS_STATE", 1e5),
        ("message_interval:SYS_STATUS", 2e5),
        ("message_interval:HOME_POSITION", 1e6),
        ("message_interval:GLOBAL_POSITION_INT", interval_us(10.0)),
    ]
    if opts.imu:
        items.append(("message_interval:SCALED_IMU", fast))
    items += [("request_message:AUTOPILOT_VERSION", float("nan")), ("param_read:GUID_OPTIONS", float("nan"))]
    if opts.read_hover_thrust:
        items.append(("param_read:MOT_THST_HOVER", float("nan")))
    return tuple(items)


def followups(answers: Mapping[str, float], opts: SetupOptions) -> tuple[tuple[tuple[str, float], ...], str | None]:
    """GUID_OPTIONS bit 3 set where clear (or a refusal), and REQUEST_DATA_STREAM where rates were refused."""
    items: list[tuple[str, float]] = []
    streams = sorted({sid for key, sid in DATA_STREAMS.items() if key in answers and refused(answers, key)})
    items += [(f"data_stream:{sid}", min(50.0, opts.rate_hz)) for sid in streams]
    gopt = answers.get("param_read:GUID_OPTIONS")
    if gopt is None or gopt != gopt:  # NaN: never answered
        return tuple(items), ("ArduCopter did not answer for GUID_OPTIONS: cannot tell whether it reads our thrust "
                              "as thrust (bit 3); check the link and the parameter")
    if not int(gopt) & GUID_OPTIONS_THRUST_AS_THRUST:
        if not opts.allow_param_writes:
            return (), (f"ArduCopter's GUID_OPTIONS is {int(gopt)}: bit 3 (8, SetAttitudeTarget thrust as thrust) is "
                        f"clear, so it would read our thrust as a climb rate. Set GUID_OPTIONS to "
                        f"{int(gopt) | GUID_OPTIONS_THRUST_AS_THRUST}, or fly without --no-param-writes")
        items.append(("param_set:GUID_OPTIONS", float(int(gopt) | GUID_OPTIONS_THRUST_AS_THRUST)))
    return tuple(items), None


ARDUPILOT = AutopilotFamily(
    name="ardupilot", modes=MODES, classify=classify, hover_param="MOT_THST_HOVER", default_hover_thrust=0.35,
    takeover_before_arm=True, heartbeat_type=MAV_TYPE_ONBOARD_CONTROLLER, setup=setup, followups=followups,
    notes="ArduCopter: GUIDED_NOGPS then arm; GUID_OPTIONS bit 3 for thrust; streams only on request",
)
