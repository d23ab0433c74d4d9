"""The camera's own processing of the light that reaches it: exposure and auto-exposure, white balance, rolling
flicker, sensor noise, tone curve and compression (:class:`CameraProcessing`, the renderer's last stage), and the
pure functions behind them.

The renderer (:mod:`edge.sim.render`) composes the scene in linear light; this turns it into the frame a webcam
sends. Each effect's physical parameters are in :mod:`edge.sim.effects`.
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import Any, cast

import cv2
import numpy as np
from numpy.typing import NDArray

from edge.camera import PinholeCamera
from edge.errors import SimulationError
from edge.sim.backdrop import Backdrop
from edge.sim.colour import awb_gains, tone_table
from edge.sim.effects import (
    CHROMA_SAMPLING,
    AutoExposure,
    Effects,
    Flicker,
    SensorNoise,
    SignalProcessing,
    drift_factor,
    sun_state,
)
from edge.sim.world import RoverState

FloatArray = NDArray[np.float64]
F32 = NDArray[np.float32]
Image = NDArray[np.uint8]

HEADROOM = 1.6  # linear light kept above sensor white until the final gain (glare, sun, over-exposure)
MIN_MOTION_PX = 0.25  # shorter motion blurs are left to the optics' point spread
ROW_BAND = 32  # rows per band in the whole-frame camera stage (fits the caches)


class CameraProcessing:
    """The camera's processing of composed linear light into 8-bit frames, deterministic for ``seed``.

    ``to_camera`` applies the fixed colour response (crosstalk, white balance) to linear light; ``capture`` turns
    the renderer's 16-bit working image (power-law code with ``HEADROOM``) into the frame at ``frame_index``.
    ``room`` is the static room in linear camera values (what auto-exposure and white balance meter, with the sun
    of ``backdrop``).
    """

    def __init__(self, effects: Effects, backdrop: Backdrop, shape_hw: tuple[int, int], seed: int, fps: float) -> None:
        self.effects = effects
        self.seed = seed
        self.fps = fps
        self.height_px, self.width_px = shape_hw
        self.gamma = effects.exposure.gamma
        self._backdrop = backdrop
        colour = effects.colour
        self._colour = None if colour.is_identity else colour.matrix.astype(np.float32)
        self.tone = tone_table(colour.tone, self.gamma, self.gamma)
        self.room = self.to_camera(backdrop.room)
        self._noise = (
            NoiseBank((self.height_px, self.width_px, 3), effects.noise.correlation, seed)
            if effects.noise is not None
            else None
        )
        self._sigma_luts: dict[int, NDArray[np.uint8]] = {}
        self._flicker_rows, self._flicker_period = self._flicker_table()
        self._ae_gains = np.ones(0)
        self._awb_gains = np.ones((0, 3))
        self._room_mean = self.room.reshape(-1, 3).mean(axis=0).astype(np.float64)
        self._sun_mean = (
            backdrop.sun.reshape(-1, 3).mean(axis=0).astype(np.float64) if backdrop.sun is not None else np.zeros(3)
        )

    @property
    def has_colour_response(self) -> bool:
        return self._colour is not None

    def to_camera(self, lin: F32) -> F32:
        """(h, w, 3) linear light on the sensor -> linear camera values through the fixed colour response."""
        if self._colour is None:
            return lin
        return np.asarray(cv2.transform(np.ascontiguousarray(lin, dtype=np.float32), self._colour), dtype=np.float32)

    def capture(self, work: NDArray[np.uint16], frame_index: int, t_s: float, noise_stream: int = 0) -> Image:
        """Exposure, white balance, flicker, noise, tone curve, compression: the camera's own processing of the
        composed light.

        Done in bands of rows so each band's data stays in cache through all the steps (twice as fast as whole-frame
        passes on this machine). Noise is added in the renderer's working power-law code, before the camera's own
        tone curve (a 256-entry table when it is another curve), as a sensor's noise precedes its tone curve.
        """
        drift = drift_factor(self.effects.drift, t_s)
        gain = float(self.auto_exposure(frame_index))
        enc_gain = (drift * gain * HEADROOM) ** (1.0 / self.gamma) * 255.0 / 65535.0
        wb = self.white_balance(frame_index) if self.effects.auto_white_balance is not None else None
        channel_gains = None if wb is None else tuple(float(enc_gain * g ** (1.0 / self.gamma)) for g in wb)
        band = None
        if self._flicker_rows is not None and self.effects.flicker is not None:
            offset = int(flicker_phase_rows(self.effects.flicker, t_s)) % self._flicker_period
            band = self._flicker_rows[offset : offset + self.height_px]
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, frame_index, noise_stream, 0xF8A3E]))
        noise = self._noise
        lut = None
        if noise is not None and self.effects.noise is not None:
            key = round(gain * 1000)
            lut = self._sigma_luts.get(key)
            if lut is None:
                lut = noise_sigma_lut(self.effects.noise, gain, self.gamma)
                self._sigma_luts[key] = lut
            draw = noise.draw(rng)
        processing = self.effects.processing
        mosaic = processing is not None and processing.demosaic is not None  # tone after the demosaicing
        frame: Image = np.empty((self.height_px, self.width_px, 3), dtype=np.uint8)
        for r0 in range(0, self.height_px, ROW_BAND):
            r1 = min(r0 + ROW_BAND, self.height_px)
            rows = frame[r0:r1]
            if channel_gains is None:
                cv2.convertScaleAbs(work[r0:r1], dst=rows, alpha=enc_gain)
            else:
                scalar = cast(Any, (*channel_gains, 0.0))  # one gain per channel (an OpenCV scalar)
                cv2.multiply(work[r0:r1], scalar, dst=rows, dtype=cv2.CV_8U)
            if band is not None:
                cv2.multiply(rows, band[r0:r1], dst=rows, scale=1.0 / 128.0)
            if noise is not None and lut is not None:
                noise.add(rows, r0, lut, draw)
            if self.tone is not None and not mosaic:
                cv2.LUT(rows, self.tone, dst=rows)
        if processing is not None:
            frame = self._process(frame, processing)
        if self.effects.compression is not None:
            frame = jpeg_roundtrip(frame, self.effects.compression.quality, self.effects.compression.chroma)
        return frame

    def _process(self, frame: Image, processing: SignalProcessing) -> Image:
        """The image signal processor's steps: demosaicing on the sensor's light (``frame`` in the working power
        code, its tone curve applied after), then sharpening of the encoded luma."""
        if processing.demosaic is not None:
            frame = demosaic(frame, self.gamma, processing.demosaic, processing.bayer_phase)
            if self.tone is not None:
                cv2.LUT(frame, self.tone, dst=frame)
        if processing.sharpen > 0.0:
            frame = sharpen_luma(frame, processing.sharpen, processing.sharpen_sigma_px)
        return frame

    # -- time-dependent camera state ----------------------------------------------------------------------------
    def auto_exposure(self, frame_index: int) -> float:
        if len(self._ae_gains) <= frame_index:
            n = max(frame_index + 1, 2 * len(self._ae_gains), 64)
            levels = np.array([self._scene_level(i / self.fps) for i in range(n)])
            self._ae_gains = auto_exposure_gains(levels, self.effects.auto_exposure)
        return float(self._ae_gains[frame_index])

    def white_balance(self, frame_index: int) -> FloatArray:
        """(3,) the automatic white balance's (B, G, R) gains at ``frame_index`` (ones without one)."""
        if self.effects.auto_white_balance is None:
            return np.ones(3)
        if len(self._awb_gains) <= frame_index:
            n = max(frame_index + 1, 2 * len(self._awb_gains), 64)
            means = np.array([self._scene_colour(i / self.fps) for i in range(n)])
            self._awb_gains = awb_gains(means, self.effects.auto_white_balance)
        return np.asarray(self._awb_gains[frame_index])

    def _scene_colour(self, t_s: float) -> FloatArray:
        """(3,) mean colour of the scene in linear camera values (what a grey-world white balance meters)."""
        strength, colour = sun_state(self.effects.sun, t_s)
        sun = self.to_camera((self._sun_mean * colour * strength).astype(np.float32).reshape(1, 1, 3)).reshape(3)
        return np.asarray(drift_factor(self.effects.drift, t_s) * self._room_mean + sun)

    def _scene_level(self, t_s: float) -> float:
        """Mean scene brightness relative to nominal (what the auto-exposure meters)."""
        strength, _ = sun_state(self.effects.sun, t_s)
        return drift_factor(self.effects.drift, t_s) + self._backdrop.sun_mean_ratio * strength

    def _flicker_table(self) -> tuple[NDArray[np.uint8] | None, int]:
        flicker = self.effects.flicker
        amp = flicker_amplitude(flicker, self.effects.exposure.exposure_s)
        if flicker is None or amp < 1e-3:
            return None, 1
        period = 1.0 / (2.0 * flicker.mains_hz * flicker.line_time_s)
        rows = np.arange(self.height_px + math.ceil(period) + 1)
        gain_lin = 1.0 + amp * np.cos(2.0 * math.pi * rows / period)
        gain_enc = np.rint(128.0 * gain_lin ** (1.0 / self.gamma)).astype(np.uint8)
        table = np.repeat(np.repeat(gain_enc[:, None, None], self.width_px, axis=1), 3, axis=2)
        return np.ascontiguousarray(table), max(round(period), 1)


def auto_exposure_gains(levels: FloatArray, ae: AutoExposure | None) -> FloatArray:
    """(N,) exposure gain per frame for the scene brightness ``levels`` (N,) (1.0 = nominal).

    Starts converged on frame 0's light; then follows with the configured delay and rate (in log terms).
    """
    levels = np.asarray(levels, dtype=np.float64)
    if ae is None:
        return np.ones_like(levels)
    target = np.clip(1.0 / np.maximum(levels, 1e-6), ae.min_gain, ae.max_gain)
    gains = np.empty_like(levels)
    g = float(target[0]) if len(levels) else 1.0
    for i in range(len(levels)):
        seen = target[max(i - ae.delay_frames, 0)]
        g = g * (seen / g) ** ae.rate
        gains[i] = g
    return gains


def flicker_amplitude(flicker: Flicker | None, exposure_s: float) -> float:
    """Band amplitude (relative) seen by a rolling shutter exposing each row for ``exposure_s``."""
    if flicker is None:
        return 0.0
    x = 2.0 * flicker.mains_hz * exposure_s
    sinc = 1.0 if x == 0 else math.sin(math.pi * x) / (math.pi * x)
    return flicker.modulation * abs(sinc)


def flicker_phase_rows(flicker: Flicker, t_s: float) -> float:
    """Row offset (in rows, modulo the band period) of the flicker pattern in the frame captured at ``t_s``."""
    period_rows = 1.0 / (2.0 * flicker.mains_hz * flicker.line_time_s)
    cycles = 2.0 * flicker.mains_hz * t_s + flicker.phase / (2.0 * math.pi)
    return (cycles % 1.0) * period_rows


# -- pure functions of images ----------------------------------------------------------------------------------
def exposure_blur(
    effects: Effects, camera: PinholeCamera, rover: RoverState, z_cm: float
) -> tuple[NDArray[np.float32] | None, float]:
    """How to blur a rover's layer: (kernel, 0) for motion during the exposure convolved with the optics' point
    spread, or (None, sigma) for the point spread alone (separable, cheaper) when the motion is under
    ``MIN_MOTION_PX`` (its variance, L^2 / 12, is then below 2 % of the point spread's)."""
    psf = effects.optics.blur_sigma_px if effects.optics is not None else 0.0
    if not effects.motion_blur or (rover.vx_cm_s == 0.0 and rover.vy_cm_s == 0.0):
        return None, psf
    half_t = 0.5 * effects.exposure.exposure_s
    pts = np.array(
        [
            [rover.x_cm - rover.vx_cm_s * half_t, rover.y_cm - rover.vy_cm_s * half_t, z_cm],
            [rover.x_cm + rover.vx_cm_s * half_t, rover.y_cm + rover.vy_cm_s * half_t, z_cm],
        ]
    )
    uv = camera.project(pts)
    if math.hypot(*(uv[1] - uv[0])) < MIN_MOTION_PX and psf > 0.0:
        return None, psf
    return blur_kernel(uv[1] - uv[0], psf), 0.0


def blur_kernel(displacement_px: FloatArray, psf_sigma_px: float) -> NDArray[np.float32] | None:
    """The blur of a moving object: its motion during the exposure (``displacement_px`` (2,), x, y) convolved with
    the optics' Gaussian point spread; normalised; None when both are negligible."""
    motion = motion_kernel(displacement_px)
    if psf_sigma_px < 0.05:
        return motion
    half = math.ceil(3.0 * psf_sigma_px)
    g = cv2.getGaussianKernel(2 * half + 1, psf_sigma_px, cv2.CV_64F)
    psf = g @ g.T
    if motion is None:
        return psf.astype(np.float32)
    # the motion line spread by the point spread: a (m + 2 half) square kernel
    full = cv2.filter2D(np.pad(motion.astype(np.float64), half), -1, psf, borderType=cv2.BORDER_CONSTANT)
    return (full / full.sum()).astype(np.float32)


def motion_kernel(displacement_px: FloatArray) -> NDArray[np.float32] | None:
    """Normalised line kernel for a blur of ``displacement_px`` (2,) (x, y) during the exposure; None if tiny."""
    dx, dy = float(displacement_px[0]), float(displacement_px[1])
    length = math.hypot(dx, dy)
    if length < 0.05:
        return None
    half = math.ceil(0.5 * max(abs(dx), abs(dy))) + 1
    size = 2 * half + 1
    n = max(8, int(6 * length))
    s = (np.arange(n) + 0.5) / n - 0.5
    xs, ys = half + s * dx, half + s * dy
    x0, y0 = np.floor(xs).astype(int), np.floor(ys).astype(int)
    fx, fy = xs - x0, ys - y0
    index = np.concatenate([(y0 + oy) * size + x0 + ox for oy in (0, 1) for ox in (0, 1)])
    weight = np.concatenate([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy])
    kernel = np.bincount(index, weights=weight, minlength=size * size).reshape(size, size)
    return (kernel / kernel.sum()).astype(np.float32)


_BAYER_CODES = {
    ("bilinear", (0, 0)): cv2.COLOR_BayerRG2BGR,
    ("bilinear", (0, 1)): cv2.COLOR_BayerGR2BGR,
    ("bilinear", (1, 0)): cv2.COLOR_BayerGB2BGR,
    ("bilinear", (1, 1)): cv2.COLOR_BayerBG2BGR,
    ("edge-aware", (0, 0)): cv2.COLOR_BayerRG2BGR_EA,
    ("edge-aware", (0, 1)): cv2.COLOR_BayerGR2BGR_EA,
    ("edge-aware", (1, 0)): cv2.COLOR_BayerGB2BGR_EA,
    ("edge-aware", (1, 1)): cv2.COLOR_BayerBG2BGR_EA,
}  # OpenCV names a pattern by the second row's second and third sites: blue at (0, 0) is its "RG"


def bayer_mosaic(image: NDArray[np.generic], phase: tuple[int, int]) -> NDArray[np.generic]:
    """(h, w) raw frame of a Bayer colour filter over ``image`` (h, w, 3 BGR): blue at the sites starting at
    ``phase`` (row, column), red at the opposite ones, green at the other two."""
    by, bx = phase
    raw = image[..., 1].copy()
    raw[by::2, bx::2] = image[by::2, bx::2, 0]
    raw[1 - by :: 2, 1 - bx :: 2] = image[1 - by :: 2, 1 - bx :: 2, 2]
    return raw


@lru_cache(maxsize=8)
def _linear_tables(gamma: float) -> tuple[NDArray[np.uint16], NDArray[np.uint8]]:
    code = np.arange(256, dtype=np.float64) / 255.0
    to_linear = np.rint(code**gamma * 65535.0).astype(np.uint16).reshape(1, 256)  # a cv2.LUT table
    level = np.arange(65536, dtype=np.float64) / 65535.0
    to_code = np.rint(level ** (1.0 / gamma) * 255.0).astype(np.uint8)
    return to_linear, to_code


def demosaic(code: Image, gamma: float, method: str, phase: tuple[int, int]) -> Image:
    """``code`` (8-bit, a power law ``gamma`` of the light) seen through a Bayer filter and interpolated back to
    three colours by ``method`` (:data:`edge.sim.effects.DEMOSAIC`), in linear light as a camera's processor does;
    returned in the same code. A uniform colour comes back unchanged; a sharp edge gets colour fringes."""
    to_linear, to_code = _linear_tables(round(gamma, 4))
    raw = bayer_mosaic(cv2.LUT(code, to_linear), phase)
    interpolated = np.asarray(cv2.cvtColor(np.ascontiguousarray(raw), _BAYER_CODES[(method, phase)]), np.uint16)
    return np.asarray(to_code.take(interpolated), dtype=np.uint8)


def sharpen_luma(image: Image, amount: float, sigma_px: float) -> Image:
    """An unsharp mask on the luma: ``amount`` times the luma's detail finer than a Gaussian of ``sigma_px`` added
    to all three channels alike (which leaves the chroma as it was), as a webcam sharpens before encoding."""
    luma = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY).astype(np.float32)
    detail = cv2.addWeighted(luma, amount, cv2.GaussianBlur(luma, (0, 0), sigma_px), -amount, 0.0)
    return np.asarray(cv2.add(image, cv2.merge([detail, detail, detail]), dtype=cv2.CV_8U), dtype=np.uint8)


def jpeg_roundtrip(image: NDArray[np.uint8], quality: int, chroma: str = "4:2:0") -> NDArray[np.uint8]:
    """``image`` through a JPEG encoder and decoder (libjpeg's, as a webcam's MJPG stream is decoded)."""
    params = [cv2.IMWRITE_JPEG_QUALITY, int(quality), cv2.IMWRITE_JPEG_SAMPLING_FACTOR, CHROMA_SAMPLING[chroma]]
    ok, buf = cv2.imencode(".jpg", image, params)
    if not ok:
        raise SimulationError("JPEG encoding failed")
    return np.asarray(cv2.imdecode(buf, cv2.IMREAD_COLOR), dtype=np.uint8)


class NoiseBank:
    """Precomputed unit Gaussian noise for a frame of ``shape``, read at random offsets each frame.

    Drawing a million Gaussians per frame costs more than the whole frame budget; instead a bank a little larger
    than the frame is drawn once and each frame reads it at a random offset and sign. The noise is applied as
    ``sigma(value) * z`` with ``sigma`` from a 256-entry table (signal-dependent shot noise), in saturating uint8
    arithmetic split into positive and negative parts.
    """

    MARGIN = 64
    Z_SCALE = 16.0  # z stored in 1/16 units: up to 6 sigma in a uint8
    SIGMA_SCALE = 16.0  # sigma table in 1/16 DN: up to ~16 DN

    def __init__(self, shape: tuple[int, int, int], correlation: float, seed: int) -> None:
        h, w, c = shape
        rng = np.random.default_rng(np.random.SeedSequence([seed, 0x0015E]))
        z = rng.standard_normal((h + self.MARGIN, w + self.MARGIN, c)).astype(np.float32)
        if correlation > 0:
            smooth = cv2.GaussianBlur(z, (3, 3), 0.8)
            z = (1.0 - correlation) * z + correlation * smooth
            z /= float(np.std(z))
        q = np.clip(np.rint(z * self.Z_SCALE), -6 * self.Z_SCALE, 6 * self.Z_SCALE)
        self.positive = np.maximum(q, 0).astype(np.uint8)
        self.negative = np.maximum(-q, 0).astype(np.uint8)
        self.shape = shape

    def draw(self, rng: np.random.Generator) -> tuple[int, int, bool]:
        """This frame's read of the bank: row and column offsets and whether the sign is flipped."""
        oy, ox = (int(v) for v in rng.integers(0, self.MARGIN, 2))
        return oy, ox, bool(rng.random() < 0.5)

    def add(
        self, rows: NDArray[np.uint8], row0: int, sigma_lut: NDArray[np.uint8], draw: tuple[int, int, bool]
    ) -> None:
        """Add noise in place to ``rows`` (a band of the frame starting at row ``row0``); ``sigma_lut`` (1, 256)
        uint8 gives sigma per value in 1/16 DN; ``draw`` from :meth:`draw` (the same for every band of a frame)."""
        oy, ox, flip = draw
        n, w = rows.shape[0], rows.shape[1]
        pos = self.positive[oy + row0 : oy + row0 + n, ox : ox + w]
        neg = self.negative[oy + row0 : oy + row0 + n, ox : ox + w]
        if flip:
            pos, neg = neg, pos
        sigma = cv2.LUT(rows, sigma_lut)
        scale = 1.0 / (self.Z_SCALE * self.SIGMA_SCALE)
        up = cv2.multiply(sigma, pos, scale=scale)
        down = cv2.multiply(sigma, neg, scale=scale)
        cv2.add(rows, up, dst=rows)
        cv2.subtract(rows, down, dst=rows)


def noise_sigma_lut(noise: SensorNoise, gain: float, gamma: float) -> NDArray[np.uint8]:
    """(1, 256) uint8: noise sigma (1/16 DN) of each output value for a camera at analogue ``gain``.

    Output linear value ``l`` came from a sensor signal ``l / gain``; its noise ``gain * sqrt(read^2 +
    (l / gain) / full_well)`` is carried through the tone curve by its slope (capped near black, where real
    cameras' curves turn linear). Value 255 gets none: it stands for every clipped (saturated) pixel.
    """
    values = np.arange(256, dtype=np.float64) / 255.0
    lin = values**gamma
    sigma_lin = gain * np.sqrt(noise.read_noise**2 + (lin / max(gain, 1e-9)) / noise.full_well)
    slope = np.minimum(255.0 / gamma * np.maximum(lin, 1e-12) ** (1.0 / gamma - 1.0), 1500.0)
    sigma_dn = sigma_lin * slope
    sigma_dn[255] = 0.0  # a clipped pixel is saturated: full well, no noise left to see
    return np.clip(np.rint(sigma_dn * NoiseBank.SIGMA_SCALE), 0, 255).astype(np.uint8).reshape(1, 256)
