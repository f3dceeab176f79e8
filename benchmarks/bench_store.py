"""Store benchmark: ingest throughput, one-signal range query, bytes on disk per sample.

Side by side in one run, on one synthetic recording of ``--signals`` HF signals at 500 Hz for
``--minutes`` minutes (default 60 x 10 min = 300 000 cycles = 18 M samples):

* DuckDB/Parquet store (``DuckDBStore.ingest``) against its floor, a plain
  ``pyarrow.parquet.write_table`` of the same table with the same codec (the store adds the
  table build, per-day split, catalog rows and atomic rename);
* PostgreSQL store (``float8[]`` blocks of 1000 cycles, binary COPY) against a narrow
  one-row-per-value table ``(time timestamptz, signal int2, value float8)`` with a btree on
  ``(signal, time)``, loaded by binary COPY built with numpy (the fast case for narrow rows: no
  Python per row) on a subset of ``--narrow-signals`` signals;
* query of one signal over ``--query-s`` seconds in the middle of the recording.

The signal mix imitates the real Capture4Analysis file (values carry 6 decimals; several feed-
forward/torque channels are constant zero): per group of six signals, 2 smooth sines with
small noise, 2 position ramps, 1 constant zero, 1 current-like noise, all rounded to 1e-6.

Run: ``.venv/bin/python benchmarks/bench_store.py`` (env ``CNCTWIN_PG_URL`` names the server;
a fresh database is created and dropped). Prints a Markdown table for BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import struct
import subprocess
import tempfile
import time
import urllib.parse
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
from numpy.typing import ArrayLike

from cnctwin.recording import Recording
from cnctwin.store import open as open_store
from cnctwin.store.duckdb_store import hf_table

CODES = ["CURRENT", "TORQUE", "CMD_SPEED", "ENC_POS", "DES_POS", "CTRL_DIFF", "CONT_DEV",
         "VEL_FFW", "TORQUE_FFW", "LOAD"]
AXES = ["X1", "Y1", "Z1", "B1", "C1", "SP1"]


def synthetic(n_cycles: int, n_signals: int, *, seed: int = 7) -> Recording:
    rng = np.random.default_rng(seed)
    cycles = np.arange(10_000_000, 10_000_000 + n_cycles, dtype=np.int64)
    t = (cycles - cycles[0]) * 0.002
    signals: dict[str, ArrayLike] = {}
    names = [f"{c}|{a}" for c in CODES for a in AXES][:n_signals]
    for i, name in enumerate(names):
        kind = i % 6
        if kind in (0, 1):
            v = 5 * np.sin(2 * np.pi * (0.2 + i * 0.05) * t) + rng.normal(0, 0.01, n_cycles)
        elif kind in (2, 3):
            v = np.cumsum(np.where(rng.random(n_cycles) < 0.999, 0.0133, -0.4)) + i
        elif kind == 4:
            v = np.zeros(n_cycles)
        else:
            v = rng.normal(0, 1.5, n_cycles)
        signals[name] = np.round(v, 6)
    return Recording.from_arrays(cycles, signals, start_time="2024-03-01T23:55:00",
                                 machine="bench")


def timed(fn: Callable[[], Any], repeat: int) -> tuple[float, Any]:
    best = float("inf")
    out = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def dir_bytes(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def narrow_copy(conn: Any, rec: Recording, columns: list[str]) -> int:
    """Binary COPY of one row per value into table ``narrow`` (vectorised, no Python per row)."""
    t_us = (rec.hf["time"].to_numpy(dtype="datetime64[ns]").view(np.int64)
            - 946_684_800 * 10**9) // 1000
    row = np.dtype([("nf", ">i2"), ("l1", ">i4"), ("t", ">i8"), ("l2", ">i4"), ("s", ">i2"),
                    ("l3", ">i4"), ("v", ">f8")])
    n = 0
    with conn.cursor() as cur, cur.copy(
        "COPY narrow (time, signal, value) FROM STDIN (FORMAT BINARY)"
    ) as cp:
        cp.write(b"PGCOPY\n\xff\r\n\x00" + struct.pack(">ii", 0, 0))
        for sid, col in enumerate(columns):
            a = np.empty(len(t_us), dtype=row)
            a["nf"], a["l1"], a["l2"], a["l3"] = 3, 8, 2, 8
            a["t"], a["s"], a["v"] = t_us, sid, rec.hf[col].to_numpy()
            cp.write(a.tobytes())
            n += len(a)
        cp.write(struct.pack(">h", -1))
    return n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--signals", type=int, default=60)
    ap.add_argument("--narrow-signals", type=int, default=6)
    ap.add_argument("--query-s", type=float, default=60.0)
    ap.add_argument("--repeat", type=int, default=2, help="ingest repetitions (best of)")
    ap.add_argument("--no-postgres", action="store_true")
    args = ap.parse_args()

    n_cycles = int(args.minutes * 60 * 500)
    rec = synthetic(n_cycles, args.signals)
    n_samples = n_cycles * len(rec.columns)
    mid = rec.hf["time"].iloc[n_cycles // 2]
    q0, q1 = mid, mid + pd.Timedelta(seconds=args.query_s)
    qsig = rec.columns[0]
    rows: list[tuple[str, str, str, str]] = []

    def msps(seconds: float, samples: int) -> str:
        return f"{samples / seconds / 1e6:.1f} M/s ({seconds:.2f} s)"

    work = Path(tempfile.mkdtemp(prefix="cnctwin-bench-"))
    try:
        # ---- Parquet floor
        table = hf_table(rec, "bench")
        base = work / "baseline.parquet"

        def write_base() -> None:
            pq.write_table(table, base, compression="zstd", row_group_size=65_536,
                           use_dictionary=["recording_id", "cycle", "time"],
                           use_byte_stream_split=rec.columns)

        t_base, _ = timed(write_base, args.repeat)
        plain = work / "plain_default.parquet"
        t_plain, _ = timed(lambda: pq.write_table(table, plain), args.repeat)

        def read_base() -> pd.DataFrame:
            return pq.read_table(base, columns=["cycle", "time", qsig],
                                 filters=[("time", ">=", q0), ("time", "<=", q1)]).to_pandas()

        tq_base, got = timed(read_base, 3)
        n_q = len(got)
        rows.append(("pyarrow write_table, zstd + byte_stream_split (floor)", msps(t_base,
                     n_samples), f"{base.stat().st_size / n_samples:.2f}",
                     f"{tq_base * 1e3:.1f} ms (pq.read_table + filter)"))
        rows.append(("pyarrow write_table, defaults (snappy, dictionary)",
                     msps(t_plain, n_samples), f"{plain.stat().st_size / n_samples:.2f}", "-"))

        # ---- DuckDB store
        root = work / "store"

        def ingest_duck() -> str:
            with open_store(root) as st:
                return st.ingest(rec, recording_id="bench")

        t_duck, _ = timed(ingest_duck, args.repeat)
        with open_store(root) as st:
            tq_duck, got = timed(lambda: st.query_signals([qsig], start=q0, end=q1), 3)
            assert len(got) == n_q, (len(got), n_q)
        rows.append(("DuckDBStore.ingest (Parquet per machine/day + catalog)",
                     msps(t_duck, n_samples), f"{dir_bytes(root / 'hf') / n_samples:.2f}",
                     f"{tq_duck * 1e3:.1f} ms (query_signals)"))

        # ---- PostgreSQL
        if not args.no_postgres:
            import psycopg

            admin = os.environ.get("CNCTWIN_PG_URL", "postgresql://postgres@127.0.0.1:5432/postgres")
            dbname = f"cnctwin_bench_{uuid.uuid4().hex[:10]}"
            parts = urllib.parse.urlsplit(admin)
            url = urllib.parse.urlunsplit(parts._replace(path=f"/{dbname}"))
            with psycopg.connect(admin, autocommit=True) as c:
                c.execute(f'CREATE DATABASE "{dbname}"')
            try:
                with open_store(url) as st:
                    def ingest_pg() -> str:
                        return st.ingest(rec, recording_id="bench")

                    t_pg, _ = timed(ingest_pg, args.repeat)
                    st.sql("VACUUM FULL hf_block")  # drop the replaced first ingest's rows
                    st.sql("VACUUM FULL hf_run")
                    size = int(st.sql("SELECT pg_total_relation_size('hf_block') + "
                                      "pg_total_relation_size('hf_run') AS b")["b"].iloc[0])
                    tq_pg, got = timed(lambda: st.query_signals([qsig], start=q0, end=q1), 3)
                    assert len(got) == n_q, (len(got), n_q)
                rows.append(("PostgresStore.ingest (float8[] x 1000 cycles, binary COPY)",
                             msps(t_pg, n_samples), f"{size / n_samples:.2f}",
                             f"{tq_pg * 1e3:.1f} ms (query_signals)"))
                sub = rec.columns[: args.narrow_signals]
                with psycopg.connect(url, autocommit=True) as c:
                    c.execute("CREATE TABLE narrow (time timestamptz NOT NULL, "
                              "signal smallint NOT NULL, value float8)")
                    c.execute("CREATE INDEX narrow_sig_time ON narrow (signal, time)")

                    def load_narrow() -> int:
                        c.execute("TRUNCATE narrow")
                        return narrow_copy(c, rec, sub)

                    t_nar, n_nar = timed(load_narrow, 1)
                    c.execute("CHECKPOINT")
                    nsize = int(c.execute("SELECT pg_total_relation_size('narrow')")
                                .fetchone()[0])  # type: ignore[index]

                    def q_narrow() -> np.ndarray:
                        with c.cursor(binary=True) as cur:
                            cur.execute("SELECT time, value FROM narrow WHERE signal = 0 AND "
                                        "time BETWEEN %s AND %s ORDER BY time", [q0, q1])
                            return np.array([r[1] for r in cur.fetchall()])

                    tq_nar, got_n = timed(q_narrow, 3)
                    assert len(got_n) == n_q, (len(got_n), n_q)
                rows.append((f"PG narrow row per value + btree, binary COPY "
                             f"({len(sub)} signals, {n_nar / 1e6:.1f} M rows)",
                             msps(t_nar, n_nar), f"{nsize / n_nar:.2f}",
                             f"{tq_nar * 1e3:.1f} ms (index range scan)"))
            finally:
                with psycopg.connect(admin, autocommit=True) as c:
                    c.execute(f'DROP DATABASE IF EXISTS "{dbname}" WITH (FORCE)')
    finally:
        shutil.rmtree(work, ignore_errors=True)

    cpu = subprocess.run(["lscpu"], capture_output=True, text=True).stdout
    model = next((ln.split(":", 1)[1].strip() for ln in cpu.splitlines()
                  if ln.startswith("Model name")), platform.processor())
    print(f"Machine: {model}, {os.cpu_count()} vCPU; Python {platform.python_version()}")
    print(f"Recording: {args.signals} signals x {n_cycles} cycles (500 Hz, {args.minutes:g} min)"
          f" = {n_samples / 1e6:.1f} M samples; query: {qsig} over {args.query_s:g} s "
          f"= {n_q} cycles; ingest best of {args.repeat}, query best of 3\n")
    print("| Path | Ingest throughput (samples/s) | Bytes on disk / sample | Query, 1 signal |")
    print("|---|---|---|---|")
    for r in rows:
        print(f"| {' | '.join(r)} |")


if __name__ == "__main__":
    main()
