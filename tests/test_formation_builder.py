"""One rule for what a formation command may say: the CLI, the dashboard and the simulator all build it here."""

from __future__ import annotations

import pytest

from edge.commands import LINE_SPACING_CM, TRIANGLE_SIDE_CM, build_formation
from edge.errors import MessageError

ROVERS = ("red", "green", "blue")


@pytest.mark.parametrize(
    ("kind", "given", "expected"),
    [
        ("line", {}, (LINE_SPACING_CM, None)),
        ("line", {"spacing_cm": 45.0, "side_cm": 80.0}, (45.0, None)),
        ("triangle", {}, (None, TRIANGLE_SIDE_CM)),
        ("triangle", {"spacing_cm": 45.0, "side_cm": 80.0}, (None, 80.0)),
        ("rendezvous", {"spacing_cm": 45.0, "side_cm": 80.0}, (None, None)),
        ("stop", {"spacing_cm": 45.0}, (None, None)),
    ],
)
def test_each_kind_carries_its_own_size_with_a_default(kind, given, expected) -> None:
    message = build_formation(kind, list(ROVERS), seq=3, **given)
    assert (message.spacing, message.side) == expected


@pytest.mark.parametrize(
    ("kind", "ids", "known", "names"),
    [
        ("line", ["red", "red"], None, "red named more than once"),
        ("line", [" red", "red "], None, "red named more than once"),  # spaces are not part of an id
        ("rendezvous", [], None, "a rendezvous needs at least one rover"),
        ("triangle", ["red", "green"], None, "a triangle needs at least three rovers, got 2"),
        ("line", ["red", "purple"], ROVERS, "not configured rovers: purple"),
        ("line", ["red", "Red!"], None, "ids.1"),  # the contract's own id pattern
    ],
)
def test_bad_ids_are_refused_naming_the_rule(kind, ids, known, names) -> None:
    with pytest.raises(MessageError, match=r"^formation: ids") as caught:
        build_formation(kind, ids, seq=1, known_ids=known)
    assert names in str(caught.value)


def test_ids_are_kept_in_order_without_spaces_and_any_rover_may_be_named_without_known_ids() -> None:
    message = build_formation("line", [" blue", "purple "], seq=1)
    assert message.ids == ["blue", "purple"]
