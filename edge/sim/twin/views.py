"""The lab's cameras: the paper's one over its floor, or two to four boards over the wide arena, one shared floor.

One camera (the default) is today's lab: :func:`edge.camera.paper_camera` above the paper's 3.9 x 5.5 m working
area, in its lighting. Several are the wide arena of :mod:`edge.sim.wide` (8 x 5.5 m; 2 side by side, 3 in a row,
or 2 x 2), each camera installed over its region of the floor with its own exposure and flicker phase, all in the
one floor frame: each board's calibration is its camera's exact one in that frame, so the boards agree where their
views overlap, as boards calibrated on shared survey points do.

Each view's rover colours are measured as an installer picks them from that camera's live picture (a rover standing
in the middle of its region), so each board's tracker gets the colours its own camera sees.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from edge.camera import MARKER_HEIGHT_CM, PinholeCamera
from edge.errors import ConfigError
from edge.sim.render import Renderer
from edge.sim.scene import RoverLook
from edge.sim.targets import PAPER_AREA, AreaCm
from edge.sim.world import WorldState
from edge.tracker_config import RoverConfig

CAMERA_COUNTS = (1, 2, 3, 4)  # 1: the paper's lab; 2-4: the wide arena's layouts
SEES_MARGIN_PX = 20.0  # a marker's centre this far inside the picture: the marker is whole in it


@dataclass(frozen=True)
class LabView:
    """One camera of the lab: ``name`` (cam1...), its model (exact, in the shared floor frame), the floor region it
    is installed to watch, the rovers' colours as it sees them, and its renderer."""

    name: str
    camera: PinholeCamera
    region_cm: AreaCm
    rover_configs: tuple[RoverConfig, ...]
    renderer: Renderer

    def render(self, state: WorldState, frame: int) -> NDArray[np.uint8]:
        return self.renderer.render(state, frame)

    def sees(self, x_cm: float, y_cm: float) -> bool:
        """Whether a marker centred at (x, y) is in this camera's picture (its far rows reach beyond its region)."""
        u, v = self.camera.project(np.array([[x_cm, y_cm, MARKER_HEIGHT_CM]]))[0]
        m = SEES_MARGIN_PX
        return bool(m <= u <= self.camera.width_px - m and m <= v <= self.camera.height_px - m)


@dataclass(frozen=True)
class LabFloor:
    """The working area the rovers are scattered over (x0, y0, x1, y1, cm) and the cameras above it."""

    area_cm: AreaCm
    views: tuple[LabView, ...]

    def view(self, name: str | None) -> LabView:
        """The camera called ``name``; the first one when ``name`` is None (a client that names none)."""
        if name is None:
            return self.views[0]
        for view in self.views:
            if view.name == name:
                return view
        raise ConfigError(f"no camera {name!r} in the lab (cameras: {', '.join(v.name for v in self.views)})")


def lab_floor(cameras: int, looks: tuple[RoverLook, ...], seed: int, fps: float) -> LabFloor:
    """The floor and its ``cameras`` (see the module docstring)."""
    from edge.sim.camera_path import marker_colors

    if cameras not in CAMERA_COUNTS:
        raise ConfigError(f"--cameras must be one of {', '.join(map(str, CAMERA_COUNTS))}, got {cameras}")
    if cameras == 1:
        from edge.camera import paper_camera
        from edge.sim.scenarios import lab_effects
        from edge.sim.scene import Scene

        camera = paper_camera()
        scene = Scene(looks)
        effects = lab_effects(np.random.default_rng(seed))
        colors = marker_colors(camera, scene, effects, seed, fps)
        renderer = Renderer(camera, scene, effects, seed=seed, fps=fps)
        return LabFloor(PAPER_AREA, (LabView("cam1", camera, PAPER_AREA, _configs(looks, colors), renderer),))
    from edge.sim.wide import ARENA_LENGTH_CM, ARENA_WIDTH_CM, wide_cameras, wide_scene

    arena: AreaCm = (0.0, 0.0, ARENA_WIDTH_CM, ARENA_LENGTH_CM)
    scene = wide_scene(looks, arena)
    views = []
    for k, cam in enumerate(
        wide_cameras(cameras, np.random.default_rng(np.random.SeedSequence([seed, 0x31DE])), arena)
    ):
        x0, y0, x1, y1 = cam.region_cm
        board_seed = seed * 16 + k
        colors = marker_colors(cam.camera, scene, cam.effects, board_seed, fps, at_cm=((x0 + x1) / 2, (y0 + y1) / 2))
        renderer = Renderer(cam.camera, scene, cam.effects, seed=board_seed, fps=fps)
        views.append(LabView(cam.name, cam.camera, cam.region_cm, _configs(looks, colors), renderer))
    return LabFloor(arena, tuple(views))


def _configs(
    looks: tuple[RoverLook, ...], colors: dict[str, tuple[tuple[int, int, int], tuple[int, int, int] | None]]
) -> tuple[RoverConfig, ...]:
    """The tracker's rovers: each id with its marker's colour (and front colour) as one camera sees them."""
    fractions = {look.rover_id: look.front_fraction for look in looks}
    return tuple(
        RoverConfig(id=rid, color_bgr=main, front_color_bgr=front, front_fraction=fractions[rid])
        for rid, (main, front) in colors.items()
    )
