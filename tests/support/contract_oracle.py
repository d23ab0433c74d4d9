"""The contract's own verdict on a payload, for checking the firmware's parser against it.

A payload is valid when it fits the kind's byte budget, is strict RFC 8259 JSON in UTF-8 (no NaN or Infinity),
both the JSON Schema in ``shared/schema`` and the pydantic model in ``edge/messages.py`` accept it, and no integer
field is written as a float (shared/schema/README.md: "ints may stand for floats, never the reverse"). The last
rule is stricter than either machine check: JSON Schema's "integer" admits 1.0, and pydantic's ``Literal[1]``
admits ``"v":1.0``; the firmware follows the README.
"""

from __future__ import annotations

import json
import math
import random
from decimal import Decimal
from functools import cache
from typing import Any

import jsonschema

from edge import contract, messages
from edge.errors import MessageError
from tests.conftest import EXAMPLES, SCHEMA_DIR

MAX_BYTES = {"pose": messages.POSE_MAX_BYTES, "formation": messages.FORMATION_MAX_BYTES}
POSE_FIELDS = ("id", "seq", "frame", "t", "x", "y", "theta", "vx", "vy", "q")
FORMATION_FIELDS = ("seq", "kind", "ids", "spacing", "side", "x", "y", "theta")
INT_FIELDS = ("v", "seq", "frame")
T_WRAP = 1 << 26  # the firmware keeps a pose's t as whole ms modulo this (msg._T_WRAP)


@cache
def validator(kind: str) -> jsonschema.Draft202012Validator:
    doc = json.loads((SCHEMA_DIR / contract.schema_file(kind)).read_text())
    return jsonschema.Draft202012Validator(doc)


def _no_constants(name: str) -> Any:
    raise ValueError(f"{name} is not JSON")


def strict_json(payload: bytes) -> Any:
    """The JSON value of payload, or raises ValueError (not UTF-8, not JSON, NaN/Infinity)."""
    return json.loads(payload.decode("utf-8"), parse_constant=_no_constants)


def oracle(kind: str, payload: bytes) -> dict[str, Any] | None:
    """The message's fields when the contract accepts it, else None."""
    if len(payload) > MAX_BYTES[kind]:
        return None
    try:
        doc = strict_json(payload)
    except ValueError:
        return None
    if not validator(kind).is_valid(doc):
        return None
    if any(type(doc.get(k)) is float for k in INT_FIELDS):
        return None
    try:
        contract.PARSERS[kind](payload)
    except MessageError:
        return None
    if kind == "pose":
        doc["t_ms"] = t_ms(payload)
    return dict(doc)


def t_ms(payload: bytes) -> int:
    """A valid pose's t in whole milliseconds (rounded down) modulo :data:`T_WRAP`, from the exact decimal value of
    its JSON text (the last "t" when a key is doubled, as every JSON parser here keeps)."""
    exact = json.loads(payload.decode("utf-8"), parse_float=Decimal, parse_constant=_no_constants)["t"]
    return math.floor(Decimal(exact) * 1000) % T_WRAP


def as_fields(kind: str, doc: dict[str, Any]) -> list[Any]:
    """The oracle's fields in the order of the firmware's tuple (absent optional formation fields are null); a pose's
    t as the firmware keeps it: from the payload's digits in a doc from :func:`oracle`, else from the number's
    shortest repr (a golden file's t, which its digits give exactly)."""
    if kind != "pose":
        return [doc.get(n) for n in FORMATION_FIELDS]
    out = [doc.get(n) for n in POSE_FIELDS]
    out[3] = doc["t_ms"] if "t_ms" in doc else math.floor(Decimal(repr(doc["t"])) * 1000) % T_WRAP
    return out


def same_fields(got: Any, want: list[Any], rel: float = 0.0) -> bool:
    """Firmware tuple (or its JSON echo from MicroPython) equal to the oracle's fields; numbers to ``rel``."""
    if got is None or len(got) != len(want):
        return False
    for g, w in zip(got, want, strict=True):
        if isinstance(w, bool) or isinstance(g, bool):
            return False
        if isinstance(w, int | float) and not isinstance(w, bool):
            if not isinstance(g, int | float) or abs(g - w) > rel * abs(w):
                return False
        elif isinstance(w, list):
            if list(g) != w:
                return False
        elif g != w:
            return False
    return True


# -- mutated messages ------------------------------------------------------------------------------------------------
INTERESTING = b',:{}[]" \t\n0123456789.-+eEtrufalsn\\\x00\x7f\xc3\xa9x'


def seeds() -> list[tuple[str, bytes]]:
    """Valid messages to mutate: the golden examples and canonical poses from the edge's encoder."""
    out = []
    for path in sorted((EXAMPLES / "valid").iterdir()):
        kind = path.name.split("-", 1)[0]
        if kind in MAX_BYTES:
            out.append((kind, path.read_bytes()))
    rng = random.Random(7)
    for _ in range(20):
        out.append(
            (
                "pose",
                messages.encode_pose(
                    rng.choice(["red", "green", "blue", "r-1", "a_b"]),
                    rng.randrange(0, 10**9),
                    rng.randrange(0, 10**9),
                    rng.uniform(0, 2e9),
                    rng.uniform(-500, 500),
                    rng.uniform(-500, 500),
                    rng.choice([None, rng.uniform(-3.2, 3.2)]),
                    rng.choice([None, rng.uniform(-50, 50), 0.0]),
                    rng.choice([None, rng.uniform(-50, 50)]),
                    rng.choice([0.0, 1.0, rng.random()]),
                ),
            )
        )
    return out


def mutate(payload: bytes, rng: random.Random) -> bytes:
    """One or two edits: delete, insert, replace or duplicate bytes, biased towards JSON's structural characters."""
    data = bytearray(payload)
    for _ in range(rng.choice((1, 1, 1, 2))):
        op = rng.randrange(5)
        i = rng.randrange(len(data) + 1)
        if op == 0 and data:
            del data[min(i, len(data) - 1)]
        elif op == 1:
            data[i:i] = bytes([rng.choice(INTERESTING)])
        elif op == 2 and data:
            data[min(i, len(data) - 1)] = rng.choice(INTERESTING)
        elif op == 3 and data:
            j = rng.randrange(len(data))
            a, b = sorted((i, j))
            data[b:b] = data[a:b][:12]
        else:
            # Swap a structural byte for another one.
            spots = [k for k, c in enumerate(data) if c in b",:{}[]"]
            if spots:
                data[rng.choice(spots)] = rng.choice(b",:{}[]")
    return bytes(data)


def mutation_corpus(n: int, seed: int = 1) -> list[tuple[str, bytes]]:
    rng = random.Random(seed)
    base = seeds()
    return [(kind, mutate(payload, rng)) for kind, payload in (rng.choice(base) for _ in range(n))]
