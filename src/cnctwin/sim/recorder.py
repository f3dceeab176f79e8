"""Recording sinks of the simulator: in memory, Parquet chunks, Capture4Analysis JSON.

:func:`cnctwin.sim.simulation.simulate` hands each chunk of simulated cycles to a sink as a
:class:`RecordedChunk` (HF columns ``CODE|AXIS`` on real cycle numbers, LF values in long form,
NC events). Sinks:

* :class:`MemorySink`: builds one :class:`~cnctwin.recording.Recording` (default).
* :class:`ParquetChunkSink`: one Parquet file per chunk (``hf_000000.parquet`` ...), plus
  ``lf.parquet``, ``events.parquet`` and ``meta.json``; memory stays bounded by one chunk, so a
  3.5 h wear run fits in well under 2 GB. :func:`read_parquet_chunks` reads the directory back.
* :class:`Capture4AnalysisSink`: streams into Capture4Analysis JSON with
  :class:`cnctwin.iotools.capture4analysis.Capture4AnalysisWriter` (what the edge device writes).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from cnctwin.exceptions import ConfigError
from cnctwin.recording import (
    EVENT_COLUMNS,
    LF_COLUMNS,
    Recording,
    RecordingMeta,
    cycles_to_time,
    find_gaps,
    meta_from_dict,
    meta_to_dict,
)

__all__ = [
    "FLOAT32_CODES",
    "Capture4AnalysisSink",
    "MemorySink",
    "ParquetChunkSink",
    "RecordedChunk",
    "RecordingSink",
    "read_parquet_chunks",
]


@dataclass
class RecordedChunk:
    """One chunk of recorded cycles.

    Attributes
    ----------
    cycles : numpy.ndarray of int64
        Real (unwrapped) cycle numbers of the recorded rows (dropped cycles are absent).
    hf : dict
        ``CODE|AXIS`` -> float64 array, one value per row of ``cycles``.
    lf : pandas.DataFrame
        LF values in long form (:data:`cnctwin.recording.LF_COLUMNS`).
    events : pandas.DataFrame
        NC events (:data:`cnctwin.recording.EVENT_COLUMNS`) with real cycle numbers.
    """

    cycles: NDArray[np.int64]
    hf: dict[str, NDArray[np.float64]]
    lf: pd.DataFrame
    events: pd.DataFrame


class RecordingSink(Protocol):
    """What :func:`~cnctwin.sim.simulation.simulate` writes to."""

    def open(self, columns: list[str], meta: RecordingMeta) -> None:
        """Called once before the first chunk with the HF column order and the metadata."""

    def write(self, chunk: RecordedChunk) -> None:
        """Called once per chunk, in cycle order."""

    def close(self, meta: RecordingMeta) -> Recording | None:
        """Called at the end with the final metadata; returns a Recording if it keeps one."""

    # Optional attribute ``keeps_chunks`` (bool, default True when absent): False promises that
    # the sink holds no reference to a chunk's arrays after write() returns (it writes them
    # out or copies them), so simulate() may reuse its output buffers for the next chunk.


@dataclass
class MemorySink:
    """Collects every chunk and builds one :class:`Recording` at :meth:`close`."""

    _columns: list[str] = field(default_factory=list)
    _chunks: list[RecordedChunk] = field(default_factory=list)
    _meta: RecordingMeta | None = None
    keeps_chunks = True  # holds every chunk's arrays until close()

    def open(self, columns: list[str], meta: RecordingMeta) -> None:
        """Remember the column order."""
        self._columns = list(columns)
        self._chunks = []
        self._meta = meta

    def write(self, chunk: RecordedChunk) -> None:
        """Keep the chunk."""
        self._chunks.append(chunk)

    def close(self, meta: RecordingMeta) -> Recording:
        """Concatenate the chunks into a Recording (gaps from dropped cycles in ``meta.gaps``)."""
        cycles = (np.concatenate([c.cycles for c in self._chunks]) if self._chunks
                  else np.empty(0, dtype=np.int64))
        data = {
            col: (np.concatenate([c.hf[col] for c in self._chunks]) if self._chunks
                  else np.empty(0))
            for col in self._columns
        }
        hf = pd.DataFrame(data, index=pd.Index(cycles, name="cycle"))
        hf.insert(0, "time", cycles_to_time(cycles, meta.time_anchors,
                                            cycle_time_s=meta.cycle_time_s))
        lf = _concat([c.lf for c in self._chunks], LF_COLUMNS)
        events = _concat([c.events for c in self._chunks], EVENT_COLUMNS)
        meta.gaps = find_gaps(cycles)
        self._chunks = []
        return Recording(hf, lf=lf, events=events, meta=meta)


def _concat(frames: list[pd.DataFrame], columns: tuple[str, ...]) -> pd.DataFrame | None:
    frames = [f for f in frames if len(f)]
    if not frames:
        return None
    out = pd.concat(frames, ignore_index=True)
    return out[list(columns)]


FLOAT32_CODES: tuple[str, ...] = ("CURRENT", "TORQUE", "LOAD", "POWER", "TORQUE_FFW")
"""HF codes :class:`ParquetChunkSink` stores as float32 by default: drive values whose
measurement noise (0.03 A current noise, 0.02 Nm torque noise) is >= 1e4 times the float32
resolution (relative 6e-8). Positions, controller differences and speeds stay float64
(ENC_POS needs 1e-5 mm at up to 1000 mm; CMD_SPEED - VEL_FFW = Kv CTRL_DIFF2 must hold to the
encoder resolution for the servo identification)."""

_CHUNK_FORMAT_VERSION = 2

_INCOMPRESSIBLE_RATIO = 0.85
"""A Parquet HF column compressed to more than this fraction of its size, PLAIN or
BYTE_STREAM_SPLIT, is written uncompressed: saves the codec's time."""

_PROBE_EVERY_FILES = 10
"""Every this many HF files one is written fully compressed to re-learn the per-column codecs
(a column's compressibility changes, e.g. the spindle angle once the spindle turns)."""

_WRITE_BATCH_ROWS = 65_536
"""Parquet ``write_batch_size``: rows encoded per batch (pyarrow default 1024); one batch per
50 000-cycle column cuts the writer's per-batch overhead (-10 % of the HF write)."""

_LF_SCHEMA_FIELDS: tuple[tuple[str, str], ...] = (
    ("cycle", "int64"), ("time", "timestamp"), ("signal", "string"), ("value", "float64"),
    ("text", "string"),
)


class ParquetChunkSink:
    """Write one Parquet file per chunk into a directory.

    Parameters
    ----------
    directory : str or path-like
        Output directory (created). Files: ``hf_000000.parquet`` ... (columns ``cycle``,
        ``CODE|AXIS``), ``lf.parquet``, ``events.parquet``, ``meta.json``.
    compression : str, default 'lz4'
        Parquet compression codec of the HF files (``'lz4'``, ``'zstd'`` (level 1),
        ``'snappy'``, ``'none'``).
    float32_codes : sequence of str, default :data:`FLOAT32_CODES`
        HF codes stored as float32 (read back as float64); ``()`` keeps every column float64.
    file_format : {'parquet', 'arrow'}, default 'parquet'
        HF chunk files as Parquet (``hf_000000.parquet``) or Arrow IPC / Feather v2
        (``hf_000000.arrow``, same compression codec). LF values and events are Parquet.

    Notes
    -----
    HF columns are written PLAIN (no dictionary), REQUIRED (non-nullable: no definition
    levels), data pages v2, one write batch per chunk, with min/max statistics only for
    ``cycle`` (delta-encoded): the noisy float columns defeat the dictionary, whose hashing made
    the writer as costly as the whole servo model, and the constant columns of idle axes
    compress to a few bytes anyway. Per column the sink learns, from the first file and every
    10th (written PLAIN and fully compressed, plus the float columns BYTE_STREAM_SPLIT to
    memory), the smaller of PLAIN and BYTE_STREAM_SPLIT (the noisy float32 drive values shrink
    to ~45 % split into byte planes, not at all PLAIN) and stores columns that neither shrinks
    by 15 % uncompressed (session 3: -21 % bytes at the same CPU). The ``time`` column is not
    stored: the reader computes it from the cycle counter and the time anchor in ``meta.json``
    exactly as the simulator does (:func:`cnctwin.recording.cycles_to_time`). Measured on
    50 000-cycle chunks of a drilling run (HF + LF, one core, CPU time; BENCHMARKS.md
    "Simulator", ``bench_sim.py --writer``): before (float64 with ``time``, pages v1) 37 ms and
    196 B/cycle; now ~21 ms and ~103 B/cycle (~0.6 GB for the 3.5 h wear run); Arrow IPC
    (Feather v2, lz4, ``file_format='arrow'``) about the same time and size.
    HF rows and LF values leave memory chunk by chunk (LF rows are appended to ``lf.parquet``
    as they come); only the NC events (one row per block) are kept until :meth:`close`.
    """

    keeps_chunks = False  # HF/LF arrays are written out in write(); simulate() reuses buffers

    def __init__(
        self,
        directory: str | Path,
        *,
        compression: str = "lz4",
        float32_codes: tuple[str, ...] | list[str] = FLOAT32_CODES,
        file_format: str = "parquet",
    ) -> None:
        if file_format not in ("parquet", "arrow"):
            raise ConfigError(f"file_format must be 'parquet' or 'arrow', not {file_format!r}")
        self.directory = Path(directory)
        self.file_format = file_format
        self.compression = compression
        self.float32_codes = tuple(float32_codes)
        self.files: list[Path] = []
        self._columns: list[str] = []
        self._f32: set[str] = set()
        self._lf_writer: Any = None
        self._schema: Any = None
        self._codecs: dict[str, str] | None = None
        self._encodings: dict[str, str] = {}
        self._events: list[pd.DataFrame] = []
        self._meta: RecordingMeta | None = None
        self._last_cycle: int | None = None
        self._gaps: list[tuple[int, int]] = []

    def open(self, columns: list[str], meta: RecordingMeta) -> None:
        """Create the directory."""
        self.directory.mkdir(parents=True, exist_ok=True)
        self._columns = list(columns)
        self._f32 = {c for c in self._columns if c.split("|", 1)[0] in self.float32_codes}
        self._meta = meta
        self._schema = None
        self._codecs = None

    def write(self, chunk: RecordedChunk) -> None:
        """Write the chunk's HF rows to the next file and append its LF rows."""
        import pyarrow as pa
        import pyarrow.parquet as pq

        assert self._meta is not None, "open() first"
        c = chunk.cycles
        if c.size:
            prev = self._last_cycle
            cc = c if prev is None else np.concatenate([[prev], c])
            self._gaps += [(g.after_cycle, g.before_cycle) for g in find_gaps(cc)]
            self._last_cycle = int(c[-1])
        # zero-copy Arrow arrays over the numpy columns (float32 casts for the drive values);
        # the columns are declared non-nullable (Parquet REQUIRED: no definition levels)
        arrays = [pa.array(c)] + [
            pa.array(chunk.hf[k].astype(np.float32) if k in self._f32 else chunk.hf[k])
            for k in self._columns
        ]
        if self._schema is None:
            self._schema = pa.schema([pa.field(name, arr.type, nullable=False) for name, arr
                                      in zip(["cycle", *self._columns], arrays, strict=True)])
        table = pa.Table.from_arrays(arrays, schema=self._schema)
        path = self.directory / f"hf_{len(self.files):06d}.{self.file_format}"
        if self.file_format == "arrow":
            import pyarrow.feather as pf

            pf.write_feather(table, path, compression=_ipc_codec(self.compression),
                             compression_level=1 if self.compression == "zstd" else None)
        else:
            probe = self._codecs is None or len(self.files) % _PROBE_EVERY_FILES == 0
            codecs: str | dict[str, str] = self.compression if probe else self._codecs or {}
            encodings = {"cycle": "DELTA_BINARY_PACKED"}
            if not probe:
                encodings.update(self._encodings)
            level: int | dict[str, int] | None = None
            if self.compression == "zstd":  # level 1; uncompressed columns take no level
                level = 1 if isinstance(codecs, str) else {
                    c: 1 for c, codec in codecs.items() if codec == "zstd"}
            pq.write_table(table, path, compression=codecs, compression_level=level,
                           use_dictionary=False, write_statistics=["cycle"],
                           column_encoding=encodings, data_page_version="2.0",
                           write_batch_size=_WRITE_BATCH_ROWS)
            if probe and self.compression not in ("none", "uncompressed"):
                self._codecs, self._encodings = _codecs_from(path, table, self.compression)
        self.files.append(path)
        if len(chunk.lf):
            self._write_lf(chunk.lf)
        if len(chunk.events):
            self._events.append(chunk.events)

    def _write_lf(self, lf: pd.DataFrame) -> None:
        import pyarrow as pa
        import pyarrow.parquet as pq

        types = {"int64": pa.int64(), "timestamp": pa.timestamp("ns", tz="UTC"),
                 "string": pa.string(), "float64": pa.float64()}
        schema = pa.schema([(n, types[t]) for n, t in _LF_SCHEMA_FIELDS])
        frame = lf[list(LF_COLUMNS)]
        table = pa.Table.from_pandas(frame, schema=schema, preserve_index=False)
        if self._lf_writer is None:
            # dictionary only for the repeated signal names (not the float values)
            self._lf_writer = pq.ParquetWriter(self.directory / "lf.parquet", schema,
                                               compression=self.compression,
                                               use_dictionary=["signal", "text"],
                                               write_statistics=["cycle", "time"])
        self._lf_writer.write_table(table)

    def close(self, meta: RecordingMeta) -> None:
        """Write events and metadata, close ``lf.parquet``; returns ``None`` (data on disk)."""
        if self._lf_writer is not None:
            self._lf_writer.close()
            self._lf_writer = None
        ev = _concat(self._events, EVENT_COLUMNS)
        if ev is not None:
            _write_frame(ev, self.directory / "events.parquet", self.compression)
        doc = {
            "format": "cnctwin.sim chunks",
            "format_version": _CHUNK_FORMAT_VERSION,
            **meta_to_dict(meta),
            "gaps": [list(g) for g in self._gaps],
            "hf_files": [p.name for p in self.files],
            "hf_time_column": False,
            "float32_columns": sorted(self._f32),
        }
        (self.directory / "meta.json").write_text(json.dumps(doc, indent=1), encoding="utf-8")
        self._events = []
        return None


def _codecs_from(path: Path, table: Any, compression: str) -> tuple[dict[str, str],
                                                                  dict[str, str]]:
    """Per-column codec and encoding, learned from the file ``path`` (``table`` written PLAIN
    with ``compression`` everywhere) and the float columns of ``table`` written once more
    BYTE_STREAM_SPLIT to memory.

    Each float column takes the smaller of PLAIN and BYTE_STREAM_SPLIT (the byte planes of
    the sign/exponent compress where the interleaved values do not: the float32 drive values
    with their noise shrink to ~45 % with lz4, which PLAIN could not compress at all); a column
    that neither shrinks below :data:`_INCOMPRESSIBLE_RATIO` is stored uncompressed.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    floats = [f.name for f in table.schema if pa.types.is_floating(f.type)]
    buf = pa.BufferOutputStream()
    pq.write_table(table.select(floats), buf, compression=compression, use_dictionary=False,
                   write_statistics=False, use_byte_stream_split=True,
                   data_page_version="2.0", write_batch_size=_WRITE_BATCH_ROWS)
    rg_split = pq.read_metadata(pa.BufferReader(buf.getvalue())).row_group(0)
    split = {rg_split.column(i).path_in_schema: rg_split.column(i).total_compressed_size
             for i in range(rg_split.num_columns)}
    rg = pq.read_metadata(path).row_group(0)
    codecs, encodings = {}, {}
    for i in range(rg.num_columns):
        col = rg.column(i)
        name = col.path_in_schema
        size = col.total_compressed_size
        if name in split and split[name] < size:
            size = split[name]
            encodings[name] = "BYTE_STREAM_SPLIT"
        ratio = size / max(col.total_uncompressed_size, 1)
        codecs[name] = "none" if ratio > _INCOMPRESSIBLE_RATIO else compression
        if codecs[name] == "none":
            encodings.pop(name, None)
    return codecs, encodings


def _ipc_codec(compression: str) -> str:
    if compression in ("lz4", "zstd"):
        return compression
    if compression in ("none", "uncompressed"):
        return "uncompressed"
    raise ConfigError(f"Arrow IPC files support compression 'lz4', 'zstd' or 'none', "
                      f"not {compression!r}")


def _write_frame(frame: pd.DataFrame, path: Path, compression: str) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    pq.write_table(pa.Table.from_pandas(frame, preserve_index=False), path,
                   compression=compression)


def read_parquet_chunks(directory: str | Path) -> Recording:
    """Read a :class:`ParquetChunkSink` directory back into one :class:`Recording`.

    Parameters
    ----------
    directory : str or path
        The sink's output directory (``meta.json``, ``hf_*.parquet``, ``events.parquet``).

    Returns
    -------
    Recording
        All chunks in one recording (float32 columns widened to float64).

    Raises
    ------
    ConfigError
        If ``meta.json`` is missing (not a simulator output directory).
    """
    d = Path(directory)
    meta_path = d / "meta.json"
    if not meta_path.exists():
        raise ConfigError(f"{d} has no meta.json; pass a directory written by ParquetChunkSink")
    doc = json.loads(meta_path.read_text(encoding="utf-8"))
    frames = [pd.read_feather(d / name) if name.endswith(".arrow") else pd.read_parquet(d / name)
              for name in doc["hf_files"]]
    hf = pd.concat(frames, ignore_index=True).set_index("cycle")
    f32 = [c for c in doc.get("float32_columns", []) if c in hf.columns]
    if f32:
        hf[f32] = hf[f32].astype(np.float64)
    meta = meta_from_dict(doc)
    meta.source_files = [str(d / n) for n in doc["hf_files"]]
    anchors = meta.time_anchors
    if "time" not in hf.columns:  # format 2: time from the counter, as the simulator did
        hf.insert(0, "time", cycles_to_time(hf.index.to_numpy(), anchors,
                                            cycle_time_s=doc["cycle_time_s"]))
    lf = pd.read_parquet(d / "lf.parquet") if (d / "lf.parquet").exists() else None
    if lf is not None and "text" in lf.columns:  # missing text is None, as in memory
        text = lf["text"].astype(object)
        lf["text"] = text.where(text.notna(), None)
    ev = pd.read_parquet(d / "events.parquet") if (d / "events.parquet").exists() else None
    return Recording(hf, lf=lf, events=ev, meta=meta)


class Capture4AnalysisSink:
    """Stream the simulation into Capture4Analysis JSON (the edge device's format).

    Parameters
    ----------
    path : str or path-like
        First output file (``run.json``) or, with ``zip=True``, the archive.
    max_file_mb : float, optional
        Roll over to a chained file before this size [MB].
    zip : bool, default False
        Write the files into one zip archive.
    timestamp_every_cycles : int, default 500
        Write an ``HFTimestamp`` anchor every this many cycles (1 s at 2 ms).
    """

    def __init__(
        self,
        path: str | Path,
        *,
        max_file_mb: float | None = None,
        zip: bool = False,
        timestamp_every_cycles: int = 500,
    ) -> None:
        self.path = Path(path)
        self.max_file_mb = max_file_mb
        self.zip = zip
        self.timestamp_every_cycles = timestamp_every_cycles
        self.keeps_chunks = False  # rows are serialised in write()
        self._writer: Any = None
        self._columns: list[str] = []
        self._meta: RecordingMeta | None = None
        self.files: list[Path] = []

    def open(self, columns: list[str], meta: RecordingMeta) -> None:
        """Create the writer (header with the HF signal list)."""
        from cnctwin.iotools.capture4analysis import Capture4AnalysisWriter

        self._columns = list(columns)
        self._meta = meta
        anchor = meta.time_anchors[0] if meta.time_anchors else None
        self._writer = Capture4AnalysisWriter(
            self.path, columns=self._columns, axis_map=meta.axis_map, machine=meta.machine,
            cycle_time_s=meta.cycle_time_s, initial=anchor, max_file_mb=self.max_file_mb,
            zip=self.zip,
        )

    def write(self, chunk: RecordedChunk) -> None:
        """Write HF rows, timestamps, events and LF values of the chunk."""
        assert self._writer is not None and self._meta is not None, "open() first"
        c = chunk.cycles
        if c.size:
            values = np.column_stack([chunk.hf[k] for k in self._columns])
            self._writer.write_hf(c, values)
            marks = c[c % self.timestamp_every_cycles == 0]
            if marks.size:
                times = cycles_to_time(marks, self._meta.time_anchors,
                                       cycle_time_s=self._meta.cycle_time_s)
                for cyc, t in zip(marks, times, strict=True):
                    self._writer.write_timestamp(int(cyc), t)
        for row in chunk.events.to_dict("records"):
            if row["kind"] == "call":
                self._writer.write_call_event(
                    int(row["cycle"]), channel=_int(row["channel"], 1),
                    seek_offset=_int(row["seek_offset"], 0),
                    call_stack_level=_int(row["call_stack_level"], 1), path=str(row["path"]),
                )
            else:
                self._writer.write_block_event(
                    int(row["cycle"]), channel=_int(row["channel"], 1),
                    seek_offset=_int(row["seek_offset"], 0),
                    selected_tool=_int(row["selected_tool"], 0),
                    active_tool=_int(row["active_tool"], 0), gcode=str(row["gcode"]),
                    ipo_gcode=str(row["ipo_gcode"]),
                )
        if len(chunk.lf):
            lf = chunk.lf
            self._writer.write_lf([
                {"cycle": int(c), "time": t, "signal": str(s), "value": float(v),
                 "value_type": "Double"}
                for c, t, s, v in zip(lf["cycle"].to_numpy(), lf["time"], lf["signal"],
                                      lf["value"].to_numpy(), strict=True)
            ])

    def close(self, meta: RecordingMeta) -> None:
        """Close the files (footer with the file chain)."""
        if self._writer is not None:
            self.files = list(self._writer.close())
        return None


def _int(value: Any, default: int) -> int:
    try:
        if value is None or pd.isna(value):
            return default
        return int(value)
    except (TypeError, ValueError):
        return default
