"""Segmentation stages, each alone: colour planes, background model (eq. 2), threshold interval, morphology."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis.extra import numpy as hnp

from edge.background import BackgroundModel, subtract_background
from edge.coverage import coverage_weights
from edge.segmentation import (
    LINEAR,
    NO_ROVER,
    ColorModel,
    auto_threshold,
    close,
    color_planes,
    erode,
    fill_holes,
    label_particles,
    open_by_reconstruction,
    opponent_planes,
    outline_particle,
    reconstruct,
    single_outline,
    threshold,
)
from tests.support.track import COLORS

MARKERS = [COLORS["red"], COLORS["green"], COLORS["blue"]]
FLOOR = (150, 162, 172)
BODY = (22, 22, 24)
GLARE = (235, 238, 240)


def patch(color: tuple[int, int, int], gain: float = 1.0, size: int = 4) -> np.ndarray:
    return np.clip(np.full((size, size, 3), color, np.float32) * gain, 0, 255).astype(np.uint8)


def model(tol: float = 30.0) -> ColorModel:
    return ColorModel.from_colors(MARKERS, hue_tolerance_deg=tol, min_saturation_fraction=0.35)


@pytest.mark.parametrize(
    ("color", "expected"),
    [
        (COLORS["red"], 0),
        (COLORS["green"], 1),
        (COLORS["blue"], 2),
        (FLOOR, NO_ROVER),
        (BODY, NO_ROVER),
        (GLARE, NO_ROVER),
        (COLORS["magenta"], NO_ROVER),  # a hue no rover has
    ],
)
@pytest.mark.parametrize("gain", [0.65, 1.0, 1.35])
def test_pixels_are_classified_by_hue_whatever_the_light_level(color, expected, gain):
    c1, c2, lum = opponent_planes(patch(color, gain))
    assert np.all(model().classify(c1, c2, lum) == expected)


def test_a_grey_marker_colour_is_refused():
    with pytest.raises(ValueError, match="grey"):
        ColorModel.from_colors([(120, 120, 120)], 30.0, 0.35)


@pytest.mark.parametrize("share", [0.0, 0.25, 0.5, 0.75, 1.0])
@pytest.mark.parametrize("surround", [(22, 22, 22), (128, 128, 128)])
def test_colour_plane_is_linear_in_marker_coverage_over_a_grey_surround(share, surround):
    mixed = tuple(share * m + (1 - share) * s for m, s in zip(COLORS["red"], surround, strict=True))
    full = float(color_planes(patch(COLORS["red"]), model())[0].mean())
    plane = color_planes(np.full((2, 2, 3), mixed, np.float32).round().astype(np.uint8), model())[0]
    assert float(plane.mean()) == pytest.approx(share * full, abs=1.5)


def test_each_plane_peaks_on_its_own_marker():
    image = np.concatenate([patch(c) for c in MARKERS], axis=1)
    planes = color_planes(image, model())
    for k in range(3):
        peaks = [float(planes[k][:, 4 * j : 4 * j + 4].mean()) for j in range(3)]
        assert int(np.argmax(peaks)) == k


@pytest.mark.parametrize("gain", [0.65, 0.8, 1.2, 1.35])
def test_background_subtraction_ignores_a_change_of_light_level(gain):
    rng = np.random.default_rng(0)
    reference = np.clip(rng.normal(FLOOR, 6.0, (40, 40, 3)), 0, 255).astype(np.uint8)
    current = np.clip(reference.astype(np.float32) * gain, 0, 255).astype(np.uint8)
    current[10:20, 10:20] = patch(COLORS["green"], gain, 10)
    fg = subtract_background(current, reference, threshold=0.2)
    assert fg[10:20, 10:20].all()
    assert fg.sum() == 100


def test_background_refresh_covers_the_frame_once_per_period_and_never_absorbs_a_tracked_rover():
    h, w, period = 60, 80, 12
    empty = np.full((h, w, 3), FLOOR, np.uint8)
    bg = BackgroundModel((h, w), period, empty)
    scene = empty.copy()
    scene[20:30, 30:40] = COLORS["red"]  # a parked rover
    scene[:, :5] = (90, 90, 90)  # the rest of the scene changed (light, a moved chair)
    for _ in range(2 * period):
        bg.refresh(scene, exclude=[(28, 18, 42, 32)])
    assert np.array_equal(bg.reference[20:30, 30:40], empty[20:30, 30:40])
    assert np.array_equal(bg.reference[:, :5], scene[:, :5])
    fg = bg.foreground(scene[20:30, 30:40], (30, 20, 40, 30), threshold=0.2)
    assert fg.all()


def test_learned_background_is_valid_only_where_no_rover_covered_it():
    h, w = 40, 40
    first = np.full((h, w, 3), FLOOR, np.uint8)
    first[10:20, 10:20] = COLORS["blue"]
    bg = BackgroundModel((h, w), period_frames=4)
    bg.refresh(first, exclude=[(8, 8, 22, 22)])
    assert not bg.valid[10:20, 10:20].any()
    assert bg.valid[30:, 30:].all()
    # Without a valid reference the rover is not hidden by the subtraction (it simply is not used there).
    assert not bg.foreground(first[10:20, 10:20], (10, 10, 20, 20), 0.2).any()


@pytest.mark.parametrize("gain", [0.65, 1.0, 1.35])
def test_threshold_interval_follows_the_marker_maximum(gain):
    plane = np.zeros((20, 20), np.float32)
    plane[5:15, 5:15] = 100.0 * gain
    plane[5, 5] = 400.0  # one hot pixel does not move a percentile
    interval = auto_threshold(plane, plane > 0, fraction=0.5)
    assert interval.k_max == pytest.approx(100.0 * gain)
    assert interval.k_min == pytest.approx(50.0 * gain)
    assert threshold(plane, interval).sum() == 100


def test_threshold_interval_without_candidates_selects_nothing():
    plane = np.ones((5, 5), np.float32)
    assert auto_threshold(plane, np.zeros((5, 5), bool), 0.5).k_max == 0.0


def test_erosion_removes_speckles_and_reconstruction_restores_the_marker_outline():
    marker = np.zeros((30, 30), bool)
    marker[5:20, 5:25] = True
    marker[19, 10] = False  # a notch in the outline survives (it is the marker's shape)
    mask = marker.copy()
    mask[7, 2] = mask[25, 25] = mask[26, 3] = True  # speckles
    assert not erode(mask)[25, 25]
    assert np.array_equal(open_by_reconstruction(mask), marker)
    assert not reconstruct(np.zeros_like(mask), mask).any()


def test_fill_holes_fills_enclosed_holes_only_as_in_fig_13():
    mask = np.zeros((20, 20), bool)
    mask[3:15, 3:15] = True
    mask[6:9, 6:9] = False  # a hole (glare on the marker)
    mask[10:15, 12:14] = False  # a bay open to the outside: not a hole
    filled = fill_holes(mask)
    assert filled[6:9, 6:9].all()
    assert not filled[10:15, 12:14].any()
    assert np.array_equal(filled & ~mask, np.pad(np.ones((3, 3), bool), ((6, 11), (6, 11))))


def test_fill_holes_handles_a_marker_touching_the_window_border():
    mask = np.zeros((10, 10), bool)
    mask[:6, :6] = True
    mask[2:4, 2:4] = False
    assert fill_holes(mask)[:6, :6].all()


def test_particles_are_measured_as_in_table_ii():
    mask = np.zeros((40, 60), bool)
    mask[5:15, 5:25] = True  # 200 px with a 2 x 3 hole
    mask[8:10, 10:13] = False
    mask[20:30, 40:45] = True  # 50 px
    _, particles = label_particles(mask, min_area_px=2)
    big = max(particles, key=lambda p: p.area_px)
    small = min(particles, key=lambda p: p.area_px)
    assert (big.area_px, big.holes_px, big.total_px) == (194, 6, 200)
    assert big.bbox == (5, 5, 25, 15)
    assert big.solidity == pytest.approx(1.0, abs=0.01)
    assert (small.area_px, small.holes_px, small.bbox) == (50, 0, (40, 20, 45, 30))
    assert small.centre_px == pytest.approx((42.0, 24.5))


def _rendered_rectangle(x0: float, y0: float, x1: float, y1: float, surround_top, surround_bottom, ss: int = 16):
    """A marker rectangle with exact sub-pixel coverage, floor above it and dark body below (as seen obliquely):
    light mixed in each pixel in linear light, then encoded with the sRGB tone curve as a webcam does."""
    h, w = 30, 40
    big = np.zeros((h * ss, w * ss, 3), np.float32)
    big[: (h * ss) // 2] = LINEAR[np.asarray(surround_top)]
    big[(h * ss) // 2 :] = LINEAR[np.asarray(surround_bottom)]
    ys, xs = np.mgrid[0 : h * ss, 0 : w * ss]
    u = (xs + 0.5) / ss - 0.5
    v = (ys + 0.5) / ss - 0.5
    inside = (u >= x0) & (u < x1) & (v >= y0) & (v < y1)
    big[inside] = LINEAR[np.asarray(COLORS["red"])]
    mixed = cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA)
    return np.interp(mixed, LINEAR, np.arange(256)).round().astype(np.uint8)


@pytest.mark.parametrize(
    "rect",
    [(10.3, 10.6, 30.1, 19.9), (12.75, 11.2, 25.4, 17.45), (9.5, 12.1, 29.5, 16.3)],
)
@pytest.mark.parametrize("jpeg", [None, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_422])
def test_coverage_weights_give_the_sub_pixel_centroid_and_area(rect, jpeg):
    """Unmixed in linear light, the edge pixels' shares put the centroid where the rectangle's is, whether the dark
    body or the bright floor surrounds the edge; through JPEG at quality 90 with full or half horizontal chroma.
    (With half the chroma rows too, 4:2:0, the spill onto the floor pulls it 0.2-0.5 px towards the floor: the
    outline fit, ``tests/test_outline.py``, is what copes with that.)"""
    image = _rendered_rectangle(*rect, surround_top=FLOOR, surround_bottom=BODY)
    if jpeg is not None:
        params = [cv2.IMWRITE_JPEG_QUALITY, 90, cv2.IMWRITE_JPEG_SAMPLING_FACTOR, jpeg]
        _, buf = cv2.imencode(".jpg", image, params)
        image = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    c1, c2, lum = opponent_planes(image)
    cls = model().classify(c1, c2, lum)
    plane = model().plane(0, c1, c2)
    interval = auto_threshold(plane, cls == 0, 0.5)
    mask = (cls == 0) & threshold(plane, interval)
    core = fill_holes(open_by_reconstruction(mask))
    w = coverage_weights(image, core, ring_px=2, pure=mask)
    vs, us = np.mgrid[0 : w.shape[0], 0 : w.shape[1]]
    x0, y0, x1, y1 = rect
    true_centre = ((x0 + x1) / 2, (y0 + y1) / 2)
    centre = (float((w * us).sum() / w.sum()), float((w * vs).sum() / w.sum()))
    binary = (float(us[mask].mean()), float(vs[mask].mean()))
    tol = 0.03 if jpeg is None else 0.15
    assert centre == pytest.approx(true_centre, abs=tol)
    assert float(w.sum()) == pytest.approx((x1 - x0) * (y1 - y0), rel=0.03 if jpeg is None else 0.25)
    # The binary mask alone is off by up to half a pixel: the grey-level edge is what makes it sub-pixel.
    assert max(abs(binary[0] - true_centre[0]), abs(binary[1] - true_centre[1])) >= max(
        abs(centre[0] - true_centre[0]), abs(centre[1] - true_centre[1])
    )


masks = hnp.arrays(np.bool_, hnp.array_shapes(min_dims=2, max_dims=2, min_side=1, max_side=24))


@pytest.mark.slow
@given(masks)
def test_hole_filling_keeps_the_mask_and_is_idempotent(mask):
    filled = fill_holes(mask)
    assert np.all(filled[mask])
    assert np.array_equal(fill_holes(filled), filled)
    # Nothing connected to the border is ever filled.
    border = np.zeros_like(mask)
    border[0, :] = border[-1, :] = True
    border[:, 0] = border[:, -1] = True
    assert not np.any(filled & ~mask & border)


@pytest.mark.slow
@given(masks)
def test_reconstruction_of_a_mask_by_itself_is_the_mask(mask):
    assert np.array_equal(reconstruct(mask, mask), mask)
    opened = open_by_reconstruction(mask)
    assert np.all(mask[opened])


def test_particles_of_a_filled_mask_are_measured_alike_when_told_so():
    mask = np.zeros((60, 80), bool)
    mask[10:30, 10:40] = True
    mask[15:20, 20:25] = False  # a hole
    mask[40:50, 50:70] = True
    filled = fill_holes(mask)
    labels, particles = label_particles(filled)
    labels_told, particles_told = label_particles(filled, filled=True)
    assert np.array_equal(labels, labels_told) and particles == particles_told
    assert [p.holes_px for p in label_particles(mask)[1]] == [25, 0]


@pytest.mark.slow
@given(masks)
def test_particles_and_reconstruction_match_opencvs_statistics_and_components(mask):
    # One particle is measured without OpenCV's statistics (a quicker path): the same integers and centroids.
    n, labels, stats, centroids = cv2.connectedComponentsWithStatsWithAlgorithm(
        mask.view(np.uint8), 8, cv2.CV_32S, cv2.CCL_GRANA
    )
    got_labels, particles = label_particles(mask)
    assert np.array_equal(got_labels, labels)
    assert [p.label for p in particles] == list(range(1, n))
    for p in particles:
        x, y, w, h, area = (int(v) for v in stats[p.label])
        assert (p.area_px, p.bbox) == (area, (x, y, x + w, y + h))
        assert p.centre_px == (float(centroids[p.label, 0]), float(centroids[p.label, 1]))
    # Reconstruction (one component or many): the components of the mask that the marker touches.
    marker = mask & mask[::-1, ::-1]
    touched = {int(v) for v in labels[marker]} - {0}
    assert np.array_equal(reconstruct(marker, mask), np.isin(labels, sorted(touched)) & mask)


def _one_particle_or_stages(mask: np.ndarray) -> tuple[np.ndarray, list] | None:
    """The particle tracker's quick path (one outline pass) where it applies, checked against the stages' result."""
    single = single_outline(mask, 1)
    filled = fill_holes(open_by_reconstruction(mask))
    particles = label_particles(filled, 2, filled=True)[1]
    if single is None:
        return None
    outline, holes, eroded = single
    quick = fill_holes(mask) if holes else mask
    assert np.array_equal(quick, filled)
    assert np.array_equal(eroded, erode(mask, 1))
    assert outline_particle(quick, outline, 2) == particles
    return quick, particles


def test_one_particle_is_opened_filled_and_measured_from_its_outline_as_by_the_stages():
    marker = np.zeros((40, 60), bool)
    marker[8:30, 10:45] = True
    assert _one_particle_or_stages(marker) is not None
    glare = marker.copy()
    glare[15:19, 20:26] = False  # a hole: filled by the stages' flood fill
    quick = _one_particle_or_stages(glare)
    assert quick is not None and quick[0][16, 22] and quick[1][0].area_px == marker.sum()
    ring = np.zeros((40, 60), bool)
    ring[5:35, 5:55] = True
    ring[9:31, 9:51] = False
    ring[20, 30] = True  # a speck inside the ring's hole: two particles, one outer outline each
    assert _one_particle_or_stages(ring) is None
    line = np.zeros((40, 60), bool)
    line[20, 5:50] = True  # removed whole by the opening
    assert _one_particle_or_stages(line) is None


@pytest.mark.slow
@given(masks)
def test_the_one_outline_path_agrees_with_the_stages_on_any_mask(mask):
    _one_particle_or_stages(mask)


def test_closing_fills_gaps_up_to_twice_its_iterations_and_leaves_the_outline() -> None:
    mask = np.zeros((30, 40), bool)
    mask[5:25, 5:20] = True
    mask[5:25, 24:35] = True  # a gap of 4 columns between two parts
    mask[5:25, 37:39] = True  # ... and one of 2 beside a strip
    closed = close(mask, 2)
    assert closed[5:25, 5:39].all()  # both gaps filled
    assert not (closed & ~mask)[:5].any() and not (closed & ~mask)[25:].any()  # nothing grown above or below
    assert not closed[:, :5].any() and not closed[:, 39:].any()  # nor beyond the ends
    assert not close(mask, 1)[10, 21]  # one iteration fills 2 columns, not 4
    assert close(mask, 1)[10, 35:37].all()
    assert close(mask, 0) is mask
    mask[:, :2] = True  # a part on the image's border keeps its pixels there
    assert (close(mask, 2) >= mask).all()
