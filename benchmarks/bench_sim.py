"""Simulator throughput on one core: machine-seconds simulated per wall-second.

Runs the full machine (5 feed axes + motor spindle, 125 us inner loops, drilling cutting loads
on) on an N-hole drilling program, streaming to a Parquet chunk sink, and reports side by side:

* the physical baseline: real time (1x) and the issue's goal (>= 1000x real time so that the
  2676-hole wear run, ~3.5 h of machining, takes < 15 s);
* the full ``simulate()`` rate and its projection to the 2676-hole run;
* the compiled blocks alone (feed-axis servo, spindle) and the same servo kernel interpreted
  by Python (``py_func``, a short segment) as the un-compiled baseline;
* peak memory (max RSS) while streaming.

Usage::

    NUMBA_NUM_THREADS=1 taskset -c 0 .venv/bin/python benchmarks/bench_sim.py --holes 20 \
        [--write BENCHMARKS.md]
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import re
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np

from cnctwin.sim.cutting import drilling_load
from cnctwin.sim.machine import Machine
from cnctwin.sim.recorder import ParquetChunkSink
from cnctwin.sim.servo import ServoState, _servo_kernel, servo_parameters
from cnctwin.sim.simulation import CuttingInput, CuttingOutput, simulate
from cnctwin.sim.spindle import simulate_spindle

WEAR_RUN_HOLES = 2676
WEAR_RUN_S = 3.5 * 3600.0
GOAL_X = 1000.0


def drilling_program(holes: int, *, depth_mm: float = 20.0, pitch_mm: float = 15.0) -> str:
    """G-code: ``holes`` holes of ``depth_mm`` at F400, S2400 (thesis wear-run settings)."""
    lines = ["G90 G17 G54", "T6 M6", "S2400 M3", "G0 X0 Y0 Z2"]
    side = int(np.ceil(np.sqrt(holes)))
    for i in range(holes):
        x, y = (i % side) * pitch_mm, (i // side) * pitch_mm
        lines += [f"G0 X{x:.3f} Y{y:.3f}", f"G1 Z{-depth_mm:.3f} F400", "G0 Z2"]
    lines += ["M5", "M30"]
    return "\n".join(lines) + "\n"


def cutting_hook(ci: CuttingInput) -> CuttingOutput:
    """Drilling loads (engineer C's Kienzle model) from the expected tip position."""
    z = ci.position["Z1"]
    depth = -z
    vz = np.gradient(z) / ci.cycle_time_s * 60.0  # mm/min
    feed = np.where(ci.spindle_speed_rpm > 1.0, -vz / np.maximum(ci.spindle_speed_rpm, 1.0), 0.0)
    load = drilling_load(depth, ci.spindle_speed_rpm, feed, material="aisi1045",
                         dt_s=ci.cycle_time_s)
    return CuttingOutput(spindle_torque_nm=load.torque_nm,
                         force_n={"Z1": load.thrust_n, "X1": load.fx_n, "Y1": load.fy_n})


def _pin_one_core() -> str:
    if hasattr(os, "sched_setaffinity"):
        cpu = min(os.sched_getaffinity(0))
        os.sched_setaffinity(0, {cpu})
        return f"sched_setaffinity cpu {cpu}"
    return "not pinned"


def _maxrss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def run(holes: int) -> dict[str, float]:
    m = Machine.thesis_default()
    # warm-up: compile / load the numba caches
    simulate(drilling_program(1), m, cutting=cutting_hook)
    rss0 = _maxrss_mb()
    prog = drilling_program(holes)
    with tempfile.TemporaryDirectory() as tmp:
        sink = ParquetChunkSink(Path(tmp) / "run")
        t0 = time.perf_counter()
        res = simulate(prog, m, cutting=cutting_hook, sink=sink, chunk_cycles=50_000)
        wall = time.perf_counter() - t0
    machine_s = res.trajectory["duration_s"]
    n = res.trajectory["n_cycles"]

    # compiled blocks alone on the same number of cycles (5 axes, spindle)
    rng = np.random.default_rng(0)
    t = np.arange(n) * m.cycle_time_s
    des = np.vstack([np.sin(0.5 * t) * 50 for _ in m.axes])
    t0 = time.perf_counter()
    from cnctwin.sim.servo import simulate_servo

    simulate_servo(des, m.axes, rng=rng)
    servo_wall = time.perf_counter() - t0
    t0 = time.perf_counter()
    simulate_spindle(np.full(n, 2400.0), np.full(n, 4.0), m.spindle, rng=rng)
    spindle_wall = time.perf_counter() - t0

    # interpreted baseline: the servo kernel run by Python on 200 cycles
    k = 200
    par = servo_parameters(m.axes)
    st = ServoState.new(len(m.axes))
    out = np.empty((len(m.axes), 20, k))
    t0 = time.perf_counter()
    _servo_kernel.py_func(des[:, :k].copy(), np.zeros((5, k)), np.zeros((5, k)), par, st.values,
                          st.history, out, m.cycle_time_s, m.inner_steps)
    py_wall = time.perf_counter() - t0
    py_rate = k * m.cycle_time_s / py_wall
    return {
        "holes": holes, "cycles": n, "machine_s": machine_s, "wall_s": wall,
        "rate": machine_s / wall, "servo_rate": machine_s / servo_wall,
        "spindle_rate": machine_s / spindle_wall, "servo_py_rate": py_rate,
        "wear_run_projection_s": WEAR_RUN_S / (machine_s / wall),
        "peak_rss_mb": _maxrss_mb(), "rss_before_mb": rss0,
    }


def table(r: dict[str, float]) -> str:
    rows = [
        ("physical baseline: real time", "1x", ""),
        ("issue goal (2676 holes, ~3.5 h, < 15 s)", f">= {GOAL_X:.0f}x", "< 15 s"),
        (f"simulate(): {r['holes']:.0f} holes, 5 axes + spindle, cutting on, Parquet sink",
         f"{r['rate']:.0f}x", f"{r['wear_run_projection_s']:.0f} s (projected)"),
        ("  feed-axis servo alone (5 axes, numba)", f"{r['servo_rate']:.0f}x", ""),
        ("  spindle drive alone (numba)", f"{r['spindle_rate']:.0f}x", ""),
        ("  servo kernel interpreted by Python (py_func)", f"{r['servo_py_rate']:.2f}x", ""),
    ]
    out = ["| what | machine-s per wall-s | 2676-hole run |", "|---|---|---|"]
    out += [f"| {a} | {b} | {c} |" for a, b, c in rows]
    out.append("")
    out.append(f"Run: {r['cycles']:.0f} cycles = {r['machine_s']:.1f} s machine time in "
               f"{r['wall_s']:.2f} s wall; peak RSS {r['peak_rss_mb']:.0f} MB "
               f"(after warm-up {r['rss_before_mb']:.0f} MB) while streaming 50 000-cycle "
               "chunks to Parquet.")
    return "\n".join(out)


def _cpu_model() -> str:
    try:
        txt = subprocess.run(["lscpu"], capture_output=True, text=True, check=False).stdout
        for line in txt.splitlines():
            if line.startswith("Model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return "unknown"


def write_section(path: Path, body: str, pinned: str) -> None:
    head = (f"## Simulator\n\n`benchmarks/bench_sim.py` ({dt.date.today().isoformat()}, "
            f"{_cpu_model()}, 2 vCPU shared with other jobs, one core: "
            f"NUMBA_NUM_THREADS=1, {pinned}).\n\n")
    section = head + body + "\n"
    text = path.read_text(encoding="utf-8") if path.exists() else "# Benchmarks\n\n"
    pattern = re.compile(r"## Simulator\n.*?(?=\n## |\Z)", re.S)
    text = pattern.sub(section.rstrip("\n") + "\n", text) if pattern.search(text) else (
        text.rstrip("\n") + "\n\n" + section)
    path.write_text(text, encoding="utf-8")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--holes", type=int, default=20, help="holes in the drilling program")
    ap.add_argument("--write", type=Path, help="update the 'Simulator' section of this file")
    args = ap.parse_args(argv)
    pinned = _pin_one_core()
    r = run(args.holes)
    body = table(r)
    print(body)
    if args.write:
        write_section(args.write, body, pinned)
        print(f"wrote {args.write}", file=sys.stderr)


if __name__ == "__main__":
    main()
