"""A rolling shutter: the simulator draws a moving rover where it is when its row is exposed, and the tracker with
``line_time_us`` takes its centre back to the frame's time (``docs/tracking.md``, "A rolling shutter")."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from edge.camera import paper_camera
from edge.filtering import ConstantVelocityFilter, FilterSettings
from edge.sim.effects import Effects, Optics, RollingShutter, at_row_times
from edge.sim.render import Renderer
from edge.sim.scene import RED_BGR, RoverLook, Scene
from edge.sim.world import RoverState, WorldState
from edge.tracker_config import RoverConfig, TrackerConfig
from edge.trackers.base import CameraPlaneMapping
from edge.trackers.factory import build_tracker
from edge.tracking import Frame

LINE_S = 1.0 / (30.0 * 750.0)  # 720 rows read out in a 30 fps frame
SPEED_CM_S = 30.0


def test_a_rover_is_drawn_where_it_is_when_its_row_is_exposed() -> None:
    """Row 0's exposure is the frame's time; row ``n`` was exposed ``n`` line times later."""
    rover = RoverState("r", 100.0, 200.0, 0.5, 30.0, -10.0, 31.6, 2.0)
    (moved,) = at_row_times((rover,), [450.0], LINE_S)
    dt = 450.0 * LINE_S
    assert moved.x_cm == pytest.approx(100.0 + 30.0 * dt)
    assert moved.y_cm == pytest.approx(200.0 - 10.0 * dt)
    assert moved.theta_rad == pytest.approx(0.5 + 2.0 * dt)
    (first_row,) = at_row_times((rover,), [0.0], LINE_S)
    assert (first_row.x_cm, first_row.y_cm) == (100.0, 200.0)


def test_a_measurement_is_moved_to_the_frames_time_by_its_rows_delay() -> None:
    """Sign and size of the correction: a marker 450 rows down was seen 20 ms late, 0.6 cm ahead of where a rover at
    30 cm/s is at the frame's time; in row 0 nothing moves; without a filter (acquisition) the measurement stands.
    The filter's prediction the shape checks compare a blob with is the one at its row's time."""
    from edge.rover_track import Observation, RoverTrack
    from edge.trackers.base import Measurement

    r = np.diag([0.01, 0.01])
    track = RoverTrack(RoverConfig(id="red", color_bgr=(40, 40, 200)), 0, line_time_s=LINE_S)

    def seen(x: float, row: float) -> Observation:
        return Observation(Measurement((x, 5.0), (600.0, row), 360.0, 1.0, 1.0, 0.0, 1.28, False), r)

    assert track.at_frame_time(seen(10.0, 450.0)).measurement.xy_cm == (10.0, 5.0)  # no filter yet
    track.filter = ConstantVelocityFilter(FilterSettings(), (0.0, 5.0), r)
    for i in range(1, 30):
        track.filter.predict(1.0 / 30.0)
        track.filter.update(np.array([SPEED_CM_S * i / 30.0, 5.0]), r)
    track.filter.back_to_frame_time((0.0, 0.0), r, 1e-9)  # the estimate moved once, as on the first correction
    ahead = 450.0 * LINE_S * SPEED_CM_S
    moved = track.at_frame_time(seen(10.0, 450.0))
    assert moved.measurement.xy_cm[0] == pytest.approx(10.0 - ahead, abs=0.01)
    assert moved.ahead_cm[0] == pytest.approx(ahead, abs=0.01)
    assert track.at_frame_time(seen(10.0, 0.0)).measurement.xy_cm == (10.0, 5.0)
    x, _ = track.filter.position
    on_time = seen(x + ahead, 450.0).measurement  # where the rover is when its row is exposed
    assert track.innovation_cm(on_time) == pytest.approx(0.0, abs=0.01)


def test_the_filter_moves_its_estimate_once_when_the_correction_begins() -> None:
    """Its first two measurements are taken as measured (no velocity yet); when the correction begins, the estimate
    that followed them is moved by as much, so the corrected measurements show no step (read as braking, a step of
    0.8 cm halved the velocity for several frames)."""
    r = np.diag([0.01, 0.01])
    f = ConstantVelocityFilter(FilterSettings(), (0.0, 0.0), r)
    assert f.back_to_frame_time((1.0, 2.0), r, 0.02) == ((1.0, 2.0), r)  # no velocity yet: as it is
    for i in range(1, 30):
        f.predict(1.0 / 30.0)
        f.update(np.array([SPEED_CM_S * i / 30.0, 0.0]), r)
    before = f.position
    (x, y), widened = f.back_to_frame_time((10.0, 5.0), r, 0.02)
    assert x == pytest.approx(10.0 - 0.02 * SPEED_CM_S, abs=0.01) and y == pytest.approx(5.0, abs=0.01)
    assert f.position[0] == pytest.approx(before[0] - 0.02 * SPEED_CM_S, abs=0.01)  # moved once ...
    f.back_to_frame_time((10.0, 5.0), r, 0.02)
    assert f.position[0] == pytest.approx(before[0] - 0.02 * SPEED_CM_S, abs=0.01)  # ... not again
    assert np.all(np.diag(widened) > np.diag(r))  # the velocity's uncertainty over 20 ms counts


def _drive(renderer: Renderer, line_time_us: float, y_cm: float, first: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """A red rover driving along +x at 30 cm/s at ``y_cm``: the tracker's errors (x, y) against the truth at the
    frame's time, from frame ``first`` on, and the image rows it was seen at."""
    camera = renderer.camera
    colour = renderer.nominal_marker_bgr("red")
    config = TrackerConfig(rovers=(RoverConfig(id="red", color_bgr=colour),), line_time_us=line_time_us)
    tracker = build_tracker(config, CameraPlaneMapping(camera, 13.0), renderer.background(0))
    errors, rows = [], []
    for i in range(45):
        truth = RoverState("red", 60.0 + SPEED_CM_S * i / 30.0, y_cm, 0.0, SPEED_CM_S, 0.0, SPEED_CM_S)
        image = renderer.render(WorldState(i / 30.0, (truth,)), i)
        estimates = tracker.process(Frame(image, i, i / 30.0, i / 30.0)).estimates
        if i >= first:
            assert len(estimates) == 1
            e = estimates[0]
            errors.append((e.x_cm - truth.x_cm, e.y_cm - truth.y_cm))
            rows.append(e.uv_px[1])
    return np.array(errors), np.array(rows)


@pytest.mark.slow
def test_a_rover_seen_late_by_a_rolling_shutter_is_placed_where_it_is_at_the_frames_time() -> None:
    """Near the bottom of the frame (about row 570) a rolling shutter exposes the marker 25 ms after the first row:
    a rover at 30 cm/s is drawn 0.76 cm ahead. Without the setting the tracker reports it there; with the camera's
    line time it is where a global shutter shows it (within 0.01 cm on average) from its third frame on; near the
    top (rows 100-140) the skew is a fifth of it."""
    camera = paper_camera()
    look = RoverLook("red", RED_BGR)
    effects = Effects(auto_exposure=None, noise=None, optics=Optics(0.6), rolling_shutter=RollingShutter(LINE_S))
    rolling = Renderer(camera, Scene((look,)), effects)
    near_y = 40.0  # near the camera: the bottom rows
    plain, rows = _drive(rolling, 0.0, near_y)
    assert rows.min() > 500.0
    skew = SPEED_CM_S * rows.mean() * LINE_S
    assert plain[:, 0].mean() == pytest.approx(skew, abs=0.05)  # seen ahead by the row's delay
    corrected, _ = _drive(rolling, LINE_S * 1e6, near_y, first=2)
    global_shutter = Renderer(camera, Scene((look,)), replace(effects, rolling_shutter=None))
    reference, _ = _drive(global_shutter, 0.0, near_y, first=2)
    assert np.abs(corrected.mean(axis=0) - reference.mean(axis=0)).max() < 0.01  # as on a global shutter
    assert np.abs(corrected - reference).max() < 0.05 < skew  # from the third frame on
    far, far_rows = _drive(rolling, 0.0, 480.0)  # far from the camera: the top rows, a small skew
    assert far_rows.max() < 200.0
    assert far[:, 0].mean() < plain[:, 0].mean() / 3.0
