"""The detections contract: canonical bytes, the covariance a board attaches, and ``edge-ips track --detections``."""

from __future__ import annotations

import csv
import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given
from hypothesis import strategies as st

from edge.board_messages import DETECTIONS_MAX_BYTES, parse_detections
from edge.camera import paper_camera
from edge.cli import main
from edge.errors import MessageError
from edge.fusion.detections import Detection, Detections, encode_detections, from_message
from edge.fusion.uncertainty import (
    CalibrationErrorModel,
    DetectionBuilder,
    calibration_error_model,
    image_quality,
)
from edge.messages import dumps
from edge.trackers.base import CameraPlaneMapping
from edge.tracking import FrameResult, RoverEstimate

ids = st.from_regex(r"\A[a-z0-9_-]{1,16}\Z")
cm = st.floats(min_value=-9999.99, max_value=9999.99)
variance = st.floats(min_value=0.0, max_value=2e6)


@st.composite
def detections(draw: st.DrawFn) -> Detections:
    rover_ids = draw(st.lists(ids, unique=True, max_size=64))
    rovers = []
    for rid in rover_ids:
        xx, yy = draw(variance), draw(variance)
        xy = draw(st.floats(min_value=-1.5, max_value=1.5)) * math.sqrt(xx * yy)  # even singular or indefinite
        rovers.append(
            Detection(
                rid,
                (draw(cm), draw(cm)),
                (xx, xy, yy),
                draw(st.one_of(st.none(), st.floats(min_value=-10, max_value=10))),
                draw(st.floats(min_value=-1, max_value=2)),
                (draw(st.floats(-2e5, 2e5)), draw(st.floats(-2e5, 2e5))),
            )
        )
    view = tuple((draw(cm), draw(cm)) for _ in range(draw(st.integers(0, 8))))
    return Detections(
        draw(ids),
        draw(st.integers(0, 2**40)),
        draw(st.integers(0, 2**40)),
        draw(st.floats(0, 9e9)),
        draw(st.floats(0, 9e9)),
        draw(st.floats(-1, 2)),
        view,
        tuple(rovers),
    )


@pytest.mark.slow
@given(d=detections())
def test_every_encoded_detections_message_is_valid_and_round_trips(d: Detections) -> None:
    payload = encode_detections(d)
    assert len(payload) <= DETECTIONS_MAX_BYTES
    message = parse_detections(payload)
    assert dumps(message) == payload
    back = from_message(message)
    assert [r.rover_id for r in back.rovers] == [r.rover_id for r in d.rovers]
    for got, want in zip(back.rovers, d.rovers, strict=True):
        assert got.xy_cm == pytest.approx(want.xy_cm, abs=0.005 + 1e-9)
        xx, xy, yy = got.cov_cm2
        assert xx > 0 and yy > 0 and xx * yy > xy * xy  # still positive definite after rounding


@pytest.mark.parametrize(
    ("what", "change"),
    [
        ("a NaN position", {"xy_cm": (math.nan, 0.0)}),
        ("an infinite variance", {"cov_cm2": (math.inf, 0.0, 1.0)}),
        ("a position beyond 100 m", {"xy_cm": (10_000.0, 0.0)}),
    ],
)
def test_encoder_refuses_what_the_contract_cannot_carry(what: str, change: dict[str, object]) -> None:
    good = Detection("red", (1.0, 2.0), (0.1, 0.0, 0.1), None, 0.9, (10.0, 20.0))
    bad = Detection(**{**good.__dict__, **change})  # type: ignore[arg-type]
    with pytest.raises(MessageError):
        encode_detections(Detections("cam1", 0, 0, 0.0, 0.0, 1.0, (), (bad,)))


def test_encoder_refuses_a_rover_twice_and_more_than_64() -> None:
    one = Detection("red", (1.0, 2.0), (0.1, 0.0, 0.1), None, 0.9, (10.0, 20.0))
    with pytest.raises(MessageError, match="twice"):
        encode_detections(Detections("cam1", 0, 0, 0.0, 0.0, 1.0, (), (one, one)))
    many = tuple(Detection(f"r{k}", (1.0, 2.0), (0.1, 0.0, 0.1), None, 0.9, (1.0, 1.0)) for k in range(65))
    with pytest.raises(MessageError, match="65 rovers"):
        encode_detections(Detections("cam1", 0, 0, 0.0, 0.0, 1.0, (), many))


# -- the covariance a board attaches -----------------------------------------------------------------------------
def _estimate(rover_id: str, uv: tuple[float, float], mapping: CameraPlaneMapping, q: float = 1.0) -> RoverEstimate:
    xy = mapping.pixel_to_world(np.array([uv]))[0]
    return RoverEstimate(rover_id, float(xy[0]), float(xy[1]), None, None, None, q, uv)


def _sigma_cm(d: Detection) -> float:
    xx, _, yy = d.cov_cm2
    return math.sqrt(0.5 * (xx + yy))


@pytest.fixture(scope="module")
def builder() -> DetectionBuilder:
    mapping = CameraPlaneMapping(paper_camera())
    return DetectionBuilder("cam1", mapping, CalibrationErrorModel(), (1280, 720))


@pytest.mark.slow
def test_sigma_grows_smoothly_towards_the_image_border(builder: DetectionBuilder) -> None:
    mapping = builder.mapping
    assert isinstance(mapping, CameraPlaneMapping)
    # the marker's outline is about 22 px from its centre here: the ramp starts 48 px further in
    columns = [640.0, 300.0, 70.0, 60.0, 50.0, 40.0, 30.0, 25.0]
    result = FrameResult(0, 0.0, 0.0, tuple(_estimate(f"r{k}", (u, 400.0), mapping) for k, u in enumerate(columns)), ())
    sigmas = [_sigma_cm(d) for d in builder.build(result, None, 0.0).rovers]
    # the same sigma far from the border (only the local scale changes), then a steady rise towards it
    assert sigmas[1] == pytest.approx(sigmas[0], rel=0.3)
    assert all(b > a for a, b in itertools.pairwise(sigmas[2:]))
    assert sigmas[-1] > 10 * sigmas[0]


@pytest.mark.slow
@pytest.mark.parametrize(("quality", "factor"), [(1.0, 1.0), (0.5, 2.0), (0.25, 4.0)])
def test_a_worse_marker_quality_means_a_proportionally_larger_sigma(
    builder: DetectionBuilder, quality: float, factor: float
) -> None:
    mapping = builder.mapping
    assert isinstance(mapping, CameraPlaneMapping)

    def one(q: float) -> Detection:
        result = FrameResult(0, 0.0, 0.0, (_estimate("red", (640.0, 400.0), mapping, q),), ())
        return builder.build(result, None, 0.0).rovers[0]

    best, worse = one(1.0), one(quality)
    assert _sigma_cm(worse) == pytest.approx(factor * _sigma_cm(best), rel=1e-6)


@pytest.mark.parametrize(
    ("fill", "expected"),
    [(128, 1.0), (255, 0.0), (0, 0.0)],
)
def test_image_quality_is_the_share_neither_crushed_nor_clipped(fill: int, expected: float) -> None:
    image = np.full((720, 1280, 3), fill, dtype=np.uint8)
    assert image_quality(image) == pytest.approx(expected)
    image[:, :320] = 255  # a quarter of the frame in a sun patch
    if fill == 128:
        assert image_quality(image) == pytest.approx(0.75)


# -- edge-ips track --detections on a rendered clip -----------------------------------------------------------------
FRAMES = 30


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("lab")
    runner = CliRunner()
    for args in (
        ["sim", "render", "lab", "--out", str(out), "--frames", str(FRAMES), "--seed", "3"],
        [
            "calibrate",
            "points",
            str(out / "points.csv"),
            "--out",
            str(out / "calibration.json"),
            "--image",
            str(out / "background.png"),
        ],
    ):
        result = runner.invoke(main, args, catch_exceptions=False)
        assert result.exit_code == 0, result.output
    return out


def _truth(path: Path) -> dict[tuple[int, str], tuple[float, float]]:
    with path.open() as f:
        return {(int(r["frame"]), r["id"]): (float(r["x"]), float(r["y"])) for r in csv.DictReader(f)}


@pytest.mark.slow
def test_track_writes_one_detections_message_per_frame_with_honest_covariances(lab: Path, tmp_path: Path) -> None:
    out = tmp_path / "det.jsonl"
    result = CliRunner().invoke(
        main,
        [
            "track",
            str(lab / "video.mp4"),
            "--calibration",
            str(lab / "calibration.json"),
            "--background",
            str(lab / "background.png"),
            "--detections",
            "--edge-id",
            "cam-7",
            "--out",
            str(out),
        ],
        catch_exceptions=False,
    )
    assert result.exit_code == 0, result.output
    lines = out.read_bytes().splitlines()
    assert len(lines) == FRAMES
    truth = _truth(lab / "truth.csv")
    nis, sigmas = [], []
    for k, line in enumerate(lines):
        message = parse_detections(line)
        assert dumps(message) == line
        assert (message.edge, message.seq, message.frame) == ("cam-7", k, k)
        assert message.t == pytest.approx(k / 30.0, abs=1e-4)
        assert {r.id for r in message.rovers} == {"red", "green", "blue"}
        assert len(message.view) >= 3
        for r in message.rovers:
            e = np.array([r.x, r.y]) - truth[(k, r.id)]
            c = np.array([[r.cov[0], r.cov[1]], [r.cov[1], r.cov[2]]])
            nis.append(float(e @ np.linalg.solve(c, e)))
            sigmas.append(math.sqrt(0.5 * (r.cov[0] + r.cov[2])))
    # Never over-confident (the fusion's gate would refuse good detections): the normalised squared error of a 2-D
    # Gaussian averages 2. Most of it is the calibration's own error, which one survey's luck makes smaller than
    # its model says on some seeds (the mean is 0.2 on this one, 1.6 on seed 0), never much larger.
    assert float(np.mean(nis)) < 4.0
    assert float(np.mean(np.array(nis) < 13.8)) > 0.97  # chi2(2) 99.9 % point
    assert max(sigmas) < 1.0  # and still a sharp measurement: sub-centimetre everywhere in the paper's view


@pytest.mark.slow
def test_the_calibrations_error_model_is_the_error_maps(lab: Path) -> None:
    """The covariance the fusion trusts at a point is the one behind the calibration's own error map."""
    from edge.calibration.errormap import radial_quantile

    model = calibration_error_model(lab / "calibration.json")
    record = json.loads((lab / "calibration.json").read_text())
    grid = np.array([[x, y] for x in np.linspace(20, 370, 8) for y in np.linspace(20, 530, 8)])
    r95 = radial_quantile(model.covariance_cm2(grid))
    assert float(r95.mean()) == pytest.approx(record["fit"]["error_map_mean_cm"], rel=0.25)
    assert calibration_error_model(lab / "camera.json").covariance_cm2(grid).max() == 0.0  # the exact camera


def test_track_refuses_a_bad_edge_id(lab: Path, tmp_path: Path) -> None:
    result = CliRunner().invoke(
        main,
        [
            "track",
            str(lab / "video.mp4"),
            "--calibration",
            str(lab / "camera.json"),
            "--detections",
            "--edge-id",
            "Cam 1",
            "--out",
            str(tmp_path / "d.jsonl"),
        ],
    )
    assert result.exit_code == 2
    assert "--edge-id 'Cam 1'" in result.output
