"""Render the pictures of docs/simulator.md into docs/img/ (seed 0): one frame per scenario and a few close-ups.

.venv/bin/python docs/make_simulator_images.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from edge.sim.scenarios import build  # noqa: E402
from edge.sim.world import RoverState, WorldState  # noqa: E402

OUT = ROOT / "docs" / "img"
# A frame that shows what each scenario is about (seed 0).
FRAMES = {
    "lab": 150,
    "drift": 140,
    "sun": 200,
    "cross": 152,
    "occlusion": 230,
    "lens": 300,
    "crowd": 120,
    "daylight": 250,
}


def save(name: str, image: np.ndarray, width: int = 512) -> None:
    h, w = image.shape[:2]
    small = cv2.resize(image, (width, round(h * width / w)), interpolation=cv2.INTER_AREA) if w > width else image
    cv2.imwrite(str(OUT / name), small, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    print(f"wrote docs/img/{name} ({(OUT / name).stat().st_size // 1024} KB)")


def zoom(image: np.ndarray, centre: np.ndarray, half: tuple[int, int], factor: int) -> np.ndarray:
    u, v = (round(float(c)) for c in centre)
    crop = image[v - half[1] : v + half[1], u - half[0] : u + half[0]]
    return cv2.resize(crop, None, fx=factor, fy=factor, interpolation=cv2.INTER_NEAREST)


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    for name, frame in FRAMES.items():
        setup = build(name, seed=0)
        renderer = setup.renderer()
        image = renderer.render(setup.world().state_at(frame / setup.fps), frame)
        save(f"sim_{name}.png", image)

    # Close-ups at full resolution, magnified: the far side, motion blur, the glare, the flicker bands.
    setup = build("lab", seed=0)
    renderer = setup.renderer()
    far = RoverState("green", 195.75, 540.0, 1.2, 0.0, 0.0)
    moving = RoverState("red", 120.0, 40.0, 0.0, 30.0, 0.0)
    image = renderer.render(WorldState(0.0, (far, moving)), 5)
    cam = setup.camera
    save("sim_far_marker_x8.png", zoom(image, cam.project(np.array([[195.75, 540.0, 13.0]]))[0], (20, 12), 8), 320)
    save("sim_motion_blur_x4.png", zoom(image, cam.project(np.array([[120.0, 40.0, 13.0]]))[0], (40, 28), 4), 320)
    sun = build("sun", seed=0)
    glare = sun.effects.glare
    assert glare is not None
    sun_image = sun.renderer().background(0)
    save(
        "sim_glare_x2.png",
        zoom(sun_image, sun.camera.project(np.array([[glare.x_cm, glare.y_cm, 0.0]]))[0], (120, 60), 2),
        480,
    )
    drift = build("drift", seed=0)
    save("sim_background_drift.png", drift.renderer().background(140))


if __name__ == "__main__":
    main()
