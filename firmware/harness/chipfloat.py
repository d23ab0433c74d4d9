"""The firmware's arithmetic as the ESP8266 port of MicroPython v1.28.0 does it, on the host.

The port stores floats in the object word (``MICROPY_OBJ_REPR_C``, ``MICROPY_FLOAT_IMPL_FLOAT``; py/obj.h): every
float a Python expression produces is an IEEE single computed in single precision, then boxed by dropping the two
lowest mantissa bits (``mp_obj_new_float``: ``(u & ~3) | 2``, plus an offset) and unboxed with those two bits filled
from the two above them (``mp_obj_float_get``: ``u |= (u >> 2) & 3``): 22 stored mantissa bits, 30 bits in all. NaN
becomes the one canonical NaN. Math functions are libm's single-precision ones (within an ulp of the correctly
rounded single, which is what this harness uses: four times finer than the boxing).

:func:`chip_modules` compiles the firmware's pure modules (msg, formation, rover, motors, config) with every float
that can appear rounded that way: each arithmetic result, each float literal, ``pi``, the math functions, and the
numbers ``json`` parses. For +, -, *, / the double-precision result rounded to single is the single-precision result
(a double has more than twice the bits), so rounding after each operation reproduces the chip. The same wrapping
counts the float objects each operation creates, which is what a MicroPython build with boxed floats (the wasm one)
allocates and the chip does not (:attr:`Counter.floats`).
"""

from __future__ import annotations

import ast
import builtins
import json
import math
import struct
import types
from collections.abc import Callable
from pathlib import Path
from typing import Any

FIRMWARE = Path(__file__).resolve().parents[2] / "firmware" / "esp8266"
PURE = ("msg", "formation", "motors", "config", "rover")  # in dependency order
_MATH = {"sin", "cos", "atan2", "sqrt"}
_NAN = float("nan")


def chip_float(x: float) -> float:
    """``x`` as a float object on the ESP8266 holds it: single precision, 30 bits in the object word."""
    if math.isnan(x):
        return _NAN
    try:
        (u,) = struct.unpack("<I", struct.pack("<f", x))
    except OverflowError:  # beyond the largest single: the C conversion gives infinity
        return math.copysign(math.inf, x)
    u &= ~3
    u |= (u >> 2) & 3
    (f,) = struct.unpack("<f", struct.pack("<I", u))
    return float(f)


class Counter:
    """Float objects created since the last reset (what a boxed-float MicroPython allocates, 16 B each)."""

    def __init__(self) -> None:
        self.floats = 0


class _Rounding(ast.NodeTransformer):
    """Wraps every float-producing expression: ``_r(expr)`` rounds and counts, ``_c(const)`` only rounds."""

    def _wrap(self, name: str, node: ast.expr) -> ast.expr:
        return ast.copy_location(ast.Call(func=ast.Name(id=name, ctx=ast.Load()), args=[node], keywords=[]), node)

    def visit_BinOp(self, node: ast.BinOp) -> ast.expr:
        self.generic_visit(node)
        return self._wrap("_r", node)

    def visit_UnaryOp(self, node: ast.UnaryOp) -> ast.expr:
        self.generic_visit(node)
        if isinstance(node.op, ast.USub | ast.UAdd):
            if isinstance(node.operand, ast.Constant):
                return self._wrap("_c", node)  # a negative literal: folded by the compiler, no object made
            return self._wrap("_r", node)
        return node

    def visit_Constant(self, node: ast.Constant) -> ast.expr:
        if type(node.value) is float:
            return self._wrap("_c", node)
        return node

    def visit_Name(self, node: ast.Name) -> ast.expr:
        if node.id == "pi" and isinstance(node.ctx, ast.Load):
            return self._wrap("_c", node)  # math.pi: a float constant of the firmware image, boxed
        return node

    def visit_AugAssign(self, node: ast.AugAssign) -> ast.stmt:
        self.generic_visit(node)
        target = node.target
        load = ast.copy_location(_as_load(target), target)
        value = self._wrap("_r", ast.copy_location(ast.BinOp(left=load, op=node.op, right=node.value), node))
        return ast.copy_location(ast.Assign(targets=[target], value=value), node)

    def visit_Call(self, node: ast.Call) -> ast.expr:
        self.generic_visit(node)
        func = node.func
        if isinstance(func, ast.Name) and func.id in _MATH:
            return self._wrap("_r", node)
        if isinstance(func, ast.Name) and func.id in ("abs", "float"):  # these may hand back their argument
            node.func = ast.copy_location(ast.Name(id="_" + func.id, ctx=ast.Load()), func)
            return node
        if isinstance(func, ast.Attribute) and func.attr in ("loads", "load") and _is_name(func.value, "json"):
            return self._wrap("_tree", node)
        return node


def _as_load(target: ast.expr) -> ast.expr:
    if isinstance(target, ast.Name):
        return ast.Name(id=target.id, ctx=ast.Load())
    if isinstance(target, ast.Attribute):
        return ast.Attribute(value=target.value, attr=target.attr, ctx=ast.Load())
    if isinstance(target, ast.Subscript):
        return ast.Subscript(value=target.value, slice=target.slice, ctx=ast.Load())
    raise TypeError(f"augmented assignment to {ast.dump(target)}")


def _is_name(node: ast.expr, name: str) -> bool:
    return isinstance(node, ast.Name) and node.id == name


def _helpers(counter: Counter) -> dict[str, Callable[[Any], Any]]:
    def r(x: Any) -> Any:
        if type(x) is float:
            counter.floats += 1
            return chip_float(x)
        return x

    def c(x: Any) -> Any:
        return chip_float(x) if type(x) is float else x

    def tree(x: Any) -> Any:
        return chip_tree(x, counter)

    def chip_abs(x: Any) -> Any:
        # MicroPython returns a non-negative float itself, and makes a new one for a negative.
        return r(abs(x)) if type(x) is float and x < 0 else abs(x)

    def float_call(x: Any) -> Any:
        return x if type(x) is float else r(float(x))

    return {"_r": r, "_c": c, "_tree": tree, "_abs": chip_abs, "_float": float_call}


def chip_modules(counter: Counter | None = None) -> dict[str, types.ModuleType]:
    """Fresh copies of the firmware's pure modules (:data:`PURE`) computing as the chip does; they import each other
    and ``micropython.const`` from this set, everything else from the host."""
    from edge.rover_host import firmware_modules

    firmware_modules()  # the host stand-ins (machine) the firmware imports
    counter = counter or Counter()
    helpers = _helpers(counter)
    modules: dict[str, types.ModuleType] = {}
    micropython = types.ModuleType("micropython")
    micropython.const = lambda v: v  # type: ignore[attr-defined]
    real_import = builtins.__import__

    def firmware_import(name: str, globals: Any = None, locals: Any = None, fromlist: Any = (), level: int = 0) -> Any:
        if name in modules:
            return modules[name]
        if name == "micropython":
            return micropython
        return real_import(name, globals, locals, fromlist, level)

    scope = {**builtins.__dict__, "__import__": firmware_import}
    for name in PURE:
        path = FIRMWARE / f"{name}.py"
        tree = _Rounding().visit(ast.parse(path.read_text(), str(path)))
        ast.fix_missing_locations(tree)
        module = types.ModuleType(name)
        module.__dict__.update(helpers, __builtins__=scope, __file__=str(path))
        exec(compile(tree, str(path), "exec"), module.__dict__)
        modules[name] = module
    modules["counter"] = types.SimpleNamespace(counter=counter)  # type: ignore[assignment]
    return modules


def parse(kind: str, payload: bytes, modules: dict[str, types.ModuleType]) -> Any:
    """The chip's verdict on a message (``pose`` or ``formation``): its fields or None."""
    msg: Any = modules["msg"]
    return msg.parse_pose(payload) if kind == "pose" else msg.parse_formation(payload)


def chip_tree(x: Any, counter: Counter | None = None) -> Any:
    """A JSON document (a message, a config) with its floats as the chip reads them; ``counter`` counts them (json
    makes each one)."""
    if type(x) is float:
        if counter is not None:
            counter.floats += 1
        return chip_float(x)
    if type(x) is dict:
        return {k: chip_tree(v, counter) for k, v in x.items()}
    if type(x) is list:
        return [chip_tree(v, counter) for v in x]
    return x


class ChipRover:
    """A rover's firmware with the chip's floats, for :class:`firmware.harness.runner.KinematicFleet` (the part of
    HostRover it uses: no broker; messages are handed over with :meth:`deliver`)."""

    def __init__(self, config: dict[str, Any], modules: dict[str, types.ModuleType] | None = None) -> None:
        self.modules = modules or chip_modules()
        fw: Any = self.modules
        cfg = json.loads(json.dumps(config))
        cfg["broker"] = {**cfg.get("broker", {}), "host": cfg.get("broker", {}).get("host") or "none"}
        self.config = fw["config"].check(fw["config"].merge(fw["config"].DEFAULTS, chip_tree(cfg)))
        self.id: str = self.config["id"]
        self.motors = fw["motors"].Motors(self.config["motors"])
        self.rover = fw["rover"].Rover(self.config, self.motors, log=lambda *a: None)

    def step(self, now_ms: int) -> None:
        self.rover.step(now_ms & ((1 << 30) - 1))

    def deliver(self, topic: str | bytes, payload: bytes, now_ms: int | None = None) -> None:
        if now_ms is not None:
            self.rover._now = now_ms & ((1 << 30) - 1)
        self.rover.on_message(topic.encode() if isinstance(topic, str) else topic, payload)

    @property
    def halt(self) -> str:
        return str(self.rover.halt)

    @property
    def wheel_speeds_rad_s(self) -> tuple[float, float]:
        left, right = self.motors.speeds()
        return float(left), float(right)
