#!/usr/bin/env python3
"""How long the edge's publisher takes to reconnect once its broker is back.

    .venv/bin/python benchmarks/bench_reconnect.py                      # outages of 0.5, 2 and 8 s, 5 times each
    .venv/bin/python benchmarks/bench_reconnect.py --outages 1,4 --repeats 3 --json

What runs: the appliance's publisher (:class:`edge.publisher.MqttPublisher`) with the configuration's default
reconnect backoff (``broker.reconnect_min_s``, ``broker.reconnect_max_s``), connected to a private Mosquitto. The
broker is stopped (SIGTERM) for OUTAGE seconds and started again on the same port; the figure is the time from the
broker's readiness line (``mosquitto version ... running``: its listener is open) to the publisher's CONNACK
(``PublisherStats.connected_since_mono``). paho doubles its wait from the minimum to the maximum while the broker is
away, so a longer outage waits up to ``reconnect_max_s`` for the next attempt.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from _common import MOSQUITTO_BENCH, free_port, private_mosquitto  # noqa: E402  (after sys.path)


def reconnect_times(outage_s: float, repeats: int, workdir: Path) -> list[float]:
    """Seconds from the broker's readiness to the publisher's reconnection, one per outage of ``outage_s``."""
    from edge.config import BrokerSection, BrokerTarget
    from edge.publisher import MqttPublisher

    defaults = BrokerSection()
    port = free_port()
    target = BrokerTarget(embedded=False, host="127.0.0.1", port=port)
    times: list[float] = []
    with private_mosquitto(workdir, MOSQUITTO_BENCH, port=port):
        publisher = MqttPublisher(
            target,
            edge_id="bench",
            rovers=["red"],
            reconnect_min_s=defaults.reconnect_min_s,
            reconnect_max_s=defaults.reconnect_max_s,
        )
        publisher.start()
        if not publisher.wait_connected(10):
            raise RuntimeError("the publisher did not connect to the private broker")
    try:
        for _ in range(repeats):
            # the broker is down here (the with block above, or the one below, stopped it)
            if not publisher.wait_disconnected(10):
                raise RuntimeError("the publisher did not notice the broker stopping")
            threading.Event().wait(outage_s)  # the outage itself
            connects = publisher.stats.connects
            with private_mosquitto(workdir, MOSQUITTO_BENCH, port=port):
                t_back = time.monotonic()
                if not publisher.wait_connected(60) or publisher.stats.connects != connects + 1:
                    raise RuntimeError("the publisher did not reconnect within 60 s")
                since = publisher.stats.connected_since_mono
                assert since is not None
                times.append(max(0.0, since - t_back))
    finally:
        publisher.stop()
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--outages", default="0.5,2,8", help="Outage lengths, seconds, comma-separated.")
    parser.add_argument("--repeats", type=int, default=5, help="Outages of each length.")
    parser.add_argument("--json", action="store_true", help="Print one JSON object.")
    args = parser.parse_args()
    from edge.config import BrokerSection

    defaults = BrokerSection()
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-reconnect-") as tmp:
        for k, outage in enumerate(float(x) for x in args.outages.split(",")):
            times = reconnect_times(outage, args.repeats, Path(tmp) / f"broker-{k}")
            rows.append(
                {
                    "outage_s": outage,
                    "n": len(times),
                    "median_s": round(statistics.median(times), 3),
                    "max_s": round(max(times), 3),
                    "times_s": [round(t, 3) for t in times],
                }
            )
    result = {
        "machine": f"{platform.node()} ({platform.machine()}, {platform.python_version()})",
        "date": time.strftime("%Y-%m-%d"),
        "reconnect_min_s": defaults.reconnect_min_s,
        "reconnect_max_s": defaults.reconnect_max_s,
        "rows": rows,
    }
    if args.json:
        print(json.dumps(result, indent=2))
        return
    print(f"{result['machine']}, {result['date']}; backoff {defaults.reconnect_min_s}-{defaults.reconnect_max_s} s")
    print(f"{'outage s':>9} {'n':>3} {'median s':>9} {'max s':>7}")
    for row in rows:
        print(f"{row['outage_s']:>9g} {row['n']:>3} {row['median_s']:>9.3f} {row['max_s']:>7.3f}")


if __name__ == "__main__":
    main()
