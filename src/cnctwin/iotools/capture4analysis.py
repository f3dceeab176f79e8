"""Capture4Analysis / SINUMERIK Data Recorder JSON files: reader and writer.

The format (Siemens "Analyze MyWorkpiece /Capture4Analysis" and its successor "SINUMERIK Data
Recorder") is one JSON object per file, ``{"Header": ..., "Payload": [...], "Footer": ...}``,
optionally zipped, and a job run may span several files chained by
``Footer.FilePathChain`` (see ``/work/shared/reference/data-formats.md`` section 1).

* :func:`read_capture4analysis` reads a ``.json`` or ``.zip`` (one or more chained files) into a
  :class:`~cnctwin.recording.Recording`.
* :class:`Capture4AnalysisWriter` writes the same structure chunk by chunk and rolls files at a
  size limit; :func:`write_capture4analysis` writes a whole recording with it.

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

import json
import re
import zipfile
import zlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
import orjson
import pandas as pd
from numpy.typing import NDArray

from cnctwin.exceptions import ConfigError, FormatError, TruncatedFileError
from cnctwin.iotools._jsonscan import (
    ERROR_TEXT,
    FLAG_LITERAL,
    FLAG_STRING,
    close_partial,
    scan_document,
)
from cnctwin.recording import (
    CYCLE_COUNTER_MODULUS,
    EVENT_COLUMNS,
    CounterGap,
    Recording,
    RecordingMeta,
    cycles_to_time,
    find_gaps,
)
from cnctwin.signals import DEFAULT_AXIS_MAP, parse_column

__all__ = [
    "Capture4AnalysisWriter",
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


def _parse_times(values: Sequence[str]) -> pd.DatetimeIndex:
    idx = pd.DatetimeIndex(pd.to_datetime(list(values), utc=True, format="ISO8601"))
    return idx.as_unit("ns")


def _fmt_time(ts: pd.Timestamp) -> str:
    """ISO time with ``Z``, with the fewest sub-second digits (3, 6 or 9) that keep it exact."""
    ts = pd.Timestamp(ts)
    ts = ts.tz_localize("UTC") if ts.tzinfo is None else ts.tz_convert("UTC")
    ns = ts.value % 1_000_000_000
    base = ts.strftime("%Y-%m-%dT%H:%M:%S")
    if ns % 1_000_000 == 0:
        frac = f"{ns // 1_000_000:03d}"
    elif ns % 1000 == 0:
        frac = f"{ns // 1000:06d}"
    else:
        frac = f"{ns:09d}"
    return f"{base}.{frac}Z"


def _nearest_unwrap(raw: int, ref: int) -> int:
    """The unwrapped counter ``raw + k*2**31`` closest to ``ref``."""
    return raw + _M * round((ref - raw) / _M)


def _to_float(value: Any) -> float | None:
    """Float of a JSON scalar; ``None`` if it is not numeric."""
    if isinstance(value, bool):
        return None
    if isinstance(value, (int, float)):
        return float(value)
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            return None
    return None


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
    """Resolves file names of a chain in a directory or inside one zip archive."""

    def __init__(self, path: Path, *, salvage: bool, issues: list[str]) -> None:
        self.path = path
        self.salvage = salvage
        self.issues = issues
        self.zip: zipfile.ZipFile | None = None
        self.zip_salvaged: _Source | None = None
        if path.suffix.lower() == ".zip":
            try:
                self.zip = zipfile.ZipFile(path)
            except (zipfile.BadZipFile, OSError) as exc:
                if not salvage:
                    raise TruncatedFileError(
                        f"broken zip archive ({exc}); re-download the file, or read it with "
                        "salvage=True to recover what can be inflated",
                        path=str(path),
                    ) from exc
                got = _read_zip_member_salvage(path.read_bytes(), str(path))
                if got is None:
                    raise TruncatedFileError(
                        f"broken zip archive ({exc}) and no entry could be recovered",
                        path=str(path),
                    ) from exc
                name, data = got
                self.issues.append(
                    f"broken zip archive ({exc}); inflated {len(data)} bytes of entry {name!r} "
                    "directly from its local header"
                )
                self.zip_salvaged = _Source(Path(name).name, f"{path}:{name}", data, True)

    def members(self) -> list[str]:
        if self.zip is None:
            return []
        return [i.filename for i in self.zip.infolist() if i.filename.lower().endswith(".json")]

    def first(self) -> _Source:
        if self.zip_salvaged is not None:
            return self.zip_salvaged
        if self.zip is None:
            return _Source(self.path.name, str(self.path), self.path.read_bytes())
        members = self.members()
        if not members:
            raise FormatError(
                "zip archive holds no .json file; expected a Capture4Analysis JSON inside",
                path=str(self.path),
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
        return _Source(Path(start).name, f"{self.path}:{start}", self._read_member(start))

    def _read_member(self, member: str) -> bytes:
        assert self.zip is not None
        try:
            return self.zip.read(member)
        except (zipfile.BadZipFile, zlib.error, OSError, EOFError) as exc:
            raise TruncatedFileError(
                f"broken zip entry {member!r} ({exc}); re-download the archive",
                path=str(self.path),
            ) from exc

    def next(self, name: str) -> _Source | None:
        """The chained file ``name`` (same zip or same directory), or None if absent."""
        bare = Path(name.replace("\\", "/")).name
        if self.zip is not None:
            for m in self.members():
                if Path(m).name == bare:
                    return _Source(bare, f"{self.path}:{m}", self._read_member(m))
            return None
        if self.zip_salvaged is not None:
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
        return pd.DataFrame({
            "cycle": pd.Series(dtype="int64"),
            "time": pd.Series(dtype="datetime64[ns, UTC]"),
            "signal": pd.Series(dtype="object"),
            "value": pd.Series(dtype="float64"),
            "text": pd.Series(dtype="object"),
        })
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


# ====================================================================== public reader
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
    if axis_map is not None and not isinstance(axis_map, dict):
        raise ConfigError("axis_map must be a dict {axis number: axis name}")
    reader = _Reader(axis_map=axis_map, salvage=salvage)
    opener = _Opener(p, salvage=salvage, issues=reader.issues)
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
                    reader.issues.append(
                        f"run continues in {nxt!r}; not read (follow_chain=False)")
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


# ====================================================================== writer
def _axis_numbers(columns: Sequence[str], axis_map: dict[int, str] | None) -> dict[str, int]:
    """Axis name -> number: from ``axis_map`` where given, new numbers for the others."""
    inverse = {name: num for num, name in (axis_map or {}).items()}
    nxt = max(inverse.values(), default=0) + 1
    for col in columns:
        _, axis = parse_column(col)
        if axis is None or axis.isdigit() or axis in inverse:
            continue
        inverse[axis] = nxt
        nxt += 1
    return inverse


class Capture4AnalysisWriter:
    """Stream a recording into Capture4Analysis JSON files, rolling files at a size limit.

    Parameters
    ----------
    path : str or path-like
        First output file (``run.json``). With ``zip=True`` the archive (``run.zip``) whose
        members are ``run.json``, ``run_2.json``, ...; without, the next files are
        ``run_2.json``, ``run_3.json``, ... beside the first.
    columns : sequence of str
        HF columns ``CODE|AXIS`` in the order of the values passed to :meth:`write_hf`.
    axis_map : dict, optional
        Axis number -> name for the ``Address`` (``CURRENT|6``); axes not in it get new
        numbers after the largest one (1..n in axis order if not given).
    machine : str, optional
        ``Header.MachineInfo.MachineName``.
    cycle_time_s : float, default 0.002
        Position-control cycle time [s] (``CycleTimeMs``).
    initial : (int, Timestamp), optional
        ``Header.Initial`` anchor (cycle, UTC time); default: the first HF cycle at the epoch.
    max_file_mb : float, optional
        Start a new chained file before a file would exceed this size [MB = 1e6 bytes].
    zip : bool, default False
        Write all files into one zip archive at ``path``.
    lf_signals : sequence of str, optional
        LF addresses for ``Header.SignalListLFData``.
    job_description : dict, optional
        Written as ``Header.JobDescription`` fragments (``{"TriggersOn": {...}}``).
    chunk_rows : int, default 100
        HF rows per ``HFData`` payload entry.
    header_extra : dict, optional
        Further header fields (``Version``, ``MachineInfo`` ...) overriding the defaults.

    Notes
    -----
    The header is written first, payload entries as they come (``HFData`` chunks,
    ``HFTimestamp``, ``HFBlockEvent``, ``HFCallEvent``, ``LFData``), the footer with
    ``FilePathChain`` on :meth:`close`. At each file boundary the last block event is repeated
    at the start of the next file, as the Siemens recorder does. The raw counter is written
    modulo 2**31. Floats are written by orjson (shortest round-trip form, so float64 values
    read back bit-exact); NaN and infinity become ``null`` (read back as NaN).
    """

    def __init__(
        self,
        path: str | PathLike[str],
        *,
        columns: Sequence[str],
        axis_map: dict[int, str] | None = None,
        machine: str = "",
        cycle_time_s: float = 0.002,
        initial: tuple[int, pd.Timestamp] | None = None,
        max_file_mb: float | None = None,
        zip: bool = False,
        lf_signals: Sequence[str] = (),
        job_description: dict[str, Any] | None = None,
        chunk_rows: int = 100,
        header_extra: dict[str, Any] | None = None,
    ) -> None:
        if chunk_rows < 1:
            raise ConfigError(f"chunk_rows must be >= 1, not {chunk_rows}")
        if max_file_mb is not None and max_file_mb <= 0:
            raise ConfigError(f"max_file_mb must be positive, not {max_file_mb}")
        self.path = Path(path)
        self.columns = list(columns)
        self.zip = zip
        self.chunk_rows = int(chunk_rows)
        self.max_bytes = None if max_file_mb is None else int(max_file_mb * 1e6)
        numbers = _axis_numbers(self.columns, axis_map)
        signals = [{"Name": "CYCLE", "Type": "INTEGER", "Axis": "Cycle", "Address": "CYCLE"}]
        for col in self.columns:
            code, axis = parse_column(col)
            if axis is None or axis.isdigit():
                address, axis_name = col, ""
            else:
                address, axis_name = f"{code}|{numbers[axis]}", axis
            signals.append({"Name": address, "Type": "DOUBLE", "Axis": axis_name,
                            "Address": address})
        self.axis_numbers = numbers
        self._initial = initial
        header: dict[str, Any] = {
            "Version": {"outputFileFormatVersion": "1.0", "RecorderVersion": "cnctwin"},
            "Format": "DEFAULT",
            "Description": None,
            "MachineInfo": {"MachineName": machine, "CFCard": ""},
            "JobDescription": [
                orjson.dumps({k: v}).decode()[1:-1] for k, v in (job_description or {}).items()
            ],
            "SignalListHFData": signals,
            "SignalListExternalData": [],
            "SignalListLFData": [
                {"id": str(i), "device": a, "path": a, "label": "", "samplingPeriod": 500}
                for i, a in enumerate(lf_signals)
            ],
            "TimeStamp": None,
            "CycleTimeMs": round(cycle_time_s * 1000, 9),
            "Initial": None,
            "Metadata": [],
        }
        header.update(header_extra or {})
        self._header = header
        self._file_index = 0
        self._names: list[str] = []
        self._out: BinaryIO | None = None
        self._zip: zipfile.ZipFile | None = None
        self._size = 0
        self._n_in_file = 0
        self._last_block: bytes | None = None
        self._closed = False
        self.files: list[Path] = []

    # ------------------------------------------------------------------ files
    def _name(self, index: int) -> str:
        stem = self.path.stem
        if index == 1:
            return self.path.name if not self.zip else f"{stem}.json"
        return f"{stem}_{index}.json"

    def _open_next(self) -> None:
        self._file_index += 1
        name = self._name(self._file_index)
        self._names.append(name)
        if self.zip:
            if self._zip is None:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                self._zip = zipfile.ZipFile(self.path, "w", zipfile.ZIP_DEFLATED,
                                            compresslevel=1)
                self.files.append(self.path)
            self._out = self._zip.open(name, "w", force_zip64=True)  # type: ignore[assignment]
        else:
            target = self.path.parent / name
            target.parent.mkdir(parents=True, exist_ok=True)
            self._out = open(target, "wb")  # noqa: SIM115 - closed in _close_file
            self.files.append(target)
        head = b'{"Header":' + orjson.dumps(self._header_now(), option=orjson.OPT_INDENT_2) \
            + b',\n"Payload":[\n'
        self._write_raw(head)
        self._n_in_file = 0

    def _header_now(self) -> dict[str, Any]:
        h = dict(self._header)
        if h.get("Initial") is None and self._initial is not None:
            c, t = self._initial
            h["Initial"] = {"Time": _fmt_time(t), "HFProbeCounter": int(c) % _M}
        if h.get("TimeStamp") is None and self._initial is not None:
            h["TimeStamp"] = _fmt_time(self._initial[1])
        return h

    def _write_raw(self, data: bytes) -> None:
        assert self._out is not None
        self._out.write(data)
        self._size += len(data)

    def _close_file(self, next_name: str | None) -> None:
        assert self._out is not None
        footer = {
            "ErrorMessages": [],
            "FilePathChain": {
                "Previous": self._names[-2] if len(self._names) > 1 else None,
                "Actual": self._names[-1],
                "Next": next_name,
                "Index": self._file_index,
                "StreamIndex": None,
            },
        }
        self._write_raw(b'\n],\n"Footer":' + orjson.dumps(footer, option=orjson.OPT_INDENT_2)
                        + b"}")
        self._out.close()
        self._out = None
        self._size = 0

    def _emit(self, element: bytes) -> None:
        if self._closed:
            raise ConfigError("writer is closed")
        if self._out is None:
            if self._initial is None:
                raise ConfigError("set initial=(cycle, time) or write HF rows first")
            self._open_next()
        if (
            self.max_bytes is not None and self._n_in_file > 0
            and self._size + len(element) + 600 > self.max_bytes
        ):
            nxt = self._name(self._file_index + 1)
            self._close_file(nxt)
            self._open_next()
            if self._last_block is not None:
                self._write_raw(self._last_block)
                self._n_in_file += 1
        if self._n_in_file:
            self._write_raw(b",\n")
        self._write_raw(element)
        self._n_in_file += 1

    # ------------------------------------------------------------------ payload
    def write_hf(self, cycles: Any, values: Any) -> None:
        """Write HF rows.

        Parameters
        ----------
        cycles : array-like of int, shape (n,)
            Cycle counter (unwrapped or raw; written modulo 2**31).
        values : array-like of float, shape (n, n_columns)
            Values in the order of ``columns``.
        """
        c = np.asarray(cycles, dtype=np.int64)
        v = np.asarray(values, dtype=np.float64)
        if v.ndim != 2 or v.shape != (c.size, len(self.columns)):
            raise ConfigError(
                f"values must have shape ({c.size}, {len(self.columns)}), not {v.shape}"
            )
        if c.size == 0:
            return
        if self._initial is None:
            self._initial = (int(c[0]), pd.Timestamp(0, tz="UTC"))
        raw = (c % _M).tolist()
        for a in range(0, c.size, self.chunk_rows):
            b = min(a + self.chunk_rows, c.size)
            rows = v[a:b].tolist()
            for row, cyc in zip(rows, raw[a:b], strict=True):
                row.insert(0, cyc)
            self._emit(b'{"HFData":' + orjson.dumps(rows) + b"}")

    def write_timestamp(self, cycle: int, time: pd.Timestamp | str) -> None:
        """Write an ``HFTimestamp`` anchor (cycle, UTC time)."""
        self._emit(orjson.dumps({"HFTimestamp": {
            "Time": _fmt_time(pd.Timestamp(time)), "HFProbeCounter": int(cycle) % _M}}))

    def write_block_event(self, cycle: int, *, channel: int = 1, seek_offset: int = 0,
                          selected_tool: int | None = None, active_tool: int | None = None,
                          gcode: str = "", ipo_gcode: str | None = None,
                          ipo_read_error: Any = None, la_buf: int | None = None) -> None:
        """Write an ``HFBlockEvent`` (an NC block started at ``cycle``)."""
        element = orjson.dumps({"HFBlockEvent": {
            "HFProbeCounter": int(cycle) % _M, "Channel": channel, "SeekOffset": seek_offset,
            "SelectedTool": selected_tool, "ActiveTool": active_tool, "GCode": gcode,
            "IpoGC": ipo_gcode, "ipoReadError": ipo_read_error, "laBuf": la_buf}})
        self._emit(element)
        self._last_block = element

    def write_call_event(self, cycle: int, *, channel: int = 1, seek_offset: int = 0,
                         call_stack_level: int | None = None, path: str = "") -> None:
        """Write an ``HFCallEvent`` (a subprogram call at ``cycle``)."""
        self._emit(orjson.dumps({"HFCallEvent": {
            "HFProbeCounter": int(cycle) % _M, "Channel": channel, "SeekOffset": seek_offset,
            "CallStackLevel": call_stack_level, "Path": path}}))

    def write_lf(self, entries: Sequence[dict[str, Any]]) -> None:
        """Write one ``LFData`` entry.

        Parameters
        ----------
        entries : sequence of dict
            Each with ``cycle``, ``signal`` (address), ``value`` (float or str), optional
            ``time`` (wall clock; default epoch) and ``value_type``.
        """
        items = []
        for e in entries:
            v = e["value"]
            if isinstance(v, str):
                text = v
            elif v is None or (isinstance(v, float) and not np.isfinite(v)):
                text = ""
            else:
                text = repr(float(v)) if not isinstance(v, int) else str(v)
            t = e.get("time")
            items.append({
                "HFProbeCounter": int(e["cycle"]) % _M,
                "timestamp": t if isinstance(t, str) else _fmt_time(
                    pd.Timestamp(t) if t is not None else pd.Timestamp(0, tz="UTC")),
                "address": str(e["signal"]),
                "value_type": e.get("value_type") or ("Double" if _to_float(text) is not None
                                                      else "String"),
                "value": text,
            })
        if items:
            self._emit(orjson.dumps({"LFData": items}))

    def write_payload(self, key: str, value: Any) -> None:
        """Write any other payload entry (``ExternalData`` ...) as ``{key: value}``."""
        self._emit(orjson.dumps({key: value}, option=orjson.OPT_SERIALIZE_NUMPY))

    # ------------------------------------------------------------------ end
    def close(self) -> list[Path]:
        """Write the footer and close; returns the files written (the archive with zip)."""
        if self._closed:
            return self.files
        if self._out is None:
            if self._initial is None:
                self._initial = (0, pd.Timestamp(0, tz="UTC"))
            self._open_next()
        self._close_file(None)
        if self._zip is not None:
            self._zip.close()
        self._closed = True
        return self.files

    def __enter__(self) -> Capture4AnalysisWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _iter_events(events: pd.DataFrame) -> Iterator[tuple[int, dict[str, Any]]]:
    cols = set(events.columns)

    def val(row: dict[str, Any], name: str) -> Any:
        if name not in cols:
            return None
        v = row[name]
        if v is None or v is pd.NA or (isinstance(v, float) and np.isnan(v)):
            return None
        if isinstance(v, np.integer):
            return int(v)
        return v

    for row in events.to_dict("records"):
        rec = {str(k): v for k, v in row.items()}
        yield int(rec["cycle"]), {k: val(rec, k) for k in cols}


def write_capture4analysis(
    rec: Recording,
    path: str | PathLike[str],
    *,
    max_file_mb: float | None = None,
    zip: bool = False,
) -> list[Path]:
    """Write a recording as Capture4Analysis JSON (one file, a chain, or a zip).

    Parameters
    ----------
    rec : Recording
        The recording; HF columns ``CODE|AXIS`` become addresses ``CODE|n`` with the axis
        numbers of ``rec.meta.axis_map`` (1..n in axis order where it has none).
    path : str or path-like
        Output ``.json`` (or ``.zip`` with ``zip=True``).
    max_file_mb : float, optional
        Split into chained files of at most this size [MB]; the last block event of a file is
        repeated at the start of the next (Siemens behaviour).
    zip : bool, default False
        Write one zip archive holding the JSON file(s).

    Returns
    -------
    list of Path
        Files written.

    Notes
    -----
    ``meta.time_anchors[0]`` becomes ``Header.Initial`` and the other anchors ``HFTimestamp``
    entries, so reading the file back rebuilds the same time column. Payload entries are
    written in cycle order: each HF chunk, then the anchors, events and LF values up to its
    last cycle.
    """
    cols = rec.columns
    anchors = list(rec.meta.time_anchors)
    if not anchors and rec.n_cycles:
        anchors = [(int(rec.cycles[0]), pd.Timestamp(rec.hf["time"].iloc[0]))]
    attrs = rec.meta.attrs
    lf_signals = list(dict.fromkeys(rec.lf["signal"].astype(str).tolist())) if len(rec.lf) else []
    header_extra: dict[str, Any] = {}
    for key, attr in (("Version", "version"), ("Format", "format"),
                      ("MachineInfo", "machine_info")):
        if attrs.get(attr) is not None:
            header_extra[key] = attrs[attr]
    if isinstance(header_extra.get("MachineInfo"), dict):
        header_extra["MachineInfo"] = {**header_extra["MachineInfo"],
                                       "MachineName": rec.meta.machine}
    job = attrs.get("job_description") if isinstance(attrs.get("job_description"), dict) else None
    writer = Capture4AnalysisWriter(
        path, columns=cols, axis_map=rec.meta.axis_map or None, machine=rec.meta.machine,
        cycle_time_s=rec.meta.cycle_time_s, initial=anchors[0] if anchors else None,
        max_file_mb=max_file_mb, zip=zip, lf_signals=lf_signals, job_description=job,
        header_extra=header_extra,
    )
    cycles = rec.cycles
    values = rec.hf[cols].to_numpy(dtype=np.float64) if cols else np.empty((rec.n_cycles, 0))
    extra_anchors = anchors[1:]
    a_cyc = np.array([a[0] for a in extra_anchors], dtype=np.int64)
    ev = rec.events.sort_values("cycle", kind="stable") if len(rec.events) else rec.events
    ev_list = list(_iter_events(ev)) if len(ev) else []
    ev_cyc = np.array([c for c, _ in ev_list], dtype=np.int64)
    lf = rec.lf
    lf_cyc = lf["cycle"].to_numpy(dtype=np.int64) if len(lf) else np.empty(0, np.int64)
    lf_order = np.argsort(lf_cyc, kind="stable")
    wall = attrs.get("lf_wall_clock")
    wall_ok = isinstance(wall, list) and len(wall) == len(lf)
    offset_ns = round(float(attrs.get("lf_wall_clock_offset_s", 0.0)) * 1e9)
    lf_times = lf["time"] if len(lf) else None
    value_types = attrs.get("lf_value_types") or {}
    lf_sig = lf["signal"].astype(str).tolist() if len(lf) else []
    lf_text = lf["text"].tolist() if len(lf) else []
    lf_val = lf["value"].to_numpy(dtype=np.float64) if len(lf) else np.empty(0)
    ia = ie = il = 0

    def flush(upto: int | None) -> None:
        nonlocal ia, ie, il
        while ia < len(extra_anchors) and (upto is None or a_cyc[ia] <= upto):
            writer.write_timestamp(*extra_anchors[ia])
            ia += 1
        while ie < len(ev_list) and (upto is None or ev_cyc[ie] <= upto):
            c, e = ev_list[ie]
            if e.get("kind") == "call":
                writer.write_call_event(
                    c, channel=e.get("channel"), seek_offset=e.get("seek_offset"),  # type: ignore[arg-type]
                    call_stack_level=e.get("call_stack_level"), path=e.get("path"),  # type: ignore[arg-type]
                )
            else:
                writer.write_block_event(
                    c, channel=e.get("channel"), seek_offset=e.get("seek_offset"),  # type: ignore[arg-type]
                    selected_tool=e.get("selected_tool"), active_tool=e.get("active_tool"),
                    gcode=e.get("gcode"), ipo_gcode=e.get("ipo_gcode"),  # type: ignore[arg-type]
                    ipo_read_error=e.get("ipo_read_error"), la_buf=e.get("la_buf"),
                )
            ie += 1
        group: list[dict[str, Any]] = []
        group_cycle: int | None = None
        while il < len(lf_order) and (upto is None or lf_cyc[lf_order[il]] <= upto):
            k = int(lf_order[il])
            c = int(lf_cyc[k])
            if group and c != group_cycle:
                writer.write_lf(group)
                group = []
            group_cycle = c
            text = lf_text[k]
            if text is None or (isinstance(text, float) and np.isnan(text)):
                text = "" if np.isnan(lf_val[k]) else repr(float(lf_val[k]))
            if wall_ok:
                t: Any = wall[k]  # type: ignore[index]
            else:
                assert lf_times is not None
                t = pd.Timestamp(lf_times.iloc[k]) + pd.Timedelta(offset_ns, "ns")
            group.append({"cycle": c, "signal": lf_sig[k], "value": str(text), "time": t,
                          "value_type": value_types.get(lf_sig[k])})
            il += 1
        if group:
            writer.write_lf(group)

    with writer:
        step = writer.chunk_rows
        for a in range(0, cycles.size, step):
            b = min(a + step, cycles.size)
            flush(int(cycles[a]) - 1)
            writer.write_hf(cycles[a:b], values[a:b])
        flush(None)
        for key, items in (attrs.get("payload_other") or {}).items():
            for item in items:
                writer.write_payload(key, item)
    return writer.files
