"""Delimited text through Arrow's CSV reader, with the line of every row kept for errors.

The readers of flat CSV exports, dynamometer and thermal-camera files and the UMich data set
share this one path instead of row loops over the standard library's ``csv`` module: the
body is parsed by ``pyarrow.csv`` (C++, one pass) with every column read as text, and numbers
are converted column-wise. What the readers promise is kept:

* a row with another number of fields than the header is an error naming its line, or, with
  ``salvage``, dropped and listed (never filled with NaN without a word, which is what pandas
  does with a short last row);
* a value that is not a number is an error naming its line and column;
* blank lines are skipped; the line numbers stay those of the file (a quoted value that spans
  lines counts as one line).
"""

from __future__ import annotations

import csv
import functools
import io
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cnctwin.exceptions import FormatError

__all__ = ["CsvTable", "header_delimiter", "read_csv_table"]

_DELIMITERS = (";", ",", "\t")


def header_delimiter(line: str) -> str:
    """The delimiter of a header line: the most frequent of ``;``, ``,`` and tab (``,`` if
    none occurs). A header holds names, not decimal commas, so counting is unambiguous."""
    d = max(_DELIMITERS, key=line.count)
    return d if line.count(d) else ","


@dataclass
class CsvTable:
    """The text cells of a delimited file.

    Attributes
    ----------
    header : list of str
        Column names, stripped.
    columns : list of pyarrow.ChunkedArray
        One string column per header name (cells verbatim, not stripped).
    lines : numpy.ndarray
        File line (1-based) of each row.
    path : str
        File name for messages.
    delimiter : str
        Field delimiter the file was read with.
    dropped_lines : list of int
        Lines of rows with a wrong number of fields dropped under ``salvage``.
    blank_lines : list of int
        Lines without a value (empty, or only delimiters and blanks), skipped.
    """

    header: list[str]
    columns: list[Any]
    lines: NDArray[np.int64]
    path: str
    delimiter: str = ","
    dropped_lines: list[int] = field(default_factory=list)
    blank_lines: list[int] = field(default_factory=list)

    def integers_or_numbers(self, j: int) -> NDArray[np.float64] | NDArray[np.int64]:
        """Column ``j`` as ``int64`` when every cell is an integer, else as :meth:`numbers`."""
        import pyarrow.compute as pc

        if self.n_rows and bool(pc.all(pc.match_substring_regex(
                self.columns[j], r"^\s*[-+]?\d+\s*$")).as_py()):
            return self.numbers(j).astype(np.int64)
        return self.numbers(j)

    @property
    def n_rows(self) -> int:
        """Number of data rows."""
        return int(self.lines.size)

    def text(self, j: int) -> list[str]:
        """Column ``j`` as Python strings (verbatim)."""
        return [str(v) for v in self.columns[j].to_pylist()]

    def numbers(self, j: int, *, decimal_comma: bool = False,
                missing: tuple[str, ...] = ("",)) -> NDArray[np.float64]:
        """Column ``j`` as numbers; an empty cell is NaN.

        Parameters
        ----------
        j : int
            Column index.
        decimal_comma : bool, default False
            Cells use ``,`` as the decimal mark.
        missing : tuple of str, default ('',)
            Cells (stripped) read as a missing value (NaN).

        Returns
        -------
        numpy.ndarray of float64

        Raises
        ------
        FormatError
            A cell that is not a number (line and column named).
        """
        import pyarrow as pa
        import pyarrow.compute as pc

        if not decimal_comma and not any(map(_is_number, missing)):
            # clean numbers (no blanks, no missing cell: the cast refuses both): one cast
            try:
                fast: NDArray[np.float64] = pc.cast(self.columns[j], pa.float64()).to_numpy()
                return fast
            except (pa.ArrowInvalid, ValueError):
                pass  # blanks, missing cells or a bad value: the checked path below
        text = pc.utf8_trim_whitespace(self.columns[j])
        if decimal_comma:
            text = pc.replace_substring(text, ",", ".")
        filled = pc.if_else(pc.is_in(text, value_set=pa.array(list(missing), pa.string())),
                            "nan", text)
        try:
            out: NDArray[np.float64] = pc.cast(filled, pa.float64()).to_numpy()
            return out
        except (pa.ArrowInvalid, ValueError):
            bad = self.first_not_number(j, decimal_comma=decimal_comma, missing=missing)
            cell = self.text(j)[bad] if bad is not None else "?"
            line = int(self.lines[bad]) if bad is not None else 0
            raise FormatError(f"value {cell!r} is not a number", path=self.path,
                              position=f"line {line}", field=self.header[j]) from None

    def first_not_number(self, j: int, *, decimal_comma: bool = False,
                         missing: tuple[str, ...] = ("",)) -> int | None:
        """Row index of the first non-missing cell of column ``j`` that is not a number."""
        import pandas as pd

        s = pd.Series(self.columns[j].to_numpy(), dtype=object).astype(str).str.strip()
        if decimal_comma:
            s = s.str.replace(",", ".", regex=False)
        absent = s.isin(missing).to_numpy()
        num = pd.to_numeric(s.where(~absent, "nan"), errors="coerce")
        bad = np.flatnonzero(num.isna().to_numpy() & (s.str.lower() != "nan").to_numpy()
                             & ~absent)
        return int(bad[0]) if bad.size else None

    def has_decimal_comma(self, *, rows: int = 5) -> bool:
        """Whether numbers use a decimal comma: only where ``;`` separates the fields (German
        locale exports) and a number of the first ``rows`` rows is written ``1,5``."""
        import re

        return self.delimiter == ";" and any(
            re.search(r"\d,\d", str(c)) for col in self.columns
            for c in col.slice(0, rows).to_pylist())


@functools.lru_cache(maxsize=64)
def _is_number(cell: str) -> bool:
    """Whether Arrow's string-to-float cast reads ``cell`` as a number (``"nan"`` does);
    asked once per missing-cell token, not once per column."""
    import pyarrow as pa
    import pyarrow.compute as pc

    try:
        pc.cast(pa.array([cell], pa.string()), pa.float64())
    except (pa.ArrowInvalid, ValueError):
        return False
    return True


def read_csv_table(
    source: Path | str,
    *,
    path: str,
    delimiter: str = ",",
    header_line: int = 1,
    salvage: bool = False,
    encoding: str = "utf-8",
    hint: str = "file cut off or damaged?",
) -> CsvTable:
    """Read a delimited file whose header is on ``header_line``.

    Parameters
    ----------
    source : pathlib.Path or str
        The file, or its whole text (``str``).
    path : str
        File name for messages.
    delimiter : str, default ','
        Field delimiter.
    header_line : int, default 1
        Line (1-based) of the header; lines before it are skipped.
    salvage : bool, default False
        Drop rows with a wrong number of fields (their lines in ``dropped_lines``) instead of
        raising.
    encoding : str, default 'utf-8'
        Text encoding of a file (a UTF-8 byte-order mark is skipped).
    hint : str
        What to do next, appended to the message on a row of the wrong length.

    Returns
    -------
    CsvTable

    Raises
    ------
    FormatError
        Empty file or no header; a row with a wrong number of fields (line named, unless
        ``salvage``).
    """
    import pyarrow as pa
    import pyarrow.csv as pacsv

    if isinstance(source, Path):
        try:
            text = source.read_text(encoding=encoding)
        except UnicodeDecodeError as exc:
            raise FormatError(f"not {encoding.upper()} text ({exc})", path=path) from None
    else:
        text = source
    text = text.removeprefix("\ufeff")
    all_lines = text.splitlines()
    if len(all_lines) < header_line:
        raise FormatError("empty file" if not all_lines else "no header line", path=path)
    header = [h.strip() for h in next(csv.reader([all_lines[header_line - 1]],
                                                 delimiter=delimiter))]
    n = len(header)
    invalid: list[tuple[int, bool]] = []  # (line, blank)

    def on_invalid(row: pacsv.InvalidRow) -> str:
        blank = not (row.text or "").strip(delimiter + " \t\r")
        invalid.append((int(row.number) if row.number is not None else -1, blank))
        return "skip"

    names = [f"f{j}" for j in range(n)]
    try:
        table = pacsv.read_csv(
            io.BytesIO(text.encode("utf-8")),
            read_options=pacsv.ReadOptions(use_threads=False, skip_rows=header_line,
                                           column_names=names),
            parse_options=pacsv.ParseOptions(delimiter=delimiter, ignore_empty_lines=False,
                                             invalid_row_handler=on_invalid),
            convert_options=pacsv.ConvertOptions(column_types=dict.fromkeys(names, pa.string()),
                                                 strings_can_be_null=False,
                                                 quoted_strings_can_be_null=False),
        )
    except pa.ArrowInvalid as exc:
        raise FormatError(f"not a readable delimited table ({exc})", path=path) from None
    bad = sorted(line for line, is_blank in invalid if not is_blank)
    blank = [line for line, is_blank in invalid if is_blank]
    if bad and not salvage:
        first = bad[0]
        got = len(next(csv.reader([all_lines[first - 1]], delimiter=delimiter))) if (
            0 < first <= len(all_lines)) else "another number of"
        raise FormatError(f"row has {got} fields, the header {n} ({hint})", path=path,
                          position=f"line {first}")
    skipped = np.array(sorted(line for line, _ in invalid), dtype=np.int64)
    candidates = np.arange(header_line + 1, header_line + 1 + table.num_rows + skipped.size,
                           dtype=np.int64)
    lines = np.setdiff1d(candidates, skipped, assume_unique=True)[: table.num_rows]
    # a line of blanks or delimiters only is a blank line, not a row of empty values
    if n and table.num_rows:
        import pyarrow.compute as pc

        keep = np.zeros(table.num_rows, dtype=np.bool_)
        for col in table.columns:  # until every row has a value (the first column, mostly)
            keep |= pc.not_equal(pc.utf8_trim_whitespace(col), "").to_numpy()
            if keep.all():
                break
        if not keep.all():
            blank += [int(x) for x in lines[~keep]]
            table = table.filter(pa.array(keep))
            lines = lines[keep]
    return CsvTable(header=header, columns=list(table.columns), lines=lines, path=path,
                    delimiter=delimiter, dropped_lines=bad, blank_lines=sorted(blank))
