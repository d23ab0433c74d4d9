"""The simulator as a frame source: ``edge-ips start --source sim[:SCENARIO]`` and the accuracy benchmarks.

:class:`SimSource` implements :class:`edge.sources.FrameSource`. It renders a scenario frame by frame, paced at the
scenario's 30 fps in real time (a late reader skips frames, as a real camera would) or as fast as possible, and
keeps the ground truth of every frame it produced (``truth(frame_index)``). Deterministic for a given seed: frame
``i`` of a scenario and seed is the same image on every run, whatever the pacing.
"""

from __future__ import annotations

import math
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from edge.calibration.exact import exact_calibration
from edge.calibration.files import Calibration
from edge.errors import SimulationError, SourceError
from edge.sim.render import Renderer
from edge.sim.scenarios import SimSetup, build
from edge.sim.scene import Heading
from edge.sim.world import World, WorldState
from edge.sources import SourceInfo
from edge.tracker_config import RoverConfig
from edge.tracking import Frame


@dataclass(frozen=True)
class RoverTruth:
    """Ground truth of one rover in one frame.

    ``x_cm, y_cm``: marker centre in world cm at marker height (z = 13 cm by default); ``theta_rad``: heading
    (0 along +x, counter-clockwise, in (-pi, pi]); ``vx_cm_s, vy_cm_s``: world velocity at the frame's time (the
    middle of its exposure); ``visible``: fraction of the marker's area in the image and not hidden (0..1).
    """

    rover_id: str
    x_cm: float
    y_cm: float
    theta_rad: float
    vx_cm_s: float
    vy_cm_s: float
    visible: float


@dataclass(frozen=True)
class FrameTruth:
    frame_index: int
    t_s: float
    rovers: tuple[RoverTruth, ...]

    def by_id(self) -> dict[str, RoverTruth]:
        return {r.rover_id: r for r in self.rovers}


def frame_truth(state: WorldState, frame_index: int, visibility: dict[str, float]) -> FrameTruth:
    """The ground truth of a rendered frame from the world state it showed and the renderer's visibility."""
    return FrameTruth(
        frame_index,
        state.t_s,
        tuple(
            RoverTruth(
                r.rover_id,
                float(r.x_cm),
                float(r.y_cm),
                float(r.theta_rad),
                float(r.vx_cm_s),
                float(r.vy_cm_s),
                float(visibility.get(r.rover_id, 0.0)),
            )
            for r in state.rovers
        ),
    )


class SimSource:
    """A simulated camera playing a scenario.

    ``frames``: length of the stream; None (the default) plays forever, the scenario's run repeating every
    ``setup.frames`` frames (rovers jump back to their starts). ``realtime``: pace frames at the scenario's fps,
    stamped when they are delivered; otherwise deliver them as fast as they render. ``heading``: heading markers on
    the rovers (``plain``, ``two_tone``, ``aruco``). ``history``: how many frames' ground truth to keep.
    """

    def __init__(
        self,
        scenario: str = "lab",
        seed: int = 0,
        realtime: bool = True,
        *,
        rovers: int | None = None,
        frames: int | None = None,
        heading: Heading = "plain",
        history: int = 9000,
        clock: Callable[[], float] = time.monotonic,
        wall_clock: Callable[[], float] = time.time,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        if frames is not None and frames < 1:
            raise SimulationError(f"sim source: frames must be at least 1, got {frames}")
        self.setup: SimSetup = build(scenario, seed=seed, rovers=rovers, heading=heading)
        self.scenario = scenario
        self.seed = seed
        self.realtime = realtime
        self.frames = frames
        self._history_size = max(int(history), 1)
        self._clock, self._wall_clock, self._sleep = clock, wall_clock, sleep
        self._renderer: Renderer | None = None
        self._world: World | None = None
        self._next_index = 0
        self._t0_mono = 0.0
        self._truths: OrderedDict[int, FrameTruth] = OrderedDict()

    # -- FrameSource ------------------------------------------------------------------------------------------------
    def open(self) -> SourceInfo:
        if self._renderer is None:
            self._renderer = self.setup.renderer()
            self._world = self.setup.world()
        self._next_index = 0
        self._t0_mono = self._clock()
        self._truths.clear()
        cam = self.setup.camera
        pacing = "real time" if self.realtime else "as fast as possible"
        return SourceInfo(
            cam.width_px,
            cam.height_px,
            self.setup.fps,
            f"sim:{self.scenario} seed {self.seed} ({pacing})",
            chroma_spread=self.setup.effects.compression is not None,  # the scenes the simulator compresses
            sharpened=self.setup.effects.sharpens,
        )

    def read(self) -> Frame | None:
        if self._renderer is None or self._world is None:
            raise SourceError("sim source: read() before open()")
        index = self._next_index
        if self.realtime:  # a real camera keeps running: a late reader gets the newest frame, not a backlog
            due = math.floor((self._clock() - self._t0_mono) * self.setup.fps)
            index = max(index, due)
        if self.frames is not None and index >= self.frames:
            return None
        image = self.render(index)
        if self.realtime:
            wait = self._t0_mono + index / self.setup.fps - self._clock()
            if wait > 0:
                self._sleep(wait)
        self._next_index = index + 1
        return Frame(image, index, self._wall_clock(), self._clock())

    def close(self) -> None:
        self._renderer = None
        self._world = None

    # -- simulator access ------------------------------------------------------------------------------------------
    def render(self, frame_index: int) -> NDArray[np.uint8]:
        """Render frame ``frame_index`` (recording its ground truth) without pacing."""
        if self._renderer is None or self._world is None:
            raise SourceError("sim source: render() before open()")
        period = self.setup.frames
        t_s = (frame_index % period) / self.setup.fps
        state = self._world.state_at(t_s)
        image = self._renderer.render(state, frame_index)
        self._truths[frame_index] = frame_truth(state, frame_index, self._renderer.visibility)
        while len(self._truths) > self._history_size:
            self._truths.popitem(last=False)
        return image

    def truth(self, frame_index: int) -> FrameTruth:
        """Ground truth of a frame this source produced (the last ``history`` frames are kept)."""
        found = self._truths.get(frame_index)
        if found is None:
            raise SimulationError(f"sim source: no ground truth for frame {frame_index} (not produced or too old)")
        return found

    # -- edge.sources.SimulatedScene -----------------------------------------------------------------------------------
    def exact_calibration(self) -> Calibration:
        """The exact calibration of this camera on the marker plane: the simulator knows its camera."""
        return exact_calibration(self.setup.camera)

    def rover_configs(self) -> tuple[RoverConfig, ...]:
        """Rover ids and marker colours as this camera sees them, for the tracker's configuration."""
        return self.setup.rover_configs(self._renderer)
