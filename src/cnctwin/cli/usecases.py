"""Use-case subcommands: ``cnctwin holes``, ``cnctwin wear``, ``cnctwin anomalies``.

``holes FILE... [--out CSV] [--figures DIR]``
    Per-hole record (thesis chapter 5) of one or more recordings in time order.
``wear FILE... [--measured hole:um,...] [--limit-um 300] [--out DIR]``
    Tool-wear trend: relative increase of the per-hole cutting torque over the new tool (set
    means remove the heating pattern), calibrated to micrometres on measured points, and the
    remaining-life forecast.
``anomalies FILE... [--detector envelope|adaptive|physics-torque|physics|spectral|tapping]
[--learn-s N] [--material M] [--out DIR]``
    Teach a detector on the first seconds, score the rest, list the alarms. ``adaptive``: the
    wear-adaptive torque band around the teach-in profile; ``physics-torque``: the same around
    the Kienzle-predicted torque, no teach-in (``--learn-s 0`` by default).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cnctwin.exceptions import ConfigError

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["register"]

_HOLE_SHOW = ("hole", "set", "position_in_set", "start_s", "depth_mm", "current_mean_a",
              "torque_mean_nm", "energy_j", "thrust_proxy", "dev_x_maxabs_mm", "dev_y_maxabs_mm",
              "tool", "cycle")


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``holes``, ``wear`` and ``anomalies`` to the ``cnctwin`` command line.

    Parameters
    ----------
    sub : argparse._SubParsersAction[argparse.ArgumentParser]
        The ``cnctwin`` subcommand parsers; the module adds its commands to them.
    """
    p = sub.add_parser("holes", help="per-hole record of drilling recordings",
                       description="One row per drilled hole (thesis chapter 5): segmentation "
                       "from Z motion and NC events, current, torque, energy, deviations.")
    p.add_argument("files", nargs="+", type=Path, metavar="FILE", help="recordings, time order")
    p.add_argument("--out", type=Path, help="write the full table to this CSV")
    p.add_argument("--figures", type=Path, metavar="DIR",
                   help="write hole-mean and deviation-path figures (PNG) here")
    p.add_argument("--machine", type=Path, metavar="FILE",
                   help="machine file (cnctwin calibrate): its calibrated spindle for the "
                   "torque (default: the thesis machine's, not calibrated to yours)")
    p.set_defaults(func=_cmd_holes)

    w = sub.add_parser("wear", help="tool-wear trend, estimate and remaining life",
                       description="Relative increase of the per-hole cutting torque (set means "
                       "remove the tool-heating pattern), mapped to flank wear on measured points.")
    w.add_argument("files", nargs="+", type=Path, metavar="FILE")
    w.add_argument("--measured", default="", metavar="HOLE:UM,...",
                   help="measured flank wear, e.g. 100:45,1000:150 (hole index: µm)")
    w.add_argument("--limit-um", type=float, default=300.0, help="wear limit [µm] (300)")
    w.add_argument("--set-size", type=int, default=6, help="holes per set (6)")
    w.add_argument("--baseline", type=int, default=30, help="new-tool holes (30)")
    w.add_argument("--out", type=Path, metavar="DIR", help="write figures and wear.csv here")
    w.add_argument("--machine", type=Path, metavar="FILE",
                   help="machine file (cnctwin calibrate): its calibrated spindle for the "
                   "torque (default: the thesis machine's, not calibrated to yours)")
    w.set_defaults(func=_cmd_wear)

    a = sub.add_parser("anomalies", help="replay recordings through an anomaly detector",
                       description="Teach a detector on the first --learn-s seconds of the "
                       "recordings (good data), score the rest, list the alarms.")
    a.add_argument("files", nargs="+", type=Path, metavar="FILE")
    a.add_argument("--detector", choices=("envelope", "adaptive", "physics-torque", "physics",
                                          "spectral", "tapping"),
                   default="envelope",
                   help="adaptive: wear-adaptive torque band (teach-in profile); "
                        "physics-torque: the same around the Kienzle torque, from part 1")
    a.add_argument("--material", default="aisi1045",
                   help="Kienzle material for physics-torque (aisi1045, grey_cast_iron)")
    a.add_argument("--drill-mm", type=float, default=8.5,
                   help="drill diameter for physics-torque [mm] (8.5)")
    a.add_argument("--learn-s", type=float, default=None,
                   help="teach-in duration [s] (default: the first third)")
    a.add_argument("--threshold", type=float, default=0.0, help="alarm above this score (0)")
    a.add_argument("--out", type=Path, metavar="DIR", help="write the score figure here")
    a.add_argument("--machine", type=Path, metavar="FILE",
                   help="machine file (cnctwin calibrate): its calibrated spindle for the "
                   "torque (default: the thesis machine's, not calibrated to yours)")
    a.set_defaults(func=_cmd_anomalies)


def _read(files: list[Path]) -> list[Any]:
    from cnctwin.iotools import read_recording

    for f in files:
        if not f.exists():
            raise ConfigError(f"file not found: {f}")
    return [read_recording(f) for f in files]


def _model(args: argparse.Namespace) -> Any:
    """The calibrated spindle of ``--machine`` (None: the thesis machine's, said so)."""
    if getattr(args, "machine", None) is None:
        return None
    from cnctwin.machine import load_machine
    from cnctwin.spindle import SpindleModel

    mf = load_machine(args.machine)
    if not mf.is_identified("spindle.kt_nm_per_a"):
        raise ConfigError(f"{args.machine}: the spindle is not calibrated (spindle.kt_nm_per_a "
                          "has no provenance); run 'cnctwin calibrate spindle ... --machine "
                          f"{args.machine}' first")
    return SpindleModel.from_machine(mf)


def _holes(files: list[Path], set_size: int = 6, model: Any = None
           ) -> tuple[list[Any], pd.DataFrame]:
    recs = _read(files)
    return recs, _holes_of(recs, set_size=set_size, model=model)


def _holes_of(recs: list[Any], set_size: int = 6, model: Any = None) -> pd.DataFrame:
    from cnctwin.usecases.holes import hole_records

    holes = hole_records(recs, set_size=set_size, model=model)
    if holes.empty:
        raise ConfigError(
            "no hole found (no plunge of the Z axis in the recordings): holes and wear need "
            "drilling. For other recordings: 'cnctwin servo FILE' (position loops), "
            "'cnctwin twin compare FILE --machine M' (against the calibrated twin), "
            "'cnctwin anomalies FILE --detector spectral|physics' (every sample scored), "
            "'cnctwin info FILE' (what it holds)")
    return holes


def _table(df: pd.DataFrame, title: str) -> None:
    from rich.console import Console
    from rich.table import Table

    t = Table(title=title)
    for c in df.columns:
        t.add_column(str(c), justify="right")
    for row in df.itertuples(index=False):
        t.add_row(*[_fmt(v) for v in row])
    Console(width=200).print(t)


def _fmt(v: object) -> str:
    import numpy as np
    import pandas as pd

    if isinstance(v, float | np.floating):
        if not math.isfinite(float(v)):
            return "-"
        return f"{float(v):.4g}"
    if v is None or v is pd.NA:
        return "-"
    return str(v)


def _cmd_holes(args: argparse.Namespace) -> int:
    import pandas as pd

    from cnctwin.usecases.figures import plot_deviation_paths, plot_hole_means
    from cnctwin.usecases.quality import deviation_paths

    recs, holes = _holes(args.files, model=_model(args))
    _table(holes[[c for c in _HOLE_SHOW if c in holes.columns]],
           f"{len(holes)} holes ({holes.attrs.get('thrust_source', '')})")
    for issue in holes.attrs.get("issues", []):
        print(f"note: {issue}")
    if args.out:
        holes.to_csv(args.out, index=False)
        print(f"wrote {args.out}")
    if args.figures:
        args.figures.mkdir(parents=True, exist_ok=True)
        plot_hole_means(holes).savefig(args.figures / "hole_means.png", dpi=110)
        paths = pd.concat([deviation_paths(r, holes) for r in recs], ignore_index=True)
        if not paths.empty:
            for view in ("3d", "xz", "yz", "xy"):
                plot_deviation_paths(paths, view=view).savefig(
                    args.figures / f"deviation_{view}.png", dpi=110)
        print(f"wrote figures to {args.figures}")
    return 0


def _parse_measured(text: str) -> dict[int, float]:
    out: dict[int, float] = {}
    for item in filter(None, (s.strip() for s in text.split(","))):
        h, sep, um = item.partition(":")
        try:
            if not sep:
                raise ValueError
            out[int(h)] = float(um)
        except ValueError:
            raise ConfigError(f"--measured {item!r}: expected HOLE:UM, e.g. 1000:150") from None
    return out


def _cmd_wear(args: argparse.Namespace) -> int:
    import numpy as np
    import pandas as pd

    from cnctwin.usecases.figures import plot_hole_means
    from cnctwin.usecases.wear import (
        WearEstimator,
        forecast_remaining_life,
        relative_increase,
        set_pattern,
    )

    measured = _parse_measured(args.measured)
    _, holes = _holes(args.files, set_size=args.set_size, model=_model(args))
    torque = holes["torque_mean_nm"].to_numpy(dtype=np.float64)
    baseline = min(args.baseline, len(holes))
    inc = relative_increase(torque, baseline=baseline, set_size=args.set_size)
    out = holes[["hole", "set", "current_mean_a", "torque_mean_nm"]].copy()
    out["relative_increase"] = inc
    summary: list[tuple[str, str]] = [("holes", str(len(holes))),
                                      ("torque increase at the last hole", f"{inc[-1]:.2%}")]
    if len(holes) >= args.set_size:
        pat = set_pattern(torque, set_size=args.set_size)
        summary.append(("last vs first hole of a set", f"{pat.rise_last_vs_first:+.2%}"))
    wear = None
    if measured:
        bad = [h for h in measured if h not in set(holes["hole"])]
        if bad:
            raise ConfigError(f"--measured holes {bad} are not in the record "
                              f"(holes 0..{int(holes['hole'].max())})")
        idx = holes.reset_index().set_index("hole").loc[list(measured), "index"].to_numpy()
        # with three or more measured holes the offset is fitted too: the run-in wear of a
        # new tool comes before the baseline sets can show a torque increase
        est = WearEstimator().fit(inc[idx], list(measured.values()),
                                  fit_offset=len(measured) >= 3)
        wear = est.predict(inc)
        out["wear_um"] = wear
        std = est.predict_std(inc[-1:])
        wear_std = float(std[0]) if np.isfinite(std[0]) else 0.0
        # the keys of the live tool life (docs/tool-life.md), for the tool's [tools.N]
        keys = [f"wear_um_per_increase = {est.slope_um:.6g}",
                f"wear_offset_um = {est.offset_um:.6g}", f"wear_std_um = {wear_std:.4g}",
                f"wear_baseline_holes = {baseline}", f"wear_limit_um = {args.limit_um:g}"]
        summary += [("wear per unit increase", f"{est.slope_um:.4g} ± {est.slope_std_um:.2g} µm"),
                    ("wear at the baseline", f"{est.offset_um:.4g} µm"),
                    ("estimated wear at the last hole", f"{wear[-1]:.1f} µm"),
                    ("uncertainty of a wear estimate",
                     f"{wear_std:.3g} µm (at the last hole; fit and scatter of the "
                     "measured points)"),
                    ("tool table keys (live tool life)", ", ".join(keys))]
        try:
            fc = forecast_remaining_life(holes["hole"], wear, limit_um=args.limit_um)
            summary.append((f"holes to {args.limit_um:g} µm",
                            f"{fc.remaining:.0f} (90 %: {fc.remaining_low:.0f}-"
                            f"{fc.remaining_high:.0f})"))
        except Exception as exc:  # not enough points for a trend
            summary.append(("forecast", f"not possible: {exc}"))
    else:
        summary.append(("wear [µm]", "give --measured HOLE:UM,... to calibrate"))
    _table(pd.DataFrame(summary, columns=["quantity", "value"]), "tool wear")
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        out.to_csv(args.out / "wear.csv", index=False)
        plot_hole_means(holes, wear_um=wear).savefig(args.out / "wear_trend.png", dpi=110)
        written = ["wear.csv", "wear_trend.png"]
        if wear is not None:
            (args.out / "wear_calibration.toml").write_text(
                f"# cnctwin wear: flank wear calibrated on {len(measured)} measured holes "
                f"({', '.join(str(h) for h in measured)});\n# copy into the tool's "
                "[tools.N] table of the tool table (cnctwin edge run --tools)\n"
                + "".join(f"{k}\n" for k in keys), encoding="utf-8")
            written.append("wear_calibration.toml")
        print(f"wrote {', '.join(written)} to {args.out}")
    return 0


def _cmd_anomalies(args: argparse.Namespace) -> int:
    import pandas as pd

    from cnctwin.usecases.figures import plot_anomaly_scores
    from cnctwin.usecases.holes import hole_records
    from cnctwin.usecases.replay import replay_detector

    recs = _read(args.files)
    model = _model(args)
    holes: pd.DataFrame | None
    if args.detector == "tapping":
        try:
            holes = hole_records(recs, model=model)
        except Exception:
            holes = pd.DataFrame(columns=["hole", "cut_start_cycle", "cut_end_cycle"])
    else:
        try:
            holes = _holes_of(recs, model=model)
        except ConfigError:
            if args.detector in ("envelope", "adaptive", "physics-torque"):  # need the holes
                raise
            holes = None
            print("note: no hole found; scoring every sample (not only the cuts)")
    rep = replay_detector(recs, holes, detector=args.detector, learn_until_s=args.learn_s,
                          threshold=args.threshold, material=args.material,
                          drill_mm=args.drill_mm, scores=bool(args.out), model=model)
    for issue in rep.issues:
        print(f"note: {issue}")
    res = rep.result
    alarms = pd.DataFrame({"alarm_s": res.alarms_s, "hole": rep.alarm_holes})
    _table(pd.DataFrame([("detector", repr(rep.detector)),
                         ("teach-in until [s]", f"{rep.learn_until_s:.1f}"),
                         ("scored [s]", f"{res.monitored_s:.1f}"),
                         ("alarms", str(len(res.alarms_s)))], columns=["quantity", "value"]),
           "anomaly replay")
    if len(alarms):
        _table(alarms, "alarms")
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        plot_anomaly_scores(rep.score_time_s, rep.score, threshold=args.threshold,
                            alarms_s=res.alarms_s, title=f"{args.detector} detector").savefig(
            args.out / f"anomalies_{args.detector}.png", dpi=110)
        alarms.to_csv(args.out / "alarms.csv", index=False)
        print(f"wrote {args.out / 'alarms.csv'} and the score figure")
    return 0
