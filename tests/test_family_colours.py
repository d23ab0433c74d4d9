"""``benchmarks/family_colours.py``: each colour's bias over the camera family, pooled from several family
outputs (one seed per process), against the issue's bar on the family's mean."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.conftest import benchmark_module

colours = benchmark_module("family_colours")

HEAD = "\n".join(
    [
        "# edge-ips tracking benchmark",
        "",
        "| scenario | seed | camera | bodies | mean cm | p95 cm | max cm | worst colour bias cm | detection | bars |",
        "|---|---|---|---|---|---|---|---|---|---|",
        "| lab | {seed} | 4:2:0 q63 | black bodies | 0.178 | 0.363 | 0.85 | 0.179 (blue) | 100.00% | missed: bias |",
        "",
        "Every scenario, camera and colour:",
        "",
        "| scenario | seed | colour | mean cm | p95 cm | max cm | bias x, y cm | detection | swaps | ghosts | head |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
        "",
    ]
)


def _output(tmp_path: Path, seed: int, rows: list[tuple[str, float, float]]) -> Path:
    body = "".join(
        f"| lab | {seed} | {c} | 0.150 | 0.300 | 0.50 | {x:+.3f}, {y:+.3f} | 100.00% | 0 | 0 | 0.30 / 1.00 |\n"
        for c, x, y in rows
    )
    path = tmp_path / f"wood-{seed}.md"
    path.write_text(HEAD.format(seed=seed) + body + "\nsomething after the table\n| not | a row |\n", encoding="utf-8")
    return path


def test_a_colour_s_family_bias_is_the_mean_of_its_runs_and_the_bar_is_on_that_mean(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Blue 0.08 toward the camera through one camera and 0.02 away through the other averages to 0.03 (within the
    bar, though one run alone is over it); green 0.06 and 0.08 the same way is over it; a colour of no palette is
    reported but not held to the bar."""
    first = _output(tmp_path, 1000, [("blue", 0.0, -0.08), ("green", 0.0, -0.06), ("teal", 0.3, 0.0)])
    second = _output(tmp_path, 4321, [("blue", 0.0, 0.02), ("green", 0.0, -0.08)])
    stats = colours.pooled(colours.read_runs(first) + colours.read_runs(second))
    assert stats["blue"]["runs"] == 2
    assert stats["blue"]["mean"] == pytest.approx(0.03)
    assert stats["blue"]["worst_run"] == pytest.approx(0.08)
    assert stats["green"]["y"] == pytest.approx(-0.07)
    assert colours.main([str(first), str(second)]) == 0
    out = capsys.readouterr().out
    assert "| blue | 2 | +0.000, -0.030 | 0.030 | 0.050 | 0.080 | ok |" in out
    assert "| green | 2 | +0.000, -0.070 | 0.070 |" in out and "missed |" in out
    assert "(not in the palettes)" in out
    assert "Palette colours over the bar: 1 (green)" in out


def test_a_file_without_the_table_or_with_a_broken_row_is_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plain = tmp_path / "no-detail.md"
    plain.write_text("# a family run without --detail\n| lab | 1000 | ... |\n", encoding="utf-8")
    assert colours.main([str(plain)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--detail" in err
    broken = _output(tmp_path, 1000, [("blue", 0.0, -0.08)])
    broken.write_text(broken.read_text(encoding="utf-8").replace("-0.080", "n/a"), encoding="utf-8")
    assert colours.main([str(broken)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "not a row of the table" in err
    assert colours.main([str(tmp_path / "missing.md")]) == 2
    assert "missing.md" in capsys.readouterr().err
