"""Soak: false alarms, hole counts and torque-without-a-cut on varied healthy production.

Issue 24: a calibrated simulated machine (hidden spindle drawn from a seed, calibrated as the
README says: air-cut sweep, one drilling cut with the dynamometer, ``cnctwin calibrate
spindle``) runs randomly drawn production (``cnctwin.sim.programs.production_program``:
drilling, peck drilling, tapping, milling entries by plunge, ramp and helix, speed and tool
changes, dwells, air moves), each draw with its own noise seed, replayed through
``cnctwin edge run`` with the default detectors, everything through the command line. On a
healthy machine every alarm is false; every drilling-cycle call must be found once and
nothing else; the cutting torque while the tip is above the workpiece must stay within the
calibration's stated uncertainty (``cnctwin.validation.soak.air_torque_bound_nm``, k = 4).

Run: ``.venv/bin/python benchmarks/bench_soak.py --draws 40`` (about 1.5 machine-hours;
``--draws 200 --operations 12`` gives >= 8 h). Prints one row per draw and the rates.

``--faults``: the same draws with one injected fault each, in turn: ``breakage`` (the drill
breaks at a random depth fraction 0.3-0.8 of a random hole), ``load_rise`` (worn drill / harder
stock: cutting load x 1.3-1.6 from a random hole on, the simulator's ``HardnessChange``) and
``friction_rise`` (spindle Coulomb friction x 1.5-2.5 against the calibrated machine file, from
the start) and ``loose_tap`` (the simulator's ``LooseTool`` from a random tapped hole on; a draw
without tapping is skipped). Per kind: draws, found (the first alarm on the fault's hole, or
any alarm for the friction), alarms before the fault's hole (false).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import sys
import tempfile
import time
from pathlib import Path

from cnctwin.cli import main
from cnctwin.iotools import read_recording
from cnctwin.sim.programs import PRODUCTION_STOCK, PRODUCTION_TOOLS, production_program
from cnctwin.sim.scenarios import random_spindle_overrides
from cnctwin.usecases.hole_load import HoleLoadJudge
from cnctwin.validation.soak import SoakTally, current_noise_a, tally_run

REFERENCE = "drill_1_aisi1045_2400rpm_0p16"
SPEEDS = list(range(200, 5001, 400)) + list(range(4600, 199, -400))


def cli(*args: object) -> None:
    sink = io.StringIO()  # the per-command summaries
    with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink):
        rc = main([str(a) for a in args])
    if rc != 0:
        raise SystemExit(f"cnctwin {' '.join(map(str, args))} exited {rc}")


def calibrated_machine(d: Path, seed: int) -> tuple[Path, list[str]]:
    """Hidden spindle of ``seed``, calibrated through the CLI; (machine file, --set opts)."""
    sets = [x for k, v in random_spindle_overrides(seed).items() for x in ("--set", f"{k}={v}")]
    cli("simulate", "air_cut_sweep", "--out", d / "ac", "--seed", seed, *sets,
        "--option", f"speeds_rpm={SPEEDS}")
    cli("simulate", "drilling_validation", "--out", d / "dv", "--seed", seed, *sets,
        "--option", 'cuts=[["aisi1045", 2400, 0.16]]')
    m = d / "machine.toml"
    cli("calibrate", "spindle", "--air-cut", d / "ac" / "air_cut_sweep.json",
        "--reference", d / "dv" / f"{REFERENCE}.json",
        "--dynamometer", d / "dv" / f"dynamometer_{REFERENCE[6:]}.csv", "--machine", m)
    return m, sets


def milling_options(d: Path, milling: bool) -> tuple[list[object], list[object]]:
    """The simulator's and the edge's extra options of a draw with real milling (the tool
    table, and the stock for the simulator); none without."""
    if not milling:
        return [], []
    tools = d / "tools.toml"
    tools.write_text(PRODUCTION_TOOLS, encoding="utf-8")
    return ["--tools", tools, "--stock", PRODUCTION_STOCK], ["--tools", tools]


def draw(d: Path, machine: Path, sets: list[str], seed: int, operations: int,
         milling: bool = False) -> SoakTally:
    """One production draw: simulate, replay through edge run, tally. ``milling``: the
    milling operations with an end mill (T3) through a stock, tool table at the edge."""
    prog = production_program(seed, operations=operations, end_mill=3 if milling else None)
    part = d / f"part{seed}.mpf"
    part.write_text(prog.text, encoding="utf-8")
    sim = d / f"sim{seed}"
    extra, edge_extra = milling_options(d, milling)
    cli("simulate", "--program", part, "--machine", machine, "--material", "aisi1045",
        "--seed", seed, *sets, *extra, "--out", sim)
    st = d / f"edge{seed}"
    cli("edge", "run", "--source", sim / f"part{seed}.json", "--machine", machine,
        "--out", st, "--no-twin", *edge_extra)
    return tally_run(st / "results.jsonl", read_recording(sim / f"part{seed}.json"),
                     holes_expected=prog.holes, machine_file=machine,
                     noise_a=current_noise_a(sim / "truth.json"))


FAULT_KINDS = ("breakage", "load_rise", "friction_rise", "loose_tap")


def draw_fault(d: Path, machine: Path, sets: list[str], seed: int, operations: int,
               kind: str, milling: bool = False) -> dict[str, object]:
    """One production draw with one fault: simulate, replay through edge run, judge."""
    import json

    import numpy as np

    prog = production_program(seed, operations=operations, end_mill=3 if milling else None)
    extra, edge_extra = milling_options(d, milling)
    rng = np.random.default_rng([seed, 24])
    part = d / f"fpart{seed}.mpf"
    part.write_text(prog.text, encoding="utf-8")
    sim = d / f"fsim{seed}"
    opts: list[object] = []
    hole: int | None = None
    judgeable = True
    if kind == "friction_rise":
        tau = float(np.exp(rng.uniform(np.log(1.5), np.log(2.5))))
        key = "spindle.coulomb_friction_nm"
        values = dict(x.split("=", 1) for x in sets[1::2])  # the hidden machine's --set
        from cnctwin.sim import Machine

        values[key] = str(float(values.get(key, Machine.thesis_default().spindle
                                           .coulomb_friction_nm)) * tau)
        sets = [x for k, v in values.items() for x in ("--set", f"{k}={v}")]
        detail = f"Coulomb x {tau:.2f}"
    else:
        # the healthy run first: which simulator hole (every entry at a new X/Y, milling
        # entries too) is which hole of the edge, so the fault goes on a real hole
        hsim, hedge = d / f"hsim{seed}", d / f"hedge{seed}"
        cli("simulate", "--program", part, "--machine", machine, "--material", "aisi1045",
            "--seed", seed, *sets, *extra, "--out", hsim)
        cli("edge", "run", "--source", hsim / f"fpart{seed}.json", "--machine", machine,
            "--out", hedge, "--no-twin", *edge_extra)
        truth = json.loads((hsim / "truth.json").read_text())["holes"]
        rows = [m["row"] for m in map(json.loads, (hedge / "results.jsonl").read_text()
                                      .splitlines()) if m["kind"] == "hole"]
        mapped = {}
        for r in rows:
            near = [t for t in truth if abs(t["x_mm"] - r["x_mm"]) < 0.05
                    and abs(t["y_mm"] - r["y_mm"]) < 0.05
                    and abs(t["cut_first_cycle"] - r["cut_start_cycle"]) < 1500]
            if near:
                mapped[int(r["hole"])] = int(near[0]["hole"])
        pool = sorted(mapped)
        if kind == "loose_tap":  # a tap that works loose: on a tapped hole after the first of
            # its condition (a tap loose from the first hole on is the reference: by design)
            taps = [r for r in rows if r["cycle"] == "CYCLE84"]
            pool = [h for h in pool if any(
                int(r["hole"]) == h and any(
                    int(q["hole"]) < h and HoleLoadJudge.same_condition(
                        HoleLoadJudge.condition(q), HoleLoadJudge.condition(r))
                    for q in taps) for r in taps)]
            if not pool:
                return {"seed": seed, "kind": kind, "detail": "no judgeable tap",
                        "found": False, "later": False, "judgeable": False, "before": 0,
                        "alarms": 0, "first": None, "skipped": True}
        hole = int(rng.choice(pool))
        sim_hole = mapped[hole]
        row = next(r for r in rows if int(r["hole"]) == hole)
        # the first hole of a cut condition has no taught reference (only a breakage in it
        # shows, against the cut's own mean): counted apart
        judgeable = kind == "breakage" or any(
            HoleLoadJudge.same_condition(HoleLoadJudge.condition(r), HoleLoadJudge.condition(row))
            for r in rows if int(r["hole"]) < hole)
        if kind == "loose_tap":
            fault = {"type": "LooseTool", "start_hole": sim_hole}
            detail = f"from hole {hole}"
        elif kind == "breakage":
            frac = float(rng.uniform(0.3, 0.8))
            # without a tool table the simulator's depth fraction is of a 20 mm hole (its one
            # drilling process has one hole depth): scaled to this hole's depth; with the
            # table (--milling) each tool's process knows its cycle's depth
            scaled = frac if milling else frac * min(1.0, float(row["depth_mm"]) / 20.0)
            fault = {"type": "ToolBreakage", "hole": sim_hole, "depth_fraction": scaled}
            detail = f"hole {hole} at {frac:.2f}"
        else:
            factor = float(rng.uniform(1.3, 1.6))
            fault = {"type": "HardnessChange", "hole": sim_hole, "factor": factor}
            detail = f"x {factor:.2f} from hole {hole}"
        opts = ["--option", f"faults={json.dumps([fault])}"]
    cli("simulate", "--program", part, "--machine", machine, "--material", "aisi1045",
        "--seed", seed, *sets, *extra, *opts, "--out", sim)
    st = d / f"fedge{seed}"
    cli("edge", "run", "--source", sim / f"fpart{seed}.json", "--machine", machine,
        "--out", st, "--no-twin", *edge_extra)
    alarms = [m for m in map(json.loads, (st / "results.jsonl").read_text().splitlines())
              if m["kind"] == "alarm"]
    later = False
    if hole is None:
        found, before = bool(alarms), 0
    else:
        before = sum(1 for a in alarms if a.get("hole") is not None and a["hole"] < hole)
        found = bool(alarms) and alarms[0].get("hole") == hole
        later = bool(alarms) and not found and before == 0
    return {"seed": seed, "kind": kind, "detail": detail, "found": found, "later": later,
            "judgeable": judgeable,
            "before": before, "alarms": len(alarms),
            "first": (alarms[0].get("detector"), alarms[0].get("fault"), alarms[0].get("hole"))
            if alarms else None}


def run_faults(draws: int, operations: int, machine_seed: int, first_seed: int,
               kinds: tuple[str, ...] = FAULT_KINDS,
               milling: bool = False) -> list[dict[str, object]]:
    out: list[dict[str, object]] = []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        machine, sets = calibrated_machine(d, machine_seed)
        for k in range(draws):
            kind = kinds[k % len(kinds)]
            r = draw_fault(d, machine, sets, first_seed + k, operations, kind, milling)
            out.append(r)
            print(f"{r['seed']:>5} {kind:<14} {r['detail']!s:<22} "
                  f"{'' if r['judgeable'] else '(first of its condition) '}"
                  f"found {r['found']!s:<5} later {r['later']!s:<5} "
                  f"alarms {r['alarms']:>3} (before the fault {r['before']}) first {r['first']}",
                  flush=True)
    for kind in kinds:
        rows = [r for r in out if r["kind"] == kind and r["judgeable"]]
        first = sum(1 for r in out if r["kind"] == kind and not r["judgeable"]
                    and not r.get("skipped"))
        if first:
            print(f"{kind}: {first} on the first hole of a cut condition (no reference: "
                  "not judged)")
        if rows:
            print(f"{kind}: found on its hole {sum(bool(r['found']) for r in rows)}/{len(rows)}"
                  f", later {sum(bool(r['later']) for r in rows)}, "
                  f"alarms before the fault {sum(int(r['before']) for r in rows)}")  # type: ignore[call-overload]
    return out


def run(draws: int, operations: int, machine_seed: int, first_seed: int,
        milling: bool = False) -> list[SoakTally]:
    out: list[SoakTally] = []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        t0 = time.perf_counter()
        machine, sets = calibrated_machine(d, machine_seed)
        print(f"machine seed {machine_seed} calibrated in {time.perf_counter() - t0:.0f} s",
              file=sys.stderr)
        print(f"{'draw':>5} {'min':>6} {'alarms':>6} {'holes':>9} {'plunge':>6} "
              f"{'air |tq| max':>12} {'bound':>6} {'over':>5}")
        for k in range(draws):
            s = first_seed + k
            t = draw(d, machine, sets, s, operations, milling)
            out.append(t)
            print(f"{s:>5} {t.machine_s / 60:6.1f} {t.alarms:6d} "
                  f"{t.holes_found:4d}/{t.holes_expected:<4d} {t.plunge_holes:6d} "
                  f"{t.air_torque_max_nm:12.3f} {t.air_torque_bound_nm:6.3f} "
                  f"{t.air_over_bound:5d}", flush=True)
    return out


def summary(rows: list[SoakTally]) -> str:
    h = sum(r.machine_s for r in rows) / 3600.0
    alarms = sum(r.alarms for r in rows)
    exp = sum(r.holes_expected for r in rows)
    wrong = sum(abs(r.holes_found - r.holes_expected) for r in rows)
    over = sum(r.air_over_bound for r in rows)
    air = sum(r.air_cycles for r in rows)
    return (f"{len(rows)} draws, {h:.2f} machine-hours: {alarms} false alarms "
            f"({alarms / h:.2f} per machine-hour); holes {exp - wrong}/{exp} right, "
            f"{sum(r.holes_expected != r.holes_found for r in rows)} draws with a wrong "
            f"count; air torque beyond the bound in {over} of {air} cycles")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=40)
    ap.add_argument("--operations", type=int, default=8)
    ap.add_argument("--machine-seed", type=int, default=7)
    ap.add_argument("--first-seed", type=int, default=100)
    ap.add_argument("--faults", action="store_true",
                    help="inject one fault per draw (breakage, load rise, friction rise, "
                    "loose tap)")
    ap.add_argument("--milling", action="store_true",
                    help="the milling operations with an end mill (T3) through a stock, with "
                    "a tool table in the simulator and at the edge")
    ap.add_argument("--kinds", default=",".join(FAULT_KINDS),
                    help="with --faults: the fault kinds, in turn (comma-separated)")
    a = ap.parse_args()
    if a.faults:
        run_faults(a.draws, a.operations, a.machine_seed, a.first_seed,
                   tuple(k.strip() for k in a.kinds.split(",") if k.strip()), a.milling)
    else:
        print(summary(run(a.draws, a.operations, a.machine_seed, a.first_seed, a.milling)))
