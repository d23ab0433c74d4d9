"""Helpers for the simulator's tests: a black test scene and geometry checks on scenario runs."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from edge.sim.effects import Effects, Exposure, Optics
from edge.sim.metrics import box_gap_cm
from edge.sim.scenarios import SimSetup
from edge.sim.scene import FloorLook, RoverLook, Scene, rectangle_cm

BLACK = (0.0, 0.0, 0.0)


def black_scene(looks: tuple[RoverLook, ...]) -> Scene:
    """A scene in which only the markers reflect light: black floor, no tape, black rover bodies, even light."""
    floor = FloorLook(base_bgr=BLACK, grout_bgr=BLACK, speckle=0.0, tile_variation=0.0, specular=0.0)
    bodies = tuple(
        RoverLook(
            look.rover_id,
            look.marker_bgr,
            heading=look.heading,
            secondary_bgr=look.secondary_bgr,
            body_bgr=BLACK,
        )
        for look in looks
    )
    return Scene(bodies, floor=floor, tape=None, lamps=(), ambient=1.0)


def clean_effects(gamma: float = 2.2, psf_sigma_px: float | None = None) -> Effects:
    """Only the camera's tone curve (and, if given, the lens's point spread): no noise, vignetting, auto-exposure,
    motion blur, flicker or compression."""
    return Effects(
        exposure=Exposure(gamma=gamma),
        auto_exposure=None,
        noise=None,
        vignetting=None,
        optics=None if psf_sigma_px is None else Optics(psf_sigma_px),
        motion_blur=False,
    )


def linear(image: NDArray[np.uint8], gamma: float = 2.2) -> NDArray[np.float64]:
    """Undo the renderer's tone curve."""
    return np.asarray((image.astype(np.float64) / 255.0) ** gamma)


def min_body_gap_cm(setup: SimSetup, step_s: float = 0.05) -> float:
    """Smallest distance between any two rover bodies, or a rover and a prop (a box standing in the area), over the
    scenario's run (negative if they ever overlap)."""
    world = setup.world()
    looks = {look.rover_id: look for look in setup.scene.rovers}
    props = [rectangle_cm(p.x_cm, p.y_cm, p.heading_rad, p.size_cm[0], p.size_cm[1]) for p in setup.effects.props]
    best = np.inf
    for t in np.arange(0.0, setup.frames / setup.fps + 1e-9, step_s):
        rovers = world.state_at(float(t)).rovers
        xy = np.array([[r.x_cm, r.y_cm] for r in rovers])
        for r in rovers:
            look = looks[r.rover_id]
            body = rectangle_cm(r.x_cm, r.y_cm, r.theta_rad, look.body_length_cm, look.body_width_cm)
            for prop in props:
                best = min(best, box_gap_cm(body, prop))
        for i in range(len(rovers)):
            near = np.nonzero(np.hypot(*(xy[i + 1 :] - xy[i]).T) < 40.0)[0] + i + 1
            for j in near:
                a, b = rovers[i], rovers[int(j)]
                la, lb = looks[a.rover_id], looks[b.rover_id]
                pa = rectangle_cm(a.x_cm, a.y_cm, a.theta_rad, la.body_length_cm, la.body_width_cm)
                pb = rectangle_cm(b.x_cm, b.y_cm, b.theta_rad, lb.body_length_cm, lb.body_width_cm)
                best = min(best, box_gap_cm(pa, pb))
    return float(best)
