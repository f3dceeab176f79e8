"""Capture4Analysis reader, one JSON document: header, payload entries, truncated tail.

The bytes are scanned once for their structure (:func:`cnctwin.iotools._jsonscan.scan_document`,
numba); the Header, the Footer and each Payload entry are then parsed separately with orjson
on a zero-copy ``memoryview`` slice, so the Python objects of one entry at a time are alive.
HF rows go straight into a preallocated column-major float64 block (:class:`_PayloadSink`).
A truncated document keeps its complete entries and the complete part of the last one
(``salvage=True``). Private to :mod:`cnctwin.iotools.capture4analysis`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import orjson
import pandas as pd
from numpy.typing import NDArray

from cnctwin.exceptions import FormatError, TruncatedFileError
from cnctwin.iotools._c4a_header import Columns, columns_of, hf_rows_slow
from cnctwin.iotools._c4a_source import Source
from cnctwin.iotools._c4a_state import ReadState, line_col, opt_int
from cnctwin.iotools._jsonscan import (
    ERROR_TEXT,
    FLAG_LITERAL,
    FLAG_STRING,
    close_partial,
    scan_document,
)

__all__ = ["FilePart", "read_document"]

_INT_EVENT_FIELDS = ("Channel", "SeekOffset", "SelectedTool", "ActiveTool", "CallStackLevel",
                     "laBuf")
"""Event fields the events table holds as integers (``Int64``)."""


@dataclass
class FilePart:
    """What one file contributed, before concatenation."""

    label: str
    header: dict[str, Any]
    footer: dict[str, Any] | None
    columns: Columns | None
    cycles: NDArray[np.int64]
    values: NDArray[np.float64]  # shape (n_columns, n_rows)
    anchors: list[tuple[int, str]]
    events: list[dict[str, Any]]
    lf: list[dict[str, Any]]
    other: dict[str, list[Any]] = field(default_factory=dict)


class _PayloadSink:
    """Collects the payload entries of one document (HF block, anchors, events, LF, other)."""

    def __init__(self, state: ReadState, cols: Columns | None, label: str, upper: int) -> None:
        self.state = state
        self.cols = cols
        self.label = label
        self.n_cols = len(cols.names) if cols else 0
        # preallocated HF block (columns x rows), sized by the scanner's row count
        self.values = np.empty((self.n_cols, upper), dtype=np.float64)
        self.cycles = np.empty(upper, dtype=np.int64)
        self.n_rows = 0
        self.anchors: list[tuple[int, str]] = []
        self.events: list[dict[str, Any]] = []
        self.lf: list[dict[str, Any]] = []
        self.other: dict[str, list[Any]] = {}
        self.perm = [cols.cycle_index, *cols.value_index] if cols else []

    def add_rows(self, block: NDArray[np.float64], where: str) -> None:
        """Append HF rows (``block``: rows x declared width) to the column-major block."""
        if self.cols is None:
            raise FormatError(
                "HFData present but the header has no SignalListHFData to map it",
                path=self.label, position=where,
            )
        n = block.shape[0]
        if n == 0:
            return
        n_rows = self.n_rows
        if n_rows + n > self.values.shape[1]:  # scanner count was low (odd input): grow
            grow = max(n_rows + n, 2 * self.values.shape[1])
            self.values = np.concatenate(
                [self.values[:, :n_rows], np.empty((self.n_cols, grow - n_rows))], axis=1)
            self.cycles = np.concatenate(
                [self.cycles[:n_rows], np.empty(grow - n_rows, np.int64)])
        perm = self.perm
        raw_c = block[:, perm[0]]
        c_int = raw_c.astype(np.int64)
        if not np.array_equal(c_int, raw_c):
            bad = int(np.flatnonzero(c_int != raw_c)[0])
            raise FormatError(
                f"CYCLE value {raw_c[bad]!r} is not an integer",
                path=self.label, position=f"{where}[{bad}][{perm[0]}]", field="CYCLE",
            )
        self.cycles[n_rows : n_rows + n] = self.state.unwrap_block(c_int)
        self.values[:, n_rows : n_rows + n] = block[:, perm[1:]].T
        self.n_rows = n_rows + n

    def handle(self, key: str, value: Any, where: str) -> None:
        """Take one ``key: value`` of a payload entry (the slow, general path)."""
        state, label = self.state, self.label
        if key == "HFData":
            if self.cols is None:
                raise FormatError(
                    "HFData present but the header has no SignalListHFData to map it",
                    path=label, position=where,
                )
            self.add_rows(hf_rows_slow(state, value, self.cols, label, where), where)
        elif key == "HFTimestamp":
            if not isinstance(value, dict) or "HFProbeCounter" not in value or \
                    "Time" not in value:
                state.bad(label, where, "HFTimestamp needs HFProbeCounter and Time")
                return
            c = opt_int(value["HFProbeCounter"])
            if c is pd.NA:
                state.bad(label, where, f"HFProbeCounter {value['HFProbeCounter']!r} is not "
                          "an integer", fld="HFProbeCounter")
                return
            self.anchors.append((state.unwrap_one(int(c)), str(value["Time"])))
        elif key in ("HFBlockEvent", "HFCallEvent"):
            if not isinstance(value, dict):
                state.bad(label, where, f"{key} is not an object")
                return
            c = opt_int(value.get("HFProbeCounter"))
            if c is pd.NA:
                state.bad(label, where, f"{key} has no integer HFProbeCounter",
                          fld="HFProbeCounter")
                return
            ev = dict(value)
            for fld in _INT_EVENT_FIELDS:
                v = ev.get(fld)
                if v is not None and opt_int(v) is pd.NA:
                    msg = f"{key}.{fld} {v!r} is not an integer"
                    if not state.salvage:
                        raise FormatError(msg + "; read with salvage=True to keep the event "
                                          "with this field missing",
                                          path=label, position=where, field=fld)
                    state.issues.append(f"{label}: {where}: {msg}; kept as missing")
                    state.partial = True
                    ev[fld] = None
            ev["__kind"] = "block" if key == "HFBlockEvent" else "call"
            ev["__cycle"] = state.unwrap_one(int(c))
            ev["__where"] = where
            self.events.append(ev)
        elif key == "LFData":
            items = value if isinstance(value, list) else [value]
            for k, item in enumerate(items):
                if not isinstance(item, dict):
                    state.bad(label, f"{where}[{k}]", "LF entry is not an object")
                    continue
                c = opt_int(item.get("HFProbeCounter"))
                if c is pd.NA:
                    state.bad(label, f"{where}[{k}]", "LF entry has no integer "
                              "HFProbeCounter", fld="HFProbeCounter")
                    continue
                entry = dict(item)
                entry["__cycle"] = state.unwrap_one(int(c))
                self.lf.append(entry)
        else:
            self.other.setdefault(key, []).append(value)


def _load_member(data: bytes, mv: memoryview, span: tuple[int, int], label: str, name: str
                 ) -> Any:
    """orjson-parse the top-level member ``name`` (Header, Footer) at byte span ``span``."""
    v0, v1 = span
    try:
        return orjson.loads(mv[v0:v1])
    except orjson.JSONDecodeError as exc:
        raise FormatError(
            f"{name} is not valid JSON ({exc.msg})",
            path=label, position=line_col(data, v0 + exc.pos),
        ) from exc


def _first_byte(mv: memoryview, pos: int) -> bytes:
    """The first non-blank byte at or after ``pos`` (``b""`` at the end)."""
    while pos < len(mv):
        chunk = bytes(mv[pos : pos + 256]).lstrip()
        if chunk:
            return chunk[:1]
        pos += 256
    return b""


def read_document(state: ReadState, src: Source) -> FilePart:
    """Parse one Capture4Analysis document (the bytes of ``src``).

    Raises
    ------
    FormatError
        Invalid JSON, no Header, wrong value types (and ``state.salvage`` is False where
        salvage applies); position as byte/line/column or ``Payload[i].HFData[j]``.
    TruncatedFileError
        The document ends early and ``state.salvage`` is False.
    """
    data = src.data
    label = src.label
    scan = scan_document(data)
    if scan.error:
        raise FormatError(
            f"not valid JSON: {ERROR_TEXT.get(scan.error, 'structure error')}",
            path=label, position=line_col(data, scan.error_pos),
        )
    mv = memoryview(data)
    truncated = not scan.complete
    if truncated:
        where = line_col(data, len(data))
        open_key = "the top-level object"
        if len(scan.members) and scan.members[-1, 3] < 0:
            k0, k1 = int(scan.members[-1, 0]), int(scan.members[-1, 1])
            open_key = bytes(mv[k0:k1]).decode("utf-8", "replace")
        where += f" inside {open_key}"
        if not state.salvage:
            raise TruncatedFileError(
                "the JSON ends early (truncated file: "
                f"{scan.depth} brackets still open"
                f"{', inside a string' if scan.in_string else ''}); re-copy the file, "
                "or read with salvage=True to keep the complete part",
                path=label, position=where,
            )
    members: dict[str, tuple[int, int, int]] = {}
    for idx, (k0, k1, v0, v1) in enumerate(scan.members.tolist()):
        key = bytes(mv[k0:k1]).decode("utf-8", "replace")
        members.setdefault(key, (idx, v0, v1))

    header: dict[str, Any] = {}
    if "Header" in members and members["Header"][2] >= 0:
        header = _load_member(data, mv, members["Header"][1:], label, "Header")
        if not isinstance(header, dict):
            raise FormatError("Header is not an object", path=label, position="Header")
    else:
        raise (TruncatedFileError if "Header" in members else FormatError)(
            "no complete Header object; this is not a usable Capture4Analysis file "
            "(Header with SignalListHFData is written first)",
            path=label, position="Header",
        )
    cols = columns_of(state, header, label)
    if cols is None:
        state.issues.append(
            f"{label}: no SignalListHFData in the header (LF-only job); HF table is empty"
        )
    footer: dict[str, Any] | None = None
    if "Footer" in members and members["Footer"][2] >= 0:
        got = _load_member(data, mv, members["Footer"][1:], label, "Footer")
        if isinstance(got, dict):
            footer = got
        elif got is not None:
            state.bad(label, "Footer", f"Footer is a {type(got).__name__}, not an object "
                      "(FilePathChain and ErrorMessages cannot be read)")

    payload_member = members.get("Payload", (-1, -1, -1))[0]
    if payload_member < 0:
        if truncated:
            state.issues.append(f"{label}: truncated before the Payload; no data kept")
        else:
            raise FormatError("no Payload array", path=label, position="Payload")
    else:
        first = _first_byte(mv, members["Payload"][1])
        if first not in (b"[", b""):
            kind = {b"{": "an object", b"n": "null", b'"': "a string"}.get(first, "a scalar")
            state.bad(label, "Payload", f"Payload is {kind}, not an array of entries; no data "
                      "read from it")
            payload_member = -1
    elements = scan.elements[scan.elements[:, 0] == payload_member] if payload_member >= 0 \
        else scan.elements[:0]

    sink = _PayloadSink(state, cols, label, int(elements[:, 3].sum()) if cols else 0)
    for e_idx, (_, s, e, _rows, flags) in enumerate(elements.tolist()):
        where = f"Payload[{e_idx}]"
        try:
            obj = orjson.loads(mv[s:e])
        except orjson.JSONDecodeError as exc:
            if not state.salvage:
                raise FormatError(
                    f"payload entry is not valid JSON ({exc.msg})",
                    path=label, position=f"{where}, {line_col(data, s + exc.pos)}",
                ) from exc
            state.issues.append(
                f"{label}: {where} ({line_col(data, s + exc.pos)}) is not valid JSON "
                f"({exc.msg}); entry dropped"
            )
            state.partial = True
            continue
        if not isinstance(obj, dict):
            state.bad(label, where, "payload entry is not an object")
            continue
        if (
            cols is not None and len(obj) == 1 and "HFData" in obj
            and not flags & (FLAG_STRING | FLAG_LITERAL)
        ):
            rows = obj["HFData"]
            try:
                block = np.array(rows, dtype=np.float64)
            except (ValueError, TypeError):
                block = None
            if block is not None and block.ndim == 2 and block.shape[1] == cols.width:
                sink.add_rows(block, f"{where}.HFData")
                continue
            if block is not None and block.size == 0 and isinstance(rows, list):
                continue
        for key, value in obj.items():
            sink.handle(key, value, f"{where}.{key}")

    if truncated and scan.open_element_start >= 0 and \
            scan.open_element_member == payload_member:
        _salvage_open_entry(state, sink, data, mv[scan.open_element_start:], len(elements))
    elif truncated:
        state.issues.append(
            f"{label}: truncated at {line_col(data, len(data))} after the Payload; "
            "Footer lost"
        )
        state.partial = True

    values, cycles = sink.values, sink.cycles
    if sink.n_rows < values.shape[1]:
        values = values[:, :sink.n_rows].copy()
        cycles = cycles[:sink.n_rows].copy()
    return FilePart(label, header, footer, cols, cycles, values, sink.anchors, sink.events,
                    sink.lf, sink.other)


def _salvage_open_entry(state: ReadState, sink: _PayloadSink, data: bytes, tail_mv: memoryview,
                        n_complete: int) -> None:
    """Keep the complete part of the payload entry the truncation cut (``salvage=True``)."""
    label, cols = sink.label, sink.cols
    tail = bytes(tail_mv)
    got = close_partial(tail)
    lost = len(tail)
    where = f"Payload[{n_complete}]"
    if got is not None and isinstance(got[0], dict):
        part_obj: dict[str, Any] = got[0]
        lost = len(tail) - got[1]
        cut_rows = 0
        for key, value in part_obj.items():
            if key == "HFData" and cols is not None and isinstance(value, list):
                whole = [r for r in value
                         if isinstance(r, list) and len(r) == cols.width]
                cut_rows += len(value) - len(whole)
                value = whole
            sink.handle(key, value, f"{where}.{key}")
        kept = (f"recovered the complete part of the last entry {where}"
                f"{f' (dropped {cut_rows} cut-off row)' if cut_rows else ''}")
    else:
        kept = f"the last, incomplete entry {where} could not be recovered"
    state.issues.append(
        f"{label}: truncated at {line_col(data, len(data))}; kept "
        f"{n_complete} complete payload entries, {kept}; lost the last {lost} bytes "
        "and everything after them (no Footer)"
    )
    state.partial = True
