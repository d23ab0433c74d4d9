"""Rendered runs and their scores, shared by the tracking benchmarks (``bench_tracking.py``).

A :class:`Clip` is one scenario run rendered in memory (frames, ground truth, the camera and the rovers' colours as
that camera sees them); :func:`run_clip` tracks it and scores every rover against the truth (marker centre on the
markers' plane):

* error: distance of every reported pose from its rover's true centre; bias: the mean error vector (x, y) of the
  poses within 5 cm of the truth;
* detection: share of frames with the marker wholly in view and unhidden (visible >= 0.99) that got a pose;
* swap: a pose more than 5 cm off and nearer another rover's true centre than its own;
* ghost: any other pose more than 5 cm off (something that is not this rover taken for it: a shirt, a box, a
  reflection, or a rover reported where it is not);
* heading: |error| of the rovers moving faster than 2 cm/s that got one (median, 95th percentile, coverage).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from edge.centre_offsets import InlineFits
from edge.sim.effects import Effects
from edge.tracker_config import TrackerConfig
from edge.trackers.base import CameraPlaneMapping
from edge.trackers.factory import build_tracker
from edge.tracking import Frame

FAR_CM = 5.0  # a pose farther than this from its rover's true centre is a swap or a ghost


@dataclass
class Clip:
    """Rendered frames of one scenario run with their ground truth (id -> x, y, theta, vx, vy, visible)."""

    name: str
    seed: int
    fps: float
    frames: list[np.ndarray]
    truth: list[dict[str, tuple[float, float, float, float, float, float]]]
    rovers: tuple
    camera: object
    background: np.ndarray
    height_cm: float = 13.0
    camera_name: str = "nominal"
    bodies: str = ""
    sharpened: bool = False  # the camera's processor sharpens its luma (the tracker is told, as a SimSource tells it)


def render_clip(
    name: str,
    seed: int,
    frames: int | None = None,
    rovers: int | None = None,
    heading: str = "plain",
    camera: str = "nominal",
    chroma: str | None = None,
    quality: int | None = None,
    line_time_s: float | None = None,
    sharpen: float | None = None,
    demosaic: str | None = None,
    floor: str = "tiles",
    off: tuple[str, ...] = (),
) -> Clip:
    """Render scenario ``name`` for ``seed`` through the nominal camera or one of the family (``camera``);
    ``chroma``, ``quality``: that camera's JPEG chroma sampling (``4:4:4``, ``4:2:2``, ``4:2:0``) or quality
    replaced, all else kept; ``line_time_s``: a rolling shutter with that line time (``edge.sim.effects``);
    ``sharpen``, ``demosaic``: its processor's sharpening (0: none) or demosaicing (``none``: no Bayer filter);
    ``floor``: the floor's material (``edge.sim.scene.FLOORS``; named after the bodies when not the default tiles);
    ``off``: the camera's effects of those names switched off (:func:`without`)."""
    from dataclasses import replace

    from edge.sim.cameras import processing_name
    from edge.sim.effects import Compression, RollingShutter, SignalProcessing
    from edge.sim.scenarios import build

    setup = build(name, seed, rovers, frames, heading, camera, floor)  # type: ignore[arg-type]
    if off:
        setup = replace(
            setup, effects=without(setup.effects, off), camera_name=f"{setup.camera_name} without {','.join(off)}"
        )
    if line_time_s is not None:
        setup = replace(setup, effects=replace(setup.effects, rolling_shutter=RollingShutter(line_time_s)))
    if chroma is not None or quality is not None:
        drawn = setup.effects.compression or Compression()
        stream = replace(drawn, chroma=chroma or drawn.chroma, quality=quality or drawn.quality)
        setup = replace(
            setup,
            effects=replace(setup.effects, compression=stream),
            camera_name=setup.camera_name.replace(drawn.chroma, stream.chroma, 1).replace(
                f"q{drawn.quality}", f"q{stream.quality}", 1
            ),
        )
    if sharpen is not None or demosaic is not None:
        had = setup.effects.processing or SignalProcessing(None)  # none: no filter, no sharpening
        method = had.demosaic if demosaic is None else {"none": None}.get(demosaic, demosaic)
        processor = replace(had, sharpen=had.sharpen if sharpen is None else sharpen, demosaic=method)
        setup = replace(
            setup,
            effects=replace(setup.effects, processing=processor),
            camera_name=setup.camera_name.removesuffix(processing_name(had)) + processing_name(processor),
        )
    renderer = setup.renderer()
    world = setup.world()
    images, truth = [], []
    for i in range(setup.frames):
        state = world.state_at(i / setup.fps)
        images.append(renderer.render(state, i))
        truth.append(
            {
                r.rover_id: (
                    r.x_cm,
                    r.y_cm,
                    r.theta_rad,
                    r.vx_cm_s,
                    r.vy_cm_s,
                    renderer.visibility.get(r.rover_id, 0.0),
                )
                for r in state.rovers
            }
        )
    configs = setup.rover_configs(renderer)
    if heading == "two_tone":
        looks = {look.rover_id: look for look in setup.scene.rovers}
        configs = tuple(
            c.model_copy(
                update={"front_color_bgr": renderer.nominal_bgr(looks[c.id].secondary_bgr, looks[c.id].body_height_cm)}
            )
            for c in configs
        )
    bodies = ", ".join(sorted({_body_name(look.body_bgr) for look in setup.scene.rovers}))
    return Clip(
        name,
        seed,
        setup.fps,
        images,
        truth,
        configs,
        setup.camera,
        renderer.background(0),
        setup.marker_height_cm,
        setup.camera_name,
        f"{bodies} bodies {setup.marker_height_cm:.0f} cm" + ("" if floor == "tiles" else f" on {floor}"),
        setup.effects.sharpens,
    )


EFFECTS_OFF = ("noise", "vignetting", "colour", "awb", "jpeg", "sharpen", "demosaic", "motion", "exposure")


def without(effects: Effects, names: tuple[str, ...]) -> Effects:
    """``effects`` with the named ones (:data:`EFFECTS_OFF`) switched off: sensor noise, vignetting, the colour
    response (``colour``: crosstalk, white-balance error and tone curve back to the nominal camera's), automatic
    white balance, the JPEG stream, the processor's sharpening or its Bayer demosaicing, motion blur, automatic
    exposure."""
    from dataclasses import replace

    from edge.sim.colour import ColourResponse

    unknown = sorted(set(names) - set(EFFECTS_OFF))
    if unknown:
        raise ValueError(f"unknown effects {', '.join(unknown)}: choose from {', '.join(EFFECTS_OFF)}")
    e = effects
    fields = {"noise": "noise", "vignetting": "vignetting", "awb": "auto_white_balance", "jpeg": "compression"}
    changes: dict[str, Any] = {fields[n]: None for n in names if n in fields}
    if "colour" in names:
        changes["colour"] = ColourResponse()
    if "motion" in names:
        changes["motion_blur"] = False
    if "exposure" in names:
        changes["auto_exposure"] = None
    processing = e.processing
    if processing is not None and "sharpen" in names:
        processing = replace(processing, sharpen=0.0)
    if processing is not None and "demosaic" in names:
        processing = replace(processing, demosaic=None)
    changes["processing"] = processing
    return replace(e, **changes)


def _body_name(bgr: tuple[float, float, float]) -> str:
    grey = sum(bgr) / 3.0
    return "black" if grey < 0.07 else "dark grey" if grey < 0.3 else "white"


def frame_of(image: np.ndarray, index: int, fps: float) -> Frame:
    t = index / fps
    return Frame(image=image, index=index, t_capture_s=t, t_mono_s=t)


@dataclass
class RoverScore:
    """One rover's (or several runs' of one colour) tallies."""

    errors: list[float] = field(default_factory=list)
    offsets: list[tuple[float, float]] = field(default_factory=list)  # (dx, dy) of poses within FAR_CM
    visible: int = 0
    detected: int = 0
    visible_half: int = 0
    detected_half: int = 0
    swaps: int = 0
    ghosts: int = 0
    heading_errors: list[float] = field(default_factory=list)
    heading_errors_still: list[float] = field(default_factory=list)
    still: int = 0
    moving: int = 0

    def add(self, other: RoverScore) -> None:
        for name in self.__dataclass_fields__:
            mine = getattr(self, name)
            if isinstance(mine, list):
                mine.extend(getattr(other, name))
            else:
                setattr(self, name, mine + getattr(other, name))


@dataclass
class Score:
    """A run's (or several runs') scores: per rover id, and the processing time per frame."""

    rovers: dict[str, RoverScore] = field(default_factory=dict)
    ms: list[float] = field(default_factory=list)
    stages: list[dict[str, float]] = field(default_factory=list)  # per frame: stage -> ms (absent: did not run)

    def rover(self, rover_id: str) -> RoverScore:
        return self.rovers.setdefault(rover_id, RoverScore())

    def add(self, other: Score) -> None:
        for rid, s in other.rovers.items():
            self.rover(rid).add(s)
        self.ms += other.ms
        self.stages += other.stages

    def total(self) -> RoverScore:
        out = RoverScore()
        for s in self.rovers.values():
            out.add(s)
        return out

    def row(self) -> dict[str, float]:
        """Summary over every rover (plus the worst colour's bias and the median time per frame)."""
        r = summary(self.total())
        r["worst_bias"] = max((summary(s)["bias"] for s in self.rovers.values()), default=math.nan)
        r["ms"] = float(np.median(self.ms)) if self.ms else math.nan
        return r


def summary(s: RoverScore) -> dict[str, float]:
    e = np.asarray(s.errors) if s.errors else np.array([math.nan])
    off = np.asarray(s.offsets) if s.offsets else np.full((1, 2), math.nan)
    h = np.asarray(s.heading_errors) if s.heading_errors else np.array([math.nan])
    bx, by = (float(v) for v in off.mean(axis=0))
    return {
        "mean": float(e.mean()),
        "p95": float(np.percentile(e, 95)),
        "max": float(e.max()),
        "bias_x": bx,
        "bias_y": by,
        "bias": math.hypot(bx, by),
        "det": s.detected / s.visible if s.visible else math.nan,
        "det50": s.detected_half / s.visible_half if s.visible_half else math.nan,
        "swaps": float(s.swaps),
        "ghosts": float(s.ghosts),
        "head": float(np.median(h)),
        "head_p95": float(np.percentile(h, 95)),
        "head_cov": len(s.heading_errors) / s.moving if s.moving else math.nan,
        "head_still": float(np.median(s.heading_errors_still)) if s.heading_errors_still else math.nan,
        "head_still_cov": len(s.heading_errors_still) / s.still if s.still else math.nan,
    }


def plane_mapping(clip: Clip, calibration: str) -> object:
    """``camera``: the scene camera itself at the markers' height (the tracker's error alone). ``points``: a
    calibration fitted with ``edge.calibration`` to 34 points surveyed at the markers' height with 0.5 px measuring
    noise (the whole system's error), with the lens intrinsics given when the camera has distortion (as
    ``edge-ips calibrate intrinsics`` would provide). ``targets``: the same clicks moved onto printed targets on the
    points in a rendered photo of them first (``calibrate points --refine-on``, ``edge.calibration.refine``)."""
    if calibration == "camera":
        return CameraPlaneMapping(clip.camera, clip.height_cm)  # type: ignore[arg-type]
    return survey_calibration(clip.camera, clip.height_cm, 1000 + clip.seed, refine=calibration == "targets")[0]


def survey_calibration(
    camera: object, height_cm: float, rng: int, noise_px: float = 0.5, refine: bool = False
) -> tuple[object, float]:
    """The ``points`` (``refine``: ``targets``) calibration of :func:`plane_mapping` for ``camera`` with the survey
    drawn from ``rng`` and clicked with ``noise_px`` RMS; also the clicks' RMS error as fitted (px)."""
    from edge.calibration import Intrinsics, calibrate_points
    from edge.calibration.points import point_table
    from edge.calibration.refine import refine_clicks
    from edge.sim.targets import survey_points, survey_target_frame

    cam = camera
    survey = survey_points(cam, height_cm=height_cm, noise_px=noise_px, rng=rng)  # type: ignore[arg-type]
    intrinsics = (
        Intrinsics(cam.camera_matrix, cam.dist_coeffs, cam.width_px, cam.height_px)  # type: ignore[attr-defined]
        if cam.has_distortion  # type: ignore[attr-defined]
        else None
    )
    clicks = survey.uv_px
    if refine:
        photo = survey_target_frame(cam, survey.xy_world_cm, height_cm, rng=rng)  # type: ignore[arg-type]
        clicks = refine_clicks(photo, clicks).uv_px
    fitted = calibrate_points(
        point_table(clicks, survey.xy_world_cm), (1280, 720), height_cm=height_cm, intrinsics=intrinsics
    )
    return fitted.calibration, float(np.sqrt(np.mean(np.sum((clicks - survey.uv_true_px) ** 2, axis=1))))


def run_clip(
    clip: Clip,
    method: str,
    use_background: bool | None = None,
    calibration: str = "camera",
    outline_fit: bool = False,
    edge_offsets: bool | str = False,
    line_time_us: float = 0.0,
) -> Score:
    """Track ``clip`` with ``method`` (the paper baseline gets the empty-scene reference; the others learn it
    unless ``use_background``; ``outline_fit``, ``edge_offsets``: the tracker settings of those names, the edge fits
    in the frame loop with their results held back as a worker would deliver them, ``edge.centre_offsets.InlineFits``;
    ``edge_offsets="worker"``: in their worker process, as the appliance runs them; ``line_time_us``: the tracker's
    rolling-shutter setting) and score it."""
    config = TrackerConfig(
        rovers=clip.rovers,  # type: ignore[arg-type]
        method=method,  # type: ignore[arg-type]
        fps=clip.fps,
        outline_fit=outline_fit,
        edge_offsets=bool(edge_offsets),
        line_time_us=line_time_us,
        camera_sharpens=clip.sharpened,
    )
    mapping = plane_mapping(clip, calibration)
    with_bg = (method == "paper") if use_background is None else use_background
    fits = InlineFits(config.edge_offsets_every) if edge_offsets is True else None
    tracker = build_tracker(config, mapping, clip.background if with_bg else None, fits=fits)  # type: ignore[arg-type]
    score = Score()
    for i, image in enumerate(clip.frames):
        t0 = time.perf_counter()
        result = tracker.process(frame_of(image, i, clip.fps))
        score.ms.append((time.perf_counter() - t0) * 1e3)
        score.stages.append(dict(result.stage_ms))
        _score_frame(score, clip.truth[i], {e.rover_id: e for e in result.estimates})
    close = getattr(tracker, "close", None)
    if close is not None:
        close()
    return score


def _score_frame(score: Score, truth: dict[str, tuple[float, ...]], got: dict[str, object]) -> None:
    for rid, (x, y, th, vx, vy, vis) in truth.items():
        s = score.rover(rid)
        if vis >= 0.99:
            s.visible += 1
            s.detected += rid in got
        if vis >= 0.5:
            s.visible_half += 1
            s.detected_half += rid in got
        e = got.get(rid)
        if e is None:
            continue
        ex, ey = e.x_cm - x, e.y_cm - y  # type: ignore[attr-defined]
        err = math.hypot(ex, ey)
        s.errors.append(err)
        if err > FAR_CM:
            others = [math.hypot(e.x_cm - o[0], e.y_cm - o[1]) for oid, o in truth.items() if oid != rid]  # type: ignore[attr-defined]
            if others and min(others) < err:
                s.swaps += 1
            else:
                s.ghosts += 1
            continue
        if vis >= 0.99:
            s.offsets.append((ex, ey))
        theta = e.theta_rad  # type: ignore[attr-defined]
        heading_error = None if theta is None else abs(math.degrees(math.remainder(theta - th, math.tau)))
        if math.hypot(vx, vy) > 2.0:
            s.moving += 1
            if heading_error is not None:
                s.heading_errors.append(heading_error)
        else:
            s.still += 1
            if heading_error is not None:
                s.heading_errors_still.append(heading_error)
