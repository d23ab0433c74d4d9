"""Colour enrolment: the rovers' marker colours as this camera sees them under this light, from one frame with the
rovers in view and one of the empty floor.

Typing ``color_bgr`` "as the camera sees it" into a configuration is guesswork; the camera knows. :func:`enroll`
finds every marker-sized blob of colour that is not on the empty floor (``edge.marker_blobs``: colour judged against
the light where it stands, told from the rovers' bodies and the floor), and measures it:

* its **colour**: the per-channel median over the blob's interior (its edge pixels, mixed with the dark body and
  the floor, are eroded away; clipped pixels are left out), so a glare on part of the marker does not move it;
* its **size** on the marker plane (through the calibration), and where it stands;
* for a **two-tone** marker, its light front part: the pixels brighter than the empty floor and the coloured part,
  under half its saturation, that touch the coloured part without surrounding it; taken only where the coloured
  part has room for a front (short of the marker by a tenth of its area, its longest side at most 0.9 of the
  marker's length) and both together are at most 1.3 markers (a light body's side beside a one-colour marker is
  not a front). Their median colour is ``front_color_bgr``, and ``front_fraction`` is 1 minus the coloured share;
* how far its hue **spreads** over the marker (the 95th percentile of its pixels' hue deviation).

Rovers are named by hue when no ids are given. Two markers whose hues are closer than their spreads plus a margin
for the light changing across the room cannot be told apart reliably under this camera and light: that is said,
naming both; so is a marker that stands out too little from the empty floor in its colour plane (a floor near
its hue: ``edge.floor_contrast``). Arrays in, dataclasses out: the CLI (``edge-ips rovers enroll``) and the
dashboard call :func:`enroll` with a frame and a background and write :meth:`Enrolment.toml`.
"""

from __future__ import annotations

import colorsys
import math
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from itertools import permutations
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from edge.errors import EnrollmentError
from edge.floor_change import changed_from, planes
from edge.floor_contrast import floor_warnings
from edge.marker_blobs import Blob, components, left_behind, marker_blobs, relative_saturation, world_outline
from edge.messages import id_problem
from edge.tracker_config import RoverConfig
from edge.trackers.base import PlaneMapping

U8 = NDArray[np.uint8]
FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

MIN_FRONT_SHARE = 0.1  # a light part (and the coloured part's shortfall) under this share of the marker: no front
FRONT_SATURATION = 0.5  # ... and no more than this share of its marker's saturation (an awb tints white 0.2-0.3)
FRONT_ROOM = 0.9  # ... and the coloured part's longest side is at most this share of the marker's length
FRONT_UNION = 1.3  # ... a front and its coloured part together are the marker: a light part adding more is a body
LIGHT_MARGIN_DEG = 10.0  # how far a hue may move between places in a room (lamps, window light) beyond its spread
CLIPPED = 250  # a channel this bright is clipped (glare): its hue is not the marker's
HUE_NAMES = ((0.0, "red"), (30.0, "orange"), (60.0, "yellow"), (90.0, "lime"), (120.0, "green"), (150.0, "teal"),
             (180.0, "cyan"), (210.0, "azure"), (240.0, "blue"), (270.0, "purple"), (300.0, "magenta"),
             (330.0, "pink"))  # fmt: skip  # HSV hue (degrees) -> name, for rovers enrolled without ids


@dataclass(frozen=True)
class EnrolledMarker:
    """One marker as measured. ``hue_deg``: HSV hue of ``color_bgr``; ``spread_deg``: 95th percentile of its
    pixels' hue deviation (the tracker's opponent-colour hue); ``saturation``: the median of its interior's, relative
    to the light there (``edge.marker_blobs.relative_saturation``); ``xy_cm``: its centre on the marker plane;
    ``length_cm`` x ``width_cm``: its size; ``front_*``: the light front part of a two-tone marker, else None."""

    rover_id: str
    color_bgr: tuple[int, int, int]
    hue_deg: float
    saturation: float
    spread_deg: float
    xy_cm: tuple[float, float]
    uv_px: tuple[float, float]
    length_cm: float
    width_cm: float
    area_cm2: float
    pixels: int
    front_color_bgr: tuple[int, int, int] | None = None
    front_fraction: float | None = None

    def rover_config(self) -> RoverConfig:
        if self.front_color_bgr is None or self.front_fraction is None:
            return RoverConfig(id=self.rover_id, color_bgr=self.color_bgr)
        return RoverConfig(
            id=self.rover_id,
            color_bgr=self.color_bgr,
            front_color_bgr=self.front_color_bgr,
            front_fraction=self.front_fraction,
        )


@dataclass(frozen=True)
class Enrolment:
    """Every marker found (in id order as given, else by hue), what was ignored, and the warnings."""

    markers: tuple[EnrolledMarker, ...]
    warnings: tuple[str, ...]
    ignored: tuple[str, ...]
    image_size: tuple[int, int]

    def rover_configs(self) -> list[RoverConfig]:
        return [m.rover_config() for m in self.markers]

    def toml(self, source: str = "", by: str = "`edge-ips rovers enroll`") -> str:
        """``[[rovers]]`` tables that ``--config`` and ``edge-ips start`` read, with what was measured as comments."""
        w, h = self.image_size
        when = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
        lines = [
            f"# Enrolled by {by} {when}{f' from {source}' if source else ''} ({w}x{h}).",
            "# Each colour is the median of the marker's interior as this camera saw it under this light: enroll",
            "# again after changing the camera's white balance, exposure or the lamps.",
        ]
        for warning in self.warnings:
            lines.append(f"# WARNING: {warning}")
        for m in self.markers:
            lines += [
                "",
                "[[rovers]]",
                f'id = "{m.rover_id}"',
                f"color_bgr = [{', '.join(str(c) for c in m.color_bgr)}]"
                f"  # hue {m.hue_deg:.0f} deg (spread {m.spread_deg:.1f}), at ({m.xy_cm[0]:.0f}, {m.xy_cm[1]:.0f}) "
                f"cm, {m.length_cm:.1f} x {m.width_cm:.1f} cm",
            ]
            if m.front_color_bgr is not None:
                lines.append(f"front_color_bgr = [{', '.join(str(c) for c in m.front_color_bgr)}]  # light front part")
                lines.append(f"front_fraction = {m.front_fraction}")
        return "\n".join(lines) + "\n"


# -- measuring -------------------------------------------------------------------------------------------------------
def _hsv_hue_deg(color_bgr: Sequence[int]) -> float:
    b, g, r = (c / 255.0 for c in color_bgr)
    return colorsys.rgb_to_hsv(r, g, b)[0] * 360.0


def _hue_gap_deg(a: float, b: float) -> float:
    d = abs(a - b) % 360.0
    return min(d, 360.0 - d)


def _interior(mask: BoolArray) -> BoolArray:
    """The blob without its edge pixels (mixed with the body or the floor); the blob itself when that is all."""
    for iterations in (2, 1):
        inner = cv2.erode(mask.astype(np.uint8), np.ones((3, 3), np.uint8), iterations=iterations).astype(bool)
        if inner.sum() >= 12:
            return inner
    return mask


def _median_bgr(image: U8, mask: BoolArray) -> tuple[int, int, int]:
    pixels = image[mask].astype(np.int32)
    unclipped = pixels[pixels.max(axis=1) < CLIPPED]
    use = unclipped if len(unclipped) >= max(4, len(pixels) // 4) else pixels
    b, g, r = (round(float(v)) for v in np.median(use, axis=0))
    return b, g, r


def _spread_deg(c1: FloatArray, c2: FloatArray, mask: BoolArray, color_bgr: Sequence[int]) -> float:
    f = np.asarray(color_bgr, dtype=np.float64)
    centre = math.atan2((f[2] + f[1] - 2.0 * f[0]) / math.sqrt(6.0), (f[2] - f[1]) / math.sqrt(2.0))
    angles = np.arctan2(c2[mask], c1[mask])
    deviation = np.abs(np.angle(np.exp(1j * (angles - centre))))
    return float(np.degrees(np.percentile(deviation, 95))) if deviation.size else 0.0


def enroll(
    frame: U8,
    background: U8,
    calibration: PlaneMapping,
    *,
    ids: Sequence[str] | None = None,
    marker_length_cm: float = 21.5,
    marker_width_cm: float = 16.8,
) -> Enrolment:
    """Measure every rover marker in ``frame`` (H, W, 3 BGR) that is not in ``background`` (the empty floor, same
    size); ``calibration`` maps the frame's pixels onto the marker plane (load it for the frame's size).
    ``ids``: one per marker (hue names such as ``red`` are matched by hue, other ids given in order of x then y on
    the floor); None names them by hue. ``marker_*_cm``: the markers' size as the tracker is configured.

    Raises :class:`EnrollmentError` when the two images differ in size, when no marker is found, when the
    background has a marker in it, or when the markers and ``ids`` do not match up.
    """
    h, w = frame.shape[:2]
    if frame.ndim != 3 or background.shape != frame.shape:
        raise EnrollmentError(f"the frame is {w}x{h} but the background is {background.shape[1]}x{background.shape[0]}")
    f1, f2, flum = planes(frame)
    b1, b2, blum = planes(background)
    changed = changed_from((f1, f2, flum), (b1, b2, blum))
    nominal_cm2 = marker_length_cm * marker_width_cm
    left = left_behind((f1, f2, flum), (b1, b2, blum), background, changed, calibration, nominal_cm2)
    if left is not None:
        raise EnrollmentError(
            f"the background image has a marker in it at ({left[0]:.0f}, {left[1]:.0f}) cm that the frame does not: "
            "take the background with no rover in view"
        )
    saturation = relative_saturation((f1, f2, flum), blum)
    blobs, ignored = marker_blobs((f1, f2, flum), (b1, b2, blum), changed, saturation, calibration, nominal_cm2)
    if not blobs:
        hint = f" ({'; '.join(ignored)})" if ignored else ""
        raise EnrollmentError(f"no marker-sized blob of colour differs from the background{hint}")
    light = changed & (flum > blum + 10.0)
    size = (marker_length_cm, marker_width_cm)
    markers = [_measure(frame, (f1, f2, flum), blob, saturation, light, calibration, size) for blob in blobs]
    named = _name(markers, ids)
    short = {m.xy_cm for m, b in zip(markers, blobs, strict=True) if _front_missing(m, b, size)}
    warnings = _too_close(named) + _odd_sizes(named, marker_length_cm, marker_width_cm)
    warnings += [_FRONT_MISSING.format(m.rover_id, m.length_cm, marker_length_cm) for m in named if m.xy_cm in short]
    seen = [(m.rover_id, m.color_bgr, m.uv_px, math.sqrt(m.pixels)) for m in named]
    warnings += floor_warnings(background, seen, calibration)  # a floor near a marker's hue (edge.floor_contrast)
    return Enrolment(tuple(named), tuple(warnings), tuple(ignored), (w, h))


def _pixel_areas_cm2(calibration: PlaneMapping, box: tuple[int, int, int, int]) -> FloatArray:
    """(y1 - y0, x1 - x0) each pixel's area on the marker plane, cm2, from where its four corners land."""
    x0, y0, x1, y1 = box
    us, vs = np.meshgrid(np.arange(x0, x1 + 1) - 0.5, np.arange(y0, y1 + 1) - 0.5)
    corners = calibration.pixel_to_world(np.column_stack([us.ravel(), vs.ravel()])).reshape(y1 - y0 + 1, x1 - x0 + 1, 2)
    d1 = corners[1:, 1:] - corners[:-1, :-1]
    d2 = corners[:-1, 1:] - corners[1:, :-1]
    return np.asarray(0.5 * np.abs(d1[..., 0] * d2[..., 1] - d1[..., 1] * d2[..., 0]))


def _measure(
    frame: U8,
    frame_planes: tuple[FloatArray, FloatArray, FloatArray],
    blob: Blob,
    saturation: FloatArray,
    light: BoolArray,
    calibration: PlaneMapping,
    size_cm: tuple[float, float],
) -> EnrolledMarker:
    """Colour, spread, area, size and the light front part of one blob.

    The coloured area is a sum of coverage: a pixel's chroma along the marker's hue, as a share of the interior's,
    is the share of the pixel the marker covers (chroma is linear in coverage: the black body, the white front and
    the grey floor add none). Counting pixels instead would count every edge pixel in full.
    """
    c1, c2, lum = frame_planes
    h, w = lum.shape
    nominal_cm2 = size_cm[0] * size_cm[1]
    inner = _interior(blob.mask)
    color = _median_bgr(frame, inner)
    vs, us = np.nonzero(blob.mask)
    pad = 4
    box = (max(0, us.min() - pad), max(0, vs.min() - pad), min(w, us.max() + pad + 1), min(h, vs.max() + pad + 1))
    x0, y0, x1, y1 = box
    areas = _pixel_areas_cm2(calibration, box)
    ring = cv2.dilate(blob.mask[y0:y1, x0:x1].astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    direction = np.array([np.median(c1[inner]), np.median(c2[inner])])
    full = float(np.hypot(*direction))
    along = (c1[y0:y1, x0:x1] * direction[0] + c2[y0:y1, x0:x1] * direction[1]) / max(full, 1e-6) ** 2
    colored_cm2 = float(np.sum(np.clip(along, 0.0, 1.0)[ring] * areas[ring]))

    near = np.zeros_like(blob.mask)
    near[y0:y1, x0:x1] = ring
    front_mask = np.zeros_like(blob.mask)
    pale = saturation < FRONT_SATURATION * float(np.median(saturation[inner]))
    for part in components(light & pale & (lum > float(np.median(lum[inner])))):
        if (part & near).any() and not _surrounds(part, blob.mask):
            front_mask |= part
    front_cm2 = 0.0
    if front_mask.any():  # over the front's own box: a front pointing along a row or column sticks out of the blob's
        fvs, fus = np.nonzero(front_mask)
        fx0, fy0, fx1, fy1 = int(fus.min()), int(fvs.min()), int(fus.max()) + 1, int(fvs.max()) + 1
        front_areas = _pixel_areas_cm2(calibration, (fx0, fy0, fx1, fy1))
        front_cm2 = float(np.sum(front_areas[front_mask[fy0:fy1, fx0:fx1]]))
    front_color: tuple[int, int, int] | None = None
    front_fraction: float | None = None
    whole = blob.mask
    short = nominal_cm2 - colored_cm2  # a two-tone marker's coloured part is short of the marker by its front
    if (
        min(front_cm2, short) >= MIN_FRONT_SHARE * nominal_cm2
        and colored_cm2 + front_cm2 <= FRONT_UNION * nominal_cm2
        and _short_of_marker(blob.world, size_cm[0])
    ):
        front_color = _median_bgr(frame, _interior(front_mask))
        # the marker's size is the tracker's (it places the centre by it); its coloured share is measured
        front_fraction = round(min(0.6, max(0.05, 1.0 - colored_cm2 / nominal_cm2)), 2)
        whole = blob.mask | front_mask
        measured_cm2 = colored_cm2 + front_cm2
    else:
        measured_cm2 = colored_cm2
    outline = world_outline(whole, calibration)
    (cx, cy), (a, b), _ = cv2.minAreaRect((outline if outline is not None else blob.world).astype(np.float32))
    scale = math.sqrt(measured_cm2 / max(a * b, 1e-6))  # the outline's box, scaled to the measured area
    wvs, wus = np.nonzero(whole)
    return EnrolledMarker(
        rover_id="",
        color_bgr=color,
        hue_deg=round(_hsv_hue_deg(color), 1),
        saturation=round(float(np.median(saturation[inner])), 3),
        spread_deg=round(_spread_deg(c1, c2, inner, color), 1),
        xy_cm=(round(float(cx), 1), round(float(cy), 1)),
        uv_px=(round(float(wus.mean()), 1), round(float(wvs.mean()), 1)),
        length_cm=round(float(max(a, b)) * scale, 1),
        width_cm=round(float(min(a, b)) * scale, 1),
        area_cm2=round(measured_cm2, 1),
        pixels=int(whole.sum()),
        front_color_bgr=front_color,
        front_fraction=front_fraction,
    )


_FRONT_MISSING = (
    "{} is one colour over {:.1f} cm of the marker's {:g} cm length and no light front was found beside it: a "
    "two-tone marker whose front is as light as its body? enrolled as one colour (its centre that of the coloured "
    "part); give two-tone markers a dark body"
)


def _front_missing(marker: EnrolledMarker, blob: Blob, size_cm: tuple[float, float]) -> bool:
    """A marker enrolled without a front whose coloured part is short of the marker by room for one (in area and
    in length): on the family's cameras, a two-tone marker on a white or light grey body."""
    return (
        marker.front_color_bgr is None
        and marker.area_cm2 <= (1.0 - MIN_FRONT_SHARE) * size_cm[0] * size_cm[1]
        and _short_of_marker(blob.world, size_cm[0])
    )


def _short_of_marker(world: FloatArray, length_cm: float) -> bool:
    """Is a coloured part (its outline ``world`` on the marker plane) short of the marker's length by room for a
    front, its longest side at most :data:`FRONT_ROOM` of ``length_cm``? A two-tone marker's coloured part showed
    0.66-0.89 of it over the family (its width, 0.78 of the length, the longest side for a front of 0.3); a
    one-colour marker's 0.92-1.0, and a light body's side beside it was taken for a front (8 of 90 on tiles)."""
    _, (a, b), _ = cv2.minAreaRect(world.astype(np.float32))
    return max(a, b) <= FRONT_ROOM * length_cm


def _surrounds(part: BoolArray, mask: BoolArray) -> bool:
    """Does the light ``part`` surround the coloured blob ``mask`` (the blob's centre inside the part's convex hull)?
    A two-tone marker's front lies at one end of it; a white or light grey body shows all round it, and was taken
    for a front of up to three times the marker's area."""
    vs, us = np.nonzero(part)
    hull = cv2.convexHull(np.column_stack([us, vs]).astype(np.int32))
    mv, mu = np.nonzero(mask)
    return cv2.pointPolygonTest(hull, (float(mu.mean()), float(mv.mean())), False) >= 0


# -- naming ----------------------------------------------------------------------------------------------------------
def _hue_name(hue_deg: float) -> str:
    return min(HUE_NAMES, key=lambda named: _hue_gap_deg(named[0], hue_deg))[1]


def _name(markers: list[EnrolledMarker], ids: Sequence[str] | None) -> list[EnrolledMarker]:
    if ids is None:
        ordered = sorted(markers, key=lambda m: m.hue_deg)
        names: list[str] = []
        for m in ordered:
            base = _hue_name(m.hue_deg)
            name, k = base, 2
            while name in names:
                name, k = f"{base}-{k}", k + 1
            names.append(name)
        return [replace(m, rover_id=n) for m, n in zip(ordered, names, strict=True)]
    problem = id_problem(ids)
    if problem is not None:
        raise EnrollmentError(problem)
    if len(markers) != len(ids):
        more = "more" if len(markers) > len(ids) else "fewer"
        where = ", ".join(f"({m.xy_cm[0]:.0f}, {m.xy_cm[1]:.0f}) cm hue {m.hue_deg:.0f}" for m in markers)
        raise EnrollmentError(
            f"found {len(markers)} markers, {more} than the {len(ids)} ids given ({', '.join(ids)}): {where}"
        )
    hue_of = dict((name, hue) for hue, name in HUE_NAMES)
    if all(i in hue_of for i in ids) and len(ids) <= 8:  # red,green,blue: each id to the marker nearest its hue
        best = min(
            permutations(range(len(markers))),
            key=lambda p: sum(_hue_gap_deg(markers[j].hue_deg, hue_of[i]) for i, j in zip(ids, p, strict=True)),
        )
        return [replace(markers[j], rover_id=i) for i, j in zip(ids, best, strict=True)]
    ordered = sorted(markers, key=lambda m: (m.xy_cm[0], m.xy_cm[1]))
    return [replace(m, rover_id=i) for m, i in zip(ordered, ids, strict=True)]


def _too_close(markers: Sequence[EnrolledMarker]) -> list[str]:
    """A line for each pair whose hues this camera and light cannot keep apart (the tracker's opponent hue)."""
    warnings = []
    hues = {m.rover_id: _opponent_hue_deg(m.color_bgr) for m in markers}
    for i, a in enumerate(markers):
        for b in markers[i + 1 :]:
            gap = _hue_gap_deg(hues[a.rover_id], hues[b.rover_id])
            need = a.spread_deg + b.spread_deg + LIGHT_MARGIN_DEG
            if gap < need:
                warnings.append(
                    f"{a.rover_id} and {b.rover_id} are too close to tell apart under this camera and light: their "
                    f"hues are {gap:.0f} deg apart, and each varies by up to {a.spread_deg:.0f} and "
                    f"{b.spread_deg:.0f} deg over its marker (with {LIGHT_MARGIN_DEG:.0f} deg for the light across "
                    f"the room they need {need:.0f}); use markers of more different colours"
                )
    return warnings


def _odd_sizes(markers: Sequence[EnrolledMarker], length_cm: float, width_cm: float) -> list[str]:
    """One-colour markers whose measured area is far from the size the tracker expects (it sizes its windows and
    filters blobs by it)."""
    nominal = length_cm * width_cm
    return [
        f"{m.rover_id} measures {m.area_cm2:.0f} cm2 ({m.length_cm:.1f} x {m.width_cm:.1f} cm) but the tracker expects "
        f"{length_cm:g} x {width_cm:g} cm: set [tracker] marker_length_cm and marker_width_cm"
        for m in markers
        if m.front_color_bgr is None and abs(m.area_cm2 / nominal - 1.0) > 0.3
    ]


def save_enrolment(enrolment: Enrolment, path: Path, source: str = "", *, text: str | None = None) -> None:
    """Write :meth:`Enrolment.toml` (or ``text``, the TOML already shown for it) to ``path``, replacing an earlier
    rovers file but never a configuration with other sections in it (``/etc/edge-ips/config.toml`` given by
    mistake)."""
    if path.exists():
        try:
            existing = tomllib.loads(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
            raise EnrollmentError(f"{path}: exists and is not a rovers file; choose another --out") from None
        others = sorted(set(existing) - {"rovers"})
        if others:
            raise EnrollmentError(
                f"{path}: is a configuration with [{'], ['.join(others)}]: write the rovers to a file of their own "
                "and copy the [[rovers]] tables in"
            )
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        tmp.write_text(enrolment.toml(source) if text is None else text, encoding="utf-8")
        tmp.replace(path)
    except OSError as exc:
        raise EnrollmentError(f"{path}: cannot write ({exc.strerror})") from exc


def _opponent_hue_deg(color_bgr: Sequence[int]) -> float:
    b, g, r = (float(c) for c in color_bgr)
    return math.degrees(math.atan2((r + g - 2.0 * b) / math.sqrt(6.0), (r - g) / math.sqrt(2.0))) % 360.0
