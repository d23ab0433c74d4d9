"""The calibration panel of the dashboard: a summary for ``/api/state`` and the error map PNG.

- A point-pair calibration file (``edge-ips calibrate points``) keeps its points: the predicted 95% error map
  (paper Fig. 3/4, :mod:`edge.calibration.errormap`) is recomputed from the points it used, with its figures.
- The simulated camera has its exact calibration: there is no mapping error to show, and the panel says so over
  the camera image with the working area outlined.
- Other calibrations (ArUco, camera) carry no point-pair fit to propagate: the panel shows the working area and
  the figures the file has.

The PNG is made once, on the first request, off the tracker's thread, and kept.
"""

from __future__ import annotations

import logging
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
from numpy.typing import NDArray

from edge.calibration.refine import clicked_by_hand, clicked_note
from edge.errors import CalibrationError

if TYPE_CHECKING:
    from edge.calibration import Calibration, CalibrationFile

log = logging.getLogger("edge.dashboard")

MIN_POINTS_FOR_MAP = 5  # 4 points fit exactly: no redundancy to estimate the noise


def _round(value: float | None) -> float | None:
    return None if value is None else round(float(value), 3)


class CalibrationView:
    """``kind``: ``simulator`` (exact), ``file`` (with ``record``), or ``none`` (no calibration known)."""

    def __init__(
        self,
        calibration: Calibration | None,
        *,
        simulated: bool,
        path: Path | None = None,
        background: Callable[[], NDArray[np.uint8] | None] = lambda: None,
    ) -> None:
        self.calibration = calibration
        self.simulated = simulated
        self.path = path
        self.background = background
        self.record: CalibrationFile | None = None
        if not simulated and path is not None and path.is_file():
            from edge.calibration import read_calibration_file

            try:
                self.record = read_calibration_file(path)
            except CalibrationError as exc:  # the runtime loaded it already; this is only the panel
                log.warning("dashboard: calibration panel without figures: %s", exc)
        self._png: bytes | None = None
        self._lock = threading.Lock()

    @property
    def kind(self) -> str:
        if self.simulated:
            return "simulator"
        return "file" if self.calibration is not None else "none"

    def summary(self) -> dict[str, Any] | None:
        """For ``/api/state``: method, the error map's mean and max (cm) where known, and a note."""
        if self.simulated:
            return {
                "method": "simulator",
                "exact": True,
                "mean_cm": 0.0,
                "max_cm": 0.0,
                "note": "simulated camera: its exact calibration, no mapping error",
            }
        if self.calibration is None:
            return None
        out: dict[str, Any] = {"method": "unknown", "exact": False, "mean_cm": None, "max_cm": None, "note": ""}
        if self.record is not None:
            fit = self.record.fit
            out["method"] = self.record.method
            out["file"] = str(self.path)
            if fit is not None:
                out["mean_cm"] = _round(fit.error_map_mean_cm)
                out["max_cm"] = _round(fit.error_map_max_cm)
                out["loo_mean_cm"] = _round(fit.loo_mean_cm)
                out["loo_max_cm"] = _round(fit.loo_max_cm)
            if out["mean_cm"] is None:
                out["note"] = f"{self.record.method} calibration: no error map (it needs a point-pair fit)"
            clicked = clicked_by_hand(self.record)
            if clicked is not None:
                out["note"] = f"{clicked_note(clicked)}; printed targets and calibrate points --refine-on take it down"
        return out

    def png(self) -> bytes:
        """The error map (or the panel's explanation) as PNG bytes; made once."""
        with self._lock:
            if self._png is None:
                self._png = self._render()
            return self._png

    def _render(self) -> bytes:
        if self.record is not None and self.calibration is not None:
            made = _point_pair_map_png(self.record, self.calibration)
            if made is not None:
                return made
        if self.simulated:
            note = "simulated camera: exact calibration, mapping error 0 cm everywhere"
        elif self.calibration is None:
            note = "no calibration known to the dashboard"
        else:
            method = self.record.method if self.record is not None else "this"
            note = f"{method} calibration: no point-pair fit, no error map"
        return _note_png(self.calibration, self.background(), note)


def _point_pair_map_png(record: CalibrationFile, cal: Calibration) -> bytes | None:
    """The predicted 95% error map of a point-pair calibration file, recomputed from the points it used."""
    from edge.calibration.errormap import predicted_error_map, write_error_map_png
    from edge.calibration.homography import fit_plane

    used = [p for p in record.points if p.used]
    if record.method != "points" or len(used) < MIN_POINTS_FOR_MAP:
        return None
    uv = np.array([[p.u, p.v] for p in used], dtype=np.float64)
    xy = np.array([[p.x, p.y] for p in used], dtype=np.float64)
    ideal = cal.intrinsics.undistort_px(uv) if cal.intrinsics is not None else uv
    try:
        plane = fit_plane(xy, ideal)
        sigma = plane.sigma_px
        if sigma is None or sigma <= 0:
            return None
        emap = predicted_error_map(plane, sigma, cal)
    except CalibrationError as exc:
        log.warning("dashboard: no error map: %s", exc)
        return None
    rejected = np.array([[p.u, p.v] for p in record.points if not p.used], dtype=np.float64).reshape(-1, 2)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "errormap.png"
        write_error_map_png(out, emap, cal, points_uv_px=uv, rejected_uv_px=rejected)
        return out.read_bytes()


def _note_png(cal: Calibration | None, background: NDArray[np.uint8] | None, note: str) -> bytes:
    """A dimmed camera image (or a dark panel) with the working area outlined and ``note`` written on it."""
    if background is not None:
        img = (background.astype(np.float32) * 0.45).astype(np.uint8)
    else:
        w, h = cal.image_size if cal is not None else (1280, 720)
        img = np.full((h, w, 3), 24, dtype=np.uint8)
    if cal is not None:
        from edge.calibration.errormap import area_outline_px

        outline = area_outline_px(cal)
        outline = outline[np.all(np.isfinite(outline), axis=1)]
        if outline.shape[0] > 2:
            pts = np.round(outline * 16).astype(np.int32)
            cv2.polylines(img, [pts], True, (255, 255, 0), 2, cv2.LINE_AA, shift=4)
    scale = img.shape[1] / 1280
    at = (int(24 * scale), int(48 * scale))
    cv2.putText(img, note, at, cv2.FONT_HERSHEY_SIMPLEX, 0.9 * scale, (255, 255, 255), 2, cv2.LINE_AA)
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise ValueError("PNG encoding failed")
    return buf.tobytes()
