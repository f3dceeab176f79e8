"""The PostgreSQL store: HF signals as ``float8[]`` blocks of consecutive cycles.

Schema (in the schema named by the URL, default ``cnctwin``)::

    recordings(recording_id PK, machine, start_time, end_time, start_ns, end_ns, first_cycle,
               last_cycle, n_cycles, cycle_time_s, step_ns, columns jsonb, units jsonb,
               source_files jsonb, source_format, issues jsonb, partial, n_gaps, meta jsonb,
               external jsonb, ingested_at)
    hf_run(recording_id, first_cycle, n, t0_ns)          the time base: runs of consecutive
                                                          cycles with time = t0 + i * step
    hf_block(recording_id, signal, first_cycle, n, t0_ns, t0, samples float8[])
             PRIMARY KEY (recording_id, signal, first_cycle)
    lf(recording_id, cycle, time, time_ns, signal, value, text)
    events(recording_id, seq, cycle, kind, channel, ..., call_stack_level)
    external(recording_id, name, data bytea)               a Parquet file per channel
    holes(recording_id, machine, <HOLE_TABLE_COLUMNS>, start_ns, extra jsonb)
             PRIMARY KEY (recording_id, hole)              per-hole rows (append_holes)
    VIEW hf_long(recording_id, cycle, time, signal, value) unnests the blocks

Why blocks of arrays and not one row per value: a machine produces 500 Hz x ~70 signals =
35 k samples/s (up to 180 k with 6 axes x 60 signals). One row per value costs ~42 B/sample on
disk (24 B tuple header + 4 B line pointer + key columns + value; measured, reference
docs/reference/physics-and-performance.md section 5: ~650 GB/day/machine) and the COPY rate is
bound by
rows (0.23 M rows/s from Python, 1.75 M rows/s server-side). A block of 1000 cycles (2 s) of
one signal is one row of ~8 kB: per-row overhead is amortised over 1000 samples, so storage is
<= 8 B/sample (the float64 itself; TOAST compresses where the values allow, with lz4 when the
server has it) and the COPY moves 18 000 rows for 18 M samples (benchmarks/bench_store.py).
Keeping one signal per row (instead of one cycle per row with all signals, ~4.3 B/sample with
real[] in section 5) means a query for one signal reads only that signal's blocks, float64
values round-trip exactly, and recordings with different signal sets need no schema change.
Blocks never cross a counter gap or a break of the linear time axis, so
``cycle = first_cycle + i`` and ``time = t0_ns + i * step_ns`` inside a block.

Ingest runs in one transaction (delete the id, insert the catalog row, binary COPY of the blocks
built with numpy); a query selects only the blocks of the wanted signals that overlap the time
range and decodes them with numpy from ``array_send``.
"""

from __future__ import annotations

import io
import json
import struct
import urllib.parse
from collections.abc import Iterable, Iterator, Sequence
from typing import Any

import numpy as np
import pandas as pd
import psycopg
import pyarrow as pa
import pyarrow.parquet as pq
from psycopg import sql as psql

from cnctwin.exceptions import ConfigError, StoreError
from cnctwin.recording import ExternalChannel, Recording, meta_from_json
from cnctwin.store.base import (
    CATALOG_COLUMNS,
    HOLE_TABLE_COLUMNS,
    Store,
    block_bounds,
    catalog_row,
    check_recording_id,
    default_recording_id,
    external_channel,
    external_meta,
    hole_rows,
    holes_frame,
    normalize_events,
    normalize_lf,
    time_runs,
    to_utc,
    wanted_columns,
)

__all__ = ["DEFAULT_SCHEMA", "PostgresStore", "hf_block_copy", "parse_pg_url"]

DEFAULT_SCHEMA = "cnctwin"
_PG_EPOCH_NS = 946_684_800 * 10**9  # 2000-01-01T00:00:00Z, the timestamptz zero
_COPY_HEADER = b"PGCOPY\n\xff\r\n\x00" + struct.pack(">ii", 0, 0)
_COPY_TRAILER = struct.pack(">h", -1)
_FLOAT8_OID = 701
_ELEM = np.dtype([("len", ">i4"), ("value", ">f8")])

_DDL = """
CREATE SCHEMA IF NOT EXISTS {s};
CREATE TABLE IF NOT EXISTS {s}.recordings (
    recording_id text PRIMARY KEY,
    machine text NOT NULL,
    start_time timestamptz,
    end_time timestamptz,
    start_ns bigint,
    end_ns bigint,
    first_cycle bigint,
    last_cycle bigint,
    n_cycles bigint NOT NULL,
    cycle_time_s double precision NOT NULL,
    step_ns bigint NOT NULL,
    columns jsonb NOT NULL,
    units jsonb NOT NULL,
    source_files jsonb NOT NULL,
    source_format text NOT NULL,
    issues jsonb NOT NULL,
    partial boolean NOT NULL,
    n_gaps integer NOT NULL,
    meta jsonb NOT NULL,
    external jsonb NOT NULL,
    ingested_at timestamptz NOT NULL DEFAULT now()
);
CREATE INDEX IF NOT EXISTS recordings_machine_time
    ON {s}.recordings (machine, start_time, end_time);
CREATE INDEX IF NOT EXISTS recordings_time ON {s}.recordings (start_time, end_time);
CREATE TABLE IF NOT EXISTS {s}.hf_run (
    recording_id text NOT NULL REFERENCES {s}.recordings ON DELETE CASCADE,
    first_cycle bigint NOT NULL,
    n integer NOT NULL,
    t0_ns bigint NOT NULL,
    PRIMARY KEY (recording_id, first_cycle)
);
CREATE TABLE IF NOT EXISTS {s}.hf_block (
    recording_id text NOT NULL REFERENCES {s}.recordings ON DELETE CASCADE,
    signal text NOT NULL,
    first_cycle bigint NOT NULL,
    n integer NOT NULL,
    t0_ns bigint NOT NULL,
    t0 timestamptz NOT NULL,
    samples float8[] NOT NULL,
    PRIMARY KEY (recording_id, signal, first_cycle)
);
CREATE TABLE IF NOT EXISTS {s}.lf (
    recording_id text NOT NULL REFERENCES {s}.recordings ON DELETE CASCADE,
    seq integer NOT NULL,
    cycle bigint NOT NULL,
    time timestamptz,
    time_ns bigint,
    signal text,
    value double precision,
    text text,
    PRIMARY KEY (recording_id, seq)
);
CREATE TABLE IF NOT EXISTS {s}.events (
    recording_id text NOT NULL REFERENCES {s}.recordings ON DELETE CASCADE,
    seq integer NOT NULL,
    cycle bigint NOT NULL,
    kind text,
    channel bigint,
    seek_offset bigint,
    gcode text,
    ipo_gcode text,
    selected_tool bigint,
    active_tool bigint,
    path text,
    call_stack_level bigint,
    PRIMARY KEY (recording_id, seq)
);
CREATE TABLE IF NOT EXISTS {s}.external (
    recording_id text NOT NULL REFERENCES {s}.recordings ON DELETE CASCADE,
    name text NOT NULL,
    data bytea NOT NULL,
    PRIMARY KEY (recording_id, name)
);
CREATE OR REPLACE VIEW {s}.hf_long AS
SELECT b.recording_id,
       b.first_cycle + u.i - 1 AS cycle,
       b.t0 + ((u.i - 1) * r.step_ns / 1000) * interval '1 microsecond' AS time,
       b.signal,
       u.value
FROM {s}.hf_block b
JOIN {s}.recordings r USING (recording_id)
CROSS JOIN LATERAL unnest(b.samples) WITH ORDINALITY AS u(value, i);
"""

_HOLE_SQL_TYPES = {"int": "bigint", "float": "double precision", "text": "text",
                   "time": "timestamptz"}
_HOLE_DB_COLUMNS = ("recording_id", "machine", *HOLE_TABLE_COLUMNS, "start_ns", "extra")
# no foreign key to recordings: ingest() replaces a recording by delete + insert, which would
# cascade to its holes; delete() removes them explicitly instead
_HOLES_DDL = (
    "CREATE TABLE IF NOT EXISTS {s}.holes (recording_id text NOT NULL, machine text NOT NULL, "
    + ", ".join(f'"{c}" {_HOLE_SQL_TYPES[k]}' + (" NOT NULL" if c == "hole" else "")
                for c, k in HOLE_TABLE_COLUMNS.items())
    + ", start_ns bigint, extra jsonb NOT NULL, PRIMARY KEY (recording_id, hole));"
    " CREATE INDEX IF NOT EXISTS holes_machine_time ON {s}.holes (machine, start_ns);"
)

_EVENT_SQL_COLUMNS = (
    "cycle", "kind", "channel", "seek_offset", "gcode", "ipo_gcode", "selected_tool",
    "active_tool", "path", "call_stack_level",
)


def parse_pg_url(url: str) -> tuple[str, str]:
    """Split a ``postgresql://`` URL into a libpq connection string and the schema name.

    The schema comes from a ``schema=`` query parameter, else the first entry of a
    ``search_path`` in ``options`` (``options=-csearch_path%3Dname``), else
    :data:`DEFAULT_SCHEMA`. ``schema=`` is removed from the returned URL (libpq rejects it).

    Parameters
    ----------
    url : str
        ``postgresql://user@host:port/db?schema=name``.

    Returns
    -------
    tuple
        (libpq connection string without ``schema=``, schema name).
    """
    parts = urllib.parse.urlsplit(url)
    query = urllib.parse.parse_qsl(parts.query, keep_blank_values=True)
    schema = None
    kept = []
    for k, v in query:
        if k == "schema":
            schema = v
        else:
            kept.append((k, v))
            if k == "options" and schema is None:
                for opt in v.replace("-c ", "-c").split():
                    if opt.startswith("-csearch_path="):
                        schema = opt.split("=", 1)[1].split(",")[0].strip().strip('"')
    conninfo = urllib.parse.urlunsplit(
        (parts.scheme, parts.netloc, parts.path, urllib.parse.urlencode(kept), parts.fragment)
    )
    schema = schema or DEFAULT_SCHEMA
    if not schema.replace("_", "a").isalnum() or schema[0].isdigit():
        raise ConfigError(
            f"schema name {schema!r} in the store URL is not valid: use letters, digits and _"
        )
    return conninfo, schema


def _redact(url: str) -> str:
    parts = urllib.parse.urlsplit(url)
    if parts.password:
        netloc = parts.netloc.replace(f":{parts.password}@", ":***@")
        return urllib.parse.urlunsplit(parts._replace(netloc=netloc))
    return url


def _text(value: str) -> bytes:
    b = value.encode()
    return struct.pack(">i", len(b)) + b


def hf_block_copy(
    rec: Recording, recording_id: str, *, block_cycles: int = 1000
) -> Iterator[bytes]:
    """The binary COPY stream of ``rec``'s HF blocks for table ``hf_block``.

    Parameters
    ----------
    rec : Recording
        The recording.
    recording_id : str
        Its id.
    block_cycles : int, default 1000
        Maximum cycles per block (1000 = 2 s at 2 ms).

    Yields
    ------
    bytes
        Header, then one chunk per signal (all its blocks), then the trailer. Columns:
        ``recording_id, signal, first_cycle, n, t0_ns, t0, samples``.

    Notes
    -----
    PostgreSQL binary COPY: each tuple is an int16 field count and per field an int32 length
    and the value in network byte order; ``timestamptz`` is int64 microseconds since
    2000-01-01 UTC; an array is ``ndim, has_null, element oid, (dim, lower bound) per dim``
    followed by (int32 length, value) per element. The elements of a whole signal are built
    in one numpy structured array, so the cost per sample is a memory copy.
    """
    cycles = rec.cycles
    t_ns = rec.hf["time"].to_numpy(dtype="datetime64[ns]").view(np.int64)
    step_ns = round(rec.meta.cycle_time_s * 1e9)
    blocks = block_bounds(time_runs(cycles, t_ns, step_ns=step_ns), block_cycles=block_cycles)
    rid = _text(recording_id)
    prefixes = [
        (
            s,
            n,
            struct.pack(">iqiiiqiq", 8, int(cycles[s]), 4, n, 8, int(t_ns[s]), 8,
                        (int(t_ns[s]) - _PG_EPOCH_NS) // 1000)
            + struct.pack(">iiiIii", 20 + 12 * n, 1, 0, _FLOAT8_OID, n, 1),
        )
        for s, n in blocks
    ]
    yield _COPY_HEADER
    elem = np.empty(len(cycles), dtype=_ELEM)
    elem["len"] = 8
    for col in rec.columns:
        elem["value"] = rec.hf[col].to_numpy(dtype=np.float64)
        raw = memoryview(elem.tobytes())
        head = struct.pack(">h", 7) + rid + _text(col)
        parts: list[bytes | memoryview] = []
        for s, n, prefix in prefixes:
            parts.append(head)
            parts.append(prefix)
            parts.append(raw[12 * s: 12 * (s + n)])
        yield b"".join(parts)
    yield _COPY_TRAILER


def _decode_float8_array(buf: bytes) -> np.ndarray:
    """Decode ``array_send(float8[])`` output to a float64 array."""
    ndim, has_null, _oid = struct.unpack_from(">iiI", buf, 0)
    if ndim == 0:
        return np.empty(0)
    (n,) = struct.unpack_from(">i", buf, 12)
    if not has_null:
        return np.frombuffer(buf, dtype=_ELEM, count=n, offset=20)["value"].astype(np.float64)
    out = np.empty(n)  # pragma: no cover - the store never writes NULL elements
    pos = 20
    for i in range(n):
        (length,) = struct.unpack_from(">i", buf, pos)
        pos += 4
        if length < 0:
            out[i] = np.nan
        else:
            out[i] = struct.unpack_from(">d", buf, pos)[0]
            pos += length
    return out


class PostgresStore(Store):
    """Recordings in a PostgreSQL schema (see the module docstring for the layout).

    Parameters
    ----------
    url : str
        ``postgresql://user[:password]@host[:port]/database[?schema=name]``.
    create : bool, default True
        Create the schema and tables if missing (idempotent); with False a missing schema
        raises :class:`~cnctwin.exceptions.StoreError`.
    block_cycles : int, default 1000
        Cycles per ``hf_block`` row (1000 = 2 s at 2 ms).
    """

    def __init__(self, url: str, *, create: bool = True, block_cycles: int = 1000) -> None:
        self.url = _redact(url)
        conninfo, self.schema = parse_pg_url(url)
        self.block_cycles = int(block_cycles)
        if self.block_cycles < 1:
            raise ConfigError(f"block_cycles must be >= 1, not {block_cycles}")
        try:
            self._conn: psycopg.Connection[Any] | None = psycopg.connect(
                conninfo, autocommit=True, connect_timeout=10
            )
        except psycopg.Error as exc:
            raise StoreError(
                f"cannot connect to PostgreSQL at {self.url}: {' '.join(str(exc).split())}"
                + "; start the server or check host, port, user and database in the URL"
            ) from exc
        s = psql.Identifier(self.schema)
        exists = self.conn.execute(
            "SELECT 1 FROM information_schema.tables "
            "WHERE table_schema = %s AND table_name = 'recordings'",
            [self.schema],
        ).fetchone()
        if not exists:
            if not create:
                self.close()
                raise StoreError(
                    f"no cnctwin schema {self.schema!r} at {self.url}; open the store with "
                    "create=True to make it"
                )
            with self.conn.transaction():
                self.conn.execute("SELECT pg_advisory_xact_lock(hashtext('cnctwin.ddl'))")
                self.conn.execute(psql.SQL(_DDL).format(s=s))
            try:  # lz4 TOAST compression: 2.7x the ingest rate of pglz at the same size
                with self.conn.transaction():
                    self.conn.execute(
                        psql.SQL("ALTER TABLE {} ALTER COLUMN samples SET COMPRESSION lz4")
                        .format(self._t("hf_block"))
                    )
            except psycopg.Error:  # pragma: no cover - server built without lz4
                pass
        if create:  # the hole table came later than the schema: add it to older stores too
            with self.conn.transaction():
                self.conn.execute("SELECT pg_advisory_xact_lock(hashtext('cnctwin.ddl'))")
                self.conn.execute(psql.SQL(_HOLES_DDL).format(s=s))
                for c, k in HOLE_TABLE_COLUMNS.items():  # columns added since the store
                    self.conn.execute(psql.SQL(
                        "ALTER TABLE {s}.holes ADD COLUMN IF NOT EXISTS {c} " + _HOLE_SQL_TYPES[k]
                    ).format(s=s, c=psql.Identifier(c)))
        self.conn.execute(
            psql.SQL("SET search_path TO {s}, public").format(s=s)
        )

    @property
    def conn(self) -> psycopg.Connection[Any]:
        """The psycopg connection."""
        if self._conn is None:
            raise StoreError(f"store {self.url} is closed")
        return self._conn

    def _t(self, name: str) -> psql.Composed:
        return psql.SQL("{}.{}").format(psql.Identifier(self.schema), psql.Identifier(name))

    # ------------------------------------------------------------------ write
    def ingest(self, rec: Recording, *, recording_id: str | None = None) -> str:
        rid = check_recording_id(
            recording_id if recording_id is not None else default_recording_id(rec)
        )
        row = catalog_row(rec, rid)
        step_ns = round(rec.meta.cycle_time_s * 1e9)
        cycles = rec.cycles
        t_ns = rec.hf["time"].to_numpy(dtype="datetime64[ns]").view(np.int64)
        external = {name: external_meta(ch) for name, ch in rec.external.items()}
        conn = self.conn
        with conn.transaction():
            conn.execute("SELECT pg_advisory_xact_lock(hashtext(%s))", [rid])
            conn.execute(
                psql.SQL("DELETE FROM {} WHERE recording_id = %s").format(
                    self._t("recordings")
                ),
                [rid],
            )
            cols = [*CATALOG_COLUMNS, "start_ns", "end_ns", "step_ns", "external"]
            values = dict(row)
            values["start_ns"] = int(t_ns[0]) if t_ns.size else None
            values["end_ns"] = int(t_ns[-1]) if t_ns.size else None
            values["step_ns"] = step_ns
            values["external"] = json.dumps(external)
            conn.execute(
                psql.SQL("INSERT INTO {} ({}) VALUES ({})").format(
                    self._t("recordings"),
                    psql.SQL(", ").join(psql.Identifier(c) for c in cols),
                    psql.SQL(", ").join(psql.Placeholder() for _ in cols),
                ),
                [values[c] for c in cols],
            )
            with conn.cursor() as cur:
                with cur.copy(
                    psql.SQL("COPY {} (recording_id, first_cycle, n, t0_ns) FROM STDIN").format(
                        self._t("hf_run")
                    )
                ) as cp:
                    for r in time_runs(cycles, t_ns, step_ns=step_ns):
                        cp.write_row((rid, r.first_cycle, r.n, r.t0_ns))
                with cur.copy(
                    psql.SQL(
                        "COPY {} (recording_id, signal, first_cycle, n, t0_ns, t0, samples) "
                        "FROM STDIN (FORMAT BINARY)"
                    ).format(self._t("hf_block"))
                ) as cp:
                    for chunk in hf_block_copy(rec, rid, block_cycles=self.block_cycles):
                        cp.write(chunk)
                lf = normalize_lf(rec.lf)
                if len(lf):
                    lf_ns = lf["time"].to_numpy(dtype="datetime64[ns]").view(np.int64)
                    nat = lf["time"].isna().to_numpy()
                    with cur.copy(
                        psql.SQL(
                            "COPY {} (recording_id, seq, cycle, time, time_ns, signal, value, "
                            "text) FROM STDIN"
                        ).format(self._t("lf"))
                    ) as cp:
                        for i, (c, t, sg, v, tx) in enumerate(
                            lf[["cycle", "time", "signal", "value", "text"]].itertuples(
                                index=False, name=None
                            )
                        ):
                            cp.write_row(
                                (rid, i, int(c), None if nat[i] else t.floor("us").to_pydatetime(),
                                 None if nat[i] else int(lf_ns[i]), sg,
                                 None if pd.isna(v) else float(v), tx)
                            )
                ev = normalize_events(rec.events)
                if len(ev):
                    with cur.copy(
                        psql.SQL("COPY {} (recording_id, seq, {}) FROM STDIN").format(
                            self._t("events"),
                            psql.SQL(", ").join(psql.Identifier(c) for c in _EVENT_SQL_COLUMNS),
                        )
                    ) as cp:
                        for i, tup in enumerate(
                            ev[list(_EVENT_SQL_COLUMNS)].itertuples(index=False, name=None)
                        ):
                            cp.write_row(
                                (rid, i, *(None if v is pd.NA or v is None else
                                           (int(v) if isinstance(v, np.integer) else v)
                                           for v in tup))
                            )
                for name, ch in rec.external.items():
                    buf = io.BytesIO()
                    pq.write_table(
                        pa.Table.from_pandas(
                            ch.data.reset_index(names=external[name]["index"]),
                            preserve_index=False,
                        ),
                        buf,
                    )
                    cur.execute(
                        psql.SQL("INSERT INTO {} (recording_id, name, data) VALUES (%s, %s, %s)")
                        .format(self._t("external")),
                        [rid, name, buf.getvalue()],
                    )
        return rid

    def delete(self, recording_id: str) -> bool:
        if self._has_holes_table():
            self.conn.execute(
                psql.SQL("DELETE FROM {} WHERE recording_id = %s").format(self._t("holes")),
                [recording_id],
            )
        cur = self.conn.execute(
            psql.SQL("DELETE FROM {} WHERE recording_id = %s").format(self._t("recordings")),
            [recording_id],
        )
        return cur.rowcount > 0

    # ------------------------------------------------------------------ holes
    def _has_holes_table(self) -> bool:
        return self.conn.execute(
            "SELECT 1 FROM information_schema.tables WHERE table_schema = %s "
            "AND table_name = 'holes'", [self.schema]).fetchone() is not None

    def append_holes(
        self, recording_id: str, holes: pd.DataFrame | Sequence[dict[str, Any]]
    ) -> int:
        rows = hole_rows(holes)
        got = self.conn.execute(
            psql.SQL("SELECT machine FROM {} WHERE recording_id = %s").format(
                self._t("recordings")), [recording_id]).fetchone()
        if got is None:
            self._meta_row(recording_id)  # raises StoreError naming stored ids
            raise AssertionError("unreachable")  # pragma: no cover
        machine = str(got[0])
        if not rows:
            return 0
        cols = psql.SQL(", ").join(psql.Identifier(c) for c in _HOLE_DB_COLUMNS)
        conn = self.conn
        with conn.transaction():
            conn.execute(
                psql.SQL("DELETE FROM {} WHERE recording_id = %s AND hole = ANY(%s)").format(
                    self._t("holes")), [recording_id, [r["hole"] for r in rows]])
            with conn.cursor() as cur:
                cur.executemany(
                    psql.SQL("INSERT INTO {} ({}) VALUES ({})").format(
                        self._t("holes"), cols,
                        psql.SQL(", ").join(psql.Placeholder() for _ in _HOLE_DB_COLUMNS)),
                    [[recording_id, machine, *(r[c] for c in _HOLE_DB_COLUMNS[2:])]
                     for r in rows],
                )
        return len(rows)

    def holes(
        self,
        *,
        recording_id: str | None = None,
        machine: str | None = None,
        start: pd.Timestamp | str | None = None,
        end: pd.Timestamp | str | None = None,
    ) -> pd.DataFrame:
        cols = [c for c in _HOLE_DB_COLUMNS if c != "start_time"]
        if not self._has_holes_table():
            return holes_frame([], cols)
        clauses: list[psql.Composable] = []
        params: list[Any] = []
        for col, val in (("recording_id", recording_id), ("machine", machine)):
            if val is not None:
                clauses.append(psql.SQL("{} = %s").format(psql.Identifier(col)))
                params.append(val)
        t0, t1 = to_utc(start), to_utc(end)
        if t0 is not None:
            clauses.append(psql.SQL("start_ns >= %s"))
            params.append(int(t0.value))
        if t1 is not None:
            clauses.append(psql.SQL("start_ns <= %s"))
            params.append(int(t1.value))
        where = (
            psql.SQL("WHERE ") + psql.SQL(" AND ").join(clauses) if clauses else psql.SQL("")
        )
        select = psql.SQL(", ").join(
            psql.SQL("extra::text") if c == "extra" else psql.Identifier(c) for c in cols)
        rows = self.conn.execute(
            psql.SQL("SELECT {} FROM {} {}").format(select, self._t("holes"), where), params
        ).fetchall()
        return holes_frame(rows, cols)

    # ------------------------------------------------------------------ read
    def recordings(
        self,
        *,
        machine: str | None = None,
        start: pd.Timestamp | str | None = None,
        end: pd.Timestamp | str | None = None,
    ) -> pd.DataFrame:
        t0, t1 = to_utc(start), to_utc(end)
        clauses: list[psql.Composable] = []
        params: list[Any] = []
        if machine is not None:
            clauses.append(psql.SQL("machine = %s"))
            params.append(machine)
        if t0 is not None:
            clauses.append(psql.SQL("end_ns >= %s"))
            params.append(int(t0.value))
        if t1 is not None:
            clauses.append(psql.SQL("start_ns <= %s"))
            params.append(int(t1.value))
        where = (
            psql.SQL("WHERE ") + psql.SQL(" AND ").join(clauses) if clauses else psql.SQL("")
        )
        select = psql.SQL(", ").join(
            psql.SQL("{}::text").format(psql.Identifier(c))
            if c in ("columns", "units", "source_files", "issues", "meta")
            else psql.Identifier(c)
            for c in CATALOG_COLUMNS
        )
        cur = self.conn.execute(
            psql.SQL("SELECT {}, start_ns, end_ns FROM {} {} ORDER BY start_ns, recording_id")
            .format(select, self._t("recordings"), where),
            params,
        )
        rows = cur.fetchall()
        out = pd.DataFrame(rows, columns=[*CATALOG_COLUMNS, "start_ns", "end_ns"])
        # exact ns times from the *_ns columns (timestamptz holds microseconds)
        out["start_time"] = pd.to_datetime(out["start_ns"].astype("Int64"), unit="ns", utc=True)
        out["end_time"] = pd.to_datetime(out["end_ns"].astype("Int64"), unit="ns", utc=True)
        out = out.drop(columns=["start_ns", "end_ns"])
        for c in ("first_cycle", "last_cycle"):
            out[c] = out[c].astype("Int64")
        out["n_cycles"] = out["n_cycles"].astype("int64")
        out["n_gaps"] = out["n_gaps"].astype("int64")
        out["partial"] = out["partial"].astype(bool)
        out["cycle_time_s"] = out["cycle_time_s"].astype("float64")
        return out

    def _meta_row(self, recording_id: str) -> tuple[str, str, str]:
        row = self.conn.execute(
            psql.SQL(
                "SELECT meta::text, external::text, columns::text FROM {} "
                "WHERE recording_id = %s"
            ).format(self._t("recordings")),
            [recording_id],
        ).fetchone()
        if row is None:
            some = [
                r[0]
                for r in self.conn.execute(
                    psql.SQL("SELECT recording_id FROM {} ORDER BY start_ns LIMIT 5").format(
                        self._t("recordings")
                    )
                ).fetchall()
            ]
            raise StoreError(
                f"recording {recording_id!r} is not in the store {self.url} "
                f"(schema {self.schema}); ids there include: "
                f"{', '.join(some) if some else '(store is empty)'}"
            )
        return str(row[0]), str(row[1]), str(row[2])

    def _read_blocks(
        self,
        ids: Sequence[str],
        columns: Sequence[str],
        start_ns: int | None,
        end_ns: int | None,
    ) -> dict[tuple[str, str], tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """(recording, signal) -> (cycles, time_ns, values) of the blocks overlapping."""
        clauses = [psql.SQL("b.recording_id = ANY(%s)"), psql.SQL("b.signal = ANY(%s)")]
        params: list[Any] = [list(ids), list(columns)]
        if end_ns is not None:
            clauses.append(psql.SQL("b.t0_ns <= %s"))
            params.append(end_ns)
        if start_ns is not None:
            clauses.append(psql.SQL("b.t0_ns + (b.n - 1)::bigint * r.step_ns >= %s"))
            params.append(start_ns)
        q = psql.SQL(
            "SELECT b.recording_id, b.signal, b.first_cycle, b.n, b.t0_ns, r.step_ns, "
            "array_send(b.samples) FROM {} b JOIN {} r USING (recording_id) WHERE {} "
            "ORDER BY b.recording_id, b.signal, b.first_cycle"
        ).format(self._t("hf_block"), self._t("recordings"), psql.SQL(" AND ").join(clauses))
        parts: dict[tuple[str, str], list[tuple[int, int, int, int, bytes]]] = {}
        with self.conn.cursor(binary=True) as cur:
            cur.execute(q, params)
            for rid, sig, c0, n, t0, step, data in cur:
                parts.setdefault((rid, sig), []).append((c0, n, t0, step, data))
        out = {}
        for key, blocks in parts.items():
            cyc = np.concatenate(
                [np.arange(c0, c0 + n, dtype=np.int64) for c0, n, _, _, _ in blocks]
            )
            tns = np.concatenate(
                [t0 + np.arange(n, dtype=np.int64) * step for _, n, t0, step, _ in blocks]
            )
            vals = np.concatenate([_decode_float8_array(bytes(d)) for *_, d in blocks])
            out[key] = (cyc, tns, vals)
        return out

    def _catalog_columns(
        self, *, machine: str | None, start: pd.Timestamp | None, end: pd.Timestamp | None
    ) -> pd.DataFrame:
        return self.recordings(machine=machine, start=start, end=end)

    def _require(self, recording_id: str) -> None:
        self._meta_row(recording_id)

    def _signal_frames(
        self,
        cols_by_rec: dict[str, list[str]],
        wanted: Sequence[str],
        start: pd.Timestamp | None,
        end: pd.Timestamp | None,
    ) -> list[pd.DataFrame]:
        start_ns = int(start.value) if start is not None else None
        end_ns = int(end.value) if end is not None else None
        data = self._read_blocks(list(cols_by_rec), wanted, start_ns, end_ns)
        frames = []
        for rid in cols_by_rec:
            per = {sig: v for (r, sig), v in data.items() if r == rid}
            if not per:
                continue
            cyc, tns, _ = next(iter(per.values()))
            frame = pd.DataFrame({"cycle": cyc, "time_ns": tns})
            for sig in wanted:
                if sig not in per:
                    frame[sig] = np.nan
                elif np.array_equal(per[sig][0], cyc):
                    frame[sig] = per[sig][2]
                else:  # pragma: no cover - every signal of a recording has the same blocks
                    frame[sig] = pd.Series(per[sig][2], index=per[sig][0]).reindex(cyc).to_numpy()
            mask = np.ones(len(frame), dtype=bool)
            if start_ns is not None:
                mask &= tns >= start_ns
            if end_ns is not None:
                mask &= tns <= end_ns
            frame = frame[mask]
            frame.insert(0, "recording_id", rid)
            frame.insert(
                2, "time", pd.to_datetime(frame.pop("time_ns").to_numpy(), unit="ns", utc=True)
            )
            frames.append(frame)
        return frames

    def load(self, recording_id: str, *, signals: Iterable[str] | None = None,
             cycles: tuple[int | None, int | None] | None = None) -> Recording:
        meta_text, external_text, columns_text = self._meta_row(recording_id)
        meta = meta_from_json(meta_text)
        columns = wanted_columns(json.loads(columns_text), signals)
        runs = self.conn.execute(
            psql.SQL(
                "SELECT first_cycle, n, t0_ns FROM {} WHERE recording_id = %s ORDER BY first_cycle"
            ).format(self._t("hf_run")),
            [recording_id],
        ).fetchall()
        step_ns = round(meta.cycle_time_s * 1e9)
        if runs:
            cyc = np.concatenate([np.arange(c0, c0 + n, dtype=np.int64) for c0, n, _ in runs])
            tns = np.concatenate(
                [t0 + np.arange(n, dtype=np.int64) * step_ns for _, n, t0 in runs]
            )
        else:
            cyc = np.empty(0, dtype=np.int64)
            tns = np.empty(0, dtype=np.int64)
        data = self._read_blocks([recording_id], columns, None, None) if columns else {}
        hf = pd.DataFrame(
            {"time": pd.to_datetime(tns, unit="ns", utc=True)},
            index=pd.Index(cyc, name="cycle"),
        )
        for col in columns:
            got = data.get((recording_id, col))
            if got is None:
                raise StoreError(
                    f"recording {recording_id!r} lists signal {col!r} but hf_block holds no "
                    "rows for it; the store is inconsistent, re-ingest the recording"
                )
            if np.array_equal(got[0], cyc):
                hf[col] = got[2]
            else:
                hf[col] = pd.Series(got[2], index=got[0]).reindex(cyc).to_numpy()
        hf["time"] = hf["time"].astype("datetime64[ns, UTC]")
        lf_rows = self.conn.execute(
            psql.SQL(
                "SELECT cycle, time_ns, signal, value, text FROM {} WHERE recording_id = %s "
                "ORDER BY seq"
            ).format(self._t("lf")),
            [recording_id],
        ).fetchall()
        lf_raw = pd.DataFrame(lf_rows, columns=["cycle", "time_ns", "signal", "value", "text"])
        lf_raw["time"] = pd.to_datetime(lf_raw.pop("time_ns").astype("Int64"), unit="ns",
                                        utc=True)
        lf = normalize_lf(lf_raw)
        ev_rows = self.conn.execute(
            psql.SQL("SELECT {} FROM {} WHERE recording_id = %s ORDER BY seq").format(
                psql.SQL(", ").join(psql.Identifier(c) for c in _EVENT_SQL_COLUMNS),
                self._t("events"),
            ),
            [recording_id],
        ).fetchall()
        events = normalize_events(pd.DataFrame(ev_rows, columns=list(_EVENT_SQL_COLUMNS)))
        external: dict[str, ExternalChannel] = {}
        ext_meta = json.loads(external_text)
        for name, blob in self.conn.execute(
            psql.SQL("SELECT name, data FROM {} WHERE recording_id = %s").format(
                self._t("external")
            ),
            [recording_id],
        ).fetchall():
            d = ext_meta[name]
            frame = pq.read_table(io.BytesIO(bytes(blob))).to_pandas()
            external[name] = external_channel(name, frame, d)
        external = {k: external[k] for k in ext_meta if k in external}
        rec = Recording(hf, lf=lf, events=events, external=external, meta=meta)
        return rec if cycles is None else rec.select(cycles=cycles)

    def sql(self, query: str) -> pd.DataFrame:
        try:
            with self.conn.cursor() as cur:
                cur.execute(query)
                if cur.description is None:
                    return pd.DataFrame()
                names = [d.name for d in cur.description]
                return pd.DataFrame(cur.fetchall(), columns=names)
        except psycopg.Error as exc:
            raise StoreError(
                f"SQL failed on {self.url} (schema {self.schema}): {exc}. Tables: recordings, "
                "hf_run, hf_block, lf, events, external, holes; view hf_long (recording_id, cycle, "
                "time, signal, value)"
            ) from exc

    def close(self) -> None:
        if self._conn is not None:
            self._conn.close()
            self._conn = None
