"""Link health from MAVLink sequence numbers and telemetry ages (pure)."""

import pytest

from companion.flight.health import DeafSpells, LinkHealth, lockstep_telemetry_wall_s
from companion.flight.sequence import SequenceConfig


def test_loss_and_reordering_from_sequence_numbers():
    h = LinkHealth()
    for s in (250, 251, 252, 254, 255, 0, 3, 2, 4):  # 253 lost; 1 lost; 2 late (reordered, then not lost)
        h.on_frame(1, 1, s)
    assert h.frames == 9 and h.reordered == 1 and h.lost == 2
    h.on_frame(1, 1, 1)  # the other late one
    assert h.lost == 1 and h.reordered == 2
    h.on_frame(2, 1, 77)  # another source starts its own count
    assert h.lost == 1


def test_stale_ticks_are_judged_against_the_streams_own_rate():
    h = LinkHealth(period_s=0.004)
    for k in range(50):  # a 50 Hz position stream, asked for at 250 Hz: its own rate is what counts
        h.on_sample("position", 0.02 * k)
    assert not h.on_tick(0.98 + 0.02 + 0.004, 0.001)  # one interval plus a period: fine
    assert h.on_tick(0.98 + 0.02 + 0.02, 0.001)  # 3 periods beyond the interval: stale
    s = h.summary()
    assert s["stale_ticks"] == 1 and s["telemetry_age_ms_p50"] == 1.0


def test_lockstep_telemetry_ages_on_vehicle_time_while_the_vehicle_waits_on_us():
    wall = 100.0
    # the vehicle waits for our answer (its last datagram came after our last answer): current samples are current
    assert lockstep_telemetry_wall_s(wall, 99.99, 99.98, 5.0, 5.0, 5.0) == wall
    # ... but an attitude we have rejected for 0.4 s of its time is 0.4 s old, however fresh the datagrams are
    # (the old rule counted it current, and an unstable loop climbed for 4.6 s of vehicle time unnoticed)
    age = wall - lockstep_telemetry_wall_s(wall, 99.99, 99.98, 5.0, 5.0, 4.6)
    assert abs(age - 0.4) < 1e-9 and age > SequenceConfig().stale_s
    # once it has had our answer and is silent, the wall clock rules as in real time
    assert lockstep_telemetry_wall_s(wall, 99.0, 99.5, 5.0, 5.0, 5.0) == 99.0
    assert lockstep_telemetry_wall_s(wall, None, 99.5, 5.0, 5.0, 5.0) is None


def test_deaf_spells_take_our_own_stalls_out_of_the_vehicles_silence():
    d = DeafSpells(min_s=0.1)
    d.add(10.0, 10.05)  # ordinary jitter: the silence through it counts
    assert d.count == 0 and d.heard_at(9.0, 11.0) == 9.0
    d.add(20.0, 20.7)  # our loop stopped for 0.7 s
    d.add(19.95, 20.72)  # the watchdog reports the same stall: one spell, extended
    assert d.count == 1 and d.longest_s == pytest.approx(0.77)
    # last heard just before the stall: 20.8 - heard = the 0.03 s we listened, not 0.85 s
    assert 20.8 - d.heard_at(19.95, 20.8) == pytest.approx(0.08)
    assert d.heard_at(20.75, 20.8) == 20.75  # heard after the stall: nothing to take out
    assert d.heard_at(None, 20.8) is None
    # a vehicle silent for 1 s of listening after the stall is lost whatever came before
    assert 21.72 - d.heard_at(19.0, 21.72) == pytest.approx(2.72 - 0.77)
    d.add(30.0, 30.2)
    assert d.count == 2 and d.summary() == {"deaf_spells": 2, "deaf_s_max": pytest.approx(0.77)}
