"""Two-tone markers: heading and centre from the marker's known geometry, not from matching the front's colour.

A two-tone marker is a ``length x width`` rectangle whose front ``front_fraction`` is light (white) and the rest the
rover's colour. The tracker measures the *coloured part* exactly as it measures a one-colour marker (hue classes,
unmixed edges, area centroid on the plane). Everything else follows from geometry on the world plane:

1. **Axis** (:func:`edge_axis`): the coloured part is a known rectangle, so the directions of its edges are its
   orientation modulo 90 degrees. They come from the image gradient around the part, mapped to the plane
   (``J^-T g``), as the angle of the fourth harmonic of the gradient directions weighted by ``|g|^2``: of the
   rover's colour plane, or of the luminance when that is more coherent (compressed video halves the chroma's
   resolution). Unlike second moments (the coloured part is 15.1 x 16.8 cm, nearly square: 2-10 degrees off, 35 at
   the far side through a compressed stream), this is sharp to a fraction of a degree (1-3 at the far side).
2. **Which end is the front** (:func:`end_strip_scores`): for each of the four directions ``axis + k * 90 deg``, the
   strip the front part would cover if that were the heading (``front_fraction * length`` beyond the coloured
   part, ``width`` across) is looked at: the light front part is bright (relative to the coloured part's own
   brightness, so the light level does not matter) and uniform; the floor behind the rover, glare and sunlit floor
   included, is darker or textured (tiles, speckle, grout, the edge of a reflection), and the body's sides are
   dark. Score = relative brightness - 2 x relative spread. Pixels near other rovers are left out.
3. **Continuity** (:class:`TwoToneHeading`): a rover cannot turn by 45 degrees between frames, so the tracked
   heading picks its candidate by nearness to the last one, and each frame's strip scores add *evidence* for that
   end against the best other candidate. The heading flips only after the evidence has turned clearly against it
   over several frames, and it is *reported* only while the evidence is strong: in a glare spot or a saturated
   patch of sunlight, where the two ends look alike, the heading is held (or null) rather than guessed. Never a
   confident wrong heading.
4. **Centre**: the coloured part's centroid shifted forwards by ``front_fraction * length / 2``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from edge.segmentation import F32, U8, BoolArray

FloatArray = NDArray[np.float64]

QUARTER = 0.5 * math.pi
SPREAD_WEIGHT = 2.0  # score = relative brightness - SPREAD_WEIGHT * relative spread
MIN_AXIS_STRENGTH = 0.3  # fourth-harmonic coherence below this: the edges do not show a rectangle
EVIDENCE_CAP = 1.0  # evidence saturates here: a few frames of contrary evidence can overturn any heading
EVIDENCE_STEP = 0.2  # one frame's contribution at most: overturning a sure heading takes 7 clear frames
AMBIGUOUS_MARGIN = 0.1  # score margins within this say nothing (sunlit floor behind, a shaded front part)
REPORT_EVIDENCE = 0.2  # evidence needed to report the heading: one clear frame
FLIP_EVIDENCE = -0.3  # evidence against the tracked end that turns the heading round
AXIS_PRIOR = 0.15  # weight of the coloured part's shape when a front is chosen anew
HOLD_FRAMES = 5  # frames a heading is carried without a view of the marker's edges (turns < 30 deg at 30 fps)
SIDEWAYS_RAD = math.radians(60.0)  # motion this far off the tracked axis (modulo 180 degrees) contradicts it...
STEADY_TURN_RAD = math.radians(2.0)  # ...while the tracked heading turns less than this a frame (60 deg/s)...
SIDEWAYS_FRAMES = 5  # ...for this many frames: the axis is the other one
AXIS_MARGIN = 0.3  # a side candidate beating both tracked ends by this much says the axis may be the other one...
AXIS_FRAMES = 45  # ...and after this many such frames (1.5 s) it is: a rover standing still, its axis taken wrong
ALONG_RAD = math.radians(30.0)  # motion within this of the tracked axis (modulo 180 degrees) confirms the axis
FRAME_S = 1.0 / 30.0  # the frame interval the frame counts above are for
_KERNEL = np.ones((3, 3), np.uint8)
CAMERA_GAMMA = 2.2  # webcams encode light with the sRGB tone curve, close to this power law
_LINEAR = (np.arange(256, dtype=np.float64) / 255.0) ** CAMERA_GAMMA  # 8-bit value -> linear light


@dataclass(frozen=True)
class TwoToneGeometry:
    """The marker: ``length_cm`` along the rover, ``width_cm`` across, the front ``front_fraction`` light."""

    length_cm: float
    width_cm: float
    front_fraction: float

    @property
    def coloured_length_cm(self) -> float:
        return (1.0 - self.front_fraction) * self.length_cm

    @property
    def front_length_cm(self) -> float:
        return self.front_fraction * self.length_cm

    @property
    def centre_offset_cm(self) -> float:
        """From the coloured part's centroid forwards to the marker's centre."""
        return 0.5 * self.front_length_cm


@dataclass(frozen=True)
class TwoToneView:
    """What one frame shows of a two-tone marker: its edges' axis (rad, modulo pi/2), how clearly the edges show a
    rectangle (0..1), the end-strip score of each candidate heading ``axis + k pi/2`` (NaN: not seen), and
    ``axis_prior`` (-1..1): how much the coloured part's spread along and across ``axis`` says that the heading
    lies along ``axis`` (+1) or across it (-1) (the part is shorter along the rover than across it)."""

    axis_rad: float
    axis_strength: float
    scores: tuple[float, float, float, float]
    axis_prior: float = 0.0

    def candidate(self, k: int) -> float:
        return math.remainder(self.axis_rad + k * QUARTER, math.tau)


def edge_axis(plane: F32, mask: BoolArray, jacobian_cm_per_px: FloatArray) -> tuple[float, float]:
    """Orientation of a rectangle's edges on the world plane, modulo pi/2, and its coherence 0..1.

    ``plane``: (h, w) float32 colour plane of the window; ``mask``: (h, w) pixels around the coloured part whose
    gradients count; ``jacobian_cm_per_px``: (2, 2) d(x, y)/d(u, v) at the part (image gradients become plane
    gradients through its inverse transpose). The angle of ``sum |g|^2 exp(4 i alpha)`` / 4: the four edge normals
    of a rectangle agree modulo pi/2, and a square pixel grid's own preference for 0 and 90 degrees cancels in
    Scharr's near-isotropic derivative.
    """
    x, y, w, h = cv2.boundingRect(mask.view(np.uint8))
    if w == 0 or h == 0:
        return 0.0, 0.0
    # The derivative needs one pixel round the mask (the window's own border is treated as before, unpadded).
    rows = slice(max(0, y - 1), min(plane.shape[0], y + h + 1))
    cols = slice(max(0, x - 1), min(plane.shape[1], x + w + 1))
    (a, b), (c, d) = np.asarray(jacobian_cm_per_px, dtype=np.float64).tolist()  # plain floats: quicker, same
    if not (math.isfinite(a * d - b * c) and a * d - b * c != 0.0):
        return 0.0, 0.0
    sub = plane[rows, cols]
    # both derivatives of the pixels in the mask as one (2, n) array: one gather of the mask's flat indices
    image = np.empty((2, *sub.shape), np.float32)
    cv2.Scharr(sub, cv2.CV_32F, 1, 0, dst=image[0])
    cv2.Scharr(sub, cv2.CV_32F, 0, 1, dst=image[1])
    image = image.reshape(2, -1).take(mask[rows, cols].ravel().nonzero()[0], axis=1)
    # Plane gradients are the inverse transpose of the Jacobian times the image's; its 1/det scales every gradient
    # alike (its sign turns each by pi, nothing modulo pi/2), so the adjugate does (in float64).
    g = np.array([[d, -c], [-b, a]]) @ image
    squares = g * g
    mag2 = squares[0] + squares[1]
    total = float(mag2.sum())
    if total <= 0.0:
        return 0.0, 0.0
    # exp(4 i alpha) * |g|^2 = (gx + i gy)^4 / |g|^2, in real arithmetic: with (gx + i gy)^2 = c2 + i s2 (s2 = 2 gx gy,
    # c2^2 + s2^2 = |g|^4) the real part is 2 c2^2 / |g|^2 - |g|^2 and the imaginary one 2 c2 s2 / |g|^2: two sums
    c2 = squares[0] - squares[1]
    share = c2 / np.maximum(mag2, 1e-30)
    re = 2.0 * float(c2 @ share) - total
    im = 4.0 * float((g[0] * g[1]) @ share)
    return math.atan2(im, re) / 4.0, math.hypot(re, im) / total


def end_strip_scores(
    lum: F32,
    x_cm: FloatArray,
    y_cm: FloatArray,
    centroid_cm: tuple[float, float],
    axis_rad: float,
    geometry: TwoToneGeometry,
    reference_lum: float,
    exclude: BoolArray | None = None,
) -> tuple[float, float, float, float]:
    """Score of each candidate front ``axis_rad + k pi/2``: how much the strip the front part would cover then looks
    like it (bright relative to ``reference_lum``, the coloured part's brightest channel, and uniform).

    ``lum``: (h, w) luminance of the window; ``x_cm``, ``y_cm``: (h, w) each pixel's position on the plane;
    ``centroid_cm``: the coloured part's centroid. The strip spans ``front_length_cm`` beyond the coloured part and
    ``width_cm`` across; its pixels are shrunk by one so that edge pixels mixed with the part or the rim do not
    count (unless that leaves too few). ``exclude``: pixels that belong to something else (other rovers).
    """
    dx = x_cm - centroid_cm[0]
    dy = y_cm - centroid_cm[1]
    half_w = 0.5 * geometry.width_cm
    near = 0.5 * geometry.coloured_length_cm
    far = near + geometry.front_length_cm
    ref = max(reference_lum, 1.0)
    out = []
    for k in range(4):
        a = axis_rad + k * QUARTER
        c, s = math.cos(a), math.sin(a)
        along = dx * c + dy * s
        across = dy * c - dx * s
        strip = (along >= near) & (along <= far) & (np.abs(across) <= half_w)
        whole = int(strip.sum())
        if exclude is not None:
            strip &= ~exclude
        inner = cv2.erode(strip.view(np.uint8), _KERNEL).view(bool)
        pick = inner if int(inner.sum()) >= 3 else strip
        n = int(pick.sum())
        if n < 2 or n < 0.2 * whole:
            out.append(math.nan)
            continue
        values = lum[pick].astype(np.float64)
        mean = float(values.mean())
        spread = float(values.std()) / max(mean, 1.0)
        out.append(mean / ref - SPREAD_WEIGHT * spread)
    return out[0], out[1], out[2], out[3]


@dataclass(frozen=True, kw_only=True)
class MarkerPixels:
    """A tracker window's pixels as :func:`view_marker` reads them (every array (h, w), the window's pixels).

    ``bgr``, ``lum``, ``plane``: the window seen under the configured white, its luminance and the rover's colour
    plane; ``own``: pixels of the rover's hue class; ``x_cm``, ``y_cm``: each pixel centre on the plane;
    ``others``: pixels of other rovers (their hue, or near their positions); ``coverage`` and ``area_cm2``: the
    tracker's coverage of each pixel by the coloured part and each pixel's area on the plane (for the shape prior;
    none without them).
    """

    bgr: U8
    lum: F32
    plane: F32
    own: BoolArray
    x_cm: FloatArray
    y_cm: FloatArray
    others: BoolArray | None = None
    coverage: F32 | None = None
    area_cm2: FloatArray | None = None


def view_marker(
    pixels: MarkerPixels, centroid_cm: tuple[float, float], jacobian_cm_per_px: FloatArray, geometry: TwoToneGeometry
) -> TwoToneView | None:
    """One frame's view of a two-tone marker in a tracker window whose coloured part's centroid is
    ``centroid_cm``. None when the coloured part is not in the window."""
    bgr, lum, plane, own, others = pixels.bgr, pixels.lum, pixels.plane, pixels.own, pixels.others
    x_cm, y_cm, coverage, area_cm2 = pixels.x_cm, pixels.y_cm, pixels.coverage, pixels.area_cm2
    half_diag = 0.5 * math.hypot(geometry.coloured_length_cm, geometry.width_cm)
    d2 = (x_cm - centroid_cm[0]) ** 2 + (y_cm - centroid_cm[1]) ** 2
    part = own & (d2 <= (half_diag + 1.0) ** 2)
    if not part.any():
        return None
    edges = cv2.dilate(part.view(np.uint8), _KERNEL, iterations=2).view(bool) & (d2 <= (half_diag + 3.0) ** 2)
    if others is not None:
        edges &= ~others
    # The rover's colour plane has the sharpest edges, unless the camera halves the chroma resolution (MJPG and
    # H.264 are 4:2:0): then the luminance's edges are sharper. Take whichever shows a rectangle more coherently.
    axis, strength = max(
        edge_axis(plane, edges, jacobian_cm_per_px), edge_axis(lum, edges, jacobian_cm_per_px), key=lambda a: a[1]
    )
    inner = cv2.erode(part.view(np.uint8), _KERNEL).view(bool)
    sample = inner if inner.any() else part
    reference = float(bgr[sample].max(axis=1).mean())
    scores = end_strip_scores(lum, x_cm, y_cm, centroid_cm, axis, geometry, reference, others)
    prior = 0.0
    expected = (geometry.width_cm**2 - geometry.coloured_length_cm**2) / 12.0  # across minus along, a rectangle's
    if coverage is not None and area_cm2 is not None and abs(expected) > 0.5:
        w = coverage.astype(np.float64) * area_cm2
        total = float(w.sum())
        if total > 0.0:
            dx = x_cm - centroid_cm[0]
            dy = y_cm - centroid_cm[1]
            c, s = math.cos(axis), math.sin(axis)
            along = dx * c + dy * s
            across = dy * c - dx * s
            spread = float((w * (across * across - along * along)).sum()) / total
            prior = max(-1.0, min(1.0, spread / expected))
    return TwoToneView(axis, strength, scores, prior)


def footprint_cm(jacobian_cm_per_px: FloatArray, direction_rad: float) -> tuple[float, float]:
    """A pixel's extent on the plane along ``direction_rad`` and across it (cm): the parallelogram spanned by the
    Jacobian's columns, projected."""
    c, s = math.cos(direction_rad), math.sin(direction_rad)
    j = jacobian_cm_per_px
    along = abs(j[0, 0] * c + j[1, 0] * s) + abs(j[0, 1] * c + j[1, 1] * s)
    across = abs(-j[0, 0] * s + j[1, 0] * c) + abs(-j[0, 1] * s + j[1, 1] * c)
    return along, across


def inner_edge_weights(
    bgr: U8,
    weights: F32,
    x_cm: FloatArray,
    y_cm: FloatArray,
    centroid_cm: tuple[float, float],
    heading_rad: float,
    geometry: TwoToneGeometry,
    jacobian_cm_per_px: FloatArray,
) -> F32 | None:
    """The coloured part's coverage with its inner edge, the one against the light front part, unmixed between the
    two colours that actually meet there.

    The tracker unmixes every edge pixel between the marker, the floor and the body (``coverage_weights``); along
    the inner edge the surround is the front part, lighter and more neutral than the floor, and those shares come
    out low: the centroid moves back by 0.1-0.6 cm. Here each pixel within 1.5 pixels of that edge is
    ``p = a M + (1 - a) W`` in *linear* light (the camera's tone curve undone: light mixes linearly, 8-bit values
    do not, and across this high-contrast edge the difference is a third of a pixel), with ``M`` the coloured
    part's interior and ``W`` the front part's, both measured in this window, so ``a = (p - W).(M - W) /
    |M - W|^2``. None when either colour cannot be sampled.
    """
    along_px, across_px = footprint_cm(jacobian_cm_per_px, heading_rad)
    c, s = math.cos(heading_rad), math.sin(heading_rad)
    dx = x_cm - centroid_cm[0]
    dy = y_cm - centroid_cm[1]
    along = dx * c + dy * s
    across = np.abs(dy * c - dx * s)
    edge = 0.5 * geometry.coloured_length_cm
    half_w = 0.5 * geometry.width_cm
    # A pixel's footprint plus the optics' blur reaches about one footprint from its centre.
    band = (np.abs(along - edge) <= 1.5 * along_px) & (across <= half_w - across_px)
    inside = (weights >= 1.0) & (along < edge - 1.5 * along_px)
    front = (
        (along >= edge + along_px)
        & (along <= edge + geometry.front_length_cm - 0.75 * along_px)
        & (across <= half_w - across_px)
    )
    if not band.any() or int(inside.sum()) < 3 or int(front.sum()) < 2:
        return None
    marker = _LINEAR[bgr[inside]].mean(axis=0)
    light = _LINEAR[bgr[front]].mean(axis=0)
    d = marker - light
    dd = float(d @ d)
    if dd < 0.003:  # the two colours are not told apart here (a saturated patch of sunlight)
        return None
    share = ((_LINEAR[bgr[band]] - light) @ d) / dd
    out = weights.copy()
    out[band] = np.clip(share, -0.5, 1.0).astype(np.float32)
    return out


class TwoToneHeading:
    """One rover's two-tone heading through time: continuity, accumulated end evidence, hold while unseen.

    ``heading_rad``: the current estimate (None before the first view); ``evidence``: how strongly the strips have
    said that its end is the front (-1..1); ``confident``: strong enough to report.

    Found anew (no heading, or none for more than ``HOLD_FRAMES``), the front is the best of the four candidates,
    their strip scores helped a little by the coloured part's shape (:attr:`TwoToneView.axis_prior`). Tracked, the
    axis is the candidate nearest the last heading, and the only question left is which *end*: each frame's
    evidence is the tracked end's score against the opposite end's, margins within ``AMBIGUOUS_MARGIN`` count for
    nothing and no frame counts for more than ``EVIDENCE_STEP``, so a person's legs hiding the front part or
    sunlit floor behind the rover for a few frames wear the evidence down without turning the heading round; it is
    turned round only when the opposite end has looked like the front, clearly, for several frames.
    """

    def __init__(self) -> None:
        self.heading_rad: float | None = None
        self.evidence = 0.0
        self.age = 0  # frames since the edges were last seen
        self.sideways = 0  # frames in a row the rover moved across its tracked axis without turning
        self.doubt = 0  # frames in which a side candidate looked clearly more like the front than either tracked end
        self._at_s: float | None = None  # the stream time of the last frame taken

    @property
    def confident(self) -> bool:
        return (
            self.heading_rad is not None
            and self.age <= HOLD_FRAMES
            and self.evidence >= REPORT_EVIDENCE
            and self.doubt < AXIS_FRAMES // 3  # the axis in doubt for half a second: not reported
        )

    def reset(self) -> None:
        self.heading_rad = None
        self.evidence = 0.0
        self.age = 0
        self.sideways = 0
        self.doubt = 0
        self._at_s = None

    def held(self) -> float | None:
        """The heading carried through a frame without a usable view (a few frames at most), else None."""
        self.age += 1
        if self.heading_rad is None or self.age > HOLD_FRAMES:
            return None
        return self.heading_rad

    def update(
        self, view: TwoToneView | None, at_s: float | None = None, motion_rad: float | None = None
    ) -> float | None:
        """Take one frame's view; return the heading to place the centre with (None: unknown this frame).

        ``at_s``: the frame's time in the stream (s; None: the frame after the last one). The frames between this
        one and the last one taken (dropped by the camera or by a computer that fell behind, or frames in which
        the rover was not measured) count as frames without a view: after more than ``HOLD_FRAMES`` the rover
        may have turned by more than 45 degrees, so continuity says nothing and the front is found anew.

        ``motion_rad``: the direction the rover's centre moves on the floor, when it moves clearly (else None). A
        differential drive moves along its axis; its centre moves across it only while the body turns (a marker
        off the wheel axle). Moving across the tracked axis for ``SIDEWAYS_FRAMES`` frames while the tracked
        heading holds still therefore means the axis was taken wrong (continuity across a gap it could not
        bridge): the axis becomes the motion's, and its strips say which end is the front.
        """
        frames = 1
        if at_s is not None:
            if self._at_s is not None:
                frames = max(1, round((at_s - self._at_s) / FRAME_S))
            self._at_s = at_s
        self.age += frames - 1
        if view is None or view.axis_strength < MIN_AXIS_STRENGTH:
            return self.held()
        scores = [s if math.isfinite(s) else -math.inf for s in view.scores]
        if self.heading_rad is not None and self.age <= HOLD_FRAMES:
            last = self.heading_rad
            k = min(range(4), key=lambda j: abs(math.remainder(view.candidate(j) - last, math.tau)))
            if self._moved_sideways(view.candidate(k), last, frames, motion_rad):
                assert motion_rad is not None
                along = [j for j in range(4) if abs(math.remainder(view.candidate(j) - motion_rad, math.pi)) < QUARTER]
                k = max(
                    along, key=lambda j: (scores[j], -abs(math.remainder(view.candidate(j) - motion_rad, math.tau)))
                )
                self.evidence = 0.0
            k = self._doubted(k, scores, frames, motion_rad, view)
            step = _evidence(scores[k] - scores[(k + 2) % 4])
        else:
            prior = [AXIS_PRIOR * view.axis_prior * (1 if j % 2 == 0 else -1) for j in range(4)]
            total = [sc + pr for sc, pr in zip(scores, prior, strict=True)]
            k = max(range(4), key=lambda j: total[j])
            if total[k] == -math.inf:
                return self.held()
            rivals = [t for j, t in enumerate(total) if j != k and t > -math.inf]
            step = _evidence(total[k] - max(rivals)) if rivals else 0.0
            self.evidence = 0.0
            self.sideways = 0
            self.doubt = 0
        self.evidence = min(EVIDENCE_CAP, max(-EVIDENCE_CAP, self.evidence + step))
        if self.evidence <= FLIP_EVIDENCE:
            k = (k + 2) % 4
            self.evidence = -FLIP_EVIDENCE  # what it took to overturn the old end now speaks for this one
        self.heading_rad = view.candidate(k)
        self.age = 0
        return self.heading_rad

    def _doubted(self, k: int, scores: list[float], frames: int, motion_rad: float | None, view: TwoToneView) -> int:
        """The tracked candidate ``k``, or the side candidate that has looked clearly more like the front than both
        tracked ends for :data:`AXIS_FRAMES` frames. Continuity carries the axis from frame to frame and the sideways
        motion check corrects it while the rover drives; a rover that stands still (or turns on the spot) with its
        axis taken wrong (a turn across frames the loaded computer dropped, a front found anew while it turned) has
        only its strips to say so. A moment of a side strip looking like the front (legs beside the rover) wears
        off; motion along the tracked axis confirms it."""
        along = motion_rad is not None and abs(math.remainder(view.candidate(k) - motion_rad, math.pi)) < ALONG_RAD
        side = max(((k + 1) % 4, (k + 3) % 4), key=lambda j: scores[j])
        tracked = max(scores[k], scores[(k + 2) % 4])  # -inf: neither tracked end in view, which says nothing
        if not along and tracked > -math.inf and scores[side] - tracked > AXIS_MARGIN:
            self.doubt += frames
        else:
            self.doubt = max(0, self.doubt - frames)
        if self.doubt < AXIS_FRAMES:
            return k
        self.doubt = 0
        self.evidence = 0.0
        return side

    def _moved_sideways(self, heading: float, last: float, frames: int, motion_rad: float | None) -> bool:
        """Count the frames the rover moved across ``heading`` without turning; True once they are enough."""
        steady = abs(math.remainder(heading - last, math.tau)) <= frames * STEADY_TURN_RAD
        across = motion_rad is not None and abs(math.remainder(heading - motion_rad, math.pi)) > SIDEWAYS_RAD
        self.sideways = self.sideways + frames if steady and across else 0
        if self.sideways < SIDEWAYS_FRAMES:
            return False
        self.sideways = 0
        return True


def _evidence(margin: float) -> float:
    """One frame's evidence from a score margin: nothing within the ambiguous band, at most EVIDENCE_STEP."""
    if not math.isfinite(margin) or abs(margin) <= AMBIGUOUS_MARGIN:
        return 0.0
    return math.copysign(min(EVIDENCE_STEP, abs(margin) - AMBIGUOUS_MARGIN), margin)
