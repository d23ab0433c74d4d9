"""One camera of the wide arena as a live frame source: ``edge-ips start --source sim:wide:cam2``.

Every board of a live twin runs its own process; they agree on the world because its time is the wall clock (the
world at wall time ``t`` is the same in every process on a machine, or on machines synchronised by NTP), not the
time a process started. Camera ``k``'s frame ``i`` is exposed at ``i / fps + phase_k`` on that clock and stamped by
its board's clock, which is ``clock_offset_s`` wrong (a few ms, as NTP leaves boards): the fuser must find that out
from the data.

``sim:wide:camK`` is camera K of the four-camera layout; ``sim:wide:camK:N`` of the N-camera layout (2, 3, 4).
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from edge.calibration.exact import exact_calibration
from edge.calibration.files import Calibration
from edge.camera import PinholeCamera
from edge.errors import SimulationError, SourceError
from edge.sim.render import Renderer
from edge.sim.wide import WideCamera, WideSetup, build_wide
from edge.sim.world import World
from edge.sources import SourceInfo
from edge.tracker_config import RoverConfig
from edge.tracking import Frame

_SPEC = re.compile(r"^wide:cam(\d+)(?::(\d+))?$")


def parse_wide(target: str) -> tuple[str, int]:
    """``wide:camK[:N]`` -> (``camK``, N); raises :class:`SimulationError` naming the right form."""
    match = _SPEC.match(target)
    if match is None:
        raise SimulationError(f"sim:{target}: the wide arena's cameras are sim:wide:camK or sim:wide:camK:N")
    n = int(match[2]) if match[2] else 4
    return f"cam{int(match[1])}", n


class WideCameraSource:
    """One board's camera over the shared wide-arena world, paced by the wall clock (``realtime``) or as fast as it
    renders (frames then follow one another at ``1 / fps`` of world time from the first)."""

    def __init__(
        self,
        target: str,
        *,
        seed: int = 0,
        rovers: int | None = None,
        realtime: bool = True,
        wall_clock: Callable[[], float] = time.time,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        name, n = parse_wide(target)
        self.setup: WideSetup = build_wide(n, seed=seed, rovers=rovers)
        self.cam: WideCamera = self.setup.camera_named(name)
        self.realtime = realtime
        self._wall, self._clock, self._sleep = wall_clock, clock, sleep
        self._renderer: Renderer | None = None
        self._world: World | None = None
        self._next = 0
        self._first = 0

    @property
    def camera(self) -> PinholeCamera:
        return self.cam.camera

    def open(self) -> SourceInfo:
        if self._renderer is None:
            self._renderer = self.setup.renderer(self.cam)
            self._world = self.setup.world()
        self._next = self._due() if self.realtime else 0
        self._first = self._next
        pacing = "real time" if self.realtime else "as fast as possible"
        return SourceInfo(
            self.camera.width_px,
            self.camera.height_px,
            self.setup.fps,
            f"sim:wide:{self.cam.name} of {len(self.setup.cameras)} ({pacing})",
            chroma_spread=self.cam.effects.compression is not None,
            sharpened=self.cam.effects.sharpens,
        )

    def _due(self) -> int:
        """The index of the newest frame exposed by now on the wall clock."""
        return math.floor((self._wall() - self.cam.phase_s) * self.setup.fps)

    def read(self) -> Frame | None:
        if self._renderer is None or self._world is None:
            raise SourceError("sim source: read() before open()")
        index = self._next
        if self.realtime:
            index = max(index, self._due())  # a late reader gets the newest frame, as from a camera
            wait = (index / self.setup.fps + self.cam.phase_s) - self._wall()
            if wait > 0:
                self._sleep(wait)
        t_exposed = index / self.setup.fps + self.cam.phase_s
        image = self.render_at(index, t_exposed)
        self._next = index + 1
        return Frame(image, index, t_exposed + self.cam.clock_offset_s, self._clock())

    def render_at(self, index: int, t_world_s: float) -> NDArray[np.uint8]:
        assert self._renderer is not None and self._world is not None
        # the renderer's own frame count starts at this source's first frame (its lighting tables grow with it)
        return self._renderer.render(self._world.state_at(t_world_s), max(index - self._first, 0))

    def close(self) -> None:
        self._renderer = None
        self._world = None

    # -- edge.sources.SimulatedScene -----------------------------------------------------------------------------------
    def exact_calibration(self) -> Calibration:
        """The exact calibration of this camera on the marker plane, in the shared floor frame."""
        return exact_calibration(self.camera)

    def rover_configs(self) -> tuple[RoverConfig, ...]:
        return self.setup.rover_configs(self._renderer or self.setup.renderer(self.cam))

    def truth_at(self, t_world_s: float) -> dict[str, tuple[float, float]]:
        """Every rover's true position at wall time ``t_world_s`` (cm)."""
        world = self._world or self.setup.world()
        return {r.rover_id: (r.x_cm, r.y_cm) for r in world.state_at(t_world_s).rovers}
