"""Reader for flattened SINUMERIK edge exports in the KIT CNC-milling layout.

The KIT CNC milling data set (Ströbel et al. 2025, DOI 10.35097/hvvwn1kfwf7qt48z) publishes
each trial as three CSV files:

* ``<TRIAL>_hfdata.csv``: one row per position-control cycle; columns ``CYCLE`` and the HF
  addresses ``DES_POS|1``, ``ENC_POS|1``, ... (``<CODE>|<axis number>``).
* ``<TRIAL>_header.csv``: ``SignalName,Type,Axis,Address``; ``SignalName`` is a long name
  (``ActualAxisPosition``), ``Address`` the code (``ENC_POS|1``). The reader keys on
  ``Address`` and takes the axis name of each axis number from ``Axis``.
* ``<TRIAL>_hfblockevent.csv``: ``HFProbeCounter,Channel,SeekOffset,SelectedTool,ActiveTool,
  GCode,IpoGC,ipoReadError,laBuf`` -> ``events`` (kind ``"block"``).

An optional ``<TRIAL>_hfcallevent.csv`` (``HFProbeCounter,Channel,SeekOffset,CallStackLevel,
Path``) becomes call events. The files carry no wall-clock time: unless a ``time`` column is
present in ``hfdata`` (ISO 8601 UTC), times start at the Unix epoch (noted in ``meta.issues``).

Cells and events, so that a trial reads like the Capture4Analysis recording it came from:

* Number cells are stripped of blanks; text cells (``GCode``, ``IpoGC``, ``Path``) are kept
  verbatim (the real G-code ``"D0"`` + 15 blanks keeps its blanks). An empty cell (or ``null``,
  ``None``) is a missing value. ``ipoReadError`` and ``laBuf`` become ``ipo_read_error`` and
  ``la_buf``; other event columns are kept as extra text columns (listed in ``meta.issues``).
* Event order: stable by cycle, then the source order, as in
  :func:`~cnctwin.iotools.capture4analysis.read_capture4analysis`. The source order within a
  file is its row order; between the two files it is the Data Recorder's write order, in
  which the ``HFCallEvent`` entries of a cycle precede the ``HFBlockEvent`` they lead to (in the
  real recording 26 cycles carry both kinds, each as calls then one block). So at one cycle the
  rows of ``_hfcallevent.csv`` come before those of ``_hfblockevent.csv``.
* Event counters are unwrapped in file order and placed next to the HF counter (nearest
  period of 2**31), so events after a wrap-around stay after it.
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from cnctwin.exceptions import FormatError
from cnctwin.iotools._csvtable import CsvTable, read_csv_table
from cnctwin.recording import (
    CYCLE_COUNTER_MODULUS,
    EVENT_COLUMNS,
    Recording,
    RecordingMeta,
    find_gaps,
    unwrap_cycles,
)
from cnctwin.signals import DEFAULT_AXIS_MAP

__all__ = ["FLAT_CSV_SUFFIXES", "flat_csv_paths", "read_flat_csv"]

FLAT_CSV_SUFFIXES: tuple[str, ...] = ("_hfdata.csv", "_header.csv", "_hfblockevent.csv",
                                      "_hfcallevent.csv")
"""File-name endings of one trial."""

_BLOCK_COLS = {
    "HFProbeCounter": "cycle", "Channel": "channel", "SeekOffset": "seek_offset",
    "SelectedTool": "selected_tool", "ActiveTool": "active_tool", "GCode": "gcode",
    "IpoGC": "ipo_gcode", "ipoReadError": "ipo_read_error", "laBuf": "la_buf",
}
_CALL_COLS = {
    "HFProbeCounter": "cycle", "Channel": "channel", "SeekOffset": "seek_offset",
    "CallStackLevel": "call_stack_level", "Path": "path",
}
_INT_EVENT_COLS = ("channel", "seek_offset", "selected_tool", "active_tool", "call_stack_level",
                   "la_buf")
_EXTRA_EVENT_COLS = ("ipo_read_error", "la_buf")
"""Block-event fields kept beside :data:`~cnctwin.recording.EVENT_COLUMNS` (as the
Capture4Analysis reader does)."""
_NULL_CELLS = ("", "null", "None")
"""Cells read as a missing value (compared verbatim, so ``" "`` is text)."""


def flat_csv_paths(path: str | PathLike[str]) -> dict[str, Path]:
    """The files of one trial from any of them or from the stem.

    Parameters
    ----------
    path : str or path-like
        ``.../T01_hfdata.csv``, ``.../T01_header.csv``, ``.../T01_hfblockevent.csv`` or the
        stem ``.../T01``.

    Returns
    -------
    dict
        ``{"hfdata": Path, "header": Path, "hfblockevent": Path, "hfcallevent": Path}``
        (the paths whether or not they exist).
    """
    p = Path(path)
    stem = str(p)
    for suffix in FLAT_CSV_SUFFIXES:
        if p.name.endswith(suffix):
            stem = str(p)[: -len(suffix)]
            break
    return {s[1:-4]: Path(stem + s) for s in FLAT_CSV_SUFFIXES}


def _read_rows(path: Path, *, salvage: bool, issues: list[str]) -> tuple[CsvTable, bool]:
    """The file's cells; rows of the wrong length raise or, with ``salvage``, are dropped."""
    table = read_csv_table(path, path=str(path), salvage=salvage, encoding="utf-8",
                           hint="pass salvage=True to keep the good rows")
    bad = table.dropped_lines
    if bad:
        shown = ", ".join(map(str, bad[:10])) + (" ..." if len(bad) > 10 else "")
        issues.append(f"{path.name}: {len(bad)} row(s) of the wrong length dropped (lines "
                      f"{shown})")
    return table, bool(bad)


def _read_header(path: Path, issues: list[str]) -> tuple[dict[int, str], dict[str, str],
                                                         list[dict[str, str]]]:
    """Axis map and long name -> address from ``_header.csv``."""
    axis_map: dict[int, str] = {}
    name_to_addr: dict[str, str] = {}
    table = read_csv_table(path, path=str(path))
    fields = table.header
    if "Address" not in fields:
        raise FormatError(f"header file needs an 'Address' column, found {fields}",
                          path=str(path), position="line 1", field="Address")
    cells = [[v.strip() for v in table.text(j)] for j in range(len(fields))]
    entries = [{h: cells[j][k] for j, h in enumerate(fields)} for k in range(table.n_rows)]
    empty_axis = 0
    for e in entries:
        addr = e.get("Address", "")
        if e.get("SignalName"):
            name_to_addr[e["SignalName"]] = addr
        if "|" not in addr:
            continue
        num = addr.split("|", 1)[1]
        if not num.isdigit():
            continue
        axis = e.get("Axis", "")
        if axis:
            axis_map.setdefault(int(num), axis)
        else:
            empty_axis += 1
    if empty_axis:
        issues.append(f"{path.name}: {empty_axis} row(s) with an empty Axis field")
    return axis_map, name_to_addr, entries


def _unwrap_near(raw: NDArray[np.int64], ref: int | None) -> NDArray[np.int64]:
    """Unwrap counters in file order, then shift by whole periods to lie nearest ``ref``."""
    cycles, _ = unwrap_cycles(raw)
    if ref is None or cycles.size == 0:
        return cycles
    return cycles + CYCLE_COUNTER_MODULUS * round((ref - int(cycles[0])) / CYCLE_COUNTER_MODULUS)


def _events(path: Path, kind: str, colmap: dict[str, str], *, salvage: bool,
            issues: list[str], ref_cycle: int | None) -> tuple[pd.DataFrame, bool]:
    """Events of one file in file order; counters unwrapped next to ``ref_cycle``.

    Number cells are stripped; text cells (``GCode``, ``IpoGC``, ``Path``) are kept verbatim
    (G-code may end in blanks: ``"D0"`` + 15 blanks in the real recording).
    """
    table, partial = _read_rows(path, salvage=salvage, issues=issues)
    header = table.header
    if "HFProbeCounter" not in header:
        raise FormatError("event file needs an 'HFProbeCounter' column", path=str(path),
                          position="line 1", field="HFProbeCounter")
    idx = {h: i for i, h in enumerate(header)}
    unknown = [h for h in header if h not in colmap]
    columns = (*EVENT_COLUMNS, *_EXTRA_EVENT_COLS, *unknown)
    n = table.n_rows
    frame: dict[str, Any] = {}
    for src, dst in colmap.items():
        if src not in idx:
            continue
        if dst == "cycle" or dst in _INT_EVENT_COLS:
            values = table.numbers(idx[src], missing=_NULL_CELLS)
            nan = np.isnan(values)
            if dst == "cycle":
                if nan.any():
                    raise FormatError("empty HFProbeCounter", path=str(path),
                                      position=f"line {int(table.lines[np.argmax(nan)])}",
                                      field=src)
                frame[dst] = _unwrap_near(values.astype(np.int64), ref_cycle)
            else:
                ints = pd.array(np.where(nan, 0, values).astype(np.int64), dtype="Int64")
                ints[nan] = pd.NA
                frame[dst] = ints
        else:
            frame[dst] = _text_cells(table, idx[src])
    for h in unknown:
        frame[h] = _text_cells(table, idx[h])
    if unknown:
        issues.append(f"{path.name}: columns not in the event schema kept as extra (text) "
                      f"columns: {', '.join(unknown)}")
    for c in columns:
        if c not in frame:
            frame[c] = (pd.array([pd.NA] * n, dtype="Int64") if c in _INT_EVENT_COLS
                        else pd.Series([None] * n, dtype="object"))
    frame["kind"] = pd.Series([kind] * n, dtype="object")
    return pd.DataFrame({c: frame[c] for c in columns}), partial


def _text_cells(table: CsvTable, j: int) -> pd.Series:
    """Text cells verbatim, a missing value (:data:`_NULL_CELLS`) as None."""
    return pd.Series([None if v in _NULL_CELLS else v for v in table.text(j)], dtype="object")


def _sorted_unique(hf: pd.DataFrame, lines: NDArray[np.int64], name: str, issues: list[str]
                   ) -> pd.DataFrame:
    """Sort rows by cycle (stable) and keep the first row of a repeated cycle.

    The first row in file order wins, as in
    :func:`~cnctwin.iotools.capture4analysis.read_capture4analysis` (first arrival); the
    dropped rows are named by line in ``issues``.
    """
    if not hf.index.is_monotonic_increasing:
        issues.append(f"{name}: rows not in cycle order; sorted")
        order = np.argsort(hf.index.to_numpy(), kind="stable")
        hf = hf.iloc[order]
        lines = lines[order]
    if not hf.index.has_duplicates:
        return hf
    cyc = hf.index.to_numpy()
    dropped = np.flatnonzero(hf.index.duplicated(keep="first"))
    first_of = np.searchsorted(cyc, cyc[dropped], side="left")  # rows are sorted by cycle
    vals = hf.to_numpy(dtype=np.float64)
    same = bool(np.array_equal(vals[dropped], vals[first_of], equal_nan=True))
    shown = "; ".join(
        f"cycle {int(cyc[d])}: line {int(lines[d])} (kept line {int(lines[f])})"
        for d, f in zip(dropped[:10], first_of[:10], strict=True)
    ) + (" ..." if dropped.size > 10 else "")
    issues.append(
        f"{name}: {dropped.size} duplicate CYCLE row(s) "
        f"({'identical' if same else 'DIFFERENT'} values) dropped, kept the first of each "
        f"cycle: {shown}"
    )
    keep = np.ones(len(hf), dtype=bool)
    keep[dropped] = False
    return hf[keep]


def _merge_events(frames: list[pd.DataFrame]) -> pd.DataFrame:
    """Concatenate event frames in the given order, then sort stably by cycle."""
    df = pd.concat(frames, ignore_index=True)
    for c in df.columns:
        if df[c].dtype == object:  # columns only one file has: None, not NaN, elsewhere
            df[c] = df[c].astype(object).where(df[c].notna(), None)
    return df.sort_values("cycle", kind="stable").reset_index(drop=True)


def read_flat_csv(
    path: str | PathLike[str],
    *,
    cycle_time_s: float = 0.002,
    salvage: bool = False,
) -> Recording:
    """Read a trial exported as flattened CSVs (KIT layout).

    Parameters
    ----------
    path : str or path-like
        Any of ``<TRIAL>_hfdata.csv``, ``<TRIAL>_header.csv``, ``<TRIAL>_hfblockevent.csv``,
        or the stem ``<TRIAL>``.
    cycle_time_s : float, default 0.002
        Position-control cycle time [s].
    salvage : bool, default False
        Drop rows of the wrong length (listed in ``meta.issues``) and set ``meta.partial``
        instead of raising.

    Returns
    -------
    Recording
        Columns ``CODE|AXIS`` (axis names from ``_header.csv``; from
        :data:`~cnctwin.signals.DEFAULT_AXIS_MAP` if it is missing, with an issue).
        ``meta.attrs["header"]`` holds the header rows (long names, types).

    Raises
    ------
    FormatError
        Missing ``_hfdata.csv`` or ``CYCLE`` column, rows of the wrong length (file and line),
        non-numeric values (file, line and column).

    Notes
    -----
    Rows are sorted by cycle; of rows repeating a cycle the first in the file is kept and the
    others are listed by line in ``meta.issues`` (the rule of
    :func:`~cnctwin.iotools.capture4analysis.read_capture4analysis`).
    """
    files = flat_csv_paths(path)
    hfpath = files["hfdata"]
    if not hfpath.exists():
        raise FormatError(
            f"no {hfpath.name} beside the given path; expected <TRIAL>_hfdata.csv", path=str(path)
        )
    issues: list[str] = []
    sources = [str(hfpath)]
    axis_map: dict[int, str] = {}
    name_to_addr: dict[str, str] = {}
    header_rows: list[dict[str, str]] = []
    if files["header"].exists():
        axis_map, name_to_addr, header_rows = _read_header(files["header"], issues)
        sources.append(str(files["header"]))
    else:
        issues.append(f"no {files['header'].name}: axis names from the default axis map "
                      f"{DEFAULT_AXIS_MAP}")

    table, partial = _read_rows(hfpath, salvage=salvage, issues=issues)
    header = table.header
    addresses = [name_to_addr.get(h, h) if "|" not in h else h for h in header]
    if "CYCLE" not in addresses:
        raise FormatError(f"no CYCLE column in {hfpath.name} (columns: {header[:5]} ...)",
                          path=str(hfpath), position="line 1", field="CYCLE")
    ci = addresses.index("CYCLE")
    time_i = next((i for i, h in enumerate(header) if h.lower() in ("time", "timestamp")),
                  None)
    sig_idx = [i for i in range(len(header)) if i not in (ci, time_i)]
    values = np.column_stack([table.numbers(j) for j in (ci, *sig_idx)]) if table.n_rows else (
        np.empty((0, 1 + len(sig_idx))))
    if np.isnan(values[:, 0]).any():
        line = int(table.lines[int(np.flatnonzero(np.isnan(values[:, 0]))[0])])
        raise FormatError("empty CYCLE value", path=str(hfpath), position=f"line {line}",
                          field="CYCLE")
    cycles, wraps = unwrap_cycles(values[:, 0].astype(np.int64))
    n_nan = int(np.isnan(values[:, 1:]).sum())
    if n_nan:
        issues.append(f"{hfpath.name}: {n_nan} empty cells kept as NaN")

    used_default = False
    for a in addresses:
        if "|" in a:
            num = a.split("|", 1)[1]
            if num.isdigit() and int(num) not in axis_map:
                if int(num) in DEFAULT_AXIS_MAP:
                    axis_map[int(num)] = DEFAULT_AXIS_MAP[int(num)]
                    used_default = True
                else:
                    axis_map[int(num)] = f"AX{num}"
                    issues.append(f"axis number {num} unknown; named AX{num}")
    if used_default and files["header"].exists():
        issues.append("some axis numbers had no Axis name in the header; filled from the "
                      "default axis map")
    names: list[str] = []
    for i in sig_idx:
        a = addresses[i]
        code, _, num = a.partition("|")
        names.append(f"{code}|{axis_map[int(num)]}" if num.isdigit() else a)
    hf = pd.DataFrame(values[:, 1:], columns=names, index=pd.Index(cycles, name="cycle"))
    hf = _sorted_unique(hf, table.lines, hfpath.name, issues)

    anchors: list[tuple[int, pd.Timestamp]] = []
    if time_i is not None:
        t = pd.to_datetime(pd.Series(table.text(time_i)), utc=True, errors="coerce")
        ok = t.notna().to_numpy()
        if ok.any():
            j = int(np.flatnonzero(ok)[0])
            anchors = [(int(cycles[j]), pd.Timestamp(t.iloc[j]))]
    else:
        issues.append("no wall-clock time in the flat CSV: times start at the Unix epoch")

    # at one cycle the Data Recorder writes the call events before the block event they lead
    # to; the two files lost that interleaving, so calls go first (see the module docstring)
    ref = int(hf.index[0]) if len(hf) else None
    by_kind: dict[str, pd.DataFrame] = {}
    for key, kind, colmap in (("hfblockevent", "block", _BLOCK_COLS),
                              ("hfcallevent", "call", _CALL_COLS)):
        if files[key].exists():
            by_kind[kind], part = _events(files[key], kind, colmap, salvage=salvage,
                                          issues=issues, ref_cycle=ref)
            partial |= part
            sources.append(str(files[key]))
    ev_all = None
    if by_kind:
        ev_all = _merge_events([by_kind[k] for k in ("call", "block") if k in by_kind])

    meta = RecordingMeta(
        cycle_time_s=cycle_time_s,
        axis_map=dict(sorted(axis_map.items())),
        source_files=sources,
        source_format="flat_csv",
        time_anchors=anchors,
        gaps=find_gaps(hf.index.to_numpy()),
        wraps=wraps,
        issues=issues,
        partial=partial,
        attrs={"header": header_rows},
    )
    return Recording(hf, events=ev_all, meta=meta)
