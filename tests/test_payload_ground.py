"""A mission whose payload would touch the ground is refused before take-off (issue 28), naming the point."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from companion.config import shipped_config
from companion.core.mission import PayloadConfig, Waypoint, load_mission
from companion.core.payload_check import check_payload_clears_ground
from companion.errors import ConfigError


def _forest():
    return load_mission(shipped_config("missions/forest.toml"))


def test_table2_forest_fits_its_payload():
    check_payload_clears_ground(_forest())  # 1 m cable at 2 m: 1 m above the ground


def test_a_start_on_the_ground_is_a_take_off_point():
    """Group 1 starts on the ground and climbs to its goal at 5 m: the payload lifts off in the climb."""
    check_payload_clears_ground(load_mission(shipped_config("missions/group1.toml")))


@pytest.mark.parametrize(("l_m", "ok"), [(1.69, True), (1.71, False), (2.5, False)])
def test_a_cable_longer_than_the_altitude_allows_is_refused(l_m, ok):
    m = _forest()
    m = m.with_(vehicle=replace(m.vehicle, l=l_m))
    if ok:
        check_payload_clears_ground(m)
    else:
        with pytest.raises(ConfigError, match=r"start_ned_m: the payload would hang .* fly at least"):
            check_payload_clears_ground(m)


def test_the_companions_belief_of_the_cable_is_checked_and_waypoints_too():
    m = _forest()
    with pytest.raises(ConfigError, match=r"cable 2\.50 m"):
        check_payload_clears_ground(m.with_(payload=PayloadConfig(cable_length_m=2.5)))
    low = Waypoint(np.array([5.0, 3.0, -1.2]), name="dip")
    with pytest.raises(ConfigError, match=r"waypoint 0 \(dip\)"):
        check_payload_clears_ground(m.with_(waypoints=(low,)))
