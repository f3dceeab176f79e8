"""``cnctwin optimize``: the user's program made as fast as the machine, tool and material allow."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from cnctwin.exceptions import ConfigError, GCodeError

__all__ = ["register"]


def register(sub: Any) -> None:
    """Add ``optimize`` to the ``cnctwin`` subcommands.

    Parameters
    ----------
    sub : argparse._SubParsersAction[argparse.ArgumentParser]
        The ``cnctwin`` subcommand parsers.
    """
    p = sub.add_parser(
        "optimize",
        help="feed-rate optimization of a part program on the calibrated twin",
        description="Find per block the highest feed within the spindle's S1 torque and power "
        "(calibrated law), its peak torque, the tool's chip thickness, torque and force per "
        "tooth, the feed axes and the machine's path feed, with the calibration's margin; "
        "write the program with only F changed (blocks split where the engagement changes), "
        "simulate both programs on the machine and report. Writes OUT/optimized.mpf, "
        "OUT/optimize.json and OUT/report.html.",
    )
    p.add_argument("program", type=Path, metavar="PART.mpf", help="the part program")
    p.add_argument("--machine", type=Path, metavar="M.toml",
                   help="machine file (cnctwin calibrate); default the thesis machine")
    p.add_argument("--material", metavar="NAME|FILE.toml",
                   help="workpiece material: one calibrated into --machine (cnctwin calibrate "
                   "material), a library name (aisi1045, grey_cast_iron, al7050) or a file")
    p.add_argument("--tools", type=Path, metavar="TOOLS.toml",
                   help="tool table ([tools.N] with kind, diameter_mm, flutes, helix_deg, "
                   "max_chip_mm)")
    p.add_argument("--stock", metavar="X0,Y0,Z0,X1,Y1,Z1",
                   help="raw part, lower and upper corner [mm]")
    p.add_argument("--out", type=Path, required=True, help="output directory")
    p.add_argument("--min-feed", type=float, default=10.0, metavar="MM_MIN",
                   help="lowest feed written (default 10 mm/min)")
    p.add_argument("--air-feed", type=float, default=None, metavar="MM_MIN",
                   help="feed of G1/G2/G3 moves in air (default the machine's path feed)")
    p.add_argument("--no-verify", action="store_true",
                   help="do not simulate the two programs (cycle times from the interpolator)")
    p.add_argument("--seed", type=int, default=0, help="seed of the verification runs")
    p.set_defaults(func=_cmd_optimize)


def _cmd_optimize(args: argparse.Namespace) -> int:
    from rich.progress import Progress

    from cnctwin.engagement import parse_stock
    from cnctwin.machine import MachineFile, load_machine, read_tool_table
    from cnctwin.optimizer import optimize_program
    from cnctwin.optimizer.report import optimize_report
    from cnctwin.sim.gcode import parse_program
    from cnctwin.sim.materials import resolve_material

    if not args.program.is_file():
        raise ConfigError(f"{args.program}: no such program file")
    for opt, what in (("material", "the workpiece material (NAME or FILE.toml)"),
                      ("tools", "the tool table (TOOLS.toml)"),
                      ("stock", "the raw part X0,Y0,Z0,X1,Y1,Z1 in mm")):
        if getattr(args, opt) is None:
            raise ConfigError(f"{args.program}: give --{opt}: the optimizer needs {what}")
    mfile = load_machine(args.machine) if args.machine is not None else MachineFile()
    material = resolve_material(args.material, machine_materials=getattr(mfile, "materials", {}),
                                machine_source=str(args.machine))
    tools = read_tool_table(args.tools)
    stock = parse_stock(args.stock)
    for v, name in ((args.min_feed, "--min-feed"), (args.air_feed, "--air-feed")):
        if v is not None and not v > 0:
            raise ConfigError(f"{name} must be a positive feed in mm/min, got {v}")
    try:
        text = args.program.read_text(encoding="utf-8")
        prog = parse_program(text, name=args.program.stem)
    except GCodeError as exc:
        raise ConfigError(f"{args.program}: {exc}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{args.program}: cannot read the program: {exc}") from None
    with Progress(transient=True) as bar:
        task = bar.add_task("optimize", total=1.0)

        def progress(fraction: float, what: str) -> None:
            bar.update(task, completed=fraction, description=f"optimize: {what}")

        try:
            res = optimize_program(prog, mfile, material, tools, stock,
                                   min_feed_mm_min=args.min_feed, air_feed_mm_min=args.air_feed,
                                   verify=not args.no_verify, seed=args.seed,
                                   name=args.program.stem, progress=progress)
        except ConfigError as exc:
            raise ConfigError(f"{args.program}: {exc}") from None
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "optimized.mpf").write_text(res.text, encoding="utf-8")
    doc = {"program": str(args.program), "machine": str(args.machine or "thesis default"),
           "material": {"name": material.material.name, "origin": material.origin,
                        "where": material.where},
           "cycle_time_s": res.cycle_time_s, "violations": res.violations,
           "verified": not args.no_verify,
           "margin": {"total": res.limits.margin, **res.limits.margin_parts},
           "lines": [ln.to_dict() for ln in res.lines]}
    (out / "optimize.json").write_text(json.dumps(doc, indent=1), encoding="utf-8")
    optimize_report(res, out / "report.html", program=args.program.name)
    ct = res.cycle_time_s
    saved = (1.0 - ct["optimized"] / ct["programmed"]) * 100.0 if ct["programmed"] else 0.0
    print(f"cycle time {ct['programmed']:.1f} s -> {ct['optimized']:.1f} s "
          f"({saved:.1f} % shorter); {len(res.lines)} milling lines, margin "
          f"{res.limits.margin * 100:.1f} %")
    binds: dict[str, int] = {}
    for ln in res.lines:
        binds[ln.binding] = binds.get(ln.binding, 0) + 1
    print("bound by: " + ", ".join(f"{k} {v}" for k, v in sorted(binds.items(),
                                                                key=lambda kv: -kv[1])))
    for v in res.violations:
        print(f"violation: line {v['line']} ({v['block']}): {v['limit']} {v['value']:.4g} > "
              f"{v['allowed']:.4g}")
    for f in ("optimized.mpf", "optimize.json", "report.html"):
        print(out / f)
    return 0
