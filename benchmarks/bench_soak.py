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
from cnctwin.sim.programs import production_program
from cnctwin.sim.scenarios import random_spindle_overrides
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


def draw(d: Path, machine: Path, sets: list[str], seed: int, operations: int) -> SoakTally:
    """One production draw: simulate, replay through edge run, tally."""
    prog = production_program(seed, operations=operations)
    part = d / f"part{seed}.mpf"
    part.write_text(prog.text, encoding="utf-8")
    sim = d / f"sim{seed}"
    cli("simulate", "--program", part, "--machine", machine, "--material", "aisi1045",
        "--seed", seed, *sets, "--out", sim)
    st = d / f"edge{seed}"
    cli("edge", "run", "--source", sim / f"part{seed}.json", "--machine", machine,
        "--out", st, "--no-twin")
    return tally_run(st / "results.jsonl", read_recording(sim / f"part{seed}.json"),
                     holes_expected=prog.holes, machine_file=machine,
                     noise_a=current_noise_a(sim / "truth.json"))


def run(draws: int, operations: int, machine_seed: int, first_seed: int) -> list[SoakTally]:
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
            t = draw(d, machine, sets, s, operations)
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
    a = ap.parse_args()
    print(summary(run(a.draws, a.operations, a.machine_seed, a.first_seed)))
