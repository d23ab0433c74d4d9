"""``python -m tests.support.synthetic_board URL EDGE_ID X0,Y0,X1,Y1 [CLOCK_OFFSET_MS [QOS]]``: a camera board without a
camera, for the fuser's process tests: it publishes detections v1 of a few rovers on fixed paths at 30 frames/s on
the wall clock (each stamped by its own clock, ``CLOCK_OFFSET_MS`` wrong), its retained status, and a last will,
through a real MQTT connection, like ``edge-ips start`` with ``edge.publish = "detections"``. Much lighter than
rendering and tracking, so the fusers' failover can be tested on a busy machine.

The rovers: ``r1`` circles round (400, 275), crossing the seam at x = 400 twice a lap; ``r2`` circles in the left
half, ``r3`` in the right half.
"""

from __future__ import annotations

import math
import signal
import sys
import threading
import time
from urllib.parse import urlsplit

import numpy as np
import paho.mqtt.client as mqtt

from edge.board_messages import detections_topic
from edge.fusion.detections import Detection, Detections, encode_detections
from edge.messages import StatusV1, dumps, edge_status_topic

FPS = 30.0
PATHS = {
    "r1": ((400.0, 275.0), 120.0, 25.0),
    "r2": ((180.0, 200.0), 80.0, 20.0),
    "r3": ((620.0, 350.0), 80.0, -20.0),
}


def truth(rover_id: str, t: float) -> tuple[float, float]:
    """Where a rover is at wall time ``t`` (the same in every process)."""
    (cx, cy), r, v = PATHS[rover_id]
    a = (v / r) * (t % 3600.0)
    return cx + r * math.cos(a), cy + r * math.sin(a)


def status(edge_id: str, state: str, rovers: list[str]) -> bytes:
    return dumps(
        StatusV1(
            v=1,
            edge=edge_id,
            state=state,
            camera="ok" if state == "online" else "stopped",
            fps=FPS if state == "online" else 0.0,
            rovers=rovers,
            missing=[],
            t=round(time.time(), 3),
        )  # type: ignore[arg-type]
    )


def main(argv: list[str]) -> None:
    url, edge_id, view = argv[0], argv[1], tuple(float(v) for v in argv[2].split(","))
    offset_s = float(argv[3]) / 1e3 if len(argv) > 3 else 0.0
    qos = int(argv[4]) if len(argv) > 4 else 0  # 1: what a bridge could queue while its link is down
    target = urlsplit(url)
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"edge-ips-{edge_id}")
    if target.username:
        client.username_pw_set(target.username, target.password)
    client.will_set(edge_status_topic(edge_id), status(edge_id, "offline", []), qos=1, retain=True)
    connected = threading.Event()
    client.on_connect = lambda c, u, f, rc, p: connected.set()
    client.connect(target.hostname or "127.0.0.1", target.port or 1883, keepalive=5)
    client.loop_start()
    connected.wait(10)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda s, f: stop.set())
    rng = np.random.default_rng(abs(hash(edge_id)) % 2**32)
    x0, y0, x1, y1 = view
    polygon = ((x0, y0), (x1, y0), (x1, y1), (x0, y1))
    seq = 0
    k = math.ceil(time.time() * FPS)
    next_status = 0.0
    print("ready", flush=True)
    while not stop.is_set():
        t_exposed = k / FPS
        wait = t_exposed - time.time()
        if wait > 0:
            stop.wait(wait)
        rovers = []
        for rover_id in PATHS:
            x, y = truth(rover_id, t_exposed)
            margin = min(x - x0, x1 - x, y - y0, y1 - y) - 14.0
            if margin <= 0:
                continue
            sigma = 0.15 * (1.0 if margin >= 12.0 else 12.0 / margin)
            noise = rng.normal(0.0, 0.15, 2)
            var = sigma * sigma + 0.0025
            rovers.append(
                Detection(rover_id, (x + noise[0], y + noise[1]), (var, 0.0, var), None, 0.95, (640.0, 360.0))
            )
        d = Detections(edge_id, seq, k, t_exposed + offset_s, time.time() + offset_s, 1.0, polygon, tuple(rovers))
        client.publish(detections_topic(edge_id), encode_detections(d), qos=qos)
        if time.time() >= next_status:
            client.publish(
                edge_status_topic(edge_id), status(edge_id, "online", [r.rover_id for r in rovers]), qos=1, retain=True
            )
            next_status = time.time() + 1.0
        seq += 1
        k = max(k + 1, math.floor(time.time() * FPS))
    client.publish(edge_status_topic(edge_id), status(edge_id, "offline", []), qos=1, retain=True).wait_for_publish(3)
    client.disconnect()
    client.loop_stop()


if __name__ == "__main__":
    main(sys.argv[1:])
