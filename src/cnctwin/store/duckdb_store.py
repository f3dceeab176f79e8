"""The embedded store: Parquet files partitioned by machine and UTC day, a DuckDB catalog.

Layout under ``root``::

    catalog.duckdb                                         recordings, files, holes tables
    hf/machine=<m>/day=<YYYY-MM-DD>/<recording_id>.parquet  wide HF table, one file per day
    lf/machine=<m>/<recording_id>.parquet                   LF values (long form)
    events/machine=<m>/<recording_id>.parquet               NC events
    external/machine=<m>/<recording_id>/<channel>.parquet   channels with their own clock

The per-hole table ``holes`` (:meth:`DuckDBStore.append_holes`) lives in the catalog itself:
``recording_id, machine``, the columns of :data:`~cnctwin.store.base.HOLE_TABLE_COLUMNS`
(BIGINT / DOUBLE / VARCHAR / TIMESTAMPTZ), ``start_ns`` BIGINT (exact ns of ``start_time``) and
``extra`` VARCHAR (JSON); primary key ``(recording_id, hole)``.

An HF file holds columns ``recording_id``, ``cycle`` (int64), ``time`` (timestamp[ns, UTC]) and
one float64 column per ``CODE|AXIS`` signal (the column metadata carry the unit). A recording
that spans UTC midnight is split into one file per day. Files are zstd-compressed, floats use
Parquet's BYTE_STREAM_SPLIT encoding (better compression of smooth signals), and row groups
hold 65 536 cycles (131 s at 2 ms) so that a time-range read skips the rest by statistics.

Reads of HF values go through pyarrow (exact ns times, column pruning, row-group skipping);
:meth:`DuckDBStore.sql` runs DuckDB over views of the files. ``<m>`` is the machine name with
characters other than letters, digits and ``._-`` percent-encoded (the ``hf``, ``lf`` and
``events`` views decode it back to the machine name).

DuckDB lets one process at a time hold a catalog file: one writer, or any number of read-only
openers, never both. Processes that share a store therefore hold it briefly (the dashboard per
request, the edge's store sink per block, ``cnctwin ingest`` per file) and wait a bounded time
for it (``lock_timeout_s``) instead of failing at once.
"""

from __future__ import annotations

import json
import os
import re
import time
import urllib.parse
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import duckdb
import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from cnctwin.exceptions import StoreError
from cnctwin.recording import ExternalChannel, Recording, meta_from_json
from cnctwin.store.base import (
    CATALOG_COLUMNS,
    HOLE_TABLE_COLUMNS,
    Store,
    catalog_row,
    check_recording_id,
    default_recording_id,
    external_channel,
    external_meta,
    hole_rows,
    holes_frame,
    normalize_events,
    normalize_lf,
    to_utc,
    wanted_columns,
)

__all__ = ["DuckDBStore", "StagedRecording", "hf_table", "stage_recording"]

_NS_PER_DAY = 86_400 * 10**9
_DUCK_TYPES = {"int64": "BIGINT", "Int64": "BIGINT", "float64": "DOUBLE",
               "datetime64[ns, UTC]": "TIMESTAMPTZ"}

_SCHEMA = """
CREATE TABLE IF NOT EXISTS recordings (
    recording_id VARCHAR PRIMARY KEY,
    machine VARCHAR NOT NULL,
    start_time TIMESTAMPTZ,
    end_time TIMESTAMPTZ,
    first_cycle BIGINT,
    last_cycle BIGINT,
    n_cycles BIGINT NOT NULL,
    cycle_time_s DOUBLE NOT NULL,
    columns VARCHAR NOT NULL,
    units VARCHAR NOT NULL,
    source_files VARCHAR NOT NULL,
    source_format VARCHAR NOT NULL,
    issues VARCHAR NOT NULL,
    partial BOOLEAN NOT NULL,
    n_gaps INTEGER NOT NULL,
    meta VARCHAR NOT NULL,
    external VARCHAR NOT NULL,
    ingested_at TIMESTAMPTZ NOT NULL
);
CREATE TABLE IF NOT EXISTS files (
    recording_id VARCHAR NOT NULL,
    kind VARCHAR NOT NULL,
    name VARCHAR NOT NULL,
    path VARCHAR NOT NULL,
    day DATE,
    start_time TIMESTAMPTZ,
    end_time TIMESTAMPTZ,
    first_cycle BIGINT,
    last_cycle BIGINT,
    n_rows BIGINT NOT NULL
);
"""

_HOLE_SQL_TYPES = {"int": "BIGINT", "float": "DOUBLE", "text": "VARCHAR", "time": "TIMESTAMPTZ"}
_HOLE_DB_COLUMNS = ("recording_id", "machine", *HOLE_TABLE_COLUMNS, "start_ns", "extra")
_HOLES_SCHEMA = (
    "CREATE TABLE IF NOT EXISTS holes (recording_id VARCHAR NOT NULL, machine VARCHAR NOT NULL, "
    + ", ".join(f'"{c}" {_HOLE_SQL_TYPES[k]}' + (" NOT NULL" if c == "hole" else "")
                for c, k in HOLE_TABLE_COLUMNS.items())
    + ", start_ns BIGINT, extra VARCHAR NOT NULL, PRIMARY KEY (recording_id, hole))"
)


def _path_part(value: str) -> str:
    return urllib.parse.quote(value, safe="._-") if value else "_none_"


def hf_table(rec: Recording, recording_id: str, rows: slice | None = None) -> pa.Table:
    """The HF table of ``rec`` (optionally some rows) as stored in a Parquet file.

    Columns ``recording_id`` (dictionary string), ``cycle`` (int64), ``time``
    (timestamp[ns, UTC]) and the signals (float64, field metadata ``unit``).

    Parameters
    ----------
    rec : Recording
        The recording.
    recording_id : str
        The recording's id in the store.
    rows : slice, optional
        Rows to take; default all.

    Returns
    -------
    pyarrow.Table
    """
    hf = rec.hf if rows is None else rec.hf.iloc[rows]
    n = len(hf)
    arrays: list[pa.Array] = [
        pa.DictionaryArray.from_arrays(
            pa.array(np.zeros(n, dtype=np.int32)), pa.array([recording_id])
        ),
        pa.array(hf.index.to_numpy(dtype=np.int64)),
        pa.array(hf["time"].to_numpy(dtype="datetime64[ns]"), type=pa.timestamp("ns", tz="UTC")),
    ]
    fields = [
        pa.field("recording_id", pa.dictionary(pa.int32(), pa.string())),
        pa.field("cycle", pa.int64()),
        pa.field("time", pa.timestamp("ns", tz="UTC")),
    ]
    for col in rec.columns:
        arrays.append(pa.array(hf[col].to_numpy(dtype=np.float64)))
        fields.append(
            pa.field(col, pa.float64(), metadata={b"unit": rec.meta.units.get(col, "").encode()})
        )
    return pa.Table.from_arrays(arrays, schema=pa.schema(fields))


@dataclass(frozen=True)
class StagedRecording:
    """A recording written to a store's files but not yet in its catalog.

    Made by :func:`stage_recording` (in any process, without the catalog), entered by
    :meth:`DuckDBStore.commit` (in the one process that holds the catalog for writing).

    Attributes
    ----------
    root : str
        Store directory.
    recording_id : str
        Id.
    row : dict
        Catalog row.
    files : list of dict
        Rows of the ``files`` table.
    tmp_to_final : list of (str, str)
        Staged file (absolute) -> final path (relative to ``root``).
    """

    root: str
    recording_id: str
    row: dict[str, Any]
    files: list[dict[str, Any]]
    tmp_to_final: list[tuple[str, str]]


def _write_parquet(root: Path, table: pa.Table, rel: str, *, floats: Sequence[str] = (),
                   compression: str = "zstd", row_group_cycles: int = 65_536) -> str:
    path = root / rel
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    pq.write_table(
        table,
        tmp,
        compression=compression,
        row_group_size=row_group_cycles,
        use_dictionary=[c for c in table.column_names if c not in floats],
        use_byte_stream_split=list(floats) if floats else False,
    )
    return str(tmp)


def stage_recording(
    root: str | os.PathLike[str], rec: Recording, recording_id: str, *,
    row_group_cycles: int = 65_536, compression: str = "zstd",
) -> StagedRecording:
    """Write a recording's files into a store directory under temporary names.

    Needs no catalog connection, so any number of processes can stage at once (the fleet's
    parallel ingest); :meth:`DuckDBStore.commit` then enters it into the catalog.

    Parameters
    ----------
    root : str or path-like
        Store directory.
    rec : Recording
        The recording.
    recording_id : str
        Its id (:func:`~cnctwin.store.base.default_recording_id`).
    row_group_cycles, compression
        As :class:`DuckDBStore`.

    Returns
    -------
    StagedRecording
    """
    root = Path(root).expanduser().resolve()
    rid = check_recording_id(recording_id)
    mdir = f"machine={_path_part(rec.meta.machine)}"
    files: list[dict[str, Any]] = []
    tmp_to_final: list[tuple[str, str]] = []
    # HF, one file per UTC day
    if rec.n_cycles:
        t_ns = rec.hf["time"].to_numpy(dtype="datetime64[ns]").view(np.int64)
        days = t_ns // _NS_PER_DAY
        cycles = rec.cycles
        for day in np.unique(days):
            mask = days == day
            idx = np.flatnonzero(mask)
            day_str = str(np.datetime64(int(day), "D"))
            rel = f"hf/{mdir}/day={day_str}/{rid}.parquet"
            if idx.size == idx[-1] - idx[0] + 1:
                table = hf_table(rec, rid, slice(int(idx[0]), int(idx[-1]) + 1))
            else:  # time not monotonic across days: take the rows of this day
                table = hf_table(rec, rid).take(pa.array(idx))
            tmp = _write_parquet(root, table, rel, floats=rec.columns, compression=compression,
                                 row_group_cycles=row_group_cycles)
            tmp_to_final.append((tmp, rel))
            files.append(
                {
                    "kind": "hf", "name": "", "path": rel, "day": day_str,
                    "start_time": pd.Timestamp(int(t_ns[idx].min()), tz="UTC"),
                    "end_time": pd.Timestamp(int(t_ns[idx].max()), tz="UTC"),
                    "first_cycle": int(cycles[idx[0]]), "last_cycle": int(cycles[idx[-1]]),
                    "n_rows": int(idx.size),
                }
            )
    # LF and events, one file each per recording
    for kind, frame in (("lf", normalize_lf(rec.lf)), ("events", normalize_events(rec.events))):
        rel = f"{kind}/{mdir}/{rid}.parquet"
        frame.insert(0, "recording_id", rid)
        table = pa.Table.from_pandas(frame, preserve_index=False)
        tmp_to_final.append((_write_parquet(root, table, rel, compression=compression,
                                           row_group_cycles=row_group_cycles), rel))
        files.append(
            {"kind": kind, "name": "", "path": rel, "day": None, "start_time": None,
             "end_time": None, "first_cycle": None, "last_cycle": None,
             "n_rows": len(frame)}
        )
    external: dict[str, dict[str, Any]] = {}
    for i, (name, ch) in enumerate(rec.external.items()):
        rel = f"external/{mdir}/{rid}/{i:03d}_{_path_part(name)}.parquet"
        data = ch.data.copy()
        index_name = data.index.name or "time_s"
        data = data.reset_index(names=index_name)
        table = pa.Table.from_pandas(data, preserve_index=False)
        tmp_to_final.append((_write_parquet(root, table, rel, compression=compression,
                                           row_group_cycles=row_group_cycles), rel))
        files.append(
            {"kind": "external", "name": name, "path": rel, "day": None, "start_time": None,
             "end_time": None, "first_cycle": None, "last_cycle": None,
             "n_rows": len(data)}
        )
        external[name] = {"path": rel, **external_meta(ch)}
    row = catalog_row(rec, rid)
    row["external"] = json.dumps(external)
    row["ingested_at"] = pd.Timestamp.now(tz="UTC")
    return StagedRecording(str(root), rid, row, files, tmp_to_final)


class DuckDBStore(Store):
    """Recordings in Parquet files under ``root`` with a DuckDB catalog.

    Parameters
    ----------
    root : str or path-like
        Store directory.
    create : bool, default True
        Create the directory and catalog if missing; with False a missing store raises
        :class:`~cnctwin.exceptions.StoreError`.
    row_group_cycles : int, default 65536
        Parquet row-group size of the HF files [cycles].
    compression : str, default 'zstd'
        Parquet compression codec.
    read_only : bool, default False
        Open the catalog read-only (several processes may then read at once).
    lock_timeout_s : float, default 0
        While another process holds the catalog, retry the open for up to this long [s]
        (backing off from 20 ms to 0.5 s) before raising.
    """

    def __init__(
        self,
        root: str | os.PathLike[str],
        *,
        create: bool = True,
        row_group_cycles: int = 65_536,
        compression: str = "zstd",
        read_only: bool = False,
        lock_timeout_s: float = 0.0,
    ) -> None:
        self.root = Path(root).expanduser().resolve()
        self.url = f"duckdb://{self.root}"
        self.row_group_cycles = int(row_group_cycles)
        self.compression = compression
        catalog = self.root / "catalog.duckdb"
        if not catalog.exists():
            if not create or read_only:
                raise StoreError(
                    f"no cnctwin store at {self.root} (missing catalog.duckdb); make one with "
                    f"`cnctwin ingest FILE... --store {self.root}` (in Python: "
                    "cnctwin.store.open(path) creates it)"
                )
            self.root.mkdir(parents=True, exist_ok=True)
        self._con: duckdb.DuckDBPyConnection | None = _connect(
            catalog, read_only=read_only, lock_timeout_s=lock_timeout_s)
        _run(self._con, "SET TimeZone = 'UTC'")
        if not read_only:
            _run(self._con, _SCHEMA)
            _run(self._con, _HOLES_SCHEMA)
            for c, k in HOLE_TABLE_COLUMNS.items():  # a column added since the store was made
                _run(self._con, f'ALTER TABLE holes ADD COLUMN IF NOT EXISTS "{c}" '
                                f"{_HOLE_SQL_TYPES[k]}")

    # ------------------------------------------------------------------ helpers
    @property
    def con(self) -> duckdb.DuckDBPyConnection:
        """The DuckDB connection to the catalog."""
        if self._con is None:
            raise StoreError(f"store {self.root} is closed")
        return self._con

    def _df(self, query: str, params: list[Any] | None = None) -> pd.DataFrame:
        rel = self.con.sql(query, params=params)
        if rel is None:  # a statement without a result
            return pd.DataFrame()
        return rel.to_arrow_table().to_pandas()

    def _abs(self, rel: str) -> Path:
        return self.root / rel

    def _existing_files(self, recording_id: str) -> list[str]:
        rows = _run(
            self.con,
            "SELECT path FROM files WHERE recording_id = ?", [recording_id]
        )
        return [r[0] for r in rows]

    # ------------------------------------------------------------------ write
    def ingest(self, rec: Recording, *, recording_id: str | None = None) -> str:
        rid = check_recording_id(
            recording_id if recording_id is not None else default_recording_id(rec)
        )
        staged = stage_recording(self.root, rec, rid, row_group_cycles=self.row_group_cycles,
                                 compression=self.compression)
        return self.commit(staged)

    def commit(self, staged: StagedRecording) -> str:
        """Enter a recording staged by :func:`stage_recording` into the catalog.

        The staged files are renamed into place and the catalog rows written in one
        transaction: a crash before it leaves only hidden ``.tmp`` files (no catalog entry),
        one after it a complete entry. Returns the recording id.

        Raises
        ------
        StoreError
            If the staged files belong to another store or are gone (staged by a process
            that crashed and cleaned up, or committed already).
        """
        if Path(staged.root).resolve() != self.root:
            raise StoreError(f"recording {staged.recording_id!r} was staged for the store "
                             f"{staged.root}, not {self.root}")
        missing = [t for t, _ in staged.tmp_to_final if not Path(t).exists()]
        if missing:
            raise StoreError(f"recording {staged.recording_id!r}: staged file {missing[0]} is "
                             "gone (committed already, or removed); ingest it again")
        rid, row, files, tmp_to_final = (staged.recording_id, staged.row, staged.files,
                                         staged.tmp_to_final)
        old = set(self._existing_files(rid))
        new = {rel for _, rel in tmp_to_final}
        con = self.con
        _run(con, "BEGIN TRANSACTION")
        try:
            _run(con, "DELETE FROM files WHERE recording_id = ?", [rid])
            _run(con, "DELETE FROM recordings WHERE recording_id = ?", [rid])
            cols = [*CATALOG_COLUMNS, "external", "ingested_at"]
            _run(con,
                f"INSERT INTO recordings ({', '.join(cols)}) "
                f"VALUES ({', '.join('?' for _ in cols)})",
                [row[c] for c in cols],
            )
            fcols = ["recording_id", "kind", "name", "path", "day", "start_time", "end_time",
                     "first_cycle", "last_cycle", "n_rows"]
            for f in files:
                f["recording_id"] = rid
                _run(con,
                    f"INSERT INTO files ({', '.join(fcols)}) "
                    f"VALUES ({', '.join('?' for _ in fcols)})",
                    [f[c] for c in fcols],
                )
            for tmp, rel in tmp_to_final:
                os.replace(tmp, self._abs(rel))
            _run(con, "COMMIT")
        except BaseException:
            _run(con, "ROLLBACK")
            for tmp, _ in tmp_to_final:
                Path(tmp).unlink(missing_ok=True)
            raise
        for rel in old - new:
            self._abs(rel).unlink(missing_ok=True)
        return rid

    def delete(self, recording_id: str) -> bool:
        old = self._existing_files(recording_id)
        n = _run(
            self.con,
            "SELECT count(*) FROM recordings WHERE recording_id = ?", [recording_id]
        )
        existed = bool(n[0][0])
        _run(self.con, "DELETE FROM files WHERE recording_id = ?", [recording_id])
        _run(self.con, "DELETE FROM recordings WHERE recording_id = ?", [recording_id])
        if self._has_holes_table():
            _run(self.con, "DELETE FROM holes WHERE recording_id = ?", [recording_id])
        for rel in old:
            self._abs(rel).unlink(missing_ok=True)
        return existed

    # ------------------------------------------------------------------ holes
    def _has_holes_table(self) -> bool:
        return bool(_run(self.con, "SELECT count(*) FROM information_schema.tables "
                                   "WHERE table_name = 'holes'")[0][0])

    def append_holes(
        self, recording_id: str, holes: pd.DataFrame | Sequence[dict[str, Any]]
    ) -> int:
        rows = hole_rows(holes)
        got = _run(self.con, "SELECT machine FROM recordings WHERE recording_id = ?",
                   [recording_id])
        if not got:
            self._catalog_entry(recording_id)  # raises StoreError naming stored ids
        machine = str(got[0][0])
        if not rows:
            return 0
        con = self.con
        cols = ", ".join(f'"{c}"' for c in _HOLE_DB_COLUMNS)
        _run(con, "BEGIN TRANSACTION")
        try:
            _run(con, "DELETE FROM holes WHERE recording_id = ? AND hole IN "
                      f"({', '.join('?' for _ in rows)})",
                 [recording_id, *(r["hole"] for r in rows)])
            con.executemany(
                f"INSERT INTO holes ({cols}) VALUES ({', '.join('?' for _ in _HOLE_DB_COLUMNS)})",
                [[recording_id, machine, *(r[c] for c in _HOLE_DB_COLUMNS[2:])] for r in rows],
            )
            _run(con, "COMMIT")
        except BaseException:
            _run(con, "ROLLBACK")
            raise
        return len(rows)

    def holes(
        self,
        *,
        recording_id: str | None = None,
        machine: str | None = None,
        start: pd.Timestamp | str | None = None,
        end: pd.Timestamp | str | None = None,
    ) -> pd.DataFrame:
        clauses: list[str] = []
        params: list[Any] = []
        for col, val in (("recording_id", recording_id), ("machine", machine)):
            if val is not None:
                clauses.append(f"{col} = ?")
                params.append(val)
        t0, t1 = to_utc(start), to_utc(end)
        if t0 is not None:
            clauses.append("start_ns >= ?")
            params.append(int(t0.value))
        if t1 is not None:
            clauses.append("start_ns <= ?")
            params.append(int(t1.value))
        where = ("WHERE " + " AND ".join(clauses)) if clauses else ""
        cols = [c for c in _HOLE_DB_COLUMNS if c != "start_time"]
        rows: list[Any] = []
        if self._has_holes_table():
            # a store opened read-only may predate a column: NULL there
            have = {r[0] for r in _run(self.con, "SELECT column_name FROM "
                                       "information_schema.columns WHERE table_name = 'holes'")}
            select = ", ".join(f'"{c}"' if c in have else f'NULL AS "{c}"' for c in cols)
            rows = _run(self.con, f"SELECT {select} FROM holes {where}", params)
        return holes_frame(rows, cols)

    # ------------------------------------------------------------------ read
    def recordings(
        self,
        *,
        machine: str | None = None,
        start: pd.Timestamp | str | None = None,
        end: pd.Timestamp | str | None = None,
    ) -> pd.DataFrame:
        return self._recordings(CATALOG_COLUMNS, machine, to_utc(start), to_utc(end))

    def _recordings(
        self,
        columns: Sequence[str],
        machine: str | None,
        start: pd.Timestamp | None,
        end: pd.Timestamp | None,
    ) -> pd.DataFrame:
        where, params = _catalog_filter(machine, start, end)
        out = self._df(
            f"SELECT {', '.join(columns)} FROM recordings {where} "
            "ORDER BY start_time, recording_id",
            params,
        )
        if "start_time" not in columns:
            return out
        for col in ("start_time", "end_time"):
            out[col] = pd.to_datetime(out[col], utc=True)
        return out

    def _catalog_entry(self, recording_id: str) -> tuple[str, str]:
        rows = _run(
            self.con,
            "SELECT meta, external FROM recordings WHERE recording_id = ?", [recording_id]
        )
        row = rows[0] if rows else None
        if row is None:
            some = [r[0] for r in _run(
            self.con,
                "SELECT recording_id FROM recordings ORDER BY start_time LIMIT 5"
            )]
            raise StoreError(
                f"recording {recording_id!r} is not in the store {self.root}; "
                f"ids there include: {', '.join(some) if some else '(store is empty)'}"
            )
        return str(row[0]), str(row[1])

    def _catalog_columns(
        self, *, machine: str | None, start: pd.Timestamp | None, end: pd.Timestamp | None
    ) -> pd.DataFrame:
        return self._recordings(("recording_id", "columns"), machine, start, end)

    def _require(self, recording_id: str) -> None:
        self._catalog_entry(recording_id)

    def _signal_frames(
        self,
        cols_by_rec: dict[str, list[str]],
        wanted: Sequence[str],
        start: pd.Timestamp | None,
        end: pd.Timestamp | None,
    ) -> list[pd.DataFrame]:
        ids = list(cols_by_rec)
        sel = _run(
            self.con,
            "SELECT recording_id, path FROM files WHERE kind = 'hf' AND recording_id IN "
            f"({', '.join('?' for _ in ids)})"
            + (" AND end_time >= ?" if start is not None else "")
            + (" AND start_time <= ?" if end is not None else "")
            + " ORDER BY recording_id, first_cycle",
            [*ids, *([start] if start is not None else []), *([end] if end is not None else [])],
        )
        filters: list[tuple[str, str, Any]] = []
        if start is not None:
            filters.append(("time", ">=", start))
        if end is not None:
            filters.append(("time", "<=", end))
        frames: list[pd.DataFrame] = []
        for rid, rel in sel:
            present = [c for c in wanted if c in cols_by_rec[rid]]
            table = pq.read_table(
                self._abs(rel),
                columns=["cycle", "time", *present],
                filters=filters or None,
            )
            frame = table.to_pandas()
            frame.insert(0, "recording_id", rid)
            frames.append(frame)
        return frames

    def load(self, recording_id: str, *, signals: Iterable[str] | None = None,
             cycles: tuple[int | None, int | None] | None = None) -> Recording:
        meta_text, external_text = self._catalog_entry(recording_id)
        meta = meta_from_json(meta_text)
        lo, hi = (None if c is None else int(c) for c in (cycles or (None, None)))
        rows = _run(
            self.con,
            "SELECT kind, path FROM files WHERE recording_id = ? AND (kind <> 'hf' OR ("
            "(? IS NULL OR last_cycle IS NULL OR last_cycle >= ?) AND "
            "(? IS NULL OR first_cycle IS NULL OR first_cycle <= ?))) "
            "ORDER BY kind, first_cycle",
            [recording_id, lo, lo, hi, hi],
        )
        by_kind: dict[str, list[str]] = {}
        for kind, rel in rows:
            by_kind.setdefault(kind, []).append(rel)
        columns = wanted_columns(json.loads(
            _run(
            self.con,
                "SELECT columns FROM recordings WHERE recording_id = ?", [recording_id]
            )[0][0]
        ), signals)
        hf_paths = by_kind.get("hf", [])
        if hf_paths:
            hf = pd.concat(
                [pq.read_table(self._abs(p), columns=["cycle", "time", *columns]).to_pandas()
                 for p in hf_paths], ignore_index=True
            )
            hf = hf.sort_values("cycle", kind="stable")
            hf = hf.set_index("cycle")
        else:
            hf = pd.DataFrame(
                {"time": pd.Series(dtype="datetime64[ns, UTC]"),
                 **{c: pd.Series(dtype="float64") for c in columns}},
                index=pd.Index([], dtype="int64", name="cycle"),
            )
        hf = hf[["time", *columns]]
        hf["time"] = hf["time"].astype("datetime64[ns, UTC]")
        lf = normalize_lf(pq.read_table(self._abs(by_kind["lf"][0])).to_pandas())
        events = normalize_events(pq.read_table(self._abs(by_kind["events"][0])).to_pandas())
        external: dict[str, ExternalChannel] = {}
        for name, d in json.loads(external_text).items():
            data = pq.read_table(self._abs(d["path"])).to_pandas()
            external[name] = external_channel(name, data, d)
        rec = Recording(hf, lf=lf, events=events, external=external, meta=meta)
        return rec if cycles is None else rec.select(cycles=cycles)

    def sql(self, query: str) -> pd.DataFrame:
        self._refresh_views()
        try:
            return self._df(query)
        except duckdb.Error as exc:
            raise StoreError(
                f"SQL failed on {self.url}: {exc}. Tables/views: recordings, files, holes, "
                "hf (wide), hf_long (recording_id, cycle, time, signal, value), lf, events"
            ) from exc

    def _refresh_views(self) -> None:
        con = self.con
        root = str(self.root).replace("'", "''")
        have = {
            k: bool(n)
            for k, n in _run(con,
                "SELECT kind, count(*) FROM files GROUP BY kind"
            )
        }
        if have.get("hf"):
            _run(con,
                "CREATE OR REPLACE TEMP VIEW hf AS SELECT * FROM "
                f"read_parquet('{root}/hf/*/*/*.parquet', union_by_name = true, "
                "hive_partitioning = true, hive_types = {'machine': VARCHAR, 'day': DATE})"
            )
            _run(con,
                "CREATE OR REPLACE TEMP VIEW hf_long AS SELECT recording_id, cycle, time, "
                "signal, value FROM (UNPIVOT (SELECT * EXCLUDE (machine) FROM hf) "
                "ON COLUMNS(* EXCLUDE (recording_id, cycle, time, day)) "
                "INTO NAME signal VALUE value)"
            )
        else:
            _run(con,
                "CREATE OR REPLACE TEMP VIEW hf AS SELECT NULL::VARCHAR AS recording_id, "
                "NULL::BIGINT AS cycle, NULL::TIMESTAMPTZ AS time, NULL::VARCHAR AS machine "
                "WHERE false"
            )
            _run(con,
                "CREATE OR REPLACE TEMP VIEW hf_long AS SELECT NULL::VARCHAR AS recording_id, "
                "NULL::BIGINT AS cycle, NULL::TIMESTAMPTZ AS time, NULL::VARCHAR AS signal, "
                "NULL::DOUBLE AS value WHERE false"
            )
        for kind in ("lf", "events"):
            if not have.get(kind):
                stub = normalize_lf(pd.DataFrame()) if kind == "lf" else normalize_events(
                    pd.DataFrame()
                )
                cols = ", ".join(
                    f"NULL::{_DUCK_TYPES.get(str(t), 'VARCHAR')} AS {c}"
                    for c, t in stub.dtypes.items()
                )
                _run(con, f"CREATE OR REPLACE TEMP VIEW {kind} AS SELECT {cols} WHERE false")
                continue
            _run(con,
                f"CREATE OR REPLACE TEMP VIEW {kind} AS SELECT * FROM "
                f"read_parquet('{root}/{kind}/*/*.parquet', union_by_name = true, "
                "hive_partitioning = true, hive_types = {'machine': VARCHAR})"
            )

    def close(self) -> None:
        if self._con is not None:
            self._con.close()
            self._con = None


def _connect(catalog: Path, *, read_only: bool, lock_timeout_s: float
             ) -> duckdb.DuckDBPyConnection:
    """Connect to the catalog, retrying while another process holds its lock."""
    deadline = time.monotonic() + max(float(lock_timeout_s), 0.0)
    delay = 0.02
    while True:
        try:
            return duckdb.connect(str(catalog), read_only=read_only)
        except duckdb.Error as exc:
            locked = "lock" in str(exc).lower()
            if locked and time.monotonic() + delay <= deadline:
                time.sleep(delay)
                delay = min(delay * 2, 0.5)
                continue
            if not locked:
                raise StoreError(f"cannot open the catalog {catalog}: {exc}") from exc
            pid = re.search(r"PID (\d+)", str(exc))
            who = f"process {pid.group(1)}" if pid else "another process"
            waited = f"; waited {lock_timeout_s:g} s" if lock_timeout_s > 0 else ""
            raise StoreError(
                f"the store catalog {catalog} is held by {who}{waited}. cnctwin's own "
                "commands hold it only while they write, so try again (or wait longer); a "
                "script that keeps cnctwin.store.open(...) open blocks everyone else until "
                "it closes the store"
            ) from exc


def _run(con: duckdb.DuckDBPyConnection, query: str, params: Any = None) -> list[Any]:
    """Execute and fetch everything (DuckDB 2 refuses new work while a result is pending)."""
    return con.execute(query, params).fetchall()


def _catalog_filter(
    machine: str | None, start: pd.Timestamp | None, end: pd.Timestamp | None
) -> tuple[str, list[Any]]:
    clauses: list[str] = []
    params: list[Any] = []
    if machine is not None:
        clauses.append("machine = ?")
        params.append(machine)
    if start is not None:
        clauses.append("end_time >= ?")
        params.append(start)
    if end is not None:
        clauses.append("start_time <= ?")
        params.append(end)
    return ("WHERE " + " AND ".join(clauses)) if clauses else "", params
