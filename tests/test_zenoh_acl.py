"""Zenoh authentication and access control as shipped in config/zenoh/ (issue 9): a router that only lets named
peers write. A real flight through it: the perception node's trunk is used and avoided; another logged-in peer
can neither erase it (an empty list on the perception key) nor plant its own trunk on the path; a peer with a
wrong password cannot connect at all."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lab.procs import free_tcp_port

pytestmark = [pytest.mark.slow, pytest.mark.shares_cores]  # each flies a mission or a peer against the vehicle

ROOT = Path(__file__).resolve().parents[1]
ZCONF = ROOT / "config" / "zenoh"
FOREST = ROOT / "config" / "missions" / "forest.toml"
PASSWORDS = {"companion1": "c-secret", "perception": "p-secret", "viewer": "v-secret"}
TRUNK = {"x_m": 6.0, "y_m": 0.1, "radius_m": 0.3}
PLANTED = {"x_m": 3.0, "y_m": 0.0, "radius_m": 0.3}


def _publisher(ep: str, user: str, password: str, key: str, payload: dict, rate_hz: float = 20.0):
    return subprocess.Popen([sys.executable, "-m", "lab.zenoh_flooder", "--connect", ep, "--user", user,
                             "--password", password, "--key", key, "--payload", json.dumps(payload),
                             "--rate-hz", str(rate_hz)], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)


@pytest.fixture(scope="module")
def acl_flight(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("acl")
    port = free_tcp_port()
    ep = f"tcp/127.0.0.1:{port}"
    (tmp / "credentials.txt").write_text("".join(f"{u}:{p}\n" for u, p in PASSWORDS.items()))
    router_cfg = (ZCONF / "acl-router.json5").read_text()
    router_cfg = router_cfg.replace('"credentials.txt"', json.dumps(str(tmp / "credentials.txt")))
    router_cfg = router_cfg.replace('"tcp/127.0.0.1:7447"', json.dumps(ep))
    (tmp / "router.json5").write_text(router_cfg)
    client_cfg = (ZCONF / "client.json5").read_text().replace('"tcp/127.0.0.1:7447"', json.dumps(ep))
    (tmp / "companion.json5").write_text(client_cfg.replace('"change-me"', json.dumps(PASSWORDS["companion1"])))
    mission = tmp / "open_field.toml"
    mission.write_text(FOREST.read_text().split("[[obstacles]]")[0].replace('name = "forest"', 'name = "open_field"'))
    router = subprocess.Popen([sys.executable, "-m", "companion.cli", "zenoh-router", "--zenoh-config",
                               str(tmp / "router.json5"), "--duration", "240"], cwd=ROOT, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True)
    procs = []
    try:
        assert router.stdout is not None and "up" in router.stdout.readline()
        procs.append(_publisher(ep, "perception", PASSWORDS["perception"], "slungpilot/1/obstacles/in/perception",
                                {"obstacles": [TRUNK]}))
        # a logged-in peer that is not the perception node: erase its trunks, plant one on the path
        procs.append(_publisher(ep, "viewer", PASSWORDS["viewer"], "slungpilot/1/obstacles/in/perception",
                                {"obstacles": []}, rate_hz=50.0))
        procs.append(_publisher(ep, "viewer", PASSWORDS["viewer"], "slungpilot/1/obstacles/in/viewer",
                                {"obstacles": [PLANTED]}, rate_hz=50.0))
        wrong = _publisher(ep, "perception", "guessed", "slungpilot/1/obstacles/in/perception", {"obstacles": []})
        fly = subprocess.run([sys.executable, "-m", "companion.cli", "fly", "--sitl", "--mission", str(mission),
                              "--run-dir", str(tmp / "run"), "--no-plots", "--zenoh-config",
                              str(tmp / "companion.json5")], cwd=ROOT, capture_output=True, text=True, timeout=240)
        wrong_out, _ = wrong.communicate(timeout=60)
    finally:
        for p in [*procs, router]:
            p.terminate()
        for p in [*procs, router]:
            try:
                p.communicate(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
    return fly, tmp / "run", wrong.returncode, wrong_out


def test_the_flight_completes_through_the_acl_router(acl_flight):
    fly, run, _, _ = acl_flight
    assert fly.returncode == 0, fly.stderr[-3000:]
    rep = json.loads((run / "report.json").read_text())
    assert rep["reached_goal"] and rep["collisions"] == 0
    assert rep["zenoh"]["obstacles_in_accepted"] >= 1 and rep["zenoh"]["obstacles_in_rejected"] == 0


def test_only_the_perception_nodes_trunk_is_flown_around(acl_flight):
    _, run, _, _ = acl_flight
    log = np.load(run / "flight_log.npz")
    pos = log["pos_ned_m"]
    at_planted = np.abs(pos[:, 0] - PLANTED["x_m"]) < 0.3
    at_trunk = np.abs(pos[:, 0] - TRUNK["x_m"]) < 0.5
    assert np.max(np.abs(pos[at_planted, 1])) < 0.2, "flew around a trunk the ACL should have refused"
    assert np.max(np.abs(pos[at_trunk, 1] - TRUNK["y_m"])) > 0.58, "the perception node's trunk was erased"


def test_a_wrong_password_cannot_connect(acl_flight):
    _, _, code, out = acl_flight
    assert code == 3 and "error" in json.loads(out.strip().splitlines()[-1])
