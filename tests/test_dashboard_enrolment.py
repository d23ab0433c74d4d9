"""The dashboard's colour enrolment without a browser: "enroll the rovers now in view".

Over HTTP on a real appliance (real server, real Mosquitto, the real tracking pipeline) whose camera is a floor the
test clears and fills with rovers the simulator renders: capture the empty floor, place the rovers, enroll; the
answer's colours and positions, the TOML it offers loading as a configuration and tracking; every refusal a 400
(or 401/403/409) with the reason. The desk's other paths (the tracker's background model, saving) on the desk
itself, with a stand-in for the running appliance.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from edge.appliance import Appliance
from edge.background import BackgroundModel
from edge.config_load import load_config
from edge.dashboard.enrolment import (
    MIN_KNOWN_SHARE,
    EnrolDesk,
    EnrolRequest,
    Refused,
    marker_json,
    parse_body,
    tracked_on,
    tracker_model,
)
from edge.enroll import EnrolledMarker
from edge.httpserver import Request
from edge.sim.scene import RoverLook, fleet_looks, marker_albedo_for_hue
from edge.tracker_config import RoverConfig, TrackerConfig
from edge.trackers.factory import build_tracker
from edge.tracking import Frame, FrameResult, RoverEstimate
from tests.support.dashboard import call
from tests.support.lab import Lab, Stage, lab_appliance, track, tracked_since, until_tracking
from tests.support.mosquitto import Mosquitto

TOKEN = "enrol-control-token"
VIEWER = "enrol-viewer-token"
CONTROL = {"Authorization": f"Bearer {TOKEN}", "Content-Type": "application/json"}
POSES = [(100.0, 150.0, 0.3), (250.0, 300.0, 1.2), (180.0, 460.0, -0.7)]  # red, green, blue
MOVED = [(300.0, 120.0, 0.0), (80.0, 330.0, 2.0), (260.0, 480.0, 1.0)]  # the same rovers elsewhere


@pytest.fixture(scope="module")
def lab() -> Lab:
    return Lab(fleet_looks(3))


# -- the pure part -------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("body", "names"),
    [
        (b"not json", "not JSON"),
        (b"[1]", "(body)"),
        (b'{"ids": "red,green"}', "ids"),
        (b'{"ids": [1, 2]}', "ids"),
        (b'{"ids": ["a"], "colour": "red"}', "colour"),
        (b'{"background": "sky"}', "background"),
        (json.dumps({"ids": [f"r{k}" for k in range(33)]}).encode(), "ids"),
        (b"{" + b" " * 5000 + b"}", "exceeds"),
    ],
)
def test_bad_enrolment_requests_are_refused_naming_the_field(body: bytes, names: str) -> None:
    with pytest.raises(Refused) as err:
        parse_body(body, EnrolRequest, "enrolment request")
    assert err.value.status == 400 and err.value.error.startswith("enrolment request: ") and names in err.value.error


@pytest.mark.parametrize(
    ("body", "ids", "background"),
    [
        (b"", None, "auto"),
        (b"{}", None, "auto"),
        (b'{"ids": ["blue", "red"]}', ["blue", "red"], "auto"),
        (b'{"ids": [], "background": "floor"}', [], "floor"),
        (b'{"background": "tracker"}', None, "tracker"),
    ],
)
def test_ids_and_background_are_optional(body: bytes, ids: list[str] | None, background: str) -> None:
    req = parse_body(body, EnrolRequest, "enrolment request")
    assert (req.ids, req.background) == (ids, background)


def _marker(rover_id: str = "red", x: float = 100.0, y: float = 200.0, front: bool = False) -> EnrolledMarker:
    return EnrolledMarker(
        rover_id, (40, 50, 200), 3.0, 0.8, 4.5, (x, y), (640.0, 360.0), 21.5, 16.8, 361.2, 900,
        (230, 235, 240) if front else None, 0.3 if front else None,
    )  # fmt: skip


def test_a_marker_is_shown_with_its_swatch_size_and_front() -> None:
    plain = marker_json(_marker(), "red")
    assert plain["color"] == "#c83228" and plain["color_bgr"] == [40, 50, 200] and plain["front"] is None
    assert (plain["length_cm"], plain["width_cm"], plain["x_cm"], plain["tracked_as"]) == (21.5, 16.8, 100.0, "red")
    two_tone = marker_json(_marker(front=True), None)
    assert two_tone["front"] == {"color": "#f0ebe6", "color_bgr": [230, 235, 240], "fraction": 0.3}


def _result(index: int, *placed: tuple[str, float, float]) -> FrameResult:
    estimates = tuple(RoverEstimate(r, x, y, 0.0, 0.0, 0.0, 1.0, (0.0, 0.0)) for r, x, y in placed)
    return FrameResult(index, 0.0, 0.0, estimates, ())


@pytest.mark.parametrize(
    ("placed", "expected"),
    [
        ((("blue", 300.0, 300.0), ("green", 104.0, 203.0)), "green"),
        ((("blue", 300.0, 300.0), ("green", 112.0, 210.0)), None),  # 15.6 cm away: on another spot
        ((), None),
    ],
)
def test_the_tracked_rover_standing_on_a_marker_is_named(
    placed: tuple[tuple[str, float, float], ...], expected: str | None
) -> None:
    assert tracked_on(_marker(), _result(3, *placed)) == expected


@pytest.mark.slow
def test_the_windowed_pipelines_expose_their_background_model_and_the_paper_pipeline_none(lab: Lab) -> None:
    rovers = tuple(RoverConfig(id=k.rover_id, color_bgr=lab.renderer.nominal_marker_bgr(k.rover_id)) for k in lab.looks)
    for method, has_model in (("particles", True), ("centroid", True), ("meanshift", True), ("paper", False)):
        tracker = build_tracker(TrackerConfig(rovers=rovers, method=method), lab.calibration)  # type: ignore[arg-type]
        tracker.process(Frame(lab.frame(POSES), 0, 0.0, 0.0))
        assert (tracker_model(tracker) is not None) == has_model, method


# -- the desk, with a stand-in for the running appliance -----------------------------------------------------------
@dataclass
class Camera:
    """What the desk reads from the running appliance: the newest frame, the result for it, the tracker."""

    last_frame: Frame | None = None
    latest_result: FrameResult | None = None
    tracker: object = None
    state: str = "ok"
    waited: list[float] = field(default_factory=list)

    def camera_state(self) -> str:
        return self.state

    def wait_tracked(self, timeout_s: float) -> None:
        self.waited.append(timeout_s)

    recent: dict[str, float] = field(default_factory=dict)  # rover id -> seconds since the tracker last saw it

    def snapshot(self) -> Any:
        rovers = [SimpleNamespace(id=rid, last_seen_age_s=age) for rid, age in self.recent.items()]
        return SimpleNamespace(rovers=tuple(rovers))

    def shows(self, image: np.ndarray, *placed: tuple[str, float, float]) -> None:
        index = (self.last_frame.index + 1) if self.last_frame is not None else 0
        self.last_frame = Frame(image, index, 1.0e9 + index, float(index))
        self.latest_result = _result(index, *placed)


@dataclass
class Learned:
    """A tracker with a background model (as the default pipeline has)."""

    background: BackgroundModel


def post(desk_route: Any, body: dict[str, Any] | None = None) -> tuple[int, dict[str, Any]]:
    raw = b"" if body is None else json.dumps(body).encode()
    response = desk_route(Request("POST", "/api/enroll", {}, {}, raw))
    return response.status, json.loads(response.body)


def _tracked(lab: Lab, poses: list[tuple[float, float, float]]) -> list[tuple[str, float, float]]:
    return [(look.rover_id, x, y) for look, (x, y, _) in zip(lab.looks, poses, strict=True)]


def _model(lab: Lab, known: float) -> BackgroundModel:
    model = BackgroundModel((720, 1280), 120, lab.background())
    model.valid.ravel()[: round((1.0 - known) * model.valid.size)] = False
    return model


@pytest.mark.slow
def test_the_trackers_model_enrolls_the_rovers_it_tracks_without_clearing_the_floor(lab: Lab) -> None:
    camera = Camera(tracker=Learned(_model(lab, 1.0)))
    camera.shows(lab.frame(POSES), *_tracked(lab, POSES))
    desk = EnrolDesk(camera, lab.calibration, enabled=True, marker_length_cm=21.5, marker_width_cm=16.8)
    status, out = post(desk.post_enroll)
    assert status == 200, out
    assert out["background"]["kind"] == "tracker" and out["warnings"] == []
    assert [(m["id"], m["tracked_as"]) for m in out["markers"]] == [
        ("red", "red"),
        ("green", "green"),
        ("azure", "blue"),
    ]


@pytest.mark.slow
def test_the_trackers_model_says_when_it_does_not_account_for_every_rover(lab: Lab) -> None:
    camera = Camera(tracker=Learned(_model(lab, 1.0)))
    camera.shows(lab.frame(POSES), *_tracked(lab, POSES)[:2])  # it tracks two: the third is not configured
    desk = EnrolDesk(camera, lab.calibration, enabled=True, marker_length_cm=21.5, marker_width_cm=16.8)
    status, out = post(desk.post_enroll)
    assert status == 200 and len(out["markers"]) == 3
    assert len(out["warnings"]) == 1 and "the tracker tracks 2 rovers in this frame but 3 markers" in out["warnings"][0]


@pytest.mark.slow
def test_a_rover_the_trackers_model_learned_as_floor_is_named_and_the_enrolment_refused(lab: Lab) -> None:
    """The model learns what the tracker does not track into its floor: a rover that stood untracked where it
    stands now is in the model there, does not differ from it, and would be left out of the enrolment (the browser
    test once enrolled red and green alone, with a warning). It is named, where it stands, and nothing is enrolled:
    enrolling again once it has moved, or against a captured floor, takes it."""
    frame = lab.frame(POSES)
    model = _model(lab, 1.0)
    x, y, _ = POSES[2]
    u, v = (round(float(c)) for c in lab.calibration.world_to_pixel(np.array([[x, y]], np.float64))[0])
    box = (slice(v - 40, v + 40), slice(u - 40, u + 40))
    model.reference[box] = frame[box]  # the third rover, learned where it stands
    camera = Camera(tracker=Learned(model))
    camera.shows(frame, *_tracked(lab, POSES))
    desk = EnrolDesk(camera, lab.calibration, enabled=True, marker_length_cm=21.5, marker_width_cm=16.8)
    status, out = post(desk.post_enroll)
    rover = lab.looks[2].rover_id
    assert status == 400, out
    assert out["error"].startswith(f"the tracker's background model has {rover} in it at ({x:.0f}, {y:.0f}) cm")
    camera.tracker = Learned(_model(lab, 1.0))  # the model without it: every rover is enrolled
    assert post(desk.post_enroll)[0] == 200


@pytest.mark.slow
def test_two_tone_fronts_and_hues_too_close_to_tell_apart_are_in_the_answer() -> None:
    looks = (RoverLook("a", marker_albedo_for_hue(0.0), heading="two_tone"),
             RoverLook("b", marker_albedo_for_hue(12.0), heading="two_tone"),
             RoverLook("c", marker_albedo_for_hue(200.0), heading="two_tone"))  # fmt: skip
    lab = Lab(looks)
    camera = Camera()
    camera.shows(lab.background())
    desk = EnrolDesk(camera, lab.calibration, enabled=True, marker_length_cm=21.5, marker_width_cm=16.8)
    assert desk.capture_floor(Request("POST", "/api/enroll/floor", {}, {}, b"")).status == 200
    camera.shows(lab.frame(POSES))
    status, out = post(desk.post_enroll, {"ids": ["r1", "r2", "r3"]})
    assert status == 200, out
    for marker in out["markers"]:
        front = marker["front"]
        assert front is not None and min(front["color_bgr"]) > 150 and front["fraction"] == pytest.approx(0.3, abs=0.03)
    assert len(out["warnings"]) == 1 and "too close to tell apart" in out["warnings"][0]
    reds = [m["id"] for m in out["markers"] if m["hue_deg"] < 30 or m["hue_deg"] > 330]
    assert len(reds) == 2 and all(r in out["warnings"][0] for r in reds)  # naming both
    assert "front_color_bgr" in out["toml"] and "# WARNING:" in out["toml"]


@pytest.mark.slow
@pytest.mark.parametrize(
    ("case", "status", "fragment"),
    [
        ("model not seen the floor", 400, "has seen only 99.8 % of the image"),
        ("no model, no floor", 400, "capture the empty floor first"),
        ("floor asked, none captured", 400, "no empty floor captured"),
        ("camera stalled", 503, "the camera is stalled"),
        ("nothing tracked yet", 503, "no camera frame tracked yet"),
        ("floor of another size", 400, "the empty floor is 640x360 but the camera now sends 1280x720"),
        ("disabled", 403, "no dashboard token is configured"),
        ("no calibration", 403, "needs the calibration"),
        ("busy", 409, "an enrolment is running"),
    ],
)
def test_the_desk_says_why_it_cannot_enroll(lab: Lab, case: str, status: int, fragment: str) -> None:
    camera = Camera(tracker=Learned(_model(lab, 0.998)) if case == "model not seen the floor" else None)
    camera.shows(lab.frame(POSES), *_tracked(lab, POSES))
    desk = EnrolDesk(
        camera,
        None if case == "no calibration" else lab.calibration,
        enabled=case != "disabled",
        marker_length_cm=21.5,
        marker_width_cm=16.8,
    )
    body: dict[str, Any] = {}
    if case == "floor asked, none captured":
        body = {"background": "floor"}
    if case == "camera stalled":
        camera.state = "stalled"
    if case == "nothing tracked yet":
        camera.last_frame = camera.latest_result = None
    if case == "floor of another size":
        small = Camera()
        small.shows(lab.background()[::2, ::2].copy())
        desk.camera = small
        assert desk.capture_floor(Request("POST", "/api/enroll/floor", {}, {}, b"")).status == 200
        desk.camera = camera
    if case == "busy":
        desk._busy.acquire()
    got, out = post(desk.post_enroll, body)
    assert got == status and fragment in out["error"], out
    if case == "nothing tracked yet":
        assert camera.waited == [1.0, 1.0, 1.0]  # it waited for the tracker's next frame before giving up


@pytest.mark.slow
def test_without_a_token_or_calibration_the_status_says_why_and_every_control_is_refused(lab: Lab) -> None:
    camera = Camera()
    camera.shows(lab.background())
    desk = EnrolDesk(camera, lab.calibration, enabled=False, marker_length_cm=21.5, marker_width_cm=16.8)
    state = json.loads(desk.status(Request("GET", "/api/enroll", {}, {}, b"")).body)
    assert state["enabled"] is False and "dashboard.token" in state["reason"]
    for route in (desk.capture_floor, desk.forget_floor, desk.post_enroll, desk.post_save):
        response = route(Request("POST", "/", {}, {}, b"{}"))
        assert response.status == 403 and b"no dashboard token" in response.body


@pytest.fixture
def enrolled(lab: Lab, tmp_path: Path) -> tuple[EnrolDesk, int]:
    camera = Camera()
    camera.shows(lab.background())
    desk = EnrolDesk(
        camera, lab.calibration, enabled=True, marker_length_cm=21.5, marker_width_cm=16.8,
        rovers_file=tmp_path / "rovers.toml", source="stage",
    )  # fmt: skip
    assert desk.capture_floor(Request("POST", "/api/enroll/floor", {}, {}, b"")).status == 200
    camera.shows(lab.frame(POSES))
    status, out = post(desk.post_enroll, {"ids": ["r1", "r2", "r3"]})
    assert status == 200, out
    return desk, out["enrolment"]


@pytest.mark.slow
def test_save_writes_the_enrolment_shown_and_asks_before_replacing(enrolled: tuple[EnrolDesk, int]) -> None:
    desk, number = enrolled
    path = desk.rovers_file
    assert path is not None
    status, out = post(desk.post_save, {"enrolment": number})
    assert (status, out["replaced"], out["rovers"]) == (200, False, ["r1", "r2", "r3"])
    first = path.read_text()
    assert first == desk._last.toml if desk._last is not None else False  # the text the page showed
    assert "Enrolled by the dashboard" in first and "from frame 1 of stage" in first
    status, out = post(desk.post_save, {"enrolment": number})
    assert status == 409 and out["exists"] is True and "exists: replace it?" in out["error"]
    assert path.read_text() == first
    status, out = post(desk.post_save, {"enrolment": number, "replace": True})
    assert status == 200 and out["replaced"] is True
    assert [r.id for r in load_config(path).config.rovers] == ["r1", "r2", "r3"]


@pytest.mark.slow
@pytest.mark.parametrize(
    ("case", "status", "fragment"),
    [
        ("an older enrolment", 409, "is not the newest"),
        ("a configuration there", 400, "is a configuration with [broker]"),
        ("no rovers file", 404, "dashboard.rovers_file"),
        ("no enrolment number", 400, "enrolment"),
    ],
)
def test_save_refuses_what_it_must_not_write(
    enrolled: tuple[EnrolDesk, int], case: str, status: int, fragment: str
) -> None:
    desk, number = enrolled
    path = desk.rovers_file
    assert path is not None
    body: dict[str, Any] = {"enrolment": number, "replace": True}
    if case == "an older enrolment":
        body["enrolment"] = number - 1
    if case == "a configuration there":
        path.write_text('[broker]\nurl = "embedded"\n\n[[rovers]]\nid = "red"\ncolor_bgr = [40, 40, 200]\n')
    if case == "no rovers file":
        desk.rovers_file = None
    if case == "no enrolment number":
        body = {"replace": True}
    before = path.read_text() if path.exists() else None
    got, out = post(desk.post_save, body)
    assert got == status and fragment in out["error"], out
    assert (path.read_text() if path.exists() else None) == before  # nothing written


# -- over HTTP, on a running appliance -----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def broker(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Mosquitto]:
    with Mosquitto(tmp_path_factory.mktemp("mosquitto")) as mosquitto:
        yield mosquitto


@dataclass
class Floor:
    """The running appliance and the floor its camera looks at."""

    app: Appliance
    stage: Stage
    lab: Lab
    rovers_file: Path

    @property
    def port(self) -> int:
        return int(self.app.http.port)

    def show(self, image: np.ndarray) -> None:
        tracked_since(self.app.runtime, self.stage.show(image))

    def request(
        self, method: str, path: str, body: dict[str, Any] | None = None, headers: dict[str, str] | None = None
    ) -> tuple[int, dict[str, Any]]:
        raw = None if body is None else json.dumps(body).encode()
        reply = call(self.port, method, path, raw, CONTROL if headers is None else headers)
        return reply.status, reply.json()


@pytest.fixture(scope="module")
def floor(lab: Lab, broker: Mosquitto, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Floor]:
    """An appliance with the real pipeline tracking the lab's three rovers, over a floor that starts empty."""
    folder = tmp_path_factory.mktemp("appliance")
    with lab_appliance(lab, broker.url, folder, token=TOKEN, viewer_token=VIEWER) as (app, stage):
        yield Floor(app, stage, lab, folder / "rovers.toml")


@pytest.mark.slow
def test_capture_the_empty_floor_place_the_rovers_and_enroll_them(floor: Floor) -> None:
    lab = floor.lab
    floor.show(lab.background())
    status, out = floor.request("POST", "/api/enroll/floor", {})
    assert status == 200 and out["warnings"] == [] and out["floor"]["kind"] == "floor"
    image = call(floor.port, "GET", f"/api/enroll/floor.jpg?token={VIEWER}")
    assert image.status == 200 and image.body.startswith(b"\xff\xd8")
    status, state = floor.request("GET", "/api/enroll", headers={"Authorization": f"Bearer {VIEWER}"})
    assert status == 200 and state["enabled"] and state["floor"]["frame"] == out["floor"]["frame"]

    floor.show(lab.frame(POSES))
    status, out = floor.request("POST", "/api/enroll", {})
    assert status == 200, out
    assert out["background"]["kind"] == "floor" and out["warnings"] == [] and out["ignored"] == []
    assert [m["id"] for m in out["markers"]] == ["red", "green", "azure"]  # named by hue
    for marker, look, (x, y, _) in zip(out["markers"], lab.looks, POSES, strict=True):
        assert math.hypot(marker["x_cm"] - x, marker["y_cm"] - y) < 2.0  # where it stands, to tell them apart
        nominal = lab.renderer.nominal_marker_bgr(look.rover_id)
        assert np.abs(np.subtract(marker["color_bgr"], nominal)).max() <= 25, (marker, nominal)
        assert marker["length_cm"] == pytest.approx(21.5, abs=1.5) and marker["front"] is None

    written = floor.rovers_file.parent / "downloaded.toml"  # what the page offers to download
    written.write_text(out["toml"])
    config = load_config(written).config
    assert [r.id for r in config.rovers] == ["red", "green", "azure"]
    errors = track(lab, config.rovers, POSES, lab_ids={"azure": "blue"})
    for rover_id, errs in errors.items():
        assert max(errs) < 1.0, f"{rover_id}: {errs}"  # every enrolled rover tracked, with its id, where it is


@pytest.mark.slow
@pytest.mark.parametrize(
    ("ids", "expected"),
    [
        (["blue", "red", "green"], ["red", "green", "blue"]),  # hue names, in any order: each to the nearest hue
        (["r1", "r2", "r3"], ["r1", "r3", "r2"]),  # in order of x: red (100), green (250), blue (180)
    ],
)
def test_ids_given_are_matched_to_the_rovers(floor: Floor, ids: list[str], expected: list[str]) -> None:
    """``expected``: the id each rover of ``POSES`` gets."""
    floor.show(floor.lab.background())
    assert floor.request("POST", "/api/enroll/floor", {})[0] == 200
    floor.show(floor.lab.frame(POSES))
    status, out = floor.request("POST", "/api/enroll", {"ids": ids})
    assert status == 200, out
    by_id = {m["id"]: (m["x_cm"], m["y_cm"]) for m in out["markers"]}
    for rover_id, (x, y, _) in zip(expected, POSES, strict=True):
        assert math.hypot(by_id[rover_id][0] - x, by_id[rover_id][1] - y) < 2.0


@pytest.mark.slow
def test_the_rovers_tracked_on_the_enrolled_markers_are_named(floor: Floor) -> None:
    floor.show(floor.lab.background())
    assert floor.request("POST", "/api/enroll/floor", {})[0] == 200
    floor.show(floor.lab.frame(POSES))
    until_tracking(floor.app.runtime, ["red", "green", "blue"])
    status, out = floor.request("POST", "/api/enroll", {"ids": ["red", "green", "blue"]})
    assert status == 200, out
    assert [(m["id"], m["tracked_as"]) for m in out["markers"]] == [
        ("red", "red"),
        ("green", "green"),
        ("blue", "blue"),
    ]


@pytest.mark.slow
@pytest.mark.parametrize(
    ("case", "fragment"),
    [
        ("no blob", "no marker-sized blob of colour differs from the background"),
        ("more blobs than ids", "found 3 markers, more than the 2 ids given (a, b)"),
        ("a blob on the background", "the background image has a marker in it"),
        ("a bad id", "rover id 'Red' is not an id"),
        ("not JSON", "enrolment request: not JSON"),
        ("ids as a string", "enrolment request: ids"),
    ],
)
def test_what_cannot_be_enrolled_is_a_400_with_the_reason(floor: Floor, case: str, fragment: str) -> None:
    lab = floor.lab
    floor.show(lab.frame(POSES) if case == "a blob on the background" else lab.background())
    assert floor.request("POST", "/api/enroll/floor", {})[0] == 200
    floor.show(lab.background() if case == "no blob" else lab.frame(MOVED))
    body: Any = {"ids": {"more blobs than ids": ["a", "b"], "a bad id": ["Red", "b", "c"]}.get(case)}
    if case == "ids as a string":
        body = {"ids": "a,b,c"}
    raw = b"{ids" if case == "not JSON" else json.dumps(body).encode()
    reply = call(floor.port, "POST", "/api/enroll", raw, CONTROL)
    assert reply.status == 400 and fragment in reply.json()["error"], reply.json()


@pytest.mark.slow
@pytest.mark.parametrize(
    ("headers", "status", "fragment"),
    [
        ({}, 401, "a token is required"),
        ({"Authorization": "Bearer wrong-token-1"}, 401, "wrong token"),
        ({"Authorization": f"Bearer {VIEWER}"}, 403, "read-only"),
    ],
)
def test_enrolment_controls_need_the_control_token(
    floor: Floor, headers: dict[str, str], status: int, fragment: str
) -> None:
    for method, path in (("POST", "/api/enroll"), ("POST", "/api/enroll/floor"), ("DELETE", "/api/enroll/floor"),
                         ("POST", "/api/enroll/save")):  # fmt: skip
        got, out = floor.request(method, path, {}, headers)
        assert got == status and fragment in out["error"], (method, path, out)
    assert call(floor.port, "GET", "/api/enroll").status == 401  # viewing needs a token too


def test_the_trackers_model_reads_ready_exactly_when_enrolment_takes_it_though_the_share_shown_is_rounded() -> None:
    model = BackgroundModel((200, 1000), 10, None)
    model.valid[...] = True
    model.valid.flat[:205] = False  # seen bare: 99.8975 % of the image, under the bar
    camera = Camera(tracker=SimpleNamespace(background=model))
    desk = EnrolDesk(camera, None, enabled=True, marker_length_cm=21.5, marker_width_cm=16.8)
    shown = desk.state()["tracker_model"]
    assert shown["known"] >= MIN_KNOWN_SHARE  # rounded, the share alone would read as enough (it once did)
    assert shown["ready"] is False
    model.valid.flat[:205] = True
    assert desk.state()["tracker_model"] == {"known": 1.0, "ready": True}


@pytest.mark.slow
def test_forgetting_the_floor_falls_back_to_the_trackers_model(floor: Floor) -> None:
    assert floor.request("POST", "/api/enroll/floor", {})[0] == 200
    status, out = floor.request("DELETE", "/api/enroll/floor")
    assert (status, out) == (200, {"floor": None})
    assert call(floor.port, "GET", f"/api/enroll/floor.jpg?token={TOKEN}").status == 404
    status, state = floor.request("GET", "/api/enroll")
    assert state["floor"] is None and 0.0 < state["tracker_model"]["known"] <= 1.0
    assert state["min_known"] == MIN_KNOWN_SHARE and state["rovers_file"] == str(floor.rovers_file)


@pytest.mark.slow
def test_capturing_the_floor_warns_of_rovers_seen_in_the_last_second_not_only_in_this_frame(lab: Lab) -> None:
    camera = Camera()
    camera.shows(lab.background())  # this frame: no rover tracked (one was lost for a frame, the scene jumped)
    camera.recent = {"green": 0.4, "blue": 7.0}  # green seen 0.4 s ago, blue long gone
    desk = EnrolDesk(camera, lab.calibration, enabled=True, marker_length_cm=21.5, marker_width_cm=16.8)
    response = desk.capture_floor(Request("POST", "/api/enroll/floor", {}, {}, b""))
    assert response.status == 200
    (warning,) = json.loads(response.body)["warnings"]
    assert warning.startswith("the tracker sees green in this frame or the last second")
    camera.recent = {}
    response = desk.capture_floor(Request("POST", "/api/enroll/floor", {}, {}, b""))
    assert json.loads(response.body)["warnings"] == []
