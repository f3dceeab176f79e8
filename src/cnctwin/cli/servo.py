"""``cnctwin servo FILE``: identify each axis' position loop and check the signal relations.

``cnctwin servo health FILE [FILE ...]``: loop health over a sequence of production recordings
(:func:`cnctwin.servo.health.track_loop_health`).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

__all__ = ["register"]


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add the ``servo`` subcommand to ``sub``.

    Parameters
    ----------
    sub : argparse._SubParsersAction[argparse.ArgumentParser]
        The ``cnctwin`` subcommand parsers; the module adds its commands to them.
    """
    p = sub.add_parser(
        "servo", help="position-loop identification and signal relations per axis",
        description="Identify Kv, feedforward, jerk filter, delays, speed loop and friction of "
                    "each axis from a recording, check the relations between its position "
                    "signals, and write thesis Fig. 3.2/3.3-style figures.")
    p.add_argument("file", type=Path, nargs="+", metavar="FILE",
                   help="recording (Capture4Analysis, servo trace, ...); 'health FILE [FILE "
                        "...]' tracks the loop health over a sequence of recordings in time "
                        "order")
    p.add_argument("--axis", action="append", default=None,
                   help="axis to analyse (repeatable; default every axis with DES_POS and "
                        "ENC_POS)")
    p.add_argument("--out", type=Path, default=None, help="directory for the PNG figures")
    p.add_argument("--verbose", "-v", action="store_true",
                   help="every signal relation, the identification method of each parameter, "
                   "why the others were not identified, and the notes (default: a summary)")
    p.add_argument("--plane", nargs=2, default=None, metavar=("H", "V"),
                   help="axes of the tool-path figure (default the first two analysed)")
    p.add_argument("--magnify", type=float, default=50.0,
                   help="magnification of deviations in the tool-path figure (default 50)")
    p.add_argument("--bootstrap", type=int, default=200,
                   help="bootstrap resamples for uncertainties (default 200)")
    h = p.add_argument_group("servo health FILE [FILE ...]")
    h.add_argument("--window-s", type=float, default=60.0,
                   help="window length [s] (default 60; windows never span two files)")
    h.add_argument("--baseline-windows", type=int, default=5,
                   help="windows forming the baseline (default 5)")
    h.add_argument("--z-alarm", type=float, default=5.0,
                   help="single-window alarm threshold on |z| (default 5)")
    h.add_argument("--min-travel", type=float, default=0.5,
                   help="least DES_POS travel of an excited window [mm or deg] (default 0.5)")
    h.add_argument("--effort", choices=("auto", "CURRENT", "TORQUE"), default="auto",
                   help="friction signal (default auto: CURRENT, else TORQUE)")
    p.set_defaults(func=_cmd_servo)


def _fmt(x: float) -> str:
    if x is None or not math.isfinite(x):
        return "-"
    return f"{x:.5g}"


def _relations_table(axis: str, rep: Any, escape: Any) -> Any:
    """The signal relations of one axis as a rich table (``--verbose``)."""
    from rich.table import Table

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
    return rt


def _cmd_servo(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    from cnctwin.exceptions import IdentificationError, SignalNotFoundError
    from cnctwin.iotools import read_recording
    from cnctwin.servo import check_relations, identify_axis

    files = list(args.file)
    if files[0].name == "health" and not files[0].exists():
        return _cmd_health(args, files[1:])
    if len(files) > 1:
        from cnctwin.exceptions import ConfigError

        raise ConfigError(f"'cnctwin servo' analyses one recording, got {len(files)}; for a "
                          f"sequence of recordings use 'cnctwin servo health FILE [FILE ...]'")
    args.file = files[0]
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
    summary = Table(title="summary (details: --verbose)", title_justify="left")
    for col in ("axis", "following-error check (rms)", "identified (± 1 s.e.)",
                "not identified (why: --verbose)"):
        summary.add_column(col)
    for axis in axes:
        if args.verbose:
            console.rule(f"[bold]{axis}")
        rep = check_relations(rec, axis)
        if args.verbose:
            console.print(_relations_table(axis, rep, escape))
        fe = rep.relations.get("following_error")
        fe_txt = (f"{_fmt(fe.rms)} {fe.unit}" if fe is not None and fe.checkable else "-")
        try:
            ident = identify_axis(rec, axis, n_bootstrap=args.bootstrap)
        except IdentificationError as exc:
            if args.verbose:
                console.print(f"[yellow]{axis}: not identified: {escape(str(exc))}[/yellow]")
            summary.add_row(axis, fe_txt, "-", escape(f"nothing: {exc}"[:120]))
            continue
        rows = list(ident.rows())
        summary.add_row(
            axis, fe_txt,
            escape("\n".join(f"{name} = {_fmt(value)} ± {_fmt(se)} "
                              f"{'' if unit == '-' else unit}".rstrip()
                              for name, value, se, unit, _ in rows) or "-"),
            escape(", ".join(ident.not_identified) or "-"))
        if not args.verbose:
            continue
        it = Table(title=f"{axis}: identification (FFW mode {ident.ffw_mode}, jerk filter "
                         f"{ident.jerk_type or 'n/a'})", title_justify="left")
        for col in ("parameter", "value", "± (1 s.e.)", "unit", "method"):
            it.add_column(col)
        for name, value, se, unit, method in rows:
            it.add_row(name, _fmt(value), _fmt(se), unit, escape(method))
        console.print(it)
        for name, reason in ident.not_identified.items():
            console.print(f"  [dim]not identified[/dim] {name}: {escape(reason)}")
        for note in ident.notes:
            console.print(f"  [cyan]note[/cyan] {escape(note)}")
    if axes:
        console.print(summary)
    if args.out is not None and axes:
        from cnctwin.servo.figures import plot_error_signals, plot_tool_path

        args.out.mkdir(parents=True, exist_ok=True)
        written = []
        # default plane: the first two linear axes (DES_POS in mm); a path over rotary axes
        # (deg) is no tool path
        linear = [a for a in axes if rec.meta.units.get(f"DES_POS|{a}", "mm") == "mm"]
        plane = tuple(args.plane) if args.plane else (tuple(linear[:2]) if len(linear) >= 2
                                                      else None)
        if plane is None:
            console.print("no tool-path figure: fewer than two linear axes (DES_POS in mm); "
                          "choose two with --plane H V")
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


_HEALTH_COLUMNS: tuple[tuple[str, str, float], ...] = (
    ("kv_1_s", "Kv [1/s]", 1.0), ("speed_loop_equiv_time_s", "T_eq [ms]", 1e3),
    ("coulomb_pos", "Fc+", 1.0), ("coulomb_neg", "Fc-", 1.0), ("viscous_pos", "b+", 1.0),
    ("viscous_neg", "b-", 1.0), ("reversal_error", "reversal", 1.0),
    ("residual_ratio", "resid/FE", 1.0),
)


def _cmd_health(args: argparse.Namespace, files: list[Path]) -> int:
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    from cnctwin.exceptions import ConfigError, SignalNotFoundError
    from cnctwin.iotools import read_recording
    from cnctwin.servo.health import track_loop_health

    if not files:
        raise ConfigError("'cnctwin servo health' needs at least one recording: "
                          "cnctwin servo health FILE [FILE ...] --axis X1")
    console = Console(width=max(Console().width, 140))
    recs = [read_recording(f) for f in files]
    labels = [f.stem if len(f.stem) <= 20 else f.stem[:19] + "~" for f in files]
    if args.axis:
        axes = list(args.axis)
        missing = [a for a in axes if not any(r.has("DES_POS", a) for r in recs)]
        if missing:
            raise SignalNotFoundError(
                f"axis {', '.join(missing)} has no DES_POS in any of the {len(files)} files; "
                f"axes with positions: "
                f"{', '.join(sorted({a for r in recs for a in r.axes if r.has('DES_POS', a)}))}")
    else:
        axes = [a for a in recs[0].axes if recs[0].has("DES_POS", a)]
    written = []
    for axis in axes:
        res = track_loop_health(recs, axis, window_s=args.window_s, labels=labels,
                                baseline_windows=args.baseline_windows, z_alarm=args.z_alarm,
                                min_travel=args.min_travel, effort_signal=args.effort,
                                n_bootstrap=args.bootstrap)
        console.rule(f"[bold]{axis}: loop health")
        alarmed = {(a.parameter, a.window_index) for a in res.alarms}
        z_of = {(t.parameter, t.window_index): t.z for ts in res.tests.values() for t in ts}
        t = Table(title=f"{axis}: per window (value, z vs baseline in brackets; ! = alarm, "
                        f"- = not identified)", title_justify="left")
        t.add_column("window")
        t.add_column("s")
        for _, head, _ in _HEALTH_COLUMNS:
            t.add_column(head, justify="right")
        for w in res.windows:
            cells = []
            for name, _, scale in _HEALTH_COLUMNS:
                if name not in w.params:
                    cells.append("-")
                    continue
                txt = _fmt(w.params[name].value * scale)
                z = z_of.get((name, w.index))
                if z is not None:
                    txt += f" ({z:+.1f})"
                if (name, w.index) in alarmed:
                    txt = f"[bold red]{txt}![/bold red]"
                cells.append(txt)
            t.add_row(escape(w.label), f"{w.duration_s:.0f}", *cells)
        console.print(t)
        b = Table(title=f"{axis}: baseline", title_justify="left")
        for col in ("parameter", "baseline", "± s.e.", "between-window σ", "band σ", "windows",
                    "unit"):
            b.add_column(col)
        for name, bp in res.baseline.items():
            b.add_row(name, _fmt(bp.mean), _fmt(bp.stderr_mean), _fmt(bp.tau), _fmt(bp.band),
                      str(bp.n_windows), bp.unit)
        console.print(b)
        for name, reason in res.no_baseline.items():
            console.print(f"  [dim]not tracked[/dim] {name}: {escape(reason)}")
        idle = [w for w in res.windows if not w.excited]
        for w in idle:
            reason = next(iter(w.not_identified.values()), "")
            console.print(f"  [dim]window {escape(w.label)}[/dim]: {escape(reason)}")
        for note in res.notes:
            console.print(f"  [cyan]note[/cyan] {escape(note)}")
        if res.alarms:
            for a in res.alarms:
                console.print(f"  [bold red]ALARM[/bold red] {escape(a.describe())}")
        else:
            console.print(f"  no drift alarm ({sum(len(v) for v in res.tests.values())} "
                          f"parameter tests)")
        if args.out is not None:
            from cnctwin.exceptions import IdentificationError
            from cnctwin.servo.health_figures import plot_health_trends

            args.out.mkdir(parents=True, exist_ok=True)
            try:
                fig = plot_health_trends(res)
            except IdentificationError as exc:
                console.print(f"  [yellow]no figure: {escape(str(exc))}[/yellow]")
                continue
            path = args.out / f"health_{axis}.png"
            fig.savefig(path, dpi=110)
            written.append(path)
    for p in written:
        console.print(f"wrote {escape(str(p))}")
    return 0
