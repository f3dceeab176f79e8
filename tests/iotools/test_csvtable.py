"""The one delimited-text path of the readers (issue 16, point 6: CSV through pyarrow/pandas,
no row loops or home-made sniffers): line numbers, salvage, blank lines, decimal commas."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cnctwin.exceptions import FormatError
from cnctwin.iotools._csvtable import header_delimiter, read_csv_table

TEXT = "comment\na;b;c\n1,5;2;3\n\n4;5\n;;\n10;x;12\n 7 ; ;9\n"


def test_lines_are_the_file_lines_around_blank_and_dropped_rows() -> None:
    t = read_csv_table(TEXT, path="t.csv", delimiter=";", header_line=2, salvage=True)
    assert t.header == ["a", "b", "c"]
    assert t.lines.tolist() == [3, 7, 8]
    assert t.dropped_lines == [5] and t.blank_lines == [4, 6]
    assert t.has_decimal_comma()
    np.testing.assert_array_equal(t.numbers(0, decimal_comma=True), [1.5, 10.0, 7.0])
    np.testing.assert_array_equal(t.numbers(2), [3.0, 12.0, 9.0])


def test_errors_name_the_line_and_column() -> None:
    t = read_csv_table(TEXT, path="t.csv", delimiter=";", header_line=2, salvage=True)
    with pytest.raises(FormatError, match="'x' is not a number") as ei:
        t.numbers(1)
    assert ei.value.position == "line 7" and ei.value.field == "b"
    with pytest.raises(FormatError, match="row has 2 fields, the header 3") as ei:
        read_csv_table(TEXT, path="t.csv", delimiter=";", header_line=2)
    assert ei.value.position == "line 5"


def test_missing_markers_and_integers(tmp_path: Path) -> None:
    p = tmp_path / "x.csv"
    p.write_bytes(b"\xef\xbb\xbfn,v\n1,null\n2,0.5\n")  # with a UTF-8 byte-order mark
    t = read_csv_table(p, path=str(p))
    assert t.header == ["n", "v"]
    assert t.integers_or_numbers(0).dtype == np.int64
    np.testing.assert_array_equal(t.numbers(1, missing=("", "null")), [np.nan, 0.5])
    p.write_bytes(b"n,v\n\xff,1\n")
    with pytest.raises(FormatError, match="not UTF-8"):
        read_csv_table(p, path=str(p))


@pytest.mark.parametrize(("line", "delimiter"), [("a;b,c;d", ";"), ("a\tb", "\t"),
                                                 ("a,b", ","), ("abc", ",")])
def test_header_delimiter(line: str, delimiter: str) -> None:
    assert header_delimiter(line) == delimiter


def test_no_csv_row_loops_in_the_readers() -> None:
    """Every reader goes through ``_csvtable`` (pyarrow); the stdlib csv module parses no
    data rows there (it still writes the CSV export)."""
    import cnctwin.iotools as io_pkg

    root = Path(io_pkg.__file__).parent
    offenders = [p.name for p in root.glob("*.py") if p.name not in ("_csvtable.py",
                                                                     "csv_export.py")
                 and any(s in p.read_text(encoding="utf-8")
                         for s in ("csv.DictReader", "for row in reader", "def _sniff("))]
    assert offenders == []
