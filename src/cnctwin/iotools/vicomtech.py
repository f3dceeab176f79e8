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

from os import PathLike
from pathlib import Path
from typing import Any

import pandas as pd

from cnctwin.exceptions import FormatError
from cnctwin.iotools._csvtable import read_csv_table

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
    if not p.is_file():
        raise FormatError("cannot read the Vicomtech CSV: file not found", path=str(p))
    table = read_csv_table(p, path=str(p))
    missing = [c for c in _REQUIRED if c not in table.header]
    if missing:
        raise FormatError(
            f"not the Vicomtech tool-wear table: missing columns {missing}", path=str(p),
            field=missing[0],
        )
    # every column is a number in the source; only an empty cell is missing ("n/a", "NULL"
    # ... are errors naming line and column)
    data = pd.DataFrame({h: table.integers_or_numbers(j) for j, h in enumerate(table.header)})
    lines = table.lines
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
