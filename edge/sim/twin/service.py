"""The lab as a process (``edge-ips sim twin``): build it, serve its socket, switch the rovers on once their broker
and logins are there, run until stopped or (when an edge started it) until nobody has watched for a while.

The rovers' logins: a credentials file (``[rovers.<id>]``: the embedded broker's ``broker-credentials.toml`` in the
state directory, or ``credentials.toml`` from ``edge-ips broker-config``), per-rover configs (``--config-dir``, as
``edge-ips flash --bundle`` writes them), or none (the example configs: user ``<id>``, no password). The embedded
broker writes its logins on the edge's first start, after the edge has opened its camera (this lab): so the lab can
wait for the file (``wait_for_logins``) and switches the rovers on when every rover has one, as rovers are flashed
once the broker's logins exist (a rover that finds no broker yet retries, as the firmware does).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from edge.errors import ConfigError
from edge.sim.twin.lab import LabEvents, LabSettings, TwinLab
from edge.sim.twin.server import LabServer

POLL_S = 0.5  # how often the lab looks for its logins file and its broker while it waits for them


@dataclass(frozen=True)
class LabPlan:
    """Everything ``edge-ips sim twin`` was asked for."""

    settings: LabSettings
    broker_url: str
    socket_path: Path
    credentials: Path | None = None
    config_dir: Path | None = None
    wait_for_logins: bool = False
    exit_unwatched_s: float | None = None


def _configs(plan: LabPlan, ids: list[str], with_logins: bool) -> list[dict[str, Any]]:
    from edge.sim.fleet import fleet_configs, rover_broker

    return fleet_configs(
        ids,
        rover_broker(plan.broker_url),
        config_dir=plan.config_dir,
        credentials=plan.credentials if with_logins else None,
    )


def _logins_ready(path: Path, ids: list[str]) -> bool:
    from edge.broker.credentials import read_credentials

    if not path.is_file():
        return False
    try:
        return all(rover_id in read_credentials(path).rovers for rover_id in ids)
    except Exception:  # being written, or not yet a whole file: look again later
        return False


def run_lab(plan: LabPlan, stop: threading.Event, echo: Callable[[str], None]) -> None:
    """Run the lab until ``stop`` is set, or until no camera reader has been connected for
    ``plan.exit_unwatched_s``. Raises :class:`EdgeIpsError` subclasses for what the user can fix."""
    from edge.sim.fleet import rover_broker
    from edge.sim.rover import fleet_ids

    ids = list(fleet_ids(plan.settings.rovers))
    rover_broker(plan.broker_url)  # a bad URL is said before anything starts
    if plan.credentials is not None and not plan.wait_for_logins:
        if not plan.credentials.is_file():
            raise ConfigError(f"{plan.credentials}: no such credentials file")
        _configs(plan, ids, with_logins=True)  # a file without every rover's login is said now, not waited for
    events = LabEvents(echo)
    lab = TwinLab(plan.settings, _configs(plan, ids, with_logins=False), events=events).start()
    server = LabServer(plan.socket_path, lab)
    try:
        server.start()
        events.add("lab", f"{lab.describe().summary}; camera on {plan.socket_path}")
        rovers_on = False
        said_waiting = ""
        while not stop.wait(POLL_S):
            if not rovers_on:
                waiting = ""
                if plan.credentials is not None and not _logins_ready(plan.credentials, ids):
                    waiting = f"the rovers' logins in {plan.credentials} (the edge writes them on its first start)"
                if waiting and waiting != said_waiting:
                    events.add("lab", f"waiting for {waiting}")
                said_waiting = waiting
                if not waiting:
                    lab.start_rovers(_configs(plan, ids, with_logins=True))
                    rovers_on = True
            left = server.last_reader_left
            limit = plan.exit_unwatched_s
            if limit is not None and left is not None and lab.clock() - left > limit:
                events.add("lab", f"no camera reader for {limit:g} s: closing")
                break
    finally:
        server.close()
        lab.close()
        events.add("lab", "closed: each rover said offline")
