"""The live twin end to end: ``edge-ips start --source sim:twin`` (its lab started by the edge, or by hand for an
external broker), and the poses as published, read by an MQTT observer and judged by the closed-loop bars.

Every wait is on messages (the observer's condition variable), bounded by a generous failure timeout.
"""

from __future__ import annotations

import json
import math
import subprocess
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from edge.messages import FORMATION_TOPIC, POSE_WILDCARD, ROVER_STATUS_WILDCARD
from edge.sim.twin.bars import FormationScore, largest_moves_cm, score_formation
from edge.sim.twin.source import LabClient
from tests.support.command import EDGE_IPS, Edge
from tests.support.dashboard import clean_env
from tests.support.runtime import MqttRecorder, stop_process

TIMEOUT_S = 180.0  # failure guard only
TOPICS = (POSE_WILDCARD, FORMATION_TOPIC, ROVER_STATUS_WILDCARD)


@dataclass(frozen=True)
class Pose:
    t_recv: float  # when the observer got it (this machine's clock)
    t: float  # the pose's own time: when the edge had the frame
    frame: int
    id: str
    x: float
    y: float
    speed: float


class Poses:
    """The observer's poses, parsed as they come (each wait looks only at what is new)."""

    def __init__(self, rec: MqttRecorder) -> None:
        self.rec = rec
        self.poses: list[Pose] = []
        self._seen = 0
        self._lock = threading.Lock()

    def _update(self, messages: Sequence[Any]) -> None:
        with self._lock:
            for m in messages[self._seen :]:
                if m.topic.endswith("/pose") and m.payload:
                    d = json.loads(m.payload)
                    speed = math.hypot(d["vx"], d["vy"]) if d.get("vx") is not None else 0.0
                    self.poses.append(Pose(m.t_recv, d["t"], d["frame"], d["id"], d["x"], d["y"], speed))
            self._seen = len(messages)

    def wait(self, done: Callable[[list[Pose]], bool], what: str, timeout_s: float = TIMEOUT_S) -> None:
        def check(messages: list[Any]) -> bool:
            self._update(messages)
            return done(self.poses)

        assert self.rec.wait_for(check, timeout_s), f"{what}: not within {timeout_s:g} s"

    def since(self, t: float) -> list[Pose]:
        """Poses whose own time is ``t`` or later."""
        with self._lock:
            return [p for p in self.poses if p.t >= t]


def wait_tracked(poses: Poses, ids: Sequence[str], after: float, seconds: float = 1.0) -> None:
    """Until every rover has been tracked for ``seconds`` of poses since ``after`` (after a scatter: the tracker
    found them again)."""

    def done(_: list[Pose]) -> bool:
        recent = poses.since(after)
        return all(len(ts := [p.t for p in recent if p.id == rid]) > 1 and ts[-1] - ts[0] >= seconds for rid in ids)

    poses.wait(done, f"every rover tracked for {seconds:g} s")


def formation_run(poses: Poses, ids: Sequence[str], kind: str, t_command: float, frames: int) -> FormationScore:
    """Wait for ``frames`` camera frames after the command and judge them by the closed-loop bar."""
    first: list[int] = []

    def enough(_: list[Pose]) -> bool:
        after = poses.since(t_command)
        if not after:
            return False
        first[:] = [min(p.frame for p in after)]
        return max(p.frame for p in after) >= first[0] + frames

    poses.wait(enough, f"{frames} frames of {kind}")
    return score_formation([asdict(p) for p in poses.since(t_command)], ids, kind, first[0], frames)


def stop_run(poses: Poses, ids: Sequence[str], t_stop: float, after_s: float, window_s: float) -> dict[str, float]:
    """Each rover's largest move in its poses from ``t_stop + after_s`` for ``window_s`` (cm): what "at rest"
    means on the poses as published."""
    t0, t1 = t_stop + after_s, t_stop + after_s + window_s
    poses.wait(lambda ps: bool(ps) and ps[-1].t >= t1 + 0.1, "poses after the stop")
    window = [p for p in poses.since(t0) if p.t <= t1]
    for rid in ids:
        assert sum(p.id == rid for p in window) > 5, f"{rid}: too few poses after the stop"
    return largest_moves_cm([asdict(p) for p in window], ids, t0, t1)


def rest_events(lab: LabClient, label: str, after: int, rovers: Sequence[str]) -> dict[str, dict[str, Any] | None]:
    """Wait for the lab's word on each of ``rovers`` after the fault or note ``label`` (events after number
    ``after``): its rest timing (``after_fault_s``, ``after_pose_s``), or None for a rover at rest already."""
    found: dict[str, dict[str, Any] | None] = {}
    seen = after
    deadline = time.monotonic() + TIMEOUT_S
    while time.monotonic() < deadline:
        status = lab.wait_event(seen, max(0.0, deadline - time.monotonic()))  # answered at the lab's next event
        for e in status["events"]:
            seen = max(seen, e["n"])
            rest = e.get("rest")
            if e["who"] in rovers and rest is not None and rest["fault"] == label:
                found[e["who"]] = None if rest.get("already") else rest
        if all(r in found for r in rovers):
            return found
    raise AssertionError(f"the lab did not time every rover after {label}: {found}")


def wait_driving(lab: LabClient, speed_cm_s: float = 10.0) -> None:
    """Until a rover drives at ``speed_cm_s`` or more by the lab's ground truth (a rover's poses jump when the lab
    scatters it, which is no driving)."""
    status = lab.wait_driving(speed_cm_s, TIMEOUT_S)  # answered by the lab once one does
    assert status["met"], f"no rover drove at {speed_cm_s:g} cm/s within {TIMEOUT_S:g} s: {status['rovers']}"


@dataclass
class TwinLabProcess:
    """``edge-ips sim twin`` started by hand (for an external broker, with the rovers' logins)."""

    args: list[str]
    state_dir: Path
    workdir: Path
    proc: subprocess.Popen[str] | None = None
    log: Path = field(init=False)

    def start(self) -> TwinLabProcess:
        self.log = self.workdir / "twin-lab.out"
        self.workdir.mkdir(parents=True, exist_ok=True)
        self.proc = subprocess.Popen(
            [*EDGE_IPS, "sim", "twin", *self.args],
            cwd=self.workdir,
            env=clean_env(EDGE_IPS_EDGE__STATE_DIR=str(self.state_dir), PYTHONUNBUFFERED="1"),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        said, ended = threading.Event(), threading.Event()
        threading.Thread(target=self._copy_log, args=(said, ended), daemon=True).start()
        assert said.wait(TIMEOUT_S), f"the lab did not serve within {TIMEOUT_S:g} s:\n{self.log.read_text()}"
        assert not ended.is_set(), f"the lab ended:\n{self.log.read_text()}"
        return self

    def _copy_log(self, said: threading.Event, ended: threading.Event) -> None:
        """The lab's output into :attr:`log`, line by line; ``said`` set at its "camera on <socket>" line (it
        serves from then on), ``ended`` and ``said`` when its output ends."""
        assert self.proc is not None and self.proc.stdout is not None
        with self.log.open("w") as out:
            for line in self.proc.stdout:
                out.write(line)
                out.flush()
                if "camera on " in line:
                    said.set()
        ended.set()
        said.set()

    def stop(self) -> None:
        if self.proc is not None:
            stop_process(self.proc)


@dataclass
class Twin:
    """A running twin: the edge, its lab's controls, the observer's poses."""

    edge: Edge
    lab: LabClient
    rec: MqttRecorder
    poses: Poses
    broker: str
