"""The firmware's message parser (firmware/esp8266/msg.py) under CPython, against the contract in shared/schema.

The same checks run inside MicroPython in test_firmware_micropython.py.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from edge import messages
from edge.rover_host import firmware_modules
from tests.conftest import EXAMPLES
from tests.support import contract_oracle as oracle

msg: Any = firmware_modules()["msg"]

VALID = sorted((EXAMPLES / "valid").iterdir())
INVALID = sorted((EXAMPLES / "invalid").iterdir())
ROVER_KINDS = ("pose", "formation")  # what the firmware parses; statuses and detections are not for it


def parse(kind: str, payload: bytes) -> Any:
    return msg.parse_pose(payload) if kind == "pose" else msg.parse_formation(payload)


def _kind(path: Path) -> str:
    return path.name.split("-", 1)[0]


@pytest.mark.parametrize("path", [p for p in VALID if _kind(p) in ROVER_KINDS], ids=lambda p: p.name)
def test_valid_example_parses_to_exactly_the_values_in_the_file(path: Path) -> None:
    kind = _kind(path)
    got = parse(kind, path.read_bytes())
    want = oracle.as_fields(kind, json.loads(path.read_bytes()))
    assert got is not None
    assert list(got) == [tuple(w) if isinstance(w, list) else w for w in want]
    for g, w in zip(got, want, strict=True):  # ints kept for counters; numbers as floats; ids as a tuple
        assert type(g) is type(w) or (type(w), type(g)) in ((int, float), (list, tuple))


@pytest.mark.parametrize("path", [p for p in INVALID if _kind(p) in ROVER_KINDS], ids=lambda p: p.name)
def test_invalid_example_is_rejected(path: Path) -> None:
    assert parse(_kind(path), path.read_bytes()) is None


@pytest.mark.parametrize("path", [p for p in VALID + INVALID if _kind(p) not in ROVER_KINDS], ids=lambda p: p.name)
def test_statuses_and_detections_are_neither_a_pose_nor_a_formation(path: Path) -> None:
    assert msg.parse_pose(path.read_bytes()) is None
    assert msg.parse_formation(path.read_bytes()) is None


# -- what MicroPython's json.loads would let through ------------------------------------------------------------------
CANONICAL = messages.encode_pose("red", 42, 1234, 1763900000.123, 81.5, 32.47, 1.5708, 12.3, -4.5, 0.97)


@pytest.mark.parametrize(
    ("what", "payload"),
    [
        ("missing comma", CANONICAL.replace(b',"seq"', b' "seq"')),
        ("missing colon", CANONICAL.replace(b'"seq":', b'"seq" ')),
        ("doubled colon", CANONICAL.replace(b'"seq":', b'"seq"::')),
        ("doubled comma", CANONICAL.replace(b',"seq"', b',,"seq"')),
        ("trailing comma", CANONICAL[:-1] + b",}"),
        ("leading zero", CANONICAL.replace(b'"seq":42', b'"seq":042')),
        ("negative leading zero", CANONICAL.replace(b'"x":81.5', b'"x":-081.5')),
        ("dot without digits", CANONICAL.replace(b'"x":81.5', b'"x":81.')),
        ("dot before exponent", CANONICAL.replace(b'"x":81.5', b'"x":81.e1')),
        ("literal glued to digits", CANONICAL.replace(b'"vx":12.3', b'"vx":null1')),
        ("bracket closes brace", CANONICAL[:-1] + b"]"),
        ("bytes after the object", CANONICAL + b"\x00"),
        ("BOM", b"\xef\xbb\xbf" + CANONICAL),
        ("raw newline in id", CANONICAL.replace(b'"red"', b'"re\nd"')),
        ("NaN", CANONICAL.replace(b'"x":81.5', b'"x":NaN')),
        ("Infinity", CANONICAL.replace(b'"vx":12.3', b'"vx":Infinity')),
        ("bool for number", CANONICAL.replace(b'"q":0.97', b'"q":true')),
        ("float for int", CANONICAL.replace(b'"seq":42', b'"seq":42.0')),
        ("huge exponent", CANONICAL.replace(b'"y":32.47', b'"y":1e400')),
        ("escaped uppercase id", CANONICAL.replace(b'"red"', b'"\\u0052ed"')),
        ("key as number", CANONICAL.replace(b'"seq":', b"7:")),
    ],
)
def test_json_that_micropython_would_accept_is_rejected(what: str, payload: bytes) -> None:
    assert oracle.oracle("pose", payload) is None, f"{what}: the contract accepts it, the case is wrong"
    assert msg.parse_pose(payload) is None


@pytest.mark.parametrize(
    ("what", "payload"),
    [
        (
            "spaces everywhere",
            b' { "v" : 1 , "id" : "red" , "seq" : 1 , "frame" : 2 , "t" : 3 , "x" : 4 , "y" : 5 ,'
            b' "theta" : null , "vx" : null , "vy" : null , "q" : 1 } ',
        ),
        ("escaped id", CANONICAL.replace(b'"red"', b'"\\u0072ed"')),
        ("exponent", CANONICAL.replace(b'"x":81.5', b'"x":8.15E1')),
        ("negative zero", CANONICAL.replace(b'"vx":12.3', b'"vx":-0')),
        ("tabs and newlines", CANONICAL.replace(b",", b",\n\t")),
    ],
)
def test_unusual_but_valid_json_takes_the_slow_path_and_parses(what: str, payload: bytes) -> None:
    want = oracle.oracle("pose", payload)
    assert want is not None, f"{what}: the contract rejects it, the case is wrong"
    assert oracle.same_fields(msg.parse_pose(payload), oracle.as_fields("pose", want))


# -- properties -------------------------------------------------------------------------------------------------------
@pytest.mark.slow
@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.binary(max_size=200))
@example(b"")
@example(b"{}")
@example(b"\xff" * 10)
def test_arbitrary_bytes_never_raise_and_are_never_accepted_against_the_schema(payload: bytes) -> None:
    for kind in ("pose", "formation"):
        got = parse(kind, payload)
        if got is not None:
            want = oracle.oracle(kind, payload)
            assert want is not None, f"accepted what the contract rejects: {payload!r}"
            assert oracle.same_fields(got, oracle.as_fields(kind, want))


JSON_ATOMS = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(10**12), max_value=10**12),
    st.floats(allow_nan=False, allow_infinity=False, width=64),
    st.text(alphabet="abcdefghijklmnopqrstuvwxyz0123456789_-RÉ\n", max_size=18),
)


@st.composite
def near_poses(draw: st.DrawFn) -> dict[str, Any]:
    """Pose-shaped dicts: mostly valid values, some fields replaced by arbitrary JSON, some dropped or added."""
    doc: dict[str, Any] = {
        "v": draw(st.sampled_from([1, 1, 1, 2, 1.0, True, "1"])),
        "id": draw(st.one_of(st.from_regex(r"\A[a-z0-9_-]{1,16}\Z"), JSON_ATOMS)),
        "seq": draw(st.integers(min_value=-2, max_value=10**9 + 2)),
        "frame": draw(st.integers(min_value=0, max_value=10**9)),
        "t": draw(st.floats(min_value=-1, max_value=1.1e10)),
        "x": draw(st.floats(min_value=-1.1e4, max_value=1.1e4)),
        "y": draw(st.one_of(st.floats(min_value=-1.1e4, max_value=1.1e4), st.integers(-20000, 20000))),
        "theta": draw(st.one_of(st.none(), st.floats(min_value=-3.2, max_value=3.2))),
        "vx": draw(st.one_of(st.none(), st.floats(min_value=-1100, max_value=1100))),
        "vy": draw(st.one_of(st.none(), st.floats(min_value=-1100, max_value=1100))),
        "q": draw(st.floats(min_value=-0.2, max_value=1.2)),
    }
    for key in draw(st.lists(st.sampled_from(sorted(doc)), max_size=2)):
        doc[key] = draw(JSON_ATOMS)
    for key in draw(st.lists(st.sampled_from(sorted(doc)), max_size=1)):
        del doc[key]
    if draw(st.booleans()) and draw(st.booleans()):
        doc[draw(st.sampled_from(["z", "extra", "V"]))] = 1
    return doc


@pytest.mark.slow
@settings(max_examples=400, deadline=None)
@given(near_poses(), st.sampled_from(["compact", "spaced", "canonical"]))
def test_near_valid_poses_are_accepted_exactly_when_the_contract_accepts_them(doc: dict[str, Any], style: str) -> None:
    if style == "compact":
        payload = json.dumps(doc, separators=(",", ":")).encode()
    elif style == "spaced":
        payload = json.dumps(doc, indent=1).encode()
    else:
        try:
            payload = messages.encode_pose(
                doc["id"],
                doc["seq"],
                doc["frame"],
                doc["t"],
                doc["x"],
                doc["y"],
                doc["theta"],
                doc["vx"],
                doc["vy"],
                doc["q"],
            )
        except (KeyError, TypeError, ValueError, messages.MessageError):
            return
    want = oracle.oracle("pose", payload)
    got = msg.parse_pose(payload)
    if want is None:
        assert got is None, f"accepted what the contract rejects: {payload!r}"
    else:
        assert oracle.same_fields(got, oracle.as_fields("pose", want)), f"{payload!r}: {got} != {want}"


@pytest.mark.slow
def test_mutated_messages_are_accepted_exactly_when_the_contract_accepts_them() -> None:
    corpus = oracle.mutation_corpus(3000)
    accepted = 0
    for kind, payload in corpus:
        want = oracle.oracle(kind, payload)
        got = parse(kind, payload)
        if want is None:
            assert got is None, f"accepted what the contract rejects: {payload!r}"
        else:
            accepted += 1
            assert oracle.same_fields(got, oracle.as_fields(kind, want)), f"{payload!r}: {got} != {want}"
    assert 100 < accepted < len(corpus) - 100  # the corpus exercises both verdicts


@pytest.mark.slow
@settings(max_examples=300, deadline=None)
@given(
    rover_id=st.from_regex(r"\A[a-z0-9_-]{1,16}\Z"),
    seq=st.integers(min_value=0, max_value=2 * 10**9),
    t=st.floats(min_value=0, max_value=9.9e9),
    x=st.floats(min_value=-9999.99, max_value=9999.99),
    y=st.floats(min_value=-9999.99, max_value=9999.99),
    theta=st.one_of(st.none(), st.floats(min_value=-10, max_value=10)),
    vx=st.one_of(st.none(), st.floats(min_value=-2000, max_value=2000)),
    q=st.floats(min_value=-1, max_value=2),
)
def test_every_pose_the_edge_encodes_is_parsed_to_its_rounded_values(
    rover_id: str, seq: int, t: float, x: float, y: float, theta: float | None, vx: float | None, q: float
) -> None:
    payload = messages.encode_pose(rover_id, seq, seq, t, x, y, theta, vx, None, q)
    got = msg.parse_pose(payload)
    assert got is not None
    assert oracle.same_fields(got, oracle.as_fields("pose", json.loads(payload)))
    assert msg._canonical_pose(payload, json.loads(payload))  # the edge's bytes take the fast path


@pytest.mark.parametrize(
    "doc",
    [
        {"v": 1, "seq": 1, "kind": "line", "ids": ["red"]},  # optional fields absent: null, as in FormationV1
        {"v": 1, "seq": 0, "kind": "stop", "ids": [], "theta": 3.1416},
        {"v": 1, "seq": 5, "kind": "triangle", "ids": ["a", "b", "c"], "side": 1000, "x": -9999.99, "y": 0},
        {"v": 1, "seq": 5, "kind": "line", "ids": [f"r{k}" for k in range(16)], "spacing": 1e-3},
    ],
)
def test_formations_the_model_accepts_are_accepted(doc: dict[str, Any]) -> None:
    payload = json.dumps(doc).encode()
    assert oracle.oracle("formation", payload) is not None
    assert oracle.same_fields(msg.parse_formation(payload), oracle.as_fields("formation", doc))


@pytest.mark.parametrize(
    "doc",
    [
        {"v": 1, "seq": 1, "kind": "line", "ids": ["red"], "spacing": 0},
        {"v": 1, "seq": 1, "kind": "line", "ids": ["red"], "spacing": 1000.5},
        {"v": 1, "seq": 1, "kind": "line", "ids": [f"r{k}" for k in range(17)]},
        {"v": 1, "seq": 1, "kind": "line", "ids": ["Red"]},
        {"v": 1, "seq": 1, "kind": "line", "ids": [1]},
        {"v": 1, "seq": 1, "kind": "line", "ids": ["red"], "colour": "red"},
        {"v": 1, "seq": 1.0, "kind": "line", "ids": ["red"]},
        {"v": 1, "seq": 1, "kind": "line", "ids": ["red"], "theta": -3.2},
        {"v": 1, "seq": 1, "kind": "LINE", "ids": ["red"]},
    ],
)
def test_formations_the_model_rejects_are_rejected(doc: dict[str, Any]) -> None:
    payload = json.dumps(doc).encode()
    assert oracle.oracle("formation", payload) is None
    assert msg.parse_formation(payload) is None


def test_formation_size_limit_is_512_bytes() -> None:
    doc = {"v": 1, "seq": 1, "kind": "line", "ids": ["abcdefghijklmnop"] * 16, "spacing": 60.0}
    compact = json.dumps(doc, separators=(",", ":")).encode()
    at_limit = compact[:-1] + b" " * (messages.FORMATION_MAX_BYTES - len(compact)) + b"}"
    assert len(at_limit) == messages.FORMATION_MAX_BYTES
    assert msg.parse_formation(at_limit) is not None
    assert msg.parse_formation(compact[:-1] + b" " + at_limit[len(compact) - 1 :]) is None  # 513 bytes


ID_CASES = [("red", True), ("r-1_x", True), ("a" * 16, True), ("", False), ("a" * 17, False), ("Red", False)]
ID_CASES += [("ré", False), ("a b", False), (7, False), (None, False)]


@pytest.mark.parametrize(("rid", "ok"), ID_CASES)
def test_rover_ids_follow_the_contract_alphabet(rid: Any, ok: bool) -> None:
    assert msg.is_id(rid) is ok


def test_topics_match_the_edge_helpers() -> None:
    assert msg.pose_topic("red") == messages.pose_topic("red").encode()
    assert msg.status_topic("red") == messages.rover_status_topic("red").encode()
    assert messages.FORMATION_TOPIC.encode() == msg.FORMATION_TOPIC
    assert messages.POSE_WILDCARD.encode() == msg.POSE_WILDCARD
    assert math.isclose(msg._THETA_LIMIT, messages.THETA_LIMIT)


def test_rover_numbers_the_fields_as_msg_and_formation_do() -> None:
    # msg's tuple fields and formation's command fields and kinds are private consts (no dict entries on the chip),
    # so rover.py keeps its own copies: each must equal the original, or the rover reads the wrong field.
    rover, fm = firmware_modules()["rover"], firmware_modules()["formation"]
    copies = [n for n in vars(rover) if n.startswith(("_P_", "_F_", "_C_")) or n == "_STOP"]
    assert len(copies) == 21
    for name in copies:
        source = fm if name.startswith("_C_") or name == "_STOP" else msg
        assert getattr(rover, name) == getattr(source, name), name
    kinds = {"line": fm._LINE, "rendezvous": fm._RENDEZVOUS, "triangle": fm._TRIANGLE, "stop": fm._STOP}
    assert {k: msg.KINDS.index(k) for k in kinds} == kinds
