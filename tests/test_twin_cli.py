"""The twin's command line: the dashboard's address and token on start's first line, the live twin as the default
source, and one-line errors from ``sim twin``, ``sim scatter`` and ``sim fault``."""

from __future__ import annotations

import os
import re
import stat
from pathlib import Path

import pytest
from click.testing import CliRunner, Result

from edge.cli import main


@pytest.fixture
def env(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> dict[str, str]:
    """No configuration found (a clean working directory), no EDGE_IPS_ variables but the state directory's."""
    monkeypatch.chdir(tmp_path)
    for key in [k for k in os.environ if k.startswith("EDGE_IPS_")]:
        monkeypatch.delenv(key)
    return {"EDGE_IPS_EDGE__STATE_DIR": str(tmp_path / "state")}


def _run(args: list[str], env: dict[str, str]) -> Result:
    return CliRunner().invoke(main, args, env=env, catch_exceptions=False)


def _error(result: Result) -> str:
    assert result.exit_code == 2, result.output
    errors = [ln for ln in result.output.splitlines() if ln.startswith("Error: ")]
    assert len(errors) == 1 and "Traceback" not in result.output, result.output
    return errors[0]


def test_start_prints_the_dashboards_address_with_a_token_it_keeps(tmp_path: Path, env: dict[str, str]) -> None:
    missing = str(tmp_path / "missing.avi")  # start stops at the source, after its first line
    first = _run(["start", "--source", missing, "--http-port", "8099"], env)
    _error(first)
    line = first.output.splitlines()[0]
    made = r"dashboard: http://localhost:8099/\?token=(\S+) \(the token is made now, kept in (\S+)\)"
    match = re.fullmatch(made, line)
    assert match is not None, line
    token, path = match.group(1), Path(match.group(2))
    assert path == tmp_path / "state" / "dashboard-token"
    assert path.read_text().strip() == token and stat.S_IMODE(path.stat().st_mode) == 0o600
    again = _run(["start", "--source", missing, "--http-port", "8099"], env).output.splitlines()[0]
    assert again == f"dashboard: http://localhost:8099/?token={token} (the token is kept in {path})"


def test_a_configured_token_is_not_printed_and_no_token_file_is_made(tmp_path: Path, env: dict[str, str]) -> None:
    secret = "configured-secret-token"
    result = _run(["start", "--source", str(tmp_path / "x.avi")], {**env, "EDGE_IPS_DASHBOARD__TOKEN": secret})
    assert result.output.splitlines()[0] == "dashboard: http://localhost:8080/ (with the configured dashboard.token)"
    assert secret not in result.output
    assert not (tmp_path / "state" / "dashboard-token").exists()


def test_with_nothing_configured_start_runs_the_live_twin(env: dict[str, str]) -> None:
    # The twin's rovers connect to the embedded broker's port, so a port picked at random cannot be theirs.
    error = _error(_run(["start", "--http-port", "0"], {**env, "EDGE_IPS_BROKER__EMBEDDED_PORT": "0"}))
    assert "sim:twin starts its rovers on the embedded broker's port: set broker.embedded_port" in error


@pytest.mark.parametrize(
    ("args", "pattern"),
    [
        (["sim", "twin", "--rovers", "13"], r"--rovers.*13 is not in the range 1<=x<=12"),
        (["sim", "twin", "--broker", "mqtts://localhost:8883"], r"rovers speak plain MQTT"),
        (["sim", "twin", "--credentials", "nowhere.toml", "--broker", "mqtt://127.0.0.1:1"], r"nowhere.toml: no such"),
        (["sim", "twin", "--camera-latency-ms", "-5"], r"--camera-latency-ms must be 0-1000"),
        (["sim", "scatter"], r"twin lab at .*twin.sock"),
        (["sim", "fault", "wifi", "--rover", "red"], r"twin lab at .*twin.sock"),
        (["sim", "fault", "flood"], r"'flood' is not one of"),
        (["sim", "fault", "edge", "--url", "http://127.0.0.1:9/"], r"no dashboard token \(start the appliance first"),
    ],
)
def test_the_twin_commands_say_what_is_wrong_in_one_line(env: dict[str, str], args: list[str], pattern: str) -> None:
    assert re.search(pattern, _error(_run(args, env)))


def test_an_edge_fault_with_no_edge_running_says_so(tmp_path: Path, env: dict[str, str]) -> None:
    token = {"EDGE_IPS_DASHBOARD__TOKEN": "a-token-for-the-test"}
    error = _error(_run(["sim", "fault", "broker", "--url", "http://127.0.0.1:9/"], {**env, **token}))
    assert "http://127.0.0.1:9/: no edge answers" in error


@pytest.mark.slow
def test_plot_draws_a_recordings_poses_from_its_directory(tmp_path: Path, env: dict[str, str]) -> None:
    from edge.messages import FORMATION_TOPIC, encode_pose, pose_topic
    from edge.recording import Recorder

    recorder = Recorder(tmp_path / "rec").start()
    recorder.record(FORMATION_TOPIC, b'{"v":1,"seq":1,"kind":"stop","ids":[]}', True)  # not a pose: left out
    for k in range(20):
        for n, rover in enumerate(("red", "green")):
            payload = encode_pose(rover, k, k, 1.7e9 + k / 30, 100.0 + k, 200.0 + 50 * n, 0.0, 30.0, 0.0, 0.9)
            recorder.record(pose_topic(rover), payload, False)
    recorder.close()
    result = _run(["plot", str(tmp_path / "rec"), "--out", str(tmp_path / "run.png")], env)
    assert result.exit_code == 0, result.output
    assert "(green: 20, red: 20 poses)" in result.output
    assert (tmp_path / "run.png").read_bytes().startswith(b"\x89PNG")


@pytest.mark.parametrize(
    ("argv0", "orig", "expected"),
    [
        ("/opt/venv/bin/edge-ips", ["py", "/opt/venv/bin/edge-ips", "start"], ["/opt/venv/bin/edge-ips", "start"]),
        ("/repo/edge/cli/__main__.py", ["py", "-m", "edge.cli", "start"], ["-m", "edge.cli", "start"]),
        ("/usr/lib/python3/site-packages/pytest/__main__.py", ["py", "-m", "pytest"], None),
    ],
    ids=["the edge-ips script", "python -m edge.cli", "inside a test runner"],
)
def test_a_killed_edge_restarts_as_it_was_started_and_only_when_it_is_the_command(
    monkeypatch: pytest.MonkeyPatch, argv0: str, orig: list[str], expected: list[str] | None
) -> None:
    import sys

    from edge.cli.twin import restart_argv

    monkeypatch.setattr(sys, "argv", [argv0, *orig[2:]])
    monkeypatch.setattr(sys, "orig_argv", orig)
    assert restart_argv() == expected
