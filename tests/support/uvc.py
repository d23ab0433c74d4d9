"""A stand-in for a UVC webcam (a Logitech C920 by default) behind V4L2, for tests on a machine without a camera.

Its controls behave as the uvcvideo driver and the C920's firmware do (``drivers/media/usb/uvc/uvc_ctrl.c``, and
what labs report): an integer is clamped to its range and rounded to its step, a menu item the camera does not offer
is EINVAL, a manual value while its automatic mode is on is EACCES, a replugged camera comes back with its defaults,
and some cameras reset focus when streaming starts. Its device node is a file that vanishes while it is unplugged,
so :class:`edge.sources.CameraSource` finds it gone exactly as it finds a real ``/dev/videoN`` gone.
"""

from __future__ import annotations

import errno
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from edge.camera_controls import ControlError, ControlInfo, ControlName

# name: (minimum, maximum, step, default, menu items, the automatic mode that makes it inactive while on)
C920: dict[ControlName, tuple[int, int, int, int, tuple[int, ...], ControlName | None]] = {
    "focus_auto": (0, 1, 1, 1, (), None),
    "focus": (0, 250, 5, 0, (), "focus_auto"),
    "white_balance_auto": (0, 1, 1, 1, (), None),
    "white_balance_k": (2000, 6500, 1, 4000, (), "white_balance_auto"),
    "exposure_auto": (0, 3, 1, 3, (1, 3), None),
    "exposure": (3, 2047, 1, 250, (), "exposure_auto"),
    "exposure_dynamic_framerate": (0, 1, 1, 1, (), None),
    "gain": (0, 255, 1, 0, (), None),
    "power_line": (0, 2, 1, 2, (0, 1, 2), None),
    "sharpness": (0, 255, 1, 128, (), None),
}
MANUAL = {"focus_auto": 0, "white_balance_auto": 0, "exposure_auto": 1}  # the value that makes a slave active


@dataclass
class FakeUvcCamera:
    """The camera: its controls' values, its node, and its quirks."""

    node: Path
    width: int = 1280
    height: int = 720
    missing: frozenset[str] = frozenset()  # controls this camera does not have
    stuck: frozenset[str] = frozenset()  # controls its firmware refuses to change (EIO)
    resets_focus_on_stream_start: bool = False
    values: dict[str, int] = field(default_factory=dict)
    sets: list[tuple[str, int]] = field(default_factory=list)  # every VIDIOC_S_CTRL, in order
    streaming: bool = False
    plugs: int = 0  # an open from before the last replug is dead, as a real file descriptor is

    def __post_init__(self) -> None:
        self.plug()

    # -- the device --------------------------------------------------------------------------------------------
    def plug(self) -> None:
        """Plugged in (again): the node appears, every control has its default (a UVC camera keeps nothing)."""
        self.values = {name: spec[3] for name, spec in C920.items() if name not in self.missing}
        self.streaming = False
        self.plugs += 1
        self.node.write_text("fake V4L2 node")

    def unplug(self) -> None:
        self.node.unlink()
        self.streaming = False

    @property
    def plugged(self) -> bool:
        return self.node.exists()

    def start_stream(self) -> bool:
        if not self.plugged:
            return False
        if not self.streaming and self.resets_focus_on_stream_start:
            self.values["focus"] = 190
        self.streaming = True
        return True

    # -- ControlDevice -----------------------------------------------------------------------------------------
    def controls(self) -> FakeControls:
        if not self.plugged:
            raise ControlError(f"{self.node}: cannot open for its controls (No such file or directory)")
        return FakeControls(self)


class FakeControls:
    """One open of the camera's node for its controls (the :class:`ControlDevice` protocol)."""

    def __init__(self, camera: FakeUvcCamera) -> None:
        self.camera = camera
        self.closed = False

    def _check(self, name: ControlName) -> None:
        if not self.camera.plugged:
            raise ControlError(f"{self.camera.node}: {name}: the camera did not answer (USB I/O error)")
        if name in self.camera.missing:
            raise ControlError(f"{self.camera.node}: {name}: no such control")

    def query(self, name: ControlName) -> ControlInfo | None:
        if name in self.camera.missing:
            return None
        lo, hi, step, default, menu, master = C920[name]
        inactive = master is not None and self.camera.values.get(master) != MANUAL[master]
        return ControlInfo(lo, hi, step, default, menu, inactive)

    def get(self, name: ControlName) -> int:
        self._check(name)
        return self.camera.values[name]

    def set(self, name: ControlName, value: int) -> None:
        self._check(name)
        lo, hi, step, _, menu, master = C920[name]
        if menu and value not in menu:
            raise ControlError(f"{self.camera.node}: set {name} to {value}: {errno.errorcode[errno.EINVAL]}")
        if master is not None and self.camera.values.get(master) != MANUAL[master]:
            raise ControlError(f"{self.camera.node}: set {name} to {value}: not writable now (EACCES)")
        self.camera.sets.append((name, value))
        if name in self.camera.stuck:
            raise ControlError(f"{self.camera.node}: set {name} to {value}: the camera did not answer (EIO)")
        clamped = min(max(value, lo), hi)
        self.camera.values[name] = lo + round((clamped - lo) / step) * step

    def close(self) -> None:
        self.closed = True


class FakeCapture:
    """The OpenCV ``VideoCapture`` of the fake camera: format properties, grab, retrieve, release."""

    def __init__(self, camera: FakeUvcCamera) -> None:
        self.camera = camera
        self.props: dict[int, float] = {}
        self.opened = camera.plugged
        self.plug = camera.plugs

    def isOpened(self) -> bool:
        return self.opened

    def set(self, prop: int, value: float) -> bool:
        self.props[prop] = value
        return True

    def get(self, prop: int) -> float:
        if prop == cv2.CAP_PROP_FRAME_WIDTH:
            return float(self.camera.width)
        if prop == cv2.CAP_PROP_FRAME_HEIGHT:
            return float(self.camera.height)
        return self.props.get(prop, 0.0)

    def grab(self) -> bool:
        return self.opened and self.plug == self.camera.plugs and self.camera.start_stream()

    def retrieve(self) -> tuple[bool, Any]:
        return True, np.zeros((self.camera.height, self.camera.width, 3), np.uint8)

    def release(self) -> None:
        self.opened = False
