"""The firmware with the ESP8266's floats: 30 bits in the object word (MicroPython v1.28.0, MICROPY_OBJ_REPR_C), every
intermediate rounded as the chip rounds it (firmware/harness/chipfloat.py). The parser's verdicts stay the contract's,
the safety layer's barrier holds, and formations still meet their bars without NaN or oscillation."""

from __future__ import annotations

import itertools
import math
import struct
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware.harness.chipfloat import ChipRover, chip_float, chip_modules, parse
from firmware.harness.runner import KinematicFleet, assert_formation_bars, formation_run
from tests.support import contract_oracle as oracle

CHIP: Any = chip_modules()
IDS = ["red", "green", "blue"]
SAFETY_CM = 30.0
BODY_RADIUS_CM = 14.0


def bits(x: float) -> int:
    return int(struct.unpack("<I", struct.pack("<f", x))[0])


@pytest.mark.parametrize(
    ("value", "stored"),
    [
        (1.0, 0x3F800000),  # exact: nothing to drop
        (math.pi, 0x40490FDA),  # the single 0x40490fdb, low bits 11 dropped, filled from the two above (10)
        (0.1, 0x3DCCCCCF),  # 0x3dcccccd -> 0x3dcccccc -> | 0b11
        (-2.5, 0xC0200000),
        (1e10, 0x501502FA),  # why t near 1e10 cannot be told from the limit (msg._T_COARSE)
    ],
)
def test_a_float_is_kept_as_the_port_boxes_it(value: float, stored: int) -> None:
    assert bits(chip_float(value)) == stored
    assert chip_float(chip_float(value)) == chip_float(value)


@settings(max_examples=300, deadline=None)
@given(st.floats(min_value=1e-30, max_value=1e30))
def test_30_bit_floats_keep_22_mantissa_bits(x: float) -> None:
    assert abs(chip_float(x) - x) <= x * 2.0**-21


def test_nan_and_infinity_stay_what_they_are() -> None:
    assert math.isnan(chip_float(float("nan")))
    assert chip_float(math.inf) == math.inf and chip_float(-1e39) == -math.inf  # beyond the largest single


def test_the_chip_parses_every_contract_example_and_mutation_as_the_contract_does() -> None:
    corpus = oracle.seeds() + oracle.mutation_corpus(3000, seed=11)
    accepted = 0
    for kind, payload in corpus:
        want = oracle.oracle(kind, payload)
        got = parse(kind, payload, CHIP)
        if want is None:
            assert got is None, payload
            continue
        accepted += 1
        for g, w in zip(got, oracle.as_fields(kind, want), strict=True):
            if type(g) is float:  # the contract's number (an int may stand for a float), as 30 bits hold it
                assert g == chip_float(float(w)), payload
            else:
                assert (list(g) if isinstance(g, tuple) else g) == w, payload
    assert accepted > 100


@pytest.mark.slow
@settings(max_examples=300, deadline=None)
@given(
    st.lists(st.tuples(st.floats(-200, 200), st.floats(-200, 200)), min_size=1, max_size=6),
    st.floats(-math.pi, math.pi),
    st.floats(-100, 100),
)
def test_the_barrier_holds_with_30_bit_floats(others: list[tuple[float, float]], theta: float, v: float) -> None:
    fm = CHIP["formation"]
    qx = [chip_float(p[0]) for p in others]
    qy = [chip_float(p[1]) for p in others]
    theta, v = chip_float(theta), chip_float(v)
    got = fm.safe_speed(v, 0.0, 0.0, theta, qx, qy, len(qx), SAFETY_CM, 4.0)
    assert math.isfinite(got)
    for x, y in zip(qx, qy, strict=True):
        if math.hypot(x, y) < SAFETY_CM:
            continue
        # d/dt |p - q|^2 = 2 (p - q) . e v >= -(gamma / 2) h, up to the rounding of 30-bit floats (2^-21 relative)
        rate = 2 * (-x * math.cos(theta) - y * math.sin(theta)) * got
        bound = -0.5 * 4.0 * (x * x + y * y - SAFETY_CM**2)
        assert rate >= bound - 1e-4 * (abs(bound) + 2 * math.hypot(x, y) * abs(got) + 1), (rate, bound)


def _settled_motion_cm(fleet: KinematicFleet, seconds: float = 3.0) -> float:
    """How far any rover moved over the last seconds of the run (a rover hunting round its place moves)."""
    rows = [xy for t, xy in zip(fleet.trace.t_s, fleet.trace.xy, strict=True) if t >= fleet.trace.t_s[-1] - seconds]
    return max(sum(math.dist(a[k], b[k]) for a, b in itertools.pairwise(rows)) for k in range(len(IDS)))


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["line", "rendezvous", "triangle"])
@pytest.mark.parametrize(("seed", "send_theta"), [(1, True), (2, False)])
def test_formations_meet_their_bars_with_30_bit_floats_without_nan_or_oscillation(
    kind: str, seed: int, send_theta: bool
) -> None:
    fleet = formation_run(kind, seed, 12.0, send_theta=send_theta, rover=ChipRover)
    assert_formation_bars(kind, fleet.positions())
    assert fleet.trace.min_distance_cm >= 2 * BODY_RADIUS_CM
    assert all(h == "none" for h in fleet.trace.halts[-1])
    assert all(math.isfinite(x) for _, _, command, wheels in fleet.commands for x in (*command, *wheels))
    # Settled as still as with double precision: no limit cycle from the coarser numbers.
    double = formation_run(kind, seed, 12.0, send_theta=send_theta)
    assert _settled_motion_cm(fleet) <= _settled_motion_cm(double) + 0.5
