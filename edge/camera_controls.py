"""Camera controls: focus, white balance, exposure, gain and flicker, fixed so that a calibration and the marker
colours stay true.

A webcam left to itself autofocuses, which moves the focal length under a calibration, and auto white-balances,
which moves the hues the rovers are told apart by. ``[camera.controls]`` fixes them; :func:`apply_controls` sets
them on the device in the order UVC cameras need (each automatic mode off before its manual value: a C920 refuses
``focus_absolute`` with EACCES while autofocus is on) and reads every one back, because a driver clamps a value to
its range and step (the C920 focuses in steps of 5) or ignores it. What the camera granted is what gets logged.

The device sits behind the small :class:`ControlDevice` protocol (real: :class:`edge.v4l2.V4l2Controls`, ioctls on
``/dev/videoN``; tests: a fake that accepts, refuses and clamps as a UVC driver does). Values are V4L2's own.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, Protocol

from pydantic import BaseModel, ConfigDict, Field, model_validator

from edge.errors import SourceError

ControlName = Literal[
    "focus_auto",
    "focus",
    "white_balance_auto",
    "white_balance_k",
    "exposure_auto",
    "exposure",
    "exposure_dynamic_framerate",
    "gain",
    "power_line",
    "sharpness",
]
EXPOSURE_MANUAL, EXPOSURE_APERTURE_PRIORITY = 1, 3  # V4L2_CID_EXPOSURE_AUTO menu items a UVC camera offers
POWER_LINE_MENU = {0: 0, 50: 1, 60: 2}  # Hz -> V4L2_CID_POWER_LINE_FREQUENCY menu item (0 = no flicker filter)


class ControlError(SourceError):
    """The device refused a control (the driver's errno in words)."""


@dataclass(frozen=True)
class ControlInfo:
    """What the device says about a control: its range and step (integers), menu items, and whether it is
    inactive (its automatic mode is on) right now."""

    minimum: int
    maximum: int
    step: int = 1
    default: int = 0
    menu: tuple[int, ...] = ()
    inactive: bool = False


class ControlDevice(Protocol):
    """A camera's controls by name. ``query`` is None for a control the camera does not have."""

    def query(self, name: ControlName) -> ControlInfo | None: ...

    def get(self, name: ControlName) -> int: ...

    def set(self, name: ControlName, value: int) -> None: ...

    def close(self) -> None: ...


INT32_MAX = 2**31 - 1  # V4L2 control values are 32-bit (struct v4l2_control)


class CameraControls(BaseModel):
    """``[camera.controls]``: unset keys are left as the camera has them."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    autofocus: bool | None = Field(default=None, description="false: fixed focus (needed under a calibration).")
    focus: int | None = Field(
        default=None, ge=0, le=INT32_MAX, description="Fixed focus, camera units (C920: 0-250 in 5s)."
    )
    auto_white_balance: bool | None = Field(default=None, description="false: fixed white balance (stable hues).")
    white_balance_k: int | None = Field(default=None, ge=1000, le=15000, description="Colour temperature, K.")
    auto_exposure: bool | None = Field(default=None, description="false: manual exposure; true: the camera's.")
    exposure: int | None = Field(
        default=None, ge=1, le=INT32_MAX, description="Exposure time, units of 100 us (V4L2's)."
    )
    exposure_dynamic_framerate: bool | None = Field(
        default=None, description="false: keep the frame rate in low light (the camera may not lengthen frames)."
    )
    gain: int | None = Field(default=None, ge=0, le=INT32_MAX)
    power_line_hz: Literal[0, 50, 60] | None = Field(default=None, description="Mains frequency (flicker), 0: off.")
    sharpness: int | None = Field(
        default=None,
        ge=0,
        le=INT32_MAX,
        description="The camera's own sharpening; its least (C920: 0 of 0-255) is none: its halos move marker centres.",
    )

    @model_validator(mode="after")
    def _manual_values_need_manual_modes(self) -> CameraControls:
        for value, auto, names in (
            (self.focus, self.autofocus, ("focus", "autofocus")),
            (self.white_balance_k, self.auto_white_balance, ("white_balance_k", "auto_white_balance")),
            (self.exposure, self.auto_exposure, ("exposure", "auto_exposure")),
        ):
            if value is not None and auto is not False:
                raise ValueError(f"{names[0]} is only used with {names[1]} = false")
        return self

    def wanted(self) -> list[tuple[ControlName, int]]:
        """(control, V4L2 value) in the order a UVC camera takes them: every automatic mode first."""
        steps: list[tuple[ControlName, int | None]] = [
            ("focus_auto", _flag(self.autofocus)),
            ("white_balance_auto", _flag(self.auto_white_balance)),
            (
                "exposure_auto",
                None
                if self.auto_exposure is None
                else (EXPOSURE_APERTURE_PRIORITY if self.auto_exposure else EXPOSURE_MANUAL),
            ),
            ("exposure_dynamic_framerate", _flag(self.exposure_dynamic_framerate)),
            ("power_line", None if self.power_line_hz is None else POWER_LINE_MENU[self.power_line_hz]),
            ("focus", self.focus),
            ("white_balance_k", self.white_balance_k),
            ("exposure", self.exposure),
            ("gain", self.gain),
            ("sharpness", self.sharpness),
        ]
        return [(name, value) for name, value in steps if value is not None]


def _flag(value: bool | None) -> int | None:
    return None if value is None else int(value)


@dataclass(frozen=True)
class Granted:
    """One control: what was asked, what the camera reports after setting it (None: not set), and why not."""

    name: ControlName
    asked: int
    got: int | None
    problem: str = ""

    def text(self) -> str:
        if self.got is None:
            return f"{self.name} {self.asked} not set: {self.problem}"
        if self.got != self.asked:
            return f"{self.name} {self.got} (asked {self.asked}: {self.problem})"
        return f"{self.name} {self.got}"


@dataclass(frozen=True)
class ControlsReport:
    """Every control asked for, as granted. ``ok``: each was set to exactly the value asked."""

    granted: tuple[Granted, ...] = field(default_factory=tuple)

    @property
    def ok(self) -> bool:
        return all(g.got == g.asked for g in self.granted)

    def line(self) -> str:
        return "; ".join(g.text() for g in self.granted) or "none asked"


def _apply_one(device: ControlDevice, name: ControlName, value: int) -> Granted:
    info = device.query(name)
    if info is None:
        return Granted(name, value, None, "the camera has no such control")
    if info.menu and value not in info.menu:
        return Granted(name, value, None, f"the camera offers {', '.join(str(m) for m in info.menu)}")
    try:
        device.set(name, value)
    except ControlError as exc:
        return Granted(name, value, None, f"refused ({exc})")
    got = device.get(name)
    if got == value:
        return Granted(name, value, got)
    if not info.minimum <= value <= info.maximum:
        why = f"clamped to the camera's range {info.minimum}-{info.maximum}"
    elif info.step > 1 and (value - info.minimum) % info.step:
        why = f"rounded to the camera's step of {info.step}"
    else:
        why = "the camera kept another value"
    return Granted(name, value, got, why)


def apply_controls(device: ControlDevice, controls: CameraControls) -> ControlsReport:
    """Set every control ``controls`` asks for, automatic modes first, and read each back."""
    return ControlsReport(tuple(_apply_one(device, name, value) for name, value in controls.wanted()))


def sharpening_on(device: ControlDevice) -> str | None:
    """What the camera's sharpening is set to when it is above the camera's least (which is none on UVC cameras),
    or None. A sharpened edge overshoots on both sides (a dark halo outside a bright one), unlike the optics' blur the
    marker edges are measured against: ``docs/benchmarks.md``, "The camera family's image processor"."""
    info = device.query("sharpness")
    if info is None:
        return None
    value = device.get("sharpness")
    return f"sharpness {value} (the camera's least is {info.minimum})" if value > info.minimum else None


def automatic_modes_on(device: ControlDevice) -> list[str]:
    """The automatic modes that move a calibration or the colours and are on now: autofocus, auto white balance."""
    on = []
    for name, label in (("focus_auto", "autofocus"), ("white_balance_auto", "auto white balance")):
        if device.query(name) is not None and device.get(name) != 0:  # type: ignore[arg-type]
            on.append(label)
    return on
