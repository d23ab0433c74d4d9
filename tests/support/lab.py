"""A lab floor under the paper's camera for the enrolment tests: frames with rovers standing where a test puts them
and of the empty floor, rendered by the simulator, and the tracker driven over them."""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from edge.appliance import Appliance, TrackerInputs
from edge.calibration.exact import exact_calibration
from edge.camera import PinholeCamera, paper_camera
from edge.runtime import EdgeRuntime
from edge.sim.cameras import CameraDraw, draw_family
from edge.sim.render import Renderer
from edge.sim.scene import FLOORS, RoverLook, Scene, marker_albedo_for_hue
from edge.sim.setup import lab_effects
from edge.sim.world import RoverState, WorldState
from edge.sources import SourceInfo
from edge.tracker_config import RoverConfig, TrackerConfig
from edge.trackers.factory import build_tracker
from edge.tracking import Frame, Tracker
from tests.support.appliance import edge_config, running

PALETTE = (("red", 0), ("orange", 30), ("yellow", 60), ("green", 120), ("cyan", 180), ("blue", 240),
           ("purple", 270), ("magenta", 300))  # fmt: skip
Pose = tuple[float, float, float]


def eight_hues(heading: str = "plain") -> tuple[RoverLook, ...]:
    return tuple(RoverLook(name, marker_albedo_for_hue(hue), heading=heading) for name, hue in PALETTE)  # type: ignore[arg-type]


def spread_out(n: int) -> list[Pose]:
    """n rovers on two rows across the working area, each turned differently."""
    cols = math.ceil(n / 2)
    return [
        (60.0 + 270.0 * (k % cols) / max(cols - 1, 1), 130.0 + 260.0 * (k // cols), 0.4 * k - 1.0) for k in range(n)
    ]


class Lab:
    """The paper's camera over the lab floor with ``looks`` on it; frames of the rovers and of the empty floor."""

    def __init__(
        self,
        looks: Sequence[RoverLook],
        seed: int = 0,
        camera: PinholeCamera | None = None,
        floor: str = "tiles",
        webcam: CameraDraw | None = None,
    ) -> None:
        self.looks = tuple(looks)
        self.camera = camera or paper_camera()
        effects = lab_effects(np.random.default_rng(seed))
        effects = webcam.apply(effects) if webcam is not None else effects
        self.renderer = Renderer(self.camera, Scene(rovers=self.looks, floor=FLOORS[floor]), effects, seed=seed)
        self.calibration = exact_calibration(self.camera, self.looks[0].body_height_cm if webcam else None)
        self.camera_name = webcam.name if webcam is not None else "the lab's"

    @classmethod
    def family(cls, looks: Sequence[RoverLook], seed: int, floor: str = "tiles") -> Lab:
        """A lab seen by a webcam drawn from the simulator's family (``edge.sim.cameras``: stream, optics, colour,
        white balance, processor) with the rovers' bodies drawn too (black, dark grey or white, 8-20 cm tall), the
        calibration on their marker plane."""
        drawn, drawn_looks = draw_family("enrol", seed, tuple(looks))
        return cls(drawn_looks, seed, floor=floor, webcam=drawn)

    def frame(self, poses: Sequence[Pose], index: int = 5) -> np.ndarray:
        rovers = tuple(
            RoverState(look.rover_id, x, y, th, 0.0, 0.0) for look, (x, y, th) in zip(self.looks, poses, strict=True)
        )
        return self.renderer.render(WorldState(index / 30.0, rovers), index)

    def background(self, index: int = 5) -> np.ndarray:
        return self.renderer.background(index)


def track(
    lab: Lab,
    rovers: Sequence[RoverConfig],
    start: Sequence[Pose],
    frames: int = 45,
    lab_ids: Mapping[str, str] | None = None,
) -> dict[str, list[float]]:
    """Drive every rover 20 cm/s along its heading for ``frames`` frames, tracked by the pipeline configured with
    ``rovers``: per rover id, its position error (cm) in each of the last 15 frames (inf when not found).
    ``lab_ids``: the lab's id of each configured rover, where they differ (rovers enrolled under other names)."""
    tracker = build_tracker(TrackerConfig(rovers=tuple(rovers)), lab.calibration, lab.background(0))
    errors: dict[str, list[float]] = {r.id: [] for r in rovers}
    for i in range(frames):
        t = i / 30.0
        poses = [(x + 20.0 * t * math.cos(th), y + 20.0 * t * math.sin(th), th) for x, y, th in start]
        result = tracker.process(Frame(lab.frame(poses, i), i, t, t))
        if i < frames - 15:
            continue
        truth = {look.rover_id: p for look, p in zip(lab.looks, poses, strict=True)}
        found = {e.rover_id: e for e in result.estimates}
        for r in rovers:
            e = found.get(r.id)
            x, y, _ = truth[(lab_ids or {}).get(r.id, r.id)]
            errors[r.id].append(math.inf if e is None else math.hypot(e.x_cm - x, e.y_cm - y))
    return errors


class Stage:
    """A camera over a floor the test clears and fills (a :class:`edge.sources.FrameSource`): every frame shows the
    image :meth:`show` was given last, delivered at ``fps`` as a camera delivers them."""

    def __init__(self, image: NDArray[np.uint8], fps: float = 30.0) -> None:
        self._image = image
        self.fps = fps
        self._index = 0
        self._next_due = 0.0
        self._lock = threading.Lock()

    def show(self, image: NDArray[np.uint8]) -> int:
        """Put ``image`` in view; returns the index of the first frame that shows it."""
        with self._lock:
            self._image = image
            return self._index

    def open(self) -> SourceInfo:
        h, w = self._image.shape[:2]
        self._next_due = time.monotonic()
        return SourceInfo(w, h, self.fps, f"stage {w}x{h}")

    def read(self) -> Frame | None:
        now = time.monotonic()
        if self._next_due > now:
            time.sleep(self._next_due - now)  # the camera's frame rate, not a test waiting for something
        self._next_due = max(self._next_due, now) + 1.0 / self.fps
        with self._lock:
            image, index = self._image, self._index
            self._index += 1
        return Frame(image, index, time.time(), time.monotonic())

    def close(self) -> None:
        pass


def tracked_since(runtime: EdgeRuntime, index: int, timeout_s: float = 60.0) -> None:
    """Wait until the appliance has tracked frame ``index`` or a later one (and its result is the newest)."""
    deadline = time.monotonic() + timeout_s
    while True:
        frame, result = runtime.last_frame, runtime.latest_result
        if frame is not None and result is not None and frame.index >= index and result.frame_index == frame.index:
            return
        if time.monotonic() > deadline:
            raise AssertionError(f"frame {index} was not tracked within {timeout_s} s")
        runtime.wait_tracked(1.0)


def until_tracking(runtime: EdgeRuntime, rover_ids: Sequence[str], timeout_s: float = 60.0) -> None:
    """Wait until the appliance's newest result has every one of ``rover_ids``."""
    deadline = time.monotonic() + timeout_s
    while True:
        result = runtime.latest_result
        if result is not None and set(rover_ids) <= {e.rover_id for e in result.estimates}:
            return
        if time.monotonic() > deadline:
            raise AssertionError(f"not all of {', '.join(rover_ids)} tracked within {timeout_s} s")
        runtime.wait_tracked(1.0)


@contextmanager
def lab_appliance(
    lab: Lab, broker_url: str, folder: Path, *, token: str | None, viewer_token: str | None = None
) -> Iterator[tuple[Appliance, Stage]]:
    """A running appliance (HTTP on a free port, the real pipeline tracking ``lab``'s rovers in their nominal
    colours, ``dashboard.rovers_file`` = ``folder/rovers.toml``) whose camera is a :class:`Stage` showing the empty
    floor; it has tracked its first frame when this yields."""
    rovers = [{"id": k.rover_id, "color_bgr": list(lab.renderer.nominal_marker_bgr(k.rover_id))} for k in lab.looks]
    settings: dict[str, Any] = {
        "edge.state_dir": str(folder / "state"), "http.enabled": True, "http.port": 0, "broker.url": broker_url,
        "dashboard.rovers_file": str(folder / "rovers.toml"), "rovers": rovers,
        "dashboard.token": token, "dashboard.viewer_token": viewer_token,
    }  # fmt: skip
    stage = Stage(lab.background())

    def tracker(inputs: TrackerInputs) -> Tracker:
        return build_tracker(TrackerConfig.of(inputs.config.tracker, inputs.config.rovers), inputs.calibration)

    with running(
        edge_config(**{k: v for k, v in settings.items() if v is not None}),
        sim_factory=lambda scenario, *, realtime: stage,
        tracker_factory=tracker,
        calibration_loader=lambda *a: lab.calibration,
    ) as app:
        tracked_since(app.runtime, 1)
        yield app, stage
