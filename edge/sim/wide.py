"""The wide arena: one shared world (8 x 5.5 m by default) seen by two to four cameras whose views overlap.

Each camera is a board of its own: its own pose, exposure (a slightly different gain and flicker phase), its own
exposure instant (frame ``i`` of camera ``k`` is exposed at ``i / fps + phase_k``, a few ms apart, as free-running
webcams are) and, for the live twin, its own clock error. All render the same :class:`edge.sim.world.World`
through the same renderer as every other scenario (:class:`edge.sim.render.Renderer`), so the truth is one truth.

Layouts: 2 cameras side by side (2 x 1), 3 (3 x 1) or 4 (2 x 2). Camera ``(c, r)`` is installed to watch its cell
of the arena grown by half the overlap on every inner side (``region_cm``), from above the arena's near edge
(first row) or far edge (second row), tilted like the paper's camera, with the lens's field of view chosen so the
region fills the image. Cells are numbered row by row: ``cam1`` is the near-left one; its clock is the reference
(phase 0), the others' exposures are a few milliseconds off it.

The rovers circle in cells of a grid over the whole arena (:func:`edge.sim.trajectories.grid_circles`), with one
hue each (the simulator's palette spreads up to 64 hues round the colour wheel); circles that straddle a seam take
their rovers from one view into the next and back every lap.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from edge.camera import MARKER_HEIGHT_CM, PinholeCamera
from edge.errors import SimulationError
from edge.sim.effects import AutoExposure, Effects, Exposure, Flicker
from edge.sim.render import Renderer
from edge.sim.scene import Lamp, RoverLook, Scene, TapeLook, fleet_looks
from edge.sim.trajectories import grid_circles
from edge.sim.world import DriveModel, Plan, World
from edge.tracker_config import RoverConfig

ARENA_WIDTH_CM = 800.0
ARENA_LENGTH_CM = 550.0
LAYOUTS = {2: (2, 1), 3: (3, 1), 4: (2, 2)}  # cameras -> (columns, rows)
OVERLAP_CM = 100.0  # the strip two neighbouring cameras both watch
MARKER_MARGIN_CM = 16.0  # a marker anywhere in a region is whole in its camera's image
CAMERA_HEIGHT_CM = 280.0
SETBACK_CM = 260.0  # behind the arena's edge, on the wall: a C920-like 70 deg lens then fits every layout
IMAGE_MARGIN_PX = 12.0
MAX_PHASE_S = 0.012  # exposure instants of the other cameras, within +-12 ms of cam1's
MAX_CLOCK_ERROR_S = 0.008  # the live twin's boards' clocks, within +-8 ms of true time
FPS = 30.0
DEFAULT_ROVERS = 12
DEFAULT_FRAMES = 450


@dataclass(frozen=True)
class WideCamera:
    """One board's camera: ``name`` (cam1...), pose and lens, the floor region it is installed to watch, its
    exposure ``phase_s`` relative to cam1, its clock error ``clock_offset_s`` (live twin), its effects."""

    name: str
    camera: PinholeCamera
    region_cm: tuple[float, float, float, float]
    phase_s: float
    clock_offset_s: float
    effects: Effects


@dataclass(frozen=True)
class WideSetup:
    """Everything one wide-arena run needs: the cameras, the scene, each rover's plan."""

    seed: int
    arena_cm: tuple[float, float, float, float]
    cameras: tuple[WideCamera, ...]
    scene: Scene
    plans: tuple[tuple[str, Plan], ...]
    frames: int
    fps: float = FPS
    drive: DriveModel = field(default_factory=DriveModel)

    @property
    def rover_ids(self) -> tuple[str, ...]:
        return tuple(look.rover_id for look in self.scene.rovers)

    def camera_named(self, name: str) -> WideCamera:
        for cam in self.cameras:
            if cam.name == name:
                return cam
        names = ", ".join(c.name for c in self.cameras)
        raise SimulationError(f"wide arena: no camera {name!r} (this layout has {names})")

    def world(self) -> World:
        return World(dict(self.plans), self.drive, seed=self.seed)

    def renderer(self, cam: WideCamera) -> Renderer:
        return Renderer(
            cam.camera, self.scene, cam.effects, seed=self.seed * 16 + self.cameras.index(cam), fps=self.fps
        )

    def rover_configs(self, renderer: Renderer) -> tuple[RoverConfig, ...]:
        """The tracker's view of the fleet from one camera: each id with its marker's colour as it sees it."""
        return tuple(
            RoverConfig(id=look.rover_id, color_bgr=renderer.nominal_marker_bgr(look.rover_id))
            for look in self.scene.rovers
        )


def regions(n_cameras: int, arena_cm: tuple[float, float, float, float]) -> list[tuple[float, float, float, float]]:
    """Each camera's region: its cell of the grid, grown by half the overlap on every inner side."""
    cols, rows = LAYOUTS[n_cameras]
    x0, y0, x1, y1 = arena_cm
    w, h = (x1 - x0) / cols, (y1 - y0) / rows
    half = OVERLAP_CM / 2.0
    out = []
    for r in range(rows):
        for c in range(cols):
            out.append(
                (
                    x0 + c * w - (half if c > 0 else 0.0),
                    y0 + r * h - (half if r > 0 else 0.0),
                    x0 + (c + 1) * w + (half if c < cols - 1 else 0.0),
                    y0 + (r + 1) * h + (half if r < rows - 1 else 0.0),
                )
            )
    return out


def fit_camera(position_cm: tuple[float, float, float], region_cm: tuple[float, float, float, float]) -> PinholeCamera:
    """A 1280x720 camera at ``position_cm`` aimed and zoomed so the region (grown by a marker's reach, at marker
    height) just fills the image."""
    x0, y0, x1, y1 = region_cm
    m = MARKER_MARGIN_CM
    xs = np.linspace(x0 - m, x1 + m, 9)
    ys = np.linspace(y0 - m, y1 + m, 9)
    edge = [(x, y) for x in xs for y in (ys[0], ys[-1])] + [(x, y) for x in (xs[0], xs[-1]) for y in ys]
    pts = np.array([[x, y, MARKER_HEIGHT_CM] for x, y in edge])
    centre = np.array([(x0 + x1) / 2.0, (y0 + y1) / 2.0])
    base = np.asarray(position_cm[:2], dtype=np.float64)
    forward = (centre - base) / np.linalg.norm(centre - base)

    def aimed(distance_cm: float, hfov_deg: float) -> PinholeCamera:
        target = base + forward * distance_cm
        return PinholeCamera.look_at(position_cm, (float(target[0]), float(target[1]), 0.0), hfov_deg=hfov_deg)

    def offset_px(cam: PinholeCamera) -> float:
        v = cam.project(pts)[:, 1]
        return 0.5 * (float(v.min()) + float(v.max())) - cam.camera_matrix[1, 2]

    hfov = 70.0
    for _ in range(4):
        # aim: the region's rows centred in the image (aiming farther moves the region down the image)
        near, far = 1.0, 4.0 * float(np.linalg.norm(centre - base))
        for _ in range(40):
            mid = 0.5 * (near + far)
            near, far = (mid, far) if offset_px(aimed(mid, hfov)) < 0 else (near, mid)
        cam = aimed(near, hfov)
        # zoom: the widest extent fills the image, less a margin
        uv = cam.project(pts)
        cx, cy = cam.camera_matrix[0, 2], cam.camera_matrix[1, 2]
        scale = max(
            float(np.max(np.abs(uv[:, 0] - cx))) / (cam.width_px / 2.0 - IMAGE_MARGIN_PX),
            float(np.max(np.abs(uv[:, 1] - cy))) / (cam.height_px / 2.0 - IMAGE_MARGIN_PX),
        )
        hfov = math.degrees(2.0 * math.atan((cam.width_px / 2.0) / (cam.camera_matrix[0, 0] / scale)))
    distance = near
    if hfov > 100.0:
        raise SimulationError(f"wide arena: a camera at {position_cm} needs a {hfov:.0f} deg lens for {region_cm}")
    return aimed(distance, hfov)


def wide_lamps(arena_cm: tuple[float, float, float, float]) -> tuple[Lamp, ...]:
    """Troffers every 270 cm across and 240 cm along the arena, as in the paper's lab."""
    x0, y0, x1, y1 = arena_cm
    xs = np.arange(x0 + 130.0, x1, 270.0)
    ys = np.arange(y0 + 40.0, y1 + 250.0, 240.0)
    return tuple(Lamp(float(x), float(y)) for x in xs for y in ys)


def build_wide(
    cameras: int = 4,
    seed: int = 0,
    rovers: int | None = None,
    frames: int | None = None,
    arena_cm: tuple[float, float, float, float] = (0.0, 0.0, ARENA_WIDTH_CM, ARENA_LENGTH_CM),
) -> WideSetup:
    """The wide arena seen by ``cameras`` boards (2, 3 or 4), ``rovers`` rovers circling (1 to 64)."""
    n = DEFAULT_ROVERS if rovers is None else rovers
    f = DEFAULT_FRAMES if frames is None else frames
    if not 1 <= n <= 64:
        raise SimulationError(f"wide arena: --rovers must be 1 to 64 (one hue each), got {n}")
    if f < 1:
        raise SimulationError(f"wide arena: --frames must be at least 1, got {f}")
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x31DE]))
    cams = wide_cameras(cameras, rng, arena_cm)
    looks = fleet_looks(n)
    scene = wide_scene(looks, arena_cm)
    plans = grid_circles(n, arena_cm, rng)
    return WideSetup(
        seed, arena_cm, cams, scene, tuple((look.rover_id, p) for look, p in zip(looks, plans, strict=True)), f
    )


def wide_cameras(
    cameras: int, rng: np.random.Generator, arena_cm: tuple[float, float, float, float]
) -> tuple[WideCamera, ...]:
    """The boards' cameras over ``arena_cm`` (layout, poses, exposures, phases, clock errors drawn from ``rng``)."""
    if cameras not in LAYOUTS:
        raise SimulationError(f"wide arena: --cameras must be one of {', '.join(map(str, LAYOUTS))}, got {cameras}")
    cols = LAYOUTS[cameras][0]
    cams = []
    for k, region in enumerate(regions(cameras, arena_cm)):
        row = k // cols
        x0, y0, x1, y1 = region
        y_cam = y0 - SETBACK_CM if row == 0 else y1 + SETBACK_CM
        camera = fit_camera(((x0 + x1) / 2.0, y_cam, CAMERA_HEIGHT_CM), region)
        effects = Effects(
            exposure=Exposure(exposure_s=1.0 / 60.0, scale=0.72 * float(rng.uniform(0.93, 1.07))),
            auto_exposure=AutoExposure(),
            flicker=Flicker(modulation=0.2, phase=float(rng.uniform(0, 2 * math.pi))),
        )
        phase = 0.0 if k == 0 else float(rng.uniform(-MAX_PHASE_S, MAX_PHASE_S))
        clock = float(rng.uniform(-MAX_CLOCK_ERROR_S, MAX_CLOCK_ERROR_S))
        cams.append(WideCamera(f"cam{k + 1}", camera, region, phase, clock, effects))
    return tuple(cams)


def wide_scene(looks: tuple[RoverLook, ...], arena_cm: tuple[float, float, float, float]) -> Scene:
    """The wide arena's floor: its tape outline and its troffers, with ``looks`` on it."""
    tape = TapeLook(area_cm=(arena_cm[2] - arena_cm[0], arena_cm[3] - arena_cm[1]))
    return Scene(looks, tape=tape, lamps=wide_lamps(arena_cm))
