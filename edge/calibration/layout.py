"""Is the marker table the layout in the image? A wrong table still gives a camera pose (a mirrored or turned table
of OpenCV's real ChArUco photo fits with 24-35 px RMS, a right one with 1 px), and a wrong calibration moves every
rover by tens of centimetres. Refuse it, and say what is most likely wrong.

A right table reprojects every marker's corners to within its survey and detection error: a marker laid a
centimetre off is 4% of a 25 cm marker's side. The limit is a quarter of the median marker side in the image (and
at least 2 px): a placement error of a quarter of a marker, or any wrong layout, is refused. Then the usual
mistakes are tried on the table, each refitted: an axis running the other way (mirrored), markers whose tops do not
face +y (turned, or the table's axes turned), both, and one marker that is not where its row says.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from edge.calibration.lens import Intrinsics
from edge.calibration.pose import diagonal_crossing, fit_pose, square_corners
from edge.camera import PinholeCamera
from edge.errors import CalibrationError

FloatArray = NDArray[np.float64]

SIDE_FRACTION = 0.25  # of the median marker side in the image: the largest corner RMS a right table gives
MIN_LIMIT_PX = 2.0
_TOP_FACES = ("+y", "-x", "-y", "+x")  # where a marker's top edge points after 0..3 counter-clockwise quarter turns
_UNITS = ((0.1, "millimetres"), (100.0, "metres"), (2.54, "inches"))  # positions in these, sizes in cm


@dataclass(frozen=True)
class MarkerCorners:
    """The markers found in the image and listed in the table, in the same order.

    ``ids``: (M,) int; ``centres_cm``: (M, 3); ``sizes_cm``: (M,); ``corners_px``: (M, 4, 2) ArUco order;
    ``rows``: (M,) where each is in the table (``markers.csv row 3 (line 4)``).
    """

    ids: tuple[int, ...]
    centres_cm: FloatArray
    sizes_cm: FloatArray
    corners_px: FloatArray
    rows: tuple[str, ...]

    def limit_px(self) -> float:
        """The largest corner reprojection RMS a right table gives for markers this size in the image."""
        sides = np.linalg.norm(self.corners_px - np.roll(self.corners_px, -1, axis=1), axis=2).mean(axis=1)
        return max(MIN_LIMIT_PX, SIDE_FRACTION * float(np.median(sides)))

    def marker_rms_px(
        self,
        intrinsics: Intrinsics | None,
        size: tuple[int, int],
        *,
        mirror: str = "",
        quarter_turns: int = 0,
        scale: float = 1.0,
        keep: NDArray[np.bool_] | None = None,
    ) -> FloatArray:
        """(K,) each kept marker's corner reprojection RMS under the best pose for the table read with ``mirror``
        ("x" or "y": that axis negated), every marker's top turned by ``quarter_turns`` and the positions times
        ``scale``, over the markers in ``keep`` (all by default); infinite when no pose fits at all."""
        keep = np.ones(len(self.ids), dtype=bool) if keep is None else keep
        centres = self.centres_cm[keep] * scale
        if mirror:
            centres[:, "xy".index(mirror)] *= -1.0
        obj = square_corners(centres, self.sizes_cm[keep], quarter_turns).reshape(-1, 3)
        img = self.corners_px[keep].reshape(-1, 2)
        try:
            fit = fit_pose(obj, img, intrinsics, size)
        except CalibrationError:
            return np.full(int(keep.sum()), np.inf)
        lens = fit.intrinsics
        proj, _ = cv2.projectPoints(obj, fit.rvec, fit.tvec, lens.camera_matrix, lens.dist_coeffs)
        squared = np.sum((proj.reshape(-1, 2) - img) ** 2, axis=1).reshape(-1, 4)
        return np.asarray(np.sqrt(squared.mean(axis=1)))

    def fits(self, intrinsics: Intrinsics | None, size: tuple[int, int], **reading: Any) -> tuple[bool, float]:
        """Whether the table read so is the layout in the image (overall and every marker within
        :meth:`limit_px`), and the overall corner RMS."""
        per_marker = self.marker_rms_px(intrinsics, size, **reading)
        rms = float(np.sqrt(np.mean(per_marker**2)))
        return bool(per_marker.max() <= self.limit_px()), rms


def _mistake(mirror: str, quarter_turns: int, table: str) -> str:
    said = []
    if mirror == "x":
        said.append(
            f"x runs the other way in {table} than on the floor (x must point to the right of +y, seen from above)"
        )
    if mirror == "y":
        said.append(
            f"y runs the other way in {table} than on the floor (y must point where the markers' tops face; a board "
            "whose y axis runs down the page, as OpenCV's boards do, needs y negated)"
        )
    if quarter_turns:
        said.append(
            f"the markers' tops face {_TOP_FACES[quarter_turns]} of {table}, not +y (turn the markers, or the table's "
            "axes)"
        )
    return " and ".join(said)


def layout_problem(
    markers: MarkerCorners, intrinsics: Intrinsics | None, size: tuple[int, int], table: str
) -> str | None:
    """None when the table fits the image as a right one does; else what is wrong, the likely cause first."""
    limit = markers.limit_px()
    per_marker = markers.marker_rms_px(intrinsics, size)
    if per_marker.max() <= limit:
        return None
    rms = float(np.sqrt(np.mean(per_marker**2)))
    worst = int(np.argmax(per_marker))
    one = f" (marker {markers.ids[worst]}: {per_marker[worst]:.1f} px)" if rms <= limit else ""
    head = (
        f"{table} is not the layout in the image: its markers' corners reproject with RMS {rms:.1f} px{one}, a right "
        f"table gives at most {limit:.1f} px here"
    )
    readings = [{"mirror": m, "quarter_turns": t} for m in ("", "y", "x") for t in range(4) if m or t]
    fitting = []
    for reading in readings:
        ok, reading_rms = markers.fits(intrinsics, size, **reading)
        if ok:
            fitting.append((bool(reading["mirror"]) + bool(reading["quarter_turns"]), reading_rms, reading))
    if fitting:  # the simplest mistake that explains the image (mirrored x is also mirrored y turned 180 degrees)
        _, best_rms, best = min(fitting, key=lambda f: (f[0], f[1]))
        mistake = _mistake(str(best["mirror"]), int(best["quarter_turns"]), table)
        return f"{head}. It fits (RMS {best_rms:.1f} px) if {mistake}"
    for scale, unit in _UNITS:
        ok, reading_rms = markers.fits(intrinsics, size, scale=scale)
        if ok:
            return f"{head}. It fits (RMS {reading_rms:.1f} px) if its x, y and z are {unit}: give them in cm"
    misplaced = _misplaced_marker(markers, intrinsics, size, limit)
    if misplaced is not None:
        return f"{head}. {misplaced}"
    return (
        f"{head}. Check that its ids are the markers' ids, that x points to the right of +y seen from above and the "
        "markers' tops face +y, and that x, y, z and size are in cm"
    )


def _misplaced_marker(
    markers: MarkerCorners, intrinsics: Intrinsics | None, size: tuple[int, int], limit: float
) -> str | None:
    """The one marker without which the others fit, and how far from its row's x, y it really lies."""
    n = len(markers.ids)
    if n < 4:
        return None
    fits = [markers.fits(intrinsics, size, keep=np.arange(n) != m) for m in range(n)]
    m = int(np.argmin([rms if ok else np.inf for ok, rms in fits]))
    if not fits[m][0]:
        return None
    keep = np.arange(n) != m
    obj = square_corners(markers.centres_cm[keep], markers.sizes_cm[keep]).reshape(-1, 3)
    fit = fit_pose(obj, markers.corners_px[keep].reshape(-1, 2), intrinsics, size)
    lens = fit.intrinsics
    camera = PinholeCamera(lens.camera_matrix, lens.dist_coeffs, fit.rvec, fit.tvec, size[0], size[1])
    centre_px = lens.distort_px(diagonal_crossing(lens.undistort_px(markers.corners_px[m]))[None])
    seen = camera.pixel_to_plane(centre_px, float(markers.centres_cm[m, 2]))[0]
    off_cm = float(np.linalg.norm(seen - markers.centres_cm[m, :2]))
    return (
        f"Marker {markers.ids[m]} ({markers.rows[m]}) is not where its row says: without it the others fit "
        f"(RMS {fits[m][1]:.1f} px), and it lies {off_cm:.1f} cm from its x, y (at {seen[0]:.1f}, {seen[1]:.1f})"
    )
