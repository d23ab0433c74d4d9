"""``python -m tests.support.edge_process ARGS``: ``edge-ips start``'s exact path (configuration, checks,
:func:`run_until_signalled`) with the fake tracker and the stand-in simulator, for signal tests in a real process.

Arguments are dotted configuration overrides, ``camera.source=sim broker.url=mqtt://127.0.0.1:1883``.
"""

from __future__ import annotations

import logging
import sys

from edge.appliance import prepare_appliance, run_until_signalled
from tests.support.appliance import edge_config, memory_sim
from tests.support.runtime import CentroidTracker


def main(argv: list[str]) -> None:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    overrides = dict(arg.split("=", 1) for arg in argv)
    config = edge_config(**overrides)
    appliance = prepare_appliance(
        config,
        tracker_factory=lambda inputs: CentroidTracker(stride=max(1, inputs.info.width_px // 320)),
        calibration_loader=lambda *a: None,
        sim_factory=memory_sim(),
    )
    print("ready", flush=True)
    run_until_signalled(appliance)


if __name__ == "__main__":
    main(sys.argv[1:])
