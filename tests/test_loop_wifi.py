"""The closed loop over Wi-Fi: rendered frames -> tracker -> broker -> each rover's modelled link -> firmware ->
world. Under a poor link every outage longer than the stale bound stops its rover within 0.5 s of its last fresh
pose (motors off, body at rest) and the rover drives on when poses come back; an outage long enough to cost the
association drops the connection, and the rover reconnects, gets the retained formation and rejoins. (The bars over
20 seeds per link: benchmarks/bench_formation.py.)"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from edge.cli import main
from edge.sim.link import LinkSettings
from edge.sim.loop import LoopConfig, LoopRecord, run
from edge.sim.report import stale_bound_ms, summarize

pytestmark = pytest.mark.realtime


def assert_every_long_outage_stops_its_rover_in_time_and_it_drives_again(record: LoopRecord) -> dict[str, object]:
    m = summarize(record)
    link = m["link"]
    checked = 0
    for rid, rover in link["rovers"].items():
        bound = stale_bound_ms(rid)
        for o in rover["outages"]:
            if not o["must_stop"]:
                continue
            checked += 1
            stop = o["stop"]
            assert stop is not None, f"{rid}: outage at {o['start_ms']} ms ({o['duration_ms']} ms) did not stop it"
            assert stop["without_pose_ms"] > bound
            assert stop["motors_off_after_ms"] <= 500, (rid, o, stop)
            if stop["without_pose_ms"] >= 600:  # long enough to see the body come to rest
                assert stop["at_rest_after_ms"] <= 500, (rid, o, stop)
            if stop["next_fresh_ms"] is not None:
                assert stop["drove_again_after_ms"] is not None, f"{rid} did not drive again after {o}"
    assert checked >= 2, "no outage long enough to stop a rover: the run proves nothing"
    assert link["outages_stopped_in_time"] == link["outages_must_stop"] == checked
    assert all(s["passed"] for s in link["stale_stops"])  # stops for any other reason too
    return m


@pytest.mark.slow
def test_a_poor_link_stops_each_rover_through_its_outages_and_the_fleet_still_forms() -> None:
    # The poor preset with outages four times as frequent: some in every run.
    config = LoopConfig("triangle", seed=5, frames=480, link=LinkSettings.parse("poor,outages=12/min"))
    record = run(config)
    m = assert_every_long_outage_stops_its_rover_in_time_and_it_drives_again(record)
    assert m["passed"]["formation"], f"the triangle did not hold at the end: {m['final']}"
    assert m["passed"]["no_collision"] and m["min_body_gap_cm"] > 0
    delays = [r["pose_delay_ms"] for r in m["link"]["rovers"].values()]
    assert all(d["median"] > 20.0 for d in delays)  # the link was in the loop: poses came late
    assert m["messages"]["poses_dropped"] == 0 and all(r["poses_lost"] == 0 for r in m["link"]["rovers"].values())


@pytest.mark.slow
def test_an_outage_that_costs_the_association_drops_the_connection_and_the_rover_rejoins() -> None:
    # Every outage 1.5-2 s long and the station gives up on its access point after 1 s of one (instead of ~8.5 s).
    link = LinkSettings.parse("typical,outages=10/min,outage=1.5s-2s,drop=1s,rejoin=0.5s")
    record = run(LoopConfig("rendezvous", seed=6, frames=450, link=link))
    m = assert_every_long_outage_stops_its_rover_in_time_and_it_drives_again(record)
    reconnected = [rid for rid, log in record.links.items() if log.connections >= 2]
    assert reconnected, "no rover lost its association"
    for rid in reconnected:
        halts = record.motors[rid].halt
        assert "disconnected" in halts
        # after its last reconnection it got the retained formation again and drove on
        assert record.links[rid].delivered[-1]["ips/v1/formation"] == 1
        assert halts[-1] in ("none", "probe")
        assert record.links[rid].poses_lost > 0  # what the broker sent while it was gone never arrived
    assert m["passed"]["no_collision"]


@pytest.mark.slow
def test_sim_formation_link_option_records_the_link(tmp_path: Path) -> None:
    out = tmp_path / "run"
    args = ["sim", "formation", "line", "--frames", "45", "--link", "typical,outages=0", "--out", str(out), "--json"]
    result = CliRunner().invoke(main, args)
    metrics = json.loads((out / "metrics.json").read_text())
    assert result.exit_code == 1  # 45 frames is too short to form
    link = metrics["link"]
    assert link["settings"] == str(LinkSettings.parse("typical,outages=0"))
    assert set(link["rovers"]) == {"red", "green", "blue"}
    assert all(r["pose_delay_ms"]["n"] > 0 and r["pose_delay_ms"]["median"] > 5.0 for r in link["rovers"].values())
    assert metrics["passed"]["stops_in_time"] is True


@pytest.mark.parametrize(
    ("link", "message"),
    [("loss=70%", "loss=70%: must be 0-50 %"), ("lossy", "unknown preset"), ("latency=5", "e.g. latency=10ms")],
)
def test_a_bad_link_is_a_one_line_error(tmp_path: Path, link: str, message: str) -> None:
    result = CliRunner().invoke(main, ["sim", "formation", "line", "--link", link, "--out", str(tmp_path / "x")])
    assert result.exit_code == 2
    assert message in result.output and "Traceback" not in result.output
    assert not (tmp_path / "x").exists()
