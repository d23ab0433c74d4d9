"""Colour enrolment (``edge-ips rovers enroll``, ``edge.enroll``) on frames the simulator renders: a frame with the
rovers in view and the empty floor. Enrolled colours must then track: the tracker configured from the written
``[[rovers]]`` tables finds every rover, with its id, where it is."""

from __future__ import annotations

import math
import tomllib
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner, Result

from edge.camera import PinholeCamera, paper_camera, save_camera
from edge.cli import main
from edge.config_load import load_config
from edge.enroll import enroll
from edge.errors import EnrollmentError
from edge.sim.scene import RoverLook, fleet_looks, marker_albedo_for_hue
from tests.support.lab import PALETTE, Lab, eight_hues, spread_out, track


# -- the library ---------------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_the_eight_hue_palette_is_enrolled_named_by_hue_and_then_tracked() -> None:
    lab = Lab(eight_hues())
    poses = spread_out(8)
    result = enroll(lab.frame(poses), lab.background(), lab.calibration)
    assert [m.rover_id for m in result.markers] == [name for name, _ in PALETTE]  # by hue, named by hue
    assert result.warnings == () and result.ignored == ()
    for marker, (x, y, _) in zip(result.markers, poses, strict=True):
        assert math.hypot(marker.xy_cm[0] - x, marker.xy_cm[1] - y) < 1.0
        assert marker.length_cm == pytest.approx(21.5, abs=1.5) and marker.width_cm == pytest.approx(16.8, abs=1.5)
        assert marker.front_color_bgr is None
    errors = track(lab, result.rover_configs(), poses)
    for rover_id, errs in errors.items():
        assert max(errs) < 1.0, f"{rover_id}: {errs}"  # every rover found, with its id, in every frame


@pytest.mark.slow
def test_two_tone_markers_are_enrolled_with_their_front_part_and_track_with_headings() -> None:
    looks = tuple(RoverLook(look.rover_id, look.marker_bgr, heading="two_tone") for look in fleet_looks(3))
    lab = Lab(looks)
    poses = [(100.0, 150.0, 0.5), (250.0, 300.0, 2.0), (180.0, 460.0, -1.0)]
    result = enroll(lab.frame(poses), lab.background(), lab.calibration, ids=["red", "green", "blue"])
    assert [m.rover_id for m in result.markers] == ["red", "green", "blue"]
    for m in result.markers:
        assert m.front_color_bgr is not None and min(m.front_color_bgr) > 150  # the near-white front
        assert m.front_fraction == pytest.approx(0.3, abs=0.03)
    configs = result.rover_configs()
    assert all(c.front_color_bgr is not None for c in configs)
    errors = track(lab, configs, poses)
    for rover_id, errs in errors.items():
        assert max(errs) < 1.0, f"{rover_id}: {errs}"


@pytest.mark.slow
@pytest.mark.parametrize("theta", [0.0, math.pi / 2, math.pi, -math.pi / 2])
def test_a_two_tone_front_pointing_along_the_image_rows_or_columns_is_measured_whole(theta: float) -> None:
    # the front sticks out of the coloured part's bounding box: it is measured over its own
    lab = Lab(tuple(RoverLook(look.rover_id, look.marker_bgr, heading="two_tone") for look in fleet_looks(1)))
    (marker,) = enroll(lab.frame([(100.0, 150.0, theta)]), lab.background(), lab.calibration).markers
    assert marker.front_fraction == pytest.approx(0.3, abs=0.03)
    assert marker.area_cm2 == pytest.approx(21.5 * 16.8, rel=0.15)


@pytest.mark.slow
def test_a_glare_on_part_of_a_marker_does_not_move_its_colour() -> None:
    lab = Lab(fleet_looks(3))
    poses = [(100.0, 150.0, 0.0), (250.0, 300.0, 1.0), (180.0, 460.0, 2.0)]
    frame, background = lab.frame(poses), lab.background()
    clean = {m.rover_id: m for m in enroll(frame, background, lab.calibration).markers}
    glared = frame.copy()
    u, v = clean["red"].uv_px  # a specular highlight over a third of the red marker, clipped white
    cv2.circle(glared, (round(u), round(v)), 9, (255, 255, 255), -1)
    red = next(m for m in enroll(glared, background, lab.calibration).markers if m.rover_id == "red")
    assert np.abs(np.subtract(red.color_bgr, clean["red"].color_bgr)).max() <= 4


@pytest.mark.slow
def test_hues_this_camera_cannot_keep_apart_are_named() -> None:
    looks = (RoverLook("a", marker_albedo_for_hue(0.0)), RoverLook("b", marker_albedo_for_hue(12.0)),
             RoverLook("c", marker_albedo_for_hue(200.0)))  # fmt: skip
    lab = Lab(looks)
    result = enroll(lab.frame(spread_out(3)), lab.background(), lab.calibration, ids=["r1", "r2", "r3"])
    assert len(result.warnings) == 1
    names = {m.rover_id for m in result.markers if m.hue_deg < 30 or m.hue_deg > 330}
    assert all(n in result.warnings[0] for n in names) and "too close to tell apart" in result.warnings[0]


def test_a_large_coloured_thing_is_not_a_marker() -> None:
    lab = Lab(fleet_looks(2))
    frame = lab.frame([(100.0, 150.0, 0.0), (300.0, 300.0, 0.0)])
    cv2.rectangle(frame, (700, 500), (860, 640), (40, 40, 190), -1)  # a red box dropped in the area: 1 m across
    result = enroll(frame, lab.background(), lab.calibration)
    assert [m.rover_id for m in result.markers] == ["red", "green"]
    assert len(result.ignored) == 1 and "too large" in result.ignored[0]


@pytest.mark.slow
@pytest.mark.parametrize(
    ("case", "message"),
    [
        ("empty", "no marker-sized blob of colour differs from the background"),
        ("swapped", "the background image has a marker in it"),
        ("too few ids", "found 3 markers, more than the 2 ids given"),
        ("too many ids", "found 3 markers, fewer than the 4 ids given"),
        ("bad id", "is not an id"),
        ("sizes", "the frame is 1280x720 but the background is 640x360"),
    ],
)
def test_what_cannot_be_enrolled_says_why(case: str, message: str) -> None:
    lab = Lab(fleet_looks(3))
    frame, background = lab.frame(spread_out(3)), lab.background()
    ids = {"too few ids": ["a", "b"], "too many ids": ["a", "b", "c", "d"], "bad id": ["Red", "b", "c"]}.get(case)
    if case == "empty":
        frame = background
    if case == "swapped":
        frame, background = background, frame
    if case == "sizes":
        background = cv2.resize(background, (640, 360))
    with pytest.raises(EnrollmentError, match=message):
        enroll(frame, background, lab.calibration, ids=ids)


@pytest.mark.slow
@pytest.mark.parametrize("floor", ["tiles", "wood"])
def test_a_marker_left_in_the_empty_floor_s_image_is_named_on_any_floor(floor: str) -> None:
    # on wood the floor where the marker stood is as saturated as a pale marker: judged against the floor round it
    left = Lab(fleet_looks(1), floor=floor).frame([(200.0, 250.0, 0.0)])
    lab = Lab(fleet_looks(3), floor=floor)
    with pytest.raises(EnrollmentError, match=r"the background image has a marker in it at \(20\d, 2[45]\d\) cm"):
        enroll(lab.frame([(80.0, 120.0, 0.0), (320.0, 130.0, 1.0), (120.0, 450.0, 2.0)]), left, lab.calibration)


# -- the command -----------------------------------------------------------------------------------------------------
def run(*args: str | Path) -> Result:
    return CliRunner().invoke(main, [str(a) for a in args], env={"EDGE_IPS_CONFIG": ""})


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("enroll")
    lab = Lab(fleet_looks(3))
    poses = [(100.0, 150.0, 0.3), (250.0, 300.0, 1.2), (180.0, 460.0, -0.7)]
    cv2.imwrite(str(d / "frame.png"), lab.frame(poses))
    cv2.imwrite(str(d / "empty.png"), lab.background())
    save_camera(lab.camera, d / "camera.json")
    writer = cv2.VideoWriter(str(d / "clip.avi"), cv2.VideoWriter.fourcc(*"MJPG"), 30.0, (1280, 720))
    for i in range(40):
        t = i / 30.0
        writer.write(lab.frame([(x + 20 * t * math.cos(th), y + 20 * t * math.sin(th), th) for x, y, th in poses], i))
    writer.release()
    return {
        "dir": d,
        "frame": d / "frame.png",
        "empty": d / "empty.png",
        "camera": d / "camera.json",
        "clip": d / "clip.avi",
    }


@pytest.mark.slow
def test_enroll_writes_rovers_that_config_and_track_read(files: dict[str, Path], tmp_path: Path) -> None:
    out = tmp_path / "rovers.toml"
    result = run("rovers", "enroll", "--image", files["frame"], "--background", files["empty"],
                 "--calibration", files["camera"], "--out", out, "--ids", "r1,r2,r3")  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "wrote 3 rovers to" in result.output and "r1: color_bgr" in result.output
    tables = tomllib.loads(out.read_text())["rovers"]
    assert [t["id"] for t in tables] == ["r1", "r2", "r3"]  # in order of x on the floor
    config = load_config(out).config  # what `edge-ips start --config rovers.toml` reads
    assert [r.id for r in config.rovers] == ["r1", "r2", "r3"]
    poses = tmp_path / "poses.jsonl"
    tracked = run("track", files["clip"], "--calibration", files["camera"], "--background", files["empty"],
                  "--config", out, "--out", poses, "--json")  # fmt: skip
    assert tracked.exit_code == 0, tracked.output
    assert '"r1": 40' in tracked.output and '"r2": 40' in tracked.output and '"r3": 40' in tracked.output


@pytest.mark.slow
def test_enroll_takes_the_frame_from_a_source(files: dict[str, Path], tmp_path: Path) -> None:
    out = tmp_path / "rovers.toml"
    result = run("rovers", "enroll", "--source", files["clip"], "--background", files["empty"],
                 "--calibration", files["camera"], "--out", out, "--json")  # fmt: skip
    assert result.exit_code == 0, result.output
    assert [t["id"] for t in tomllib.loads(out.read_text())["rovers"]] == ["red", "green", "azure"]


def test_the_enroll_command_has_help_with_an_example() -> None:
    for args in (["rovers", "--help"], ["rovers", "enroll", "--help"]):
        result = run(*args)
        assert result.exit_code == 0 and "Example:" in result.output and "edge-ips rovers enroll" in result.output


@pytest.mark.slow
@pytest.mark.parametrize(
    ("case", "fragment"),
    [
        ("no markers", "no marker-sized blob of colour differs from the background"),
        ("background with a rover", "the background image has a marker in it"),
        ("more markers than ids", "found 3 markers, more than the 2 ids given"),
        ("unreadable image", "cannot read image"),
        ("missing image", "image not found"),
        ("calibration of another size", "640x360"),
        ("both frames", "either --image FRAME.png or --source SPEC"),
        ("a configuration as --out", "is a configuration with [broker]"),
    ],
)
def test_enroll_errors_are_one_line(files: dict[str, Path], tmp_path: Path, case: str, fragment: str) -> None:
    frame, empty, camera = files["frame"], files["empty"], files["camera"]
    out = tmp_path / "rovers.toml"
    extra: list[str | Path] = []
    if case == "no markers":
        frame = empty
    if case == "background with a rover":
        frame, empty = empty, frame
    if case == "more markers than ids":
        extra = ["--ids", "a,b"]
    if case == "unreadable image":
        frame = tmp_path / "frame.png"
        frame.write_bytes(b"not a png")
    if case == "missing image":
        frame = tmp_path / "nothing.png"
    if case == "calibration of another size":
        small = paper_camera()
        k = small.camera_matrix.copy()
        k[:2] /= 2.0
        camera = tmp_path / "camera.json"
        save_camera(PinholeCamera(k, small.dist_coeffs, small.rvec, small.tvec, 640, 360), camera)
    if case == "both frames":
        extra = ["--source", "sim"]
    if case == "a configuration as --out":
        out.write_text('[broker]\nurl = "embedded"\n')
    result = run("rovers", "enroll", "--image", frame, "--background", empty, "--calibration", camera,
                 "--out", out, *extra)  # fmt: skip
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: ") and fragment in lines[0], result.stderr
    if case == "a configuration as --out":
        assert out.read_text() == '[broker]\nurl = "embedded"\n'


# -- the camera family ---------------------------------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize(("seed", "floor"), [(0, "wood"), (1, "wood"), (2, "tiles"), (7, "wood")])
def test_markers_seen_by_the_family_s_webcams_on_its_bodies_are_enrolled_whole_where_they_stand(
    seed: int, floor: str
) -> None:
    # black bodies tinted by the white balance, white ones turned bluish by an automatic one over wood (seed 7), a
    # wooden floor as saturated as a pale marker: each once made a body part of its marker's blob or a marker
    lab = Lab.family(eight_hues(), seed, floor)
    poses = spread_out(8)
    result = enroll(lab.frame(poses), lab.background(), lab.calibration, ids=[name for name, _ in PALETTE])
    assert [m.rover_id for m in result.markers] == [name for name, _ in PALETTE], lab.camera_name
    for marker, (x, y, _) in zip(result.markers, poses, strict=True):
        assert math.hypot(marker.xy_cm[0] - x, marker.xy_cm[1] - y) < 2.0, (lab.camera_name, marker)
        assert 0.7 < marker.area_cm2 / (21.5 * 16.8) < 1.35, (lab.camera_name, marker)
        assert marker.front_color_bgr is None  # a light body beside a one-colour marker is not its front


@pytest.mark.slow
def test_colours_enrolled_through_one_of_the_family_s_webcams_then_track_every_rover() -> None:
    lab = Lab.family(eight_hues(), 0, "wood")
    poses = spread_out(8)
    result = enroll(lab.frame(poses), lab.background(), lab.calibration, ids=[name for name, _ in PALETTE])
    for rover_id, errs in track(lab, result.rover_configs(), poses).items():
        assert max(errs) < 1.5, f"{rover_id}: {errs}"  # found, with its id, in every one of the last 15 frames


@pytest.mark.slow
@pytest.mark.parametrize("seed", [2, 7])
def test_a_light_body_round_a_one_colour_marker_is_neither_a_marker_nor_its_front(seed: int) -> None:
    lab = Lab.family(fleet_looks(3), seed, "wood")
    assert any(min(look.body_bgr) > 0.5 for look in lab.looks)  # the family drew a white body here
    poses = spread_out(3)
    result = enroll(lab.frame(poses), lab.background(), lab.calibration)
    assert len(result.markers) == 3, lab.camera_name
    for marker in result.markers:
        assert min(math.hypot(marker.xy_cm[0] - x, marker.xy_cm[1] - y) for x, y, _ in poses) < 2.0
        assert marker.front_color_bgr is None and marker.area_cm2 / (21.5 * 16.8) < 1.35
    assert not [w for w in result.warnings if "no light front" in w]  # whole one-colour markers: nothing missing


@pytest.mark.slow
def test_a_two_tone_marker_whose_front_is_lost_in_a_white_body_is_named() -> None:
    looks = tuple(replace(look, heading="two_tone", body_bgr=(0.8, 0.8, 0.8)) for look in fleet_looks(3))
    lab = Lab(looks)
    result = enroll(lab.frame(spread_out(3)), lab.background(), lab.calibration)
    missing = [m.rover_id for m in result.markers if m.front_color_bgr is None]
    assert missing  # the light front and the white body are one light part
    said = [w.split()[0] for w in result.warnings if "no light front was found beside it" in w]
    assert said == missing


@pytest.mark.slow
def test_a_grey_body_over_a_wooden_floor_is_not_a_marker_left_in_the_background() -> None:
    # the body hides the wood's colour where it stands: the empty floor there is as saturated as a pale marker
    looks = tuple(replace(look, body_bgr=(0.45, 0.45, 0.45)) for look in fleet_looks(3))
    lab = Lab(looks, floor="wood")
    result = enroll(lab.frame(spread_out(3)), lab.background(), lab.calibration, ids=["red", "green", "blue"])
    assert [m.rover_id for m in result.markers] == ["red", "green", "blue"]


def test_a_coloured_blob_beyond_the_working_area_is_not_a_rover() -> None:
    lab = Lab(fleet_looks(2))
    frame = lab.frame([(100.0, 150.0, 0.0), (300.0, 300.0, 0.0)])
    corners = np.array([[185.0, 630.0], [206.5, 630.0], [206.5, 646.8], [185.0, 646.8]])  # 80 cm beyond its far side
    cv2.fillConvexPoly(frame, lab.calibration.world_to_pixel(corners).round().astype(np.int32), (40, 40, 190))
    result = enroll(frame, lab.background(), lab.calibration)
    assert [m.rover_id for m in result.markers] == ["red", "green"]
    assert any("outside the working area" in line for line in result.ignored)


@pytest.mark.slow
def test_markers_printed_larger_than_the_tracker_is_configured_for_are_named_with_their_size() -> None:
    # the tracker sizes its windows and area checks by the configured marker: 40 % more area is learned as the
    # rover's own, and a part of it hidden down to the configured size would look whole (docs/tracking.md)
    big = tuple(
        replace(look, marker_length_cm=25.4, marker_width_cm=19.9, body_length_cm=29.0, body_width_cm=23.0)
        for look in fleet_looks(3)
    )
    lab = Lab(big)
    result = enroll(lab.frame(spread_out(3)), lab.background(), lab.calibration, ids=["red", "green", "blue"])
    sized = [w for w in result.warnings if "but the tracker expects 21.5 x 16.8 cm" in w]
    assert [w.split()[0] for w in sized] == ["red", "green", "blue"]
    for marker in result.markers:
        assert marker.area_cm2 == pytest.approx(25.4 * 19.9, rel=0.12)
