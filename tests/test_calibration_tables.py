"""The CSV readers take any text: they return a table or raise CalibrationError, nothing else."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge.calibration.fiducial import parse_markers_csv
from edge.calibration.points import parse_points_csv, read_points_csv, write_points_csv
from edge.errors import CalibrationError

cells = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-10_000, 10_000).map(str),
    st.text(alphabet="0123456789.-eEnaif ,\"'x#", max_size=8),
)
csv_text = st.lists(st.lists(cells, min_size=0, max_size=6).map(",".join), max_size=8).map("\n".join)


@pytest.mark.slow
@settings(max_examples=300, deadline=None)
@given(body=csv_text, header=st.sampled_from(["u,v,x,y", "x,y,u,v", "u,v,x,y,label", "u,v,x", ""]))
def test_points_reader_returns_a_table_or_a_calibration_error(body: str, header: str) -> None:
    try:
        table = parse_points_csv(header + "\n" + body, "p.csv")
    except CalibrationError as exc:
        assert str(exc).startswith("p.csv")
        return
    assert table.uv_px.shape == table.xy_world_cm.shape == (len(table), 2)
    assert np.all(np.isfinite(table.uv_px)) and np.all(np.isfinite(table.xy_world_cm))


@pytest.mark.slow
@settings(max_examples=200, deadline=None)
@given(body=csv_text, header=st.sampled_from(["id,x,y,z,size", "id,x,y,z", "x,y,z"]))
def test_markers_reader_returns_a_table_or_a_calibration_error(body: str, header: str) -> None:
    try:
        table = parse_markers_csv(header + "\n" + body, "m.csv", 20.0)
    except CalibrationError as exc:
        assert str(exc).startswith("m.csv")
        return
    assert len(set(table.ids.tolist())) == table.ids.size
    assert np.all(table.sizes_cm > 0)


@pytest.mark.slow
@settings(max_examples=50, deadline=None)
@given(
    pts=st.lists(
        st.tuples(*[st.floats(-5000, 5000, allow_nan=False, allow_infinity=False)] * 4), min_size=1, max_size=40
    )
)
def test_points_csv_round_trips_to_the_thousandth(tmp_path_factory, pts: list[tuple[float, ...]]) -> None:  # type: ignore[no-untyped-def]
    arr = np.asarray(pts)
    path: Path = tmp_path_factory.mktemp("csv") / "points.csv"
    write_points_csv(path, arr[:, :2], arr[:, 2:])
    table = read_points_csv(path)
    np.testing.assert_allclose(table.uv_px, arr[:, :2], atol=6e-4)
    np.testing.assert_allclose(table.xy_world_cm, arr[:, 2:], atol=6e-4)
    assert table.rows.tolist() == list(range(1, len(pts) + 1))


def test_comments_blank_lines_and_extra_columns_are_allowed() -> None:
    text = "# survey of 2026-11-20\nlabel, V, U ,y,x\n\nA,10,20,3,4\n# re-measured\nB,11,21,5,6\n"
    table = parse_points_csv(text, "p.csv")
    np.testing.assert_allclose(table.uv_px, [[20, 10], [21, 11]])
    np.testing.assert_allclose(table.xy_world_cm, [[4, 3], [6, 5]])
    assert table.lines.tolist() == [4, 6] and table.where(1) == "p.csv row 2 (line 6)"


def test_a_csv_saved_by_excel_with_a_byte_order_mark_reads_like_any_other(tmp_path: Path) -> None:
    path = tmp_path / "points.csv"
    path.write_bytes("u,v,x,y\r\n10,20,3,4\r\n11,21,5,6\r\n".encode("utf-8-sig"))  # Excel's "CSV UTF-8"
    table = read_points_csv(path)
    np.testing.assert_allclose(table.uv_px, [[10, 20], [11, 21]])
    np.testing.assert_allclose(table.xy_world_cm, [[3, 4], [5, 6]])
