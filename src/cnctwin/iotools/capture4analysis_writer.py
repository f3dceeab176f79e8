"""Capture4Analysis / SINUMERIK Data Recorder JSON files: writer.

:class:`Capture4AnalysisWriter` writes the structure read by
:func:`cnctwin.iotools.capture4analysis.read_capture4analysis` chunk by chunk and rolls files
at a size limit (``Footer.FilePathChain``); :func:`write_capture4analysis` writes a whole
recording with it. Both are re-exported from :mod:`cnctwin.iotools.capture4analysis` and
:mod:`cnctwin.iotools`. The format is described in ``docs/reference/data-formats.md``
section 1.
"""

from __future__ import annotations

import zipfile
from collections.abc import Iterator, Sequence
from os import PathLike
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
import orjson
import pandas as pd

from cnctwin.exceptions import ConfigError
from cnctwin.iotools._c4a_format import fmt_time as _fmt_time
from cnctwin.iotools._c4a_format import to_float as _to_float
from cnctwin.recording import CYCLE_COUNTER_MODULUS, Recording
from cnctwin.signals import parse_column

__all__ = ["Capture4AnalysisWriter", "write_capture4analysis"]

_M = CYCLE_COUNTER_MODULUS


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
