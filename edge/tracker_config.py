"""The tracker's configuration: the rovers to track and every setting of the tracking pipeline, validated once.

:class:`TrackerSettings` is the ``[tracker]`` section of the appliance's configuration file (``edge.config``);
:class:`TrackerConfig` adds the rovers, which the appliance configures in ``[[rovers]]`` tables. Every setting
reaches the code that uses it: ``edge.trackers.factory.build_tracker`` hands them to the window trackers, the filter and
the pipeline (``edge.pipeline``).
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import Annotated, Literal, TypeVar

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from edge.errors import ConfigError, describe_validation
from edge.messages import ID_PATTERN, id_problem

RoversT = TypeVar("RoversT", bound=Sequence["RoverConfig"])
Channel = Annotated[int, Field(ge=0, le=255)]
ColorBgr = tuple[Channel, Channel, Channel]


# the words an environment override may spell ``edge_offsets`` with (TOML has its own true and false)
_WORDS: dict[str, bool | str] = {"true": True, "yes": True, "on": True, "1": True, "auto": "auto"}
_WORDS.update({"false": False, "no": False, "off": False, "0": False})


class RoverConfig(BaseModel):
    """One rover to track: its id (the topic name) and its marker colour."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    id: str = Field(pattern=ID_PATTERN, description="Rover id, also the MQTT topic segment.")
    color_bgr: ColorBgr = Field(description="Nominal marker colour as seen by the camera, B, G, R 0-255.")
    front_color_bgr: ColorBgr | None = Field(
        default=None,
        description="Two-tone marker: colour of its light (white) front part as the camera sees it (the rest has "
        "color_bgr); it gives the heading even when the rover stands still. None: a one-colour marker.",
    )
    front_fraction: float = Field(default=0.3, gt=0.0, lt=1.0, description="Share of the marker's length in front.")


DEFAULT_ROVERS = (
    RoverConfig(id="red", color_bgr=(40, 40, 200)),
    RoverConfig(id="green", color_bgr=(60, 170, 40)),
    RoverConfig(id="blue", color_bgr=(190, 90, 30)),
)


Method = Literal["centroid", "particles", "meanshift", "paper"]
MAX_SHARE = 20.0  # the largest share of a nominal area or colour strength a range may reach


class TrackerSettings(BaseModel):
    """Everything the tracking pipeline can be tuned with (the ``[tracker]`` section of a configuration file).

    Every number is finite and bounded: an unbounded one (``fps = inf``, ``accel_sigma_cm_s2 = 1e308``) passed
    here and killed the tracker thread at its first frame, which systemd would restart forever."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    method: Method = Field(
        default="particles",
        description="centroid, particles or meanshift (the paper's three trackers, windowed); paper: the "
        "straightforward full-frame version of the paper's pipeline, for comparison.",
    )
    marker_length_cm: float = Field(
        default=21.5, gt=0.0, le=200.0, description="Marker side along the rover (21.5 x 16.8 cm: Table II, 361 cm^2)."
    )
    marker_width_cm: float = Field(default=16.8, gt=0.0, le=200.0, description="Marker side across the rover.")
    hue_tolerance_deg: float = Field(default=30.0, gt=0.0, le=90.0, description="Largest hue error of a marker.")
    min_saturation_fraction: float = Field(
        default=0.35, gt=0.0, le=1.0, description="Least relative saturation, as a share of the markers' own."
    )
    threshold_fraction: float = Field(
        default=0.5, gt=0.0, lt=1.0, description="k_min / k_max of the automatic threshold interval."
    )
    erosion_iterations: int = Field(default=1, ge=0, le=3, description="3x3 erosions before reconstruction.")
    background_threshold: float = Field(
        default=0.2, gt=0.0, le=10.0, description="eq. 2 threshold, in normalised chroma (lighting-invariant)."
    )
    background_refresh_s: float = Field(
        default=4.0, gt=0.0, le=3600.0, description="Time to refresh the whole reference."
    )
    window_margin_cm: float = Field(
        default=3.0,
        ge=0.0,
        le=500.0,
        description="Search window margin around the marker (plus 6 pixels for its edge band).",
    )
    lost_after_frames: int = Field(
        default=3,
        ge=1,
        le=100_000,
        description="Frames unseen in its window before a rover is searched for everywhere.",
    )
    acquire_scale: int = Field(
        default=4,
        ge=1,
        le=8,
        description="Largest downscale factor of the acquisition pass (smaller when the far side's markers are "
        "too few pixels to survive it).",
    )
    min_area_fraction: float = Field(
        default=0.9,
        gt=0.0,
        le=1.0,
        description="A marker showing less of its usual area is partly hidden or cut off: no pose (its centre would "
        "be biased).",
    )
    max_area_fraction: float = Field(
        default=1.3, ge=1.0, le=10.0, description="A larger blob is not one marker: no pose."
    )
    acquire_area_range: tuple[float, float] = Field(
        default=(0.5, 2.0),
        description="Blob area, as a share of the nominal marker area, accepted before the "
        "rover's own marker area has been learned.",
    )
    level_range: tuple[float, float] = Field(
        default=(0.4, 2.5),
        description="A marker's colour strength (chroma along its hue) as a share of the configured colour's: the "
        "light may change it this much; dark clothes of the same hue are far below.",
    )
    max_elongation_factor: float = Field(
        default=1.5,
        ge=1.0,
        le=10.0,
        description="A blob more elongated than the marker's own aspect times this is not it.",
    )
    max_speed_cm_s: float | None = Field(
        default=None,
        gt=0.0,
        le=10_000.0,
        description="Fastest a rover drives: a lost rover is looked for again only as far from where it was last "
        "seen as it could have driven since (something of its hue farther away, a shirt or a box, is not it); "
        "unset: anywhere (a rover carried elsewhere, or a video that starts again, is found at once).",
    )
    outline_fit: bool = Field(
        default=False,
        description="Centre of a one-colour marker from its fitted outline (edges in linear light) instead of its "
        "coverage centroid: less colour-dependent bias on some cameras, but about 3.5x the tracking time per frame; a "
        "fitted marker skips the area and shape checks (its edges showed its size).",
    )
    edge_offsets: bool | Literal["auto"] = Field(
        default="auto",
        description="Move each one-colour marker's coverage centre by the offset that full fits of its edges in the "
        "camera's encoded chroma find (edge.centre_offsets: a fit of one rover's window every edge_offsets_every "
        "frames, in a worker process): takes out the bias a stream's chroma subsampling (4:2:0) puts in the centre. "
        "A rover's centre moves once it has three fits. auto: on where the frames come through a camera's or a "
        "codec's colour path (a camera, a video file, a network stream, a simulated scene with compression), off "
        "for uncompressed simulated frames (edge_offsets_on).",
    )
    edge_offsets_every: int = Field(
        default=10, ge=1, le=1000, description="Frames between two edge fits (each one rover's window, in turn)."
    )
    heading_min_speed_cm_s: float = Field(
        default=3.0, ge=0.0, le=1000.0, description="Slowest motion that gives a heading."
    )
    accel_sigma_cm_s2: float = Field(
        default=40.0, gt=0.0, le=100_000.0, description="Filter process noise (acceleration)."
    )
    measurement_sigma_px: float = Field(default=0.15, gt=0.0, le=100.0, description="Marker centre noise in pixels.")
    fps: float = Field(
        default=30.0, gt=0.0, le=240.0, description="Frame rate assumed when frames carry no usable time."
    )
    line_time_us: float = Field(
        default=0.0,
        ge=0.0,
        le=1000.0,
        description="The camera's rolling shutter: the time between the exposures of two rows, us (0: a global "
        "shutter; about 44 for 720 rows read out in a 30 fps frame). A moving rover's centre is taken back to the "
        "frame's time, its first row's (not by method paper).",
    )

    @field_validator("edge_offsets", mode="before")
    @classmethod
    def _true_false_or_auto(cls, value: object) -> object:
        if isinstance(value, bool) or value == "auto":
            return value
        if isinstance(value, str) and value.strip().lower() in _WORDS:  # an EDGE_IPS_TRACKER__EDGE_OFFSETS override
            return _WORDS[value.strip().lower()]
        raise ValueError(f'must be true, false or "auto" (got {value!r})')

    @field_validator("acquire_area_range", "level_range")
    @classmethod
    def _share_range(cls, value: tuple[float, float]) -> tuple[float, float]:
        low, high = value
        if not 0.0 < low < high <= MAX_SHARE:
            raise ValueError(f"must be two shares, 0 < low < high <= {MAX_SHARE:g}")
        return value

    @property
    def marker_area_cm2(self) -> float:
        return self.marker_length_cm * self.marker_width_cm

    @property
    def marker_radius_cm(self) -> float:
        return 0.5 * math.hypot(self.marker_length_cm, self.marker_width_cm)


class TrackerConfig(TrackerSettings):
    """The settings and the rovers they track: what a tracker is built from (``edge.trackers.factory``)."""

    rovers: tuple[RoverConfig, ...] = Field(default=DEFAULT_ROVERS, min_length=1, max_length=64)
    # whether the frames' camera may sharpen its luma: the source's to say (``edge.sources.SourceInfo.sharpened``);
    # not known counts as may, as most webcams do by default. The edge fits weigh the luma by what the model misses.
    camera_sharpens: bool = True

    @field_validator("rovers")
    @classmethod
    def _unique_ids(cls, rovers: tuple[RoverConfig, ...]) -> tuple[RoverConfig, ...]:
        return require_unique_ids(rovers)

    @classmethod
    def of(cls, settings: TrackerSettings, rovers: Sequence[RoverConfig]) -> TrackerConfig:
        """``settings`` with ``rovers`` (the appliance's ``[tracker]`` section and ``[[rovers]]`` tables)."""
        return cls(rovers=tuple(rovers), **dict(settings))

    def for_source(self, chroma_spread: bool, sharpened: bool = True) -> TrackerConfig:
        """This configuration with ``edge_offsets`` decided for a source (:func:`edge_offsets_on`): the pipeline
        takes ``auto`` it is handed as off, not knowing where its frames come from; ``sharpened``: whether its
        camera may sharpen (:attr:`camera_sharpens`)."""
        update = {"edge_offsets": edge_offsets_on(self.edge_offsets, chroma_spread), "camera_sharpens": sharpened}
        return self.model_copy(update=update)


def edge_offsets_on(setting: bool | Literal["auto"], chroma_spread: bool) -> bool:
    """Whether the ``edge_offsets`` setting turns the edge fits on for a source whose frames have (``chroma_spread``)
    or have not been through a colour path that spreads the chroma (``edge.sources.SourceInfo.chroma_spread``):
    ``auto`` follows the source, ``true`` and ``false`` are what they say."""
    return chroma_spread if setting == "auto" else bool(setting)


def require_unique_ids(rovers: RoversT) -> RoversT:
    """``rovers`` unchanged when no two share an id (a validator's body: raises ValueError naming the repeats)."""
    problem = id_problem([r.id for r in rovers])
    if problem is not None:
        raise ValueError(problem)
    return rovers


def load_tracker_config(path: Path) -> TrackerConfig:
    """Read a TOML file: either a ``[tracker]`` table or the tracker keys at top level; ``[[rovers]]`` anywhere.

    Example::

        method = "particles"
        [[rovers]]
        id = "red"
        color_bgr = [40, 40, 200]
    """
    try:
        data = tomllib.loads(path.read_text())
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read ({exc.strerror})") from exc
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc})") from exc
    section = data.get("tracker", data)
    if "tracker" in data and "rovers" in data and "rovers" not in section:
        section = {**section, "rovers": data["rovers"]}
    try:
        return TrackerConfig.model_validate(section)
    except ValidationError as exc:
        raise ConfigError(f"{path}: {describe_validation(exc)}") from exc
