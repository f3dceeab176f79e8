"""Store subcommands: ``ingest`` (recordings into a store) and ``query`` (signals, catalog, SQL).

Examples::

    cnctwin ingest run1.json run2.json --store ./store
    cnctwin query --store ./store                                   # the catalog
    cnctwin query --store ./store --signals CURRENT|SP1 --start 2023-12-22T14:26:00Z
    cnctwin query --store postgresql://postgres@127.0.0.1/db --sql "SELECT count(*) FROM hf_block"
    cnctwin query --store ./store --signals CURRENT --out current.parquet
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from cnctwin.exceptions import ConfigError

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["register"]

_CATALOG_SUMMARY = ["recording_id", "machine", "start_time", "end_time", "n_cycles", "n_gaps",
                    "partial"]


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``ingest`` and ``query`` to ``sub``.

    Parameters
    ----------
    sub : argparse._SubParsersAction[argparse.ArgumentParser]
        The ``cnctwin`` subcommand parsers; the module adds its commands to them.
    """
    p = sub.add_parser(
        "ingest",
        help="store recordings (any readable format) in a DuckDB/Parquet or PostgreSQL store",
        description="Read each FILE with cnctwin.read_recording and store it; prints the ids. "
        "Ingesting the same file again replaces it (ids are deterministic).",
    )
    p.add_argument("files", nargs="+", metavar="FILE", help="recording files")
    p.add_argument("--store", required=True, metavar="URL",
                   help="directory, duckdb:///path or postgresql://user@host/db[?schema=name]")
    p.add_argument("--machine", metavar="NAME", help="override the machine name of every file")
    p.add_argument("--salvage", action="store_true",
                   help="keep what can be read from damaged files (stored as partial)")
    p.add_argument("--wait", metavar="S", type=float, default=60.0,
                   help="wait up to S seconds for an embedded store that another process is "
                   "writing (another ingest, edge run --store; default 60)")
    p.set_defaults(func=_ingest)

    q = sub.add_parser(
        "query",
        help="read signals, the catalog or a SQL result from a store",
        description="Without --signals or --sql, lists the recordings (the catalog).",
    )
    q.add_argument("--store", required=True, metavar="URL", help="store directory or URL")
    q.add_argument("--signals", metavar="LIST",
                   help="comma-separated codes or columns: CURRENT or CURRENT|SP1,ENC_POS|X1")
    q.add_argument("--machine", metavar="NAME", help="only this machine")
    q.add_argument("--start", metavar="ISO", help="from this UTC time (inclusive)")
    q.add_argument("--end", metavar="ISO", help="until this UTC time (inclusive)")
    q.add_argument("--recording", metavar="ID", help="only this recording id")
    q.add_argument("--sql", metavar="QUERY", help="run SQL (views: recordings, hf_long, lf, "
                   "events; DuckDB also hf)")
    q.add_argument("--out", metavar="FILE", type=Path, help="write the result (.csv or .parquet)")
    q.add_argument("--head", metavar="N", type=int, default=20,
                   help="rows to print when --out is not given (default 20)")
    q.set_defaults(func=_query)


def _ingest(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

    from cnctwin.iotools import read_recording
    from cnctwin.store import open as open_store

    err = Console(stderr=True)
    with open_store(args.store, lock_timeout_s=args.wait):  # made (or found) before reading
        pass
    with Progress(
        TextColumn("[progress.description]{task.description}"), BarColumn(),
        MofNCompleteColumn(), console=err, transient=True,
    ) as progress:
        task = progress.add_task("ingesting", total=len(args.files))
        for f in args.files:
            progress.update(task, description=f"ingesting {Path(f).name}")
            rec = read_recording(f, salvage=args.salvage)
            if args.machine:
                rec.meta.machine = args.machine
            # an embedded store is held only while this file goes in: a dashboard or an
            # edge run beside it gets its turn between files
            with open_store(args.store, lock_timeout_s=args.wait) as st:
                rid = st.ingest(rec)
            print(f"{rid}\t{f}\t{rec.n_cycles} cycles{' PARTIAL' if rec.meta.partial else ''}")
            progress.advance(task)
    return 0


def _query(args: argparse.Namespace) -> int:
    import pandas as pd

    from cnctwin.store import open as open_store

    if args.sql and args.signals:
        raise ConfigError("give either --sql or --signals, not both")
    with open_store(args.store, create=False, read_only=True, lock_timeout_s=30.0) as st:
        if args.sql:
            result = st.sql(args.sql)
        elif args.signals:
            signals = [s.strip() for s in args.signals.split(",") if s.strip()]
            result = st.query_signals(
                signals, machine=args.machine, start=args.start, end=args.end,
                recording_id=args.recording,
            ).reset_index()
        else:
            result = st.recordings(machine=args.machine, start=args.start, end=args.end)
            if args.recording:
                result = result[result["recording_id"] == args.recording]
            if args.out is None:
                result = result[_CATALOG_SUMMARY]
    if args.out is not None:
        _write(result, args.out)
        print(f"wrote {len(result)} rows x {len(result.columns)} columns to {args.out}")
        return 0
    with pd.option_context("display.width", 200, "display.max_columns", 12):
        print(result.head(args.head).to_string(index=False))
    if len(result) > args.head:
        print(f"... {len(result)} rows in all (use --out FILE to write them)")
    return 0


def _write(frame: pd.DataFrame, path: Path) -> None:
    suffix = path.suffix.lower()
    if suffix == ".csv":
        frame.to_csv(path, index=False)
    elif suffix == ".parquet":
        frame.to_parquet(path, index=False)
    else:
        raise ConfigError(f"--out {path}: use a .csv or .parquet file name")
    sys.stdout.flush()
