"""The autopilot families' tables (pure): mode numbers both ways, set-up requests and their follow-ups."""

import math

import pytest

from companion.autopilots import px4_modes as pm
from companion.autopilots.ardupilot import ARDUPILOT
from companion.autopilots.family import SetupOptions
from companion.autopilots.profile import profile_by_name, profile_for_autopilot
from companion.autopilots.px4 import PX4


@pytest.mark.parametrize("family", [PX4, ARDUPILOT])
def test_every_mode_word_round_trips_through_do_set_mode_and_heartbeat(family):
    for word in ("offboard", "hold", "land"):
        base, main, sub = family.mode_params(word)
        assert base == 1.0
        custom = (int(main) << 16 | int(sub) << 24) if family is PX4 else int(main)
        assert family.mode_class(custom) == word


def test_px4_modes_other_than_ours_are_other():
    assert PX4.mode_class(pm.POSCTL.custom_mode) == "other"
    assert PX4.mode_class(pm.AUTO_TAKEOFF.custom_mode) == "takeoff"
    assert ARDUPILOT.mode_class(0) == "other"  # STABILIZE


def test_profiles_follow_the_heartbeats_autopilot():
    ap = profile_for_autopilot(3)
    assert ap.autopilot == "ardupilot" and ap.hover_param == "MOT_THST_HOVER"
    assert profile_for_autopilot(12).autopilot == "px4" and profile_for_autopilot(12).hover_param == "MPC_THR_HOVER"
    assert profile_by_name("bundled").family is PX4 and profile_by_name("bundled").hover_thrust_norm == 0.4
    assert profile_by_name("ardupilot").takeover_before_arm and not profile_by_name("px4").takeover_before_arm


def test_px4_setup_asks_rates_at_the_control_rate_and_the_hover_thrust():
    items = dict(PX4.setup(SetupOptions(rate_hz=200.0)))
    assert items["message_interval:ATTITUDE"] == 5000.0 and items["message_interval:LOCAL_POSITION_NED"] == 5000.0
    assert "param_read:MPC_THR_HOVER" in items and "message_interval:HIGHRES_IMU" in items
    assert "param_read:MPC_THR_HOVER" not in dict(PX4.setup(SetupOptions(read_hover_thrust=False)))


def test_ardupilot_sets_guid_options_bit_3_only_where_clear():
    opts = SetupOptions()
    more, refusal = ARDUPILOT.followup({"param_read:GUID_OPTIONS": 0.0}, opts)
    assert refusal is None and more == (("param_set:GUID_OPTIONS", 8.0),)
    more, refusal = ARDUPILOT.followup({"param_read:GUID_OPTIONS": 9.0}, opts)
    assert refusal is None and more == ()
    more, refusal = ARDUPILOT.followup({"param_read:GUID_OPTIONS": 1.0}, opts)
    assert more == (("param_set:GUID_OPTIONS", 9.0),)


def test_ardupilot_without_param_writes_refuses_and_says_what_to_set():
    more, refusal = ARDUPILOT.followup({"param_read:GUID_OPTIONS": 0.0}, SetupOptions(allow_param_writes=False))
    assert more == () and "GUID_OPTIONS" in refusal and "Set GUID_OPTIONS to 8" in refusal


def test_ardupilot_refused_rates_fall_back_to_data_streams():
    answers = {"param_read:GUID_OPTIONS": 8.0, "message_interval:ATTITUDE": 2.0,
               "message_interval:LOCAL_POSITION_NED": math.nan, "message_interval:SYS_STATUS": 0.0}
    more, refusal = ARDUPILOT.followup(answers, SetupOptions(rate_hz=250.0))
    assert refusal is None and more == (("data_stream:6", 50.0), ("data_stream:10", 50.0))
