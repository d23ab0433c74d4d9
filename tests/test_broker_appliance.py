"""The default appliance (`edge-ips start`, no configuration) is closed: probed from another host, with a rover's
login, and used by the edge's own tools (`edge-ips formation`, `doctor`, `flash --bundle`) through the state
directory's logins. Real processes throughout."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from edge.broker import read_credentials
from edge.messages import FORMATION_TOPIC, ROVER_STATUS_WILDCARD, edge_status_topic, parse_status, rover_status_topic
from tests.conftest import REPO
from tests.support.mosquitto import free_port
from tests.support.probe import Probe, other_host
from tests.support.runtime import MqttRecorder, poses, stop_process

EDGE_IPS = [sys.executable, "-m", "edge.cli"]


def _env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("EDGE_IPS_")}
    return {**env, "PYTHONPATH": str(REPO), **extra}


@pytest.mark.slow
def test_the_default_appliance_is_closed_to_other_hosts_and_to_rover_logins(tmp_path: Path) -> None:
    port = free_port()
    env = _env(EDGE_IPS_BROKER__EMBEDDED_PORT=str(port))
    state = Path(os.environ["XDG_STATE_HOME"]) / "edge-ips"
    log = tmp_path / "edge.log"
    with open(log, "w") as err:
        edge = subprocess.Popen([*EDGE_IPS, "start", "--http-port", "0"], cwd=tmp_path, env=env, stderr=err)
    try:
        with MqttRecorder(
            "127.0.0.1", port, topics=("ips/v1/#", ROVER_STATUS_WILDCARD)
        ) as watcher:  # anonymous, from this machine: may read
            assert watcher.wait_for(lambda m: len(poses(m)) >= 3, 90)
            creds = read_credentials(state / "broker-credentials.toml")
            assert (state / "broker-credentials.toml").stat().st_mode & 0o777 == 0o600
            assert sorted(creds.rovers) == ["blue", "green", "red"]
            red = creds.rovers["red"]
            with other_host() as there:
                anonymous = there.probe(port, client_id="lab", publish=FORMATION_TOPIC, payload='{"from":"lan"}')
                stolen = there.probe(
                    port, client_id="rover-red", user="red", password=red.password,
                    publish=FORMATION_TOPIC, payload='{"from":"rover"}',
                )  # fmt: skip
                takeover = there.probe(port, client_id="edge-ips-edge-1", user="red", password=red.password)
                big = there.probe(port, client_id="rover-red", user="red", password=red.password,
                                  publish=rover_status_topic("red"), payload_bytes=2 << 20)  # fmt: skip
                marker = there.probe(port, client_id="rover-red", user="red", password=red.password,
                                     publish=rover_status_topic("red"), payload='{"marker":1}')  # fmt: skip
            assert marker["accepted"] and marker["published"], (marker, log.read_text()[-3000:])
            assert watcher.wait_for(lambda m: any(x.payload == b'{"marker":1}' for x in m), 30), log.read_text()[-3000:]
            refused_at = max(x.t_recv for x in watcher.messages if x.payload == b'{"marker":1}')
            status = edge_status_topic("edge-1")
            assert watcher.wait_for(lambda m: any(x.topic == status and x.t_recv > refused_at for x in m), 30)
            seen = list(watcher.messages)
    finally:
        stop_process(edge)
    stderr = log.read_text()
    assert (anonymous["accepted"], anonymous["connack"]) == (False, 5)
    assert stolen["accepted"]  # a rover's login connects ...
    assert not [x for x in seen if b'"from"' in x.payload]  # ... but publishes no formation, nor does anyone else
    assert (takeover["accepted"], takeover["connack"]) == (False, 2)
    assert big["disconnected"]
    assert "offline" not in [parse_status(x.payload).state for x in seen if x.topic == status]
    first = stderr.splitlines()[0]
    assert f"broker embedded (amqtt on 0.0.0.0:{port}; logins required, in {state}/broker-credentials.toml" in first
    assert "anonymous: read-only, from this machine only)" in first
    assert "a publish on ips/v1/formation from 'red': not in its rights" in stderr
    assert red.password not in stderr


@pytest.mark.slow
def test_the_edges_tools_use_the_state_directorys_logins(tmp_path: Path) -> None:
    port = free_port()
    env = _env(EDGE_IPS_BROKER__EMBEDDED_PORT=str(port))
    state = Path(os.environ["XDG_STATE_HOME"]) / "edge-ips"
    edge = subprocess.Popen([*EDGE_IPS, "start", "--http-port", "0"], cwd=tmp_path, env=env, stderr=subprocess.DEVNULL)
    try:
        with MqttRecorder("127.0.0.1", port, topics=[FORMATION_TOPIC, "ips/v1/rovers/+/pose"]) as watcher:
            assert watcher.wait_for(lambda m: len(poses(m)) >= 1, 90)
            cli = {"cwd": tmp_path, "env": env, "capture_output": True, "text": True}
            sent = subprocess.run([*EDGE_IPS, "formation", "stop"], **cli)  # type: ignore[call-overload]
            assert sent.returncode == 0, sent.stderr
            assert watcher.wait_for(lambda m: any(x.topic == FORMATION_TOPIC and b'"stop"' in x.payload for x in m))
            doctor = subprocess.run([*EDGE_IPS, "doctor"], **cli)  # type: ignore[call-overload]
    finally:
        stop_process(edge)
    line = next(ln for ln in doctor.stdout.splitlines() if ln.split()[1] == "broker")
    assert line.startswith("OK") and f"logins in {state}/broker-credentials.toml (mode 600)" in line
    assert "edge edge-1 is running" in line
    bundle = tmp_path / "bundle"
    flashed = subprocess.run(
        [*EDGE_IPS, "flash", "--rover", "red", "--bundle", str(bundle)],
        cwd=tmp_path,
        env={**env, "EDGE_IPS_WIFI_SSID": "lab", "EDGE_IPS_WIFI_PASSWORD": "wifi-pw"},
        capture_output=True,
        text=True,
        stdin=subprocess.DEVNULL,
    )
    assert flashed.returncode == 0, flashed.stderr
    config = json.loads((bundle / "config.json").read_text())
    red = read_credentials(state / "broker-credentials.toml").rovers["red"]
    assert (config["broker"]["user"], config["broker"]["password"]) == ("red", red.password)
    assert (bundle / "config.json").stat().st_mode & 0o777 == 0o600


@pytest.mark.slow
def test_formation_without_the_appliances_logins_says_where_they_should_be(tmp_path: Path) -> None:
    result = subprocess.run([*EDGE_IPS, "formation", "stop"], cwd=tmp_path, env=_env(), capture_output=True, text=True)
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert "no embedded broker logins yet" in result.stderr.strip().splitlines()[-1]


@pytest.mark.slow
def test_a_probe_from_this_machine_is_anonymous_and_read_only(tmp_path: Path) -> None:
    port = free_port()
    env = _env(EDGE_IPS_BROKER__EMBEDDED_PORT=str(port))
    edge = subprocess.Popen([*EDGE_IPS, "start", "--http-port", "0"], cwd=tmp_path, env=env, stderr=subprocess.DEVNULL)
    try:
        with MqttRecorder("127.0.0.1", port) as watcher:
            assert watcher.wait_for(lambda m: len(poses(m)) >= 1, 90)
            with Probe("127.0.0.1", port, client_id="local") as local:
                assert local.accepted
                local.publish(rover_status_topic("red"), b'{"anonymous":1}', retain=True)
        with Probe("127.0.0.1", port, client_id="late") as late:
            late.subscribe(rover_status_topic("red"))
            late.subscribe(edge_status_topic("edge-1"))  # retained: arrives after red's, if red's were kept
            assert late.wait(lambda: bool(late.payloads(edge_status_topic("edge-1"))))
            assert b'{"anonymous":1}' not in late.payloads(rover_status_topic("red"))  # red's own may be there
    finally:
        stop_process(edge)
