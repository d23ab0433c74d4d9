"""Host stand-in for MicroPython's ``micropython`` module: just what the firmware uses (``const``)."""

from __future__ import annotations

from typing import TypeVar

T = TypeVar("T")


def const(value: T) -> T:
    """On the board ``const()`` folds the value into the bytecode; on the host it is the identity."""
    return value
