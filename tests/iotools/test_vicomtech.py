"""Reader of the Vicomtech turning tool-wear table, on the real file and on damaged copies.

Real file: ``tests/data/real/vicomtech-turning-wear/Dataset_Machine_tool_wear.csv``
(Vicomtech/dataset-machine-tool-wear, CC BY-SA 4.0; see PROVENANCE.md). Facts from its
README.source.txt: 2054 one-second segments of 13 tools. The cell values below were read with
the stdlib ``csv`` module (an oracle independent of the reader): 154 columns, the last two
``tool`` and ``Vb``; the first data row (line 2) is tool 5 with Vb 0, TV2.S_MEAN 116.28 and
F_c_MEAN 528.644022; the last row (line 2055) tool 6, Vb 247; tool 15 has 274 segments and
tools 9 and 5 have 88 each.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from cnctwin.exceptions import FormatError
from cnctwin.iotools.vicomtech import read_vicomtech

VICOMTECH = (Path(__file__).parents[1] / "data" / "real" / "vicomtech-turning-wear"
             / "Dataset_Machine_tool_wear.csv")


def test_real_file_facts() -> None:
    data, meta = read_vicomtech(VICOMTECH)
    assert meta["n_segments"] == len(data) == 2054  # README.source.txt
    assert len(meta["tools"]) == 13  # README.source.txt
    assert meta["tools"][0] == 5 and meta["source"] == str(VICOMTECH)
    assert data.shape[1] == 154 + 1  # the source columns and the added ``segment``
    first, last = data.iloc[0], data.iloc[-1]
    assert (first["tool"], first["Vb"]) == (5, 0.0)
    assert first["TV2.S_MEAN"] == pytest.approx(116.28, abs=1e-12)
    assert first["F_c_MEAN"] == pytest.approx(528.644022, abs=1e-9)
    assert (last["tool"], last["Vb"]) == (6, 247.0)
    counts = data.groupby("tool").size()
    assert counts[15] == 274 and counts[9] == counts[5] == 88
    # ``segment`` numbers the rows of each tool from 0 in file order
    for _, g in data.groupby("tool"):
        np.testing.assert_array_equal(g["segment"].to_numpy(), np.arange(len(g)))
    # CNC-internal features are the TV*/CV* and CON.* columns
    assert "TV2.S_MEAN" in meta["cnc_internal_features"]
    assert "F_c_MEAN" not in meta["cnc_internal_features"]


def _prefix(tmp_path: Path, n_rows: int = 20) -> tuple[Path, list[list[str]]]:
    """The header and the first ``n_rows`` rows of the real file (stdlib csv)."""
    with VICOMTECH.open(newline="", encoding="utf-8") as fh:
        rows = [r for _, r in zip(range(n_rows + 1), csv.reader(fh), strict=False)]
    p = tmp_path / "wear.csv"
    _write(p, rows)
    return p, rows


def _write(p: Path, rows: list[list[str]]) -> None:
    with p.open("w", newline="", encoding="utf-8") as fh:
        csv.writer(fh, lineterminator="\n").writerows(rows)


def test_prefix_reads_like_the_file(tmp_path: Path) -> None:
    p, rows = _prefix(tmp_path)
    data, meta = read_vicomtech(p)
    assert len(data) == 20 and meta["tools"] == [5]
    assert data["TV2.S_MEAN"].iloc[0] == pytest.approx(float(rows[1][119]), abs=0)


def test_empty_file(tmp_path: Path) -> None:
    """An empty file used to escape as pandas' EmptyDataError."""
    p = tmp_path / "wear.csv"
    p.write_text("", encoding="utf-8")
    with pytest.raises(FormatError, match="empty file") as info:
        read_vicomtech(p)
    assert info.value.path == str(p)


def test_cut_off_last_row(tmp_path: Path) -> None:
    """A cut-off row used to be padded with NaN by pandas (or fail as ValueError on tool)."""
    p, rows = _prefix(tmp_path)
    rows[-1] = rows[-1][:60]
    _write(p, rows)
    with pytest.raises(FormatError, match="row has 60 fields, the header 154") as info:
        read_vicomtech(p)
    assert info.value.position == "line 21"


def test_non_numeric_feature(tmp_path: Path) -> None:
    """A text cell used to turn the column into strings, or "n/a" into NaN, without a word."""
    p, rows = _prefix(tmp_path)
    rows[7][3] = "n/a"
    _write(p, rows)
    with pytest.raises(FormatError, match="'n/a' is not a number") as info:
        read_vicomtech(p)
    assert info.value.position == "line 8" and info.value.field == rows[0][3]


def test_missing_tool_id(tmp_path: Path) -> None:
    p, rows = _prefix(tmp_path)
    rows[4][152] = ""
    _write(p, rows)
    with pytest.raises(FormatError, match="no tool id") as info:
        read_vicomtech(p)
    assert info.value.position == "line 5" and info.value.field == "tool"


def test_blank_lines_do_not_shift_line_numbers(tmp_path: Path) -> None:
    p, rows = _prefix(tmp_path)
    rows[9][10] = "x"
    _write(p, rows)
    lines = p.read_text(encoding="utf-8").splitlines()
    p.write_text("\n".join([*lines[:3], "", *lines[3:]]) + "\n", encoding="utf-8")
    with pytest.raises(FormatError) as info:
        read_vicomtech(p)
    assert info.value.position == "line 11"  # row 9 is on line 10, one blank line above it
