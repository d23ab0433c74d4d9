"""How sure a board is of each detection: the covariance a detections message carries, and the builder.

A detection's covariance on the plane (cm^2) is the sum of two parts:

* **the calibration's error** at that point: for a point-pair calibration, the fitted homography's parameter
  covariance propagated to the world point (the same model as the calibration's error map, ``sigma^2 (J^T J)^-1``
  with sigma from the fit's residuals, :meth:`edge.calibration.homography.PlaneFit.world_covariance`); for an
  ArUco calibration its leave-one-out or residual RMS as an isotropic floor; none for a known camera (simulator);
* **the detection's pixel noise** seen through the local scale of the mapping (the tracker's own measurement
  covariance when it gives one, else ``measurement_sigma_px`` through the numerical Jacobian), scaled up by
  ``1 / (marker quality x image quality)``, and by the **edge of the view**: a marker whose outline comes within
  ``edge_ramp_px`` of the image border is trusted less and less (its sigma grows as ``ramp / margin``), so the
  fusion hands a rover from one camera to the next gradually instead of at the frame where one camera loses it.

Image quality is the share of the frame neither crushed nor clipped (sampled every ``stride`` pixels): a marker in
a saturated sun patch or a dark corner has lost its colour, whatever the tracker's score says.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from edge.calibration.files import CalibrationFile, read_calibration_file
from edge.calibration.homography import PlaneFit, fit_plane
from edge.calibration.lens import Intrinsics
from edge.errors import CalibrationError
from edge.fusion.detections import Detection, Detections
from edge.trackers.base import PlaneMapping
from edge.tracking import FrameResult, RoverEstimate

FloatArray = NDArray[np.float64]

MARKER_RADIUS_CM = 0.5 * math.hypot(21.5, 16.8)  # half the diagonal of the paper's marker (Table II)


@dataclass(frozen=True)
class UncertaintySettings:
    """Tuning of the detection covariance (units in the names)."""

    measurement_sigma_px: float = 0.3  # when the tracker gives no covariance of its own
    edge_ramp_px: float = 48.0
    max_edge_factor: float = 100.0
    marker_radius_cm: float = MARKER_RADIUS_CM
    min_quality: float = 0.05
    min_image_quality: float = 0.1
    dark_level: int = 8
    clipped_level: int = 247
    stride: int = 8


class CalibrationErrorModel:
    """The calibration's own error at world points: ``covariance_cm2(xy) -> (N, 2, 2)``."""

    def __init__(self, plane: PlaneFit | None = None, sigma_px: float = 0.0, floor_cm: float = 0.0) -> None:
        self.plane = plane
        self.sigma_px = sigma_px
        self.floor_cm2 = floor_cm * floor_cm

    def covariance_cm2(self, xy_cm: FloatArray) -> FloatArray:
        xy = np.asarray(xy_cm, dtype=np.float64).reshape(-1, 2)
        out = np.zeros((len(xy), 2, 2))
        if self.plane is not None and self.sigma_px > 0 and len(xy):
            out += self.plane.world_covariance(xy, self.sigma_px)
        out[:, 0, 0] += self.floor_cm2
        out[:, 1, 1] += self.floor_cm2
        return out


def calibration_error_model(path: Path) -> CalibrationErrorModel:
    """The error model of the calibration in ``path``: an ``edge-ips/calibration`` file (point pairs: the fit's
    covariance, rebuilt from the points it kept; ArUco: an isotropic floor) or a ``camera.json`` (exact: none)."""
    try:
        kind = json.loads(path.read_text()).get("kind")
    except (OSError, ValueError, AttributeError) as exc:
        raise CalibrationError(f"{path}: cannot read calibration file ({exc})") from exc
    if kind == "edge-ips/camera":
        return CalibrationErrorModel()
    return error_model_of(read_calibration_file(path))


def error_model_of(record: CalibrationFile) -> CalibrationErrorModel:
    fit = record.fit
    used = [p for p in record.points if p.used]
    if record.method == "points" and len(used) > 4:
        uv = np.array([[p.u, p.v] for p in used])
        if record.intrinsics is not None:
            intr = Intrinsics(
                np.asarray(record.intrinsics.camera_matrix),
                np.asarray(record.intrinsics.dist_coeffs),
                record.image_width_px,
                record.image_height_px,
            )
            uv = intr.undistort_px(uv)
        plane = fit_plane(np.array([[p.x, p.y] for p in used]), uv)
        sigma = (fit.sigma_px if fit is not None else None) or plane.sigma_px or 0.0
        return CalibrationErrorModel(plane, sigma)
    if fit is not None:
        floor = fit.loo_rms_cm or fit.residual_mean_cm or 0.0
        return CalibrationErrorModel(floor_cm=floor)
    return CalibrationErrorModel()


def image_quality(image: NDArray[np.uint8], settings: UncertaintySettings = UncertaintySettings()) -> float:
    """Share of sampled pixels with every channel above ``dark_level`` and below ``clipped_level`` (0..1)."""
    s = settings.stride
    sample = image[::s, ::s]
    if sample.size == 0:
        return 0.0
    ok = np.all((sample > settings.dark_level) & (sample < settings.clipped_level), axis=-1)
    return float(np.count_nonzero(ok)) / float(ok.size)


def pixel_jacobian_cm(mapping: PlaneMapping, uv_px: FloatArray, step_px: float = 1.0) -> FloatArray:
    """(N, 2, 2) d(world cm) / d(pixel) at (N, 2) pixels, by central differences through ``mapping``."""
    uv = np.asarray(uv_px, dtype=np.float64).reshape(-1, 2)
    h = step_px
    offsets = np.array([[h, 0.0], [-h, 0.0], [0.0, h], [0.0, -h]])
    pts = (uv[:, None, :] + offsets[None, :, :]).reshape(-1, 2)
    xy = mapping.pixel_to_world(pts).reshape(-1, 4, 2)
    jac = np.empty((len(uv), 2, 2))
    jac[:, :, 0] = (xy[:, 0] - xy[:, 1]) / (2 * h)
    jac[:, :, 1] = (xy[:, 2] - xy[:, 3]) / (2 * h)
    return jac


def view_polygon(
    mapping: PlaneMapping, size_wh: tuple[int, int], area_cm: tuple[float, float, float, float] | None
) -> tuple[tuple[float, float], ...]:
    """The image's corners on the floor, clipped to ``area_cm`` (x0, y0, x1, y1); empty when a corner's ray misses
    the plane (a view up to the horizon has no finite footprint)."""
    w, h = size_wh
    corners = np.array([[0.0, 0.0], [w - 1.0, 0.0], [w - 1.0, h - 1.0], [0.0, h - 1.0]])
    xy = mapping.pixel_to_world(corners)
    if not np.all(np.isfinite(xy)):
        return ()
    poly = [(float(x), float(y)) for x, y in xy]
    if area_cm is not None:
        poly = clip_polygon(poly, area_cm)
    return tuple(poly)


def clip_polygon(poly: list[tuple[float, float]], box: tuple[float, float, float, float]) -> list[tuple[float, float]]:
    """Sutherland-Hodgman clipping of a convex polygon to the box ``(x0, y0, x1, y1)``."""
    x0, y0, x1, y1 = box
    edges = ((0, x0, 1.0), (0, x1, -1.0), (1, y0, 1.0), (1, y1, -1.0))  # (axis, bound, inside sign)
    out = poly
    for axis, bound, sign in edges:
        src, out = out, []
        for i, cur in enumerate(src):
            prev = src[i - 1]
            cur_in = sign * (cur[axis] - bound) >= 0
            prev_in = sign * (prev[axis] - bound) >= 0
            if cur_in != prev_in:
                f = (bound - prev[axis]) / (cur[axis] - prev[axis])
                out.append((prev[0] + f * (cur[0] - prev[0]), prev[1] + f * (cur[1] - prev[1])))
            if cur_in:
                out.append(cur)
        if not out:
            return []
    return out


class DetectionBuilder:
    """A board's :class:`Detections` from the tracker's :class:`FrameResult` (pure: no clock, no I/O).

    ``mapping``: the board's pixel <-> floor calibration; ``errors``: its calibration error model; ``size_wh``: the
    image size; ``area_cm``: the working area its view is clipped to (for ``view_cm``).
    """

    def __init__(
        self,
        edge_id: str,
        mapping: PlaneMapping,
        errors: CalibrationErrorModel,
        size_wh: tuple[int, int],
        area_cm: tuple[float, float, float, float] | None = None,
        settings: UncertaintySettings = UncertaintySettings(),
    ) -> None:
        self.edge_id = edge_id
        self.mapping = mapping
        self.errors = errors
        self.size_wh = size_wh
        self.settings = settings
        self.view_cm = view_polygon(mapping, size_wh, area_cm)
        self.seq = 0

    def build(self, result: FrameResult, image: NDArray[np.uint8] | None, t_sent_s: float) -> Detections:
        """The detections of one tracked frame; ``image`` gives the image quality (1.0 when None)."""
        iq = image_quality(image, self.settings) if image is not None else 1.0
        estimates = result.estimates
        rovers: tuple[Detection, ...] = ()
        if estimates:
            rovers = self._detections(estimates, iq)
        out = Detections(
            edge_id=self.edge_id,
            seq=self.seq,
            frame=result.frame_index,
            t_capture_s=result.t_capture_s,
            t_sent_s=t_sent_s,
            image_quality=iq,
            view_cm=self.view_cm,
            rovers=rovers,
        )
        self.seq += 1
        return out

    def _detections(self, estimates: Sequence[RoverEstimate], iq: float) -> tuple[Detection, ...]:
        s = self.settings
        xy = np.array([e.measured_xy_cm or (e.x_cm, e.y_cm) for e in estimates], dtype=np.float64)
        uv = np.array([e.uv_px for e in estimates], dtype=np.float64)
        jac = pixel_jacobian_cm(self.mapping, uv)
        cal = self.errors.covariance_cm2(xy)
        # the marker's radius in pixels: its radius in cm over the local scale (cm per pixel)
        cm_per_px = np.sqrt(np.abs(np.linalg.det(jac)))
        radius_px = s.marker_radius_cm / np.maximum(cm_per_px, 1e-6)
        w, h = self.size_wh
        border_px = np.minimum.reduce([uv[:, 0], uv[:, 1], (w - 1) - uv[:, 0], (h - 1) - uv[:, 1]])
        margin_px = border_px - radius_px
        edge = np.where(
            margin_px >= s.edge_ramp_px,
            1.0,
            np.minimum(s.edge_ramp_px / np.maximum(margin_px, 1e-9), s.max_edge_factor),
        )
        out = []
        for i, e in enumerate(estimates):
            if e.measured_cov_cm2 is not None:
                a, b, d = e.measured_cov_cm2
                pixel = np.array([[a, b], [b, d]])
            else:
                pixel = jac[i] @ jac[i].T * (s.measurement_sigma_px**2)
            scale = edge[i] / (max(e.quality, s.min_quality) * max(iq, s.min_image_quality))
            cov = cal[i] + pixel * (scale * scale)
            if not np.all(np.isfinite(cov)):
                continue  # the mapping is undefined here (a ray that misses the plane): no usable detection
            out.append(
                Detection(
                    rover_id=e.rover_id,
                    xy_cm=(float(xy[i, 0]), float(xy[i, 1])),
                    cov_cm2=(float(cov[0, 0]), float(cov[0, 1]), float(cov[1, 1])),
                    theta_rad=e.theta_rad,
                    quality=float(e.quality),
                    uv_px=(float(uv[i, 0]), float(uv[i, 1])),
                )
            )
        return tuple(out)
