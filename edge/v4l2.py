"""A V4L2 camera's controls through the kernel's own ioctls (``VIDIOC_QUERYCTRL``, ``VIDIOC_G_CTRL``,
``VIDIOC_S_CTRL``), as ``v4l2-ctl`` and OpenCV's V4L2 backend use them.

Not through OpenCV's ``CAP_PROP_*``: they have no power-line frequency and no ``exposure_auto_priority``, and their
meaning depends on ``OPENCV_VIDEOIO_V4L_RANGE_NORMALIZED``. Not through ``v4l2-ctl``: its control names changed in
Linux 5.x (``focus_auto`` became ``focus_automatic_continuous``, ``exposure_auto`` became ``auto_exposure``), while
the control ids below are fixed by the kernel's ABI (``linux/v4l2-controls.h``). The device may be open in OpenCV at
the same time: V4L2 allows several opens, and controls belong to the device, not to an open file.
"""

from __future__ import annotations

import ctypes
import errno
import fcntl
import os

from edge.camera_controls import ControlError, ControlInfo, ControlName

_USER_BASE = 0x00980900  # V4L2_CID_BASE (V4L2_CTRL_CLASS_USER | 0x900)
_CAMERA_BASE = 0x009A0900  # V4L2_CID_CAMERA_CLASS_BASE (V4L2_CTRL_CLASS_CAMERA | 0x900)
CONTROL_IDS: dict[ControlName, int] = {
    "white_balance_auto": _USER_BASE + 12,  # V4L2_CID_AUTO_WHITE_BALANCE
    "gain": _USER_BASE + 19,  # V4L2_CID_GAIN
    "power_line": _USER_BASE + 24,  # V4L2_CID_POWER_LINE_FREQUENCY
    "white_balance_k": _USER_BASE + 26,  # V4L2_CID_WHITE_BALANCE_TEMPERATURE
    "sharpness": _USER_BASE + 27,  # V4L2_CID_SHARPNESS
    "exposure_auto": _CAMERA_BASE + 1,  # V4L2_CID_EXPOSURE_AUTO
    "exposure": _CAMERA_BASE + 2,  # V4L2_CID_EXPOSURE_ABSOLUTE
    "exposure_dynamic_framerate": _CAMERA_BASE + 3,  # V4L2_CID_EXPOSURE_AUTO_PRIORITY
    "focus": _CAMERA_BASE + 10,  # V4L2_CID_FOCUS_ABSOLUTE
    "focus_auto": _CAMERA_BASE + 12,  # V4L2_CID_FOCUS_AUTO
}
_FLAG_DISABLED, _FLAG_INACTIVE = 0x0001, 0x0010
_TYPE_MENU, _TYPE_INTEGER_MENU = 3, 9


class _QueryCtrl(ctypes.Structure):
    _fields_ = [
        ("id", ctypes.c_uint32),
        ("type", ctypes.c_uint32),
        ("name", ctypes.c_char * 32),
        ("minimum", ctypes.c_int32),
        ("maximum", ctypes.c_int32),
        ("step", ctypes.c_int32),
        ("default_value", ctypes.c_int32),
        ("flags", ctypes.c_uint32),
        ("reserved", ctypes.c_uint32 * 2),
    ]


class _Control(ctypes.Structure):
    _fields_ = [("id", ctypes.c_uint32), ("value", ctypes.c_int32)]


class _QueryMenu(ctypes.Structure):
    _pack_ = 1  # struct v4l2_querymenu is __attribute__((packed))
    _fields_ = [
        ("id", ctypes.c_uint32),
        ("index", ctypes.c_uint32),
        ("name", ctypes.c_char * 32),
        ("reserved", ctypes.c_uint32),
    ]


def _iowr(nr: int, size: int) -> int:
    """Linux's ``_IOWR('V', nr, size)``."""
    return (3 << 30) | (size << 16) | (ord("V") << 8) | nr


VIDIOC_G_CTRL = _iowr(27, ctypes.sizeof(_Control))
VIDIOC_S_CTRL = _iowr(28, ctypes.sizeof(_Control))
VIDIOC_QUERYCTRL = _iowr(36, ctypes.sizeof(_QueryCtrl))
VIDIOC_QUERYMENU = _iowr(37, ctypes.sizeof(_QueryMenu))

_WHY = {
    errno.EACCES: "not writable now: its automatic mode is on, or it is read-only",
    errno.EINVAL: "no such control, or a value the camera does not offer",
    errno.ERANGE: "value out of range",
    errno.EBUSY: "busy",
    errno.EIO: "the camera did not answer (USB I/O error)",
    errno.ENOTTY: "not a V4L2 device",
}


class V4l2Controls:
    """The controls of the V4L2 device at ``path`` (``/dev/video0``, ``/dev/v4l/by-id/...``)."""

    def __init__(self, path: str) -> None:
        self.path = path
        try:
            self._fd = os.open(path, os.O_RDWR | os.O_NONBLOCK)
        except OSError as exc:
            raise ControlError(f"{path}: cannot open for its controls ({exc.strerror})") from exc

    def close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1

    def __enter__(self) -> V4l2Controls:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _ioctl(self, request: int, arg: ctypes.Structure, what: str) -> None:
        try:
            fcntl.ioctl(self._fd, request, arg)
        except OSError as exc:
            why = _WHY.get(exc.errno or 0, exc.strerror or str(exc))
            raise ControlError(f"{self.path}: {what}: {why}") from exc

    def query(self, name: ControlName) -> ControlInfo | None:
        q = _QueryCtrl(id=CONTROL_IDS[name])
        try:
            self._ioctl(VIDIOC_QUERYCTRL, q, f"query {name}")
        except ControlError as exc:
            if isinstance(exc.__cause__, OSError) and exc.__cause__.errno == errno.EINVAL:
                return None  # the camera has no such control
            raise
        if q.flags & _FLAG_DISABLED:
            return None
        menu: tuple[int, ...] = ()
        if q.type in (_TYPE_MENU, _TYPE_INTEGER_MENU):
            menu = tuple(i for i in range(q.minimum, q.maximum + 1) if self._menu_item(q.id, i))
        return ControlInfo(
            minimum=q.minimum,
            maximum=q.maximum,
            step=max(1, q.step),
            default=q.default_value,
            menu=menu,
            inactive=bool(q.flags & _FLAG_INACTIVE),
        )

    def _menu_item(self, control_id: int, index: int) -> bool:
        item = _QueryMenu(id=control_id, index=index)
        try:
            fcntl.ioctl(self._fd, VIDIOC_QUERYMENU, item)
        except OSError:
            return False  # a gap in the menu (UVC exposure_auto offers 1 and 3 only)
        return True

    def get(self, name: ControlName) -> int:
        c = _Control(id=CONTROL_IDS[name])
        self._ioctl(VIDIOC_G_CTRL, c, f"read {name}")
        return int(c.value)

    def set(self, name: ControlName, value: int) -> None:
        self._ioctl(VIDIOC_S_CTRL, _Control(id=CONTROL_IDS[name], value=int(value)), f"set {name} to {value}")
