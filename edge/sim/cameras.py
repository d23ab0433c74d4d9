"""A family of cameras and rovers: each seed draws another webcam and another fleet's bodies.

The tracker must not be tuned to one camera. :func:`draw_camera` draws, from a seed, everything a webcam does
differently from another (the ranges are those of consumer webcams and their MJPG streams):

| property | range |
|---|---|
| chroma sampling | 4:2:0, 4:2:2 (MJPG from a YUYV pipeline) or 4:4:4, equally likely |
| JPEG quality | 60-95 |
| optical blur (lens, demosaicing, focus) | Gaussian sigma 0.3-1.2 px |
| tone curve | sRGB, BT.709, or a power law 2.0-2.4 |
| colour crosstalk | 0-15 % to the spectral neighbours |
| white balance error | red and blue gains within +-12 % |
| automatic white balance | on in half the cameras (strength 0.4-0.9, lag) |
| sensor noise | read noise 0.002-0.008, full well 800-6000 e-, 20-60 % demosaicing correlation |
| vignetting | strength 0.2-0.7 |
| Bayer demosaicing | bilinear or edge-aware, the filter at any of its four phases |
| sharpening of the luma | an unsharp mask of 0-1.5 times the detail finer than 0.6-1.4 px |

and :func:`draw_bodies` the rovers' bodies: black, dark grey or white (each rover its own), 8-20 cm tall (one
height per fleet: the marker plane is one plane), with 0.2-2.5 cm of the body's top showing around the marker.
All optics act on linear light before the tone curve and the JPEG encoder, as in a real camera; the demosaicing
on the sensor's light, the sharpening on the encoded luma just before the encoder. :func:`draw_processing` draws
the processor from its own stream of the seed, so a seed's camera is otherwise the one it drew before the processor
was part of the family.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from edge.sim.colour import AutoWhiteBalance, ColourResponse, crosstalk_matrix
from edge.sim.effects import (
    BAYER_PHASES,
    DEMOSAIC,
    Compression,
    Effects,
    Exposure,
    Optics,
    SensorNoise,
    SignalProcessing,
    Vignetting,
)
from edge.sim.scene import RoverLook
from edge.sim.setup import scenario_rng

BODY_ALBEDOS = {"black": 0.035, "dark grey": 0.12, "white": 0.80}
CHROMA = ("4:2:0", "4:2:2", "4:4:4")


@dataclass(frozen=True)
class CameraDraw:
    """One camera of the family: the effects it changes and a one-line description."""

    name: str
    optics: Optics
    vignetting: Vignetting
    noise: SensorNoise
    compression: Compression
    colour: ColourResponse
    gamma: float
    auto_white_balance: AutoWhiteBalance | None
    processing: SignalProcessing | None = None

    def with_processing(self, processing: SignalProcessing) -> CameraDraw:
        """This camera with ``processing`` as its image processor (named in its description)."""
        return replace(self, name=self.name + processing_name(processing), processing=processing)

    def apply(self, effects: Effects) -> Effects:
        """``effects`` seen by this camera (the scene's light, exposure time and motion are kept)."""
        return replace(
            effects,
            exposure=Exposure(effects.exposure.exposure_s, effects.exposure.scale, self.gamma),
            optics=self.optics,
            vignetting=self.vignetting,
            noise=self.noise,
            compression=self.compression,
            colour=self.colour,
            auto_white_balance=self.auto_white_balance or effects.auto_white_balance,
            processing=self.processing,
        )


def draw_camera(rng: np.random.Generator) -> CameraDraw:
    """A random webcam of the family (see the module's table)."""
    chroma = CHROMA[int(rng.integers(len(CHROMA)))]
    quality = int(rng.integers(60, 96))
    blur = float(rng.uniform(0.3, 1.2))
    tone_pick = int(rng.integers(3))
    tone = ("srgb", "bt709", "gamma")[tone_pick]
    gamma = float(rng.uniform(2.0, 2.4)) if tone == "gamma" else 2.2
    share = float(rng.uniform(0.0, 0.15))
    wb = (float(math.exp(rng.uniform(-0.12, 0.12))), 1.0, float(math.exp(rng.uniform(-0.12, 0.12))))
    awb = (
        AutoWhiteBalance(rate=float(rng.uniform(0.03, 0.15)), strength=float(rng.uniform(0.4, 0.9)))
        if rng.random() < 0.5
        else None
    )
    noise = SensorNoise(
        read_noise=float(rng.uniform(0.002, 0.008)),
        full_well=float(rng.uniform(800.0, 6000.0)),
        correlation=float(rng.uniform(0.2, 0.6)),
    )
    vignetting = Vignetting(float(rng.uniform(0.2, 0.7)))
    tone_name = f"gamma {gamma:.2f}" if tone == "gamma" else tone
    name = (
        f"{chroma} q{quality} blur {blur:.2f} {tone_name} xt {share:.2f} "
        f"wb {wb[2]:.2f}/{wb[0]:.2f}{' awb' if awb else ''}"
    )
    return CameraDraw(
        name,
        Optics(blur),
        vignetting,
        noise,
        Compression(quality, chroma),
        ColourResponse(crosstalk_matrix(share, rng), wb, tone),
        gamma,
        awb,
    )


def processing_name(processing: SignalProcessing | None) -> str:
    """How a camera's description names its processor: `` bilinear sharpen 0.60`` (empty: none)."""
    if processing is None:
        return ""
    demosaic = f" {processing.demosaic}" if processing.demosaic is not None else ""
    sharpen = f" sharpen {processing.sharpen:.2f}" if processing.sharpen > 0.0 else ""
    return demosaic + sharpen


def draw_processing(rng: np.random.Generator) -> SignalProcessing:
    """A webcam's image processor (see the module's table): its demosaicing and its sharpening."""
    method = DEMOSAIC[int(rng.integers(len(DEMOSAIC)))]
    phase = BAYER_PHASES[int(rng.integers(len(BAYER_PHASES)))]
    return SignalProcessing(method, phase, float(rng.uniform(0.0, 1.5)), float(rng.uniform(0.6, 1.4)))


def draw_bodies(looks: tuple[RoverLook, ...], rng: np.random.Generator) -> tuple[RoverLook, ...]:
    """The fleet's looks with bodies drawn from the family: colour per rover, one height, margins per rover."""
    height = float(rng.uniform(8.0, 20.0))
    names = list(BODY_ALBEDOS)
    out = []
    for look in looks:
        grey = BODY_ALBEDOS[names[int(rng.integers(len(names)))]]
        tint = rng.uniform(0.97, 1.03, 3) * grey  # paint is never perfectly neutral
        margin_l, margin_w = (float(rng.uniform(0.2, 2.5)) for _ in range(2))
        out.append(
            replace(
                look,
                body_bgr=(float(tint[0]), float(tint[1]), float(tint[2])),
                body_height_cm=height,
                body_length_cm=look.marker_length_cm + 2.0 * margin_l,
                body_width_cm=look.marker_width_cm + 2.0 * margin_w,
            )
        )
    return tuple(out)


def draw_family(name: str, seed: int, looks: tuple[RoverLook, ...]) -> tuple[CameraDraw, tuple[RoverLook, ...]]:
    """The webcam (with its processor) and the rovers' bodies that the family draws for scenario ``name`` and
    ``seed`` (the accuracy benchmark's runs, enrolment's stills): ``looks`` with their bodies drawn."""
    rng = scenario_rng(f"{name}/camera", seed)
    drawn = draw_camera(rng)
    looks = draw_bodies(looks, rng)
    return drawn.with_processing(draw_processing(scenario_rng(f"{name}/processing", seed))), looks
