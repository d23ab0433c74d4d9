"""Small numeric CSV tables (survey points, markers) read with errors that name the file, row and line."""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from edge.errors import CalibrationError


@dataclass(frozen=True)
class NumericTable:
    """``columns``: name -> (N,) float64 (optional columns absent from the header are missing here).
    ``rows``: (N,) data-row numbers (1 = first row after the header); ``lines``: (N,) line numbers in the file."""

    source: str
    columns: dict[str, NDArray[np.float64]]
    rows: NDArray[np.int64]
    lines: NDArray[np.int64]

    def where(self, i: int) -> str:
        return f"{self.source} row {int(self.rows[i])} (line {int(self.lines[i])})"


def read_text(path: Path, what: str) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except OSError as exc:
        raise CalibrationError(f"{path}: cannot read {what} ({exc.strerror or exc})") from exc
    except UnicodeDecodeError:
        raise CalibrationError(f"{path}: not a text (UTF-8) CSV file") from None


def parse_table(text: str, source: str, required: tuple[str, ...], optional: tuple[str, ...] = ()) -> NumericTable:
    """Parse a CSV with a header naming at least ``required`` (any order, case-insensitive; other columns are
    ignored; blank lines and lines starting with ``#`` are skipped). Every value must be a finite number. A
    leading byte-order mark (Excel's "CSV UTF-8") is ignored."""
    text = text.removeprefix("\ufeff")
    lines = [
        (n, line)
        for n, line in enumerate(text.splitlines(), start=1)
        if line.strip() and not line.lstrip().startswith("#")
    ]
    if not lines:
        raise CalibrationError(f"{source}: empty file, expected a header {','.join(required)} and data rows")
    header_line, header = lines[0]
    names = [h.strip().lower() for h in next(csv.reader([header]))]
    missing = [c for c in required if c not in names]
    if missing:
        raise CalibrationError(
            f"{source} line {header_line}: header must name the columns {','.join(required)} "
            f"(missing {','.join(missing)}; found {','.join(names) or 'nothing'})"
        )
    wanted = [c for c in (*required, *optional) if c in names]
    index = {c: names.index(c) for c in wanted}
    values: list[list[float]] = []
    line_numbers: list[int] = []
    for row_number, (line_number, line) in enumerate(lines[1:], start=1):
        fields = next(csv.reader([line]))
        where = f"{source} row {row_number} (line {line_number})"
        if len(fields) != len(names):
            raise CalibrationError(f"{where}: expected {len(names)} fields like the header, got {len(fields)}")
        row: list[float] = []
        for c in wanted:
            raw = fields[index[c]].strip()
            try:
                value = float(raw)
            except ValueError:
                raise CalibrationError(f"{where}: {c} is not a number: {raw!r}") from None
            if not math.isfinite(value):
                raise CalibrationError(f"{where}: {c} is not a finite number: {raw!r}")
            row.append(value)
        values.append(row)
        line_numbers.append(line_number)
    arr = np.asarray(values, dtype=np.float64).reshape(-1, len(wanted))
    n = arr.shape[0]
    return NumericTable(
        source=source,
        columns={c: arr[:, k].copy() for k, c in enumerate(wanted)},
        rows=np.arange(1, n + 1, dtype=np.int64),
        lines=np.asarray(line_numbers, dtype=np.int64),
    )
