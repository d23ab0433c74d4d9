"""What the lab looks like: floor tiles and grout, tape, ceiling lamps and their reflections, rovers and markers.

Everything here is a description (frozen dataclasses of plain values) plus pure functions that evaluate it at world
points. Colours are diffuse reflectances (albedo, 0..1, B, G, R order), not pixel values: the renderer multiplies
them by the illumination, the exposure and the camera's tone curve. Lengths in cm, world frame as in
:mod:`edge.camera`.

The working area of the paper's Fig. 1 (391.5 x 549.5 cm) is outlined with masking tape just outside its edge. The
floor is a glossy vinyl/terrazzo-like tiling, lit by fluorescent troffers on a 300 cm ceiling; its gloss reflects
the lamps, most visibly towards the far side where the camera looks at the floor at a grazing angle (Fresnel).
"""

from __future__ import annotations

import colorsys
import math
from dataclasses import dataclass, field
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from edge.camera import AREA_LENGTH_CM, AREA_WIDTH_CM, MARKER_HEIGHT_CM
from edge.errors import SimulationError
from edge.messages import repeated_ids

FloatArray = NDArray[np.float64]
Bgr = tuple[float, float, float]
Heading = Literal["plain", "two_tone", "aruco"]
HEADINGS: tuple[Heading, ...] = ("plain", "two_tone", "aruco")

# Printed-paper marker colours (diffuse reflectance, B, G, R): saturated but not pure primaries, as paper and ink
# are (a red sheet still reflects ~8% of green and blue).
RED_BGR: Bgr = (0.07, 0.08, 0.62)
GREEN_BGR: Bgr = (0.14, 0.38, 0.10)
BLUE_BGR: Bgr = (0.55, 0.17, 0.06)
HUE_NAMES = (
    (0.0, "red"),
    (30.0, "orange"),
    (55.0, "yellow"),
    (90.0, "lime"),
    (130.0, "green"),
    (165.0, "teal"),
    (185.0, "cyan"),
    (210.0, "azure"),
    (235.0, "blue"),
    (270.0, "violet"),
    (300.0, "magenta"),
    (330.0, "pink"),
)


@dataclass(frozen=True)
class RoverLook:
    """A rover's body and marker.

    The body is a dark box (the paper's black cover) ``body_length_cm`` along the heading, ``body_width_cm`` across,
    ``body_height_cm`` tall; the flat marker lies on its top, centred, ``marker_length_cm`` x ``marker_width_cm``
    (21.5 x 16.8 = 361 cm^2, the paper's Table II: 355-366 cm^2). ``heading``: ``plain`` (one colour), ``two_tone``
    (the front ``front_fraction`` of the marker in ``secondary_bgr``) or ``aruco`` (a black-and-white ArUco
    DICT_4X4_50 tag of side ``aruco_side_cm`` centred on the marker, its top edge towards the front).
    """

    rover_id: str
    marker_bgr: Bgr
    heading: Heading = "plain"
    secondary_bgr: Bgr = (0.80, 0.82, 0.82)
    front_fraction: float = 0.3
    aruco_id: int = 0
    aruco_side_cm: float = 12.0
    marker_length_cm: float = 21.5
    marker_width_cm: float = 16.8
    body_length_cm: float = 25.0
    body_width_cm: float = 20.0
    body_height_cm: float = MARKER_HEIGHT_CM
    body_bgr: Bgr = (0.035, 0.034, 0.032)

    def __post_init__(self) -> None:
        if self.heading not in HEADINGS:
            raise SimulationError(f"rover {self.rover_id!r}: heading marker must be one of {', '.join(HEADINGS)}")
        if self.marker_length_cm > self.body_length_cm or self.marker_width_cm > self.body_width_cm:
            raise SimulationError(f"rover {self.rover_id!r}: the marker must fit on the body's top")
        if not 0.0 < self.front_fraction < 1.0:
            raise SimulationError(f"rover {self.rover_id!r}: front_fraction must be between 0 and 1")


@dataclass(frozen=True)
class FloorLook:
    """Square tiles with grout lines, per-tile tone variation, speckle and a glossy finish."""

    tile_cm: float = 40.0
    tile_origin_cm: tuple[float, float] = (-13.0, -7.0)
    base_bgr: Bgr = (0.44, 0.47, 0.50)
    tile_variation: float = 0.05
    speckle: float = 0.10
    grout_cm: float = 0.6
    grout_bgr: Bgr = (0.20, 0.21, 0.22)
    specular: float = 0.035
    roughness_deg: float = 3.0


# Floors of other materials (``Scenario.build``'s ``floor``): a lab's floor is rarely the default grey tiles, and
# its colour is what every marker edge mixes with on the floor side, what the background and the local light are
# read from, and, warm and lit by the sun, what comes nearest a marker's hue.
FLOORS: dict[str, FloorLook] = {
    "tiles": FloorLook(),
    "beige": FloorLook(base_bgr=(0.42, 0.50, 0.58), tile_cm=30.0, grout_bgr=(0.30, 0.34, 0.38)),
    "wood": FloorLook(
        tile_cm=15.0,  # parquet: squares of 15 cm
        base_bgr=(0.16, 0.27, 0.42),
        tile_variation=0.12,
        speckle=0.15,
        grout_cm=0.2,
        grout_bgr=(0.08, 0.13, 0.20),
        specular=0.05,
    ),
    "white": FloorLook(base_bgr=(0.70, 0.72, 0.74), grout_bgr=(0.45, 0.46, 0.47)),
    "dark": FloorLook(base_bgr=(0.10, 0.10, 0.11), tile_variation=0.03, grout_bgr=(0.06, 0.06, 0.06)),
}


@dataclass(frozen=True)
class TapeLook:
    """Masking tape laid just outside the working area's edge (the paper's Fig. 1 outline)."""

    width_cm: float = 4.8
    bgr: Bgr = (0.50, 0.62, 0.68)
    area_cm: tuple[float, float] = (AREA_WIDTH_CM, AREA_LENGTH_CM)


@dataclass(frozen=True)
class Lamp:
    """A ceiling troffer: ``length_cm`` along y, ``width_cm`` along x, centred at ``(x, y)``, ``height_cm`` up."""

    x_cm: float
    y_cm: float
    height_cm: float = 300.0
    length_cm: float = 120.0
    width_cm: float = 30.0
    power: float = 1.0


def default_lamps() -> tuple[Lamp, ...]:
    return tuple(Lamp(x, y) for x in (60.0, 330.0) for y in (40.0, 280.0, 520.0, 760.0))


@dataclass(frozen=True)
class Scene:
    """The static lab plus the rovers' looks. ``ambient`` is the share of diffuse light from walls and ceiling."""

    rovers: tuple[RoverLook, ...]
    floor: FloorLook = FloorLook()
    tape: TapeLook | None = TapeLook()
    lamps: tuple[Lamp, ...] = field(default_factory=default_lamps)
    ambient: float = 0.35
    lamp_luminance: float = 22.0
    texture_seed: int = 7

    def __post_init__(self) -> None:
        twice = repeated_ids([r.rover_id for r in self.rovers])
        if twice:
            raise SimulationError(f"scene: rover {', '.join(twice)} named more than once")

    def look(self, rover_id: str) -> RoverLook:
        for r in self.rovers:
            if r.rover_id == rover_id:
                return r
        raise SimulationError(f"scene: no rover {rover_id!r}")


# -- fleets ----------------------------------------------------------------------------------------------------
def marker_albedo_for_hue(hue_deg: float, saturation: float = 0.86, value: float = 0.62) -> Bgr:
    """A printed marker of the given hue: HSV to reflectance, never a pure primary (saturation < 1)."""
    r, g, b = colorsys.hsv_to_rgb((hue_deg % 360.0) / 360.0, saturation, value)
    # Equalise perceived brightness a little: pure blue/violet paper is darker than yellow paper.
    return (round(b, 4), round(g, 4), round(r, 4))


# The eight-hue palette (hue in degrees of HSV): eight printable colours a camera tells apart.
EIGHT_HUES = (
    ("red", 0.0),
    ("orange", 28.0),
    ("yellow", 55.0),
    ("green", 125.0),
    ("cyan", 185.0),
    ("blue", 230.0),
    ("purple", 270.0),
    ("magenta", 315.0),
)


def fleet_looks(n_rovers: int, heading: Heading = "plain") -> tuple[RoverLook, ...]:
    """Looks for ``n_rovers`` rovers with distinct hues.

    Up to three rovers: the paper's red, green and blue (ids ``red``, ``green``, ``blue``). Eight: the eight-hue
    palette (:data:`EIGHT_HUES`). Otherwise hues spread evenly round the colour wheel, named after the nearest of
    twelve hue names when they are distinct (up to twelve rovers), else ``hue000``... by hue in degrees.
    """
    if n_rovers < 1 or n_rovers > 64:
        raise SimulationError(f"a fleet has 1 to 64 rovers, got {n_rovers}")
    if n_rovers <= 3:
        base = (("red", RED_BGR), ("green", GREEN_BGR), ("blue", BLUE_BGR))[:n_rovers]
        return tuple(RoverLook(i, c, heading=heading, aruco_id=k) for k, (i, c) in enumerate(base))
    if n_rovers == len(EIGHT_HUES):
        return tuple(
            RoverLook(name, marker_albedo_for_hue(h), heading=heading, aruco_id=k)
            for k, (name, h) in enumerate(EIGHT_HUES)
        )
    hues = [k * 360.0 / n_rovers for k in range(n_rovers)]
    names = [_nearest_hue_name(h) for h in hues]
    if len(set(names)) != len(names):
        names = [f"hue{round(h):03d}" for h in hues]
    return tuple(
        RoverLook(name, marker_albedo_for_hue(h), heading=heading, aruco_id=k)
        for k, (name, h) in enumerate(zip(names, hues, strict=True))
    )


def _nearest_hue_name(hue_deg: float) -> str:
    return min(HUE_NAMES, key=lambda named: _hue_distance(named[0], hue_deg))[1]


def _hue_distance(a: float, b: float) -> float:
    d = abs(a - b) % 360.0
    return min(d, 360.0 - d)


# -- rover geometry ---------------------------------------------------------------------------------------------
def rectangle_cm(x_cm: float, y_cm: float, theta_rad: float, length_cm: float, width_cm: float) -> FloatArray:
    """(4, 2) corners of a rectangle centred at (x, y), ``length`` along the heading; counter-clockwise."""
    c, s = math.cos(theta_rad), math.sin(theta_rad)
    lc, ls = 0.5 * length_cm * c, 0.5 * length_cm * s
    wc, ws = 0.5 * width_cm * c, 0.5 * width_cm * s
    return np.array(
        [
            [x_cm + lc + ws, y_cm + ls - wc],
            [x_cm + lc - ws, y_cm + ls + wc],
            [x_cm - lc - ws, y_cm - ls + wc],
            [x_cm - lc + ws, y_cm - ls - wc],
        ]
    )


def aruco_cells(look: RoverLook) -> FloatArray:
    """(K, 4, 2) marker-local corners (cm, x forward, y left) of the black cells of the rover's ArUco tag."""
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    bits = cv2.aruco.generateImageMarker(dictionary, look.aruco_id, 6)  # 6x6 cells: 4x4 data + black border
    cell = look.aruco_side_cm / 6.0
    half = 0.5 * look.aruco_side_cm
    cells = []
    for row in range(6):
        for col in range(6):
            if bits[row, col] >= 128:
                continue
            # image row 0 is the tag's top, towards the rover's front (+x); column 0 is its left (+y)
            x0, x1 = half - row * cell, half - (row + 1) * cell
            y0, y1 = half - col * cell, half - (col + 1) * cell
            cells.append([[x0, y0], [x0, y1], [x1, y1], [x1, y0]])
    return np.asarray(cells, dtype=np.float64).reshape(-1, 4, 2)


# -- floor and lighting (pure functions of world points) -------------------------------------------------------
def room_irradiance(xy_cm: FloatArray, lamps: tuple[Lamp, ...], ambient: float) -> FloatArray:
    """(N,) irradiance on the floor from the lamps (Lambertian emitters, cos^2 / d^2) plus an ambient share.

    Normalised so that the mean over the working area is 1.
    """
    raw = _lamp_sum(xy_cm, lamps)
    gx, gy = np.meshgrid(np.linspace(0, AREA_WIDTH_CM, 24), np.linspace(0, AREA_LENGTH_CM, 32))
    mean = float(np.mean(_lamp_sum(np.column_stack([gx.ravel(), gy.ravel()]), lamps))) if lamps else 1.0
    direct = raw / mean if lamps else np.zeros(len(xy_cm))
    return np.asarray(ambient + (1.0 - ambient) * direct)


def _lamp_sum(xy_cm: FloatArray, lamps: tuple[Lamp, ...]) -> FloatArray:
    total = np.zeros(len(xy_cm))
    for lamp in lamps:
        for f in np.linspace(-0.4, 0.4, 5):  # a strip lamp as five point sources along its length
            dx = xy_cm[:, 0] - lamp.x_cm
            dy = xy_cm[:, 1] - (lamp.y_cm + f * lamp.length_cm)
            d2 = dx * dx + dy * dy + lamp.height_cm**2
            total += lamp.power * lamp.height_cm**2 / (d2 * d2)
    return total


def lamp_reflection(
    xy_cm: FloatArray, camera_cm: FloatArray, lamps: tuple[Lamp, ...], floor: FloorLook, luminance: float
) -> FloatArray:
    """(N,) specular reflection of the ceiling lamps in the glossy floor, as seen from ``camera_cm``.

    The mirror ray from the camera through a floor point rises to the ceiling at ``F + (F - C)_xy * h / C_z``; where
    it meets a lamp the floor shows the lamp, blurred by the finish's roughness and weighted by Schlick's Fresnel
    term (strong at the grazing angles of the far side).
    """
    out = np.zeros(len(xy_cm))
    if not lamps or floor.specular <= 0:
        return out
    cx, cy, cz = (float(v) for v in camera_cm)
    dx, dy = xy_cm[:, 0] - cx, xy_cm[:, 1] - cy
    horiz = np.hypot(dx, dy)
    cos_inc = cz / np.sqrt(horiz**2 + cz**2)
    fresnel = floor.specular + (1.0 - floor.specular) * (1.0 - cos_inc) ** 5
    spread = math.tan(math.radians(floor.roughness_deg))
    for lamp in lamps:
        k = lamp.height_cm / cz
        qx, qy = xy_cm[:, 0] + dx * k, xy_cm[:, 1] + dy * k
        path = np.sqrt((horiz * k) ** 2 + lamp.height_cm**2)
        blur = np.maximum(path * spread, 1.0)
        inside_x = _soft_box(qx - lamp.x_cm, 0.5 * lamp.width_cm, blur)
        inside_y = _soft_box(qy - lamp.y_cm, 0.5 * lamp.length_cm, blur)
        # Roughness spreads the lamp's flux over the blur footprint: the peak falls as the blur grows.
        area = lamp.width_cm * lamp.length_cm
        spread_area = (lamp.width_cm + 2 * blur) * (lamp.length_cm + 2 * blur)
        out += luminance * lamp.power * inside_x * inside_y * area / spread_area
    return np.asarray(out * fresnel)


def _soft_box(offset: FloatArray, half: float, blur: FloatArray) -> FloatArray:
    """Smooth indicator of |offset| < half with edge width ``blur`` (logistic edges)."""
    return np.asarray(1.0 / (1.0 + np.exp((np.abs(offset) - half) / (0.5 * blur))))


class FloorTexture:
    """Albedo of the floor at world points (tiles, grout, speckle, tape), anti-aliased over a sample footprint."""

    def __init__(self, floor: FloorLook, tape: TapeLook | None, seed: int) -> None:
        self.floor = floor
        self.tape = tape
        rng = np.random.default_rng(np.random.SeedSequence([seed, 0xF1008]))
        tone = 1.0 + floor.tile_variation * rng.standard_normal((64 * 64, 1))
        tint = 1.0 + 0.25 * floor.tile_variation * rng.standard_normal((64 * 64, 3))
        self._tiles = (np.asarray(floor.base_bgr)[None, :] * tone * tint).astype(np.float32)
        white = rng.standard_normal((512, 512)).astype(np.float32)
        speck = _wrap_blur(white, 0.8)
        spot_signs = (rng.random((512, 512)) < 0.01) * rng.choice([-2.5, 2.5], (512, 512))
        spots = _wrap_blur(spot_signs.astype(np.float32), 1.0) * 6.0
        field_ = speck + spots
        self._speckle = (field_ / float(np.std(field_))).astype(np.float32).ravel()
        self._speckle_texel_cm = 0.5

    def albedo(self, xy_cm: FloatArray, footprint_cm: FloatArray) -> NDArray[np.float32]:
        """(N, 3) BGR albedo at (N, 2) world points; ``footprint_cm`` (N,) is the sample spacing for anti-aliasing."""
        f = self.floor
        x = (xy_cm[:, 0] - f.tile_origin_cm[0]).astype(np.float32)
        y = (xy_cm[:, 1] - f.tile_origin_cm[1]).astype(np.float32)
        fp = footprint_cm.astype(np.float32)
        ti = np.floor(x / f.tile_cm).astype(np.int64) % 64
        tj = np.floor(y / f.tile_cm).astype(np.int64) % 64
        base = np.take(self._tiles, ti * 64 + tj, axis=0)
        # Speckle from a periodic noise tile (nearest texel), offset per tile so the repeat is not visible; fine
        # speckle averages out over a large footprint (far side), as it would on a real sensor.
        u = (np.floor(x / self._speckle_texel_cm).astype(np.int64) + ti * 97) % 512
        v = (np.floor(y / self._speckle_texel_cm).astype(np.int64) + tj * 53) % 512
        speck = np.take(self._speckle, v * 512 + u)
        speck_gain = f.speckle / np.maximum(1.0, fp / self._speckle_texel_cm)
        base *= (1.0 + speck_gain * speck)[:, None]
        half = np.float32(0.5 * f.tile_cm)
        dx = np.abs((x + half) % f.tile_cm - half)
        dy = np.abs((y + half) % f.tile_cm - half)
        grout = np.maximum(_band(dx, f.grout_cm, fp), _band(dy, f.grout_cm, fp))
        base += (np.asarray(f.grout_bgr, dtype=np.float32)[None, :] - base) * grout[:, None]
        if self.tape is not None:
            tape = _tape_cover(self.tape, xy_cm, footprint_cm).astype(np.float32)
            base += (np.asarray(self.tape.bgr, dtype=np.float32)[None, :] - base) * tape[:, None]
        return base


def _tape_cover(tape: TapeLook, xy_cm: FloatArray, footprint_cm: FloatArray) -> FloatArray:
    """Fraction of each sample covered by the tape frame around the working area."""
    w = tape.width_cm
    ax, ay = tape.area_cm
    x, y = xy_cm[:, 0], xy_cm[:, 1]
    outer = _span(x, -w, ax + w, footprint_cm) * _span(y, -w, ay + w, footprint_cm)
    inner = _span(x, 0.0, ax, footprint_cm) * _span(y, 0.0, ay, footprint_cm)
    return np.asarray(np.clip(outer - inner, 0.0, 1.0))


def _wrap_blur(tile: NDArray[np.float32], sigma: float) -> NDArray[np.float32]:
    """Gaussian blur of a periodic tile (OpenCV's filters do not wrap)."""
    pad = int(4 * sigma) + 1
    padded = np.pad(tile, pad, mode="wrap")
    return np.asarray(cv2.GaussianBlur(padded, (0, 0), sigma)[pad:-pad, pad:-pad], dtype=np.float32)


def _band(distance: NDArray[np.floating], width: float, footprint: NDArray[np.floating]) -> NDArray[np.floating]:
    """Coverage of a box sample of size ``footprint`` by a line of ``width`` whose centre is ``distance`` away."""
    overlap = np.minimum(distance + 0.5 * width, 0.5 * footprint) - np.maximum(distance - 0.5 * width, -0.5 * footprint)
    return np.asarray(np.clip(overlap / footprint, 0.0, 1.0))


def _span(v: FloatArray, lo: float, hi: float, footprint: FloatArray) -> FloatArray:
    """Coverage of the interval [lo, hi] by a box sample of size ``footprint`` centred at ``v``."""
    left = np.clip((v - lo) / footprint + 0.5, 0.0, 1.0)
    right = np.clip((hi - v) / footprint + 0.5, 0.0, 1.0)
    return np.asarray(left + right - 1.0).clip(0.0, 1.0)
