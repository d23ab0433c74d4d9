"""The fused map: every board's view on the floor, every rover's fused position and the boards that measured it,
as JSON and on the page in Debian's chromium, from a fuser on a real Mosquitto fed by two board processes."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from edge.board_messages import BoardStateV1, FuserStatusV1
from edge.config import parse_broker_url
from edge.fusion.core import FusedPose
from edge.fusion.fusedmap import map_state, serve_map
from edge.fusion.service import FuserService
from edge.httpguard import HostAllowList, Tokens
from edge.httpserver import HttpServer
from tests.support.dashboard import call, chromium
from tests.support.mosquitto import Mosquitto
from tests.test_fusion_live import board, process

VIEW_A = [[0.0, 0.0], [450.0, 0.0], [450.0, 550.0], [0.0, 550.0]]
VIEW_B = [[350.0, 0.0], [800.0, 0.0], [800.0, 550.0], [350.0, 550.0]]


def _board(edge: str, state: str, view: list[list[float]], rovers: list[str]) -> BoardStateV1:
    return BoardStateV1(
        edge=edge,
        state=state,  # type: ignore[arg-type]
        offset_ms=1.5,
        offset_sigma_ms=0.2,
        offset_source="overlap",
        age_ms=20.0,
        stale=0,
        rovers=rovers,
        view=view,
    )


def _pose(rover_id: str, t_s: float, boards: tuple[str, ...]) -> FusedPose:
    return FusedPose(rover_id, 30, t_s, 400.0, 275.0, 0.5, 1.0, 2.0, 0.9, boards)


def test_the_map_says_which_boards_measured_each_rover_and_where_nobody_watches() -> None:
    status = FuserStatusV1(
        v=1,
        fuser="f1",
        state="active",
        holder="f1",
        boards=[_board("a", "ok", VIEW_A, ["r1", "r2"]), _board("b", "offline", VIEW_B, [])],
        rovers=["r1", "r2"],
        missing=["r3"],
        t=100.0,
    )
    poses = {"r1": _pose("r1", 99.98, ("a", "b")), "r2": _pose("r2", 99.99, ("a",)), "r3": _pose("r3", 98.0, ("b",))}
    state = map_state(status, poses, now_s=100.0, timeout_s=0.5)
    assert {r["id"]: r["boards"] for r in state["rovers"]} == {"r1": ["a", "b"], "r2": ["a"]}  # r3: too old
    assert state["missing"] == ["r3"]
    assert state["unwatched"] == [VIEW_B]
    boards = [(b["edge"], b["state"], b["view"]) for b in state["boards"]]
    assert boards == [("a", "ok", VIEW_A), ("b", "offline", VIEW_B)]
    assert state["rovers"][0]["age_ms"] == pytest.approx(20.0)


def camera_of_board_a() -> HttpServer:
    """Board a's dashboard as far as the map uses it: ``/api/frame.jpg`` behind the same viewer token, on the
    project's HTTP server, a JPEG of a rendered camera frame of the wide arena."""
    from edge.dashboard.frames import encode_jpeg
    from edge.httpserver import Response
    from edge.sim.wide_source import WideCameraSource

    source = WideCameraSource("wide:cam1:2", realtime=False)
    source.open()
    frame = source.read()
    source.close()
    assert frame is not None
    jpeg, _, _ = encode_jpeg(frame.image, max_width_px=640, quality=70)
    http = HttpServer("127.0.0.1", 0, hosts=HostAllowList.for_this_board(), tokens=Tokens(None, "seen"))
    http.route("/api/frame.jpg", lambda request: Response(200, jpeg, "image/jpeg"), access="read")
    return http.start()


@pytest.fixture(scope="module")
def fused(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[int, dict[str, threading.Event]]]:
    """A fuser with its map on a free port, fed by boards ``a`` and ``b`` (a's dashboard, with its camera image,
    given; b's not); events set when r2 and r3 were fused."""
    work: Path = tmp_path_factory.mktemp("fusedmap")
    fused_once = {rover: threading.Event() for rover in ("r2", "r3")}

    def on_pose(pose: FusedPose, line: bytes) -> None:
        if pose.rover_id in fused_once:
            fused_once[pose.rover_id].set()

    camera = camera_of_board_a()
    with Mosquitto(work) as broker:
        dashboards = {"a": f"http://127.0.0.1:{camera.port}"}
        service = FuserService(parse_broker_url(broker.url), "f1", on_pose=on_pose, dashboards=dashboards)
        http = HttpServer("127.0.0.1", 0, hosts=HostAllowList.for_this_board(), tokens=Tokens(None, "seen")).start()
        serve_map(http, service.map_state)
        service.start()
        try:
            with process(board(broker.url, "a", work), work), process(board(broker.url, "b", work), work):
                yield http.port, fused_once
        finally:
            service.stop()
            http.stop()
            camera.stop()


@pytest.mark.slow
def test_the_map_serves_each_rover_with_the_board_that_saw_it(fused: tuple[int, dict[str, threading.Event]]) -> None:
    port, fused_once = fused
    assert all(event.wait(60.0) for event in fused_once.values()), "the fuser published no pose of r2 or r3"
    assert call(port, "GET", "/api/fusion").status == 401  # the viewer token guards the data, as on the dashboard
    state = call(port, "GET", "/api/fusion", headers={"Authorization": "Bearer seen"}).json()
    seen_by = {r["id"]: r["boards"] for r in state["rovers"]}
    assert seen_by["r2"] == ["a"] and seen_by["r3"] == ["b"]  # r2 circles in a's half only, r3 in b's
    views = {b["edge"]: b["view"] for b in state["boards"]}
    assert views == {"a": VIEW_A, "b": VIEW_B}
    dashboards = {b["edge"]: b["dashboard"] for b in state["boards"]}
    assert dashboards["a"].startswith("http://127.0.0.1:") and dashboards["b"] is None
    assert state["fuser"] == "f1" and state["unwatched"] == []


@pytest.mark.slow
def test_the_page_draws_both_views_and_marks_who_saw_each_rover(
    fused: tuple[int, dict[str, threading.Event]],
) -> None:
    port, fused_once = fused
    assert all(event.wait(60.0) for event in fused_once.values())
    with chromium() as browser:
        page = browser.new_page()
        page.goto(f"http://127.0.0.1:{port}/?token=seen")
        page.wait_for_selector('g.rover[data-rover="r3"]', timeout=30_000)
        assert page.get_attribute('g.rover[data-rover="r2"]', "data-boards") == "a"
        assert page.get_attribute('g.rover[data-rover="r3"]', "data-boards") == "b"
        assert sorted(page.eval_on_selector_all("polygon.view", "ps => ps.map(p => p.dataset.board)")) == ["a", "b"]
        assert "r2 · a" in (page.text_content("#map") or "")
        assert page.url.endswith("/")  # the token is taken out of the address


@pytest.mark.slow
def test_the_page_shows_each_boards_camera_and_the_rovers_it_sees(
    fused: tuple[int, dict[str, threading.Event]],
) -> None:
    """Board a's camera image comes from its dashboard, asked again and again with the page's viewer token; board b
    (no dashboard given) says how to give it; each caption lists the rovers that board sees."""
    port, fused_once = fused
    assert all(event.wait(60.0) for event in fused_once.values())
    with chromium() as browser:
        page = browser.new_page()
        page.goto(f"http://127.0.0.1:{port}/?token=seen")
        # Three frames loaded, and the width of one on show, read in the same step: the page asks for the next frame
        # 0.1 s after each, and while it comes (or after a fetch that failed on a loaded machine) the image is empty
        width = page.wait_for_function(
            """() => { const f = document.querySelector('figure.camera[data-board="a"]');
                       const img = f && f.querySelector('img');
                       const shown = img && img.complete ? img.naturalWidth : 0;
                       return Number(f && f.dataset.frames || 0) >= 3 && shown; }""",
            timeout=30_000,
        ).json_value()
        assert width == 640  # the board's JPEG, decoded: the token went with it
        page.wait_for_function(
            """() => /r3/.test(document.querySelector('figure.camera[data-board="b"] figcaption').textContent)"""
        )
        caption_a = page.text_content('figure.camera[data-board="a"] figcaption') or ""
        caption_b = page.text_content('figure.camera[data-board="b"] figcaption') or ""
        assert "r2" in caption_a and "r3" not in caption_a  # r2 circles in a's half only, r3 in b's
        assert page.query_selector('figure.camera[data-board="b"] img') is None
        assert "--board-dashboard b=URL" in caption_b
