"""``slungpilot fleet N``: N bundled vehicles and N companions through one Zenoh router, real processes on loopback.

Lockstep here (deterministic, quick); the real-time figures (4 pairs, loss and tick p99) are measured by hand and
quoted in the README, since timing is never asserted in tests."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

pytestmark = pytest.mark.slow


def test_two_pairs_fly_through_one_router_and_every_swing_sample_arrives(tmp_path):
    out = subprocess.run([sys.executable, "-m", "companion.cli", "fleet", "2", "--lockstep", "--run-dir",
                          str(tmp_path)], capture_output=True, text=True, timeout=240)
    assert out.returncode == 0, out.stdout + out.stderr
    summary = json.loads((tmp_path / "fleet.json").read_text())
    assert summary["n"] == 2 and summary["codes"] == [0, 0]
    for vid in ("1", "2"):
        report = json.loads((tmp_path / f"vehicle-{vid}" / "report.json").read_text())
        assert report["outcome"] == "completed"
        published = report["zenoh"]["published"]["swing"]
        # every sample the companion published reached the subscriber on the other side of the router
        assert published > 100 and summary["swing_received"][vid] == published
        assert summary["swing_lost"].get(vid, 0) == 0
        assert f"vehicle {vid}: completed (exit 0)" in out.stdout


def test_rates_downsample_at_the_edge(tmp_path):
    """--zenoh-rates: one pair, the swing stream at 25 Hz instead of every 4 ms tick, and nothing lost."""
    out = subprocess.run([sys.executable, "-m", "companion.cli", "fleet", "1", "--lockstep", "--zenoh-rates",
                          "swing=25,state=10,setpoint=5", "--run-dir", str(tmp_path)], capture_output=True, text=True,
                         timeout=240)
    assert out.returncode == 0, out.stdout + out.stderr
    v = json.loads((tmp_path / "fleet.json").read_text())["vehicles"]["1"]
    sim_s = v["sim_time_s"]
    for stream, hz in (("swing", 25), ("state", 10), ("setpoint", 5)):
        s = v["streams"][stream]
        assert s["received"] == s["published"] and s["lost"] == 0
        # sim_time_s is the mission part; streams run from connect to landed too (about 1.5x that)
        assert 0.5 * hz * sim_s < s["received"] < 2.5 * hz * sim_s, (stream, s, sim_s)
    bad = subprocess.run([sys.executable, "-m", "companion.cli", "fly", "--sitl", "--zenoh-rates", "swing=fast"],
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "--zenoh-rates" in bad.stderr


def test_fleet_size_is_checked():
    out = subprocess.run([sys.executable, "-m", "companion.cli", "fleet", "0"], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 2 and "1..16" in out.stderr


def test_a_fleet_the_machine_cannot_carry_is_warned_of_with_the_rate_that_fits():
    from companion.cli.fleet import capacity_warning

    assert capacity_warning(4, 250.0, 2) is None  # ~1.4 cores: fits (measured: fleet 4 completes, 0 loss)
    said = capacity_warning(8, 250.0, 2)  # ~2.8 cores (measured: 6 of 8 complete, swing samples lost)
    assert said is not None and "~2.8 cores" in said and "--rate-hz 100 needs ~1.6" in said
    assert capacity_warning(8, 100.0, 2) is None  # measured: 8 of 8 complete, 0 lost, tick p99 < 0.5 ms
    said = capacity_warning(16, 250.0, 2)
    assert said is not None and "--rate-hz" not in said  # no rate fits 16 pairs on 2 cores: no hint
