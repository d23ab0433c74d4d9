"""A camera's colour processing: sensor crosstalk, white balance (fixed or automatic) and the tone curve.

Everything here acts on linear light (1.0 = sensor white at the nominal exposure), before the tone curve turns it
into 8-bit values, as in a real camera's image signal processor:

* **crosstalk**: the sensor's colour filters overlap and its colour-correction matrix undoes that only in part, so
  each output channel is a mix of the three: a 3x3 matrix whose rows sum to 1 (a grey stays grey, colours lose or
  gain a little saturation and turn a little in hue);
* **white balance**: per-channel gains. A fixed white balance set for another light tints everything (a camera set
  for daylight under warm lamps renders their white orange); the automatic one (:class:`AutoWhiteBalance`) follows
  the scene's mean colour with a lag, so when a warm sunlit patch grows the whole picture turns colder;
* **tone curve**: the camera's transfer function: a pure power law (``gamma``), the sRGB curve (IEC 61966-2-1:
  linear toe, then a 1/2.4 power) or the BT.709 curve (linear toe, then a 0.45 power).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from edge.errors import SimulationError

FloatArray = NDArray[np.float64]
Bgr = tuple[float, float, float]
TONE_CURVES = ("gamma", "srgb", "bt709")
IDENTITY: tuple[Bgr, Bgr, Bgr] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


@dataclass(frozen=True)
class ColourResponse:
    """A camera's colour processing. ``crosstalk``: 3x3, row ``i`` gives output channel ``i`` (B, G, R) as a mix of
    the three input channels, rows summing to 1. ``white_balance``: (B, G, R) gains relative to a white balance
    that renders the lamps' light grey. ``tone``: the tone curve, one of :data:`TONE_CURVES` (``gamma`` uses
    ``Exposure.gamma``)."""

    crosstalk: tuple[Bgr, Bgr, Bgr] = IDENTITY
    white_balance: Bgr = (1.0, 1.0, 1.0)
    tone: str = "gamma"

    def __post_init__(self) -> None:
        if self.tone not in TONE_CURVES:
            raise SimulationError(f"colour response: tone must be one of {', '.join(TONE_CURVES)}")
        m = np.asarray(self.crosstalk, dtype=np.float64)
        if m.shape != (3, 3) or not np.allclose(m.sum(axis=1), 1.0, atol=1e-6):
            raise SimulationError("colour response: crosstalk is a 3x3 matrix whose rows sum to 1")
        if min(self.white_balance) <= 0:
            raise SimulationError("colour response: white balance gains must be positive")

    @property
    def matrix(self) -> FloatArray:
        """(3, 3) linear light on the sensor -> linear camera values: white balance after crosstalk."""
        return np.diag(np.asarray(self.white_balance, dtype=np.float64)) @ np.asarray(self.crosstalk)

    @property
    def is_identity(self) -> bool:
        return bool(np.allclose(self.matrix, np.eye(3)))


def crosstalk_matrix(share: float, rng: np.random.Generator | None = None) -> tuple[Bgr, Bgr, Bgr]:
    """A crosstalk matrix leaking ``share`` of each channel into its spectral neighbours (blue <-> green <-> red;
    red and blue barely overlap), rows summing to 1; with ``rng`` each leak varies by +-30 %."""
    jitter = (lambda: float(rng.uniform(0.7, 1.3))) if rng is not None else (lambda: 1.0)
    b_g, g_b, g_r, r_g = (share * jitter() for _ in range(4))
    b_r, r_b = 0.15 * share * jitter(), 0.15 * share * jitter()
    return (
        (1.0 - b_g - b_r, b_g, b_r),
        (g_b, 1.0 - g_b - g_r, g_r),
        (r_b, r_g, 1.0 - r_b - r_g),
    )


@dataclass(frozen=True)
class AutoWhiteBalance:
    """Grey-world automatic white balance with a lag: each frame the gains move ``rate`` of the way (in log terms)
    towards the gains that would turn the mean colour of the frame seen ``delay_frames`` ago grey, corrected by
    ``strength`` (webcams correct a colour cast only partly), within [1 / max_gain, max_gain]. Green is the
    reference channel (gain 1)."""

    rate: float = 0.08
    delay_frames: int = 3
    strength: float = 0.7
    max_gain: float = 2.0

    def __post_init__(self) -> None:
        if not (0 < self.rate <= 1 and 0 <= self.strength <= 1 and self.max_gain >= 1 and self.delay_frames >= 0):
            raise SimulationError("auto white balance: rate in (0, 1], strength in [0, 1], max_gain >= 1")


def awb_gains(mean_bgr: FloatArray, awb: AutoWhiteBalance | None) -> FloatArray:
    """(N, 3) per-frame (B, G, R) gains of the automatic white balance for the scene's (N, 3) mean colours (linear,
    after the camera's fixed colour response). Starts converged on frame 0's colour."""
    means = np.asarray(mean_bgr, dtype=np.float64).reshape(-1, 3)
    if awb is None or len(means) == 0:
        return np.ones_like(means)
    safe = np.maximum(means, 1e-6)
    target = np.clip((safe[:, 1:2] / safe) ** awb.strength, 1.0 / awb.max_gain, awb.max_gain)
    out = np.empty_like(target)
    g = target[0].copy()
    for i in range(len(target)):
        seen = target[max(i - awb.delay_frames, 0)]
        g = g * (seen / g) ** awb.rate
        out[i] = g
    return out


def tone_encode(linear: FloatArray, tone: str, gamma: float) -> FloatArray:
    """Linear light (0..1, clipped) to the camera's encoded value (0..1) through its tone curve."""
    x = np.clip(np.asarray(linear, dtype=np.float64), 0.0, 1.0)
    if tone == "gamma":
        return np.asarray(x ** (1.0 / gamma))
    if tone == "srgb":
        return np.asarray(np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1.0 / 2.4) - 0.055))
    if tone == "bt709":
        return np.asarray(np.where(x < 0.018, 4.5 * x, 1.099 * x**0.45 - 0.099))
    raise SimulationError(f"unknown tone curve {tone!r}")


def tone_table(tone: str, gamma: float, working_gamma: float) -> NDArray[np.uint8] | None:
    """(256,) uint8 look-up table from 8-bit values encoded with the renderer's working power law
    (``working_gamma``) to the camera's tone curve; None when they are the same curve."""
    if tone == "gamma" and math.isclose(gamma, working_gamma):
        return None
    lin = (np.arange(256, dtype=np.float64) / 255.0) ** working_gamma
    return np.asarray(np.clip(np.rint(tone_encode(lin, tone, gamma) * 255.0), 0, 255), dtype=np.uint8)
