"""How wrong the rovers' heading estimate gets over Wi-Fi, fused at the pose's age (the firmware) or at its arrival.

    .venv/bin/python benchmarks/bench_heading_delay.py                               # line, seeds 0-4 and 17
    .venv/bin/python benchmarks/bench_heading_delay.py --at-arrival                  # the fusion before dating poses
    .venv/bin/python benchmarks/bench_heading_delay.py --kinds line,rendezvous --seeds 0,1,2 --links wire,poor

The firmware (formation.Heading) integrates its *commanded* turn rate and gates each pose heading against its
estimate. A pose heading is as old as the pose: 50-80 ms on a wire (capture to publish, and the wait for the next
control step), 100-250 ms over a poor link, more in a burst after a retransmission; a rover turning at 3 rad/s has
turned 15-40 degrees since. The firmware dates each pose by its capture time `t` (rover.PoseClock: its age beyond the
fastest delivery, plus control.latency_ms for the fastest delivery itself), winds the estimate back by the turn it
commanded since, fuses the pose there, and winds forward again. For every control step in which a rover drives, this
prints the error of its heading estimate against the simulated truth, and how often the error exceeds what the
safety layer allows for (its heading margin, 0.35 rad, plus the estimate's spread): there the barrier certificate
protects the wrong heading.

``--at-arrival`` runs the same closed loop with each pose heading fused as if it had just been captured (age 0: the
firmware before it dated poses; freshness is still judged by age), to show what the dating buys.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from edge.rover_host import firmware_modules
from edge.sim import loop as loop_module
from edge.sim import loop_fleet as fleet_module
from edge.sim.link import LinkSettings
from edge.sim.loop import LoopConfig, run
from edge.sim.report import summarize

MARGIN_DEG = math.degrees(0.35)  # control.heading_margin_rad of the example configs


def install_fusion_at_arrival() -> None:
    """Make the firmware's Heading fuse every pose as if it were new (this process only)."""
    fm = firmware_modules()["formation"]
    measured = fm.Heading.measured

    def at_arrival(self: Any, x: float, y: float, theta: float | None, age_ms: int = 0) -> None:
        measured(self, x, y, theta, 0)

    fm.Heading.measured = at_arrival


def heading_errors(config: LoopConfig) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """(error deg, allowed deg) at every driving step of every rover, and the run's metrics."""
    errors: list[float] = []
    allowed: list[float] = []
    world: dict[str, Any] = {}
    init, step = loop_module.ClosedLoop.__init__, fleet_module.Fleet.step

    def remember_world(self: Any, *args: Any, **kwargs: Any) -> None:
        init(self, *args, **kwargs)
        world["w"] = self.world

    def step_and_look(self: Any, now_ms: int) -> Any:
        out = step(self, now_ms)
        truth = world["w"].state().by_id()
        for rid, host in self.rovers.items():
            h = host.rover.heading
            if host.halt == "none" and h.known:
                errors.append(math.degrees(abs(math.remainder(h.theta - truth[rid].theta_rad, math.tau))))
                allowed.append(MARGIN_DEG + math.degrees(h.spread))
        return out

    loop_module.ClosedLoop.__init__ = remember_world  # type: ignore[method-assign]
    fleet_module.Fleet.step = step_and_look  # type: ignore[method-assign]
    try:
        metrics = summarize(run(config))
    finally:
        loop_module.ClosedLoop.__init__ = init  # type: ignore[method-assign]
        fleet_module.Fleet.step = step  # type: ignore[method-assign]
    return np.asarray(errors), np.asarray(allowed), metrics


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--kinds", default="line", help="formations, comma separated (default line)")
    parser.add_argument("--seeds", default="0,1,2,3,4,17", help="seeds, comma separated")
    parser.add_argument("--links", default="wire,typical,poor", help="link presets, comma separated")
    parser.add_argument("--at-arrival", action="store_true", help="fuse pose headings as if new (for comparison)")
    args = parser.parse_args()
    if args.at_arrival:
        install_fusion_at_arrival()
    print(
        "| link | formation | heading error p50 / p95 / p99 / max deg | driving steps beyond the margin | "
        "closest bodies cm | runs passing |"
    )
    print("|---|---|---|---|---|---|")
    for link in args.links.split(","):
        for kind in args.kinds.split(","):
            errs, allow, gaps, passing = [], [], [], 0
            seeds = [int(s) for s in args.seeds.split(",")]
            for seed in seeds:
                e, a, m = heading_errors(LoopConfig(kind, seed=seed, frames=360, link=LinkSettings.parse(link)))
                errs.append(e)
                allow.append(a)
                gaps.append(m["min_body_gap_cm"])
                passing += all(m["passed"].values())
            e, a = np.concatenate(errs), np.concatenate(allow)
            p50, p95, p99 = np.percentile(e, [50, 95, 99])
            print(
                f"| {link} | {kind} | {p50:.1f} / {p95:.1f} / {p99:.1f} / {e.max():.1f} | {100 * np.mean(e > a):.1f} % "
                f"| {min(gaps):.1f} | {passing} / {len(seeds)} |",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
