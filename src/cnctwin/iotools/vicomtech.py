"""Reader for the Mondragon / Vicomtech turning tool-wear feature table.

The dataset (Vicomtech/dataset-machine-tool-wear, CC BY-SA 4.0) holds 2054 one-second segments
of 13 turning tools. Each row has features (MEAN, RMS, MAX, SK, KURT) of CNC-internal drive
signals, dynamometer forces, accelerometers, acoustic emission and a microphone, plus the flank
wear ``Vb`` [µm] and the tool id. It is a feature table, not a time series of edge samples, so
this reader returns a DataFrame and a metadata dict (pvlib ``iotools`` style), not a Recording.

Columns added: ``segment`` (0-based order of the segment within its tool; rows are in time
order, Vb is non-decreasing within every tool).
"""

from __future__ import annotations

import csv
from os import PathLike
from pathlib import Path
from typing import Any

import pandas as pd

from cnctwin.exceptions import FormatError

__all__ = ["CNC_INTERNAL_SIGNALS", "DYNAMOMETER_SIGNALS", "read_vicomtech"]

CNC_INTERNAL_SIGNALS: dict[str, str] = {
    "TV2.S": "spindle motor torque (CNC internal)",
    "TV50.S": "spindle mechanical power (CNC internal)",
    "TV51.S": "spindle electrical power (CNC internal)",
    "CV3.S": "spindle motor current (CNC internal)",
    "TV2.X": "X motor torque (CNC internal)",
    "TV2.Z": "Z motor torque (CNC internal)",
    "CV3.X": "X motor current (CNC internal)",
    "CV3.Z": "Z motor current (CNC internal)",
}
"""Signal prefixes that come from the control (what an edge device can record)."""

DYNAMOMETER_SIGNALS: dict[str, str] = {
    "F_c": "cutting force [N] (dynamometer)",
    "F_f": "feed force [N] (dynamometer)",
    "F_p": "radial (passive) force [N] (dynamometer)",
}

_REQUIRED = ("tool", "Vb", "TV2.S_MEAN", "CV3.S_MEAN", "F_c_MEAN")


def read_vicomtech(path: str | PathLike[str]) -> tuple[pd.DataFrame, dict[str, Any]]:
    """Read ``Dataset_Machine_tool_wear.csv``.

    Parameters
    ----------
    path : str or path-like
        The CSV file.

    Returns
    -------
    data : pandas.DataFrame
        One row per 1 s segment; feature columns as in the source, ``tool``, ``Vb`` [µm] and
        ``segment`` (order within the tool).
    metadata : dict
        ``tools`` (ids in file order), ``n_segments``, ``cnc_internal_features`` (column names
        from the control), ``source``.

    Raises
    ------
    FormatError
        If the file is empty or not UTF-8 text, is missing a required column, has a row with
        the wrong number of fields (a cut-off file), a non-numeric value or a row without a
        tool id; the message names the line and the column.
    """
    p = Path(path)
    try:
        # only an empty cell is missing: "n/a", "NULL", ... in a number column are errors
        data = pd.read_csv(p, keep_default_na=False, na_values=[""])
        lines = _data_lines(p, len(data.columns))
    except (OSError, pd.errors.ParserError, pd.errors.EmptyDataError,
            UnicodeDecodeError) as exc:
        raise FormatError(f"cannot read the Vicomtech CSV: {exc}", path=str(p)) from exc
    missing = [c for c in _REQUIRED if c not in data.columns]
    if missing:
        raise FormatError(
            f"not the Vicomtech tool-wear table: missing columns {missing}", path=str(p),
            field=missing[0],
        )
    if len(lines) != len(data):  # pragma: no cover - csv and pandas disagree on the rows
        raise FormatError(f"{len(data)} rows read by pandas but {len(lines)} CSV data lines",
                          path=str(p))
    vb = pd.to_numeric(data["Vb"], errors="coerce")
    bad = vb.isna() & data["Vb"].notna()
    if bad.any():
        row = int(bad.to_numpy().nonzero()[0][0])
        raise FormatError("Vb is not numeric", path=str(p), position=f"line {lines[row]}",
                          field="Vb")
    for col in data.columns:  # every column is a number in the source
        if not pd.api.types.is_numeric_dtype(data[col]):
            num = pd.to_numeric(data[col], errors="coerce")
            text = (num.isna() & data[col].notna()).to_numpy().nonzero()[0]
            if text.size:
                row = int(text[0])
                raise FormatError(f"value {data[col].iloc[row]!r} is not a number",
                                  path=str(p), position=f"line {lines[row]}", field=str(col))
    no_tool = data["tool"].isna().to_numpy().nonzero()[0]
    if no_tool.size:
        raise FormatError("row has no tool id", path=str(p),
                          position=f"line {lines[int(no_tool[0])]}", field="tool")
    segment = data.groupby("tool", sort=False).cumcount().rename("segment")
    data = pd.concat([data, segment], axis=1)
    cnc = [
        c for c in data.columns
        if any(c.startswith(prefix + "_") for prefix in CNC_INTERNAL_SIGNALS)
        or c.startswith("CON.")
    ]
    meta: dict[str, Any] = {
        "tools": [int(t) for t in pd.unique(data["tool"])],
        "n_segments": len(data),
        "cnc_internal_features": cnc,
        "source": str(p),
    }
    return data, meta


def _data_lines(path: Path, n_fields: int) -> list[int]:
    """Line numbers of the data rows; a row with another field count raises FormatError.

    pandas fills a short row (the last row of a cut-off file) with NaN without a word; the
    stdlib reader sees it.
    """
    lines: list[int] = []
    with path.open(newline="", encoding="utf-8") as fh:
        reader = csv.reader(fh)
        next(reader, None)
        for row in reader:
            if not row:
                continue  # pandas skips blank lines too
            if len(row) != n_fields:
                raise FormatError(
                    f"row has {len(row)} fields, the header {n_fields} (file cut off or "
                    "damaged?)", path=str(path), position=f"line {reader.line_num}",
                )
            lines.append(reader.line_num)
    return lines
