"""``cnctwin servo FILE``: identify each axis' position loop and check the signal relations."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

__all__ = ["register"]


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add the ``servo`` subcommand to ``sub``."""
    p = sub.add_parser(
        "servo", help="position-loop identification and signal relations per axis",
        description="Identify Kv, feedforward, jerk filter, delays, speed loop and friction of "
                    "each axis from a recording, check the relations between its position "
                    "signals, and write thesis Fig. 3.2/3.3-style figures.")
    p.add_argument("file", type=Path, help="recording (Capture4Analysis, servo trace, ...)")
    p.add_argument("--axis", action="append", default=None,
                   help="axis to analyse (repeatable; default every axis with DES_POS and "
                        "ENC_POS)")
    p.add_argument("--out", type=Path, default=None, help="directory for the PNG figures")
    p.add_argument("--plane", nargs=2, default=None, metavar=("H", "V"),
                   help="axes of the tool-path figure (default the first two analysed)")
    p.add_argument("--magnify", type=float, default=50.0,
                   help="magnification of deviations in the tool-path figure (default 50)")
    p.add_argument("--bootstrap", type=int, default=200,
                   help="bootstrap resamples for uncertainties (default 200)")
    p.set_defaults(func=_cmd_servo)


def _fmt(x: float) -> str:
    if x is None or not math.isfinite(x):
        return "-"
    return f"{x:.5g}"


def _cmd_servo(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    from cnctwin.exceptions import IdentificationError, SignalNotFoundError
    from cnctwin.iotools import read_recording
    from cnctwin.servo import check_relations, identify_axis

    rec = read_recording(args.file)
    console = Console(width=max(Console().width, 120))
    if args.axis:
        axes = list(args.axis)
        missing = [a for a in axes if not (rec.has("DES_POS", a) or rec.has("ENC_POS", a))]
        if missing:
            raise SignalNotFoundError(
                f"axis {', '.join(missing)} has no DES_POS/ENC_POS in {args.file}; axes with "
                f"positions: {', '.join(a for a in rec.axes if rec.has('DES_POS', a))}")
    else:
        axes = [a for a in rec.axes if rec.has("DES_POS", a)
                and (rec.has("ENC_POS", a) or rec.has("ENC1_POS", a))]
    console.print(f"[bold]{escape(str(args.file))}[/bold]: {rec.n_cycles} cycles, "
                  f"axes {', '.join(axes) or '-'}")
    for axis in axes:
        console.rule(f"[bold]{axis}")
        rep = check_relations(rec, axis)
        rt = Table(title=f"{axis}: signal relations", title_justify="left")
        for col in ("relation", "rms", "max |r|", "tolerance", "within tol", "ref rms", "unit",
                    "note"):
            rt.add_column(col)
        for r in rep.relations.values():
            if r.checkable:
                rt.add_row(r.name, _fmt(r.rms), _fmt(r.max_abs), _fmt(r.tolerance),
                           f"{100 * r.fraction_within:.1f} %", _fmt(r.reference_rms), r.unit,
                           escape(", ".join(f"{k}={_fmt(v) if isinstance(v, float) else v}"
                                            for k, v in list(r.details.items())[:4])))
            else:
                rt.add_row(r.name, "-", "-", "-", "-", "-", "", escape(f"not checkable: "
                                                                        f"{r.reason}"))
        console.print(rt)
        try:
            ident = identify_axis(rec, axis, n_bootstrap=args.bootstrap)
        except IdentificationError as exc:
            console.print(f"[yellow]{axis}: not identified: {escape(str(exc))}[/yellow]")
            continue
        it = Table(title=f"{axis}: identification (FFW mode {ident.ffw_mode}, jerk filter "
                         f"{ident.jerk_type or 'n/a'})", title_justify="left")
        for col in ("parameter", "value", "± (1 s.e.)", "unit", "method"):
            it.add_column(col)
        for name, value, se, unit, method in ident.rows():
            it.add_row(name, _fmt(value), _fmt(se), unit, escape(method))
        console.print(it)
        for name, reason in ident.not_identified.items():
            console.print(f"  [dim]not identified[/dim] {name}: {escape(reason)}")
        for note in ident.notes:
            console.print(f"  [cyan]note[/cyan] {escape(note)}")
    if args.out is not None and axes:
        from cnctwin.servo.figures import plot_error_signals, plot_tool_path

        args.out.mkdir(parents=True, exist_ok=True)
        written = []
        plane = tuple(args.plane) if args.plane else (tuple(axes[:2]) if len(axes) >= 2
                                                      else None)
        if plane is not None:
            fig = plot_tool_path(rec, (plane[0], plane[1]), magnify=args.magnify)
            path = args.out / f"tool_path_{plane[0]}_{plane[1]}.png"
            fig.savefig(path, dpi=120)
            written.append(path)
        for axis in axes:
            try:
                fig = plot_error_signals(rec, axis)
            except IdentificationError:
                continue
            path = args.out / f"errors_{axis}.png"
            fig.savefig(path, dpi=120)
            written.append(path)
        for p in written:
            console.print(f"wrote {escape(str(p))}")
    return 0
