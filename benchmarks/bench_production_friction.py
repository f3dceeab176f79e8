"""Friction from a production job's air moves: are its stated uncertainties honest?

``tests/servo/test_production_friction.py`` calibrates X1/Y1 friction from one milling job
(``milling_square_circle``, thesis §3.1.2, with a CAM program's air moves at 1500 and 4000
mm/min before the square): four constant-velocity runs per axis, three parameters (Coulomb,
viscous, weight offset), one residual degree of freedom. This script repeats it over many
draws, through the command line as a user types it: per draw a machine with hidden X1/Y1 loop
parameters and Coulomb friction (``random_loop_overrides``: Coulomb U(80, 220) N; viscous the
thesis machine's 0.2 N/(mm/s)) and its own noise; ``cnctwin calibrate axes`` on the file.

Per parameter: the mean error, its scatter, the **coverage** (share of draws whose hidden value
lies within value +- 1.96 u; goal 90-98 %) and within +- 3 u (what the test asserts), the
rms of z = error / u (1 for an honest u), the median, smallest and largest u.

Usage::

    .venv/bin/python benchmarks/bench_production_friction.py [--draws 24] [--jobs 2]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import math
import platform
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from _common import cpu_model
from cnctwin.cli import main
from cnctwin.machine import Machine, load_machine
from cnctwin.sim.scenarios import random_loop_overrides

AIR = ["--option", "air_moves_mm_min=[1500,4000]"]
KEYS = ["axes.X1.coulomb_n", "axes.Y1.coulomb_n", "axes.X1.viscous_n_per_mm_s",
        "axes.Y1.viscous_n_per_mm_s"]


def _cli(*args: object) -> None:
    with contextlib.redirect_stdout(io.StringIO()):
        code = main([str(a) for a in args])
    if code != 0:
        raise SystemExit(f"cnctwin {' '.join(map(str, args[:2]))} failed ({code})")


def _draw(args: tuple[int, str]) -> tuple[int, dict[str, tuple[float, float, float]]]:
    seed, tmp = args
    d = Path(tmp) / f"seed{seed}"
    hidden: dict[str, Any] = dict(random_loop_overrides(seed))
    sets = [x for k, v in hidden.items() for x in ("--set", f"{k}={v}")]
    _cli("simulate", "milling_square_circle", "--out", d, "--seed", seed, *sets, *AIR)
    m = d / "m.toml"
    _cli("calibrate", "axes", d / "milling_square_circle.json", "--machine", m)
    mf = load_machine(m)
    ref = Machine.thesis_default()
    out = {}
    for key in KEYS:
        ax, name = key.split(".")[1:]
        true = float(hidden.get(key, getattr(ref.axis(ax), name)))
        rec = mf.record(key)
        ok = rec is not None and rec.identified and rec.uncertainty is not None
        out[key] = (true, rec.value if ok and rec else math.nan,
                    float(rec.uncertainty) if ok and rec and rec.uncertainty else math.nan)
    return seed, out


def main_() -> int:
    from concurrent.futures import ProcessPoolExecutor

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=24)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=1)
    a = ap.parse_args()
    t0 = time.perf_counter()
    seeds = range(a.first_seed, a.first_seed + a.draws)
    with tempfile.TemporaryDirectory() as tmp, ProcessPoolExecutor(a.jobs) as ex:
        res = dict(ex.map(_draw, [(s, tmp) for s in seeds]))
    print(f"{a.draws} draws (seeds {seeds[0]}-{seeds[-1]}), {time.perf_counter() - t0:.0f} s; "
          f"{cpu_model()}, python {platform.python_version()}")
    print()
    print("| parameter | identified | mean error | scatter | coverage 1.96 u | within 3 u "
          "| rms z | median u | smallest u | largest u |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for key in KEYS:
        t, v, u = (np.array([res[s][key][k] for s in seeds]) for k in range(3))
        ok = np.isfinite(v) & np.isfinite(u)
        e, z = (v - t)[ok], ((v - t) / u)[ok]
        print(f"| {key} | {ok.sum()}/{len(seeds)} | {e.mean():+.3g} | {e.std(ddof=1):.3g} "
              f"| {np.mean(np.abs(z) <= 1.96):.0%} | {np.mean(np.abs(z) <= 3):.0%} "
              f"| {np.sqrt(np.mean(z**2)):.2f} | {np.median(u[ok]):.3g} | {u[ok].min():.3g} "
              f"| {u[ok].max():.3g} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main_())
