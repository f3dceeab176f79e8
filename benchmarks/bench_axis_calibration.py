"""Axis identification with the compiled setpoint chain beside the NumPy/SciPy chain.

``fit_setpoint_chain`` (the jerk filter, delays and PT1s between DES_POS and CTRL_POS)
evaluates its model some 7000 times per axis recording; each evaluation used to run
``apply_setpoint_chain`` run by run (NumPy and ``scipy.signal.lfilter`` calls on ~6 runs of
~500 cycles: call overhead). It now runs ``setpoint_chain_segments`` (numba), which repeats
the same operations. Baseline in the same run and process: ``identify_axis`` with the chain
put back to the per-run NumPy evaluation (exactly what the old ``model_of`` computed); the
two give the same estimates, checked here.

Run: ``.venv/bin/python benchmarks/bench_axis_calibration.py [--repeat 3]``; one core,
best of ``repeat``; writes its section of BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import io
import itertools
import platform
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

import cnctwin.servo.identify as ident_mod
from _common import REPO, best_wall_cpu, cpu_model, pin_one_core, replace_section
from cnctwin.cli import main as cli
from cnctwin.iotools import read_recording
from cnctwin.servo._common import setpoint_chain_segments
from cnctwin.servo.identify import _N_JERK, apply_setpoint_chain, identify_axis

TITLE = "## Axis identification: the compiled setpoint chain"


def numpy_chain(des: np.ndarray, starts: np.ndarray, jerk_type: str,
                params: np.ndarray) -> np.ndarray:
    """The chain run by run with the NumPy/SciPy filters (the code before the kernel)."""
    nj = _N_JERK[jerk_type]
    return np.concatenate([
        apply_setpoint_chain(des[a:b], jerk_type=jerk_type, jerk_cycles=tuple(params[:nj]),
                             delay_cycles=params[nj], pt1_cycles=params[nj + 1],
                             pt1b_cycles=params[nj + 2], delay2_cycles=params[nj + 3])
        for a, b in itertools.pairwise(starts)])


def identify_both(rec: Any) -> dict[str, tuple[float, float]]:
    out = {}
    for ax in ("X1", "Y1"):
        for k, e in identify_axis(rec, ax).params.items():
            out[f"{ax}.{k}"] = (e.value, e.stderr)
    return out


def with_chain(chain: Callable[..., np.ndarray], fn: Callable[[], Any]) -> Any:
    saved = ident_mod.setpoint_chain_segments
    ident_mod.setpoint_chain_segments = chain  # type: ignore[assignment]
    try:
        return fn()
    finally:
        ident_mod.setpoint_chain_segments = saved


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--out", type=Path, default=REPO / "BENCHMARKS.md")
    a = ap.parse_args()
    pinned = pin_one_core()
    with tempfile.TemporaryDirectory() as tmp, contextlib.redirect_stdout(io.StringIO()):
        assert cli(["simulate", "axis_test", "--out", tmp, "--seed", str(a.seed),
                    "--option", 'axes=["X1", "Y1"]']) == 0
        rec = read_recording(Path(tmp) / "axis_test.json")
    # one evaluation on runs like the fit's (6 runs of ~500 cycles)
    rng = np.random.default_rng(0)
    des = np.cumsum(rng.normal(size=3000))
    starts = np.array([0, 500, 1000, 1500, 2000, 2500, 3000], dtype=np.int64)
    p = np.array([7.3, 1.2, 2.0, 0.5, 0.3])
    setpoint_chain_segments(des, starts, "moving_average", p)  # compile or load the cache

    def many(chain: Callable[..., np.ndarray]) -> Callable[[], None]:
        return lambda: [chain(des, starts, "moving_average", p) for _ in range(1000)]

    _, c_kernel = best_wall_cpu(many(setpoint_chain_segments), a.repeat)
    _, c_numpy = best_wall_cpu(many(numpy_chain), a.repeat)
    new = identify_both(rec)  # warm
    old = with_chain(numpy_chain, lambda: identify_both(rec))
    same = new.keys() == old.keys() and all(  # NaN standard errors compare equal
        np.array_equal(new[k], old[k], equal_nan=True) for k in new)
    w_new, c_new = best_wall_cpu(lambda: identify_both(rec), a.repeat)
    w_old, c_old = best_wall_cpu(lambda: with_chain(numpy_chain, lambda: identify_both(rec)),
                                 a.repeat)
    n_cycles = rec.n_cycles
    lines = [
        TITLE, "",
        f"`benchmarks/bench_axis_calibration.py` ({datetime.date.today()}, {cpu_model()}, "
        f"{platform.python_implementation()} {platform.python_version()}, one core: "
        f"{pinned}; best of {a.repeat}). Recording: `cnctwin simulate axis_test --seed "
        f"{a.seed}` with X1 and Y1 ({n_cycles} cycles); `identify_axis` of both axes, every "
        "jerk-filter model tried (as `calibrate axes` runs it). Baseline in the same "
        "process: the same call with the setpoint chain evaluated run by run by the "
        "NumPy/SciPy filters (the code before the kernel). Estimates identical: "
        f"**{'yes' if same else 'NO'}**.", "",
        "| what | baseline (NumPy/SciPy chain) | compiled chain | ratio |",
        "|---|---|---|---|",
        f"| one chain evaluation, 6 runs x 500 cycles [us CPU] | {c_numpy * 1e3:.0f} | "
        f"{c_kernel * 1e3:.0f} | {c_numpy / c_kernel:.1f}x |",
        f"| `identify_axis` X1 + Y1 [s CPU] | {c_old:.2f} | {c_new:.2f} | "
        f"{c_old / c_new:.2f}x |",
        f"| `identify_axis` X1 + Y1 [s wall] | {w_old:.2f} | {w_new:.2f} | "
        f"{w_old / w_new:.2f}x |", "",
        "What remains of `identify_axis` is mostly scipy's trust-region iterations "
        "(`least_squares`, numerical Jacobians) of the setpoint fit and the other fits.",
    ]
    text = "\n".join(lines) + "\n"
    print(text)
    replace_section(a.out, TITLE, text)


if __name__ == "__main__":
    main()
