"""Benchmark: interpolation of the thesis wear run (2676 holes, sets of 6) at 2 ms.

Measures, in one run: parsing, planning + compiled sampling (streamed in 1 M-cycle chunks),
and as baseline the same sampling kernel interpreted by Python (``py_func``) on a slice,
extrapolated per cycle. Prints a Markdown table row set for BENCHMARKS.md.

Run: ``.venv/bin/python benchmarks/bench_interpolator.py``
"""

from __future__ import annotations

import platform
import resource
import time

import numpy as np

from cnctwin.sim import interpolator as ip
from cnctwin.sim.gcode import parse_program
from cnctwin.sim.interpolator import AxisLimits, SpindleLimits, interpolate_chunks
from cnctwin.sim.programs import hole_pattern

LIMITS = {
    "X1": AxisLimits(30000.0, 3000.0, 50000.0),
    "Y1": AxisLimits(30000.0, 2500.0, 40000.0),
    "Z1": AxisLimits(20000.0, 2000.0, 30000.0),
    "C1": AxisLimits(7200.0, 1000.0, 20000.0),
    "B1": AxisLimits(7200.0, 1000.0, 20000.0),
}
SPINDLE = SpindleLimits(max_speed_rpm=20000.0, accel_rpm_s=4000.0)


def main() -> None:
    # warm-up (numba cache load / compile)
    list(interpolate_chunks(parse_program(hole_pattern(6)), limits=LIMITS, spindle=SPINDLE))
    text = hole_pattern(2676)
    t0 = time.perf_counter()
    prog = parse_program(text)
    t1 = time.perf_counter()
    n = 0
    duration = 0.0
    for tr in interpolate_chunks(prog, limits=LIMITS, spindle=SPINDLE, chunk_cycles=1_000_000):
        n += tr.n_cycles
        duration = tr.duration_s
    t2 = time.perf_counter()
    # baseline: the sampling kernel interpreted by Python on the first 100 000 cycles
    orig = ip._sample_kernel
    ip._sample_kernel = orig.py_func  # type: ignore[attr-defined]
    try:
        m = 100_000
        t3 = time.perf_counter()
        gen = interpolate_chunks(prog, limits=LIMITS, spindle=SPINDLE, chunk_cycles=m)
        t4 = time.perf_counter()
        next(gen)
        t5 = time.perf_counter()
    finally:
        ip._sample_kernel = orig
    del t4
    # planning time alone (generator creation does nothing until next(): measure via a tiny
    # chunk with the compiled kernel)
    t6 = time.perf_counter()
    next(interpolate_chunks(prog, limits=LIMITS, spindle=SPINDLE, chunk_cycles=1))
    t7 = time.perf_counter()
    plan_s = t7 - t6
    py_per_cycle = (t5 - t3 - plan_s) / m if (t5 - t3) > plan_s else float("nan")
    rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"machine: {platform.processor() or platform.machine()}")
    print(f"program: 2676 holes, {len(prog.blocks)} blocks, {n} cycles = {duration / 3600:.3f} h")
    print("| step | wall | machine-s per wall-s |")
    print("|---|---|---|")
    print(f"| parse_program | {t1 - t0:.2f} s | |")
    print(f"| interpolate_chunks (plan + numba sampling, 1 M-cycle chunks) | {t2 - t1:.2f} s | "
          f"{duration / (t2 - t1):.0f}x |")  # fmt: skip
    print(f"|   of which planning (segments, profiles, events, holes) | {plan_s:.2f} s | |")
    base_s = py_per_cycle * n + plan_s
    print(f"| baseline: kernel interpreted (py_func), extrapolated to {n} cycles | "
          f"{base_s:.0f} s | {duration / base_s:.0f}x |")  # fmt: skip
    print(f"peak RSS {rss_mb:.0f} MB")
    assert np.isfinite(duration)


if __name__ == "__main__":
    main()
