"""The formation bars over random starting layouts and Wi-Fi links: every formation from N seeds per link setting.

    .venv/bin/python benchmarks/bench_formation.py                          # 20 seeds x 3 formations, wire link
    .venv/bin/python benchmarks/bench_formation.py --links wire,good,typical,poor --json runs.json
    .venv/bin/python benchmarks/bench_formation.py --seeds 5 --kinds line --broker mqtt://127.0.0.1:1883
    .venv/bin/python benchmarks/bench_formation.py --first-seed 1000            # unseen seeds

Each run: random starts at least 1.5 m apart, rendered frames (the paper's lab), edge.pipeline.Pipeline, the pose
publishing rule of the runtime, edge.publisher.MqttPublisher, a real broker (embedded amqtt unless --broker), per
rover a Wi-Fi link (edge.sim.link: a preset or key=value items, see docs/experiments.md) and the firmware
(edge.rover_host.HostRover), 360 frames. Prints one line per run and two tables: per link and formation, runs
passing every bar, frames to converge (median, max, and the median's change against the first link), the final
shape, the closest bodies came; then what the links did: outages, stops for want of a fresh (young) pose (motors off
and body at rest after the last fresh pose, worst), rovers that drove again after each, poses lost, pose delays, and
how old (since capture) the rovers' own poses were when they drove on them (the bar: never older than 0.5 s).
Exit status 1 when any run misses a bar.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from edge.sim.link import LinkSettings
from edge.sim.loop import LoopConfig, run
from edge.sim.report import YOUNG_BAR_MS, summarize


def final_figure(kind: str, final: dict[str, Any]) -> float:
    """The number the bar is about: line: worst of displacement and |gap - 60|; rendezvous: zone diameter;
    triangle: worst |side - 100|."""
    if kind == "line":
        return max(final["line_displacement_cm"], *(abs(g - 60.0) for g in final["gaps_cm"]))
    if kind == "rendezvous":
        return float(final["zone_diameter_cm"])
    return max(abs(s - 100.0) for s in final["sides_cm"])


def run_line(kind: str, link: str, seed: int, m: dict[str, Any]) -> str:
    ok = all(m["passed"].values())
    ln = m["link"]
    outages = sum(len(r["outages"]) for r in ln["rovers"].values())
    stops = ln["stale_stops"]
    worst = max((s["motors_off_after_ms"] for s in stops), default=0)
    return (
        f"{link:<8} {kind:<10} seed {seed:>4}: converged {m['converged_frame']!s:>4}  final "
        f"{final_figure(kind, m['final']):6.2f} cm  gap {m['min_body_gap_cm']:5.1f} cm  outages {outages}  stops "
        f"{len(stops)} (off after {worst} ms)  {'ok' if ok else 'FAIL ' + str(m['passed'])}  {m['wall_s']:.1f} s"
    )


def bar_table(results: dict[str, dict[str, list[dict[str, Any]]]]) -> list[str]:
    lines = [
        "| link | formation | runs passing | converged frame median / max | median vs first link | final median / "
        "worst | closest bodies cm |",
        "|---|---|---|---|---|---|---|",
    ]
    first = next(iter(results))
    for link, by_kind in results.items():
        for kind, rows in by_kind.items():
            conv = [r["converged_frame"] for r in rows if r["converged_frame"] is not None]
            base = [r["converged_frame"] for r in results[first].get(kind, []) if r["converged_frame"] is not None]
            finals = [final_figure(kind, r["final"]) for r in rows]
            passing = sum(all(r["passed"].values()) for r in rows)
            median = statistics.median(conv) if conv else None
            slower = (
                f"{100.0 * (median / statistics.median(base) - 1.0):+.0f} %"
                if median is not None and base and link != first
                else "-"
            )
            lines.append(
                f"| {link} | {kind} | {passing} / {len(rows)} | {median if median is not None else '-'} / "
                f"{max(conv) if conv else '-'} | {slower} | {statistics.median(finals):.2f} / {max(finals):.2f} | "
                f"{min(r['min_body_gap_cm'] for r in rows):.1f} |"
            )
    return lines


def link_table(results: dict[str, dict[str, list[dict[str, Any]]]]) -> list[str]:
    lines = [
        "| link | outages: all / longer than the stale bound | of those, stopped within 0.5 s / drove again | "
        "stops for want of a pose (all causes) | motors off after, worst ms | at rest after, worst ms | poses lost "
        "| pose delay median / p95 / max ms | own pose age when driving p95 / max ms | runs driving on an own pose "
        "older than 0.5 s |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for link, by_kind in results.items():
        links = [r["link"] for kind_rows in by_kind.values() for r in kind_rows]
        outages = sum(len(rv["outages"]) for ln in links for rv in ln["rovers"].values())
        must = sum(ln["outages_must_stop"] for ln in links)
        stopped = sum(ln["outages_stopped_in_time"] for ln in links)
        rejoined = sum(ln["outages_rejoined"] for ln in links)
        stops = [s for ln in links for s in ln["stale_stops"]]
        off = max((s["motors_off_after_ms"] for s in stops), default=None)
        rest = max((s["at_rest_after_ms"] for s in stops if s["without_pose_ms"] >= 600), default=None)
        lost = sum(rv["poses_lost"] for ln in links for rv in ln["rovers"].values())
        delays = [rv["pose_delay_ms"] for ln in links for rv in ln["rovers"].values() if rv["pose_delay_ms"]["n"]]
        median = statistics.median(d["median"] for d in delays) if delays else 0.0
        p95 = statistics.median(d["p95"] for d in delays) if delays else 0.0
        worst = max((d["max"] for d in delays), default=0.0)
        ages = [ln["driven_pose_age_ms"] for ln in links if ln["driven_pose_age_ms"]["n"]]
        age_p95 = statistics.median(a["p95"] for a in ages) if ages else 0.0
        age_max = max((a["max"] for a in ages), default=0.0)
        old = sum(a["max"] > YOUNG_BAR_MS for a in ages)
        lines.append(
            f"| {link} | {outages} / {must} | {stopped} / {rejoined} | {len(stops)} | "
            f"{off if off is not None else '-'} | {f'{rest:.0f}' if rest is not None else '-'} | {lost} | "
            f"{median:.1f} / {p95:.0f} / {worst:.0f} | {age_p95:.0f} / {age_max:.0f} | {old} / {len(links)} |"
        )
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=20, help="random starts per formation and link (default 20)")
    parser.add_argument("--first-seed", type=int, default=0, help="first seed (default 0)")
    parser.add_argument("--kinds", default="line,rendezvous,triangle", help="formations, comma separated")
    parser.add_argument(
        "--links", default="wire", help="link settings separated by ';' or presets by ',' (default wire)"
    )
    parser.add_argument("--frames", type=int, default=360, help="frames per run (default 360)")
    parser.add_argument("--broker", default=None, help="mqtt://host:port (default: an embedded broker per run)")
    parser.add_argument("--heading", default="two_tone", choices=("two_tone", "plain"))
    parser.add_argument("--json", type=Path, default=None, help="write every run's metrics here")
    args = parser.parse_args()

    kinds = args.kinds.split(",")
    links = args.links.split(";") if ";" in args.links else args.links.split(",")
    settings = {link: LinkSettings.parse(link) for link in links}
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    results: dict[str, dict[str, list[dict[str, Any]]]] = {}
    failed = 0
    started = time.monotonic()
    for link, link_settings in settings.items():
        results[link] = {}
        for kind in kinds:
            rows = []
            for seed in seeds:
                config = LoopConfig(kind, seed=seed, frames=args.frames, broker_url=args.broker, link=link_settings)
                config = replace(config, heading=args.heading)
                m = summarize(run(config))
                failed += not all(m["passed"].values())
                rows.append(m)
                print(run_line(kind, link, seed, m), flush=True)
            results[link][kind] = rows
        if args.json is not None:
            args.json.write_text(json.dumps(results, indent=1))
    print()
    for link, link_settings in settings.items():
        print(f"{link}: {link_settings}")
    print()
    print("\n".join(bar_table(results)))
    print()
    print("\n".join(link_table(results)))
    n_runs = len(settings) * len(kinds) * len(seeds)
    print(f"\n{n_runs} runs in {time.monotonic() - started:.0f} s; {failed} missed a bar")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
