"""The storage interface shared by every backend, and the backend-neutral pieces of it.

A store keeps :class:`~cnctwin.recording.Recording` objects so that many recordings of many
machines can be searched by machine and time and read back signal by signal. Two backends
implement :class:`Store`:

* :class:`~cnctwin.store.duckdb_store.DuckDBStore`: embedded, a directory of Parquet files
  partitioned by machine and UTC day plus a DuckDB catalog (the default);
* :class:`~cnctwin.store.postgres_store.PostgresStore`: a PostgreSQL schema that keeps the HF
  signals as ``float8[]`` blocks of consecutive cycles.

This module holds what both need: the catalog row of a recording, the (de)serialisation of
:class:`~cnctwin.recording.RecordingMeta` to JSON, the split of the HF table into runs of
consecutive cycles on a linear time axis, and the normalisation of LF and event tables.
"""

from __future__ import annotations

import abc
import hashlib
import json
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from types import TracebackType
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from cnctwin.exceptions import ConfigError, SignalNotFoundError
from cnctwin.recording import (
    EVENT_COLUMNS,
    LF_COLUMNS,
    ExternalChannel,
    Recording,
    jsonable,
    meta_to_json,
)
from cnctwin.signals import parse_column

__all__ = [
    "CATALOG_COLUMNS",
    "HOLE_TABLE_COLUMNS",
    "Store",
    "TimeRun",
    "catalog_row",
    "default_recording_id",
    "external_channel",
    "external_meta",
    "hole_rows",
    "holes_frame",
    "normalize_events",
    "normalize_lf",
    "resolve_columns",
    "time_runs",
    "to_utc",
    "wanted_columns",
]

CATALOG_COLUMNS: tuple[str, ...] = (
    "recording_id",
    "machine",
    "start_time",
    "end_time",
    "first_cycle",
    "last_cycle",
    "n_cycles",
    "cycle_time_s",
    "columns",
    "units",
    "source_files",
    "source_format",
    "issues",
    "partial",
    "n_gaps",
    "meta",
)
"""Columns of :meth:`Store.recordings`. ``columns``/``units``/``source_files``/``issues`` are
JSON text (a list or an object); ``meta`` is the full :class:`RecordingMeta` as JSON."""

_ID_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._:@+=-]{0,199}$")

_EVENT_INT_COLUMNS = (
    "channel",
    "seek_offset",
    "selected_tool",
    "active_tool",
    "call_stack_level",
)
_EVENT_TEXT_COLUMNS = ("kind", "gcode", "ipo_gcode", "path")


def to_utc(value: pd.Timestamp | str | None) -> pd.Timestamp | None:
    """A timestamp as tz-aware UTC; naive input is taken as UTC.

    Parameters
    ----------
    value : pandas.Timestamp or str, optional
        A time (naive = UTC), its ISO text, or None.

    Returns
    -------
    pandas.Timestamp or None
    """
    if value is None:
        return None
    ts = pd.Timestamp(value)
    if ts.tzinfo is None:
        return ts.tz_localize("UTC")
    return ts.tz_convert("UTC")


def check_recording_id(recording_id: str) -> str:
    """Validate a recording id (it becomes a file name); returns it unchanged.

    Raises
    ------
    ConfigError
        If the id is empty, longer than 200 characters or contains characters other than
        letters, digits and ``. _ : @ + = -`` (or starts with one of those).
    """
    if not isinstance(recording_id, str) or not _ID_PATTERN.match(recording_id):
        raise ConfigError(
            f"recording id {recording_id!r} is not valid: use 1-200 letters, digits and "
            "'._:@+=-', starting with a letter or digit"
        )
    return recording_id


def default_recording_id(rec: Recording) -> str:
    """A deterministic id for ``rec``: machine, start time, first cycle and a content hash.

    The same recording read twice from the same file gets the same id, so ingesting it again
    replaces instead of duplicating (``"<machine>-20231222T132341-5558098-1a2b3c4d"``).

    Parameters
    ----------
    rec : Recording
        The recording.

    Returns
    -------
    str
        The id.
    """
    machine = re.sub(r"[^A-Za-z0-9._-]+", "_", rec.meta.machine or "unknown").strip("_.-")
    machine = (machine or "unknown")[:60]
    if rec.n_cycles:
        t0 = pd.Timestamp(rec.hf["time"].iloc[0])
        stamp = t0.strftime("%Y%m%dT%H%M%S")
        first = int(rec.cycles[0])
        last = int(rec.cycles[-1])
    else:
        stamp, first, last = "empty", 0, 0
    h = hashlib.sha256()
    h.update(
        json.dumps(
            [
                rec.meta.machine,
                first,
                last,
                rec.n_cycles,
                rec.columns,
                [str(s) for s in rec.meta.source_files],
                int(pd.Timestamp(rec.hf["time"].iloc[0]).value) if rec.n_cycles else 0,
            ]
        ).encode()
    )
    if rec.n_cycles:
        h.update(np.ascontiguousarray(rec.hf[rec.columns].to_numpy(dtype=np.float64)).tobytes())
    return f"{machine}-{stamp}-{first}-{h.hexdigest()[:8]}"


# ---------------------------------------------------------------------------- meta <-> JSON
def catalog_row(rec: Recording, recording_id: str) -> dict[str, Any]:
    """The catalog entry (:data:`CATALOG_COLUMNS`) of ``rec``.

    Parameters
    ----------
    rec : Recording
        The recording.
    recording_id : str
        The recording's id in the store.

    Returns
    -------
    dict
        The catalog entry (:data:`CATALOG_COLUMNS`).
    """
    n = rec.n_cycles
    t = rec.hf["time"]
    return {
        "recording_id": recording_id,
        "machine": rec.meta.machine,
        "start_time": pd.Timestamp(t.iloc[0]) if n else None,
        "end_time": pd.Timestamp(t.iloc[-1]) if n else None,
        "first_cycle": int(rec.cycles[0]) if n else None,
        "last_cycle": int(rec.cycles[-1]) if n else None,
        "n_cycles": n,
        "cycle_time_s": float(rec.meta.cycle_time_s),
        "columns": json.dumps(rec.columns),
        "units": json.dumps({c: rec.meta.units.get(c, "") for c in rec.columns}),
        "source_files": json.dumps([str(s) for s in rec.meta.source_files]),
        "source_format": rec.meta.source_format,
        "issues": json.dumps(list(rec.meta.issues)),
        "partial": bool(rec.meta.partial),
        "n_gaps": len(rec.meta.gaps),
        "meta": meta_to_json(rec.meta),
    }


def external_meta(ch: ExternalChannel) -> dict[str, Any]:
    """The catalog description of an external channel (everything but its data).

    ``index`` is the name of the data's index column (``"time_s"`` if unnamed).

    Parameters
    ----------
    ch : ExternalChannel
        The channel.

    Returns
    -------
    dict
        The channel's fields without its data, and ``index`` (the index column's name).
    """
    return {
        "index": ch.data.index.name or "time_s", "units": ch.units, "fs_hz": ch.fs_hz,
        "offset_s": ch.offset_s, "drift_ppm": ch.drift_ppm, "aligned": ch.aligned,
        "source": ch.source,
    }


def external_channel(name: str, data: pd.DataFrame, desc: dict[str, Any]) -> ExternalChannel:
    """Inverse of :func:`external_meta`: the channel from its stored table and description.

    Parameters
    ----------
    name : str
        Channel name.
    data : pandas.DataFrame
        The stored table.
    desc : dict
        The stored description (:func:`external_meta`).

    Returns
    -------
    ExternalChannel
    """
    return ExternalChannel(
        name=name, data=data.set_index(desc["index"]), units=dict(desc["units"]),
        fs_hz=desc["fs_hz"], offset_s=float(desc["offset_s"]),
        drift_ppm=float(desc["drift_ppm"]), aligned=bool(desc["aligned"]), source=desc["source"],
    )


# ---------------------------------------------------------------------------- HF time runs
@dataclass(frozen=True)
class TimeRun:
    """Rows ``start .. start+n-1`` of an HF table: consecutive cycles, time linear in cycle.

    Within a run ``cycle = first_cycle + i`` and ``time_ns = t0_ns + i * step_ns``, so a run
    is fully described by these four numbers; :func:`time_runs` splits a table at counter gaps
    and wherever the time column departs from that line.
    """

    start: int
    n: int
    first_cycle: int
    t0_ns: int


def time_runs(
    cycles: NDArray[np.int64], time_ns: NDArray[np.int64], *, step_ns: int
) -> list[TimeRun]:
    """Split an HF table into runs of consecutive cycles with ``time = t0 + i * step``.

    Parameters
    ----------
    cycles : numpy.ndarray of int64
        Unwrapped, increasing cycle counter.
    time_ns : numpy.ndarray of int64
        UTC time of each cycle in ns since the Unix epoch [ns].
    step_ns : int
        Cycle time [ns].

    Returns
    -------
    list of TimeRun
        Covering every row exactly once, in order.
    """
    n = cycles.size
    if n == 0:
        return []
    offset = time_ns - cycles * step_ns
    breaks = np.flatnonzero((np.diff(cycles) != 1) | (np.diff(offset) != 0)) + 1
    starts = np.concatenate([[0], breaks]).astype(np.int64)
    ends = np.concatenate([breaks, [n]]).astype(np.int64)
    return [
        TimeRun(int(s), int(e - s), int(cycles[s]), int(time_ns[s]))
        for s, e in zip(starts, ends, strict=True)
    ]


def block_bounds(runs: Iterable[TimeRun], *, block_cycles: int) -> list[tuple[int, int]]:
    """Cut runs into blocks of at most ``block_cycles`` rows: ``(start_row, n)`` pairs."""
    out: list[tuple[int, int]] = []
    for r in runs:
        for s in range(0, r.n, block_cycles):
            out.append((r.start + s, min(block_cycles, r.n - s)))
    return out


# ---------------------------------------------------------------------------- LF and events
def _text_or_none(src: pd.Series) -> pd.Series:
    """Values as ``str``, missing ones (None, NaN, NA) as ``None``; object dtype."""
    return pd.Series(
        [None if (v is None or (isinstance(v, float) and np.isnan(v)) or v is pd.NA)
         else str(v) for v in src.astype(object)],
        dtype=object,
    )


def normalize_events(events: pd.DataFrame) -> pd.DataFrame:
    """Events with exactly :data:`EVENT_COLUMNS` in the canonical dtypes.

    ``cycle`` int64; channel, offsets, tools, call level nullable ``Int64``; texts ``object``
    with ``None`` for missing. Columns absent in the input are added empty.

    Parameters
    ----------
    events : pandas.DataFrame
        Event table of any reader.

    Returns
    -------
    pandas.DataFrame
        :data:`EVENT_COLUMNS` with the store's dtypes.
    """
    out = pd.DataFrame(index=pd.RangeIndex(len(events)))
    for col in EVENT_COLUMNS:
        src = events[col] if col in events.columns else pd.Series([None] * len(events))
        src = src.reset_index(drop=True)
        if col == "cycle":
            out[col] = src.astype("int64")
        elif col in _EVENT_INT_COLUMNS:
            out[col] = pd.to_numeric(src, errors="raise").astype("Int64")
        else:
            out[col] = _text_or_none(src)
    return out


def normalize_lf(lf: pd.DataFrame) -> pd.DataFrame:
    """LF values with exactly :data:`LF_COLUMNS` in the canonical dtypes.

    Parameters
    ----------
    lf : pandas.DataFrame
        LF table of any reader.

    Returns
    -------
    pandas.DataFrame
        :data:`LF_COLUMNS` with the store's dtypes.
    """
    out = pd.DataFrame(index=pd.RangeIndex(len(lf)))
    for col in LF_COLUMNS:
        src = lf[col].reset_index(drop=True) if col in lf.columns else pd.Series(
            [None] * len(lf)
        )
        if col == "cycle":
            out[col] = src.astype("int64")
        elif col == "time":
            out[col] = pd.to_datetime(src, utc=True).astype("datetime64[ns, UTC]")
        elif col == "value":
            out[col] = pd.to_numeric(src, errors="coerce").astype("float64")
        else:
            out[col] = _text_or_none(src)
    return out


def resolve_columns(
    wanted: Sequence[str], available: Iterable[str], *, where: str = "the store"
) -> list[str]:
    """Expand signal codes (``"CURRENT"``) and column names (``"CURRENT|SP1"``) to columns.

    Parameters
    ----------
    wanted : sequence of str
        Codes or ``CODE|AXIS`` column names.
    available : iterable of str
        Columns that exist.
    where : str
        Named in the error message.

    Returns
    -------
    list of str
        Matching columns in the order of ``available`` grouped by ``wanted``, no duplicates.

    Raises
    ------
    SignalNotFoundError
        If an entry of ``wanted`` matches nothing; the message lists what exists.
    """
    avail = list(dict.fromkeys(available))
    out: dict[str, None] = {}
    for w in wanted:
        hits = [c for c in avail if c == w or parse_column(c)[0] == w]
        if not hits:
            raise SignalNotFoundError(
                f"signal {w!r} is not in {where}; available columns: "
                f"{', '.join(avail) if avail else '(none)'}"
            )
        for h in hits:
            out.setdefault(h, None)
    return list(out)


# ---------------------------------------------------------------------------- hole table
_HOLE_INT = ("hole", "set", "position_in_set", "start_cycle", "cut_start_cycle",
             "cut_end_cycle", "end_cycle")
_HOLE_FLOAT_A = ("start_s", "end_s", "extraction_s", "cut_duration_s", "x_mm", "y_mm",
                 "surface_z_mm")
_HOLE_FLOAT_B = (
    "bottom_z_mm", "depth_mm", "feed_mm_min", "speed_rpm", "current_mean_a", "current_peak_a",
    "current_first_a", "torque_first_nm", "torque_mean_nm", "torque_last_nm", "energy_j",
    "thrust_proxy", "reverse_current_fluct_a", "reverse_z_fluct_mm",
    *(f"dev_{a}_{s}_mm" for a in "xyz" for s in ("mean", "maxabs", "rms")),
)

HOLE_TABLE_COLUMNS: dict[str, str] = {
    **dict.fromkeys(_HOLE_INT, "int"),
    "start_time": "time",
    **dict.fromkeys(_HOLE_FLOAT_A, "float"),
    "surface_source": "text",
    **dict.fromkeys(_HOLE_FLOAT_B, "float"),
    "tool": "int",
    "cycle": "text",
}
"""Columns of the per-hole table and their storage kind (``int``, ``float``, ``text``,
``time``): the columns of :func:`cnctwin.usecases.holes.hole_record` in its order (meanings
and units in :data:`cnctwin.usecases.holes.HOLE_COLUMNS`). Both backends add ``recording_id``
and ``machine`` in front, ``start_ns`` (exact ns of ``start_time``) and ``extra`` (JSON object
of any further columns of the appended frame, so nothing is dropped). Key:
``(recording_id, hole)``."""


def _py(value: Any, kind: str) -> Any:
    """One cell as the Python value stored for its column kind (None for missing)."""
    if value is None or value is pd.NA or value is pd.NaT:
        return None
    if kind == "float":
        f = float(value)
        return None if np.isnan(f) else f
    if isinstance(value, float) and np.isnan(value):
        return None
    if kind == "int":
        return int(value)
    if kind == "text":
        return str(value)
    return value


def hole_rows(holes: pd.DataFrame | Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per-hole rows as the values both backends store (:data:`HOLE_TABLE_COLUMNS`).

    Parameters
    ----------
    holes : pandas.DataFrame or sequence of dict
        Rows of :func:`cnctwin.usecases.holes.hole_record` (or the ``row`` of the edge
        runtime's ``hole`` messages, where ``start_time`` is ISO text).

    Returns
    -------
    list of dict
        Per row: every :data:`HOLE_TABLE_COLUMNS` entry (``None`` where missing, ``start_time``
        as a UTC :class:`datetime.datetime` to the microsecond, which SQL timestamps hold),
        ``start_ns`` (the exact ``start_time`` [ns since the epoch]) and ``extra`` (JSON text of
        the other columns).

    Raises
    ------
    ConfigError
        If a row has no ``hole`` index, the same hole appears twice, or a value cannot be
        converted to its column's kind (the message names the hole and the column).
    """
    frame = holes if isinstance(holes, pd.DataFrame) else pd.DataFrame(list(holes))
    if "hole" not in frame.columns:
        raise ConfigError(
            f"the hole table needs a 'hole' column (hole_record output); got {list(frame.columns)}"
        )
    extra_cols = [c for c in frame.columns if c not in HOLE_TABLE_COLUMNS]
    out: list[dict[str, Any]] = []
    seen: set[int] = set()
    for rec in frame.to_dict("records"):
        row: dict[str, Any] = {}
        for col, kind in HOLE_TABLE_COLUMNS.items():
            v = rec.get(col)
            try:
                if kind == "time":
                    v = None if v is None or pd.isna(v) else to_utc(v)
                else:
                    v = _py(v, kind)
            except (TypeError, ValueError) as exc:
                raise ConfigError(
                    f"hole {rec.get('hole')!r}: column {col!r} value {v!r} is not {kind}: {exc}"
                ) from exc
            row[col] = v
        if row["hole"] is None:
            raise ConfigError(f"a hole row has no 'hole' index: {rec}")
        if row["hole"] in seen:
            raise ConfigError(f"hole {row['hole']} appears twice in the appended rows")
        seen.add(row["hole"])
        t = row["start_time"]
        row["start_ns"] = int(t.value) if t is not None else None
        row["start_time"] = t.floor("us").to_pydatetime() if t is not None else None
        row["extra"] = json.dumps({c: rec[c] for c in extra_cols}, default=jsonable)
        out.append(row)
    return out


def holes_frame(rows: Sequence[Sequence[Any]], columns: Sequence[str]) -> pd.DataFrame:
    """The result of :meth:`Store.holes` from stored rows (canonical dtypes, extras expanded).

    ``rows`` hold ``recording_id, machine``, the :data:`HOLE_TABLE_COLUMNS` without
    ``start_time``, then ``start_ns`` and ``extra`` (``columns`` names them).

    Parameters
    ----------
    rows : sequence
        Stored rows.
    columns : sequence
        Their column names.

    Returns
    -------
    pandas.DataFrame
        A hole table with the hole record's dtypes.
    """
    raw = pd.DataFrame(list(rows), columns=list(columns))
    out = pd.DataFrame({"recording_id": raw["recording_id"].astype(object),
                        "machine": raw["machine"].astype(object)})
    for col, kind in HOLE_TABLE_COLUMNS.items():
        if kind == "time":
            out[col] = pd.to_datetime(raw["start_ns"].astype("Int64"), unit="ns", utc=True)
        elif kind == "int":
            s = pd.array(raw[col].tolist(), dtype="Int64")
            out[col] = s if col == "tool" or s.isna().any() else s.astype("int64")
        elif kind == "float":
            out[col] = pd.to_numeric(raw[col], errors="coerce").astype("float64")
        else:  # inferred like hole_record's own frame (pandas' default string dtype)
            out[col] = pd.Series(_text_or_none(raw[col]).tolist(), dtype=None)
    extras = [json.loads(e) if e else {} for e in raw["extra"]]
    for k in dict.fromkeys(k for e in extras for k in e):
        out[k] = [e.get(k) for e in extras]
    order = np.lexsort((out["hole"].to_numpy(), out["recording_id"].to_numpy(dtype=str),
                        raw["start_ns"].fillna(np.iinfo(np.int64).max).to_numpy(dtype=np.int64)))
    return out.iloc[order].reset_index(drop=True)


# ---------------------------------------------------------------------------- the interface
def wanted_columns(columns: Sequence[str], signals: Iterable[str] | None) -> list[str]:
    """The stored columns a :meth:`Store.load` ``signals`` selection keeps, in stored order.

    Parameters
    ----------
    columns : sequence of str
        The recording's stored HF columns (``CODE|AXIS``).
    signals : iterable of str or None
        Signal codes or full column names; None keeps every column.

    Returns
    -------
    list of str
        The kept columns.
    """
    if signals is None:
        return list(columns)
    wanted = set(signals)
    return [c for c in columns if c in wanted or parse_column(c)[0] in wanted]


class Store(abc.ABC):
    """A store of recordings; see :func:`cnctwin.store.open`.

    Use as a context manager (``with cnctwin.store.open(path) as st: ...``) or call
    :meth:`close`.
    """

    url: str

    @abc.abstractmethod
    def ingest(self, rec: Recording, *, recording_id: str | None = None) -> str:
        """Store ``rec`` and return its id.

        Parameters
        ----------
        rec : Recording
            The recording. HF values, LF values, events, external channels and metadata
            (gaps, issues, partial flag, attrs) are stored.
        recording_id : str, optional
            Id to store it under; default :func:`default_recording_id` (deterministic, so the
            same file ingested twice is stored once). Ingesting an id that exists replaces it.

        Returns
        -------
        str
            The recording id.
        """

    @abc.abstractmethod
    def recordings(
        self,
        *,
        machine: str | None = None,
        start: pd.Timestamp | str | None = None,
        end: pd.Timestamp | str | None = None,
    ) -> pd.DataFrame:
        """The catalog: one row per recording (:data:`CATALOG_COLUMNS`), sorted by start time.

        Parameters
        ----------
        machine : str, optional
            Only this machine.
        start, end : Timestamp or str, optional
            Only recordings overlapping ``[start, end]`` (UTC; naive times are taken as UTC).
        """

    def query_signals(
        self,
        signals: Sequence[str],
        *,
        machine: str | None = None,
        start: pd.Timestamp | str | None = None,
        end: pd.Timestamp | str | None = None,
        recording_id: str | None = None,
    ) -> pd.DataFrame:
        """HF values of some signals over a time range.

        Parameters
        ----------
        signals : sequence of str
            Column names (``"CURRENT|SP1"``) or codes (``"CURRENT"``, expanded to every axis).
        machine : str, optional
            Only this machine.
        start, end : Timestamp or str, optional
            Inclusive UTC time range.
        recording_id : str, optional
            Only this recording.

        Returns
        -------
        pandas.DataFrame
            Column ``time`` (UTC) and one float64 column per matched signal (NaN where a
            recording lacks it). Indexed by ``cycle`` when ``recording_id`` is given, otherwise
            by ``(recording_id, cycle)``; sorted.

        Raises
        ------
        SignalNotFoundError
            If a requested signal is in none of the selected recordings.
        StoreError
            If ``recording_id`` is given and not in the store.

        Notes
        -----
        The argument handling (UTC times, the recording check, expanding codes to columns
        with :func:`resolve_columns`) and the shape of the result are shared by every
        backend; a backend supplies the catalog (:meth:`_catalog_columns`), the existence
        check (:meth:`_require`) and the HF reads (:meth:`_signal_frames`).
        """
        t0, t1 = to_utc(start), to_utc(end)
        cat = self._catalog_columns(machine=machine, start=t0, end=t1)
        if recording_id is not None:
            if recording_id not in set(cat["recording_id"]):
                self._require(recording_id)  # raises if unknown
            cat = cat[cat["recording_id"] == recording_id]
        cols_by_rec = {
            r: json.loads(c) for r, c in zip(cat["recording_id"], cat["columns"], strict=True)
        }
        available = [c for cols in cols_by_rec.values() for c in cols]
        where = f"recording {recording_id!r}" if recording_id else "the selected recordings"
        wanted = (
            resolve_columns(signals, available, where=where) if cols_by_rec else list(signals)
        )
        frames = self._signal_frames(cols_by_rec, wanted, t0, t1) if cols_by_rec else []
        if frames:
            out = pd.concat(frames, ignore_index=True)
        else:
            out = pd.DataFrame(
                {"recording_id": pd.Series(dtype=object), "cycle": pd.Series(dtype="int64"),
                 "time": pd.Series(dtype="datetime64[ns, UTC]")}
            )
        for c in wanted:
            if c not in out.columns:
                out[c] = np.nan
        out = out[["recording_id", "cycle", "time", *wanted]]
        out["recording_id"] = out["recording_id"].astype(object)
        return index_result(out, single=recording_id is not None)

    @abc.abstractmethod
    def _catalog_columns(
        self, *, machine: str | None, start: pd.Timestamp | None, end: pd.Timestamp | None
    ) -> pd.DataFrame:
        """Catalog rows (``recording_id``, ``columns`` as JSON text) of the selection."""

    @abc.abstractmethod
    def _require(self, recording_id: str) -> None:
        """Raise :class:`~cnctwin.exceptions.StoreError` if ``recording_id`` is not stored."""

    @abc.abstractmethod
    def _signal_frames(
        self,
        cols_by_rec: dict[str, list[str]],
        wanted: Sequence[str],
        start: pd.Timestamp | None,
        end: pd.Timestamp | None,
    ) -> list[pd.DataFrame]:
        """HF rows of ``wanted`` in ``[start, end]``, one frame per recording (or file).

        Each frame has ``recording_id``, ``cycle``, ``time`` (UTC) and the wanted signals
        the recording has (``cols_by_rec``: recording id -> its columns); missing signals
        are filled with NaN by :meth:`query_signals`.
        """

    @abc.abstractmethod
    def load(self, recording_id: str, *, signals: Iterable[str] | None = None,
             cycles: tuple[int | None, int | None] | None = None) -> Recording:
        """Read a stored recording back (HF, LF, events, external channels, metadata).

        Parameters
        ----------
        recording_id : str
            The recording.
        signals : iterable of str, optional
            Only these HF signals (codes such as ``"CURRENT"`` or full column names, as
            :meth:`cnctwin.recording.Recording.select`); the others are not read. Default:
            every signal.
        cycles : (int or None, int or None), optional
            Only this inclusive range of the cycle counter (LF values and events cut to it);
            the store reads only the data that overlaps it.

        Raises
        ------
        StoreError
            If the id is not in the store (the message lists some that are).
        """

    @abc.abstractmethod
    def sql(self, query: str) -> pd.DataFrame:
        """Run a SQL query and return the result.

        Both backends offer ``recordings``, ``lf``, ``events`` and ``hf_long``
        (``recording_id, cycle, time, signal, value``); DuckDB also has the wide ``hf`` view.
        """

    @abc.abstractmethod
    def delete(self, recording_id: str) -> bool:
        """Remove a recording; returns whether it existed."""

    @abc.abstractmethod
    def append_holes(
        self, recording_id: str, holes: pd.DataFrame | Sequence[dict[str, Any]]
    ) -> int:
        """Add per-hole rows of a stored recording to the hole table (idempotent).

        Parameters
        ----------
        recording_id : str
            The recording the holes were found in (must be stored; its machine is kept with
            each row).
        holes : pandas.DataFrame or sequence of dict
            Rows of :func:`cnctwin.usecases.holes.hole_record` (columns
            :data:`HOLE_TABLE_COLUMNS`; further columns are kept in ``extra``).

        Returns
        -------
        int
            Rows written.

        Raises
        ------
        StoreError
            If ``recording_id`` is not in the store.
        ConfigError
            If a row has no ``hole`` index or a value does not fit its column.

        Notes
        -----
        The key is ``(recording_id, hole)``: appending a hole that is already stored replaces
        its row, so re-sending the same holes (a restarted edge runtime) stores each once.
        Deleting the recording deletes its holes; re-ingesting it keeps them.
        """

    @abc.abstractmethod
    def holes(
        self,
        *,
        recording_id: str | None = None,
        machine: str | None = None,
        start: pd.Timestamp | str | None = None,
        end: pd.Timestamp | str | None = None,
    ) -> pd.DataFrame:
        """Per-hole rows from the hole table.

        Parameters
        ----------
        recording_id : str, optional
            Only holes of this recording.
        machine : str, optional
            Only this machine.
        start, end : Timestamp or str, optional
            Only holes whose ``start_time`` (cut start, UTC) is in ``[start, end]``.

        Returns
        -------
        pandas.DataFrame
            ``recording_id``, ``machine``, the :data:`HOLE_TABLE_COLUMNS` (``start_time`` UTC
            with ns precision, ``tool`` nullable ``Int64``) and any extra columns; sorted by
            ``start_time``, ``recording_id``, ``hole``.
        """

    @abc.abstractmethod
    def close(self) -> None:
        """Release the connection (idempotent)."""

    def __enter__(self) -> Store:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.url}>"


def index_result(frame: pd.DataFrame, *, single: bool) -> pd.DataFrame:
    """Set the :meth:`Store.query_signals` index on a frame with ``recording_id``/``cycle``."""
    rid = frame["recording_id"].to_numpy()
    cyc = frame["cycle"].to_numpy()
    same = rid[1:] == rid[:-1]
    ordered = bool(np.all((rid[1:] > rid[:-1]) | (same & (cyc[1:] > cyc[:-1]))))
    if not ordered:
        frame = frame.sort_values(["recording_id", "cycle"], kind="stable")
    if single:
        frame = frame.drop(columns="recording_id").set_index("cycle")
    else:
        frame = frame.set_index(["recording_id", "cycle"])
    return frame
