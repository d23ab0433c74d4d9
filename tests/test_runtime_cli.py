"""The appliance's commands: help with examples, clear one-line errors with exit code 2, config, formation, doctor."""

from __future__ import annotations

import json
import os
import re
import socket
import subprocess
import tomllib
from collections.abc import Iterator
from pathlib import Path

import click
import pytest
from click.testing import CliRunner, Result

from edge.broker import write_mosquitto_config
from edge.cli import main
from edge.messages import FORMATION_TOPIC, parse_formation
from tests.conftest import REPO
from tests.support.appliance import edge_config as make_config
from tests.support.appliance import running
from tests.support.mosquitto import Mosquitto, free_port
from tests.support.runtime import MqttRecorder, poses, write_clip

EDGE_IPS = REPO / ".venv" / "bin" / "edge-ips"


def _commands(group: click.Group, prefix: tuple[str, ...] = ()) -> Iterator[tuple[str, ...]]:
    for name, command in group.commands.items():
        yield (*prefix, name)
        if isinstance(command, click.Group):
            yield from _commands(command, (*prefix, name))


@pytest.mark.parametrize("path", list(_commands(main)), ids=" ".join)
def test_every_command_has_help_with_an_example(path: tuple[str, ...]) -> None:
    result = CliRunner().invoke(main, [*path, "--help"])
    assert result.exit_code == 0, result.output
    assert "Example:" in result.output


@pytest.fixture
def env(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> dict[str, str]:
    """A clean working directory and environment: no configuration found, free ports."""
    monkeypatch.chdir(tmp_path)
    for key in [k for k in os.environ if k.startswith("EDGE_IPS_")]:
        monkeypatch.delenv(key)
    return {"EDGE_IPS_BROKER__EMBEDDED_PORT": "0"}


def _run(args: list[str], env: dict[str, str]) -> Result:
    return CliRunner().invoke(main, args, env=env, catch_exceptions=False)


def _one_line_error(result: Result, pattern: str) -> None:
    import re

    assert result.exit_code == 2, result.output
    lines = [ln for ln in result.output.splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.startswith("Error: ")]
    assert len(errors) == 1 and "Traceback" not in result.output, result.output
    assert re.search(pattern, errors[0]), errors[0]


@pytest.mark.parametrize(
    ("config_text", "extra_env", "args", "pattern"),
    [
        ("[camera\n", {}, [], r"edge-ips.toml: invalid TOML"),
        ("[camera]\nfsp = 30\n", {}, [], r"edge-ips.toml: camera.fsp: unknown key"),
        ("", {"EDGE_IPS_CAMERA__FPS": "fast"}, [], r"environment variable EDGE_IPS_CAMERA__FPS: camera.fps"),
        ("", {}, ["--broker", "tcp://x"], r"command line: broker.url: 'tcp://x' is not a broker URL"),
        ("", {}, ["--source", "/dev/video7"], r"no camera at /dev/video7 .*--source sim"),
        ("[camera]\nsource = '/dev/video9'\n", {}, [], r"no camera at /dev/video9 .*--source sim"),
        ("", {}, ["--source", "CLIP"], r"no calibration configured: set calibration.path in .*edge-ips.toml"),
        ("[calibration]\npath = 'cal.json'\n", {}, ["--source", "CLIP"], r"cal.json: calibration file not found"),
        ("[broker]\nca_file = 'ca.pem'\nurl = 'mqtts://localhost'\n", {}, [], r"broker.ca_file: .*ca.pem not found"),
    ],
)
def test_start_refuses_bad_setups_before_starting(
    tmp_path: Path, env: dict[str, str], config_text: str, extra_env: dict[str, str], args: list[str], pattern: str
) -> None:
    (tmp_path / "edge-ips.toml").write_text(config_text)
    clip = write_clip(tmp_path / "clip.avi", frames=3)
    args = [str(clip) if a == "CLIP" else a for a in args]
    _one_line_error(_run(["start", "--http-port", "0", *args], {**env, **extra_env}), pattern)


def test_start_refuses_a_calibration_made_for_another_resolution(tmp_path: Path, env: dict[str, str]) -> None:
    from edge.calibration import save_calibration
    from edge.calibration.exact import exact_calibration
    from edge.camera import paper_camera

    save_calibration(exact_calibration(paper_camera()), tmp_path / "cal.json")  # 1280x720
    (tmp_path / "edge-ips.toml").write_text("[calibration]\npath = 'cal.json'\n")
    clip = write_clip(tmp_path / "clip.avi", frames=3)  # 320x240
    result = _run(["start", "--http-port", "0", "--source", str(clip)], env)
    _one_line_error(result, r"cal.json: calibration is for 1280x720 images but the camera delivers 320x240")


@pytest.mark.slow
def test_start_says_when_the_http_port_is_taken(env: dict[str, str]) -> None:
    with socket.socket() as holder:
        holder.bind(("0.0.0.0", 0))
        holder.listen()
        port = holder.getsockname()[1]
        result = _run(["start", "--source", "sim", "--http-port", str(port)], env)
    _one_line_error(result, rf"http: port {port} on 0.0.0.0 is already in use; choose another with --http-port")


def _real_start(tmp_path: Path, *args: str, **env_vars: str) -> subprocess.CompletedProcess[str]:
    """``edge-ips start ARGS`` as its own process (what amqtt or OpenCV log on the way reaches stderr too)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("EDGE_IPS_")}
    return subprocess.run(
        [str(EDGE_IPS), "start", *args, "--http-port", "0"],
        cwd=tmp_path,
        env={**env, **env_vars},
        capture_output=True,
        text=True,
        timeout=120,
    )


@pytest.mark.slow
def test_start_says_when_the_embedded_broker_port_is_taken_without_a_traceback(tmp_path: Path) -> None:
    with socket.socket() as holder:  # a Mosquitto service on 1883
        holder.bind(("0.0.0.0", 0))
        holder.listen()
        port = holder.getsockname()[1]
        result = _real_start(tmp_path, EDGE_IPS_BROKER__EMBEDDED_PORT=str(port))
    assert result.returncode == 2
    assert re.match(rf"Error: embedded broker: port {port} .* in use .*embedded_port", result.stderr.splitlines()[-1])
    assert "Traceback" not in result.stderr and "startup failed" not in result.stderr


@pytest.mark.slow
def test_a_missing_camera_is_a_one_line_error_from_the_real_command(tmp_path: Path) -> None:
    result = _real_start(tmp_path, "--source", "/dev/video7", EDGE_IPS_BROKER__EMBEDDED_PORT="0")
    assert result.returncode == 2
    assert result.stderr.strip().splitlines()[-1].startswith("Error: no camera at /dev/video7")
    assert "Traceback" not in result.stderr


@pytest.mark.slow
def test_a_file_that_is_not_a_video_is_a_one_line_error_without_opencv_noise(tmp_path: Path) -> None:
    (tmp_path / "junk.mp4").write_text("not a video")
    result = _real_start(tmp_path, "--source", str(tmp_path / "junk.mp4"), EDGE_IPS_BROKER__EMBEDDED_PORT="0")
    assert result.returncode == 2
    assert result.stderr.strip().splitlines()[-1] == f"Error: {tmp_path / 'junk.mp4'}: not a video file OpenCV can read"
    assert "WARN" not in result.stderr and "moov atom" not in result.stderr and "Traceback" not in result.stderr


# -- config ------------------------------------------------------------------------------------------------------
def test_config_init_writes_a_starting_file_and_show_prints_it_with_secrets_masked(env: dict[str, str]) -> None:
    assert _run(["config", "init"], env).exit_code == 0
    _one_line_error(_run(["config", "init"], env), r"edge-ips.toml: already exists")
    shown = _run(["config", "show"], {**env, "EDGE_IPS_BROKER__PASSWORD": "hunter2"})
    assert shown.exit_code == 0
    assert "hunter2" not in shown.output and 'password = "********"' in shown.output
    assert "EDGE_IPS_BROKER__PASSWORD" in shown.output.splitlines()[0]
    data = tomllib.loads(shown.output)
    assert data["camera"]["source"] == "/dev/video0"
    as_json = json.loads(_run(["config", "show", "--json"], {**env, "EDGE_IPS_BROKER__PASSWORD": "hunter2"}).output)
    assert as_json["broker"]["password"] == "********"


# -- broker-config -----------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_broker_config_command_writes_working_files(tmp_path: Path, env: dict[str, str]) -> None:
    result = _run(["broker-config", "--out", str(tmp_path / "mq"), "--rovers", "red,green"], env)
    assert result.exit_code == 0, result.output
    creds = tomllib.loads((tmp_path / "mq" / "credentials.toml").read_text())
    assert set(creds["rovers"]) == {"red", "green"}
    with Mosquitto(tmp_path / "run", conf_path=tmp_path / "mq" / "mosquitto.conf") as broker:
        url = f"mqtt://edge:{creds['edge']['password']}@127.0.0.1:{broker.port}"
        sent = _run(["formation", "stop", "--broker", url], env)
        assert sent.exit_code == 0, sent.output
        assert json.loads(sent.output)["kind"] == "stop"
    _one_line_error(_run(["broker-config", "--out", str(tmp_path / "mq")], env), r"already exist")


# -- formation ---------------------------------------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize(
    ("args", "kind", "spacing", "side", "ids"),
    [
        (["line"], "line", 60.0, None, ["red", "green", "blue"]),
        (["line", "--spacing", "45", "--rovers", "blue,red"], "line", 45.0, None, ["blue", "red"]),
        (["triangle"], "triangle", None, 100.0, ["red", "green", "blue"]),
        (["triangle", "--side", "80"], "triangle", None, 80.0, ["red", "green", "blue"]),
        (["rendezvous"], "rendezvous", None, None, ["red", "green", "blue"]),
        (["stop"], "stop", None, None, ["red", "green", "blue"]),
    ],
)
def test_formation_publishes_the_retained_message(
    mosquitto: Mosquitto,
    env: dict[str, str],
    args: list[str],
    kind: str,
    spacing: float | None,
    side: float | None,
    ids: list[str],
) -> None:
    for expected_seq in (1, 2):
        result = _run(["formation", *args, "--broker", mosquitto.url], env)
        assert result.exit_code == 0, result.output
        assert json.loads(result.output)["seq"] == expected_seq
    with MqttRecorder("127.0.0.1", mosquitto.port, topics=[FORMATION_TOPIC]) as late:
        assert late.wait_for(lambda m: len(m) >= 1, 10)
    message = parse_formation(late.messages[0].payload)
    assert late.messages[0].retain
    assert (message.kind, message.spacing, message.side, message.ids, message.seq) == (kind, spacing, side, ids, 2)


@pytest.mark.parametrize(
    ("args", "pattern"),
    [
        (["line", "--spacing", "-5"], r"formation: spacing: Input should be greater than 0"),
        (["line", "--rovers", "Red"], r"formation: ids.0"),
        (["line", "--rovers", "red,red,green"], r"formation: ids: red named more than once"),
        (["rendezvous", "--rovers", ","], r"formation: ids: a rendezvous needs at least one rover"),
        (["triangle", "--rovers", "red,green"], r"formation: ids: a triangle needs at least three rovers, got 2"),
        (["line", "--broker", "mqtt://127.0.0.1:PORT"], r"cannot reach broker mqtt://127.0.0.1:\d+"),
    ],
)
def test_formation_errors_are_one_line(env: dict[str, str], args: list[str], pattern: str) -> None:
    args = [a.replace("PORT", str(free_port())) for a in args]
    _one_line_error(_run(["formation", *args], env), pattern)


# -- doctor ------------------------------------------------------------------------------------------------------
def test_doctor_reports_one_line_per_check_with_fix_hints(tmp_path: Path, env: dict[str, str]) -> None:
    clip = write_clip(tmp_path / "clip.avi", frames=3)
    result = CliRunner().invoke(main, ["doctor", "--source", str(clip)], env=env)
    lines = result.output.strip().splitlines()
    assert [ln.split()[1] for ln in lines] == ["config", "camera", "calibration", "broker", "clock"]
    assert lines[0].startswith("OK") and lines[1].startswith("OK") and "320x240" in lines[1]
    assert lines[2].startswith("FAIL") and "-> run `edge-ips calibrate`" in lines[2]
    assert lines[3].startswith("OK") and "embedded: amqtt on 0.0.0.0:0, logins generated on the first start" in lines[3]
    assert "anonymous: read-only, this machine only; port 0 is free" in lines[3]
    assert result.exit_code == 1


@pytest.mark.slow
def test_doctor_checks_that_the_broker_lets_the_edge_publish(tmp_path: Path, env: dict[str, str]) -> None:
    passwords = {"edge": "e", "red": "r"}
    files = write_mosquitto_config(tmp_path / "mq", rovers=["red"], passwords=passwords)
    with Mosquitto(tmp_path / "run", conf_path=files.conf) as broker:
        lines = {}
        for user, port in (("edge", broker.port), ("red", broker.ports[1883])):  # red on the rovers' listener
            url = f"mqtt://{user}:{passwords[user]}@127.0.0.1:{port}"
            out = CliRunner().invoke(main, ["doctor", "--broker", url, "--source", "/dev/video7"], env=env).output
            lines[user] = next(ln for ln in out.splitlines() if ln.split()[1] == "broker")
        wrong = (
            CliRunner().invoke(main, ["doctor", "--broker", f"mqtt://edge:bad@127.0.0.1:{broker.port}"], env=env).output
        )
    assert lines["edge"].startswith("OK") and "may publish" in lines["edge"]
    assert lines["red"].startswith("FAIL") and "may not publish" in lines["red"] and "-> the ACL" in lines["red"]
    wrong_line = next(ln for ln in wrong.splitlines() if ln.split()[1] == "broker")
    assert wrong_line.startswith("FAIL") and "refused" in wrong_line


@pytest.mark.slow
def test_doctor_recognises_a_running_edge(mosquitto: Mosquitto, env: dict[str, str]) -> None:
    config = make_config(**{"broker.url": mosquitto.url, "edge.id": "edge-1"})
    with MqttRecorder("127.0.0.1", mosquitto.port) as rec, running(config):
        assert rec.wait_for(lambda m: len(poses(m)) >= 3)
        out = CliRunner().invoke(main, ["doctor", "--broker", mosquitto.url, "--source", "/dev/video7"], env=env)
    broker_line = next(ln for ln in out.output.splitlines() if ln.split()[1] == "broker")
    assert broker_line.startswith("OK") and "edge edge-1 is running" in broker_line


@pytest.mark.slow
def test_doctor_with_no_configuration_checks_the_simulator(env: dict[str, str]) -> None:
    result = CliRunner().invoke(main, ["doctor"], env=env)
    lines = {ln.split()[1]: ln for ln in result.output.strip().splitlines()}
    assert lines["camera"].startswith("OK") and "sim:lab" in lines["camera"] and "1280x720" in lines["camera"]
    assert lines["calibration"].startswith("OK") and "exact calibration" in lines["calibration"]
