"""Synthetic calibration inputs, made the way a person would make them, with exact ground truth.

- :func:`survey_points`: points surveyed on a 30 cm grid at marker height, their pixels measured with noise.
- :func:`checkerboard_views`: photos of a printed checkerboard held in front of the camera (for intrinsics).
- :func:`aruco_floor_frame`: one frame of ArUco markers laid flat at known floor positions, plus the markers table.

Rendering is sub-pixel exact: every pixel's centre is traced through the lens model (distortion inverted
numerically) onto the target's plane; pixels whose footprint crosses an edge of the pattern are supersampled 16x16
with the pixel's local Jacobian, so edges land where the geometry puts them, to about 1/100 px. A mild optical blur
and sensor noise follow.

Measuring noise ``noise_px`` is the RMS *radial* error of a measured pixel position: sigma = noise_px / sqrt(2) on
each axis.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from edge.calibration.points import write_points_csv
from edge.calibration.survey import grid_candidates, plan_survey
from edge.camera import AREA_LENGTH_CM, AREA_WIDTH_CM, MARKER_HEIGHT_CM, PinholeCamera
from edge.errors import SimulationError

FloatArray = NDArray[np.float64]
AreaCm = tuple[float, float, float, float]

PAPER_AREA: AreaCm = (0.0, 0.0, AREA_WIDTH_CM, AREA_LENGTH_CM)
SUPERSAMPLE = 16
BLUR_SIGMA_PX = 0.6
SENSOR_NOISE_DN = 1.5

__all__ = [
    "PAPER_AREA",
    "ArucoFrame",
    "CheckerboardViews",
    "SurveyPoints",
    "aruco_floor_frame",
    "check_points",
    "checkerboard_views",
    "survey_layout",
    "survey_points",
    "survey_target_frame",
    "targets_apart",
    "write_markers_csv",
    "write_points_csv",
]


# -- survey points ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SurveyPoints:
    """``uv_px``: (N, 2) measured pixels (with noise, as the lens shows them); ``xy_world_cm``: (N, 2) surveyed
    positions; ``uv_true_px``: (N, 2) the exact pixels; ``height_cm``: the plane they were surveyed on."""

    uv_px: FloatArray
    xy_world_cm: FloatArray
    uv_true_px: FloatArray
    height_cm: float

    def write_csv(self, path: Path) -> None:
        write_points_csv(path, self.uv_px, self.xy_world_cm)


def _camera_key(camera: PinholeCamera) -> tuple[float, ...]:
    return (
        *camera.camera_matrix.ravel().tolist(),
        *camera.dist_coeffs.tolist(),
        *camera.rvec.tolist(),
        *camera.tvec.tolist(),
        float(camera.width_px),
        float(camera.height_px),
    )


def survey_layout(
    camera: PinholeCamera,
    n: int = 34,
    grid_cm: float = 30.0,
    height_cm: float = MARKER_HEIGHT_CM,
    area_cm: AreaCm = PAPER_AREA,
) -> FloatArray:
    """(n, 2) world cm: the grid points to survey, chosen to minimise the worst predicted error over the area
    (see :func:`edge.calibration.survey.plan_survey`): the far edge and the sides, where resolution is lowest."""
    key = (_camera_key(camera), n, grid_cm, height_cm, area_cm)
    if key not in _LAYOUTS:
        _LAYOUTS[key] = _survey_layout(camera, n, grid_cm, height_cm, area_cm)
    return _LAYOUTS[key].copy()


_LAYOUTS: dict[object, FloatArray] = {}
_IDEAL_GRIDS: dict[tuple[float, ...], FloatArray] = {}


def _survey_layout(camera: PinholeCamera, n: int, grid_cm: float, height_cm: float, area_cm: AreaCm) -> FloatArray:
    x0, y0, x1, y1 = area_cm
    cand = grid_candidates(x1 - x0, y1 - y0, grid_cm) + np.array([x0, y0])
    xyz = np.column_stack([cand, np.full(cand.shape[0], height_cm)])
    uv = camera.project(xyz)
    visible = (
        camera.in_front(xyz)
        & (uv[:, 0] >= 2.0)
        & (uv[:, 0] <= camera.width_px - 3.0)
        & (uv[:, 1] >= 2.0)
        & (uv[:, 1] <= camera.height_px - 3.0)
    )
    cand = cand[visible]
    if cand.shape[0] < n:
        raise SimulationError(f"only {cand.shape[0]} grid points of the area are in view, {n} wanted")
    idx = plan_survey(camera.plane_homography(height_cm), cand, area_cm, n)
    return cand[idx]


def survey_points(
    camera: PinholeCamera,
    n: int = 34,
    grid_cm: float = 30.0,
    height_cm: float = MARKER_HEIGHT_CM,
    noise_px: float = 0.5,
    rng: np.random.Generator | int | None = None,
    area_cm: AreaCm = PAPER_AREA,
) -> SurveyPoints:
    """``n`` points on a ``grid_cm`` grid at ``height_cm``, in the G-optimal layout, measured with ``noise_px`` RMS."""
    gen = np.random.default_rng(rng)
    xy = survey_layout(camera, n, grid_cm, height_cm, area_cm)
    return _measure(camera, xy, height_cm, noise_px, gen)


def check_points(
    camera: PinholeCamera,
    n: int = 20,
    height_cm: float = MARKER_HEIGHT_CM,
    noise_px: float = 0.5,
    rng: np.random.Generator | int | None = None,
    area_cm: AreaCm = PAPER_AREA,
) -> SurveyPoints:
    """``n`` independent check points anywhere in the area (not on the survey grid), measured with noise."""
    gen = np.random.default_rng(rng)
    x0, y0, x1, y1 = area_cm
    xy = np.column_stack([gen.uniform(x0, x1, n), gen.uniform(y0, y1, n)])
    return _measure(camera, xy, height_cm, noise_px, gen)


def _measure(
    camera: PinholeCamera, xy: FloatArray, height_cm: float, noise_px: float, gen: np.random.Generator
) -> SurveyPoints:
    xyz = np.column_stack([xy, np.full(xy.shape[0], height_cm)])
    true_uv = camera.project(xyz)
    noisy = true_uv + gen.normal(0.0, noise_px / math.sqrt(2.0), true_uv.shape)
    return SurveyPoints(noisy, xy.copy(), true_uv, height_cm)


TARGET_CELL_CM = 7.0  # a survey target's squares: a 2 x 2 checker 14 cm wide on a 21 cm card (an A4 sheet)


def survey_target_frame(
    camera: PinholeCamera,
    xy_world_cm: FloatArray,
    height_cm: float = MARKER_HEIGHT_CM,
    cell_cm: float = TARGET_CELL_CM,
    rng: np.random.Generator | int | None = None,
) -> NDArray[np.uint8]:
    """One photo of the survey's printed targets in place: at each point ``xy_world_cm`` (N, 2) on the plane
    ``height_cm``, a 2 x 2 checker of ``cell_cm`` squares (dark at the near left and the far right) on a white card
    half a square wider each way, its X-corner on the point, over a mid-grey floor (``edge.calibration.refine``)."""
    gen = np.random.default_rng(rng)
    image = np.full((camera.height_px, camera.width_px), 95.0)
    g = camera.plane_homography(height_cm)
    cells = np.full((6, 6), 230.0)  # half squares: the card's margin is one of them
    cells[1:3, 1:3] = cells[3:5, 3:5] = 25.0
    c = cell_cm / 2.0
    for x, y in np.asarray(xy_world_cm, np.float64).reshape(-1, 2):
        card = np.array([[c, 0.0, x - 3.0 * c], [0.0, -c, y + 3.0 * c], [0.0, 0.0, 1.0]])  # cells -> plane cm
        _render_cells(image, camera, g @ card, cells)
    return _finish(image, gen)


def targets_apart(xy_world_cm: FloatArray, cell_cm: float = TARGET_CELL_CM) -> NDArray[np.bool_]:
    """(N,) which of the points can carry a printed target: those a card's width (3 squares) or more from every other
    (two cards cannot lie on one spot; random check points may fall closer)."""
    xy = np.asarray(xy_world_cm, np.float64).reshape(-1, 2)
    gap = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
    np.fill_diagonal(gap, np.inf)
    return np.asarray(gap.min(axis=1, initial=np.inf) >= 3.0 * cell_cm)


# -- rendering of planar cell patterns ------------------------------------------------------------------------------
def _ideal_grid(camera: PinholeCamera) -> FloatArray:
    """(H, W, 2) the ideal (undistorted) pixel of every pixel centre (cached for the last few cameras)."""
    key = _camera_key(camera)
    if key not in _IDEAL_GRIDS:
        u, v = np.meshgrid(np.arange(camera.width_px, dtype=np.float64), np.arange(camera.height_px, dtype=np.float64))
        uv = np.column_stack([u.ravel(), v.ravel()])
        if len(_IDEAL_GRIDS) >= 4:
            _IDEAL_GRIDS.pop(next(iter(_IDEAL_GRIDS)))
        _IDEAL_GRIDS[key] = camera.undistort_px(uv).reshape(camera.height_px, camera.width_px, 2)
    return _IDEAL_GRIDS[key]


def _render_cells(
    image: FloatArray,
    camera: PinholeCamera,
    h_cells_to_ideal: FloatArray,
    cells: FloatArray,
) -> None:
    """Paint a grid of square cells (``cells[j, i]`` = intensity of cell column i, row j; cell (i, j) spans
    ``[i, i+1] x [j, j+1]`` in cell coordinates) onto ``image`` (H, W) in place, with exact edge coverage."""
    ny, nx = cells.shape
    grid_corners = np.array([[0.0, 0.0], [nx, 0.0], [nx, ny], [0.0, ny]])
    ideal_c = _apply(h_cells_to_ideal, grid_corners)
    if np.any(_w(h_cells_to_ideal, grid_corners) <= 0):
        raise SimulationError("the pattern is (partly) behind the camera")
    # the lens may bend edges outward, so take the distorted bbox of densely sampled outline points
    t = np.linspace(0.0, 1.0, 33)
    outline = np.vstack([ideal_c[k] + (ideal_c[(k + 1) % 4] - ideal_c[k]) * t[:, None] for k in range(4)])
    distorted = camera.project(_ideal_to_rays(camera, outline)) if camera.has_distortion else outline
    h, w = image.shape
    u0 = max(math.floor(distorted[:, 0].min()) - 3, 0)
    u1 = min(math.ceil(distorted[:, 0].max()) + 4, w)
    v0 = max(math.floor(distorted[:, 1].min()) - 3, 0)
    v1 = min(math.ceil(distorted[:, 1].max()) + 4, h)
    if u0 >= u1 or v0 >= v1:
        return
    ideal = _ideal_grid(camera)[v0:v1, u0:u1]
    inv = np.linalg.inv(h_cells_to_ideal)
    b = _apply(inv, ideal.reshape(-1, 2)).reshape(v1 - v0, u1 - u0, 2)
    db_du: FloatArray = np.asarray(np.gradient(b, axis=1))
    db_dv: FloatArray = np.asarray(np.gradient(b, axis=0))
    ext = 0.5 * (np.abs(db_du) + np.abs(db_dv))  # half-extent of the pixel footprint along cell x and y
    bx, by = b[..., 0], b[..., 1]
    region = image[v0:v1, u0:u1]
    inside = (bx >= 0) & (bx < nx) & (by >= 0) & (by < ny)
    ix = np.clip(np.floor(bx).astype(np.int64), 0, nx - 1)
    iy = np.clip(np.floor(by).astype(np.int64), 0, ny - 1)
    centre_val = np.where(inside, cells[iy, ix], region)
    near_x = np.abs(bx - np.round(bx)) <= ext[..., 0] * 1.01
    near_y = np.abs(by - np.round(by)) <= ext[..., 1] * 1.01
    in_reach = (bx > -ext[..., 0]) & (bx < nx + ext[..., 0]) & (by > -ext[..., 1]) & (by < ny + ext[..., 1])
    edge = (near_x | near_y) & in_reach
    out = centre_val.copy()
    ev, eu = np.nonzero(edge)
    offs = (np.arange(SUPERSAMPLE) + 0.5) / SUPERSAMPLE - 0.5
    du, dv = (a.ravel() for a in np.meshgrid(offs, offs))
    for start in range(0, ev.size, 4096):
        sv, su = ev[start : start + 4096], eu[start : start + 4096]
        sbx = bx[sv, su][:, None] + db_du[sv, su, 0][:, None] * du + db_dv[sv, su, 0][:, None] * dv
        sby = by[sv, su][:, None] + db_du[sv, su, 1][:, None] * du + db_dv[sv, su, 1][:, None] * dv
        sin = (sbx >= 0) & (sbx < nx) & (sby >= 0) & (sby < ny)
        jx = np.clip(np.floor(sbx).astype(np.int64), 0, nx - 1)
        jy = np.clip(np.floor(sby).astype(np.int64), 0, ny - 1)
        vals = np.where(sin, cells[jy, jx], region[sv, su][:, None])
        out[sv, su] = vals.mean(axis=1)
    region[...] = out


def _apply(h: NDArray[np.floating[Any]], xy: FloatArray) -> FloatArray:
    q = xy @ h[:, :2].T + h[:, 2]
    return np.asarray(q[:, :2] / q[:, 2:3])


def _w(h: FloatArray, xy: FloatArray) -> FloatArray:
    return np.asarray(xy @ h[2, :2] + h[2, 2])


def _ideal_to_rays(camera: PinholeCamera, ideal: FloatArray) -> FloatArray:
    """Ideal pixels -> world points on their rays (for re-projection through the lens)."""
    k_inv = np.linalg.inv(camera.camera_matrix)
    rays_cam = np.column_stack([ideal, np.ones(ideal.shape[0])]) @ k_inv.T
    return np.asarray(camera.position_cm + (rays_cam * 100.0) @ camera.rotation)


def _finish(image: FloatArray, gen: np.random.Generator) -> NDArray[np.uint8]:
    """Optics and sensor: a mild symmetric blur, Gaussian noise, 8-bit BGR."""
    blurred = cv2.GaussianBlur(image, (0, 0), BLUR_SIGMA_PX)
    noisy = blurred + gen.normal(0.0, SENSOR_NOISE_DN, blurred.shape)
    gray = np.clip(np.round(noisy), 0, 255).astype(np.uint8)
    return np.asarray(cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR))


# -- checkerboard views -----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CheckerboardViews:
    """``images``: BGR uint8 photos; ``board``: inner corners (columns, rows); ``square_cm``; ``board_poses``:
    (rvec, tvec) board -> camera per image (board origin at its first inner corner, z into the board)."""

    images: tuple[NDArray[np.uint8], ...]
    board: tuple[int, int]
    square_cm: float
    board_poses: tuple[tuple[FloatArray, FloatArray], ...]

    def write(self, directory: Path, stem: str = "board") -> list[Path]:
        directory.mkdir(parents=True, exist_ok=True)
        paths = []
        for k, img in enumerate(self.images):
            p = directory / f"{stem}_{k:02d}.png"
            cv2.imwrite(str(p), img)
            paths.append(p)
        return paths


def checkerboard_views(
    camera: PinholeCamera,
    board: tuple[int, int] = (9, 6),
    square_cm: float = 2.5,
    n_views: int = 14,
    rng: np.random.Generator | int | None = None,
    distance_cm: tuple[float, float] = (40.0, 65.0),
) -> CheckerboardViews:
    """Photos of a ``board`` (inner corners) checkerboard with ``square_cm`` squares and a one-square white margin,
    held at ``distance_cm`` in front of the camera, tilted up to 40 degrees, placed to cover the whole image (the
    corners of the image too, where distortion is strongest) as a careful person would."""
    gen = np.random.default_rng(rng)
    cols, rows = board
    nx, ny = cols + 3, rows + 3  # squares plus a one-square white margin on each side
    cells = np.full((ny, nx), 225.0)
    for j in range(rows + 1):
        for i in range(cols + 1):
            cells[j + 1, i + 1] = 30.0 if (i + j) % 2 == 0 else 225.0
    k = camera.camera_matrix
    w, h = camera.width_px, camera.height_px
    # targets: a 4 x 3 grid over the image, then the centre
    targets = [(fu * w, fv * h) for fv in (0.2, 0.5, 0.8) for fu in (0.15, 0.38, 0.62, 0.85)]
    targets += [(0.5 * w, 0.5 * h)] * max(0, n_views - len(targets))
    images: list[NDArray[np.uint8]] = []
    poses: list[tuple[FloatArray, FloatArray]] = []
    for view in range(n_views):
        tu, tv = targets[view % len(targets)]
        for attempt in range(200):
            pull = attempt / 200.0  # a board too big for the corner is moved toward the centre, as a person would
            tu_a, tv_a = tu + (0.5 * w - tu) * pull, tv + (0.5 * h - tv) * pull
            d = gen.uniform(*distance_cm)
            axis_angle = gen.uniform(0.0, 2.0 * math.pi)
            tilt = math.radians(gen.uniform(10.0, 40.0))
            spin = math.radians(gen.uniform(-25.0, 25.0))
            r_tilt = cv2.Rodrigues(np.array([math.cos(axis_angle), math.sin(axis_angle), 0.0]) * tilt)[0]
            r_spin = cv2.Rodrigues(np.array([0.0, 0.0, spin]))[0]
            rot = r_tilt @ r_spin
            jitter = gen.normal(0.0, 0.03, 2) * np.array([w, h])
            ray = np.linalg.inv(k) @ np.array([tu_a + jitter[0], tv_a + jitter[1], 1.0])
            centre = ray / ray[2] * d
            # board frame: origin at the first inner corner; cell (i, j) corner at ((i - 2) s, (j - 2) s)
            t = centre - rot @ np.array([(cols - 1) * square_cm / 2.0, (rows - 1) * square_cm / 2.0, 0.0])
            h_board = k @ np.column_stack([rot[:, 0], rot[:, 1], t])
            h_cells = h_board @ np.array(
                [[square_cm, 0.0, -2.0 * square_cm], [0.0, square_cm, -2.0 * square_cm], [0, 0, 1]]
            )
            corners_cells = np.array([[0.0, 0.0], [nx, 0.0], [nx, ny], [0.0, ny]])
            if np.any(_w(h_cells, corners_cells) <= 0):
                continue
            outline = _apply(h_cells, corners_cells)
            seen = camera.project(_ideal_to_rays(camera, outline)) if camera.has_distortion else outline
            if np.all((seen[:, 0] > 4) & (seen[:, 0] < w - 5) & (seen[:, 1] > 4) & (seen[:, 1] < h - 5)):
                break
        else:
            raise SimulationError(f"cannot place the board for view {view} inside the image")
        background = 110.0 + 25.0 * np.sin(np.linspace(0, 3.0, w))[None, :] * np.cos(np.linspace(0, 2.0, h))[:, None]
        image = np.array(background, dtype=np.float64)
        _render_cells(image, camera, h_cells, cells)
        images.append(_finish(image, gen))
        poses.append((np.asarray(cv2.Rodrigues(rot)[0], dtype=np.float64).ravel(), t))
    return CheckerboardViews(tuple(images), board, square_cm, tuple(poses))


# -- ArUco floor frame ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ArucoFrame:
    """``image``: BGR uint8; ``markers``: (M, 5) id, x, y, z (centre, cm), size (black square side, cm);
    ``dictionary``: the OpenCV predefined dictionary name."""

    image: NDArray[np.uint8]
    markers: FloatArray
    dictionary: str


DEFAULT_MARKER_GRID: tuple[tuple[float, float], ...] = tuple(
    (x, y) for y in (45.0, 190.0, 340.0, 500.0) for x in (45.0, 195.75, 346.5)
)


def aruco_floor_frame(
    camera: PinholeCamera,
    positions_cm: tuple[tuple[float, float], ...] = DEFAULT_MARKER_GRID,
    size_cm: float = 25.0,
    z_cm: float = 0.0,
    dictionary: str = "DICT_4X4_50",
    rng: np.random.Generator | int | None = None,
) -> ArucoFrame:
    """A frame of ArUco markers printed ``size_cm`` wide, laid flat at ``positions_cm`` on the plane ``z_cm``
    (default: the floor), each upright with its top edge toward +y (the far side of the area)."""
    gen = np.random.default_rng(rng)
    aruco_dict = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    image = np.full((camera.height_px, camera.width_px), 95.0)
    rows = []
    g = camera.plane_homography(z_cm)
    for marker_id, (x, y) in enumerate(positions_cm):
        bits = cv2.aruco.generateImageMarker(aruco_dict, marker_id, 6, borderBits=1)
        cells = np.pad(np.where(bits > 127, 230.0, 25.0), 1, constant_values=230.0)
        c = size_cm / 6.0
        h_cells = g @ np.array([[c, 0.0, x - 4.0 * c], [0.0, -c, y + 4.0 * c], [0.0, 0.0, 1.0]])
        _render_cells(image, camera, h_cells, cells)
        rows.append((marker_id, x, y, z_cm, size_cm))
    return ArucoFrame(_finish(image, gen), np.asarray(rows, dtype=np.float64), dictionary)


def write_markers_csv(path: Path, markers: FloatArray) -> None:
    """Write the markers table ``id,x,y,z,size`` (centre and black-square side in cm)."""
    lines = ["id,x,y,z,size"] + [f"{int(m[0])},{m[1]:.2f},{m[2]:.2f},{m[3]:.2f},{m[4]:.2f}" for m in markers]
    path.write_text("\n".join(lines) + "\n")
