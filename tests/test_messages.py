"""The message contract: generated schemas, golden examples, canonical encoding."""

from __future__ import annotations

import json
import math
from pathlib import Path

import jsonschema
import pytest
from hypothesis import given
from hypothesis import strategies as st

from edge import contract, messages
from edge.errors import MessageError
from tests.conftest import EXAMPLES, SCHEMA_DIR

VALID = sorted((EXAMPLES / "valid").iterdir())
INVALID = sorted((EXAMPLES / "invalid").iterdir())


def _kind(path: Path) -> str:
    return path.name.split("-", 1)[0]


def _validator(kind: str) -> jsonschema.Draft202012Validator:
    doc = json.loads((SCHEMA_DIR / contract.schema_file(kind)).read_text())
    return jsonschema.Draft202012Validator(doc)


def test_committed_schemas_match_the_models() -> None:
    generated = contract.schema_documents()
    committed = {p.name for p in SCHEMA_DIR.glob("*.schema.json")}
    assert committed == set(generated), "schema files differ from the models: run `edge-ips schema`"
    for name, doc in generated.items():
        assert (SCHEMA_DIR / name).read_text() == contract.render_schema(doc), (
            f"{name} drifted from edge/messages.py or edge/board_messages.py: run `edge-ips schema --out shared/schema`"
        )


def test_schemas_are_valid_json_schema() -> None:
    for name in contract.schema_documents():
        jsonschema.Draft202012Validator.check_schema(json.loads((SCHEMA_DIR / name).read_text()))


def test_examples_cover_every_message_kind() -> None:
    assert {_kind(p) for p in VALID} == set(contract.MODELS)
    assert {_kind(p) for p in INVALID} == set(contract.MODELS)


@pytest.mark.parametrize("path", VALID, ids=lambda p: p.name)
def test_valid_example_parses_to_the_values_in_the_file(path: Path) -> None:
    payload = path.read_bytes()
    model = contract.PARSERS[_kind(path)](payload)
    expected = json.loads(payload)
    assert model.model_dump() == expected
    _validator(_kind(path)).validate(expected)


@pytest.mark.parametrize("path", INVALID, ids=lambda p: p.name)
def test_invalid_example_is_rejected(path: Path) -> None:
    with pytest.raises(MessageError):
        contract.PARSERS[_kind(path)](path.read_bytes())


class _FloatLiteral(float):
    """A JSON number written with a fraction or exponent (``1.0``), which the contract never accepts for an int."""


def _int_fields_written_as_floats(doc: object, schema: dict[str, object]) -> bool:
    props = schema.get("properties", {})
    assert isinstance(props, dict)

    def integer(prop: dict[str, object]) -> bool:  # "integer", or a nullable one (anyOf integer / null)
        options = prop.get("anyOf", [prop])
        assert isinstance(options, list)
        return any(o.get("type") == "integer" for o in options)

    return isinstance(doc, dict) and any(
        isinstance(doc.get(key), _FloatLiteral) and integer(props[key]) for key in doc if key in props
    )


@pytest.mark.parametrize("path", INVALID, ids=lambda p: p.name)
def test_invalid_example_is_rejected_by_the_json_schema_or_the_byte_rules(path: Path) -> None:
    """What the schema language cannot say (size, encoding, NaN, ``1.0`` for an int) the README's rules say."""
    payload = path.read_bytes()
    kind = _kind(path)
    schema = contract.schema_documents()[contract.schema_file(kind)]
    if len(payload) > schema["x-max-bytes"]:
        return
    try:
        doc = json.loads(
            payload.decode("utf-8"),
            parse_float=_FloatLiteral,
            parse_constant=lambda c: pytest.fail(f"{c} is not JSON"),
        )
    except (UnicodeDecodeError, json.JSONDecodeError):
        return
    except pytest.fail.Exception:
        return
    if _int_fields_written_as_floats(doc, schema):
        return
    if _breaks_a_rule_beyond_the_schema(kind, doc):
        return
    assert not _validator(kind).is_valid(doc)


def _breaks_a_rule_beyond_the_schema(kind: str, doc: object) -> bool:
    """The README's rules for detections that JSON Schema cannot state: each covariance positive definite, each
    rover id once per message."""
    if kind != "detections" or not isinstance(doc, dict) or not isinstance(doc.get("rovers"), list):
        return False
    rovers = [r for r in doc["rovers"] if isinstance(r, dict)]
    ids = [r.get("id") for r in rovers]
    if len(set(ids)) != len(ids):
        return True
    for r in rovers:
        cov = r.get("cov")
        if isinstance(cov, list) and len(cov) == 3 and all(isinstance(c, int | float) for c in cov):
            xx, xy, yy = cov
            if not (xx > 0 and yy > 0 and xx * yy > xy * xy):
                return True
    return False


NON_CANONICAL = {"pose-integers.json", "pose-reordered-spaced.json"}  # valid, but not what the edge writes


@pytest.mark.parametrize("path", [p for p in VALID if p.name not in NON_CANONICAL], ids=lambda p: p.name)
def test_canonical_example_is_the_byte_exact_encoding_of_its_values(path: Path) -> None:
    payload = path.read_bytes()
    assert messages.dumps(contract.PARSERS[_kind(path)](payload)) == payload


def test_longest_pose_fits_the_byte_budget() -> None:
    payload = (EXAMPLES / "valid" / "pose-longest.json").read_bytes()
    assert len(payload) <= messages.POSE_MAX_BYTES


@pytest.mark.parametrize(
    ("theta_in", "theta_out"),
    [(0.0, 0.0), (math.pi, 3.1416), (-math.pi + 1e-9, -3.1416), (3 * math.pi / 2, -1.5708), (7.0, 0.7168)],
)
def test_heading_is_wrapped_into_minus_pi_pi(theta_in: float, theta_out: float) -> None:
    pose = messages.parse_pose(messages.encode_pose("red", 0, 0, 0.0, 0.0, 0.0, theta_in, None, None, 1.0))
    assert pose.theta == pytest.approx(theta_out, abs=1e-4)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_encoder_refuses_non_finite_values(bad: float) -> None:
    with pytest.raises(MessageError):
        messages.encode_pose("red", 0, 0, 0.0, bad, 0.0, None, None, None, 1.0)


finite = st.floats(allow_nan=False, allow_infinity=False)


@pytest.mark.slow
@given(
    rover_id=st.from_regex(r"\A[a-z0-9_-]{1,16}\Z"),
    seq=st.integers(min_value=0, max_value=2**40),
    t=st.floats(min_value=0, max_value=9e9),
    x=st.floats(min_value=-9999.99, max_value=9999.99),
    y=st.floats(min_value=-9999.99, max_value=9999.99),
    theta=st.one_of(st.none(), st.floats(min_value=-100, max_value=100)),
    vx=st.one_of(st.none(), finite),
    q=st.floats(min_value=-1, max_value=2),
)
def test_every_encoded_pose_is_valid_and_round_trips(
    rover_id: str, seq: int, t: float, x: float, y: float, theta: float | None, vx: float | None, q: float
) -> None:
    payload = messages.encode_pose(rover_id, seq, seq, t, x, y, theta, vx, vx, q)
    assert len(payload) <= messages.POSE_MAX_BYTES
    pose = messages.parse_pose(payload)
    _validator("pose").validate(json.loads(payload))
    assert messages.dumps(pose) == payload
    assert pose.x == pytest.approx(x, abs=0.005 + 1e-9)


@pytest.mark.parametrize(
    ("ids", "problem"),
    [
        (["red", "green", "blue"], None),
        ([], None),
        (["red", "Red"], "rover id 'Red' is not an id: 1-16 of a-z, 0-9, _ and -"),
        (["red", "a" * 17], f"rover id '{'a' * 17}' is not an id: 1-16 of a-z, 0-9, _ and -"),
        (["red\n"], "rover id 'red\\n' is not an id: 1-16 of a-z, 0-9, _ and -"),  # "$" matches before a newline
        (["red", "blue", "red", "blue", "green"], "blue, red named more than once"),
    ],
)
def test_one_rule_for_a_list_of_rover_ids(ids: list[str], problem: str | None) -> None:
    assert messages.id_problem(ids) == problem
