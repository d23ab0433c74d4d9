"""The closed-loop bars judged on published poses: frames counted from the command, frames with a rover missing
left out, the last frame deciding whether the bar holds."""

from __future__ import annotations

import math
from typing import Any

import pytest

from edge.sim.twin.bars import largest_moves_cm, score_formation

IDS = ["red", "green", "blue"]


def _line(frame: int, spread_cm: float) -> list[dict[str, Any]]:
    """A vertical line at x=200, 60 cm apart, each rover ``spread_cm`` off it (alternating sides)."""
    return [
        {"id": rid, "frame": frame, "t": frame / 30, "x": 200.0 + spread_cm * (-1) ** k, "y": 100.0 + 60.0 * k}
        for k, rid in enumerate(IDS)
    ]


@pytest.mark.parametrize(("settle", "expected"), [(0, 0), (100, 100), (239, 239), (260, 260)])
def test_a_line_holds_from_the_frame_it_settles(settle: int, expected: int) -> None:
    poses = [p for f in range(1000, 1301) for p in _line(f, 10.0 if f - 1000 < settle else 1.0)]
    score = score_formation(poses, IDS, "line", 1000, 300)
    assert score.converged_frame == expected and score.frames == 301
    assert score.final_cm == pytest.approx(4 / 3)  # the worst displacement from the common line (their mean x)
    assert score.holds_by(240) == (expected <= 240)


def test_frames_missing_a_rover_are_left_out_and_a_bar_broken_at_the_end_never_held() -> None:
    poses = [p for f in range(0, 301) for p in _line(f, 1.0) if not (f % 2 and p["id"] == "blue")]
    assert score_formation(poses, IDS, "line", 0, 300).frames == 151
    broken = [*poses, *_line(300, 9.0)]
    assert score_formation(broken, IDS, "line", 0, 300).converged_frame is None


def test_a_rendezvous_is_judged_by_the_zone_and_a_triangle_by_its_sides() -> None:
    ring = [{"id": r, "frame": 5, "t": 0.0, "x": 100 + 15 * math.cos(a), "y": 100 + 15 * math.sin(a)}
            for r, a in zip(IDS, (0.0, 2.1, 4.2), strict=True)]  # fmt: skip
    assert score_formation(ring, IDS, "rendezvous", 0, 10).final_cm == pytest.approx(30.0, abs=0.1)
    side = 101.0
    tri = [{"id": "red", "frame": 5, "t": 0.0, "x": 0.0, "y": 0.0},
           {"id": "green", "frame": 5, "t": 0.0, "x": side, "y": 0.0},
           {"id": "blue", "frame": 5, "t": 0.0, "x": side / 2, "y": side * math.sqrt(3) / 2}]  # fmt: skip
    score = score_formation(tri, IDS, "triangle", 0, 10)
    assert score.converged_frame == 5 and score.final_cm == pytest.approx(1.0)  # frames count from first_frame


def test_how_far_each_rover_moved_in_a_window_of_pose_time() -> None:
    poses = [
        {"id": "red", "t": 0.9, "x": 0.0, "y": 0.0},  # before the window
        {"id": "red", "t": 1.0, "x": 10.0, "y": 0.0},
        {"id": "red", "t": 1.5, "x": 10.3, "y": 0.4},
        {"id": "red", "t": 2.1, "x": 50.0, "y": 0.0},  # after it
        {"id": "green", "t": 1.2, "x": 5.0, "y": 5.0},
    ]
    moved = largest_moves_cm(poses, ["red", "green", "blue"], 1.0, 2.0)
    assert moved == {"red": pytest.approx(0.5), "green": 0.0, "blue": 0.0}
