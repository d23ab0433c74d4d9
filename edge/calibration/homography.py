"""Plane homographies: the image-space maximum-likelihood fit, its Jacobians and its parameter covariance.

The model is the paper's "point coordinates calibration" (section III.A) made explicit: a plane at marker height
seen by a pinhole camera is a homography ``G`` from world ``(x, y, 1)`` cm to ideal (undistorted) pixels. The
measuring noise is in the pixels, so ``G`` is fitted world -> image minimising the pixel reprojection error (the
maximum-likelihood estimate for Gaussian pixel noise) and inverted for use; fitting image -> world instead puts the
noise on the wrong side and is about 25% worse at the far edge.

Covariances are computed in Hartley-normalised coordinates, where the 8 free entries of ``G`` (``g33 = 1``) are
well conditioned.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from edge.errors import CalibrationError

FloatArray = NDArray[np.float64]
AnyFloat = NDArray[np.floating[Any]]

N_PARAMS = 8
GAUSS_NEWTON_STEPS = 5


def apply_homography(h: AnyFloat, xy: AnyFloat) -> FloatArray:
    """(N, 2) points through the (3, 3) homography ``h`` -> (N, 2). Points mapped to infinity come out non-finite."""
    pts = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    q = pts @ h[:, :2].T + h[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.asarray(q[:, :2] / q[:, 2:3])


def homography_w(h: FloatArray, xy: FloatArray) -> FloatArray:
    """(N,) the homogeneous scale ``w`` of ``h @ (x, y, 1)``; ``w > 0`` means in front of the camera for ``G``."""
    pts = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    return np.asarray(pts @ h[2, :2] + h[2, 2])


def normaliser(xy: FloatArray) -> FloatArray:
    """(3, 3) Hartley similarity: centroid to the origin, mean distance sqrt(2)."""
    pts = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    c = pts.mean(axis=0)
    d = float(np.mean(np.linalg.norm(pts - c, axis=1)))
    s = np.sqrt(2.0) / d if d > 0 else 1.0
    return np.array([[s, 0.0, -s * c[0]], [0.0, s, -s * c[1]], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class PlaneFit:
    """A world -> ideal-pixel homography fitted to point pairs, with what is needed to propagate its uncertainty.

    ``g``: (3, 3) world (x, y, 1) cm -> ideal pixels, ``g[2, 2] == 1``.
    ``t_world``, ``t_px``: (3, 3) the normalising similarities used for the parameterisation.
    ``information``: (8, 8) ``J^T J`` of the pixel residuals w.r.t. the normalised parameters (unit noise).
    ``residuals_px``: (N, 2) measured minus predicted pixels of the points fitted.
    """

    g: FloatArray
    t_world: FloatArray
    t_px: FloatArray
    information: FloatArray
    residuals_px: FloatArray

    @property
    def n_points(self) -> int:
        return int(self.residuals_px.shape[0])

    @property
    def dof(self) -> int:
        return 2 * self.n_points - N_PARAMS

    @property
    def sigma_px(self) -> float | None:
        """Per-axis pixel noise estimated from the residuals, or None with no redundancy (4 points)."""
        if self.dof <= 0:
            return None
        return float(np.sqrt(np.sum(self.residuals_px**2) / self.dof))

    @property
    def normalised_params(self) -> FloatArray:
        gn = self.t_px @ self.g @ np.linalg.inv(self.t_world)
        gn = gn / gn[2, 2]
        return np.asarray(gn.ravel()[:N_PARAMS])

    def covariance(self) -> FloatArray:
        """(8, 8) parameter covariance for unit pixel noise (multiply by sigma^2)."""
        return np.asarray(np.linalg.pinv(self.information))

    def param_jacobian_px(self, xy_world: FloatArray) -> FloatArray:
        """(N, 2, 8) d(ideal pixel) / d(normalised parameters) at world points."""
        return _param_jacobian(self.normalised_params, self.t_world, self.t_px, xy_world)

    def world_jacobian(self, xy_world: FloatArray) -> FloatArray:
        """(N, 2, 2) d(ideal pixel) / d(world x, y) at world points."""
        return _world_jacobian(self.g, xy_world)

    def world_covariance(self, xy_world: FloatArray, sigma_px: float) -> FloatArray:
        """(N, 2, 2) covariance (cm^2) of the world point the fitted mapping gives for the pixel of ``xy_world``.

        Implicit differentiation of ``G(x; p) = u`` at fixed ``u``: ``dx = -(dG/dx)^-1 (dG/dp) dp``.
        """
        jp = self.param_jacobian_px(xy_world)
        jx_inv = np.linalg.inv(self.world_jacobian(xy_world))
        m = -np.einsum("nij,njk->nik", jx_inv, jp)
        return np.asarray(np.einsum("nik,kl,njl->nij", m, self.covariance(), m) * sigma_px**2)


def _param_jacobian(params: FloatArray, t_world: FloatArray, t_px: FloatArray, xy_world: FloatArray) -> FloatArray:
    xn = apply_homography(t_world, xy_world)
    gn = np.append(params, 1.0).reshape(3, 3)
    q = xn @ gn[:, :2].T + gn[:, 2]
    w = q[:, 2]
    un, vn = q[:, 0] / w, q[:, 1] / w
    x, y = xn[:, 0], xn[:, 1]
    n = xn.shape[0]
    j = np.zeros((n, 2, N_PARAMS))
    j[:, 0, 0], j[:, 0, 1], j[:, 0, 2] = x / w, y / w, 1.0 / w
    j[:, 1, 3], j[:, 1, 4], j[:, 1, 5] = x / w, y / w, 1.0 / w
    j[:, 0, 6], j[:, 0, 7] = -un * x / w, -un * y / w
    j[:, 1, 6], j[:, 1, 7] = -vn * x / w, -vn * y / w
    return np.asarray(j / t_px[0, 0])  # back from normalised to real pixels (a similarity: one scale)


def _world_jacobian(g: FloatArray, xy_world: FloatArray) -> FloatArray:
    pts = np.asarray(xy_world, dtype=np.float64).reshape(-1, 2)
    q = pts @ g[:, :2].T + g[:, 2]
    w = q[:, 2]
    u, v = q[:, 0] / w, q[:, 1] / w
    j = np.empty((pts.shape[0], 2, 2))
    j[:, 0, 0] = (g[0, 0] - u * g[2, 0]) / w
    j[:, 0, 1] = (g[0, 1] - u * g[2, 1]) / w
    j[:, 1, 0] = (g[1, 0] - v * g[2, 0]) / w
    j[:, 1, 1] = (g[1, 1] - v * g[2, 1]) / w
    return j


def fit_plane(xy_world: FloatArray, uv_px: FloatArray) -> PlaneFit:
    """Fit the world -> ideal-pixel homography minimising pixel reprojection error (>= 4 points in general position).

    ``cv2.findHomography(..., method=0)`` gives the normalised DLT refined by Levenberg-Marquardt on the
    reprojection error in the destination (pixel) image, which is the MLE for pixel noise.
    """
    world = np.asarray(xy_world, dtype=np.float64).reshape(-1, 2)
    uv = np.asarray(uv_px, dtype=np.float64).reshape(-1, 2)
    if world.shape[0] < 4:
        raise CalibrationError(f"need at least 4 points for a plane mapping, got {world.shape[0]}")
    found, _ = cv2.findHomography(world, uv, 0)
    if found is None:
        raise CalibrationError("the points do not determine a plane mapping (degenerate layout)")
    if not np.all(np.isfinite(found)) or abs(found[2, 2]) < 1e-300:
        raise CalibrationError("the points do not determine a plane mapping (degenerate layout)")
    g = np.asarray(found / found[2, 2], dtype=np.float64)
    if abs(np.linalg.det(g)) < 1e-12 * np.linalg.norm(g) ** 3:
        raise CalibrationError("the fitted plane mapping is degenerate (points nearly collinear?)")
    t_world, t_px = normaliser(world), normaliser(uv)
    gn = t_px @ g @ np.linalg.inv(t_world)
    params = np.asarray((gn / gn[2, 2]).ravel()[:N_PARAMS])
    # a few Gauss-Newton steps polish OpenCV's Levenberg-Marquardt result to the exact least-squares optimum
    for _ in range(GAUSS_NEWTON_STEPS):
        j = _param_jacobian(params, t_world, t_px, world).reshape(-1, N_PARAMS)
        g_try = np.linalg.inv(t_px) @ np.append(params, 1.0).reshape(3, 3) @ t_world
        r = (uv - apply_homography(g_try, world)).reshape(-1)
        step, *_ = np.linalg.lstsq(j, r, rcond=None)
        params = params + step
        if np.linalg.norm(step) < 1e-12 * (1.0 + np.linalg.norm(params)):
            break
    g = np.linalg.inv(t_px) @ np.append(params, 1.0).reshape(3, 3) @ t_world
    g = np.asarray(g / g[2, 2], dtype=np.float64)
    j = _param_jacobian(params, t_world, t_px, world).reshape(-1, N_PARAMS)
    residuals = uv - apply_homography(g, world)
    return PlaneFit(g=g, t_world=t_world, t_px=t_px, information=j.T @ j, residuals_px=residuals)
