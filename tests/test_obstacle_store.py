"""ObstacleStore: parsing, validation, merge with mission obstacles, replace, clear, expiry, moving ones."""

from __future__ import annotations

import json
import logging
import re

import pytest

from companion.core.obstacles import Obstacle
from companion.zenoh_io.obstacle_store import MAX_OBSTACLES_PER_SAMPLE, MAX_SOURCES, ObstacleStore, parse_obstacles_in

MISSION = (Obstacle(1.0, 2.0, 0.3), Obstacle(5.0, -1.0, 0.4))
TRUNK = {"x_m": 6.0, "y_m": 0.1, "radius_m": 0.3, "height_m": 4.0, "safe_distance_m": 0.1,
         "vx_mps": 0.0, "vy_mps": 0.0}
SRC = "slungpilot/1/obstacles/in/cam"


def sample(obstacles: list[dict], **extra) -> bytes:
    return json.dumps({"obstacles": obstacles, **extra}).encode()


def test_full_and_minimal_obstacle_parse_with_documented_defaults() -> None:
    obs, exp = parse_obstacles_in(sample([TRUNK, {"x_m": 1, "y_m": 2, "radius_m": 0.5}], expires_s=2.0), SRC)
    assert exp == 2.0
    assert obs[0] == Obstacle(6.0, 0.1, 0.3, 4.0, 0.1, 0.0, 0.0, SRC)
    assert obs[1] == Obstacle(1.0, 2.0, 0.5, 4.0, 0.1, 0.0, 0.0, SRC)
    assert isinstance(obs[1].x_m, float)
    assert parse_obstacles_in(sample([]), SRC) == ((), None)
    assert parse_obstacles_in(
        json.dumps({"schema": "slungpilot.obstacles_in", "version": 1, "obstacles": [], "expires_s": None}), SRC
    ) == ((), None)


@pytest.mark.parametrize(
    ("raw", "key"),
    [
        (b"not json", "sample"),
        (b"\xff\xfe", "sample"),
        (b"[1, 2]", "sample"),
        (b'{"obstacles": [{"x_m": NaN, "y_m": 0, "radius_m": 1}]}', "NaN"),
        (b'{"obstacles": [{"x_m": Infinity, "y_m": 0, "radius_m": 1}]}', "Infinity"),
        (sample([{**TRUNK, "radius_m": -0.3}]), "radius_m"),
        (sample([{**TRUNK, "radius_m": 1e6}]), "radius_m"),
        (sample([{**TRUNK, "height_m": 0.0}]), "height_m"),
        (sample([{**TRUNK, "x_m": 1e9}]), "x_m"),
        (sample([{**TRUNK, "vx_mps": 400.0}]), "vx_mps"),
        (sample([{**TRUNK, "y_m": "3"}]), "y_m"),
        (sample([{**TRUNK, "y_m": True}]), "y_m"),
        (sample([{**TRUNK, "colour": "brown"}]), "colour"),
        (sample([{**TRUNK, "source": "mission"}]), "source"),
        (sample([{"x_m": 1.0, "y_m": 2.0}]), "radius_m"),
        (sample(["trunk"]), "obstacles[0]"),
        (sample([TRUNK] * (MAX_OBSTACLES_PER_SAMPLE + 1)), "obstacles"),
        (json.dumps({"obstacle": [TRUNK]}).encode(), "obstacle"),
        (json.dumps({"obstacles": TRUNK}).encode(), "obstacles"),
        (sample([TRUNK], schema="slungpilot.swing"), "schema"),
        (sample([TRUNK], version=2), "version"),
        (sample([TRUNK], expires_s=-1.0), "expires_s"),
        (sample([TRUNK], expires_s="2"), "expires_s"),
        (b" " * (300 * 1024), "sample"),
    ],
)
def test_bad_samples_are_refused_naming_the_key(raw: bytes, key: str) -> None:
    with pytest.raises(ValueError, match=re.escape(key)):
        parse_obstacles_in(raw, SRC)


def test_merge_replace_and_clear_per_publisher() -> None:
    st = ObstacleStore()
    assert st.current(0.0, MISSION) == MISSION
    v0 = st.version
    assert st.ingest(SRC, sample([TRUNK]), now_s=1.0)
    assert st.version > v0
    cur = st.current(1.0, MISSION)
    assert cur[:2] == MISSION and len(cur) == 3 and cur[2].source == SRC and cur[2].x_m == 6.0
    other = "slungpilot/world/obstacles/lidar"
    assert st.ingest(other, sample([{"x_m": -3.0, "y_m": 1.0, "radius_m": 0.2}]), now_s=1.1)
    assert {o.source for o in st.current(1.1, MISSION)} == {"mission", SRC, other}
    # same content again: no change in version, same tuple object returned (cached)
    v1 = st.version
    first = st.current(1.2, MISSION)
    assert st.ingest(SRC, sample([TRUNK]), now_s=1.2)
    assert st.version == v1 and st.current(1.2, MISSION) is first
    # a new list replaces that publisher's list only
    assert st.ingest(SRC, sample([{**TRUNK, "x_m": 7.0}, {**TRUNK, "x_m": 8.0}]), now_s=1.3)
    xs = sorted(o.x_m for o in st.current(1.3, MISSION) if o.source == SRC)
    assert xs == [7.0, 8.0] and st.version > v1
    # empty list clears that publisher
    assert st.ingest(SRC, sample([]), now_s=1.4)
    assert [o.source for o in st.current(1.4, MISSION)] == ["mission", "mission", other]
    assert st.sources() == (other,)
    assert st.accepted_count == 5 and st.rejected_count == 0


def test_expiry_counts_from_ingest_time_and_refresh_extends_it() -> None:
    st = ObstacleStore()
    st.ingest(SRC, sample([TRUNK], expires_s=2.0), now_s=10.0)
    assert len(st.current(11.999, MISSION)) == 3
    v = st.version
    assert st.current(12.0, MISSION) == MISSION
    assert st.version == v + 1 and st.sources() == ()
    # refreshing before expiry keeps it
    st.ingest(SRC, sample([TRUNK], expires_s=1.0), now_s=20.0)
    st.ingest(SRC, sample([TRUNK], expires_s=1.0), now_s=20.9)
    assert len(st.current(21.5, ())) == 1
    assert st.current(21.9, ()) == ()
    # no expires_s: stays
    st.ingest(SRC, sample([TRUNK]), now_s=30.0)
    assert len(st.current(1e6, ())) == 1


def test_one_publisher_expiring_keeps_the_others() -> None:
    st = ObstacleStore()
    st.ingest("a", sample([TRUNK], expires_s=1.0), now_s=0.0)
    st.ingest("b", sample([{**TRUNK, "x_m": 9.0}], expires_s=5.0), now_s=0.0)
    assert [o.source for o in st.current(2.0, ())] == ["b"]
    assert st.current(5.0, ()) == ()


def test_moving_obstacle_is_advanced_from_ingest_time() -> None:
    st = ObstacleStore()
    st.ingest(SRC, sample([{**TRUNK, "vx_mps": 1.0, "vy_mps": -0.5}]), now_s=2.0)
    (o,) = st.current(4.0, ())
    assert o.x_m == pytest.approx(8.0) and o.y_m == pytest.approx(-0.9) and o.vx_mps == 1.0
    (o,) = st.current(1.0, ())  # clock before ingest: not moved backwards
    assert o.x_m == 6.0


def test_bad_samples_are_counted_ignored_and_logged_at_most_once_per_second(
    caplog: pytest.LogCaptureFixture,
) -> None:
    fake_wall = [100.0]
    st = ObstacleStore(clock=lambda: fake_wall[0])
    st.ingest(SRC, sample([TRUNK]), now_s=0.0)
    before = st.current(0.0, MISSION)
    v = st.version
    with caplog.at_level(logging.WARNING, logger="companion.zenoh_io.obstacle_store"):
        for i in range(50):
            fake_wall[0] = 100.0 + i * 0.05  # 2.5 s of wall time
            assert not st.ingest(SRC, b'{"obstacles": [{"x_m": NaN}]}', now_s=0.1)
            assert not st.ingest("slungpilot/world/obstacles/x", b"\x00garbage", now_s=0.1)
    assert st.rejected_count == 100
    assert st.version == v and st.current(0.1, MISSION) == before
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert 2 <= len(warnings) <= 3
    assert "rejected obstacle sample" in warnings[0].getMessage()
    assert "more since last report" in warnings[1].getMessage()
    assert st.last_error is not None and "garbage" not in st.last_error


def test_number_of_live_publishers_is_bounded() -> None:
    st = ObstacleStore()
    for i in range(MAX_SOURCES):
        assert st.ingest(f"p/{i}", sample([TRUNK]), now_s=0.0)
    assert not st.ingest("p/extra", sample([TRUNK]), now_s=0.0)
    assert st.ingest("p/extra", sample([]), now_s=0.0)  # clearing nothing is fine
    assert st.ingest("p/0", sample([{**TRUNK, "x_m": 1.0}]), now_s=0.0)  # known source may update
    assert len(st.current(0.0, ())) == MAX_SOURCES


def test_sample_parser_spreads_a_long_list_over_several_budgets_and_agrees_with_the_one_shot_parse():
    import json as _json

    from companion.zenoh_io.obstacle_store import SampleParser, parse_obstacles_in

    raw = _json.dumps({"obstacles": [{"x_m": 10.0 + i, "y_m": -3.0, "radius_m": 0.2 + 0.001 * i}
                                     for i in range(200)], "expires_s": 2.0}).encode()
    ticks = [0.0]

    def clock() -> float:  # every look at the clock costs 10 µs of "time"
        ticks[0] += 10e-6
        return ticks[0]

    p = SampleParser("k", raw)
    calls = 0
    while True:
        calls += 1
        if p.work(ticks[0] + 30e-6, clock):
            break
    assert calls > 5  # it stopped at the deadline and went on
    assert p.error is None and (p.obstacles, p.expires_s) == parse_obstacles_in(raw, "k")


def test_sample_parser_refuses_a_bad_item_with_its_index():
    from companion.zenoh_io.obstacle_store import SampleParser

    p = SampleParser("k", b'{"obstacles": [{"x_m": 1, "y_m": 0, "radius_m": 0.3}, {"x_m": 1, "y_m": 0}]}')
    assert p.work(1e9) and p.error == "obstacles[1].radius_m: missing required key"


N_MAX = 256 * 1024
HOSTILE = {  # each one took json.loads 1-15 ms, or raised RecursionError (not a ValueError: it escaped the parser)
    "256 kB of numbers": (b'{"obstacles": [' + b",".join([b"0"] * (N_MAX // 2 - 20)) + b"]}", "obstacles[0]"),
    "arrays nested 100k deep": (b'{"obstacles": ' + b"[" * 100_000 + b"]" * 100_000 + b"}", "obstacles[0]"),
    "a whole sample nested": (b"[" * 100_000 + b"]" * 100_000, "JSON object"),
    "objects nested in an item": (b'{"obstacles": [{"x_m": ' + b'{"a": ' * 30_000 + b"1" + b"}" * 30_001 + b"]}",
                                  "obstacles[0]"),
    "one key repeated 20k times": (b'{"obstacles": [{' + b",".join([b'"x_m": 1'] * 20_000) + b"}]}", "obstacles[0]"),
    "250 kB of whitespace": (b'{"obstacles": [' + b" " * 250_000 + b"]}", "whitespace"),
    "a 250 kB key": (b'{"' + b"a" * 250_000 + b'": 1}', "sample"),
    "a 250 kB number": (b'{"expires_s": 1' + b"0" * 250_000 + b"}", "sample"),
    "a key given twice": (b'{"obstacles": [], "obstacles": []}', "given twice"),
    "trailing data": (b'{"obstacles": []} []', "extra data"),
    "truncated": (b'{"obstacles": [{"x_m": 1, "y_m": 2, "radius_m": 0.3},', "sample"),
}


@pytest.mark.parametrize("name", sorted(HOSTILE))
def test_samples_built_to_be_slow_or_deep_are_refused_early_with_a_value_error(name: str) -> None:
    raw, key = HOSTILE[name]
    assert len(raw) <= N_MAX
    from companion.zenoh_io.obstacle_store import SampleParser

    p = SampleParser("k", raw)
    looks = [0]

    def clock() -> float:
        looks[0] += 1
        return 0.0

    assert p.work(1.0, clock), "refused within its first slice"
    assert p.error is not None and key in p.error, p.error
    assert len(p.error) < 300, "the message quotes at most a short part of what was sent"
    with pytest.raises(ValueError, match=re.escape(key)):
        parse_obstacles_in(raw, SRC)


def test_the_scanner_reads_what_json_reads() -> None:
    """Pretty-printed, escaped keys, any member order, exponents, negative zero: the same as json.loads."""
    body = {"expires_s": 2.5e0, "obstacles": [{"radius_m": 3e-1, "y_m": -0.0, "x_m": 12, "vx_mps": -1.5E-1},
                                              {"x_m": 1, "y_m": 2, "radius_m": 0.5}], "version": 1}
    for raw in (json.dumps(body).encode(), json.dumps(body, indent=4).encode(),
                json.dumps(body, separators=(",", ":")).encode(),
                b'{"obstacles": [{"x\\u005fm": 1, "y_m": 2, "radius_m": 0.5}]}'):
        obs, exp = parse_obstacles_in(raw, SRC)
        ref = json.loads(raw)
        assert exp == ref.get("expires_s")
        assert [(o.x_m, o.y_m, o.radius_m, o.vx_mps) for o in obs] == [
            (it["x_m"], it["y_m"], it["radius_m"], it.get("vx_mps", 0.0)) for it in ref["obstacles"]]


def test_an_unexpected_error_in_the_parser_refuses_that_sample_only(caplog) -> None:
    from companion.zenoh_io.obstacle_store import SampleParser

    p = SampleParser("k", 12345)  # type: ignore[arg-type]  # not bytes: len() raises TypeError inside the parser
    with caplog.at_level(logging.ERROR):
        assert p.work(1e9)
    assert p.error == "sample: could not be parsed (TypeError)" and p.work(1e9)
    assert "obstacles: parsing a sample from k failed" in caplog.text
