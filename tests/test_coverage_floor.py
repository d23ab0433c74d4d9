"""The edge's pixels of another hue that are the marker mixed with the floor beside them (``on_the_floor``): a
marker's edge mixed with a warm floor can fall in another rover's hue class (a purple marker's against wood are
magenta). The floor is the surround's, read beside each pixel, not the background model's: none is needed."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from edge.coverage import coverage_weights
from edge.segmentation import LINEAR

PURPLE = (170, 102, 138)  # BGR as a webcam gave the far-side purple marker of crowd8 4321 on the wooden floor
MAGENTA = (120, 40, 190)  # another rover's marker: more saturated than any mix of purple with the wood
WOOD = (123, 129, 150)
WHITE = (150, 151, 152)  # the camera-facing side of a white body
RECT = (9.3, 10.4, 30.8, 18.2)  # the marker: x0, y0, x1, y1 in pixels (a far-side marker, about 21 x 8 px)
SS = 16


def _render(marker: bool = True, body: bool = True, other: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(30, 40) BGR: the marker on the floor, the body's side below it and, ``other``, a touching rover's marker
    above it; light mixed in linear light over each pixel, blurred by the optics (0.8 px) and encoded as a webcam
    does. Also the marker's true coverage per pixel."""
    h, w = 30, 40
    big = np.empty((h * SS, w * SS, 3), np.float32)
    big[:] = LINEAR[np.asarray(WOOD)]
    ys, xs = np.mgrid[0 : h * SS, 0 : w * SS]
    u, v = (xs + 0.5) / SS - 0.5, (ys + 0.5) / SS - 0.5
    x0, y0, x1, y1 = RECT
    if body:
        big[(v >= y1) & (u > x0 - 2) & (u < x1 + 2)] = LINEAR[np.asarray(WHITE)]
    if other:
        big[(v >= y0 - 5) & (v < y0) & (u >= x0 + 4) & (u < x1 - 4)] = LINEAR[np.asarray(MAGENTA)]
    inside = (u >= x0) & (u < x1) & (v >= y0) & (v < y1)
    if marker:
        big[inside] = LINEAR[np.asarray(PURPLE)]
    mixed = cv2.GaussianBlur(cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA), (0, 0), 0.8)
    image = np.interp(mixed, LINEAR, np.arange(256)).round().astype(np.uint8)
    return image, cv2.resize(inside.astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)


def _weights(image: np.ndarray, truth: np.ndarray, mixes: bool = True, extra: np.ndarray | None = None):
    core = truth >= 0.5
    dist = cv2.distanceTransform((~core).view(np.uint8), cv2.DIST_C, 3)
    # the ring's pixels on the floor's side, as the hue classes take them on warm wood: another rover's
    exclude = (dist > 0) & (dist <= 2) & (np.arange(truth.shape[0])[:, None] < RECT[1] + 1)
    if extra is not None:
        exclude |= extra  # another rover's marker: of its hue, and as saturated as a marker (left out of the band)
    return coverage_weights(image, core, 2, exclude=exclude, pure=core, apart=extra, floor_mixes=mixes)


def _centre(w: np.ndarray) -> tuple[float, float]:
    vs, us = np.mgrid[0 : w.shape[0], 0 : w.shape[1]]
    return float((w * us).sum() / w.sum()), float((w * vs).sum() / w.sum())


@pytest.mark.parametrize("body", [True, False])
def test_edge_pixels_of_another_hue_mixed_with_the_floor_beside_them_get_their_share(body: bool) -> None:
    """Left out, the marker's edge on the floor's side is lost and its centre moves toward the body (the camera) by
    a quarter of a pixel (at the far side, half a centimetre); given the share the floor beside them says, the
    centre is the marker's within 0.1 px and the area within 5 %, with no background model at all."""
    image, truth = _render(body=body)
    true_u, true_v = 0.5 * (RECT[0] + RECT[2]), 0.5 * (RECT[1] + RECT[3])
    left_out = _weights(image, truth, mixes=False)
    assert _centre(left_out)[1] - true_v > 0.2
    assert float(left_out.sum()) < 0.98 * float(truth.sum())
    kept = _weights(image, truth)
    assert _centre(kept) == pytest.approx((true_u, true_v), abs=0.1)
    assert float(kept.sum()) == pytest.approx(float(truth.sum()), rel=0.05)


def test_a_touching_rover_s_marker_is_not_on_the_line_from_the_floor_and_gets_no_share() -> None:
    """Another rover's marker beside the edge (its pixels of its own hue, left out) is more saturated than any mix
    of this marker with the floor: the floor does not explain it, and it stays out of this marker's area."""
    image, truth = _render(other=True)
    x0, y0, x1, _ = RECT
    theirs = np.zeros(truth.shape, bool)
    theirs[int(y0) - 5 : int(y0), int(x0) + 5 : int(x1) - 5] = True  # its pixels up to this marker's edge
    w = _weights(image, truth, extra=theirs)
    assert float(w[theirs].max()) == 0.0
    assert float(w.sum()) < 1.1 * float(truth.sum())
