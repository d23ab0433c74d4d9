"""The dashboard in a real browser: ``edge-ips start --source sim`` with a real Mosquitto, driven by Debian's
headless chromium through Playwright.

One appliance and one page serve the module's tests: the page loads, the three rovers appear and move on the map,
the camera view updates, the formation buttons publish the retained message with the token and are refused without
it, and a screenshot is saved.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from playwright.sync_api import TimeoutError as PlaywrightTimeout

from edge.messages import parse_formation
from tests.support.appliance import edge_config, running
from tests.support.dashboard import EdgeProcess, FormationSubscriber, chromium, clean_env, edge_start
from tests.support.mosquitto import Mosquitto

pytestmark = [pytest.mark.slow, pytest.mark.realtime]  # end to end, or long: left out of the quick loop (-m 'not slow')

TOKEN = "test-dashboard-token"
ROVERS = ["red", "green", "blue"]
WAIT_MS = 60_000  # how long the browser may take to see something happen before the test fails


@pytest.fixture(scope="module")
def broker(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Mosquitto]:
    with Mosquitto(tmp_path_factory.mktemp("mosquitto")) as mosquitto:
        yield mosquitto


@pytest.fixture(scope="module")
def edge(broker: Mosquitto, tmp_path_factory: pytest.TempPathFactory) -> Iterator[EdgeProcess]:
    env = clean_env(EDGE_IPS_DASHBOARD__TOKEN=TOKEN)
    with edge_start(["--source", "sim", "--broker", broker.url], tmp_path_factory.mktemp("edge"), env) as process:
        yield process


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    with chromium() as chromium_browser:
        yield chromium_browser


@pytest.fixture(scope="module")
def page(edge: EdgeProcess, browser: Any) -> Iterator[Any]:
    browser_page = browser.new_page(viewport={"width": 1400, "height": 1000})
    frames: list[dict[str, Any]] = []

    def on_response(response: Any) -> None:
        if "/api/frame.jpg" in response.url and response.status == 200:
            frames.append({"index": int(response.headers["x-frame-index"])})

    browser_page.on("response", on_response)
    browser_page.frames_seen = frames
    browser_page.goto(f"{edge.url}?token={TOKEN}")  # as `start` prints it: the page keeps the token for the session
    yield browser_page
    browser_page.close()


ALL_ROVERS_SEEN = "ids => ids.every(id => state.rovers.has(id) && state.rovers.get(id).last !== null)"
POSITIONS = "ids => Object.fromEntries(ids.map(id => [id, [state.rovers.get(id).last.x, state.rovers.get(id).last.y]]))"
# How much of each rover's dot on the map canvas has the rover's colour, computed with the page's own transform.
MAP_COLOUR_SHARE = """
ids => {
  const cv = document.getElementById("map"), ctx = cv.getContext("2d");
  const W = state.info.area.width_cm, m = 30, scale = (cv.width - 2 * m) / W;
  const x0 = state.info.area.x0_cm, y0 = state.info.area.y0_cm;
  const out = {};
  for (const id of ids) {
    const p = state.rovers.get(id).last, hex = colorOf(id);
    const want = [1, 3, 5].map(i => parseInt(hex.slice(i, i + 2), 16));
    const cx = Math.round(m + (p.x - x0) * scale), cy = Math.round(cv.height - m - (p.y - y0) * scale);
    const r = Math.max(2, Math.floor(Math.max(4, 9 * scale) * 0.7));
    const px = ctx.getImageData(cx - r, cy - r, 2 * r + 1, 2 * r + 1).data;
    let hit = 0, n = 0;
    for (let k = 0; k < px.length; k += 4) {
      n++;
      if ([0, 1, 2].every(c => Math.abs(px[k + c] - want[c]) < 40)) hit++;
    }
    out[id] = hit / n;
  }
  return out;
}
"""


def test_page_loads_and_the_three_rovers_appear_and_move_on_the_map(page: Any) -> None:
    assert page.title() == "edge-ips dashboard"
    page.wait_for_function(ALL_ROVERS_SEEN, arg=ROVERS, timeout=WAIT_MS)
    before = page.evaluate(POSITIONS, ROVERS)
    moved = """([ids, before]) => ids.every(id => {
        const p = state.rovers.get(id).last;
        return Math.hypot(p.x - before[id][0], p.y - before[id][1]) > 3;
    })"""
    page.wait_for_function(moved, arg=[ROVERS, before], timeout=WAIT_MS)
    after = page.evaluate(POSITIONS, ROVERS)
    for rover in ROVERS:
        x, y = after[rover]
        assert 0.0 <= x <= 391.5 and 0.0 <= y <= 549.5
        assert after[rover] != before[rover]
    # Each rover's dot is drawn where it is, in its colour. Read at one instant a dot can be grey (a rover missed in
    # the newest frame is drawn where it was last seen) or under another's: once, on two busy cores, red and green
    # read 0 and blue 0.9. So wait for a frame that draws all three, each read with the map of that frame.
    drawn = f"ids => Object.values(({MAP_COLOUR_SHARE})(ids)).every(share => share > 0.3)"
    try:
        page.wait_for_function(drawn, arg=ROVERS, timeout=WAIT_MS)
    except PlaywrightTimeout:
        shares = page.evaluate(MAP_COLOUR_SHARE, ROVERS)
        missing = page.evaluate("ids => ids.filter(id => state.rovers.get(id).missing)", ROVERS)
        pytest.fail(f"a rover's dot is not drawn where it is: colour shares {shares}, missing {missing}")
    rows = page.locator("#rovers tbody tr")
    assert rows.count() == 3
    page.wait_for_function("() => document.querySelector('#pill-state').textContent === 'online'", timeout=WAIT_MS)
    page.wait_for_function("() => document.querySelector('#fps').textContent !== '–'", timeout=WAIT_MS)


def test_the_token_in_the_address_is_kept_for_the_session_and_removed_from_the_address(page: Any) -> None:
    page.wait_for_function("() => state.info !== null", timeout=WAIT_MS)
    assert "token" not in page.url
    assert page.evaluate("() => sessionStorage.getItem('edge-ips-token')") == TOKEN


def test_without_the_token_the_page_shows_nothing_until_it_is_given(edge: EdgeProcess, browser: Any) -> None:
    other = browser.new_page()  # a new tab: a session of its own, no token
    try:
        other.goto(edge.url)
        result = other.locator("#formation-result")
        other.wait_for_function("() => document.getElementById('formation-result').dataset.status === '401'")
        assert "enter the dashboard token" in result.text_content()
        assert other.evaluate("() => state.info") is None and other.evaluate("() => state.rovers.size") == 0
        other.fill("#token", TOKEN)
        other.locator("#token").dispatch_event("change")
        other.wait_for_function(ALL_ROVERS_SEEN, arg=ROVERS, timeout=WAIT_MS)
        other.wait_for_function("() => document.getElementById('camera').naturalWidth > 0", timeout=WAIT_MS)
    finally:
        other.close()


def test_camera_view_updates(page: Any) -> None:
    page.wait_for_function(
        "() => document.getElementById('camera').naturalWidth > 0 && document.getElementById('camera').complete",
        timeout=WAIT_MS,
    )
    first = len(page.frames_seen)
    page.wait_for_function(
        "n => document.getElementById('camera').src.includes('n=' + n)", arg=first + 2, timeout=WAIT_MS
    )
    indices = [f["index"] for f in page.frames_seen]
    assert len(set(indices)) >= 2 and indices == sorted(indices)  # newer frames, never an old one again
    loaded_width = "() => { const i = document.getElementById('camera'); return i.complete && i.naturalWidth; }"
    width = page.wait_for_function(loaded_width, timeout=WAIT_MS).json_value()
    assert 0 < width <= 960  # downscaled for the page (dashboard.max_width_px)


def test_formation_button_publishes_with_the_token_and_is_refused_without(
    page: Any, broker: Mosquitto, tmp_path: Path
) -> None:
    subscriber = FormationSubscriber("127.0.0.1", broker.port)
    result = page.locator("#formation-result")
    try:
        start, was_retained = subscriber.next()  # the appliance's own stop at start, retained
        assert (start["kind"], start["seq"], was_retained) == ("stop", 1, True)
        page.fill("#token", "")
        page.click("button[data-kind=line]")
        page.wait_for_function("() => document.getElementById('formation-result').dataset.status === '401'")
        assert result.text_content().startswith("refused")
        page.fill("#token", "not-the-token")
        page.click("button[data-kind=triangle]")
        page.wait_for_function("() => document.getElementById('formation-result').textContent.includes('wrong token')")
        page.fill("#token", TOKEN)
        page.fill("#formation-rovers", "blue,red,green")
        page.click("button[data-kind=rendezvous]")
        page.wait_for_function("() => document.getElementById('formation-result').dataset.status === '200'")
        message, _ = subscriber.next()
        formation = parse_formation(json.dumps(message).encode())
        # the next formation the broker carried is the accepted one: the refused clicks published nothing
        assert (formation.seq, formation.kind, formation.ids) == (2, "rendezvous", ["blue", "red", "green"])
        assert result.text_content() == "published rendezvous (seq 2)"
        page.wait_for_function(
            "() => document.getElementById('formation-current').textContent.startsWith('rendezvous')",
            timeout=WAIT_MS,
        )
        # the map's target: the firmware's ring (31 cm sides for three rovers) round where the rovers are
        page.wait_for_function("() => (state.lastPose?.targets || []).length === 3", timeout=WAIT_MS)
        targets = page.evaluate("() => state.lastPose.targets")
        assert sorted(t["id"] for t in targets) == sorted(ROVERS)
        corners = [(t["x"], t["y"]) for t in targets]
        sides = [math.dist(corners[k], corners[(k + 1) % 3]) for k in range(3)]
        assert sides == pytest.approx([31.0] * 3, abs=0.05)
    finally:
        subscriber.close()
    late = FormationSubscriber("127.0.0.1", broker.port)  # a rover that connects later still gets it: retained
    try:
        message, retained = late.next()
        assert retained and message["kind"] == "rendezvous" and message["seq"] == 2
    finally:
        late.close()
    shot = tmp_path / "dashboard.png"
    page.screenshot(path=str(shot), full_page=True)
    assert shot.read_bytes().startswith(b"\x89PNG")


def test_controls_are_disabled_without_a_configured_token(mosquitto: Mosquitto, browser: Any) -> None:
    config = edge_config(**{"http.enabled": True, "http.port": 0, "broker.url": mosquitto.url})
    with running(config) as app:
        page = browser.new_page()
        page.goto(f"http://127.0.0.1:{app.http.port}/")
        page.wait_for_function("() => document.getElementById('formation-result').textContent.length > 0")
        assert "no dashboard token" in page.locator("#formation-result").text_content()
        for kind in ("line", "rendezvous", "triangle", "stop"):
            assert page.locator(f"button[data-kind={kind}]").is_disabled()
        page.wait_for_function("() => state.rovers.size === 3", timeout=WAIT_MS)  # the rest of the page works
