"""``cnctwin optimize`` on a 10 000-block program, and the engagement model against real time.

The program: a 300 x 300 mm block of AISI 1045, a 16 mm two-flute end mill at 2400 rpm
roughing three levels (2 mm each) in 30 mm-wide bands of slots and 8 mm side steps, every
pass cut into 3 mm blocks (CAM output of a contour-parallel path looks like this), conservative
F300, G64. Measured in one run, on one core (numba and BLAS threads pinned to 1):

* the planning (interpolation, Z-map engagement, feed limits, rewriting; what the 60 s budget
  of issue 25 is about), with the cycle times from the interpolator (``--no-verify``);
* the engagement model alone: seconds of machine time swept per second of wall time (real
  time = 1; the edge needs > 1 to follow a live machine);
* optionally (``--verify``) the two twin simulations of the verification.

Run: ``.venv/bin/python benchmarks/bench_optimize.py [--blocks 10000] [--verify]``
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import time

import numpy as np

from cnctwin.engagement import Stock, ZMap
from cnctwin.machine import MachineFile, ToolSpec, ToolTable
from cnctwin.optimizer import optimize_program
from cnctwin.sim.gcode import parse_program
from cnctwin.sim.materials import resolve_material

BUDGET_S = 60.0
"""Issue 25: a 10 000-block program optimized in under 60 s on one core."""


def program(blocks: int, *, seg_mm: float = 3.0) -> str:
    """A roughing program of about ``blocks`` G1 blocks of ``seg_mm``."""
    lines = ["; bench: roughing in 3 mm blocks", "G90 G17 G94 G64", "T2 M6", "S2400 M3"]
    n = 0
    level = 0
    while n < blocks:
        z = -2.0 * (level % 3 + 1)
        y0 = 10.0 + 30.0 * (level // 3 % 9)
        lines += [f"G0 X-12 Y{y0:g} Z5", f"G0 Z{z:g}"]
        for k, dy in enumerate((0.0, 8.0, 16.0, 24.0)):
            y = y0 + dy
            xs = np.arange(0.0, 300.0 + seg_mm, seg_mm)
            if k % 2:
                xs = xs[::-1]
            if k:
                lines.append(f"G1 Y{y:g} F300")
                n += 1
            for x in xs:
                lines.append(f"G1 X{x:g} F300")
                n += 1
                if n >= blocks:
                    break
            if n >= blocks:
                break
        lines.append("G0 Z5")
        level += 1
    lines += ["G0 Z50", "M30"]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--blocks", type=int, default=10_000)
    ap.add_argument("--verify", action="store_true", help="also the two twin simulations")
    args = ap.parse_args()
    text = program(args.blocks)
    prog = parse_program(text, name="bench")
    n_g1 = sum(b.kind == "linear" for b in prog.blocks)
    tools = ToolTable({2: ToolSpec(2, "end_mill", 16.0, flutes=2, helix_deg=30.0,
                                   max_chip_mm=0.15)}, source="bench")
    stock = Stock(0.0, 0.0, -30.0, 310.0, 300.0, 0.0)
    mat = resolve_material("aisi1045")
    mfile = MachineFile()
    # warm the numba kernels (compiled once per installation; not part of the budget)
    ZMap(Stock(0, 0, -1, 10, 10, 0)).sweep(np.zeros(3), np.zeros(3), np.full(3, -0.5),
                                           diameter_mm=4.0)
    t0 = time.perf_counter()
    res = optimize_program(prog, mfile, mat, tools, stock, verify=False, name="bench")
    plan_s = time.perf_counter() - t0
    tr = res.trace
    assert tr is not None
    eng_speed = 1.0 / (tr.seconds_per_cycle_of_work / tr.cycle_time_s)
    # the Z-map sweep alone, on the interpolated path
    zm = ZMap(stock)
    t1 = time.perf_counter()
    zm.sweep(tr.x_mm, tr.y_mm, tr.z_mm, diameter_mm=16.0)
    sweep_s = time.perf_counter() - t1
    ct = res.cycle_time_s
    print(f"program: {len(prog.blocks)} blocks ({n_g1} G1), {tr.duration_s:.0f} s of machine "
          f"time ({len(tr)} cycles)")
    print("| step | wall time | against |")
    print("|---|---|---|")
    print(f"| optimize (plan, no verification), one core | {plan_s:.1f} s | budget "
          f"{BUDGET_S:.0f} s ({'within' if plan_s < BUDGET_S else 'OVER'}) |")
    print(f"| engagement pass (interpolator + Z-map) | {tr.seconds_per_cycle_of_work * len(tr):.1f}"
          f" s | {eng_speed:.0f} x real time |")
    print(f"| Z-map sweep alone | {sweep_s:.2f} s | {tr.duration_s / sweep_s:.0f} x real time "
          f"({1e6 * sweep_s / len(tr):.2f} us per 2 ms cycle) |")
    print(f"cycle time {ct['programmed']:.0f} s -> {ct['optimized']:.0f} s "
          f"({100 * (1 - ct['optimized'] / ct['programmed']):.1f} % shorter), "
          f"{len(res.lines)} lines planned")
    if args.verify:
        t2 = time.perf_counter()
        res_v = optimize_program(prog, mfile, mat, tools, stock, verify=True, name="bench")
        print(f"| optimize with both twin simulations | {time.perf_counter() - t2:.1f} s | "
              f"{len(res_v.violations)} violations |")


if __name__ == "__main__":
    main()
