"""A board of several: the configuration that makes one, and what its status can carry."""

from __future__ import annotations

import pytest

from edge.config import EdgeConfig
from edge.errors import ConfigError
from edge.fusion.board import listed_rovers
from edge.messages import STATUS_MAX_BYTES, StatusV1, dumps


def _rovers(n: int) -> list[dict[str, object]]:
    return [{"id": f"hue{k:03d}", "color_bgr": [k, 100, 200]} for k in range(n)]


def test_a_board_publishes_poses_unless_told_it_is_one_of_several() -> None:
    assert EdgeConfig().edge.publish == "poses"
    assert EdgeConfig.model_validate({"edge": {"publish": "detections"}}).edge.publish == "detections"
    with pytest.raises(ValueError, match="publish"):
        EdgeConfig.model_validate({"edge": {"publish": "both"}})


@pytest.mark.parametrize(
    ("publish", "n", "ok"),
    [("poses", 32, True), ("poses", 33, False), ("detections", 64, True), ("detections", 65, False)],
)
def test_more_than_32_rovers_take_several_boards(publish: str, n: int, ok: bool) -> None:
    data = {"edge": {"publish": publish}, "rovers": _rovers(n)}
    if ok:
        assert len(EdgeConfig.model_validate(data).rovers) == n
    else:
        with pytest.raises(ValueError):
            EdgeConfig.model_validate(data)


def test_the_error_for_too_many_rovers_says_what_to_do(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from edge.config_load import load_config

    path = tmp_path / "edge-ips.toml"
    path.write_text("".join(f'[[rovers]]\nid = "r{k}"\ncolor_bgr = [{k}, 100, 200]\n' for k in range(40)))
    with pytest.raises(ConfigError, match="detections"):
        load_config(path, {})


@pytest.mark.parametrize(("n", "id_length"), [(0, 16), (5, 16), (50, 16), (50, 6)])
def test_a_boards_status_lists_as_many_seen_rovers_as_the_contract_carries(n: int, id_length: int) -> None:
    seen = [f"r{k:02d}-abcdefghijklmn"[:id_length] for k in range(n)]
    listed = listed_rovers(seen)
    assert listed == seen[: len(listed)]

    def size(rovers: list[str]) -> int:
        status = StatusV1(
            v=1,
            edge="abcdefghijklmnop",
            state="degraded",
            camera="starting",
            fps=999.99,
            rovers=rovers,
            missing=[],
            t=9999999999.999,
        )
        return len(dumps(status))

    assert size(listed) <= STATUS_MAX_BYTES
    if len(listed) < n:  # one more would not fit the byte budget or the 32 the contract allows
        assert len(listed) == 32 or size(seen[: len(listed) + 1]) > STATUS_MAX_BYTES - 20
