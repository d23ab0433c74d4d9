"""Camera effects and scene effects: what real cameras and real rooms do to the picture.

Each effect is a small frozen description with its physical parameters plus a pure function of time or of an
image; the renderer (:mod:`edge.sim.render`) applies them. Light is handled in linear units (1.0 = sensor white at
the nominal exposure); the camera's tone curve (a power law, gamma 2.2) turns it into 8-bit values.

Camera effects
    exposure and tone curve, auto-exposure with lag, colour crosstalk and white balance, fixed or automatic with a
    lag (:mod:`edge.sim.colour`), sensor read and shot noise (spatially correlated by demosaicing), vignetting,
    motion blur over the exposure time, rolling flicker from mains lighting (each row is exposed at a different
    moment of the lamps' 100/120 Hz ripple), JPEG compression with subsampled chroma. Lens distortion is part of the
    camera model (:class:`edge.camera.PinholeCamera`). :mod:`edge.sim.cameras` draws whole cameras from a family.
Scene effects
    global illumination drift and lamps switching, a sunlit window patch that changes strength and colour
    temperature as clouds pass, a specular glare of the sun on the glossy floor, a person walking in and standing in
    the view for a while, boxes left standing in the area. Rovers leaving and re-entering the view are trajectories
    (:mod:`edge.sim.world`).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field, replace

import cv2
import numpy as np
from numpy.typing import NDArray

from edge.errors import SimulationError
from edge.sim.colour import AutoWhiteBalance, ColourResponse
from edge.sim.world import RoverState

FloatArray = NDArray[np.float64]
Bgr = tuple[float, float, float]
GAMMA = 2.2


# -- camera effects ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Exposure:
    """Fixed exposure: ``exposure_s`` integration time (sets motion blur and flicker), ``scale`` the linear value
    of a white (albedo 1) surface under the room's mean illumination, ``gamma`` the tone curve's exponent."""

    exposure_s: float = 1.0 / 60.0
    scale: float = 0.72
    gamma: float = GAMMA

    def __post_init__(self) -> None:
        if not (0 < self.exposure_s <= 1.0 and self.scale > 0 and self.gamma > 0):
            raise SimulationError("exposure: exposure_s in (0, 1], scale and gamma positive")


@dataclass(frozen=True)
class AutoExposure:
    """Auto-exposure with lag: each frame the gain moves ``rate`` of the way (in log terms) towards the gain that
    would restore the mean brightness measured ``delay_frames`` ago, within [min_gain, max_gain]. After a sudden
    change of light the picture is over- or under-exposed for a few frames."""

    rate: float = 0.25
    delay_frames: int = 2
    min_gain: float = 0.35
    max_gain: float = 3.0


@dataclass(frozen=True)
class SensorNoise:
    """Read and shot noise: variance ``read_noise^2 + signal / full_well`` (linear units, signal before gain).

    ``full_well``: electrons at sensor white (shot noise ~ sqrt(signal)). ``correlation``: share of the noise
    smoothed over 3x3 neighbours, as Bayer demosaicing spreads it.
    """

    read_noise: float = 0.003
    full_well: float = 2000.0
    correlation: float = 0.4


@dataclass(frozen=True)
class Optics:
    """Lens and demosaicing softness: a Gaussian point spread of ``blur_sigma_px`` pixels (an in-focus webcam lens
    and Bayer interpolation: about half a pixel). Symmetric, so it moves no centroid."""

    blur_sigma_px: float = 0.5


@dataclass(frozen=True)
class Vignetting:
    """Light fall-off towards the corners: ``1 - strength * (1 - cos^4(angle off axis))``."""

    strength: float = 0.5


@dataclass(frozen=True)
class Flicker:
    """Mains-powered lamps ripple at twice the mains frequency; a rolling shutter exposes row ``r`` at
    ``t + r * line_time_s``, so the ripple shows as horizontal bands that roll from frame to frame. The band
    amplitude is ``modulation * |sinc(2 f_mains * exposure_s)|`` (an exposure of whole ripple periods cancels it)."""

    mains_hz: float = 50.0
    modulation: float = 0.3
    line_time_s: float = 1.0 / (30.0 * 750.0)  # 720 active rows + blanking at 30 fps
    phase: float = 0.0


@dataclass(frozen=True)
class RollingShutter:
    """A rolling shutter's skew: row ``r`` is exposed ``r * line_time_s`` after row 0 (whose exposure is centred on
    the frame's time, as the flicker's rows are), so a moving rover is drawn where it is when its marker's row is
    exposed: at 30 cm/s about 1 cm lower in the frame than at its top (720 rows at 30 fps). People and the sun do
    not move fast enough for it to show."""

    line_time_s: float = 1.0 / (30.0 * 750.0)  # 720 active rows + blanking at 30 fps, as Flicker's

    def __post_init__(self) -> None:
        if not 0.0 <= self.line_time_s <= 1e-3:
            raise SimulationError("rolling_shutter: line_time_s must be 0-1 ms")


def at_row_times(rovers: tuple[RoverState, ...], rows_px: list[float], line_time_s: float) -> tuple[RoverState, ...]:
    """``rovers`` at the frame's time moved to where each is when its row (``rows_px``: its marker's centre row) is
    exposed: along its velocity and turn rate for ``row * line_time_s``."""
    out = []
    for r, row in zip(rovers, rows_px, strict=True):
        dt = max(row, 0.0) * line_time_s
        theta = math.remainder(r.theta_rad + r.omega_rad_s * dt, math.tau)
        out.append(replace(r, x_cm=r.x_cm + r.vx_cm_s * dt, y_cm=r.y_cm + r.vy_cm_s * dt, theta_rad=theta))
    return tuple(out)


CHROMA_SAMPLING = {
    "4:4:4": cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444,
    "4:2:2": cv2.IMWRITE_JPEG_SAMPLING_FACTOR_422,
    "4:2:0": cv2.IMWRITE_JPEG_SAMPLING_FACTOR_420,
}


@dataclass(frozen=True)
class Compression:
    """JPEG compression as an MJPG webcam delivers it, at ``quality`` (0-100), with its chroma sampled at
    ``chroma`` (``4:2:2``: half the horizontal resolution, as webcams that encode their YUYV stream send it;
    ``4:2:0``: half in both directions, libjpeg's default; ``4:4:4``: full)."""

    quality: int = 85
    chroma: str = "4:2:0"

    def __post_init__(self) -> None:
        if self.chroma not in CHROMA_SAMPLING:
            raise SimulationError(f"compression: chroma must be one of {', '.join(CHROMA_SAMPLING)}")
        if not 1 <= self.quality <= 100:
            raise SimulationError("compression: quality must be 1-100")


DEMOSAIC = ("bilinear", "edge-aware")
BAYER_PHASES = ((0, 0), (0, 1), (1, 0), (1, 1))  # where the filter's blue sites start (row, column)


@dataclass(frozen=True)
class SignalProcessing:
    """The camera's image signal processor between the sensor and the encoder: a Bayer colour filter whose missing
    colours are interpolated (``demosaic``: ``bilinear`` or ``edge-aware``, OpenCV's two quick methods; the blue
    sites start at ``bayer_phase``), and luma sharpening (an unsharp mask of ``sharpen`` times the detail finer than
    a Gaussian of ``sharpen_sigma_px``; 0: none). Webcams do both: the demosaicing puts colour fringes on sharp edges,
    the sharpening overshoots every edge (a dark halo outside a bright one)."""

    demosaic: str | None = "bilinear"
    bayer_phase: tuple[int, int] = (0, 0)
    sharpen: float = 0.0
    sharpen_sigma_px: float = 1.0

    def __post_init__(self) -> None:
        if self.demosaic is not None and self.demosaic not in DEMOSAIC:
            raise SimulationError(f"signal processing: demosaic must be one of {', '.join(DEMOSAIC)}")
        if self.bayer_phase not in BAYER_PHASES:
            raise SimulationError("signal processing: bayer_phase must be (0 or 1, 0 or 1)")
        if not 0.0 <= self.sharpen <= 4.0 or self.sharpen_sigma_px <= 0.0:
            raise SimulationError("signal processing: sharpen must be 0-4 and its sigma positive")


# -- scene effects ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class IlluminationDrift:
    """Room light ``1 + amplitude * sin(2 pi t / period_s + phase)`` times any lamp banks switched off:
    ``switches`` holds ``(t_off_s, t_on_s, factor)``: between those times the light is multiplied by ``factor``."""

    amplitude: float = 0.35
    period_s: float = 12.0
    phase: float = 0.0
    switches: tuple[tuple[float, float, float], ...] = ()


@dataclass(frozen=True)
class SunPatch:
    """Sunlight through a window: the window's ``window_cm`` corners (world cm, a planar quadrilateral) cast a
    sunlit patch on the floor along the sun's rays.

    The sun stands at ``elevation_deg``; its light travels along azimuth ``azimuth_deg`` (0: towards +x, -90:
    towards -y, i.e. from a window in the far wall towards the camera). ``strength``: irradiance of the clear beam on
    a horizontal surface relative to the room's mean lamp light. Clouds pass every ``cloud_period_s`` and dim the
    beam by up to ``cloud_depth``; its colour goes from ``clear_bgr`` (warm direct sun) towards ``cloudy_bgr``
    (bluish skylight) as it dims: a change of colour temperature. ``penumbra_cm``: the soft edge (the sun's disc).
    """

    window_cm: tuple[tuple[float, float, float], ...] = (
        (120.0, 700.0, 195.0),
        (275.0, 700.0, 195.0),
        (275.0, 700.0, 290.0),
        (120.0, 700.0, 290.0),
    )
    elevation_deg: float = 30.0
    azimuth_deg: float = -90.0
    strength: float = 1.5
    clear_bgr: Bgr = (0.74, 0.90, 1.0)
    cloudy_bgr: Bgr = (1.0, 0.96, 0.88)
    cloud_period_s: float = 7.0
    cloud_depth: float = 0.75
    cloud_phase: float = 0.0
    penumbra_cm: float = 1.5

    @property
    def travel(self) -> FloatArray:
        """(3,) unit direction the light travels (downwards)."""
        el, az = math.radians(self.elevation_deg), math.radians(self.azimuth_deg)
        return np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), -math.sin(el)])

    def patch_cm(self, z_cm: float) -> FloatArray:
        """(4, 2) the window's sunlit image on the horizontal plane at height ``z_cm``."""
        d = self.travel
        corners = np.asarray(self.window_cm, dtype=np.float64)
        t = (z_cm - corners[:, 2]) / d[2]
        return np.column_stack([corners[:, 0] + t * d[0], corners[:, 1] + t * d[1]])


def sun_mirror_point(camera_cm: FloatArray, sun: SunPatch) -> tuple[float, float]:
    """Floor point where the camera sees the sun reflected (the centre of the glare on a glossy floor)."""
    d = sun.travel
    up = np.array([d[0], d[1], -d[2]])  # the reflected ray, rising towards the camera
    t = camera_cm[2] / up[2]
    return float(camera_cm[0] - t * up[0]), float(camera_cm[1] - t * up[1])


@dataclass(frozen=True)
class Glare:
    """A specular glare of the sun on the glossy floor: a bright, desaturated (clipping to white) spot centred at
    ``(x_cm, y_cm)`` (where the camera sees the sun mirrored: :func:`sun_mirror_point`), spread by the floor's
    roughness over ``radius_cm`` and stretched ``elongation`` times along the line of sight; ``peak`` linear units at
    its core in the clear sun (it dims with the clouds). Only where the floor is sunlit."""

    x_cm: float = 195.75
    y_cm: float = 285.0
    radius_cm: float = 16.0
    elongation: float = 2.5
    peak: float = 3.0
    bgr: Bgr = (0.90, 0.96, 1.0)


@dataclass(frozen=True)
class Occluder:
    """A person walking into the view, standing a while and leaving: ``keyframes`` ``(t_s, x_cm, y_cm)`` walked
    in straight lines; absent before the first and after the last keyframe."""

    keyframes: tuple[tuple[float, float, float], ...]
    height_cm: float = 172.0
    shirt_bgr: Bgr = (0.30, 0.30, 0.32)
    trousers_bgr: Bgr = (0.12, 0.07, 0.05)
    skin_bgr: Bgr = (0.28, 0.36, 0.52)

    def __post_init__(self) -> None:
        times = [k[0] for k in self.keyframes]
        if len(times) < 2 or any(b < a for a, b in itertools.pairwise(times)):
            raise SimulationError("occluder: at least two keyframes with non-decreasing times")

    def pose(self, t_s: float) -> tuple[float, float, float, float] | None:
        """(x_cm, y_cm, heading_rad, distance walked cm) at ``t_s``, or None when absent."""
        keys = self.keyframes
        if t_s < keys[0][0] or t_s > keys[-1][0]:
            return None
        walked = 0.0
        heading = 0.0
        for (t0, x0, y0), (t1, x1, y1) in itertools.pairwise(keys):
            seg = math.hypot(x1 - x0, y1 - y0)
            if seg > 1e-9:
                heading = math.atan2(y1 - y0, x1 - x0)
            if t_s <= t1:
                f = 0.0 if t1 <= t0 else (t_s - t0) / (t1 - t0)
                return x0 + f * (x1 - x0), y0 + f * (y1 - y0), heading, walked + f * seg
            walked += seg
        _, x, y = keys[-1]
        return x, y, heading, walked


@dataclass(frozen=True)
class Prop:
    """A box put down in the area (a grey or white carton, a red crate) at ``appears_s`` and left there:
    ``size_cm`` (length along ``heading_rad``, width, height) at ``(x_cm, y_cm)``, diffuse ``albedo_bgr``. It hides
    what is behind it; it is part of the empty scene only from ``appears_s`` on."""

    x_cm: float
    y_cm: float
    size_cm: tuple[float, float, float] = (40.0, 30.0, 30.0)
    heading_rad: float = 0.0
    albedo_bgr: Bgr = (0.55, 0.55, 0.55)
    appears_s: float = 0.0


@dataclass(frozen=True)
class Effects:
    """Every effect of a scenario. ``None`` switches an effect off."""

    exposure: Exposure = Exposure()
    auto_exposure: AutoExposure | None = AutoExposure()
    colour: ColourResponse = field(default_factory=ColourResponse)
    auto_white_balance: AutoWhiteBalance | None = None
    noise: SensorNoise | None = SensorNoise()
    vignetting: Vignetting | None = Vignetting()
    optics: Optics | None = Optics()
    motion_blur: bool = True
    flicker: Flicker | None = None
    rolling_shutter: RollingShutter | None = None
    compression: Compression | None = None
    processing: SignalProcessing | None = None
    drift: IlluminationDrift | None = None
    sun: SunPatch | None = None
    glare: Glare | None = None
    occluders: tuple[Occluder, ...] = field(default_factory=tuple)
    props: tuple[Prop, ...] = field(default_factory=tuple)

    @property
    def sharpens(self) -> bool:
        """Whether the camera's processor sharpens its luma (``edge.sources.SourceInfo.sharpened``)."""
        return self.processing is not None and self.processing.sharpen > 0.0

    def describe(self) -> list[str]:
        """One line per active effect with its parameters (for ``scenario.json`` and the docs)."""
        lines = []
        names = ("exposure", "auto_exposure", "colour", "auto_white_balance", "noise", "optics", "vignetting")
        for name in (*names, "flicker", "rolling_shutter", "compression", "processing", "drift"):
            value = getattr(self, name)
            if value is not None:
                lines.append(f"{name}: {value}")
        if self.motion_blur:
            lines.append(f"motion_blur: over the {self.exposure.exposure_s * 1000:.1f} ms exposure")
        for name in ("sun", "glare"):
            value = getattr(self, name)
            if value is not None:
                lines.append(f"{name}: {value}")
        lines.extend(f"occluder: {o}" for o in self.occluders)
        lines.extend(f"prop: {p}" for p in self.props)
        return lines


# -- pure functions of time ------------------------------------------------------------------------------------
def drift_factor(drift: IlluminationDrift | None, t_s: float) -> float:
    """Room-light multiplier at ``t_s``."""
    if drift is None:
        return 1.0
    f = 1.0 + drift.amplitude * math.sin(2.0 * math.pi * t_s / drift.period_s + drift.phase)
    for t_off, t_on, factor in drift.switches:
        if t_off <= t_s < t_on:
            f *= factor
    return f


def sun_state(sun: SunPatch | None, t_s: float) -> tuple[float, FloatArray]:
    """(beam strength relative to room light, (3,) BGR colour of the beam) at ``t_s``."""
    if sun is None:
        return 0.0, np.ones(3)
    # Clouds: a smooth dip once per period, sharper than a sinusoid (a cloud passes, then clear sky).
    phase = (t_s / sun.cloud_period_s + sun.cloud_phase) % 1.0
    dip = math.exp(-(((phase - 0.5) / 0.16) ** 2))
    clear = 1.0 - sun.cloud_depth * dip
    mix = (1.0 - clear) / max(sun.cloud_depth, 1e-9) if sun.cloud_depth > 0 else 0.0
    colour = (1.0 - mix) * np.asarray(sun.clear_bgr) + mix * np.asarray(sun.cloudy_bgr)
    return sun.strength * clear, colour


def vignetting_map(camera_matrix: FloatArray, width_px: int, height_px: int, vig: Vignetting | None) -> FloatArray:
    """(H, W) relative illumination of each pixel (1 on the optical axis)."""
    if vig is None:
        return np.ones((height_px, width_px))
    fx, fy = camera_matrix[0, 0], camera_matrix[1, 1]
    cx, cy = camera_matrix[0, 2], camera_matrix[1, 2]
    u = (np.arange(width_px) - cx) / fx
    v = (np.arange(height_px) - cy) / fy
    r2 = v[:, None] ** 2 + u[None, :] ** 2
    cos4 = 1.0 / (1.0 + r2) ** 2
    return np.asarray(1.0 - vig.strength * (1.0 - cos4))
