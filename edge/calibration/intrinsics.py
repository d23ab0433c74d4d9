"""Lens intrinsics from checkerboard photos (OpenCV camera calibration), and their versioned JSON file.

``cv2.findChessboardCorners`` + ``cv2.cornerSubPix`` per photo, then ``cv2.calibrateCamera`` with the 5-coefficient
model (``k1, k2, p1, p2, k3``). The result is used to undistort measured *points* only, never frames.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from edge.calibration.lens import Intrinsics
from edge.camera import Distortion, ImageSide, Matrix3x3
from edge.errors import CalibrationError, describe_validation

FloatArray = NDArray[np.float64]

KIND = "edge-ips/intrinsics"
VERSION = 1
MIN_VIEWS = 5
SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-4)
FIND_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE


def read_image(path: Path) -> NDArray[np.uint8]:
    """A BGR image from disk, or a :class:`CalibrationError` naming the file."""
    if not path.is_file():
        raise CalibrationError(f"{path}: image not found")
    data = np.fromfile(str(path), dtype=np.uint8)
    image = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
    if image is None:
        raise CalibrationError(f"{path}: cannot read image (not a PNG/JPEG/... OpenCV can decode)")
    return np.asarray(image)


def parse_board(text: str) -> tuple[int, int]:
    """``"9x6"`` -> (9, 6): inner corners per row and per column."""
    parts = text.lower().replace(" ", "").split("x")
    try:
        cols, rows = (int(p) for p in parts)
    except ValueError:
        raise CalibrationError(f"board {text!r}: expected inner corners as COLSxROWS, e.g. 9x6") from None
    if cols < 2 or rows < 2:
        raise CalibrationError(f"board {text!r}: needs at least 2x2 inner corners")
    return cols, rows


def board_object_points(board: tuple[int, int], square_cm: float) -> FloatArray:
    """(cols*rows, 3) inner-corner positions on the board plane (cm), in findChessboardCorners' order."""
    cols, rows = board
    obj = np.zeros((cols * rows, 3), dtype=np.float64)
    obj[:, :2] = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * square_cm
    return obj


def find_board(image: NDArray[np.uint8], board: tuple[int, int]) -> FloatArray | None:
    """(cols*rows, 2) sub-pixel inner corners, or None when the board is not found."""
    gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    found, corners = cv2.findChessboardCorners(gray, board, flags=FIND_FLAGS)
    if not found:
        return None
    refined = cv2.cornerSubPix(gray, corners.astype(np.float32), (5, 5), (-1, -1), SUBPIX_CRITERIA)
    return np.asarray(refined.reshape(-1, 2), dtype=np.float64)


@dataclass(frozen=True)
class IntrinsicsResult:
    """``rms_px``: reprojection RMS of all corners; ``per_view_rms_px``: per used image; ``skipped``: (name, reason)."""

    intrinsics: Intrinsics
    rms_px: float
    used: tuple[str, ...]
    per_view_rms_px: tuple[float, ...]
    skipped: tuple[tuple[str, str], ...]
    board: tuple[int, int]
    square_cm: float


def calibrate_intrinsics(
    images: Iterable[tuple[str, NDArray[np.uint8]]],
    board: tuple[int, int],
    square_cm: float,
    *,
    allow_missing: bool = False,
) -> IntrinsicsResult:
    """Intrinsics from photos of a checkerboard with ``board`` inner corners and ``square_cm`` squares.

    A photo where the board is not found is an error naming it, unless ``allow_missing`` (then it is skipped and
    reported); at least :data:`MIN_VIEWS` photos with the board are needed either way.
    """
    if square_cm <= 0 or not np.isfinite(square_cm):
        raise CalibrationError(f"square size must be a positive number of cm, got {square_cm}")
    size: tuple[int, int] | None = None
    obj = board_object_points(board, square_cm).astype(np.float32)
    obj_points, img_points, used = [], [], []
    skipped: list[tuple[str, str]] = []
    for name, image in images:
        h, w = image.shape[:2]
        if size is None:
            size = (w, h)
        elif size != (w, h):
            raise CalibrationError(f"{name}: image is {w}x{h} but the first image is {size[0]}x{size[1]}")
        corners = find_board(image, board)
        if corners is None:
            reason = f"no {board[0]}x{board[1]} checkerboard found"
            if not allow_missing:
                raise CalibrationError(f"{name}: {reason} (check --board, lighting and focus; or --allow-missing)")
            skipped.append((name, reason))
            continue
        obj_points.append(obj)
        img_points.append(corners.astype(np.float32).reshape(-1, 1, 2))
        used.append(name)
    if len(used) < MIN_VIEWS:
        raise CalibrationError(
            f"board found in {len(used)} image(s), need at least {MIN_VIEWS} (not found in: "
            f"{', '.join(n for n, _ in skipped) or 'none'})"
        )
    if size is None:  # unreachable: images is not empty
        raise CalibrationError("no checkerboard images given")
    rms, k, dist, rvecs, tvecs = cv2.calibrateCamera(obj_points, img_points, size, None, None)
    per_view = []
    for o, im, rv, tv in zip(obj_points, img_points, rvecs, tvecs, strict=True):
        proj, _ = cv2.projectPoints(o, rv, tv, k, dist)
        per_view.append(float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - im.reshape(-1, 2)) ** 2, axis=1)))))
    intr = Intrinsics(np.asarray(k, dtype=np.float64), np.asarray(dist, dtype=np.float64).ravel()[:5], size[0], size[1])
    return IntrinsicsResult(intr, float(rms), tuple(used), tuple(per_view), tuple(skipped), board, float(square_cm))


class IntrinsicsFile(BaseModel):
    """On-disk intrinsics, ``kind`` ``edge-ips/intrinsics``, ``version`` 1."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    kind: Literal["edge-ips/intrinsics"] = "edge-ips/intrinsics"
    version: Literal[1] = 1
    image_width_px: ImageSide
    image_height_px: ImageSide
    camera_matrix: Matrix3x3
    dist_coeffs: Distortion
    rms_px: float | None = None
    board: tuple[int, int] | None = None
    square_cm: float | None = Field(default=None, gt=0.0)
    images_used: list[str] = Field(default_factory=list)
    images_skipped: list[str] = Field(default_factory=list)

    def to_intrinsics(self) -> Intrinsics:
        k = np.asarray(self.camera_matrix, dtype=np.float64)
        return Intrinsics(k, np.asarray(self.dist_coeffs, dtype=np.float64), self.image_width_px, self.image_height_px)


def intrinsics_record(result: IntrinsicsResult) -> IntrinsicsFile:
    i = result.intrinsics
    return IntrinsicsFile(
        image_width_px=i.width_px,
        image_height_px=i.height_px,
        camera_matrix=i.camera_matrix.tolist(),
        dist_coeffs=i.dist_coeffs.tolist(),
        rms_px=result.rms_px,
        board=result.board,
        square_cm=result.square_cm,
        images_used=list(result.used),
        images_skipped=[n for n, _ in result.skipped],
    )


def save_intrinsics(record: IntrinsicsFile, path: Path) -> None:
    try:
        path.write_text(record.model_dump_json(indent=2) + "\n")
    except OSError as exc:
        raise CalibrationError(f"{path}: cannot write intrinsics file ({exc.strerror or exc})") from exc


def load_intrinsics(path: Path, expected_size: tuple[int, int] | None = None) -> Intrinsics:
    """Read an intrinsics file; a :class:`CalibrationError` names the file and what is wrong."""
    try:
        data = json.loads(path.read_bytes())
    except OSError as exc:
        raise CalibrationError(f"{path}: cannot read intrinsics file ({exc.strerror or exc})") from exc
    except (UnicodeDecodeError, json.JSONDecodeError):
        raise CalibrationError(f"{path}: malformed intrinsics file (not JSON)") from None
    if not isinstance(data, dict) or data.get("kind") != KIND:
        raise CalibrationError(f"{path}: not an edge-ips intrinsics file (kind must be {KIND!r})")
    if data.get("version") != VERSION:
        raise CalibrationError(
            f"{path}: unknown intrinsics file version {data.get('version')!r} (this edge-ips reads {VERSION})"
        )
    try:
        intr = IntrinsicsFile.model_validate(data).to_intrinsics()
    except ValidationError as exc:
        raise CalibrationError(f"{path}: invalid intrinsics file at {describe_validation(exc)}") from None
    except CalibrationError as exc:
        raise CalibrationError(f"{path}: {exc}") from None
    if expected_size is not None and tuple(expected_size) != (intr.width_px, intr.height_px):
        raise CalibrationError(
            f"{path}: intrinsics are for {intr.width_px}x{intr.height_px} images, "
            f"not {expected_size[0]}x{expected_size[1]}"
        )
    return intr
