"""A newcomer's first run, in a real browser: ``edge-ips start`` with nothing configured (the live twin, the embedded
broker), the page opened at the address start printed with its token, and the buttons pressed in Debian's headless
chromium: a formation moves the fleet, STOP stops it, scatter moves the rovers, a fault shows on the page and the
rovers come back.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.support.dashboard import EdgeProcess, chromium, clean_env, edge_start
from tests.support.mosquitto import free_port

pytestmark = [pytest.mark.slow, pytest.mark.realtime]

ROVERS = ["red", "green", "blue"]
WAIT_MS = 120_000  # failure guard: how long the page may take to show something

ALL_SEEN = "ids => ids.every(id => state.rovers.has(id) && state.rovers.get(id).last !== null)"
HALTS = "() => Object.fromEntries([...document.querySelectorAll('#rovers tbody tr')].map(r => [r.dataset.rover, r.querySelector('td.halt').dataset.halt]))"  # noqa: E501
TRUTH = "() => Object.fromEntries([...document.querySelectorAll('#sim-rovers tbody tr')].map(r => [r.dataset.rover, r.querySelector('td[data-moving]').dataset.moving]))"  # noqa: E501


@pytest.fixture(scope="module")
def edge(tmp_path_factory: pytest.TempPathFactory) -> Iterator[EdgeProcess]:
    workdir = tmp_path_factory.mktemp("first-run")  # no configuration file here: a newcomer's first start
    state = tmp_path_factory.mktemp("s")
    env = clean_env(EDGE_IPS_BROKER__EMBEDDED_PORT=str(free_port()), EDGE_IPS_EDGE__STATE_DIR=str(state))
    with edge_start([], workdir, env) as process:
        yield process


@pytest.fixture(scope="module")
def page(edge: EdgeProcess) -> Iterator[Any]:
    first = edge.log().splitlines()[0]  # what start prints first: the page's address with the token it made
    address = rf"dashboard: http://localhost:{edge.http_port}/\?token=(\S+) \(the token is made now, kept in \S+\)"
    match = re.fullmatch(address, first)
    assert match is not None, first
    with chromium() as browser:
        tab = browser.new_page(viewport={"width": 1400, "height": 1100})
        tab.goto(f"{edge.url}?token={match.group(1)}")
        yield tab
        tab.close()


def _wait(page: Any, script: str, arg: Any = None) -> Any:
    return page.wait_for_function(script, arg=arg, timeout=WAIT_MS).json_value()


def test_the_formation_buttons_move_the_fleet_and_stop_stops_it(page: Any, tmp_path: Path) -> None:
    _wait(page, ALL_SEEN, ROVERS)
    _wait(page, "() => !document.getElementById('sim-panel').hidden")  # the lab's panel, once its route answers
    _wait(page, "() => Object.values((" + HALTS + ")()).every(h => h === 'stop')")  # the stop at start, reported
    page.click("button[data-kind=triangle]")
    _wait(page, "() => document.getElementById('formation-result').dataset.status === '200'")
    _wait(page, "() => Object.values((" + TRUTH + ")()).some(m => m === 'true')")  # the lab: the rovers drive
    _wait(page, "() => Object.values((" + HALTS + ")()).every(h => h === 'none')")  # each reports it drives
    page.click("button[data-kind=stop]")
    _wait(page, "() => Object.values((" + HALTS + ")()).every(h => h === 'stop')")
    _wait(page, "() => Object.values((" + TRUTH + ")()).every(m => m === 'false')")  # and they are at rest
    shot = tmp_path / "twin-dashboard.png"
    page.screenshot(path=str(shot), full_page=True)
    assert shot.read_bytes().startswith(b"\x89PNG")


def test_scatter_moves_the_rovers_elsewhere_on_the_map(page: Any) -> None:
    _wait(page, ALL_SEEN, ROVERS)
    before = page.evaluate("ids => ids.map(id => [state.rovers.get(id).last.x, state.rovers.get(id).last.y])", ROVERS)
    page.click("#scatter")
    _wait(page, "() => document.getElementById('sim-result').dataset.status === '200'")
    moved = """([ids, before]) => ids.every((id, k) => {
        const p = state.rovers.get(id).last;
        return p && Math.hypot(p.x - before[k][0], p.y - before[k][1]) > 20;
    })"""
    _wait(page, moved, [ROVERS, before])
    _wait(page, "() => document.getElementById('sim-events').textContent.includes('scattered: red at')")


def test_a_hung_camera_shows_on_the_page_and_the_rovers_stop_and_come_back(page: Any) -> None:
    page.click("button[data-kind=rendezvous]")
    _wait(page, "() => Object.values((" + TRUTH + ")()).some(m => m === 'true')")
    page.select_option("#fault-kind", "camera")
    page.fill("#fault-seconds", "4")
    page.click("#fault")
    _wait(page, "() => document.getElementById('sim-result').textContent === 'camera hung for 4 s'")
    _wait(page, "() => document.getElementById('pill-camera').textContent === 'camera stalled'")
    _wait(page, "() => Object.values((" + HALTS + ")()).every(h => h === 'stale')")  # each rover's own word
    _wait(page, "() => document.getElementById('sim-events').textContent.includes('after camera hung for 4 s')")
    _wait(page, "() => document.getElementById('pill-camera').textContent === 'camera ok'")
    _wait(page, "() => Object.values((" + HALTS + ")()).some(h => h === 'none')")  # driving on
