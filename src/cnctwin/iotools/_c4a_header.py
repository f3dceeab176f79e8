"""Capture4Analysis reader, the header's HF signal list and the HF rows it describes.

Columns are matched by ``Address`` (``CURRENT|6``), never by ``Name``; the axis name comes from
the header's ``Axis`` field, an empty one is filled from the axis map. :func:`hf_rows_slow`
converts rows one value at a time with exact error positions; the document parser uses it only
for entries that the fast path (one ``np.array`` per entry) cannot take. Private to
:mod:`cnctwin.iotools.capture4analysis`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cnctwin.exceptions import FormatError
from cnctwin.iotools._c4a_format import to_float
from cnctwin.iotools._c4a_state import ReadState
from cnctwin.signals import parse_column

__all__ = ["Columns", "columns_of", "hf_rows_slow"]


@dataclass
class Columns:
    """How the HF rows of one file map to recording columns."""

    names: list[str]  # recording column names (CODE|AXIS), without CYCLE
    cycle_index: int
    value_index: list[int]  # row index of each name
    width: int  # row length declared by the header
    declared_string: list[str]


def columns_of(state: ReadState, header: dict[str, Any], label: str) -> Columns | None:
    """Map ``Header.SignalListHFData`` to recording columns; None if the file has no HF list."""
    signals = header.get("SignalListHFData")
    if signals is None:
        return None
    if not isinstance(signals, list):
        raise FormatError(
            "SignalListHFData must be a list of signal definitions",
            path=label, position="Header.SignalListHFData",
        )
    if not signals:
        return None
    names: list[str] = []
    value_index: list[int] = []
    cycle_index = -1
    declared_string: list[str] = []
    used: set[str] = set()
    for i, sig in enumerate(signals):
        pos = f"Header.SignalListHFData[{i}]"
        if not isinstance(sig, dict):
            raise FormatError("signal definition is not an object", path=label, position=pos)
        address = sig.get("Address")
        if not isinstance(address, str) or not address.strip():
            if state.salvage and isinstance(sig.get("Name"), str):
                address = sig["Name"]
                state.issues.append(f"{label}: {pos} has no Address; used its Name {address!r}")
                state.partial = True
            else:
                raise FormatError(
                    "signal definition has no Address (columns are matched by Address, "
                    "not Name); fix the header or read with salvage=True to use Name",
                    path=label, position=pos, field="Address",
                )
        address = address.strip()
        if address.upper() == "CYCLE":
            if cycle_index < 0:
                cycle_index = i
            continue
        name = _column_name(state, address, sig.get("Axis"), label, pos)
        if name in used:
            state.issues.append(
                f"{label}: {pos} repeats column {name!r} (Address {address!r}); "
                "kept the first definition, ignored this one"
            )
            continue
        used.add(name)
        names.append(name)
        value_index.append(i)
        if str(sig.get("Type", "")).upper() == "STRING":
            declared_string.append(name)
    if cycle_index < 0:
        raise FormatError(
            "SignalListHFData has no CYCLE entry; HF rows need the cycle counter",
            path=label, position="Header.SignalListHFData", field="Address",
        )
    return Columns(names, cycle_index, value_index, len(signals), declared_string)


def _column_name(state: ReadState, address: str, axis_field: Any, label: str, pos: str) -> str:
    code, suffix = parse_column(address)
    if suffix is None:
        return address
    axis = axis_field.strip() if isinstance(axis_field, str) else ""
    if not suffix.isdigit():
        return address  # already CODE|AXIS
    number = int(suffix)
    if axis:
        if state.explicit_map and number in state.axis_map and state.axis_map[number] != axis:
            state.issues.append(
                f"{label}: {pos} {address}: header Axis {axis!r} differs from axis_map "
                f"{state.axis_map[number]!r}; kept the header's"
            )
        state.seen_axes.setdefault(number, axis)
        return f"{code}|{axis}"
    if number in state.axis_map:
        axis = state.axis_map[number]
        state.issues.append(
            f"{label}: {pos} {address}: empty Axis field repaired to {axis!r} from the axis map"
        )
        state.seen_axes.setdefault(number, axis)
        return f"{code}|{axis}"
    state.issues.append(
        f"{label}: {pos} {address}: empty Axis field and axis number {number} not in the "
        f"axis map {state.axis_map}; column kept as {address!r} (pass axis_map= to name it)"
    )
    return address

# ------------------------------------------------------------------ HF rows

def hf_rows_slow(
    state: ReadState, rows: Any, cols: Columns, label: str, where: str
) -> NDArray[np.float64]:
    """Row-by-row conversion with exact error positions (strings, nulls, bad rows)."""
    if not isinstance(rows, list):
        raise FormatError(
            f"HFData must be a list of rows, got {type(rows).__name__}",
            path=label, position=where,
        )
    out = np.full((len(rows), cols.width), np.nan)
    keep = np.ones(len(rows), dtype=bool)
    all_names = ["CYCLE" if j == cols.cycle_index else "" for j in range(cols.width)]
    for name, j in zip(cols.names, cols.value_index, strict=True):
        all_names[j] = name
    for r, row in enumerate(rows):
        pos = f"{where}[{r}]"
        if not isinstance(row, list) or len(row) != cols.width:
            got = f"{len(row)} values" if isinstance(row, list) else type(row).__name__
            msg = (f"HF row has {got}, SignalListHFData declares {cols.width} columns")
            if not state.salvage:
                raise FormatError(msg + "; read with salvage=True to drop such rows",
                                  path=label, position=pos)
            state.issues.append(f"{label}: {pos}: {msg}; row dropped")
            state.partial = True
            keep[r] = False
            continue
        for j, v in enumerate(row):
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                out[r, j] = v
                continue
            name = all_names[j] or f"column {j}"
            if v is None and j != cols.cycle_index:
                state.nulls[name] = state.nulls.get(name, 0) + 1
                continue
            f = to_float(v) if isinstance(v, str) else None
            if f is not None:
                out[r, j] = f
                state.string_conversions[name] = state.string_conversions.get(name, 0) + 1
                continue
            msg = (f"value {v!r} where a number is required")
            if not state.salvage or j == cols.cycle_index:
                raise FormatError(
                    msg + ("; read with salvage=True to keep it as NaN"
                           if j != cols.cycle_index else ""),
                    path=label, position=f"{pos}[{j}]", field=name,
                )
            state.issues.append(f"{label}: {pos}[{j}] ({name}): {msg}; kept as NaN")
            state.partial = True
    return out if keep.all() else out[keep]
