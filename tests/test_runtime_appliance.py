"""The whole appliance: HTTP endpoints, recording, clean shutdown on SIGTERM in a real process."""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import urllib.error
import urllib.request
from pathlib import Path

import pytest

from edge.metrics import LatencyWindow, RateMeter
from edge.recording import Recorder, read_recording, record_line
from tests.conftest import REPO
from tests.support.appliance import edge_config, running
from tests.support.mosquitto import Mosquitto, free_port
from tests.support.runtime import MqttRecorder, poses, write_clip

pytestmark = pytest.mark.realtime

PROM_LINE = re.compile(
    r'^(# (HELP|TYPE) \w+ .+|(edge_ips|process)_\w+(\{(\w+="[^"]*",?)+\})? (-?[0-9.e+-]+|NaN|\+Inf))$'
)


def _get(url: str) -> tuple[int, bytes, str]:
    try:
        with urllib.request.urlopen(url, timeout=10) as resp:
            return resp.status, resp.read(), resp.headers.get("Content-Type", "")
    except urllib.error.HTTPError as err:
        return err.code, err.read(), err.headers.get("Content-Type", "")


def _metric(text: str, name: str) -> float:
    match = re.search(rf"^edge_ips_{name} (\S+)$", text, re.M)
    assert match, f"{name} missing from /metrics"
    return float(match.group(1))


@pytest.mark.slow
def test_healthz_and_metrics_describe_the_running_edge(mosquitto: Mosquitto) -> None:
    port = free_port()
    config = edge_config(
        **{"broker.url": mosquitto.url, "http.enabled": True, "http.host": "127.0.0.1", "http.port": port}
    )
    with MqttRecorder("127.0.0.1", mosquitto.port) as rec, running(config) as app:
        assert rec.wait_for(lambda m: len(poses(m)) >= 90)
        runtime = app.runtime
        while runtime.tracking_for_s <= runtime.settle_s:  # past the start-up grace for missing rovers
            runtime.wait_tracked(1.0)
        status, body, ctype = _get(f"http://127.0.0.1:{port}/healthz")
        assert status == 200 and ctype == "application/json"
        health = json.loads(body)
        assert health["state"] == "online" and health["broker_connected"] is True
        assert health["rovers"] == {"red": True, "green": True, "blue": True}

        status, body, ctype = _get(f"http://127.0.0.1:{port}/metrics")
        text = body.decode()
        assert status == 200 and ctype.startswith("text/plain; version=0.0.4")
        bad = [ln for ln in text.splitlines() if not PROM_LINE.match(ln)]
        assert not bad, f"not Prometheus text format: {bad[:3]}"
        assert _metric(text, "fps") > 0  # frames tracked in the last two seconds (how many depends on the machine)
        assert _metric(text, "broker_connected") == 1
        assert _metric(text, 'state{state="online"}') == 1
        assert _metric(text, 'camera_state{state="ok"}') == 1
        for rover in ("red", "green", "blue"):
            assert _metric(text, f'detections_total{{rover="{rover}"}}') >= 30
        p50 = _metric(text, 'processing_seconds{quantile="0.5"}')
        p99 = _metric(text, 'processing_seconds{quantile="0.99"}')
        e2e = _metric(text, 'end_to_end_seconds{quantile="0.5"}')
        assert 0 < p50 <= p99 and e2e >= p50
        assert _metric(text, "frames_processed_total") == _metric(text, "processing_seconds_count")
        assert _metric(text, "poses_published_total") >= 90
        assert _get(f"http://127.0.0.1:{port}/nope")[0] == 404
        assert app.runtime.snapshot().state == "online"


@pytest.mark.slow
def test_recording_keeps_every_published_byte_rotates_and_is_flushed_on_stop(
    mosquitto: Mosquitto, tmp_path: Path
) -> None:
    config = edge_config(
        **{"broker.url": mosquitto.url, "recording.dir": str(tmp_path / "rec"), "recording.max_bytes": 10_000}
    )
    with MqttRecorder("127.0.0.1", mosquitto.port) as rec:
        with running(config):
            assert rec.wait_for(lambda m: len(poses(m)) >= 300)
        assert rec.wait_for(lambda m: b'"offline"' in m[-1].payload, 10)
    lines = list(read_recording(tmp_path / "rec"))
    files = sorted((tmp_path / "rec").glob("published-*.jsonl"))
    assert len(files) >= 3 and all(f.stat().st_size <= 10_000 for f in files)
    recorded = {(ln["topic"], json.dumps(ln["payload"], separators=(",", ":"))) for ln in lines}
    received = {(m.topic, m.payload.decode()) for m in rec.messages}
    assert received <= recorded  # everything a subscriber saw is in the recording, byte for byte
    assert lines[-1]["topic"] == "ips/v1/edge/edge-t/status" and lines[-1]["payload"]["state"] == "offline"
    retained = ("ips/v1/edge/", "ips/v1/formation")  # the status, and the appliance's stop at start
    assert all(ln["retain"] == ln["topic"].startswith(retained) for ln in lines)


def test_recording_rotation_deletes_the_oldest_files(tmp_path: Path) -> None:
    recorder = Recorder(tmp_path, max_bytes=10_000, max_files=2).start()
    payload = b'{"v":1,"pad":"' + b"x" * 1000 + b'"}'
    for _ in range(50):
        recorder.record("t", payload, False)
    recorder.close()
    assert len(list(tmp_path.glob("published-*.jsonl"))) == 2
    assert recorder.lines_written == 50 and recorder.lines_dropped == 0


@pytest.mark.parametrize(
    ("payload", "expected"),
    [(b'{"a":1.50}', '{"a":1.50}'), (b"not json", '"not json"'), (b"", '""')],
)
def test_record_line_embeds_json_payloads_verbatim(payload: bytes, expected: str) -> None:
    line = record_line(12.5, "ips/v1/x", payload, True)
    assert line.endswith(b',"payload":' + expected.encode() + b"}\n")
    assert json.loads(line)["topic"] == "ips/v1/x"


@pytest.mark.slow
def test_a_finite_video_file_ends_the_run_cleanly(mosquitto: Mosquitto, tmp_path: Path) -> None:
    clip = write_clip(tmp_path / "clip.avi", frames=20)
    config = edge_config(**{"broker.url": mosquitto.url, "camera.source": str(clip), "camera.realtime": False})
    with MqttRecorder("127.0.0.1", mosquitto.port) as rec, running(config) as app:
        assert rec.wait_for(lambda m: any(b'"offline"' in x.payload for x in m), 20)
    assert app.runtime.capture.ended and app.runtime.error is None
    assert app.runtime.frames_processed <= 20 and app.runtime.capture.frames == 20


@pytest.mark.slow
def test_sigterm_publishes_offline_and_exits_zero(mosquitto: Mosquitto, tmp_path: Path) -> None:
    args = [f"broker.url={mosquitto.url}", f"recording.dir={tmp_path / 'rec'}"]
    with MqttRecorder("127.0.0.1", mosquitto.port) as rec:
        proc = subprocess.Popen(
            [sys.executable, "-m", "tests.support.edge_process", *args],
            cwd=REPO,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
        )
        try:
            assert proc.stdout is not None and proc.stdout.readline().strip() == b"ready"
            assert rec.wait_for(lambda m: len(poses(m)) >= 30)
            proc.send_signal(signal.SIGTERM)
            assert proc.wait(30) == 0
        finally:
            proc.kill()
        last = json.loads(rec.messages[-1].payload) if rec.wait_for(lambda m: b"offline" in m[-1].payload, 10) else {}
    assert last["state"] == "offline" and last["camera"] == "stopped"
    assert rec.messages[-1].topic == "ips/v1/edge/edge-t/status"
    stderr = proc.stderr.read().decode() if proc.stderr else ""
    assert "SIGTERM received: stopping" in stderr and "Traceback" not in stderr
    assert list(read_recording(tmp_path / "rec"))[-1]["payload"]["state"] == "offline"


def test_latency_window_and_rate_meter() -> None:
    window = LatencyWindow(size=4)
    for v in (1.0, 2.0, 3.0, 4.0, 100.0):
        window.add(v)
    assert window.count == 5 and window.total_s == 110.0
    assert window.quantiles((0.5,))[0] == pytest.approx(3.5)  # the oldest sample left the window
    meter = RateMeter(window_s=2.0)
    for k in range(60):
        meter.tick(10.0 + k / 30)
    assert meter.rate(12.0) == pytest.approx(30.0, abs=1)
    assert meter.rate(20.0) == 0.0
