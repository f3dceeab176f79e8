"""Recording subcommands: ``info`` (describe a recording) and ``convert`` (to Parquet, flattened
CSV or Capture4Analysis). The store subcommands ``ingest`` and ``query`` live in
:mod:`cnctwin.cli.store`.

One ``_add_<verb>(sub)`` function registers each subcommand and one ``_cmd_<verb>(args)`` runs
it; :func:`register` calls the ``_add_*`` functions listed in :data:`_SUBCOMMANDS`. To add a
recording subcommand, write the two functions and append the adder to :data:`_SUBCOMMANDS`.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

__all__ = ["register"]


# ---------------------------------------------------------------------- info
def _add_info(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("info", help="describe a recording (signals, time span, gaps, events)",
                       description="Read a recording of any supported format and describe it.")
    p.add_argument("file", type=Path, help="recording file (or Parquet directory)")
    p.add_argument("--salvage", action="store_true",
                   help="keep what can be read from damaged input (marked partial)")
    p.add_argument("--max-issues", type=int, default=20,
                   help="issues to list (default 20; 0 for all)")
    p.set_defaults(func=_cmd_info)


def _cmd_info(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    from cnctwin.iotools import read_recording
    from cnctwin.signals import parse_column

    rec = read_recording(args.file, salvage=args.salvage)
    console = Console(width=max(Console().width, 100))
    m = rec.meta
    console.print(f"[bold]{escape(str(args.file))}[/bold]  ({m.source_format or '?'}"
                  f"{', [red]PARTIAL[/red]' if m.partial else ''})")
    summary = Table(show_header=False, box=None, pad_edge=False)
    summary.add_column(style="bold")
    summary.add_column()
    summary.add_row("machine", escape(m.machine) or "-")
    summary.add_row("files", str(len(m.source_files)))
    summary.add_row("cycles", f"{rec.n_cycles}")
    summary.add_row("duration", f"{rec.duration_s:.3f} s (counter span, gaps included)")
    summary.add_row("rate", f"{rec.fs_hz:g} Hz (cycle {m.cycle_time_s * 1e3:g} ms)")
    if rec.n_cycles:
        t = rec.hf["time"]
        summary.add_row("start (UTC)", str(t.iloc[0]))
        summary.add_row("end (UTC)", str(t.iloc[-1]))
        summary.add_row("first/last cycle", f"{int(rec.cycles[0])} / {int(rec.cycles[-1])}")
    gaps = ", ".join(f"{g.missing} after {g.after_cycle}" for g in m.gaps[:5])
    summary.add_row("gaps", f"{len(m.gaps)}" + (f" ({gaps}{' ...' if len(m.gaps) > 5 else ''})"
                                                 if m.gaps else ""))
    summary.add_row("wraps", str(m.wraps))
    ev = rec.events
    if len(ev):
        kinds = ev["kind"].value_counts()
        counts = ", ".join(f"{int(n)} {k}" for k, n in kinds.items())
        codes = [escape(str(g)) for g in ev.loc[ev["kind"] == "block", "gcode"].head(5)]
        summary.add_row("events", f"{len(ev)} ({counts})")
        if codes:
            summary.add_row("first G-code", " | ".join(codes))
    else:
        summary.add_row("events", "0")
    lf_signals = sorted(rec.lf["signal"].astype(str).unique()) if len(rec.lf) else []
    summary.add_row("LF signals", f"{len(lf_signals)} ({len(rec.lf)} values)"
                    + (": " + escape(", ".join(lf_signals)) if lf_signals else ""))
    if rec.external:
        summary.add_row("external", escape(", ".join(rec.external)))
    summary.add_row("partial", "yes" if m.partial else "no")
    console.print(summary)

    by_axis: dict[str, list[str]] = {}
    for col in rec.columns:
        code, axis = parse_column(col)
        unit = m.units.get(col, "")
        by_axis.setdefault(axis or "-", []).append(f"{code} [{unit}]" if unit else code)
    if by_axis:
        table = Table(title=f"{len(rec.columns)} HF signals by axis")
        table.add_column("axis", style="bold")
        table.add_column("n", justify="right")
        table.add_column("signals [unit]")
        for axis, sigs in by_axis.items():
            table.add_row(escape(axis), str(len(sigs)), escape(", ".join(sigs)))
        console.print(table)
    if m.issues:
        shown = m.issues if args.max_issues <= 0 else m.issues[: args.max_issues]
        console.print(f"[bold]issues[/bold] ({len(m.issues)}):")
        for issue in shown:
            console.print(f"  - {issue}", markup=False, highlight=False, soft_wrap=True)
        if len(shown) < len(m.issues):
            console.print(f"  ... {len(m.issues) - len(shown)} more (--max-issues 0)")
    return 0


# ---------------------------------------------------------------------- convert
_TARGETS = ("parquet", "csv", "c4a")


def _default_out(src: Path, to: str) -> Path:
    stem = src.name
    for suffix in (".json", ".zip", ".parquet", ".xml", ".csv", ".tdms"):
        if stem.lower().endswith(suffix):
            stem = stem[: -len(suffix)]
            break
    if to == "parquet":
        return src.with_name(stem + ".parquet")
    if to == "csv":
        return src.with_name(stem)
    return src.with_name(stem + "_c4a.json")


def _add_convert(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "convert", help="convert a recording to Parquet, flattened CSV or Capture4Analysis",
        description="Read a recording of any supported format and write it as a Parquet "
        "directory, flattened CSV files (KIT layout) or Capture4Analysis JSON.")
    p.add_argument("file", type=Path, help="recording file (or Parquet directory)")
    p.add_argument("--to", required=True, choices=_TARGETS, help="output format")
    p.add_argument("--out", type=Path, default=None,
                   help="output path (default beside the input: <stem>.parquet, <stem>_*.csv, "
                   "<stem>_c4a.json)")
    p.add_argument("--salvage", action="store_true",
                   help="keep what can be read from damaged input (marked partial)")
    p.add_argument("--max-file-mb", type=float, default=None,
                   help="c4a only: split into chained files of at most this size [MB]")
    p.add_argument("--zip", action="store_true", help="c4a only: write one zip archive")
    p.set_defaults(func=_cmd_convert)


def _cmd_convert(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    from cnctwin.iotools import read_recording, write_capture4analysis, write_csv, write_parquet

    out = args.out or _default_out(args.file, args.to)
    if args.to == "c4a" and args.zip and out.suffix.lower() != ".zip":
        out = out.with_suffix(".zip")
    err = Console(stderr=True)
    with Progress(SpinnerColumn(), TextColumn("{task.description}"), TimeElapsedColumn(),
                  console=err, transient=True) as progress:
        task = progress.add_task(f"reading {args.file.name}", total=2)
        rec = read_recording(args.file, salvage=args.salvage)
        progress.update(task, advance=1, description=f"writing {args.to} to {out}")
        if args.to == "parquet":
            written = [write_parquet(rec, out)]
        elif args.to == "csv":
            written = list(write_csv(rec, out).values())
        else:
            written = write_capture4analysis(rec, out, max_file_mb=args.max_file_mb,
                                             zip=args.zip)
        progress.update(task, advance=1)
    console = Console()
    console.print(f"{rec.n_cycles} cycles, {len(rec.columns)} signals, {len(rec.events)} events"
                  f"{' (PARTIAL input)' if rec.meta.partial else ''} -> {args.to}:",
                  highlight=False)
    for path in written:
        console.print(f"  {path}", markup=False, highlight=False)
    return 0


# ---------------------------------------------------------------------- registry
_SUBCOMMANDS: list[Callable[[argparse._SubParsersAction[argparse.ArgumentParser]], None]] = [
    _add_info,
    _add_convert,
]
"""Adders of the subcommands of this module, in help order."""


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add the recording subcommands to ``sub``.

    Parameters
    ----------
    sub : argparse._SubParsersAction[argparse.ArgumentParser]
        The ``cnctwin`` subcommand parsers; the module adds its commands to them.
    """
    for add in _SUBCOMMANDS:
        add(sub)
