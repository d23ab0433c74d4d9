"""Run a whole appliance (``prepare_appliance``) in a thread of the test, with the fake tracker."""

from __future__ import annotations

import os
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from edge.appliance import Appliance, prepare_appliance
from edge.config import EdgeConfig, default_state_dir
from edge.config_load import with_overrides
from edge.sources import MemorySource
from tests.support.runtime import CentroidTracker, scene


def memory_sim(frames: int = 90, fps: float = 30.0) -> Any:
    """A stand-in for the simulator: pre-rendered scene frames, looped, paced at ``fps`` when its caller asks."""
    images = [scene(i) for i in range(frames)]
    return lambda scenario, *, realtime: MemorySource(images, fps=fps, loop=True, realtime=realtime)


def edge_config(**overrides: Any) -> EdgeConfig:
    base = {
        "edge.id": "edge-t",
        "edge.state_dir": default_state_dir(os.environ),  # the test's own (tests/conftest.py)
        "edge.status_interval_s": 0.3,
        "http.enabled": False,
        "broker.reconnect_min_s": 0.1,
        "broker.reconnect_max_s": 2.0,
        "camera.stall_timeout_s": 0.5,
        "camera.reopen_min_s": 0.1,
        "camera.reopen_max_s": 0.5,
    }
    base.update(overrides)
    return with_overrides(EdgeConfig(), **base)


@contextmanager
def running(config: EdgeConfig, **kw: Any) -> Iterator[Appliance]:
    """Prepare and run the appliance in a background thread; stop it (SIGTERM's path) on exit."""
    kw.setdefault("tracker_factory", lambda inputs: CentroidTracker())
    kw.setdefault("calibration_loader", lambda *a: None)
    kw.setdefault("sim_factory", memory_sim())
    app = prepare_appliance(config, **kw)
    stop = threading.Event()
    errors: list[BaseException] = []

    def run() -> None:
        try:
            app.run(stop)
        except BaseException as exc:
            errors.append(exc)

    thread = threading.Thread(target=run, name="appliance", daemon=True)
    thread.start()
    try:
        yield app
    finally:
        stop.set()
        thread.join(20)
    if errors:
        raise errors[0]
