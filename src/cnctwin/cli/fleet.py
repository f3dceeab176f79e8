"""Fleet subcommands on Dask: ``cnctwin fleet ingest|holes|wear|health|quality|compare``.

Examples::

    cnctwin simulate fleet --machines 20 --days 5 --cycles-per-day 2 --seed 1 --out fleet/
    cnctwin fleet ingest fleet/ --store fleet-store/
    cnctwin fleet health --store fleet-store/ --out results/      # health + alarms.parquet
    cnctwin fleet holes --store fleet-store/ --out results/ --scheduler tcp://10.0.0.5:8786

Every job runs on an embedded LocalCluster unless ``--scheduler`` (or ``CNCTWIN_SCHEDULER``)
names an existing one; the Dask dashboard link is printed and a progress bar follows the tasks.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["register", "run_cluster_tasks"]

_JOBS = ("holes", "wear", "health", "quality", "compare")


def _cluster_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scheduler", metavar="ADDR",
                   help="Dask scheduler (tcp://HOST:8786); default $CNCTWIN_SCHEDULER, else an "
                   "embedded LocalCluster with one worker per core")
    p.add_argument("--workers", type=int, metavar="N",
                   help="worker processes of the embedded cluster (default: the cores)")


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``fleet`` and its subcommands to ``sub``.

    Parameters
    ----------
    sub : argparse._SubParsersAction[argparse.ArgumentParser]
        The ``cnctwin`` subcommand parsers; the module adds its commands to them.
    """
    p = sub.add_parser("fleet", help="fleet analyses over a store, on Dask distributed",
                       description="Run an analysis for every (machine, day) of a store on a "
                       "Dask cluster; results are Parquet tables in --out.")
    fsub = p.add_subparsers(dest="fleet_command", metavar="JOB", required=True)
    i = fsub.add_parser("ingest", help="ingest many recordings in parallel (idempotent)",
                        description="Find the recordings in FILES and DIRS (recursively), hash "
                        "them and store the new ones. A file ingested twice is stored once; "
                        "a file that cannot be read is reported with its reason and skipped.")
    i.add_argument("paths", nargs="+", metavar="PATH", help="recording files or directories")
    i.add_argument("--store", required=True, metavar="URL",
                   help="directory, duckdb:///path or postgresql://user@host/db")
    i.add_argument("--machine", metavar="NAME", help="file every recording under this machine")
    _cluster_options(i)
    i.set_defaults(func=_cmd_ingest)
    for job in _JOBS:
        j = fsub.add_parser(job, help=_HELP[job], description=_HELP[job])
        j.add_argument("--store", required=True, metavar="URL", help="the store")
        j.add_argument("--out", required=True, type=Path, metavar="RES",
                       help="result directory (Parquet tables)")
        j.add_argument("--machine", dest="machines", action="append", metavar="NAME",
                       help="only this machine (repeatable)")
        if job != "quality":
            j.add_argument("--machines-dir", type=Path, metavar="DIR",
                           help="machine files <machine>.toml (cnctwin calibrate): each machine's "
                           "own spindle model; default the thesis machine's")
        if job == "health":
            w = j.add_mutually_exclusive_group()
            w.add_argument("--window-s", type=_positive_s, default=20.0, metavar="S",
                           help="seconds analysed per shift: the shift's first recordings, "
                           "whole, until S are covered (a longer recording: its first S); "
                           "default 20, about one part cycle")
            w.add_argument("--all-cycles", action="store_true",
                           help="analyse every recorded cycle (the cost grows with the "
                           "recorded time: ~30 us per cycle)")
            j.add_argument("--shift-hours", type=_positive_s, default=8.0, metavar="H",
                           help="shift length, shifts from 06:00 UTC (default 8)")
        _cluster_options(j)
        j.set_defaults(func=_cmd_job, job=job)


def _positive_s(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"{text!r}: give a positive number")
    return v


_HELP = {
    "holes": "per-hole records of every machine (RES/holes.parquet)",
    "wear": "wear trend per machine, tool and day (RES/holes.parquet, RES/wear.parquet)",
    "health": "servo and spindle health per machine and day with drift alarms "
              "(RES/health.parquet, RES/alarms.parquet)",
    "quality": "signal quality per recording: coverage, gaps, jitter (RES/quality.parquet)",
    "compare": "the same part program on different machines side by side (RES/compare.parquet)",
}


@contextmanager
def _client(args: argparse.Namespace) -> Iterator[Any]:
    from cnctwin.fleet import fleet_client

    with fleet_client(args.scheduler, n_workers=args.workers) as client:
        n = len(client.scheduler_info().get("workers", {}))
        print(f"Dask: {n} workers, dashboard {client.dashboard_link}", file=sys.stderr)
        yield client


@contextmanager
def _progress(label: str) -> Iterator[Callable[[int, int], None]]:
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeElapsedColumn

    with Progress("[progress.description]{task.description}", BarColumn(),
                  MofNCompleteColumn(), TimeElapsedColumn(), transient=True,
                  console=_console()) as bar:
        task = bar.add_task(label, total=None)

        def update(done: int, total: int) -> None:
            bar.update(task, completed=done, total=total)

        yield update


def _console() -> Any:
    from rich.console import Console

    return Console(stderr=True)


def run_cluster_tasks(args: argparse.Namespace, label: str, fn: Callable[..., Any],
                      items: list[Any], **kwargs: Any) -> list[Any]:
    """Run ``fn(item, **kwargs)`` over ``items`` on the job's cluster with a progress bar.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed options (``--scheduler``, ``--workers``).
    label : str
        Task key and progress-bar label.
    fn : callable
        Function run per item.
    items : list
        The items.
    **kwargs
        Passed to ``fn``.

    Returns
    -------
    list
        ``fn``'s results in item order.
    """
    from cnctwin.fleet import map_tasks

    with _client(args) as client, _progress(label) as progress:
        return map_tasks(client, fn, items, key=label, progress=progress, **kwargs)


def _cmd_ingest(args: argparse.Namespace) -> int:
    from cnctwin.exceptions import ConfigError
    from cnctwin.fleet import find_recordings, ingest_recordings
    from cnctwin.fleet.ingest import RECORDING_SUFFIXES

    found = find_recordings(args.paths)
    if not found:
        raise ConfigError(f"no recordings under {', '.join(map(str, args.paths))}: looked for "
                          f"files ending in {' '.join(RECORDING_SUFFIXES)} and Parquet "
                          "recording directories (holding hf.parquet)")
    print(f"{len(found)} recordings found", file=sys.stderr)
    with _client(args) as client, _progress("ingest") as progress:
        report = ingest_recordings(found, store_url=args.store, client=client,
                                   machine=args.machine, progress=progress)
    for o in report.failed:
        print(f"skipped {o.path}: {o.reason}", file=sys.stderr)
    failed = report.count("failed")
    print(f"{report.count('ingested')} ingested, {report.count('already')} already stored, "
          f"{failed} failed (of {len(report.outcomes)}) into {args.store}")
    if failed:
        print(f"cnctwin fleet ingest: {failed} of {len(report.outcomes)} recordings were not "
              "stored (reasons above); the others are. Fix or remove those files and run the "
              "same command again (stored files are recognised and skipped)", file=sys.stderr)
        return 1
    return 0


def _write(df: pd.DataFrame, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    df.to_parquet(tmp, index=False)
    tmp.replace(path)
    return path


def _cmd_job(args: argparse.Namespace) -> int:
    import pandas as pd

    from cnctwin.exceptions import StoreError
    from cnctwin.fleet import (
        compare_partition,
        drift_alarms,
        health_estimates,
        health_table,
        holes_partition,
        machine_files_in,
        partitions,
        quality_partition,
        run_job,
        split_partitions,
        wear_trend,
    )

    window = None
    if args.job == "health" and not args.all_cycles:
        window = {"window_s": args.window_s, "shift_hours": args.shift_hours}
    try:
        parts = partitions(args.store, machines=args.machines, **(window or {}))
    except StoreError as exc:
        if "no cnctwin store at" not in str(exc):
            raise
        # the library's hint names its own argument; here the store comes from ingest
        raise StoreError(f"--store {args.store}: no cnctwin store there; make it with "
                         f"`cnctwin fleet ingest DIR --store {args.store}`") from None
    if not parts:
        from cnctwin.exceptions import ConfigError

        raise ConfigError(f"the store {args.store} holds no recordings"
                          + (f" of {args.machines}" if args.machines else "")
                          + "; fill it with `cnctwin fleet ingest DIR --store URL`")
    print(f"{len(parts)} partitions (machine x day), "
          f"{len({p.machine for p in parts})} machines", file=sys.stderr)
    if window is not None:
        n_an = sum(p.n_cycles for p in parts)
        n_rec = sum(p.recorded_cycles or 0 for p in parts)
        print(f"analysing {n_an:,} of {n_rec:,} recorded cycles ({n_an / max(n_rec, 1):.1%}): "
              f"{args.window_s:g} s per {args.shift_hours:g} h shift (--all-cycles for all)",
              file=sys.stderr)
    kw: dict[str, Any] = {"store_url": args.store}
    if args.job != "quality":
        kw["machine_files"] = machine_files_in(getattr(args, "machines_dir", None))
    fn = {"holes": holes_partition, "wear": holes_partition, "health": health_estimates,
          "quality": quality_partition, "compare": compare_partition}[args.job]
    with _client(args) as client, _progress(args.job) as progress:
        tasks = parts
        if args.job == "health":  # combined per day afterwards: split for busy workers
            n_workers = len(client.scheduler_info().get("workers", {})) or 1
            tasks = split_partitions(parts, n_tasks=4 * n_workers)
        table = run_job(fn, tasks, client=client, progress=progress, **kw)
    if args.job == "health":
        table = health_table(table)
    out: Path = args.out
    written: list[Path] = []
    partial = sorted({f"{m} {d}" for m, d, p in zip(table.get("machine", []),
                                                    table.get("day", []),
                                                    table.get("partial", []), strict=False)
                      if p})
    if args.job in ("holes", "wear"):
        written.append(_write(table, out / "holes.parquet"))
    if args.job == "wear":
        written.append(_write(wear_trend(table), out / "wear.parquet"))
    if args.job == "health":
        written.append(_write(table, out / "health.parquet"))
        alarms = drift_alarms(table)
        written.append(_write(alarms, out / "alarms.parquet"))
        _print_alarms(alarms)
    if args.job == "quality":
        written.append(_write(table, out / "quality.parquet"))
    if args.job == "compare":
        written.append(_write(table, out / "compare.parquet"))
        _print_compare(table)
    job = {"job": args.job, "store": args.store, "partitions": len(parts),
           "partial_partitions": partial, "tables": [p.name for p in written],
           "finished": pd.Timestamp.now(tz="UTC").isoformat()}
    (out / f"{args.job}.json").write_text(json.dumps(job, indent=1), encoding="utf-8")
    for p in written:
        print(p)
    if partial:
        print(f"warning: {len(partial)} partial partitions (a recording could not be "
              f"analysed): {', '.join(partial[:10])}; see the 'issues' column", file=sys.stderr)
    return 0


def _print_alarms(alarms: pd.DataFrame) -> None:
    import pandas as pd
    from rich.table import Table

    if alarms.empty:
        print("no drift alarms", file=sys.stderr)
        return
    t = Table(title=f"{len(alarms)} drift alarms")
    for c in ("machine", "day", "kind", "axis", "change", "z"):
        t.add_column(c)
    for _, a in alarms.iterrows():
        axis = "-" if pd.isna(a["axis"]) else str(a["axis"])
        t.add_row(str(a["machine"]), str(a["day"]), str(a["kind"]), axis,
                  f"{a['relative_change']:+.1%}", f"{a['z']:.0f}")
    _console().print(t)


def _print_compare(table: pd.DataFrame) -> None:
    if table.empty:
        return
    summary = table.groupby(["program", "machine"]).agg(
        recordings=("recording_id", "size"), cycle_time_s=("cycle_time_s", "mean"),
        torque_per_hole_nm=("torque_per_hole_nm", "mean"),
        following_error_max_mm=("following_error_max_mm", "max")).reset_index()
    print(summary.to_string(index=False, float_format=lambda v: f"{v:.4g}"), file=sys.stderr)
