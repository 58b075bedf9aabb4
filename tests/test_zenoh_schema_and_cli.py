"""Telemetry encoders, session flags, in-process ZenohTelemetry logic, and the CLI tools as processes."""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from companion.cli.bench_zenoh import free_tcp_port
from companion.cli.zenoh_cmds import add_listen_parser, add_obstacles_parser, add_router_parser, load_obstacles_payload
from companion.core.obstacles import Obstacle
from companion.errors import ConfigError, LinkError
from companion.zenoh_io import schema as ts
from companion.zenoh_io.session import add_zenoh_arguments, zenoh_config, zenoh_config_from_args
from companion.zenoh_io.telemetry import ZenohTelemetry
from companion.zenoh_io.telemetry_options import TelemetryOptions, _Every

pytestmark = pytest.mark.paired  # wall clock, light: may run beside one other such test (tests/conftest.py)

ROOT = Path(__file__).resolve().parents[1]


def test_fast_encoders_give_valid_json_with_header_and_nulls_for_non_finite() -> None:
    d = json.loads(ts.encode_swing(5, "1", 0.004, 1.7e9, np.array([0.1, -0.2, math.nan, 0.4]), 0.45, "live"))
    assert d == {"schema": ts.SWING, "version": 1, "seq": 5, "vehicle_id": "1", "t_s": 0.004, "wall_s": 1.7e9,
                 "alpha_rad": 0.1, "beta_rad": -0.2, "alpha_rate_radps": None, "beta_rate_radps": 0.4,
                 "valid": True, "r_max_m": 0.45, "envelope_mode": "live"}
    d = json.loads(ts.encode_swing(6, 'a"b', 0.0, 1.0, None, math.inf, 'fixed "l"'))
    assert d["alpha_rad"] is None and d["valid"] is False and d["r_max_m"] is None
    assert d["vehicle_id"] == 'a"b' and d["envelope_mode"] == 'fixed "l"'
    d = json.loads(ts.encode_state(0, "2", 1.0, 2.0, (1, 2, 3), np.zeros(3), [0.1, 0.2, 0.3], None))
    assert d["pos_ned_m"] == [1.0, 2.0, 3.0] and d["payload_pos_ned_m"] is None and ts.decode(json.dumps(d))
    raw = ts.encode_dict(3, "1", 1.0, 2.0, {"a": np.array([1.0, np.nan]), "b": {"c": np.float32(2.5)},
                                            "o": Obstacle(1, 2, 0.3)}, ts.SETPOINT)
    d = json.loads(raw)
    assert d["a"] == [1.0, None] and d["b"] == {"c": 2.5} and d["o"]["source"] == "mission"
    with pytest.raises(ValueError, match="seq"):
        ts.encode_dict(3, "1", 1.0, 2.0, {"seq": 1}, ts.STATUS)
    with pytest.raises(ValueError, match="version"):
        ts.decode(json.dumps({**d, "version": 2}))


def test_decimation_follows_sim_time_and_restarts_when_clock_jumps() -> None:
    every = _Every(50.0)
    due = [k for k in range(60) if every.due(k * 0.004)]
    assert due == [0, 5, 10, 15, 20, 25, 30, 35, 40, 45, 50, 55]
    assert every.due(0.0)  # clock went back (new flight): due at once
    assert not every.due(0.004)
    assert all(_Every(0.0).due(t) for t in (0.0, 0.0, 1.0))


def _parse(role: str, argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    add_zenoh_arguments(p, role)
    return p.parse_args(argv)


def test_session_flags_defaults_and_overrides(tmp_path: Path) -> None:
    cfg = zenoh_config_from_args(_parse("companion", []), "companion")
    assert json.loads(cfg.get_json("listen/endpoints")) == ["tcp/127.0.0.1:7447"]
    assert json.loads(cfg.get_json("connect/endpoints")) == []
    assert json.loads(cfg.get_json("scouting/multicast/enabled")) is False
    assert json.loads(cfg.get_json("mode")) == "peer"
    cfg = zenoh_config_from_args(_parse("listener", []), "listener")
    assert json.loads(cfg.get_json("connect/endpoints")) == ["tcp/127.0.0.1:7447"]
    assert json.loads(cfg.get_json("listen/endpoints")) == []
    args = _parse("companion", ["--zenoh-connect", "tcp/10.0.0.1:7447", "--zenoh-connect", "tcp/10.0.0.2:7447",
                                "--zenoh-mode", "client", "--vehicle-id", "3"])
    cfg = zenoh_config_from_args(args, "companion")
    assert json.loads(cfg.get_json("connect/endpoints")) == ["tcp/10.0.0.1:7447", "tcp/10.0.0.2:7447"]
    assert json.loads(cfg.get_json("listen/endpoints")) == [] and args.vehicle_id == "3"
    assert json.loads(zenoh_config_from_args(_parse("router", []), "router").get_json("mode")) == "router"
    f = tmp_path / "z.json5"
    f.write_text('{ mode: "client", connect: { endpoints: ["tcp/127.0.0.1:9"] } }')
    cfg = zenoh_config_from_args(_parse("listener", ["--zenoh-config", str(f)]), "listener")
    assert json.loads(cfg.get_json("connect/endpoints")) == ["tcp/127.0.0.1:9"]
    with pytest.raises(ConfigError, match="--zenoh-listen"):
        zenoh_config("companion", listen=["not-an-endpoint"])
    bad = tmp_path / "bad.json5"
    bad.write_text("{ mode: ")
    with pytest.raises(ConfigError, match=r"bad\.json5"):
        zenoh_config("listener", config_file=bad)
    with pytest.raises(ConfigError, match="vehicle_id"):
        ZenohTelemetry(zenoh_config("companion"), TelemetryOptions(vehicle_id="world"))
    with pytest.raises(ConfigError, match="prefix"):
        ZenohTelemetry(zenoh_config("companion"), TelemetryOptions(prefix="a/*"))


def test_in_process_telemetry_rates_and_obstacle_stream_logic() -> None:
    """One process, sync use: the decimation and on-change/heartbeat rules as sequence counts."""
    ep = f"tcp/127.0.0.1:{free_tcp_port()}"
    mission = (Obstacle(1.0, 1.0, 0.3),)
    with ZenohTelemetry(zenoh_config("companion", listen=[ep]), TelemetryOptions(vehicle_id="9")) as zt:
        assert zt.is_open and zt.keys["swing"] == "slungpilot/9/swing"
        sent_obs = []
        for k in range(500):  # 2 s of sim time at 250 Hz
            t = k * 0.004
            zt.publish_swing(t, None if k % 2 else (0.1, 0.0, 0.0, 0.0), 0.4, "live")
            zt.publish_state(t, np.zeros(3), np.zeros(3), np.zeros(3), None)
            zt.publish_status(t, {"mode": "OFFBOARD"})
            obs = mission if k < 250 else (*mission, Obstacle(5.0, 0.0, 0.2, source="x"))
            if k == 260:
                obs = mission
            if zt.publish_obstacles(t, obs):
                sent_obs.append(k)
        assert zt.seq["swing"] == 500 and zt.seq["state"] == 100 and zt.seq["status"] == 2
        # heartbeat at 0 and 250 (1 s), change at 250 -> same sample, change back at 260 waits for the
        # 20 Hz cap (50 ms = 12.5 ticks) -> 263
        assert sent_obs == [0, 250, 263]
        with pytest.raises(ValueError, match="t_s"):
            zt.publish_setpoint(0.0, {"t_s": 1.0})
    assert not zt.is_open and not zt.publish_swing(3.0, None, 0.4, "live")


def test_a_busy_listen_port_is_a_link_error_naming_the_fix() -> None:
    ep = f"tcp/127.0.0.1:{free_tcp_port()}"
    with ZenohTelemetry(zenoh_config("companion", listen=[ep]), TelemetryOptions()), \
            pytest.raises(LinkError, match="another companion on this port"):
        ZenohTelemetry(zenoh_config("companion", listen=[ep]), TelemetryOptions(vehicle_id="2")).open()


def test_obstacle_file_loading_for_the_publish_tool(tmp_path: Path) -> None:
    toml = tmp_path / "m.toml"
    toml.write_text('[mission]\nname = "x"\n[[obstacles]]\nx_m = 6.0\ny_m = 0.1\nradius_m = 0.3\n')
    d = json.loads(load_obstacles_payload(toml, expires_s=2.0))
    assert d == {"obstacles": [{"x_m": 6.0, "y_m": 0.1, "radius_m": 0.3}], "expires_s": 2.0}
    js = tmp_path / "o.json"
    js.write_text(json.dumps([{"x_m": 1, "y_m": 2, "radius_m": 0.5, "vx_mps": 0.2}]))
    assert json.loads(load_obstacles_payload(js, None))["obstacles"][0]["vx_mps"] == 0.2
    js.write_text(json.dumps({"obstacles": [{"x_m": 1, "y_m": 2, "radius_m": -0.5}]}))
    with pytest.raises(ConfigError, match=r"o.json: obstacles\[0\].radius_m"):
        load_obstacles_payload(js, None)
    assert json.loads(load_obstacles_payload(js, None, clear=True))["obstacles"] == []
    with pytest.raises(ConfigError, match="not found"):
        load_obstacles_payload(tmp_path / "nope.json", None)


def test_cli_parsers_register_their_subcommands() -> None:
    p = argparse.ArgumentParser()
    sub = p.add_subparsers(dest="command")
    add_listen_parser(sub)
    add_obstacles_parser(sub)
    add_router_parser(sub)
    a = p.parse_args(["listen", "slungpilot/1/**", "--json"])
    assert a.keyexpr == "slungpilot/1/**" and a.json and callable(a.func)
    a = p.parse_args(["obstacles", "publish", "f.toml", "--world", "--expires", "2", "--repeat-hz", "5"])
    assert a.world and a.expires == 2.0 and a.repeat_hz == 5.0
    a = p.parse_args(["zenoh-router"])
    assert a.zenoh_mode is None  # the role's default (or the --zenoh-config file's mode) applies
    from companion.zenoh_io.session import zenoh_config_from_args

    assert zenoh_config_from_args(a, "router").get_json("mode") == '"router"'


def _run(args: list[str], timeout: float = 40.0) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", *args], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


@pytest.mark.slow
def test_listen_json_and_obstacles_publish_against_a_running_driver(tmp_path: Path) -> None:
    """listen --json prints the driver's samples; obstacles publish from a mission TOML reaches it."""
    ep = f"tcp/127.0.0.1:{free_tcp_port()}"
    toml = tmp_path / "trunk.toml"
    toml.write_text("[[obstacles]]\nx_m = 6.0\ny_m = 0.1\nradius_m = 0.3\n")
    drv = _run(["companion.cli.bench_zenoh", "drive", "--zenoh-listen", ep, "--vehicle-id", "5", "--realtime",
                "--ticks", "0"])
    procs = [drv]
    try:
        lis = _run(["companion.cli.zenoh_cmds", "listen", "slungpilot/5/obstacles", "--json", "--zenoh-connect", ep,
                    "--duration", "25"])
        procs.append(lis)
        pub = _run(["companion.cli.zenoh_cmds", "obstacles", "publish", str(toml), "--vehicle-id", "5", "--name", "cam",
                    "--zenoh-connect", ep, "--wait-s", "15"])
        procs.append(pub)
        out, err = pub.communicate(timeout=40)
        assert pub.returncode == 0, err
        assert "published 1 obstacles to slungpilot/5/obstacles/in/cam" in out
        deadline = time.monotonic() + 25
        found = None
        while time.monotonic() < deadline and found is None:
            line = lis.stdout.readline()
            if not line:
                break
            d = json.loads(line)
            assert d["key"] == "slungpilot/5/obstacles"
            assert d["encoding"] == "application/json;slungpilot.obstacles/v1"
            if "slungpilot/5/obstacles/in/cam" in d["sample"]["sources"]:
                found = d["sample"]
        assert found is not None and found["count"] == 3
        bad = _run(["companion.cli.zenoh_cmds", "obstacles", "publish", str(tmp_path / "missing.toml"),
                    "--zenoh-connect", ep])
        procs.append(bad)
        _, err = bad.communicate(timeout=40)
        assert bad.returncode == 2 and "missing.toml: file not found" in err
        view = _run(["companion.cli.zenoh_cmds", "listen", "--zenoh-connect", ep, "--duration", "2.5"])
        procs.append(view)
        out, err = view.communicate(timeout=40)
        assert view.returncode == 0, err
        final = out.strip().split("slungpilot listen")[-1]
        assert "alive: slungpilot/5/alive" in final
        swing_row = next(line for line in final.splitlines() if line.startswith("slungpilot/5/swing"))
        rate, count, lost = swing_row.split()[1:4]
        assert float(rate) > 0 and int(count) > 0 and int(lost) == 0
        assert "R_max" in swing_row and "[live]" in swing_row
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
            p.communicate(timeout=10)


def test_sink_publishes_a_tick_of_the_app_types() -> None:
    """ZenohTelemetrySink.on_tick with the real Estimate and Command types; payload position as the model's."""
    import threading

    import zenoh

    from companion.core.model import payload_offset_ned_m
    from companion.estimation.estimate import Estimate
    from companion.flight.core import Command
    from companion.zenoh_io.telemetry_sink import ZenohTelemetrySink

    ep = f"tcp/127.0.0.1:{free_tcp_port()}"
    got: dict[str, dict] = {}
    lock = threading.Lock()

    def on_sample(s: zenoh.Sample) -> None:
        with lock:
            got[str(s.key_expr).rsplit("/", 1)[-1]] = json.loads(s.payload.to_bytes())

    v3 = np.array([0.1, 0.2, 0.3])
    est = Estimate(t_s=0.0, pos_ned_m=np.array([1.0, 2.0, -3.0]), vel_ned_mps=v3, euler_rad=v3,
                   rates_frd_rad_s=v3, swing=np.array([0.2, -0.1, 0.0, 0.0]), swing_source="payload")
    cmd = Command(t_s=0.0, q_ned_frd_wxyz=np.array([1.0, 0, 0, 0]), thrust_n=14.7, thrust_norm=0.5,
                  euler_cmd_rad=v3, ref_pos_ned_m=v3, ref_vel_ned_mps=v3, ref_acc_ned_mps2=v3, force_att_n=v3[:2],
                  force_rep_n=v3[:2], r_max_m=0.42, envelope_mode="swing", phase="cruise", ff_accel=v3)
    with ZenohTelemetry(zenoh_config("companion", listen=[ep]), TelemetryOptions(vehicle_id="6")) as zt, \
            zenoh.open(zenoh_config("listener", connect=[ep])) as s:
        s.declare_subscriber("slungpilot/6/*", on_sample)
        deadline = time.monotonic() + 15
        while not zt._pubs["swing"].matching_status.matching and time.monotonic() < deadline:
            time.sleep(0.02)
        zt.obstacles_now(0.0, (Obstacle(5.0, 0.0, 0.3),))
        ZenohTelemetrySink(zt, cable_l_m=1.0, status_fn=lambda app: {"mode": app}).on_tick(est, cmd, "OFFBOARD")
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            with lock:
                if len(got) == 5:
                    break
            time.sleep(0.02)
    assert sorted(got) == ["obstacles", "setpoint", "state", "status", "swing"]
    assert got["swing"]["r_max_m"] == 0.42 and got["swing"]["envelope_mode"] == "swing"
    assert got["state"]["payload_pos_ned_m"] == pytest.approx(
        (est.pos_ned_m + payload_offset_ned_m(0.2, -0.1, 1.0)).tolist())
    assert got["setpoint"]["thrust_n"] == 14.7 and got["setpoint"]["q_ned_frd_wxyz"] == [1.0, 0, 0, 0]
    assert got["status"]["mode"] == "OFFBOARD" and got["obstacles"]["count"] == 1
