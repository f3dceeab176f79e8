"""``cnctwin twin compare``: where does the machine depart from its calibrated twin?"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

import orjson

from cnctwin.exceptions import ConfigError

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from cnctwin.compare import AxisComparison, MachineComparison

__all__ = ["register"]


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``twin compare`` to the command line.

    Parameters
    ----------
    sub : argparse._SubParsersAction[argparse.ArgumentParser]
        The ``cnctwin`` subcommand parsers; the module adds its commands to them.
    """
    p = sub.add_parser("twin", help="run the calibrated twin beside a recording",
                       description="Run the twin of a machine file beside the machine.")
    tsub = p.add_subparsers(dest="what", metavar="WHAT", required=True)
    c = tsub.add_parser(
        "compare",
        help="compare a recording with the calibrated twin (compare.json + HTML)",
        description="Drive the calibrated twin with the recording's own setpoints and compare "
        "following error, axis current and spindle air current with what the machine "
        "measured. Writes DIR/compare.json and DIR/compare.html; an axis is flagged where "
        "the machine departs from its twin beyond the calibrated uncertainty.",
    )
    c.add_argument("recording", type=Path, help="recording of the machine")
    c.add_argument("--machine", type=Path, required=True, metavar="FILE",
                   help="machine file (cnctwin calibrate)")
    c.add_argument("--out", type=Path, required=True, metavar="DIR", help="output directory")
    c.add_argument("--axis", action="append", default=[], metavar="NAME",
                   help="axis to compare (repeatable; default every moving axis)")
    c.add_argument("--residual-limit", type=float, default=0.2,
                   help="largest following-error residual ratio of a twin that holds "
                   "(default 0.2)")
    c.add_argument("--fail-on-departure", action="store_true",
                   help="exit with status 3 when anything is flagged")
    c.set_defaults(func=_cmd_compare)


def _axis_figure(name: str, a: AxisComparison) -> Figure:
    import matplotlib.pyplot as plt
    import numpy as np

    s = a.series
    t = s["time_s"] - s["time_s"][0]
    n = 3 if "i_meas" in s else 2
    fig, axs = plt.subplots(n, 1, figsize=(9, 2.3 * n), sharex=True)
    axs[0].plot(t, s["fe_meas"] * 1000.0, lw=0.8, label="machine")
    axs[0].plot(t, s["fe_pred"] * 1000.0, lw=0.8, ls="--", label="twin")
    axs[0].set_ylabel("following error [µm]")
    axs[0].legend(fontsize=8, loc="upper right")
    axs[1].plot(t, (s["fe_meas"] - s["fe_pred"]) * 1000.0, lw=0.8, color="C3")
    axs[1].set_ylabel("machine - twin [µm]")
    for sp in a.spans:
        for ax in axs:
            ax.axvspan(sp["start_s"] - s["time_s"][0], sp["end_s"] - s["time_s"][0],
                       color="C3", alpha=0.15)
    if n == 3:
        axs[2].plot(t, s["i_meas"], lw=0.6, label="machine")
        axs[2].plot(t, s["i_pred"], lw=0.8, ls="--", label="twin (measured motion)")
        axs[2].set_ylabel("current [A]")
        axs[2].legend(fontsize=8, loc="upper right")
    axs[-1].set_xlabel("time [s]")
    for ax in axs:
        ax.grid(alpha=0.3)
    fig.suptitle(f"{name}: residual ratio {a.residual_ratio:.3f}"
                 + ("  (flagged)" if a.flagged else ""), fontsize=10)
    fig.tight_layout()
    _ = np
    return fig


def _report(cmp: MachineComparison, path: Path, recording: Path, machine: Path) -> None:
    import pandas as pd

    from cnctwin.report import Report

    rep = Report("Machine against its twin", subtitle=f"{recording} with {machine}")
    sec = rep.section("Summary")
    rows = []
    for name, a in cmp.axes.items():
        rows.append({"axis": name, "FE residual ratio [-]": f"{a.residual_ratio:.3f}",
                     "current residual ratio [-]": "-" if a.current_residual_ratio is None
                     else f"{a.current_residual_ratio:.3f}",
                     "flagged": "yes" if a.flagged else "no",
                     "why": "; ".join(a.reasons) or "-"})
    if cmp.spindle is not None:
        sp = cmp.spindle
        rows.append({"axis": "spindle (air current)",
                     "FE residual ratio [-]": "-",
                     "current residual ratio [-]": "-" if sp.residual_ratio != sp.residual_ratio
                     else f"{sp.residual_ratio:.3f}",
                     "flagged": "yes" if sp.flagged else "no",
                     "why": "; ".join(sp.reasons) or "-"})
    sec.table(pd.DataFrame(rows), caption="residual ratio = rms(machine - twin) / rms(machine) "
              "over the moving cycles")
    for k, v in cmp.skipped.items():
        sec.text(f"{k}: not compared ({v})", note=True)
    for name, a in cmp.axes.items():
        s2 = rep.section(f"Axis {name}")
        s2.figure(_axis_figure(name, a), caption=f"{name}: following error of machine and "
                  "twin, their difference (departures shaded) and the motor current (thesis "
                  "Figs. 3.2/3.3 style)")
        if a.parameters:
            s2.table(pd.DataFrame([{"parameter": k, "twin": f"{v['twin']:.5g}",
                                    "this recording": f"{v['machine']:.5g}",
                                    "distance [sigma]": f"{v['z']:.1f}"}
                                   for k, v in a.parameters.items()]),
                     caption="what the recording shows against the machine file")
    rep.write(path)


def _cmd_compare(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

    from cnctwin.compare import compare_recording
    from cnctwin.iotools import read_recording
    from cnctwin.machine import load_machine

    mf = load_machine(args.machine)
    if not args.recording.exists():
        raise ConfigError(f"{args.recording}: no such file")
    err = Console(stderr=True)
    with err.status("reading the recording"):
        rec = read_recording(args.recording)
    with err.status("running the twin beside the recording"):
        cmp = compare_recording(rec, mf, axes=args.axis or None,
                                residual_limit=args.residual_limit)
    if not cmp.axes and cmp.spindle is None:
        raise ConfigError(f"{args.recording}: nothing to compare: no axis of {args.machine} "
                          f"moves in it and the spindle has no current "
                          f"({'; '.join(f'{k}: {v}' for k, v in cmp.skipped.items()) or '-'})")
    args.out.mkdir(parents=True, exist_ok=True)
    doc: dict[str, Any] = {"recording": str(args.recording), "machine": str(args.machine),
                           **cmp.to_dict()}
    tmp = args.out / "compare.json.tmp"
    # orjson: strict JSON, a value that could not be computed (NaN) is null
    tmp.write_bytes(orjson.dumps(doc, option=orjson.OPT_INDENT_2 | orjson.OPT_SERIALIZE_NUMPY)
                    + b"\n")
    _report(cmp, args.out / "compare.html", args.recording, args.machine)
    tmp.replace(args.out / "compare.json")
    table = Table(title=f"{args.recording.name} against {args.machine.name}")
    for col in ("axis", "FE residual ratio", "flagged", "why"):
        table.add_column(col)
    for name, a in cmp.axes.items():
        table.add_row(name, f"{a.residual_ratio:.3f}", "yes" if a.flagged else "no",
                      "; ".join(a.reasons))
    if cmp.spindle is not None:
        table.add_row("spindle", "-", "yes" if cmp.spindle.flagged else "no",
                      "; ".join(cmp.spindle.reasons))
    out = Console()
    out.print(table)
    out.print(f"wrote {args.out / 'compare.json'} and {args.out / 'compare.html'}")
    flagged = doc["flagged"]
    return 3 if (flagged and args.fail_on_departure) else 0
