"""Camera controls (``[camera.controls]``): set automatic modes first, read every value back and log it as granted,
set again at every reopen and once the stream runs; ``doctor`` warns about autofocus or auto white balance under a
calibration. The camera is a stand-in that accepts, refuses and clamps as a UVC camera behind uvcvideo does
(tests/support/uvc.py): this machine's kernel has no V4L2 (no media support, no modules), so neither vivid nor
v4l2loopback can give a real device here. The ioctl layer itself is checked against the kernel's ABI numbers and a
real file that is not a V4L2 device."""

from __future__ import annotations

import logging
import threading
from pathlib import Path

import pytest
from click.testing import CliRunner

from edge.camera_controls import CameraControls, ControlError, apply_controls
from edge.capture import CaptureThread, FrameSlot
from edge.cli import main
from edge.config import EdgeConfig
from edge.config_load import with_overrides
from edge.doctor import check_controls
from edge.sources import CameraSource
from edge.v4l2 import CONTROL_IDS, VIDIOC_G_CTRL, VIDIOC_QUERYCTRL, VIDIOC_QUERYMENU, VIDIOC_S_CTRL, V4l2Controls
from tests.support.uvc import FakeCapture, FakeUvcCamera

FIXED = CameraControls(
    autofocus=False,
    focus=0,
    auto_white_balance=False,
    white_balance_k=4000,
    auto_exposure=False,
    exposure=156,
    exposure_dynamic_framerate=False,
    gain=64,
    power_line_hz=50,
    sharpness=0,
)


def camera_source(camera: FakeUvcCamera, controls: CameraControls = FIXED) -> CameraSource:
    return CameraSource(
        str(camera.node),
        controls=controls,
        open_capture=lambda path: FakeCapture(camera),
        open_controls=lambda path: camera.controls(),
    )


def test_controls_are_set_automatic_modes_first_and_each_read_back(tmp_path: Path) -> None:
    camera = FakeUvcCamera(tmp_path / "video0")
    report = apply_controls(camera.controls(), FIXED)
    assert report.ok, report.line()
    assert camera.values == {
        "focus_auto": 0,
        "focus": 0,
        "white_balance_auto": 0,
        "white_balance_k": 4000,
        "exposure_auto": 1,  # V4L2's "manual" (OpenCV's CAP_PROP_AUTO_EXPOSURE = 1 on V4L2; 3 = aperture priority)
        "exposure": 156,
        "exposure_dynamic_framerate": 0,
        "gain": 64,
        "power_line": 1,  # 50 Hz
        "sharpness": 0,  # the C920's default is 128: its halos move the marker centres
    }
    order = [name for name, _ in camera.sets]
    for auto, manual in (
        ("focus_auto", "focus"),
        ("white_balance_auto", "white_balance_k"),
        ("exposure_auto", "exposure"),
    ):
        assert order.index(auto) < order.index(manual), order


def test_the_same_controls_in_the_other_order_are_refused_by_the_camera(tmp_path: Path) -> None:
    """Why the order matters: a UVC camera refuses a manual value while its automatic mode is on (EACCES)."""
    camera = FakeUvcCamera(tmp_path / "video0")
    with pytest.raises(ControlError, match="EACCES"):
        camera.controls().set("focus", 0)


@pytest.mark.parametrize(
    ("controls", "name", "got", "why"),
    [
        (CameraControls(autofocus=False, focus=17), "focus", 15, "rounded to the camera's step of 5"),
        (CameraControls(auto_exposure=False, exposure=5000), "exposure", 2047, "clamped to the camera's range 3-2047"),
        (CameraControls(auto_white_balance=False, white_balance_k=9000), "white_balance_k", 6500, "range 2000-6500"),
    ],
)
def test_a_value_the_camera_cannot_take_is_logged_as_granted_not_as_asked(
    tmp_path: Path, controls: CameraControls, name: str, got: int, why: str
) -> None:
    camera = FakeUvcCamera(tmp_path / "video0")
    report = apply_controls(camera.controls(), controls)
    granted = {g.name: g for g in report.granted}[name]  # type: ignore[index]
    assert not report.ok and granted.got == got and why in granted.problem
    assert f"{name} {got} (asked {granted.asked}: " in report.line() and why in report.line()


def test_controls_a_camera_lacks_or_refuses_are_named(tmp_path: Path) -> None:
    # a fixed-focus camera, and one whose firmware will not leave auto white balance (as some C920s refuse focus)
    camera = FakeUvcCamera(
        tmp_path / "video0", missing=frozenset({"focus_auto", "focus"}), stuck=frozenset({"white_balance_auto"})
    )
    report = apply_controls(camera.controls(), FIXED)
    text = {g.name: g.text() for g in report.granted}
    assert text["focus_auto"] == "focus_auto 0 not set: the camera has no such control"
    assert "white_balance_auto 0 not set: refused" in text["white_balance_auto"]
    assert "white_balance_k 4000 not set: refused" in text["white_balance_k"] and "EACCES" in text["white_balance_k"]
    assert text["exposure"] == "exposure 156" and not report.ok


def test_a_menu_item_the_camera_does_not_offer_is_named(tmp_path: Path) -> None:
    camera = FakeUvcCamera(tmp_path / "video0")
    controls = camera.controls()
    info = controls.query("exposure_auto")
    assert info is not None and info.menu == (1, 3)
    with pytest.raises(ControlError, match="EINVAL"):
        controls.set("exposure_auto", 0)  # fully automatic: a UVC camera offers manual (1) and aperture priority (3)


def test_controls_are_set_once_the_stream_runs(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    camera = FakeUvcCamera(tmp_path / "video0", resets_focus_on_stream_start=True)
    source = camera_source(camera, CameraControls(autofocus=False, focus=30))
    with caplog.at_level(logging.INFO, logger="edge.sources"):
        info = source.open()
    assert (info.width_px, info.height_px) == (1280, 720)
    assert camera.streaming and camera.values["focus"] == 30 and source.controls_report.ok
    assert any("controls granted: focus_auto 0; focus 30" in r.getMessage() for r in caplog.records)
    source.close()


def test_controls_come_back_after_the_camera_is_replugged(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    camera = FakeUvcCamera(tmp_path / "video0")
    source = camera_source(camera)
    info = source.open()
    slot, stop = FrameSlot(), threading.Event()
    capture = CaptureThread(source, slot, stop, info=info, reopen_min_s=0.01, reopen_max_s=0.05)
    with caplog.at_level(logging.INFO, logger="edge.sources"):
        capture.start()
        assert slot.take(timeout_s=30) is not None
        camera.unplug()  # a replugged UVC camera comes back with every control at its default
        camera.plug()
        assert camera.values["focus_auto"] == 1 and camera.values["white_balance_auto"] == 1
        for _ in range(10_000):  # frames keep coming until the thread has noticed and reopened
            assert slot.take(timeout_s=30) is not None
            if capture.reopens >= 1:
                break
        stop.set()
        capture.join(10)
    assert camera.values["focus_auto"] == 0 and camera.values["white_balance_k"] == 4000
    assert camera.values["exposure"] == 156 and camera.values["power_line"] == 1
    granted = [r for r in caplog.records if "controls granted" in r.getMessage()]
    assert len(granted) == 1 and capture.reopens >= 1  # the first open was before the log capture


def calibrated_config(tmp_path: Path) -> EdgeConfig:
    return with_overrides(EdgeConfig(), **{"calibration.path": str(tmp_path / "calibration.json")})


@pytest.mark.parametrize(
    ("controls", "level", "fragment"),
    [
        (CameraControls(), "warn", "autofocus and auto white balance on"),
        (CameraControls(autofocus=False, focus=0), "warn", "auto white balance on"),
        (FIXED, "ok", "focus_auto 0; white_balance_auto 0; exposure_auto 1"),
    ],
)
def test_doctor_warns_about_automatic_modes_under_a_calibration(
    tmp_path: Path, controls: CameraControls, level: str, fragment: str
) -> None:
    camera = FakeUvcCamera(tmp_path / "video0")
    source = camera_source(camera, controls)
    source.open()
    check = check_controls(calibrated_config(tmp_path), source)
    assert check is not None and check.level == level and fragment in check.detail, check.line()
    if level == "warn":
        assert "autofocus = false" in check.line()


def test_doctor_warns_while_the_camera_sharpens_its_frames(tmp_path: Path) -> None:
    """A C920 sharpens at its default (128 of 0-255); the family benchmark's cameras that sharpen put marker centres
    further off (docs/benchmarks.md). Asked to stop, it is quiet; a camera without the control is not warned about."""
    camera = FakeUvcCamera(tmp_path / "video0")
    source = camera_source(camera, FIXED.model_copy(update={"sharpness": None}))
    source.open()
    check = check_controls(calibrated_config(tmp_path), source)
    assert check is not None and check.level == "warn" and "sharpness 128 (the camera's least is 0)" in check.detail
    assert "sharpness" in check.hint
    source = camera_source(camera)
    source.open()
    assert camera.values["sharpness"] == 0
    check = check_controls(calibrated_config(tmp_path), source)
    assert check is not None and check.level == "ok" and "sharpness 0" in check.detail, check.line()
    plain = FakeUvcCamera(tmp_path / "video1", missing=frozenset({"sharpness"}))
    source = camera_source(plain, FIXED.model_copy(update={"sharpness": None}))
    source.open()
    check = check_controls(calibrated_config(tmp_path), source)
    assert check is not None and check.level == "ok", check.line()


def test_the_source_says_the_camera_sharpens_unless_its_sharpening_was_read_back_off(tmp_path: Path) -> None:
    """The edge fits weigh the luma by their residuals where the camera may sharpen (``SourceInfo.sharpened``, the
    tracker's ``camera_sharpens``): a camera whose sharpness was set to its least and read back there does not; one
    left at its default, one lacking the control and one whose controls were not asked for may."""
    camera = FakeUvcCamera(tmp_path / "video0")
    assert camera_source(camera).open().sharpened is False
    assert camera.values["sharpness"] == 0
    assert camera_source(camera, FIXED.model_copy(update={"sharpness": 96})).open().sharpened is True
    assert camera_source(camera, CameraControls()).open().sharpened is True  # nothing asked: not read
    plain = FakeUvcCamera(tmp_path / "video1", missing=frozenset({"sharpness"}))
    assert camera_source(plain).open().sharpened is True


def test_doctor_says_what_the_camera_did_not_grant(tmp_path: Path) -> None:
    camera = FakeUvcCamera(tmp_path / "video0", stuck=frozenset({"gain"}))
    source = camera_source(camera)
    source.open()
    check = check_controls(calibrated_config(tmp_path), source)
    assert check is not None and check.level == "warn" and "gain 64 not set" in check.detail


@pytest.mark.parametrize(
    ("table", "fragment"),
    [
        ("focus = 20\n", "focus is only used with autofocus = false"),
        ("autofocus = true\nfocus = 20\n", "focus is only used with autofocus = false"),
        ("auto_white_balance = false\nwhite_balance_k = 100\n", "white_balance_k"),
        ("exposure = 156\n", "exposure is only used with auto_exposure = false"),
        ("power_line_hz = 55\n", "power_line_hz"),
        ("focus_mode = 'manual'\n", "camera.controls.focus_mode: unknown key"),
    ],
)
def test_bad_camera_controls_are_one_line(tmp_path: Path, table: str, fragment: str) -> None:
    config = tmp_path / "edge-ips.toml"
    config.write_text("[camera.controls]\n" + table)
    result = CliRunner().invoke(main, ["config", "show", "--config", str(config)])
    assert result.exit_code == 2 and fragment in result.stderr and len(result.stderr.strip().splitlines()) == 1


def test_the_ioctl_numbers_are_the_kernels() -> None:
    # linux/videodev2.h: _IOWR('V', 36, struct v4l2_queryctrl) ... as v4l2-ctl and OpenCV use them
    assert (VIDIOC_G_CTRL, VIDIOC_S_CTRL) == (0xC008561B, 0xC008561C)
    assert (VIDIOC_QUERYCTRL, VIDIOC_QUERYMENU) == (0xC0445624, 0xC02C5625)
    assert CONTROL_IDS["focus_auto"] == 0x009A090C and CONTROL_IDS["exposure_auto"] == 0x009A0901
    assert CONTROL_IDS["white_balance_auto"] == 0x0098090C and CONTROL_IDS["power_line"] == 0x00980918
    assert CONTROL_IDS["sharpness"] == 0x0098091B


def test_a_file_that_is_not_a_v4l2_device_is_said_so() -> None:
    with (
        V4l2Controls("/dev/null") as device,
        pytest.raises(ControlError, match="/dev/null: query focus_auto: not a V4L2"),
    ):
        device.query("focus_auto")
    with pytest.raises(ControlError, match="cannot open for its controls"):
        V4l2Controls("/dev/video-that-is-not-there")


def test_doctor_names_a_calibration_from_points_clicked_by_hand(tmp_path: Path) -> None:
    """Clicked points (0.5 px) fit with residuals of about a third of a pixel, and over a run each rover carries the
    mapping's error as a bias (docs/calibration.md): doctor says so and points at printed targets; the same points
    refined on a photo of the targets fit to a few hundredths and pass, as does an ArUco calibration."""
    import cv2

    from edge.camera import paper_camera
    from edge.doctor import check_calibration
    from edge.sim.targets import aruco_floor_frame, survey_points, survey_target_frame, write_markers_csv

    cam = paper_camera()
    survey = survey_points(cam, rng=5)
    survey.write_csv(tmp_path / "points.csv")
    cv2.imwrite(str(tmp_path / "targets.png"), survey_target_frame(cam, survey.xy_world_cm, rng=5))
    frame = aruco_floor_frame(cam, rng=6)
    cv2.imwrite(str(tmp_path / "floor.png"), frame.image)
    write_markers_csv(tmp_path / "markers.csv", frame.markers)
    made = {
        "clicked": ["points", tmp_path / "points.csv"],
        "refined": ["points", tmp_path / "points.csv", "--refine-on", tmp_path / "targets.png"],
        "aruco": ["aruco", tmp_path / "floor.png", "--markers", tmp_path / "markers.csv"],
    }
    camera = FakeUvcCamera(tmp_path / "video0")
    checks = {}
    for name, args in made.items():
        out = tmp_path / f"{name}.json"
        result = CliRunner().invoke(main, ["calibrate", *map(str, args), "--out", str(out)])
        assert result.exit_code == 0, result.output
        config = with_overrides(EdgeConfig(), **{"calibration.path": str(out), "camera.source": str(camera.node)})
        source = camera_source(camera)
        info = source.open()
        checks[name] = check_calibration(config, source, info, "test")
    assert checks["clicked"].level == "warn", checks["clicked"].line()
    assert "clicked by hand" in checks["clicked"].detail and "--refine-on" in checks["clicked"].hint
    assert checks["refined"].level == "ok" and checks["aruco"].level == "ok", [c.line() for c in checks.values()]
