"""Capture4Analysis / SINUMERIK Data Recorder JSON files: reader (writer re-exported).

The format (Siemens "Analyze MyWorkpiece /Capture4Analysis" and its successor "SINUMERIK Data
Recorder") is one JSON object per file, ``{"Header": ..., "Payload": [...], "Footer": ...}``,
optionally zipped, and a job run may span several files chained by
``Footer.FilePathChain`` (see ``/work/shared/reference/data-formats.md`` section 1).

* :func:`read_capture4analysis` reads a ``.json`` or ``.zip`` (one or more chained files) into a
  :class:`~cnctwin.recording.Recording`.
* :func:`parse_capture4analysis` parses one document (JSON or zip) held in memory, e.g. a Data
  Recorder MQTT message; :func:`read_capture4analysis` runs the same document parser on each
  file of a chain.
* :class:`Capture4AnalysisWriter` and :func:`write_capture4analysis` live in
  :mod:`cnctwin.iotools.capture4analysis_writer` and are re-exported here.

Reading rules (each repair is written to ``rec.meta.issues``):

* HF columns are matched by ``Address`` (``CURRENT|6``), never by ``Name``; the axis name comes
  from the header's ``Axis``; empty ``Axis`` fields are filled from ``axis_map``; unknown axis
  numbers keep ``CODE|<n>``. Each file of a chain is mapped with its own header.
* The cycle counter is the clock: times come from ``Initial`` and the ``HFTimestamp`` anchors
  (:func:`~cnctwin.recording.cycles_to_time`). Wrap-around is unwrapped, gaps are reported,
  rows are sorted by cycle and duplicate cycles keep the first arrival.
* LF values are aligned by ``HFProbeCounter`` (their ``timestamp`` runs on another clock; it is
  kept in ``meta.attrs["lf_wall_clock"]``).
* Unknown payload keys (``ExternalData``) are kept in ``meta.attrs["payload_other"]``.
"""

from __future__ import annotations

import io
import json
import re
import zipfile
import zlib
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
import orjson
import pandas as pd
from numpy.typing import NDArray

from cnctwin.exceptions import ConfigError, FormatError, TruncatedFileError
from cnctwin.iotools._c4a_format import parse_times as _parse_times
from cnctwin.iotools._c4a_format import to_float as _to_float
from cnctwin.iotools._jsonscan import (
    ERROR_TEXT,
    FLAG_LITERAL,
    FLAG_STRING,
    close_partial,
    scan_document,
)

# the writer lives in its own module; re-exported here so existing imports keep working
from cnctwin.iotools.capture4analysis_writer import (
    Capture4AnalysisWriter,
    write_capture4analysis,
)
from cnctwin.recording import (
    CYCLE_COUNTER_MODULUS,
    EVENT_COLUMNS,
    CounterGap,
    Recording,
    RecordingMeta,
    cycles_to_time,
    empty_lf,
    find_gaps,
)
from cnctwin.signals import DEFAULT_AXIS_MAP, parse_column

__all__ = [
    "Capture4AnalysisWriter",
    "parse_capture4analysis",
    "read_capture4analysis",
    "write_capture4analysis",
]

_M = CYCLE_COUNTER_MODULUS
_KNOWN_PAYLOAD = ("HFData", "HFTimestamp", "LFData", "HFBlockEvent", "HFCallEvent")
_BLOCK_FIELDS = {
    "HFProbeCounter": "cycle",
    "Channel": "channel",
    "SeekOffset": "seek_offset",
    "SelectedTool": "selected_tool",
    "ActiveTool": "active_tool",
    "GCode": "gcode",
    "IpoGC": "ipo_gcode",
    "ipoReadError": "ipo_read_error",
    "laBuf": "la_buf",
}
_CALL_FIELDS = {
    "HFProbeCounter": "cycle",
    "Channel": "channel",
    "SeekOffset": "seek_offset",
    "CallStackLevel": "call_stack_level",
    "Path": "path",
}
_INT_EVENT_COLUMNS = (
    "channel", "seek_offset", "selected_tool", "active_tool", "call_stack_level", "la_buf",
)
_EXTRA_EVENT_COLUMNS = ("ipo_read_error", "la_buf")
"""Block-event fields kept beside :data:`~cnctwin.recording.EVENT_COLUMNS`."""


# ====================================================================== small helpers
def _line_col(data: bytes | memoryview, pos: int) -> str:
    """``"byte 123 (line 4, column 7)"`` for an absolute offset."""
    raw = bytes(data[: max(pos, 0)]) if isinstance(data, memoryview) else data[: max(pos, 0)]
    line = raw.count(b"\n") + 1
    col = pos - (raw.rfind(b"\n") + 1) + 1
    return f"byte {pos} (line {line}, column {col})"


def _nearest_unwrap(raw: int, ref: int) -> int:
    """The unwrapped counter ``raw + k*2**31`` closest to ``ref``."""
    return raw + _M * round((ref - raw) / _M)


def _opt_int(value: Any) -> Any:
    if value is None:
        return pd.NA
    if isinstance(value, bool):
        return int(value)
    if isinstance(value, int):
        return value
    f = _to_float(value)
    if f is None or not np.isfinite(f) or f != int(f):
        return pd.NA
    return int(f)


# ====================================================================== file access
@dataclass
class _Source:
    """One JSON document of a run: its bytes and where it came from."""

    name: str  # file name (for chain resolution) or zip member name
    label: str  # what error messages show: path or "archive.zip:member.json"
    data: bytes
    salvaged_zip: bool = False


def _read_zip_member_salvage(raw: bytes, label: str) -> tuple[str, bytes] | None:
    """Inflate the first local file entry of a damaged zip as far as it goes."""
    pos = raw.find(b"PK\x03\x04")
    if pos < 0 or pos + 30 > len(raw):
        return None
    import struct

    (_, _, _, method, _, _, _, _, _, n_name, n_extra) = struct.unpack(
        "<IHHHHHIIIHH", raw[pos : pos + 30]
    )
    name = raw[pos + 30 : pos + 30 + n_name].decode("utf-8", "replace")
    start = pos + 30 + n_name + n_extra
    body = raw[start:]
    if method == 0:
        return name, body
    if method != 8:
        return None
    d = zlib.decompressobj(-15)
    out = bytearray()
    step = 1 << 20
    for i in range(0, len(body), step):
        try:
            out += d.decompress(body[i : i + step])
        except zlib.error:
            break
        if d.eof:
            break
    return name, bytes(out)


class _Opener:
    """Resolves file names of a chain in a directory or inside one zip archive.

    With ``data`` the document (or zip archive) is already in memory and ``label`` names it;
    chained files are then found only inside that archive.
    """

    def __init__(self, path: Path, *, salvage: bool, issues: list[str],
                 data: bytes | None = None, label: str | None = None) -> None:
        self.path = path
        self.label = str(path) if label is None else label
        self.data = data
        self.salvage = salvage
        self.issues = issues
        self.zip: zipfile.ZipFile | None = None
        self.zip_salvaged: _Source | None = None
        is_zip = data[:2] == b"PK" if data is not None else path.suffix.lower() == ".zip"
        if is_zip:
            try:
                self.zip = zipfile.ZipFile(path if data is None else io.BytesIO(data))
            except (zipfile.BadZipFile, OSError) as exc:
                if not salvage:
                    raise TruncatedFileError(
                        f"broken zip archive ({exc}); re-download the file, or read it with "
                        "salvage=True to recover what can be inflated",
                        path=self.label,
                    ) from exc
                raw = path.read_bytes() if data is None else data
                got = _read_zip_member_salvage(raw, self.label)
                if got is None:
                    raise TruncatedFileError(
                        f"broken zip archive ({exc}) and no entry could be recovered",
                        path=self.label,
                    ) from exc
                name, member = got
                self.issues.append(
                    f"broken zip archive ({exc}); inflated {len(member)} bytes of entry "
                    f"{name!r} directly from its local header"
                )
                self.zip_salvaged = _Source(Path(name).name, f"{self.label}:{name}", member, True)

    def members(self) -> list[str]:
        if self.zip is None:
            return []
        return [i.filename for i in self.zip.infolist() if i.filename.lower().endswith(".json")]

    def first(self) -> _Source:
        if self.zip_salvaged is not None:
            return self.zip_salvaged
        if self.zip is None:
            data = self.path.read_bytes() if self.data is None else self.data
            return _Source(self.path.name, self.label, data)
        members = self.members()
        if not members:
            raise FormatError(
                "zip archive holds no .json file; expected a Capture4Analysis JSON inside",
                path=self.label,
            )
        start = members[0]
        if len(members) > 1:
            # the chain starts at the member whose footer has no Previous inside this archive
            base = {Path(m).name: m for m in members}
            prev_re = re.compile(rb'"Previous"\s*:\s*(null|"((?:[^"\\]|\\.)*)")')
            starts = []
            for m in members:
                tail = self._read_member(m)[-4096:]
                hit = prev_re.search(tail)
                prev = None if hit is None or hit.group(2) is None else hit.group(2).decode()
                if prev is None or Path(prev).name not in base:
                    starts.append(m)
            if starts:
                start = starts[0]
            if len(starts) > 1:
                self.issues.append(
                    f"zip archive holds {len(starts)} chain starts ({', '.join(starts)}); "
                    f"read the run starting at {start!r} only"
                )
        return _Source(Path(start).name, f"{self.label}:{start}", self._read_member(start))

    def _read_member(self, member: str) -> bytes:
        assert self.zip is not None
        try:
            return self.zip.read(member)
        except (zipfile.BadZipFile, zlib.error, OSError, EOFError) as exc:
            raise TruncatedFileError(
                f"broken zip entry {member!r} ({exc}); re-download the archive",
                path=self.label,
            ) from exc

    def next(self, name: str) -> _Source | None:
        """The chained file ``name`` (same zip or same directory), or None if absent."""
        bare = Path(name.replace("\\", "/")).name
        if self.zip is not None:
            for m in self.members():
                if Path(m).name == bare:
                    return _Source(bare, f"{self.label}:{m}", self._read_member(m))
            return None
        if self.zip_salvaged is not None or self.data is not None:
            return None
        folder = self.path.parent
        for cand in (folder / bare, folder / (bare + ".zip"), folder / (Path(bare).stem + ".zip")):
            if cand.is_file():
                if cand.suffix.lower() == ".zip":
                    sub = _Opener(cand, salvage=self.salvage, issues=self.issues)
                    src = sub.first()
                    return src
                return _Source(cand.name, str(cand), cand.read_bytes())
        return None

    def close(self) -> None:
        if self.zip is not None:
            self.zip.close()


# ====================================================================== one file
@dataclass
class _Columns:
    """How the HF rows of one file map to recording columns."""

    names: list[str]  # recording column names (CODE|AXIS), without CYCLE
    cycle_index: int
    value_index: list[int]  # row index of each name
    width: int  # row length declared by the header
    declared_string: list[str]


@dataclass
class _FilePart:
    """What one file contributed, before concatenation."""

    label: str
    header: dict[str, Any]
    footer: dict[str, Any] | None
    columns: _Columns | None
    cycles: NDArray[np.int64]
    values: NDArray[np.float64]  # shape (n_columns, n_rows)
    anchors: list[tuple[int, str]]
    events: list[dict[str, Any]]
    lf: list[dict[str, Any]]
    other: dict[str, list[Any]] = field(default_factory=dict)


class _Reader:
    """State shared across the files of one chain."""

    def __init__(self, *, axis_map: dict[int, str] | None, salvage: bool) -> None:
        self.explicit_map = axis_map is not None
        self.axis_map = dict(DEFAULT_AXIS_MAP if axis_map is None else axis_map)
        self.salvage = salvage
        self.issues: list[str] = []
        self.partial = False
        self.ref: int | None = None  # last unwrapped counter, for nearest-wrap unwrapping
        self.seen_axes: dict[int, str] = {}
        self.string_conversions: dict[str, int] = {}
        self.nulls: dict[str, int] = {}

    # ------------------------------------------------------------------ counters
    def unwrap_one(self, raw: int) -> int:
        value = raw if self.ref is None else _nearest_unwrap(raw, self.ref)
        self.ref = value
        return value

    def unwrap_block(self, raw: NDArray[np.int64]) -> NDArray[np.int64]:
        if raw.size == 0:
            return raw
        first = self.unwrap_one(int(raw[0]))
        step = np.diff(raw)
        fix = np.zeros(raw.size, dtype=np.int64)
        if step.size and (step.min() < -(_M // 2) or step.max() > _M // 2):
            k = (step < -(_M // 2)).astype(np.int64) - (step > _M // 2).astype(np.int64)
            fix[1:] = np.cumsum(k) * _M
        out = raw - raw[0] + first + fix
        self.ref = int(out[-1])
        return out

    # ------------------------------------------------------------------ header
    def columns_of(self, header: dict[str, Any], label: str) -> _Columns | None:
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
                if self.salvage and isinstance(sig.get("Name"), str):
                    address = sig["Name"]
                    self.issues.append(f"{label}: {pos} has no Address; used its Name {address!r}")
                    self.partial = True
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
            name = self._column_name(address, sig.get("Axis"), label, pos)
            if name in used:
                self.issues.append(
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
        return _Columns(names, cycle_index, value_index, len(signals), declared_string)

    def _column_name(self, address: str, axis_field: Any, label: str, pos: str) -> str:
        code, suffix = parse_column(address)
        if suffix is None:
            return address
        axis = axis_field.strip() if isinstance(axis_field, str) else ""
        if not suffix.isdigit():
            return address  # already CODE|AXIS
        number = int(suffix)
        if axis:
            if self.explicit_map and number in self.axis_map and self.axis_map[number] != axis:
                self.issues.append(
                    f"{label}: {pos} {address}: header Axis {axis!r} differs from axis_map "
                    f"{self.axis_map[number]!r}; kept the header's"
                )
            self.seen_axes.setdefault(number, axis)
            return f"{code}|{axis}"
        if number in self.axis_map:
            axis = self.axis_map[number]
            self.issues.append(
                f"{label}: {pos} {address}: empty Axis field repaired to {axis!r} from the axis map"
            )
            self.seen_axes.setdefault(number, axis)
            return f"{code}|{axis}"
        self.issues.append(
            f"{label}: {pos} {address}: empty Axis field and axis number {number} not in the "
            f"axis map {self.axis_map}; column kept as {address!r} (pass axis_map= to name it)"
        )
        return address

    # ------------------------------------------------------------------ HF rows
    def hf_rows_slow(
        self, rows: Any, cols: _Columns, label: str, where: str
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
                if not self.salvage:
                    raise FormatError(msg + "; read with salvage=True to drop such rows",
                                      path=label, position=pos)
                self.issues.append(f"{label}: {pos}: {msg}; row dropped")
                self.partial = True
                keep[r] = False
                continue
            for j, v in enumerate(row):
                if isinstance(v, (int, float)) and not isinstance(v, bool):
                    out[r, j] = v
                    continue
                name = all_names[j] or f"column {j}"
                if v is None and j != cols.cycle_index:
                    self.nulls[name] = self.nulls.get(name, 0) + 1
                    continue
                f = _to_float(v) if isinstance(v, str) else None
                if f is not None:
                    out[r, j] = f
                    self.string_conversions[name] = self.string_conversions.get(name, 0) + 1
                    continue
                msg = (f"value {v!r} where a number is required")
                if not self.salvage or j == cols.cycle_index:
                    raise FormatError(
                        msg + ("; read with salvage=True to keep it as NaN"
                               if j != cols.cycle_index else ""),
                        path=label, position=f"{pos}[{j}]", field=name,
                    )
                self.issues.append(f"{label}: {pos}[{j}] ({name}): {msg}; kept as NaN")
                self.partial = True
        return out if keep.all() else out[keep]

    # ------------------------------------------------------------------ one document
    def read_file(self, src: _Source) -> _FilePart:
        data = src.data
        label = src.label
        scan = scan_document(data)
        if scan.error:
            raise FormatError(
                f"not valid JSON: {ERROR_TEXT.get(scan.error, 'structure error')}",
                path=label, position=_line_col(data, scan.error_pos),
            )
        mv = memoryview(data)
        truncated = not scan.complete
        if truncated:
            where = _line_col(data, len(data))
            open_key = "the top-level object"
            if len(scan.members) and scan.members[-1, 3] < 0:
                k0, k1 = int(scan.members[-1, 0]), int(scan.members[-1, 1])
                open_key = bytes(mv[k0:k1]).decode("utf-8", "replace")
            where += f" inside {open_key}"
            if not self.salvage:
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
            _, v0, v1 = members["Header"]
            try:
                header = orjson.loads(mv[v0:v1])
            except orjson.JSONDecodeError as exc:
                raise FormatError(
                    f"Header is not valid JSON ({exc.msg})",
                    path=label, position=_line_col(data, v0 + exc.pos),
                ) from exc
            if not isinstance(header, dict):
                raise FormatError("Header is not an object", path=label, position="Header")
        else:
            raise (TruncatedFileError if "Header" in members else FormatError)(
                "no complete Header object; this is not a usable Capture4Analysis file "
                "(Header with SignalListHFData is written first)",
                path=label, position="Header",
            )
        cols = self.columns_of(header, label)
        if cols is None:
            self.issues.append(
                f"{label}: no SignalListHFData in the header (LF-only job); HF table is empty"
            )
        footer: dict[str, Any] | None = None
        if "Footer" in members and members["Footer"][2] >= 0:
            _, v0, v1 = members["Footer"]
            try:
                footer = orjson.loads(mv[v0:v1])
            except orjson.JSONDecodeError as exc:
                raise FormatError(
                    f"Footer is not valid JSON ({exc.msg})",
                    path=label, position=_line_col(data, v0 + exc.pos),
                ) from exc

        payload_member = members.get("Payload", (-1, -1, -1))[0]
        if payload_member < 0:
            if truncated:
                self.issues.append(f"{label}: truncated before the Payload; no data kept")
            else:
                raise FormatError("no Payload array", path=label, position="Payload")
        elements = scan.elements[scan.elements[:, 0] == payload_member] if payload_member >= 0 \
            else scan.elements[:0]

        # preallocate the HF block (columns x rows) from the scanner's row count
        n_cols = len(cols.names) if cols else 0
        upper = int(elements[:, 3].sum()) if cols else 0
        values = np.empty((n_cols, upper), dtype=np.float64)
        cycles = np.empty(upper, dtype=np.int64)
        n_rows = 0
        anchors: list[tuple[int, str]] = []
        events: list[dict[str, Any]] = []
        lf: list[dict[str, Any]] = []
        other: dict[str, list[Any]] = {}
        perm = [cols.cycle_index, *cols.value_index] if cols else []

        def add_rows(block: NDArray[np.float64], where: str) -> None:
            nonlocal values, cycles, n_rows
            if cols is None:
                raise FormatError(
                    "HFData present but the header has no SignalListHFData to map it",
                    path=label, position=where,
                )
            n = block.shape[0]
            if n == 0:
                return
            if n_rows + n > values.shape[1]:  # scanner count was low (odd input): grow
                grow = max(n_rows + n, 2 * values.shape[1])
                values = np.concatenate(
                    [values[:, :n_rows], np.empty((n_cols, grow - n_rows))], axis=1)
                cycles = np.concatenate([cycles[:n_rows], np.empty(grow - n_rows, np.int64)])
            raw_c = block[:, perm[0]]
            c_int = raw_c.astype(np.int64)
            if not np.array_equal(c_int, raw_c):
                bad = int(np.flatnonzero(c_int != raw_c)[0])
                raise FormatError(
                    f"CYCLE value {raw_c[bad]!r} is not an integer",
                    path=label, position=f"{where}[{bad}][{perm[0]}]", field="CYCLE",
                )
            cycles[n_rows : n_rows + n] = self.unwrap_block(c_int)
            values[:, n_rows : n_rows + n] = block[:, perm[1:]].T
            n_rows += n

        def handle(key: str, value: Any, where: str) -> None:
            if key == "HFData":
                if cols is None:
                    raise FormatError(
                        "HFData present but the header has no SignalListHFData to map it",
                        path=label, position=where,
                    )
                add_rows(self.hf_rows_slow(value, cols, label, where), where)
            elif key == "HFTimestamp":
                if not isinstance(value, dict) or "HFProbeCounter" not in value or \
                        "Time" not in value:
                    self._bad(label, where, "HFTimestamp needs HFProbeCounter and Time")
                    return
                c = _opt_int(value["HFProbeCounter"])
                if c is pd.NA:
                    self._bad(label, where, f"HFProbeCounter {value['HFProbeCounter']!r} is not "
                              "an integer", fld="HFProbeCounter")
                    return
                anchors.append((self.unwrap_one(int(c)), str(value["Time"])))
            elif key in ("HFBlockEvent", "HFCallEvent"):
                if not isinstance(value, dict):
                    self._bad(label, where, f"{key} is not an object")
                    return
                c = _opt_int(value.get("HFProbeCounter"))
                if c is pd.NA:
                    self._bad(label, where, f"{key} has no integer HFProbeCounter",
                              fld="HFProbeCounter")
                    return
                ev = dict(value)
                ev["__kind"] = "block" if key == "HFBlockEvent" else "call"
                ev["__cycle"] = self.unwrap_one(int(c))
                ev["__where"] = where
                events.append(ev)
            elif key == "LFData":
                items = value if isinstance(value, list) else [value]
                for k, item in enumerate(items):
                    if not isinstance(item, dict):
                        self._bad(label, f"{where}[{k}]", "LF entry is not an object")
                        continue
                    c = _opt_int(item.get("HFProbeCounter"))
                    if c is pd.NA:
                        self._bad(label, f"{where}[{k}]", "LF entry has no integer "
                                  "HFProbeCounter", fld="HFProbeCounter")
                        continue
                    entry = dict(item)
                    entry["__cycle"] = self.unwrap_one(int(c))
                    lf.append(entry)
            else:
                other.setdefault(key, []).append(value)

        for e_idx, (_, s, e, _rows, flags) in enumerate(elements.tolist()):
            where = f"Payload[{e_idx}]"
            try:
                obj = orjson.loads(mv[s:e])
            except orjson.JSONDecodeError as exc:
                if not self.salvage:
                    raise FormatError(
                        f"payload entry is not valid JSON ({exc.msg})",
                        path=label, position=f"{where}, {_line_col(data, s + exc.pos)}",
                    ) from exc
                self.issues.append(
                    f"{label}: {where} ({_line_col(data, s + exc.pos)}) is not valid JSON "
                    f"({exc.msg}); entry dropped"
                )
                self.partial = True
                continue
            if not isinstance(obj, dict):
                self._bad(label, where, "payload entry is not an object")
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
                    add_rows(block, f"{where}.HFData")
                    continue
                if block is not None and block.size == 0 and isinstance(rows, list):
                    continue
            for key, value in obj.items():
                handle(key, value, f"{where}.{key}")

        if truncated and scan.open_element_start >= 0 and \
                scan.open_element_member == payload_member:
            tail = bytes(mv[scan.open_element_start:])
            got = close_partial(tail)
            lost = len(tail)
            where = f"Payload[{len(elements)}]"
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
                    handle(key, value, f"{where}.{key}")
                kept = (f"recovered the complete part of the last entry {where}"
                        f"{f' (dropped {cut_rows} cut-off row)' if cut_rows else ''}")
            else:
                kept = f"the last, incomplete entry {where} could not be recovered"
            self.issues.append(
                f"{label}: truncated at {_line_col(data, len(data))}; kept "
                f"{len(elements)} complete payload entries, {kept}; lost the last {lost} bytes "
                "and everything after them (no Footer)"
            )
            self.partial = True
        elif truncated:
            self.issues.append(
                f"{label}: truncated at {_line_col(data, len(data))} after the Payload; "
                "Footer lost"
            )
            self.partial = True

        if n_rows < values.shape[1]:
            values = values[:, :n_rows].copy()
            cycles = cycles[:n_rows].copy()
        return _FilePart(label, header, footer, cols, cycles, values, anchors, events, lf, other)

    def _bad(self, label: str, where: str, msg: str, *, fld: str | None = None) -> None:
        if not self.salvage:
            raise FormatError(msg + "; read with salvage=True to skip it",
                              path=label, position=where, field=fld)
        self.issues.append(f"{label}: {where}: {msg}; entry skipped")
        self.partial = True


# ====================================================================== assembly
def _parse_job_description(items: Any, issues: list[str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    if not isinstance(items, list):
        return out
    for k, s in enumerate(items):
        if not isinstance(s, str):
            out[f"item{k}"] = s
            continue
        try:
            part = json.loads("{" + s + "}")
        except json.JSONDecodeError:
            issues.append(f"Header.JobDescription[{k}] is not a JSON fragment; kept as text")
            out[f"item{k}"] = s
            continue
        out.update(part)
    return out


def _events_frame(events: list[dict[str, Any]], issues: list[str]) -> pd.DataFrame:
    cols: dict[str, list[Any]] = {c: [] for c in (*EVENT_COLUMNS, *_EXTRA_EVENT_COLUMNS)}
    unknown: dict[str, list[Any]] = {}
    for i, ev in enumerate(events):
        kind = ev["__kind"]
        mapping = _BLOCK_FIELDS if kind == "block" else _CALL_FIELDS
        row: dict[str, Any] = {"cycle": ev["__cycle"], "kind": kind}
        for key, value in ev.items():
            if key.startswith("__") or key == "HFProbeCounter":
                continue
            col = mapping.get(key)
            if col is None:
                unknown.setdefault(key, [None] * i).append(value)
                continue
            row[col] = value
        for lst in unknown.values():
            if len(lst) < i + 1:
                lst.extend([None] * (i + 1 - len(lst)))
        for c, lst in cols.items():
            lst.append(row.get(c))
    if unknown:
        issues.append(
            f"event fields not in the event schema kept as extra columns: {', '.join(unknown)}"
        )
    frame: dict[str, Any] = {}
    for c, lst in cols.items():
        if c == "cycle":
            frame[c] = pd.Series(lst, dtype="int64")
        elif c in _INT_EVENT_COLUMNS:
            frame[c] = pd.Series([_opt_int(v) for v in lst], dtype="Int64")
        else:
            frame[c] = pd.Series(lst, dtype="object")
    for key, lst in unknown.items():
        frame[key] = pd.Series(lst + [None] * (len(events) - len(lst)), dtype="object")
    df = pd.DataFrame(frame)
    if len(df):
        df = df.sort_values("cycle", kind="stable").reset_index(drop=True)
    return df


def _lf_frame(
    lf: list[dict[str, Any]], anchors: list[tuple[int, pd.Timestamp]], cycle_time_s: float,
    issues: list[str], attrs: dict[str, Any], gaps: list[CounterGap],
) -> pd.DataFrame:
    if not lf:
        return empty_lf()
    order = sorted(range(len(lf)), key=lambda i: lf[i]["__cycle"])
    lf = [lf[i] for i in order]
    cycles = np.array([e["__cycle"] for e in lf], dtype=np.int64)
    values = np.full(len(lf), np.nan)
    texts: list[Any] = []
    n_str = n_text = 0
    types: dict[str, str] = {}
    for i, e in enumerate(lf):
        v = e.get("value")
        if isinstance(v, str):
            n_str += 1
            f = _to_float(v)
            texts.append(v)
        else:
            f = _to_float(v)
            texts.append(None if v is None else str(v))
        if f is None:
            n_text += 1
        else:
            values[i] = f
        addr = str(e.get("address", ""))
        if "value_type" in e:
            types.setdefault(addr, str(e["value_type"]))
    time = cycles_to_time(cycles, anchors, cycle_time_s=cycle_time_s, gaps=gaps)
    df = pd.DataFrame({
        "cycle": cycles,
        "time": pd.Series(time, dtype="datetime64[ns, UTC]"),
        "signal": pd.Series([str(e.get("address", "")) for e in lf], dtype="object"),
        "value": values,
        "text": pd.Series(texts, dtype="object"),
    })
    if n_str:
        issues.append(
            f"LF values arrive as JSON strings: {n_str - n_text} of {len(lf)} converted to float, "
            f"{n_text} non-numeric kept as text only (value NaN)"
        )
    attrs["lf_value_types"] = types
    wall = [e.get("timestamp") for e in lf]
    attrs["lf_wall_clock"] = wall
    stamps = [w for w in wall if isinstance(w, str)]
    if stamps and anchors:
        try:
            lf_ns = _parse_times(stamps).asi8
        except (ValueError, TypeError):
            issues.append("LF timestamps could not be parsed; kept as text in attrs")
        else:
            hf_ns = np.asarray(time.asi8)[[i for i, w in enumerate(wall) if isinstance(w, str)]]
            offset_s = float(np.median(lf_ns - hf_ns)) / 1e9
            attrs["lf_wall_clock_offset_s"] = offset_s
            issues.append(
                f"LF values aligned by HFProbeCounter; their own wall-clock timestamps differ "
                f"from the HF clock by {offset_s:+.3f} s (median; kept in "
                "meta.attrs['lf_wall_clock'])"
            )
    return df


def _drop_repeated_boundary_event(
    prev: list[dict[str, Any]], nxt: list[dict[str, Any]], label: str, issues: list[str]
) -> None:
    last_prev = next((e for e in reversed(prev) if e["__kind"] == "block"), None)
    first_next = next((i for i, e in enumerate(nxt) if e["__kind"] == "block"), None)
    if last_prev is None or first_next is None:
        return

    def core(e: dict[str, Any]) -> dict[str, Any]:
        return {k: v for k, v in e.items() if k not in ("__where",)}

    if core(last_prev) == core(nxt[first_next]):
        ev = nxt.pop(first_next)
        issues.append(
            f"{label}: removed the repeated block event at cycle {ev['__cycle']} "
            f"({ev.get('GCode')!r}) at the start of the file (Siemens repeats the last block "
            "event of the previous file)"
        )


def _assemble(parts: list[_FilePart], reader: _Reader, files: list[str]) -> Recording:
    issues = reader.issues
    first = parts[0]
    header = first.header
    attrs: dict[str, Any] = {}
    cycle_ms = header.get("CycleTimeMs", 2)
    cycle_f = _to_float(cycle_ms)
    if cycle_f is None or cycle_f <= 0:
        issues.append(f"Header.CycleTimeMs {cycle_ms!r} unusable; assumed 2 ms")
        cycle_f = 2.0
    cycle_time_s = cycle_f / 1000.0
    machine_info = header.get("MachineInfo") or {}
    machine = str(machine_info.get("MachineName", "")) if isinstance(machine_info, dict) else ""
    attrs["version"] = header.get("Version")
    attrs["format"] = header.get("Format")
    attrs["description"] = header.get("Description")
    attrs["machine_info"] = machine_info
    attrs["job_description"] = _parse_job_description(header.get("JobDescription"), issues)
    attrs["header_timestamp"] = header.get("TimeStamp")
    attrs["initial"] = header.get("Initial")
    attrs["signal_list_hf"] = header.get("SignalListHFData")
    attrs["signal_list_lf"] = header.get("SignalListLFData")
    attrs["signal_list_external"] = header.get("SignalListExternalData")
    attrs["header_metadata"] = header.get("Metadata")
    known_header = {
        "Version", "Format", "Description", "MachineInfo", "JobDescription", "SignalListHFData",
        "SignalListLFData", "SignalListExternalData", "TimeStamp", "CycleTimeMs", "Initial",
        "Metadata",
    }
    extra_header = {k: v for k, v in header.items() if k not in known_header}
    if extra_header:
        attrs["header_other"] = extra_header
        issues.append(f"header fields not interpreted, kept in meta.attrs['header_other']: "
                      f"{', '.join(extra_header)}")
    attrs["footers"] = [p.footer for p in parts]
    for p in parts:
        errs = (p.footer or {}).get("ErrorMessages")
        if errs:
            issues.append(f"{p.label}: recorder reported errors in the Footer: {errs}")
    other: dict[str, list[Any]] = {}
    for p in parts:
        for k, v in p.other.items():
            other.setdefault(k, []).extend(v)
    if other:
        attrs["payload_other"] = other
        for k, v in other.items():
            issues.append(
                f"payload key {k!r} ({len(v)} entries) not interpreted; kept in "
                f"meta.attrs['payload_other'][{k!r}]"
            )

    # anchors: Initial first, then HFTimestamps in arrival order
    raw_anchors: list[tuple[int, str]] = []
    initial = header.get("Initial")
    if isinstance(initial, dict) and "HFProbeCounter" in initial and "Time" in initial:
        c0 = _opt_int(initial["HFProbeCounter"])
        if c0 is not pd.NA:
            ref = int(first.cycles[0]) if first.cycles.size else int(c0)
            raw_anchors.append((_nearest_unwrap(int(c0), ref), str(initial["Time"])))
    for p in parts:
        raw_anchors.extend(p.anchors)
    anchors: list[tuple[int, pd.Timestamp]] = []
    if raw_anchors:
        try:
            times = _parse_times([t for _, t in raw_anchors])
        except (ValueError, TypeError) as exc:
            issues.append(f"time anchors could not be parsed ({exc}); times start at the epoch")
        else:
            anchors = [(c, t) for (c, _), t in zip(raw_anchors, times, strict=True)]
    else:
        issues.append("no Initial/HFTimestamp time anchors; times start at the Unix epoch")
    if len(anchors) > 1:
        step_ns = round(cycle_time_s * 1e9)
        a_c = np.array([a[0] for a in anchors], dtype=np.int64)
        a_ns = np.array([a[1].value for a in anchors], dtype=np.int64)
        off = a_ns - (a_c - a_c[0]) * step_ns
        spread_ms = float(off.max() - off.min()) / 1e6
        attrs["anchor_spread_ms"] = spread_ms
        if spread_ms > 50.0:
            med = np.median(off)
            far = np.abs(off - med) > 25e6
            issues.append(
                f"time anchors disagree with the cycle counter by up to {spread_ms / 1e3:.3f} s: "
                f"{int(far.sum())} of {len(anchors)} anchors (cycles {int(a_c[far].min())}.."
                f"{int(a_c[far].max())}) are off the median by "
                f"{float(np.median(off[far] - med)) / 1e9:+.3f} s; sections between "
                "counter gaps are timed by their own anchors where time stays monotonic, else the "
                "counter with the median offset is the clock (wall clock stepped, or the counter "
                "jumped)"
            )

    # HF: columns in the first file's order; later files mapped by name
    names: list[str] = []
    for p in parts:
        if p.columns is not None:
            for n in p.columns.names:
                if n not in names:
                    names.append(n)
    cyc_parts = []
    val_parts = []
    for p in parts:
        if p.columns is None or p.cycles.size == 0:
            continue
        if p.columns.names == names:
            val_parts.append(p.values)
        else:
            block = np.full((len(names), p.cycles.size), np.nan)
            pos = {n: i for i, n in enumerate(p.columns.names)}
            missing = [n for n in names if n not in pos]
            for i, n in enumerate(names):
                if n in pos:
                    block[i] = p.values[pos[n]]
            if missing:
                issues.append(f"{p.label}: columns {', '.join(missing)} absent; NaN there")
            val_parts.append(block)
        cyc_parts.append(p.cycles)
    if cyc_parts:
        cycles = cyc_parts[0] if len(cyc_parts) == 1 else np.concatenate(cyc_parts)
        values = val_parts[0] if len(val_parts) == 1 else np.concatenate(val_parts, axis=1)
    else:
        cycles = np.empty(0, dtype=np.int64)
        values = np.empty((len(names), 0))
    for p in parts:  # free memory early
        p.values = np.empty((0, 0))
    if cycles.size > 1 and not bool(np.all(np.diff(cycles) > 0)):
        order = np.argsort(cycles, kind="stable")
        n_moved = int(np.count_nonzero(order != np.arange(order.size)))
        cycles = cycles[order]
        values = values[:, order]
        if n_moved:
            issues.append(f"HF rows arrived out of order; {n_moved} rows sorted by cycle")
        dup = np.flatnonzero(np.diff(cycles) == 0) + 1
        if dup.size:
            same = bool(np.array_equal(values[:, dup], values[:, dup - 1], equal_nan=True))
            keep = np.ones(cycles.size, dtype=bool)
            keep[dup] = False
            issues.append(
                f"{dup.size} duplicate HF rows (same cycle, e.g. {int(cycles[dup[0]])}, "
                f"{'identical' if same else 'DIFFERENT'} values): kept the first arrival"
            )
            cycles = cycles[keep]
            values = values[:, keep]
    gaps = find_gaps(cycles)
    for g in gaps:
        issues.append(
            f"cycle counter gap: {g.missing} cycles missing between {g.after_cycle} and "
            f"{g.before_cycle} ({g.missing * cycle_time_s:.3f} s)"
        )
    wraps = int(cycles[-1] // _M - cycles[0] // _M) if cycles.size else 0
    if wraps:
        issues.append(f"cycle counter wrapped {wraps} time(s) at 2**31; unwrapped")
    if reader.string_conversions:
        total = sum(reader.string_conversions.values())
        declared = [n for p in parts if p.columns for n in p.columns.declared_string]
        issues.append(
            f"{total} HF values given as strings converted to float (columns "
            f"{', '.join(sorted(reader.string_conversions))}"
            f"{'; declared STRING: ' + ', '.join(sorted(set(declared))) if declared else ''})"
        )
    if reader.nulls:
        issues.append(
            f"{sum(reader.nulls.values())} HF values were null, kept as NaN (columns "
            f"{', '.join(sorted(reader.nulls))})"
        )

    hf = pd.DataFrame(values.T, index=pd.Index(cycles, name="cycle"), columns=names, copy=False)
    hf.insert(
        0, "time", cycles_to_time(cycles, anchors, cycle_time_s=cycle_time_s, gaps=gaps)
    )

    # events (repeated boundary event dropped) and LF
    events: list[dict[str, Any]] = []
    for i_part, p in enumerate(parts):
        if i_part > 0:
            _drop_repeated_boundary_event(parts[i_part - 1].events, p.events, p.label, issues)
    for p in parts:
        events.extend(p.events)
    lf = [e for p in parts for e in p.lf]
    lf_df = _lf_frame(lf, anchors, cycle_time_s, issues, attrs, gaps)
    ev_df = _events_frame(events, issues)

    axis_map = dict(sorted(reader.seen_axes.items()))
    meta = RecordingMeta(
        machine=machine,
        cycle_time_s=cycle_time_s,
        axis_map=axis_map,
        source_files=files,
        source_format="capture4analysis",
        time_anchors=anchors,
        gaps=gaps,
        wraps=wraps,
        issues=issues,
        partial=reader.partial,
        attrs=attrs,
    )
    return Recording(hf, lf=lf_df, events=ev_df, meta=meta)


# ====================================================================== the chain
def _read_run(opener: _Opener, reader: _Reader, *, follow_chain: bool, stop_note: str
              ) -> Recording:
    """Read the first document of ``opener`` and, with ``follow_chain``, the files chained to it.

    ``stop_note`` says in ``meta.issues`` why a ``FilePathChain.Next`` was not followed.
    """
    try:
        src: _Source | None = opener.first()
        parts: list[_FilePart] = []
        files: list[str] = []
        visited: set[str] = set()
        while src is not None:
            visited.add(src.name)
            files.append(src.label)
            part = reader.read_file(src)
            src.data = b""
            parts.append(part)
            chain = (part.footer or {}).get("FilePathChain") or {}
            if len(parts) == 1 and isinstance(chain, dict) and chain.get("Previous"):
                reader.issues.append(
                    f"{part.label} continues a run (Previous {chain['Previous']!r}, Index "
                    f"{chain.get('Index')}); earlier files were not read"
                )
            nxt = chain.get("Next") if isinstance(chain, dict) else None
            if not nxt or not follow_chain:
                if nxt:
                    reader.issues.append(f"run continues in {nxt!r}; not read ({stop_note})")
                break
            if Path(str(nxt)).name in visited:
                reader.issues.append(f"file chain loops back to {nxt!r}; stopped there")
                break
            src = opener.next(str(nxt))
            if src is None:
                reader.issues.append(
                    f"run continues in {nxt!r}, which is not in the same "
                    f"{'zip' if opener.zip is not None else 'directory'}; recording is incomplete"
                )
                reader.partial = True
    finally:
        opener.close()
    return _assemble(parts, reader, files)


def _check_axis_map(axis_map: Any) -> None:
    if axis_map is not None and not isinstance(axis_map, dict):
        raise ConfigError("axis_map must be a dict {axis number: axis name}")


# ====================================================================== public reader
def parse_capture4analysis(
    data: bytes,
    *,
    source: str = "<bytes>",
    axis_map: dict[int, str] | None = None,
    salvage: bool = False,
) -> Recording:
    """Parse one Capture4Analysis / SINUMERIK Data Recorder document held in memory.

    Parameters
    ----------
    data : bytes
        The JSON document, or a zip archive holding it (``PK`` signature; Data Recorder MQTT
        messages may be zipped). Of an archive with several chained members the chain start
        is parsed.
    source : str, default ``"<bytes>"``
        Where the bytes came from (file name, MQTT topic); used in error messages,
        ``meta.issues`` and ``meta.source_files`` (``"<source>:<member>"`` for a zip).
    axis_map : dict, optional
        Axis number -> axis name for empty ``Axis`` fields; default
        :data:`cnctwin.signals.DEFAULT_AXIS_MAP`.
    salvage : bool, default False
        Keep what can be read from damaged input instead of raising (see
        :func:`read_capture4analysis`).

    Returns
    -------
    Recording
        What :func:`read_capture4analysis` returns for a file with these bytes and
        ``follow_chain=False``: a ``Footer.FilePathChain.Next`` is not followed, only noted in
        ``meta.issues``.

    Raises
    ------
    ConfigError
        ``data`` is not bytes (pass a path to :func:`read_capture4analysis` instead).
    FormatError
        Invalid JSON, missing Header, wrong value types; ``path`` is ``source``.
    TruncatedFileError
        The JSON ends early or the zip is broken (and ``salvage`` is False).

    Notes
    -----
    :func:`read_capture4analysis` parses each file of a chain with the same document parser;
    this entry point skips the file system, so a stream (MQTT message, HTTP body) needs no
    temporary file.
    """
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise ConfigError(
            f"data must be bytes, not {type(data).__name__}; to read a file pass its path to "
            "read_capture4analysis"
        )
    _check_axis_map(axis_map)
    reader = _Reader(axis_map=axis_map, salvage=salvage)
    opener = _Opener(Path(source), salvage=salvage, issues=reader.issues, data=bytes(data),
                     label=source)
    return _read_run(opener, reader, follow_chain=False,
                     stop_note="one document parsed; read_capture4analysis follows chains")


def read_capture4analysis(
    path: str | PathLike[str],
    *,
    axis_map: dict[int, str] | None = None,
    salvage: bool = False,
    follow_chain: bool = True,
) -> Recording:
    """Read a Capture4Analysis / SINUMERIK Data Recorder recording.

    Parameters
    ----------
    path : str or path-like
        A ``.json`` file or a ``.zip`` holding one or more chained JSON files.
    axis_map : dict, optional
        Axis number -> axis name used to repair empty ``Axis`` fields in the header; default
        :data:`cnctwin.signals.DEFAULT_AXIS_MAP` (``{1: "X1", ..., 6: "SP1"}``).
    salvage : bool, default False
        Keep what can be read from damaged input (truncated JSON, rows of the wrong length,
        non-numeric values, a broken zip) instead of raising; sets ``rec.meta.partial`` and
        describes what was lost in ``rec.meta.issues``.
    follow_chain : bool, default True
        Follow ``Footer.FilePathChain.Next`` to the following files of the run (same
        directory or same zip) and concatenate them.

    Returns
    -------
    Recording
        HF table indexed by the unwrapped cycle counter with ``CODE|AXIS`` columns, LF values,
        block/call events and metadata (header fields in ``meta.attrs``).

    Raises
    ------
    FormatError
        Invalid JSON, missing Header, wrong value types, rows of the wrong length; the message
        names the file and the position (byte offset or ``Payload[i].HFData[j]``).
    TruncatedFileError
        The JSON ends early or the zip is broken (and ``salvage`` is False).

    Notes
    -----
    Time of cycle :math:`c` is :math:`t = t_0 + (c - c_0)\\,T_c` with the cycle time
    :math:`T_c` = ``CycleTimeMs`` and :math:`t_0 - c_0 T_c` the median over the ``Initial`` and
    ``HFTimestamp`` anchors (:func:`cnctwin.recording.cycles_to_time`).

    The file is scanned once for its structure and each payload entry is parsed separately
    with orjson, so the Python objects of one entry at a time are alive; HF rows go straight
    into a preallocated column-major float64 array.
    """
    p = Path(path)
    if not p.is_file():
        raise FormatError("file not found", path=str(p))
    _check_axis_map(axis_map)
    reader = _Reader(axis_map=axis_map, salvage=salvage)
    opener = _Opener(p, salvage=salvage, issues=reader.issues)
    return _read_run(opener, reader, follow_chain=follow_chain, stop_note="follow_chain=False")

