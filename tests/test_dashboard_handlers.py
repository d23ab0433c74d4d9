"""The dashboard without a browser: token checks, bad input, the events and frames it serves, the configuration.

Handlers are exercised on a real appliance (fake tracker, stand-in simulator) with its real HTTP server and a real
Mosquitto; the pure parts (token, request parsing, overlays) as tables.
"""

from __future__ import annotations

import asyncio
import json
import math
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from edge.calibration import Calibration
from edge.calibration.exact import exact_calibration
from edge.camera import MARKER_HEIGHT_CM, paper_camera
from edge.config import EdgeConfig
from edge.config_text import masked
from edge.dashboard.events import EventHub, Overlay, pose_event, sse, status_event
from edge.dashboard.formation import authorize, formation_targets, parse_request, with_targets
from edge.dashboard.frames import FrameEncoder, encode_jpeg
from edge.dashboard.server import hex_color, static_files
from edge.dashboard.streams import EventFanout
from edge.errors import MessageError
from edge.messages import parse_formation
from edge.metrics import Latency, RoverSnapshot, Snapshot
from edge.tracking import Frame, FrameResult, RoverEstimate
from tests.support.appliance import edge_config, running
from tests.support.dashboard import FormationSubscriber, call, read_events
from tests.support.mosquitto import Mosquitto

TOKEN = "correct-horse-battery"
ROVERS = ("red", "green", "blue")


# -- who may command -----------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("token", "headers", "expected"),
    [
        (None, {"Authorization": f"Bearer {TOKEN}"}, 403),
        (None, {}, 403),
        (TOKEN, {}, 401),
        (TOKEN, {"Authorization": ""}, 401),
        (TOKEN, {"Authorization": "Bearer "}, 401),
        (TOKEN, {"Authorization": f"Basic {TOKEN}"}, 401),
        (TOKEN, {"Authorization": "Bearer wrong-token"}, 401),
        (TOKEN, {"Authorization": f"Bearer {TOKEN}x"}, 401),
        (TOKEN, {"Authorization": f"Bearer {TOKEN[:-1]}"}, 401),
        (TOKEN, {"Authorization": f"Bearer {TOKEN}"}, None),
        (TOKEN, {"authorization": f"bearer {TOKEN}"}, None),
        (TOKEN, {"AUTHORIZATION": f"Bearer  {TOKEN} "}, None),
    ],
)
def test_formation_commands_need_the_configured_token(
    token: str | None, headers: dict[str, str], expected: int | None
) -> None:
    refused = authorize(token, headers)
    assert (refused.status if refused else None) == expected
    if refused is not None:
        assert refused.error


# -- what a command may say ----------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("body", "names"),
    [
        (b"not json", "not JSON"),
        (b"[1, 2]", "(body)"),
        (b'{"kind": "circle", "ids": ["red"]}', "kind"),
        (b'{"ids": ["red"]}', "kind"),
        (b'{"kind": "line"}', "ids"),
        (b'{"kind": "line", "ids": "red"}', "ids"),
        (b'{"kind": "line", "ids": ["red", "purple"]}', "purple"),
        (b'{"kind": "line", "ids": ["red", "red"]}', "red named more than once"),
        (b'{"kind": "triangle", "ids": ["red", "green"]}', "at least three rovers"),
        (b'{"kind": "line", "ids": []}', "at least one rover"),
        (b'{"kind": "line", "ids": ["red", "green"], "spacing": -5}', "spacing"),
        (b'{"kind": "line", "ids": ["red", "green"], "spacing": 5000}', "spacing"),
        (b'{"kind": "line", "ids": ["red", "green"], "spacing": NaN}', "spacing"),
        (b'{"kind": "triangle", "ids": ["red", "green", "blue"], "side": 0}', "side"),
        (b'{"kind": "line", "ids": ["red"], "colour": "red"}', "colour: unknown key"),
        (b'{"kind": "line", "ids": ["red"], "theta": 99}', "theta"),
        (b"{" + b" " * 5000 + b"}", "exceeds"),
    ],
)
def test_bad_formation_requests_are_refused_naming_the_field(body: bytes, names: str) -> None:
    with pytest.raises(MessageError, match=r"formation request|formation:") as err:
        parse_request(body, ROVERS)
    assert names in str(err.value)


JSON = st.recursive(
    st.none() | st.booleans() | st.floats(allow_nan=False) | st.integers() | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
    max_leaves=12,
)
REQUESTS = st.fixed_dictionaries(
    {"kind": st.sampled_from(["line", "rendezvous", "triangle", "stop", "circle"]), "ids": st.lists(st.text())},
    optional={"spacing": JSON, "side": JSON, "x": JSON, "theta": JSON},
)


BODIES = st.binary(max_size=64) | (JSON | REQUESTS).map(lambda v: json.dumps(v).encode())


@pytest.mark.slow
@given(BODIES)
def test_any_body_is_accepted_or_refused_with_a_message_error(body: bytes) -> None:
    try:
        message = parse_request(body, ROVERS)(1)
    except MessageError as exc:
        assert str(exc).startswith(("formation request:", "formation:"))
    else:
        assert set(message.ids) <= set(ROVERS)


@pytest.mark.parametrize(
    ("body", "kind", "ids", "spacing", "side"),
    [
        ({"kind": "line", "ids": ["red", "green", "blue"], "spacing": 45, "side": 100}, "line", ROVERS, 45.0, None),
        ({"kind": "line", "ids": ["blue", "red"]}, "line", ("blue", "red"), 60.0, None),
        ({"kind": "triangle", "ids": list(ROVERS), "spacing": 60, "side": 120}, "triangle", ROVERS, None, 120.0),
        ({"kind": "rendezvous", "ids": list(ROVERS), "spacing": 60, "side": 100}, "rendezvous", ROVERS, None, None),
        ({"kind": "stop", "ids": [], "spacing": 60, "side": 100}, "stop", (), None, None),
    ],
)
def test_a_valid_request_becomes_the_formation_message(
    body: dict[str, object], kind: str, ids: tuple[str, ...], spacing: float | None, side: float | None
) -> None:
    message = parse_request(json.dumps(body).encode(), ROVERS)(7)
    assert (message.seq, message.kind, tuple(message.ids), message.spacing, message.side) == (
        7,
        kind,
        ids,
        spacing,
        side,
    )


# -- what the page is told -----------------------------------------------------------------------------------------
def _estimate(rover: str, x: float, y: float, theta: float | None, cal: Calibration | None) -> RoverEstimate:
    uv = cal.world_to_pixel(np.array([[x, y]]))[0] if cal is not None else np.array([0.0, 0.0])
    return RoverEstimate(rover, x, y, theta, 1.0, -2.0, 0.9, (float(uv[0]), float(uv[1])))


def test_pose_event_projects_each_marker_outline_and_heading_into_the_image() -> None:
    cal = exact_calibration(paper_camera((-0.12, 0.04, 0.0, 0.0, 0.0)))
    result = FrameResult(
        12,
        1000.0,
        5.0,
        (
            _estimate("red", 100.0, 200.0, 0.0, cal),
            _estimate("green", 300.0, 400.0, math.pi / 2, cal),
            _estimate("blue", 200.0, 100.0, None, cal),
            _estimate("stranger", 50.0, 50.0, 0.0, cal),
        ),
        ("yellow",),
    )
    event = pose_event(result, Overlay(cal, 21.5, 16.8), ["red", "green", "blue", "yellow"])
    assert event["frame"] == 12 and event["missing"] == ["yellow"]
    by_id = {r["id"]: r for r in event["rovers"]}
    assert set(by_id) == {"red", "green", "blue"}  # a rover the configuration does not know is not shown
    assert "outline" not in by_id["blue"] and "head_u" not in by_id["blue"]  # no heading: the page draws a circle
    for rover_id, (x, y, theta) in {"red": (100.0, 200.0, 0.0), "green": (300.0, 400.0, math.pi / 2)}.items():
        item = by_id[rover_id]
        outline_px = np.array(item["outline"])
        back = cal.pixel_to_world(outline_px)  # the outline is the marker's rectangle on the marker plane
        local = back - [x, y]
        along = local @ [math.cos(theta), math.sin(theta)]
        across = local @ [-math.sin(theta), math.cos(theta)]
        assert np.abs(along).max() == pytest.approx(21.5 / 2, abs=0.1)
        assert np.abs(across).max() == pytest.approx(16.8 / 2, abs=0.1)
        tip = cal.pixel_to_world(np.array([[item["head_u"], item["head_v"]]]))[0]
        assert tip == pytest.approx([x + 30.0 * math.cos(theta), y + 30.0 * math.sin(theta)], abs=0.1)
        assert (item["vx"], item["vy"], item["q"]) == (1.0, -2.0, 0.9)


def test_pose_event_without_calibration_has_positions_but_no_outlines() -> None:
    result = FrameResult(3, 1.0, 1.0, (_estimate("red", 10.0, 20.0, 0.5, None),), ())
    event = pose_event(result, Overlay(None), ["red"])
    assert event["rovers"][0]["x"] == 10.0 and "outline" not in event["rovers"][0]
    assert Overlay(None).area_px() == []


def _snapshot(p99_s: float) -> Snapshot:
    lat = Latency(0.004, 0.006, p99_s, 10, 0.05)
    rover = RoverSnapshot("red", 10, 0, None, 0.0, None, None, None, None)
    return Snapshot(
        "edge-t", "online", "", "ok", "sim", "b", 1.0, 30.0, 10, 0, lat, lat, (rover,), True, 1, 0, 10, 0, 0, 0, 0, 0, 0
    )


def test_status_event_is_json_even_before_the_first_measurement() -> None:
    event = status_event(_snapshot(math.nan))
    assert event["latency_ms"] == {"p50": 4.0, "p99": None}
    assert event["rovers"]["red"] == {"last_seen_s": None, "rate_hz": 0.0, "q": None}
    assert event["broker"] == "connected"
    assert sse("status", event).startswith(b"event: status\ndata: {")


@pytest.mark.parametrize(
    ("bgr", "css"), [((40, 40, 200), "#c82828"), ((255, 0, 0), "#0000ff"), ((0, 300, -1), "#00ff00")]
)
def test_rover_colours_are_css_colours(bgr: tuple[int, int, int], css: str) -> None:
    assert hex_color(bgr) == css


def test_the_page_is_shipped_in_the_package() -> None:
    files = static_files()
    assert {"index.html", "app.js", "style.css"} <= set(files)
    assert b'src="static/app.js"' in files["index.html"][0]
    assert files["app.js"][1].startswith("text/javascript")


# -- one build per tick, for every viewer --------------------------------------------------------------------------
def test_event_hub_starts_only_for_a_viewer_and_hands_each_event_to_all() -> None:
    results = [FrameResult(1, 1.0, 1.0, (), ())]
    built: list[int] = []
    hub = EventHub(
        latest=lambda: results[-1],
        make_pose=lambda r: built.append(r.frame_index) or {"frame": r.frame_index},
        make_status=lambda: {"state": "online"},
        pose_hz=50.0,
    )
    assert hub._thread is None  # nobody watching: nothing runs
    one, two = hub.stream([("hello", 1)]), hub.stream()
    assert next(one).endswith(b"event: hello\ndata: 1\n\n") and next(two) == b"retry: 2000\n\n"
    assert hub.viewers == 2
    # a new result once both viewers are in (the first pose may have gone out before the second joined)
    results.append(FrameResult(2, 2.0, 2.0, (), ()))
    hub.publish("formation", {"kind": "line"})
    for stream in (one, two):
        seen = b""
        for _ in range(20):
            if b"event: formation" in seen and b'"frame":2' in seen and b"event: status" in seen:
                break
            seen += next(stream)
        assert b'event: formation\ndata: {"kind":"line"}\n\n' in seen
        assert b'event: pose\ndata: {"frame":2}\n\n' in seen and b'event: status\ndata: {"state":"online"}' in seen
    assert built in ([1, 2], [2])  # one pose event built per result, whatever the number of viewers
    one.close()
    assert hub.viewers == 1
    hub.close()
    assert list(two) == []  # closing the hub ends the streams


def test_pages_share_one_hub_viewer_and_the_hub_sleeps_when_they_leave() -> None:
    hub = EventHub(
        latest=lambda: None, make_pose=lambda r: {}, make_status=lambda: {"state": "online"}, status_interval_s=600.0
    )
    fanout = EventFanout(hub.stream, queue_size=4)

    async def watch() -> threading.Thread:
        pages = [fanout.stream(f"hello {k}\n".encode()) for k in range(3)]
        assert [await page.__anext__() for page in pages] == [b"hello 0\n", b"hello 1\n", b"hello 2\n"]
        assert fanout.pages == 3 and fanout._thread is not None
        thread = fanout._thread

        def joined() -> bool:  # the hub notifies its condition when a viewer joins
            with hub._cond:
                return hub._cond.wait_for(lambda: bool(hub._viewers), timeout=30)

        assert await asyncio.to_thread(joined)  # the fan-out thread has joined the hub
        hub.publish("formation", {"kind": "line"})
        for page in pages:  # every page gets it (after the hub's first status), through one viewer of the hub
            received = b""
            while b"event: formation" not in received:
                received += await asyncio.wait_for(page.__anext__(), 30)
            assert b'event: formation\ndata: {"kind":"line"}\n\n' in received
        assert hub.viewers == 1
        for page in pages:
            await page.aclose()
        assert fanout.pages == 0
        return thread

    thread = asyncio.run(watch())
    hub.publish("formation", None)  # the next chunk finds no page: the thread leaves and the hub has no viewer
    thread.join(30)
    assert not thread.is_alive() and hub.viewers == 0
    hub.close()


def test_closing_the_hub_ends_every_page() -> None:
    hub = EventHub(latest=lambda: None, make_pose=lambda r: {}, make_status=lambda: {}, status_interval_s=600.0)
    fanout = EventFanout(hub.stream)

    async def watch() -> list[list[bytes]]:
        pages = [fanout.stream(b"hello\n") for _ in range(2)]
        for page in pages:
            await page.__anext__()
        await asyncio.get_running_loop().run_in_executor(None, hub.close)
        return [[chunk async for chunk in page] for page in pages]  # each ends (an endless page would hang here)

    assert all(b"hello" not in b"".join(rest) for rest in asyncio.run(watch()))
    assert fanout.pages == 0


# -- the camera view -----------------------------------------------------------------------------------------------
def test_jpeg_is_downscaled_to_the_configured_width() -> None:
    image = np.zeros((720, 1280, 3), dtype=np.uint8)
    image[300:420, 600:680] = (0, 0, 255)
    jpeg, w, h = encode_jpeg(image, max_width_px=640, quality=70)
    decoded = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
    assert (w, h) == (640, 360) and decoded.shape == (360, 640, 3)
    assert decoded[180, 320, 2] > 200 and decoded[20, 20, 2] < 30


@pytest.mark.slow
def test_frames_are_encoded_only_when_asked_and_once_per_new_frame() -> None:
    frames = [Frame(np.full((240, 320, 3), 10, dtype=np.uint8), 0, 1.0, 1.0)]
    encoder = FrameEncoder(lambda: frames[-1], max_fps=30.0, max_width_px=160)
    try:
        assert encoder._thread is None and encoder.encoded == 0  # no viewer: no thread, no encoding
        first = encoder.next_frame()
        assert first is not None and first.index == 0 and (first.width_px, first.height_px) == (160, 120)
        again = encoder.next_frame(timeout_s=0.0)  # no new frame: the one held
        assert again is not None and again.seq == first.seq
        frames.append(Frame(np.full((240, 320, 3), 200, dtype=np.uint8), 1, 2.0, 2.0))
        second = encoder.next_frame()
        # the next encoding is the new frame's: the first was not encoded twice meanwhile
        assert second is not None and second.index == 1 and second.seq == first.seq + 1 and encoder.encoded == 2
    finally:
        encoder.close()


@pytest.mark.slow
def test_with_wait_next_the_encoder_works_right_after_each_tracked_frame() -> None:
    # The appliance hands the encoder runtime.last_frame and EdgeRuntime.wait_tracked; here a list and a semaphore.
    tracked: list[Frame] = []
    done = threading.Semaphore(0)
    woken: list[float] = []

    def wait_next(timeout_s: float) -> None:
        if done.acquire(True, timeout_s):
            woken.append(time.monotonic())

    def track(value: int) -> None:
        tracked.append(Frame(np.full((240, 320, 3), value, dtype=np.uint8), len(tracked), 1.0, 1.0))
        done.release()

    encoder = FrameEncoder(
        lambda: tracked[-1] if tracked else None, max_fps=30.0, max_width_px=160, wait_next=wait_next
    )
    try:
        # Nothing tracked yet: nothing to encode (and nothing was meanwhile: below, the encodings are the frames')
        assert encoder.next_frame(timeout_s=0.0) is None
        track(10)
        first = encoder.next_frame()
        assert first is not None and first.index == 0 and woken  # encoded after the tracker said it was done
        track(200)
        second = encoder.next_frame()
        assert second is not None and second.index == 1 and encoder.encoded == 2 and len(woken) == 2
    finally:
        encoder.close()


# -- the handlers on a running appliance ---------------------------------------------------------------------------
def _config(broker: Mosquitto, **overrides: object) -> EdgeConfig:
    return edge_config(**{"http.enabled": True, "http.port": 0, "broker.url": broker.url, **overrides})


@pytest.mark.slow
def test_state_events_frames_and_error_map_are_served(mosquitto: Mosquitto) -> None:
    with running(_config(mosquitto)) as app:
        port = app.http.port
        page = call(port, "GET", "/")
        assert page.status == 200 and page.headers["content-type"].startswith("text/html")
        assert call(port, "GET", "/static/app.js").status == 200
        state = call(port, "GET", "/api/state").json()
        assert state["edge_id"] == "edge-t" and [r["id"] for r in state["rovers"]] == ["red", "green", "blue"]
        assert state["formation_enabled"] is False and state["image"] == {"width": 320, "height": 240}
        assert state["area"]["width_cm"] == pytest.approx(391.5)
        events = read_events(port, {"status": 2, "pose": 3})
        frames = [p["frame"] for p in events["pose"]]
        assert frames == sorted(frames) and len(set(frames)) == len(frames)  # only new results are sent
        assert {r["id"] for r in events["pose"][-1]["rovers"]} == {"red", "green", "blue"}
        assert events["status"][-1]["broker"] == "connected"
        # nothing but the appliance's own retained stop (once the page's watcher has it)
        assert events["formation"] and all(f is None or f["kind"] == "stop" for f in events["formation"])
        jpeg = call(port, "GET", "/api/frame.jpg")
        assert jpeg.status == 200 and jpeg.headers["content-type"] == "image/jpeg"
        assert cv2.imdecode(np.frombuffer(jpeg.body, np.uint8), cv2.IMREAD_COLOR).shape == (240, 320, 3)
        nxt = call(port, "GET", "/api/frame.jpg")
        assert int(nxt.headers["x-frame-seq"]) > int(jpeg.headers["x-frame-seq"])
        errormap = call(port, "GET", "/api/errormap.png")
        assert errormap.status == 200 and errormap.body.startswith(b"\x89PNG")
        assert call(port, "GET", "/healthz").status in (200, 503)


@pytest.mark.slow
def test_formation_controls_are_off_without_a_token(mosquitto: Mosquitto) -> None:
    with running(_config(mosquitto)) as app:
        reply = call(
            app.http.port,
            "POST",
            "/api/formation",
            json.dumps({"kind": "line", "ids": ["red"]}).encode(),
            {"Authorization": "Bearer anything-at-all"},
        )
        assert reply.status == 403 and "no dashboard token" in reply.json()["error"]


@pytest.mark.slow
def test_formation_post_publishes_only_with_the_token(mosquitto: Mosquitto) -> None:
    subscriber = FormationSubscriber("127.0.0.1", mosquitto.port)
    line = json.dumps({"kind": "line", "ids": ["red", "green"], "spacing": 50}).encode()
    try:
        with running(_config(mosquitto, **{"dashboard.token": TOKEN})) as app:
            port = app.http.port
            auth = {"Authorization": f"Bearer {TOKEN}"}
            assert subscriber.next()[0]["kind"] == "stop"  # the appliance's own retained stop at start (seq 1)
            assert call(port, "GET", "/api/state", headers=auth).json()["formation_enabled"] is True
            refused = [
                call(port, "POST", "/api/formation", line),
                call(port, "POST", "/api/formation", line, {"Authorization": "Bearer not-the-token"}),
                call(port, "POST", "/api/formation", b'{"kind": "line"}', {"Authorization": "Bearer wrong"}),
                call(port, "POST", "/api/formation", b'{"kind": "zigzag"}', {"Authorization": f"Bearer {TOKEN}"}),
                call(port, "POST", "/api/formation", b"x" * 70_000, {"Authorization": f"Bearer {TOKEN}"}),
            ]
            assert [r.status for r in refused] == [401, 401, 401, 400, 413]
            assert refused[0].headers["www-authenticate"].startswith("Bearer")
            assert "kind" in refused[3].json()["error"]
            ok = call(port, "POST", "/api/formation", line, {"Authorization": f"Bearer {TOKEN}"})
            assert ok.status == 200 and ok.json()["seq"] == 2
            message, _ = subscriber.next()
            # the next formation on the broker is the accepted one: the refused requests published nothing
            assert parse_formation(json.dumps(message).encode()).model_dump(exclude_none=True) == {
                "v": 1,
                "seq": 2,
                "kind": "line",
                "ids": ["red", "green"],
                "spacing": 50.0,
            }
            stop = call(port, "POST", "/api/formation", b'{"kind":"stop","ids":[]}', auth)
            assert stop.json()["seq"] == 3 and subscriber.next()[0]["kind"] == "stop"
            events = read_events(port, {"formation": 1}, headers=auth)
            assert events["formation"][0]["kind"] == "stop"  # a new page learns the retained formation at once
            assert call(port, "GET", "/api/state", headers=auth).json()["formation"]["seq"] == 3
    finally:
        subscriber.close()


@pytest.mark.slow
def test_no_dashboard_leaves_health_and_metrics(mosquitto: Mosquitto) -> None:
    with running(_config(mosquitto, **{"dashboard.enabled": False})) as app:
        assert app.dashboard is None
        assert call(app.http.port, "GET", "/").status == 404
        assert call(app.http.port, "GET", "/api/state").status == 404
        assert call(app.http.port, "GET", "/metrics").status == 200


# -- configuration ---------------------------------------------------------------------------------------------------
def test_the_token_is_masked_and_settings_are_validated(tmp_path: Path) -> None:
    from edge.config_load import load_config
    from edge.errors import ConfigError

    config = EdgeConfig.model_validate({"dashboard": {"token": TOKEN, "viewer_token": "viewer-only-1", "frame_fps": 5}})
    shown = masked(config)["dashboard"]
    assert shown["token"] == shown["viewer_token"] == "********" and shown["frame_fps"] == 5.0
    assert TOKEN not in json.dumps(masked(config)) and "viewer-only-1" not in json.dumps(masked(config))
    bad = tmp_path / "edge-ips.toml"
    for text, key in [
        ('[dashboard]\ntoken = "short"\n', "dashboard.token"),
        ("[dashboard]\nframe_fps = 0\n", "dashboard.frame_fps"),
        ("[dashboard]\njpeg_quality = 101\n", "dashboard.jpeg_quality"),
        ("[dashboard]\nframes = 3\n", "dashboard.frames: unknown key"),
        ('[dashboard]\nviewer_token = "short"\n', "dashboard.viewer_token"),
        ('[http]\nallowed_hosts = ["http://edge.lab/"]\n', "http.allowed_hosts: 'http://edge.lab/' is not a host name"),
        ('[http]\nallowed_hosts = "edge.lab"\n', "http.allowed_hosts"),
        ("[http]\nmax_connections = 1\n", "http.max_connections"),
        ("[http]\nrequest_timeout_s = 0\n", "http.request_timeout_s"),
        ("[http]\nmax_streams = 0\n", "http.max_streams"),
    ]:
        bad.write_text(text)
        with pytest.raises(ConfigError, match=key):
            load_config(bad)
    env = load_config(None, {"EDGE_IPS_DASHBOARD__TOKEN": TOKEN}).config
    assert env.dashboard.token is not None and env.dashboard.token.get_secret_value() == TOKEN


@pytest.mark.slow
def test_calibration_panel_from_a_point_pair_file(tmp_path: Path) -> None:
    from edge.calibration import save_calibration
    from edge.calibration.points import calibrate_points, point_table
    from edge.dashboard.calibration_view import CalibrationView

    camera = paper_camera()
    gx, gy = np.meshgrid(np.linspace(20, 370, 6), np.linspace(20, 530, 7))
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    uv = camera.project(np.column_stack([xy, np.full(len(xy), MARKER_HEIGHT_CM)]))
    uv += np.random.default_rng(1).normal(0.0, 0.4, uv.shape)
    result = calibrate_points(point_table(uv, xy), (1280, 720), area_cm=(0.0, 0.0, 391.5, 549.5))
    path = tmp_path / "calibration.json"
    save_calibration(result.record, path)
    view = CalibrationView(result.calibration, simulated=False, path=path)
    summary = view.summary()
    assert summary is not None and summary["method"] == "points" and summary["exact"] is False
    assert result.error_map is not None
    assert summary["mean_cm"] == pytest.approx(result.error_map.mean_cm, abs=1e-3)
    assert "clicked by hand" in summary["note"] and "--refine-on" in summary["note"]  # 0.4 px of click noise
    exact = calibrate_points(
        point_table(camera.project(np.column_stack([xy, np.full(len(xy), 13.0)])), xy), (1280, 720)
    )
    save_calibration(exact.record, tmp_path / "exact.json")
    refined_view = CalibrationView(exact.calibration, simulated=False, path=tmp_path / "exact.json").summary()
    assert refined_view is not None and refined_view["note"] == ""  # points to a few hundredths: nothing to say
    png = cv2.imdecode(np.frombuffer(view.png(), np.uint8), cv2.IMREAD_COLOR)
    assert png.shape[0] > 300 and png.shape[1] > 600
    simulated = CalibrationView(exact_calibration(camera), simulated=True)
    assert simulated.summary() == {
        "method": "simulator",
        "exact": True,
        "mean_cm": 0.0,
        "max_cm": 0.0,
        "note": "simulated camera: its exact calibration, no mapping error",
    }
    assert simulated.png().startswith(b"\x89PNG") and CalibrationView(None, simulated=False).summary() is None


@pytest.mark.slow
def test_start_with_no_dashboard_serves_no_page(mosquitto: Mosquitto, tmp_path: Path) -> None:
    from tests.support.dashboard import clean_env, edge_start

    args = ["--source", "sim", "--broker", mosquitto.url, "--no-dashboard"]
    with edge_start(args, tmp_path, clean_env()) as edge:
        assert call(edge.http_port, "GET", "/").status == 404
        assert call(edge.http_port, "GET", "/api/events").status == 404
        assert call(edge.http_port, "GET", "/healthz").status == 200
    assert "dashboard on" not in edge.log()


# -- formation target on the map ---------------------------------------------------------------------------------
def _formation(kind: str, **fields: object) -> dict[str, object]:
    base: dict[str, object] = {"v": 1, "seq": 1, "kind": kind, "ids": ["red", "green", "blue"]}
    base.update({"spacing": None, "side": None, "x": None, "y": None, "theta": None, **fields})
    return base


def test_an_unanchored_triangle_is_drawn_turned_and_mirrored_to_fit_the_rovers() -> None:
    # Rovers already nearly in a triangle that is upside down and mirrored against the formation frame.
    at = {"red": (200.0, 150.0), "green": (150.0, 240.0), "blue": (250.0, 240.0)}
    targets = formation_targets(_formation("triangle", side=100.0), at)
    assert targets is not None and [t["id"] for t in targets] == ["red", "green", "blue"]
    xy = {t["id"]: (t["x"], t["y"]) for t in targets}
    sides = [math.dist(xy[a], xy[b]) for a, b in (("red", "green"), ("green", "blue"), ("blue", "red"))]
    assert sides == pytest.approx([100.0] * 3, abs=0.01)
    assert all(math.dist(xy[r], at[r]) < 15.0 for r in at)  # each corner is the one nearest its rover
    mean = np.mean(list(at.values()), axis=0)
    assert np.mean(list(xy.values()), axis=0) == pytest.approx(mean)  # placed on the rovers' mean


def test_targets_of_a_line_an_anchored_formation_missing_rovers_and_stop() -> None:
    at = {"red": (100.0, 100.0), "green": (200.0, 120.0), "blue": (150.0, 300.0)}
    line = formation_targets(_formation("line", spacing=60.0), at)
    assert line is not None and {t["x"] for t in line} == {150.0} and [t["y"] for t in line] == [113.33, 173.33, 233.33]
    anchored = formation_targets(_formation("line", spacing=60.0, x=50.0, y=60.0, theta=0.0), at)
    assert anchored is not None and [(t["x"], t["y"]) for t in anchored] == [(50.0, 0.0), (50.0, 60.0), (50.0, 120.0)]
    two = formation_targets(_formation("rendezvous"), {"red": at["red"], "green": at["green"]})
    assert two is not None and [t["id"] for t in two] == ["red", "green"]
    assert formation_targets(_formation("stop"), at) is None and formation_targets(None, at) is None
    assert formation_targets(_formation("line"), {}) is None


def test_the_pose_event_carries_the_targets_of_the_rovers_it_places() -> None:
    event = {"frame": 1, "t": 0.0, "missing": ["blue"], "rovers": [{"id": "red", "x": 10.0, "y": 20.0}]}
    assert with_targets(event, None)["targets"] is None
    placed = with_targets(event, _formation("rendezvous"))
    assert placed["targets"] == [{"id": "red", "x": 10.0, "y": 20.0}] and placed["rovers"] == event["rovers"]
