"""Where the colour-dependent bias of the marker centre comes from: single frames of one marker at known poses,
rendered through the simulator's camera with one JPEG chroma sampling and quality at a time.

    python benchmarks/bench_chroma_bias.py [--poses N] [--seed S] [--palette default|eight]
        [--centre linear|encoded|edges] [--margins 0.2,1.0,2.5] [--streams 'none,4:2:0 q90'] [--tone srgb|gamma2.2|...]
        [--sharpen AMOUNT] [--weigh-channels]

The centre is the tracker's default one (``edge.coverage.coverage_weights``: the linear-light coverage, its area
centroid on the plane by ``world_blob``); the marker's interior mask is the truth's (the pixels whose centre lies on
the marker), so only the sub-pixel edge is measured. Each row: one chroma sampling and quality over every body
(black, dark grey, white, with ``--margins`` cm of the body's top around the marker, 1 cm unless given), blur (0.5
and 1.2 px) and marker colour, ``--poses`` random poses each over the whole floor (seed ``--seed``): the mean error
(x, y) over all of them and the worst per-colour mean |(x, y)| (the bias bar: 0.05 cm). ``none`` is the uncompressed
frame; ``q100`` JPEG with the least quantisation (the chroma subsampling alone); lower qualities add the
quantisation of the chroma.
No noise, no motion, no automatic exposure: the bias, not the scatter. ``--sharpen``: the camera's processor sharpens
its luma by that amount (an unsharp mask of 1 px, ``edge.sim.effects.SignalProcessing``; no demosaicing);
``--weigh-channels``: the edge fits fitted again with the luma weighed by their residuals, as the tracker's are
where the camera may sharpen (``edge.edges_encoded``).

``--centre encoded`` measures two centres that were tried and not adopted (``docs/benchmarks.md``, "Shares in
the camera's values plus an optics correction"). *encoded*: shares by one affine map of the decoded 8-bit B'G'R'
(which a chroma spread that keeps the chroma's sum leaves in place), over a 4-pixel ring, the surround's levels
from a band 4-7 pixels out; besides its error, how far it moves from the same pose's uncompressed frame (the
stream's own part) and the ceiling of any optics correction (the uncompressed frame's optics offset, encoded minus
linear centre, taken off exactly). *optics*: the encoded shares plus a per-pixel optics correction from a model
of the marker's rectangle (its size known, placed at the centre found, two rounds) blurred by the *true* blur and
the pixel's aperture in linear light, each pixel's surround level solved from its full-resolution luma (BT.601,
which the chroma spread does not touch), the model's encoded share taken off and its linear coverage put in.

``--centre edges``: the default centre, the *half* crossings (per side, where the encoded chroma projected on the
marker's chroma falls to half between the marker and the band beyond the spread; no optics offset) and the *edges*
fitted in the encoded Y'CbCr (``edge.edges_encoded``: a 1D model per side with the optics, the body's margin and
the stream's spread, the tone curve assumed ``--tone``), each from the profiles around the default centre along the
true axis; per row also the worst per-colour bias within one body and margin, and the mean y bias per body and
margin.
"""

from __future__ import annotations

import argparse
import itertools
import math
import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np

# the checkout this script is in, ahead of an installed edge (an editable install may be another checkout's): a
# benchmark measures the code beside it, unless PYTHONPATH says which (stages --baseline runs another checkout so)
if not os.environ.get("PYTHONPATH"):
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from edge import edges_encoded
from edge.camera import paper_camera
from edge.coverage import coverage_weights
from edge.edges_encoded import YCC_FROM_BGR, EdgeFit, edge_midpoint, fit_edges, side_profiles
from edge.edges_held import HeldEdges, fit_edges_held, hold
from edge.segmentation import LINEAR, dilate, erode
from edge.sim.effects import Compression, Effects, Optics, SignalProcessing
from edge.sim.render import Renderer
from edge.sim.scene import BLUE_BGR, EIGHT_HUES, GREEN_BGR, RED_BGR, RoverLook, Scene, marker_albedo_for_hue
from edge.sim.world import RoverState, WorldState
from edge.trackers.base import CameraPlaneMapping, PlaneGrid
from edge.trackers.plane import world_blob

BODIES = {"black": (0.035, 0.034, 0.032), "dark grey": (0.12, 0.12, 0.12), "white": (0.8, 0.8, 0.8)}
BLURS_PX = (0.5, 1.2)
STREAMS = (
    ("none", None),
    ("4:4:4", 100),
    ("4:4:4", 90),
    ("4:4:4", 70),
    ("4:2:2", 100),
    ("4:2:2", 90),
    ("4:2:2", 70),
    ("4:2:0", 100),
    ("4:2:0", 90),
    ("4:2:0", 70),
)
MARKER_CM = (21.5, 16.8)


def palette(name: str) -> dict[str, tuple[float, float, float]]:
    if name == "default":
        return {"red": RED_BGR, "green": GREEN_BGR, "blue": BLUE_BGR}
    return {hue_name: marker_albedo_for_hue(hue) for hue_name, hue in EIGHT_HUES}


ENCODED_RING_PX = 4
ENCODED_BAND_PX = (4, 7)


LUMA_BGR = np.array([0.114, 0.587, 0.299])  # BT.601, the luma JPEG and FFmpeg decode to
_ERF = np.vectorize(math.erf)


def encoded_affine(values: np.ndarray, core: np.ndarray) -> tuple[np.ndarray, float]:
    """The affine map ``share = values @ row + offset`` of the decoded B'G'R' (no tone curve undone): 1 at the
    core's mean, 0 at the darker and brighter halves of the band ``ENCODED_BAND_PX`` out (beyond the chroma's
    spread)."""
    band = dilate(core, ENCODED_BAND_PX[1]) & ~dilate(core, ENCODED_BAND_PX[0])
    brightness = values.sum(axis=2)
    cut = float(np.median(brightness[band]))
    marker = values[erode(core, 1)].mean(axis=0)
    dark = values[band & (brightness <= cut)].mean(axis=0)
    bright = values[band & (brightness >= cut)].mean(axis=0)
    a_vec, b_vec = marker - dark, bright - dark
    aa, ab = float(a_vec @ a_vec), float(a_vec @ b_vec)
    bb = float(b_vec @ b_vec) + 1e-3 * aa
    row = (a_vec * bb - b_vec * ab) / (aa * bb - ab * ab)
    return row, -float(dark @ row)


def encoded_shares(bgr: np.ndarray, core: np.ndarray) -> np.ndarray:
    """(h, w) float32 marker share by :func:`encoded_affine`, unclipped, over the core and a ``ENCODED_RING_PX``
    ring (the interior too: a sum-keeping spread moves share out of it as much as into the ring)."""
    values = bgr.astype(np.float32)
    row, offset = encoded_affine(values, core)
    affine = np.array([[*row, offset]], np.float32)
    return np.where(dilate(core, ENCODED_RING_PX), cv2.transform(values, affine), 0.0).astype(np.float32)


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """Linear light (0..1) -> 8-bit values through the sRGB curve (the inverse of the tracker's ``LINEAR``)."""
    v = np.clip(linear, 0.0, 1.0)
    return 255.0 * np.where(v <= 0.0031308, 12.92 * v, 1.055 * np.power(v, 1 / 2.4) - 0.055)


def model_coverage(
    shape: tuple[int, int], offset: tuple[int, int], centre_cm: tuple[float, float], theta: float, sigma_px: float
) -> np.ndarray:
    """(h, w) linear coverage of each pixel by the marker's rectangle at ``centre_cm`` (on the plane 13 cm up),
    blurred by a Gaussian of ``sigma_px`` (by the distance to the nearest side: corners are approximate)."""
    c, s = math.cos(theta), math.sin(theta)
    half = (MARKER_CM[0] / 2, MARKER_CM[1] / 2)
    corners = [(a * half[0], b * half[1]) for a, b in ((1, 1), (-1, 1), (-1, -1), (1, -1))]
    world = np.array([[centre_cm[0] + c * a - s * b, centre_cm[1] + s * a + c * b, 13.0] for a, b in corners])
    quad = paper_camera().project(world)
    vv, uu = np.mgrid[0 : shape[0], 0 : shape[1]]
    u, v = uu + offset[0], vv + offset[1]
    middle = quad.mean(axis=0)
    outside = np.full(shape, -np.inf)
    for k in range(4):
        p0, p1 = quad[k], quad[(k + 1) % 4]
        normal = np.array([p1[1] - p0[1], p0[0] - p1[0]]) / math.hypot(*(p1 - p0))
        if (middle - p0) @ normal > 0:
            normal = -normal
        outside = np.maximum(outside, (u - p0[0]) * normal[0] + (v - p0[1]) * normal[1])
    return 0.5 * (1.0 - _ERF(outside / (sigma_px * math.sqrt(2.0))))


def optics_weights(
    bgr: np.ndarray, core: np.ndarray, offset: tuple[int, int], grid: PlaneGrid, theta: float, blur_px: float
) -> np.ndarray:
    """Encoded shares plus the optics correction (module docstring), after two rounds of placing the model."""
    values = bgr.astype(np.float64)
    row, shift = encoded_affine(values.astype(np.float32), core)
    region = dilate(core, ENCODED_RING_PX)
    observed = np.where(region, values @ row + shift, 0.0)
    linear = LINEAR[bgr].astype(np.float64)
    marker = linear[erode(core, 1)].mean(axis=0)
    band = dilate(core, ENCODED_BAND_PX[1]) & ~dilate(core, ENCODED_BAND_PX[0])
    tint = linear[band].mean(axis=0)
    tint /= tint @ LUMA_BGR
    luma = values @ LUMA_BGR
    sigma_px = math.sqrt(blur_px**2 + 1.0 / 12.0)  # the lens's blur and the pixel's own aperture
    weights = observed.astype(np.float32)
    for _ in range(2):
        blob = world_blob(weights, offset, grid)
        assert blob is not None
        cover = model_coverage(core.shape, offset, (blob.x_cm, blob.y_cm), theta, sigma_px)
        mixed_marker = cover[..., None] * marker
        lo, hi = np.zeros(core.shape), np.full(core.shape, 2.0)
        for _ in range(24):  # the surround's level that gives the pixel's luma, by bisection
            mid = 0.5 * (lo + hi)
            below = srgb_encode(mixed_marker + (1 - cover)[..., None] * mid[..., None] * tint) @ LUMA_BGR < luma
            lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
        surround = 0.5 * (lo + hi)[..., None] * tint
        model = srgb_encode(mixed_marker + (1 - cover)[..., None] * surround) @ row + shift
        model -= (1 - cover) * (srgb_encode(surround) @ row + shift)  # the surround alone counts 0
        weights = np.where(region, observed + cover - model, 0.0).astype(np.float32)
    return weights


TONES = {
    "srgb": (edges_encoded.srgb_decode, edges_encoded.srgb_encode),
    "gamma2.2": (lambda v: np.clip(v, 0, 1) ** 2.2, lambda x: np.clip(x, 0, 1) ** (1 / 2.2)),
    "gamma2.0": (lambda v: np.clip(v, 0, 1) ** 2.0, lambda x: np.clip(x, 0, 1) ** (1 / 2.0)),
    "gamma2.4": (lambda v: np.clip(v, 0, 1) ** 2.4, lambda x: np.clip(x, 0, 1) ** (1 / 2.4)),
}
TONE = ["srgb"]
WEIGH = [False]  # --weigh-channels
SKIPPED: list[str] = []  # poses whose edge profiles did not reach the band beyond the spread


def half_crossings(profiles: list[edges_encoded.SideProfile], marker_ycc: np.ndarray) -> list[float]:
    """The simple variant: per side, where the chroma projected on the marker's chroma (relative to the band
    beyond the spread) first falls below half, from inside out (pixels along the normal)."""
    out = []
    for p in profiles:
        band = (p.u_px > edges_encoded.BAND_PX[0]) & (p.u_px < edges_encoded.BAND_PX[1])
        surround = p.ycc[band, 1:].mean(axis=0)
        direction = marker_ycc[1:] - surround
        q = (p.ycc[:, 1:] - surround) @ direction / float(direction @ direction)
        below = np.nonzero((q < 0.5) & (p.u_px > -edges_encoded.REACH_IN_PX + 1))[0]
        k = int(below[0]) if below.size else len(q) - 1
        if k == 0:
            out.append(float(p.u_px[0]))
            continue
        t = (q[k - 1] - 0.5) / (q[k - 1] - q[k])
        out.append(float(p.u_px[k - 1] + t * (p.u_px[k] - p.u_px[k - 1])))
    return out


def edge_centres(
    roi: np.ndarray,
    core: np.ndarray,
    offset: tuple[int, int],
    grid: PlaneGrid,
    start: tuple[float, float],
    th: float,
    held: HeldEdges | None = None,
) -> tuple[list[tuple[float, float]], EdgeFit] | None:
    """The simple variant (:func:`half_crossings`, no optics offset) and the fitted edge model's centres
    (``edge.edges_encoded``, tone curve ``--tone``), from the profiles around ``start`` (the default centre) along
    the true axis ``th``, and the full fit; with ``held`` also the centre on that held model (``edge.edges_held``;
    the start where it refuses), its time per marker (profiles and fit) in ``HELD_MS``; None where a side's profile
    does not reach the band beyond the spread."""
    h, w = core.shape
    xy = grid.xy_cm[:, offset[1] : offset[1] + h, offset[0] : offset[0] + w]
    tic = time.perf_counter()
    profiles = side_profiles(roi, xy, start, th, (MARKER_CM[0] / 2, MARKER_CM[1] / 2))
    if not all(edges_encoded.has_band(p) for p in profiles):
        return None
    held_fit = None
    marker_ycc = roi[erode(core, 2)].astype(np.float64).mean(axis=0) @ YCC_FROM_BGR.T
    if held is not None:
        held_fit = fit_edges_held(profiles, marker_ycc, held, *TONES[TONE[0]])
        HELD_MS.append(1e3 * (time.perf_counter() - tic))
    fit = fit_edges(profiles, marker_ycc, *TONES[TONE[0]], weigh_channels=WEIGH[0])
    centres = [edge_midpoint(start, th, u0, profiles) for u0 in (half_crossings(profiles, marker_ycc), fit.u0_px)]
    if held is not None:
        centres.append(start if held_fit is None else edge_midpoint(start, th, held_fit.u0_px, profiles))
        REFUSED.append(held_fit is None)
    return centres, fit


HELD_MS: list[float] = []
REFUSED: list[bool] = []


def centre_errors_cm(
    image: np.ndarray,
    pose: tuple[float, float, float],
    grid: PlaneGrid,
    blur_px: float | None,
    edges: bool = False,
    held: HeldEdges | None = None,
    fits: list[EdgeFit] | None = None,
) -> tuple[tuple[float, float], ...] | None:
    """(x, y) error of the default centre of the marker at ``pose`` in ``image``; with ``blur_px`` (the true blur)
    also of the encoded-share centre and of that centre with the optics correction; with ``edges`` of the half
    crossings and the fitted edges (and with ``held`` of the edges on that held model; the full fit is appended
    to ``fits`` when given)."""
    x, y, th = pose
    uv = paper_camera().project(np.array([[x, y, 13.0]]))[0]
    local = grid.at(*uv)
    assert local is not None
    _, _, su, sv = local.pixel_of(x, y)
    reach = 18.0
    x0, y0 = int(uv[0] - reach * su) - 6, int(uv[1] - reach * sv) - 6
    x1, y1 = int(uv[0] + reach * su) + 7, int(uv[1] + reach * sv) + 7
    xs, ys = grid.x_cm[y0:y1, x0:x1], grid.y_cm[y0:y1, x0:x1]
    along = (xs - x) * math.cos(th) + (ys - y) * math.sin(th)
    across = (ys - y) * math.cos(th) - (xs - x) * math.sin(th)
    core = (np.abs(along) < MARKER_CM[0] / 2) & (np.abs(across) < MARKER_CM[1] / 2)
    roi = np.ascontiguousarray(image[y0:y1, x0:x1])
    shares = [coverage_weights(roi, core, 2, pure=core)]
    if blur_px is not None:
        shares += [encoded_shares(roi, core), optics_weights(roi, core, (x0, y0), grid, th, blur_px)]
    errors = []
    for weights in shares:
        blob = world_blob(weights, (x0, y0), grid)
        assert blob is not None
        errors.append((blob.x_cm - x, blob.y_cm - y))
    if edges:
        start = (errors[0][0] + x, errors[0][1] + y)
        found = edge_centres(roi, core, (x0, y0), grid, start, th, held)
        if found is None and fits is not None:  # a pose to learn from, not one to measure
            return tuple(errors)
        if found is None:  # a side's profile does not reach its band beyond the spread (a pose by the floor's edge)
            return None
        centres, fit = found
        errors += [(ex - x, ey - y) for ex, ey in centres]
        if fits is not None:
            fits.append(fit)
    return tuple(errors)


def worst_colour(errors: np.ndarray, colour_of: list[str]) -> tuple[float, str]:
    """The largest per-colour mean |(x, y)| of (N, 2) ``errors`` and its colour."""
    means = {c: errors[[k == c for k in colour_of]].mean(axis=0) for c in dict.fromkeys(colour_of)}
    worst = max(means, key=lambda c: float(np.hypot(*means[c])))
    return float(np.hypot(*means[worst])), worst


def print_edges_row(name: str, centre: str, every: np.ndarray, colour_of: list[str], body_of: list[str]) -> None:
    """One row of the ``--centre edges`` table: (N, 2) ``every`` errors of one centre on one stream."""
    bias = every.mean(axis=0)
    worst = worst_colour(every, colour_of)
    groups = list(dict.fromkeys(body_of))
    per_group = {}
    for g in groups:
        pick = [b == g for b in body_of]
        per_group[g] = worst_colour(every[pick], [c for c, k in zip(colour_of, pick, strict=True) if k])
    worst_group = max(groups, key=lambda g: per_group[g][0])
    by_group = ", ".join(f"{every[[b == g for b in body_of]].mean(axis=0)[1]:+.3f}" for g in groups)
    cells = [
        name,
        centre,
        f"{bias[0]:+.3f}, {bias[1]:+.3f}",
        f"{float(np.hypot(*every.T).mean()):.3f}",
        f"{worst[0]:.3f} ({worst[1]})",
        f"{per_group[worst_group][0]:.3f} ({worst_group}, {per_group[worst_group][1]})",
        by_group,
    ]
    print("| " + " | ".join(cells) + " |", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--poses", type=int, default=4, help="random poses per body, blur and colour")
    parser.add_argument("--seed", type=int, default=2000)
    parser.add_argument("--palette", choices=("default", "eight"), default="default")
    parser.add_argument("--centre", choices=("linear", "encoded", "edges"), default="linear")
    parser.add_argument("--streams", default="", help="only these rows, e.g. 'none,4:2:0 q90' (default: all)")
    parser.add_argument("--tone", choices=tuple(TONES), default="srgb", help="the edge model's assumed tone curve")
    parser.add_argument("--margins", default="1.0", help="the body's top around the marker, cm (comma-separated)")
    parser.add_argument(
        "--held",
        type=int,
        default=0,
        help="with --centre edges: also the edges on a model held from this many full fits of other poses",
    )
    parser.add_argument("--sharpen", type=float, default=0.0, help="the camera's luma sharpening (0: none)")
    parser.add_argument("--weigh-channels", action="store_true", help="the edge fits' second fit (edge.edges_encoded)")
    args = parser.parse_args()
    TONE[0], WEIGH[0] = args.tone, args.weigh_channels
    processing = SignalProcessing(demosaic=None, sharpen=args.sharpen) if args.sharpen > 0 else None
    grid = PlaneGrid(CameraPlaneMapping(paper_camera()), (1280, 720))
    colours = palette(args.palette)
    rng = np.random.default_rng(args.seed)
    poses = [
        (float(rng.uniform(40, 380)), float(rng.uniform(60, 520)), float(rng.uniform(-math.pi, math.pi)))
        for _ in range(args.poses)
    ]
    encoded, edges = args.centre == "encoded", args.centre == "edges"
    calibration_rng = np.random.default_rng(args.seed + 1)  # other poses than the measured ones
    margins = [float(m) for m in args.margins.split(",")]
    print(f"# edge-ips chroma bias on static poses, {time.strftime('%Y-%m-%d %H:%M')}\n")
    print(
        f"{args.poses} poses (seed {args.seed}) x bodies {', '.join(BODIES)} x margins {margins} cm x blur "
        f"{BLURS_PX} px x {args.palette}"
        + (f"; luma sharpened {args.sharpen:g}" if args.sharpen > 0 else "")
        + ("; edge fits weigh the luma by their residuals" if args.weigh_channels else "")
    )
    if edges:
        print("palette; exact interior mask, true axis; the default centre, half crossings and the fitted edges.\n")
        print(
            "| stream | centre | bias x, y cm (all) | mean error cm | worst colour bias cm | worst body/margin "
            "colour bias cm | bias y per body/margin |"
        )
        print("|---|---|---|---|---|---|---|")
    elif encoded:
        print("palette; exact interior mask; the encoded-share centre and it with the optics correction (true blur).\n")
        print(
            "| stream | centre | bias x, y cm (all) | mean error cm | worst colour bias cm | bias y: black, dark "
            "grey, white | moved from uncompressed: mean y, worst colour, max cm | ceiling: worst colour bias, mean "
            "error cm |"
        )
        print("|---|---|---|---|---|---|---|---|")
    else:
        print("palette; exact interior mask; the default centre (linear-light coverage centroid).\n")
        print(
            "| stream | bias x, y cm (all) | mean error cm | worst colour bias cm | black body bias y "
            "| white body bias y |"
        )
        print("|---|---|---|---|---|---|")
    uncompressed: np.ndarray | None = None
    wanted = [w.strip() for w in args.streams.split(",") if w.strip()]
    for chroma, quality in STREAMS:
        if wanted and ("none" if quality is None else f"{chroma} q{quality}") not in wanted:
            continue
        body_of: list[str] = []
        colour_of: list[str] = []
        measured: list[tuple[tuple[float, float], ...]] = []
        for body, margin, blur, colour in itertools.product(BODIES, margins, BLURS_PX, colours):
            look = RoverLook(
                "r",
                colours[colour],
                body_bgr=BODIES[body],
                body_length_cm=MARKER_CM[0] + 2 * margin,
                body_width_cm=MARKER_CM[1] + 2 * margin,
            )
            compression = None if quality is None else Compression(quality, chroma)
            effects = Effects(
                auto_exposure=None,
                noise=None,
                motion_blur=False,
                optics=Optics(blur),
                compression=compression,
                processing=processing,
            )
            renderer = Renderer(paper_camera(), Scene((look,)), effects)
            held = None
            if edges and args.held:  # the same rover and camera on other poses, its heading as found there
                fits: list[EdgeFit] = []
                while len(fits) < args.held:
                    pose = (
                        float(calibration_rng.uniform(40, 380)),
                        float(calibration_rng.uniform(60, 520)),
                        float(calibration_rng.uniform(-math.pi, math.pi)),
                    )
                    image = renderer.render(WorldState(0.0, (RoverState("r", *pose, 0.0, 0.0, 0.0),)), 0)
                    centre_errors_cm(image, pose, grid, None, True, fits=fits)
                held = hold(fits)
            for pose in poses:
                image = renderer.render(WorldState(0.0, (RoverState("r", *pose, 0.0, 0.0, 0.0),)), 0)
                errors_cm = centre_errors_cm(image, pose, grid, blur if encoded else None, edges, held)
                if errors_cm is None:
                    SKIPPED.append(f"{body} {margin:g} blur {blur:g} {colour} at {pose[0]:.0f}, {pose[1]:.0f}")
                    continue
                measured.append(errors_cm)
                body_of.append(f"{body} {margin:g}" if edges else body)
                colour_of.append(colour)
        errors = np.array(measured)  # (N, centres, 2)
        if uncompressed is None:
            uncompressed = errors
        name = "none" if quality is None else f"{chroma} q{quality}"
        if edges:
            for k, centre in enumerate(("linear", "half", "edges", "held")[: errors.shape[1]]):
                print_edges_row(name, centre, errors[:, k], colour_of, body_of)
            continue
        centres = ("encoded", "optics") if encoded else ("linear",)
        for k, centre in enumerate(centres, start=len(errors[0]) - len(centres)):
            every = errors[:, k]
            bias = every.mean(axis=0)
            worst = worst_colour(every, colour_of)
            by_body = {b: every[[i == b for i in body_of]].mean(axis=0)[1] for b in BODIES}
            cells = [
                name,
                f"{bias[0]:+.3f}, {bias[1]:+.3f}",
                f"{float(np.hypot(*every.T).mean()):.3f}",
                f"{worst[0]:.3f} ({worst[1]})",
            ]
            if not encoded:
                print("| " + " | ".join([*cells, f"{by_body['black']:+.3f}", f"{by_body['white']:+.3f}"]) + " |")
                continue
            moved = every - uncompressed[:, k]
            moved_worst = worst_colour(moved, colour_of)
            ceiling = "-"
            if centre == "encoded":  # the uncompressed frame's optics offset taken off exactly
                exact = worst_colour(uncompressed[:, 0] + moved, colour_of)
                ceiling = f"{exact[0]:.3f} ({exact[1]}), {float(np.hypot(*(uncompressed[:, 0] + moved).T).mean()):.3f}"
            cells.insert(1, centre)
            cells += [
                f"{by_body['black']:+.3f}, {by_body['dark grey']:+.3f}, {by_body['white']:+.3f}",
                f"{moved[:, 1].mean():+.3f}, {moved_worst[0]:.3f} ({moved_worst[1]}), "
                f"{float(np.hypot(*moved.T).max()):.2f}",
                ceiling,
            ]
            print("| " + " | ".join(cells) + " |")
    if SKIPPED:
        print(f"\nnot measured ({len(SKIPPED)}: a side's profile short of its band): " + "; ".join(SKIPPED))
    if HELD_MS:
        print(
            f"\nheld model ({args.held} full fits of other poses per rover and camera): {sum(REFUSED)} of "
            f"{len(REFUSED)} refused (the default centre kept); per marker (profiles and fit) median "
            f"{float(np.median(HELD_MS)):.2f} ms, p95 {float(np.percentile(HELD_MS, 95)):.2f} ms "
            "(to re-run on a quiet machine)"
        )


if __name__ == "__main__":
    main()
