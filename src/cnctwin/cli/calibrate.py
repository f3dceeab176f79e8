"""``cnctwin calibrate spindle|axes``: the twin of one's own machine from its recordings.

Each subcommand reads the user's recordings, identifies what they support, writes the
values with their uncertainty and provenance into the machine file (created if needed,
replaced atomically) and prints a short summary. Data that cannot support a parameter is an
error saying what to record next; nothing is written then.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from cnctwin.exceptions import CnctwinError, ConfigError, SignalNotFoundError

__all__ = ["register"]


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``calibrate spindle`` and ``calibrate axes`` to the command line.

    Parameters
    ----------
    sub : argparse._SubParsersAction[argparse.ArgumentParser]
        The ``cnctwin`` subcommand parsers; the module adds its commands to them.
    """
    p = sub.add_parser(
        "calibrate",
        help="calibrate the twin of your machine from its recordings into a machine file",
        description="Identify the spindle (friction, torque constant, inertia) or the feed "
        "axes' position loops from your own recordings and write them, with uncertainty "
        "and provenance, into the machine file (TOML) that simulate, edge, web and fleet read.",
    )
    csub = p.add_subparsers(dest="what", metavar="WHAT", required=True)
    s = csub.add_parser(
        "spindle",
        help="friction and torque constant from air cuts and one reference cut",
        description="Friction (B, tau_f) from the air cuts' constant-speed plateaus and the "
        "torque constant Kt from one reference cut with a dynamometer or a known torque "
        "(thesis chapters 3.2 and 4). Record the air cut up and back down through "
        "500-5000 rpm (3 s per speed) so the bearings' self-heating can be fitted out.",
    )
    s.add_argument("--air-cut", nargs="+", type=Path, required=True, metavar="FILE",
                   help="air-cut recording(s): spindle at constant speeds, no contact")
    s.add_argument("--reference", type=Path, nargs="+", metavar="FILE",
                   help="recording of a cut whose torque is known; cuts at two or more speeds "
                   "give the speed law of Kt (constant-power range)")
    g = s.add_mutually_exclusive_group()
    g.add_argument("--dynamometer", type=Path, nargs="+", metavar="CSV",
                   help="dynamometer CSV of each reference cut, in the same order (its own "
                   "clock; aligned on the current)")
    g.add_argument("--torque-nm", type=float, nargs="+", metavar="VALUE",
                   help="mean cutting torque of each reference cut [Nm], if no dynamometer")
    s.add_argument("--kt-nm-per-a", type=float, metavar="VALUE",
                   help="no reference cut: the motor's torque constant from the drive's data "
                   "(SINAMICS p0316 / data sheet) [Nm/A]")
    s.add_argument("--kt-tolerance-pct", type=float, default=5.0, metavar="PCT",
                   help="its tolerance as the data sheet states it [+- %%] (5)")
    s.add_argument("--torque-uncertainty-pct", type=float, default=0.0, metavar="PCT",
                   help="relative standard uncertainty of the torque reference [%%] "
                   "(calibration certificate); default 0 = not included")
    s.add_argument("--warm-up", type=Path, metavar="FILE",
                   help="optional long constant-speed run from cold (thermal referral)")
    s.add_argument("--machine", type=Path, required=True, metavar="FILE",
                   help="machine file to update (created if missing)")
    s.add_argument("--method", choices=("improved", "thesis"), default="improved",
                   help="improved (default) or the thesis' own method")
    s.add_argument("--spindle", default="SP1", help="spindle axis name (default SP1)")
    s.add_argument("--report", type=Path, metavar="HTML",
                   help="HTML report (default: beside the machine file)")
    s.set_defaults(func=_cmd_spindle)
    a = csub.add_parser(
        "axes",
        help="Kv, feedforward, jerk filter, speed loop and friction per feed axis",
        description="Identify each feed axis' position loop (Kv MD32200, FFW weight MD32610, "
        "jerk filter MD32402/32410, equivalent speed-loop time MD32810) and its friction from "
        "production recordings (thesis chapter 3.1).",
    )
    a.add_argument("files", nargs="+", type=Path, metavar="FILE", help="recordings")
    a.add_argument("--machine", type=Path, required=True, metavar="FILE",
                   help="machine file to update (created if missing)")
    a.add_argument("--axis", action="append", default=[], metavar="NAME",
                   help="axis to calibrate (repeatable; default every moving axis)")
    a.add_argument("--verbose", action="store_true",
                   help="print the identification's notes on each recording")
    a.add_argument("--report", type=Path, metavar="HTML",
                   help="HTML report (default: beside the machine file, "
                   "<machine>.axes-report.html)")
    a.set_defaults(func=_cmd_axes)
    mt = csub.add_parser(
        "material",
        help="milling coefficients of your workpiece material from your own cuts",
        description="Fit the linear edge-force coefficients (Ktc Krc Kac Kte Kre Kae) of a "
        "material from recordings of end-mill cuts: cutting torque from the spindle current "
        "(the calibrated spindle), forces from the feed axes, engagement from the recorded "
        "tool path through the stock (Z-map). Cut slots and side steps at three or more "
        "feeds per tooth at a steady spindle speed. Written with uncertainty and provenance "
        "into the machine file's [materials.NAME]; simulate and optimize use it by name.",
    )
    mt.add_argument("files", nargs="+", type=Path, metavar="REC",
                    help="recordings of the program, in machining order")
    mt.add_argument("--material", required=True, metavar="NAME",
                    help="name to store it under (a library name keeps its values where a "
                    "coefficient is not identified)")
    mt.add_argument("--program", type=Path, required=True, metavar="PART.mpf",
                    help="the program the recordings ran (checked against the tool table)")
    mt.add_argument("--tools", type=Path, required=True, metavar="TOOLS.toml",
                    help="tool table")
    mt.add_argument("--stock", required=True, metavar="X0,Y0,Z0,X1,Y1,Z1",
                    help="the raw part before the first recording [mm]")
    mt.add_argument("--machine", type=Path, required=True, metavar="M.toml",
                    help="the calibrated machine file to read and update")
    mt.set_defaults(func=_cmd_material)


def _read(path: Path) -> Any:
    from cnctwin.iotools import read_recording

    if not path.exists():
        raise ConfigError(f"{path}: no such file")
    return read_recording(path)


def _load_or_new(path: Path) -> Any:
    from cnctwin.machine import MachineFile, load_machine

    return load_machine(path) if path.exists() else MachineFile()


def _cmd_spindle(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

    from cnctwin.calibration import calibrate_spindle
    from cnctwin.calibration.report import spindle_calibration_report
    from cnctwin.iotools.dynamometer import attach_external, read_dynamometer_csv
    from cnctwin.machine import save_machine

    console = Console(stderr=True)
    mf = _load_or_new(args.machine)  # a damaged machine file stops here, before any work
    if args.torque_uncertainty_pct < 0:
        raise ConfigError("--torque-uncertainty-pct must be >= 0")
    if (args.reference is None) == (args.kt_nm_per_a is None):
        raise ConfigError("give --reference FILE... (cuts with a known torque) or "
                          "--kt-nm-per-a VALUE (the motor's torque constant), one of them")
    if args.kt_nm_per_a is not None:
        return _spindle_from_motor_kt(args, mf)
    n_ref = len(args.reference)
    bad = [v for v in args.torque_nm or [] if not v > 0]
    if bad:
        raise ConfigError(f"--torque-nm {bad[0]:g}: a reference cut's torque must be positive "
                          "[Nm] (the mean cutting torque the dynamometer or a force model gives)")
    for opt, vals in (("--dynamometer", args.dynamometer), ("--torque-nm", args.torque_nm)):
        if vals is not None and len(vals) != n_ref:
            raise ConfigError(f"{opt}: {len(vals)} given for {n_ref} --reference cut(s); give "
                              "one per reference cut, in the same order")
    with console.status("reading the recordings"):
        air = [_read(p) for p in args.air_cut]
        refs = [_read(p) for p in args.reference]
        for k, csv in enumerate(args.dynamometer or []):
            if not csv.exists():
                raise ConfigError(f"{csv}: no such file")
            dyn = read_dynamometer_csv(csv)
            if "mz_nm" not in dyn.data.columns:
                unknown = [c for c in dyn.data.columns if dyn.units.get(c) == "unknown"]
                raise ConfigError(
                    f"{csv}: no torque column in N*m"
                    + (f" (the header gives {unknown} without a unit)" if unknown else "")
                    + "; state the unit in the header, e.g. 'Mz [Nm]', or give --torque-nm")
            refs[k] = attach_external(refs[k], dyn, replace=True)
        warm = _read(args.warm_up) if args.warm_up is not None else None
    for path, rec in zip(args.reference, refs, strict=True):
        if args.torque_nm is None and "dynamometer" not in rec.external:
            raise ConfigError(f"{path}: the reference cut has no dynamometer channel; "
                              "give --dynamometer CSV or --torque-nm VALUE")
    ref = refs[0]
    names = [str(p) for p in (*args.air_cut, *args.reference)]
    with console.status(f"calibrating the spindle ({args.method} method)"):
        try:
            cal = calibrate_spindle(
                air, refs, method=args.method, reference_torque_nm=args.torque_nm,
                reference_uncertainty_pct=args.torque_uncertainty_pct, warm_up=warm,
                spindle=args.spindle, recording_names=names)
        except SignalNotFoundError as exc:
            raise SignalNotFoundError(
                f"{exc}; the spindle calibration needs CURRENT|{args.spindle} and the spindle "
                f"speed in every recording ({', '.join(names)}); check --spindle") from None
        except CnctwinError as exc:
            msg = str(exc)
            if any(n in msg for n in names):
                raise
            raise ConfigError(f"{args.reference[0]}: {msg}") from None
    report = args.report or args.machine.with_name(args.machine.stem + ".spindle-report.html")
    spindle_calibration_report(cal, ref, report, spindle=args.spindle,
                               reference_torque_nm=args.torque_nm[0] if args.torque_nm
                               else None, machine_path=str(args.machine))
    save_machine(mf.with_records(cal.records), args.machine)
    table = Table(title=f"spindle ({args.method} method)")
    for col in ("parameter", "value", "std. uncertainty", "unit"):
        table.add_column(col, justify="left" if col == "parameter" else "right")
    for _, r in cal.budget.iterrows():
        table.add_row(str(r["parameter"]), f"{r['value']:.5g}", f"{r['combined']:.2g}",
                      str(r["unit"]))
    if cal.model.j_kgm2 > 0:
        table.add_row("j_kgm2", f"{cal.model.j_kgm2:.4g}", "-", "kg m^2")
    fb = cal.records.get("spindle.flux_base_speed_rpm")
    if fb is not None and fb.identified:
        table.add_row("base speed (Kt ~ n_b/n above)", f"{fb.value:.0f}",
                      f"{fb.uncertainty:.2g}" if fb.uncertainty is not None else "-", "rpm")
    out = Console()
    out.print(table)
    for note in cal.notes:
        out.print(f"note: {note}")
    out.print(f"wrote {args.machine} and {report}")
    return 0


def _spindle_from_motor_kt(args: argparse.Namespace, mf: Any) -> int:
    from rich.console import Console

    from cnctwin.calibration import calibrate_spindle
    from cnctwin.calibration.report import spindle_calibration_report
    from cnctwin.machine import save_machine

    if args.dynamometer is not None or args.torque_nm is not None:
        raise ConfigError("--dynamometer/--torque-nm go with --reference, not --kt-nm-per-a")
    with Console(stderr=True).status("reading the air cuts"):
        air = [_read(p) for p in args.air_cut]
        warm = _read(args.warm_up) if args.warm_up is not None else None
    cal = calibrate_spindle(air, None, method=args.method, kt_nm_per_a=args.kt_nm_per_a,
                            kt_tolerance_pct=args.kt_tolerance_pct, warm_up=warm,
                            spindle=args.spindle,
                            recording_names=[str(p) for p in args.air_cut])
    report = args.report or args.machine.with_name(args.machine.stem + ".spindle-report.html")
    spindle_calibration_report(cal, None, report, spindle=args.spindle,
                               machine_path=str(args.machine))
    save_machine(mf.with_records(cal.records), args.machine)
    out = Console()
    for _, r in cal.budget.iterrows():
        out.print(f"{r['parameter']:>14s} {r['value']:.5g} +- {r['combined']:.2g} {r['unit']}")
    for note in cal.notes:
        out.print(f"note: {note}")
    out.print(f"wrote {args.machine} and {report}")
    return 0


def _cmd_axes(args: argparse.Namespace) -> int:
    import dataclasses

    from rich.console import Console
    from rich.table import Table

    from cnctwin.calibration.axes import calibrate_axes
    from cnctwin.calibration.report import axes_calibration_report
    from cnctwin.machine import parameter_unit, save_machine

    console = Console(stderr=True)
    mf = _load_or_new(args.machine)
    with console.status("reading the recordings"):
        recs = [_read(p) for p in args.files]
    with console.status("identifying the position loops"):
        cal = calibrate_axes(recs, machine=mf.machine, axes=args.axis or None,
                             recording_names=[str(p) for p in args.files])
    # an axis that did not move this time keeps what an earlier calibration identified
    kept = [k for k, r in cal.records.items() if not r.identified
            and k.split(".")[1] in cal.not_moving and mf.is_identified(k)]
    records = {k: r for k, r in cal.records.items() if k not in kept}
    save_machine(mf.with_records(records), args.machine)
    report = args.report or args.machine.with_name(args.machine.stem + ".axes-report.html")
    with console.status("writing the report"):
        axes_calibration_report(dataclasses.replace(cal, records=records), recs, report,
                                machine=mf.machine, machine_path=str(args.machine))
    table = Table(title="feed axes (parameter = the machine file's key in \\[axes.<axis>])")
    table.add_column("axis", no_wrap=True)
    table.add_column("parameter", no_wrap=True)
    table.add_column("value", justify="right", no_wrap=True)
    table.add_column("std. unc.", justify="right", no_wrap=True)
    table.add_column("unit", justify="right", no_wrap=True)
    reasons: list[str] = []  # footnotes: why a value was not identified

    def note_of(why: str) -> str:
        if why not in reasons:
            reasons.append(why)
        return f"not identified [{reasons.index(why) + 1}]"

    for key, rec in records.items():
        axis, name = key.split(".")[1], key.split(".")[2]
        if axis in cal.not_moving:
            continue
        rot = mf.machine.axis(axis).rotary if axis in mf.machine.axis_names else False
        table.add_row(axis, name,
                      f"{rec.value:.5g}" if rec.identified else note_of(rec.reason),
                      f"{rec.uncertainty:.2g}" if rec.uncertainty is not None else "-",
                      parameter_unit(key, rotary=rot))
    for axis in cal.not_moving:
        table.add_row(axis, "(all)", note_of(
            "did not move in the recordings" + (" (earlier values kept)" if any(
                k.startswith(f"axes.{axis}.") for k in kept) else "")), "-", "-")
    out = Console()
    out.print(table)
    for k, why in enumerate(reasons, start=1):
        out.print(f"[{k}] {why}", markup=False)
    if reasons:
        out.print("not identified: the value stays the default; the machine file and the "
                  "report give each reason in full")
    if args.verbose:
        for note in cal.notes:
            out.print(f"note: {note}")
    elif cal.notes:
        out.print(f"{len(cal.notes)} notes on the recordings (--verbose shows them)")
    out.print(f"wrote {args.machine} and {report}")
    return 0


def _cmd_material(args: argparse.Namespace) -> int:
    import datetime as dt
    import math

    from rich.console import Console
    from rich.table import Table

    from cnctwin.calibration.material import calibrate_material
    from cnctwin.engagement import parse_stock
    from cnctwin.machine import read_tool_table, save_machine
    from cnctwin.sim.gcode import parse_program

    if not args.machine.exists():
        raise ConfigError(f"{args.machine}: no such machine file; calibrate the spindle first "
                          "(cnctwin calibrate spindle ... --machine FILE): the cutting torque "
                          "comes from its current")
    mf = _load_or_new(args.machine)
    tools = read_tool_table(args.tools)
    stock = parse_stock(args.stock)
    if not args.program.is_file():
        raise ConfigError(f"{args.program}: no such program file")
    try:
        prog = parse_program(args.program.read_text(encoding="utf-8"), name=args.program.stem)
    except ConfigError as exc:
        raise ConfigError(f"{args.program}: {exc}") from None
    for b in prog.blocks:
        if b.tool is not None and "T" in b.words:
            try:
                tools.get(int(b.tool), line=b.line, text=b.text)
            except ConfigError as exc:
                raise ConfigError(f"{args.program}: {exc}") from None
    console = Console(stderr=True)
    with console.status("reading the recordings"):
        recs = [_read(p) for p in args.files]
    with console.status("fitting the milling coefficients"):
        cal = calibrate_material(recs, name=args.material, mfile=mf, tools=tools, stock=stock)
    prov = {"method": "cnctwin calibrate material (spindle current + axis forces, Z-map)",
            "recordings": [str(p) for p in args.files],
            "date": dt.datetime.now(dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")}
    materials = {**mf.materials, args.material: cal.machine_table(provenance=prov)}
    import dataclasses

    save_machine(dataclasses.replace(mf, materials=materials), args.machine)
    table = Table(title=f"material {args.material} (machine file [materials.{args.material}])")
    for col in ("coefficient", "value", "std. unc.", "unit"):
        table.add_column(col, justify="left" if col == "coefficient" else "right")
    from cnctwin.calibration.material import UNITS

    for key, unit in UNITS.items():
        u = cal.uncertainty.get(key, math.nan)
        table.add_row(key, f"{getattr(cal.coefficients, key):.5g}" if cal.identified.get(key)
                      else f"not identified ({cal.reasons.get(key, '')}); kept "
                      f"{getattr(cal.coefficients, key):.5g}",
                      f"{u:.2g}" if math.isfinite(u) else "-", unit)
    out = Console()
    out.print(table)
    for note in cal.notes:
        out.print(f"note: {note}", markup=False)
    out.print(f"wrote {args.machine}")
    return 0
