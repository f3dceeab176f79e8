"""Cutting-torque estimator throughput, side by side with its memory-bandwidth floor.

Measures in one run, on the same float64 arrays (spindle current and speed at 500 Hz):

* floor: a plain numpy pass ``kt*i - b*n - tf*sign(n) - j*np.gradient(n*c, dt)`` (the
  arithmetic of the model with no checks, what memory bandwidth allows);
* ``SpindleModel.cutting_torque`` (vectorized, one call on the whole array);
* ``StreamingTorqueEstimator.update`` over 50-cycle chunks (100 ms of one machine at 2 ms,
  a realistic edge chunking) and over 1-cycle chunks (worst case, one call per 2 ms cycle).

Goal (issue #4): vectorized >= 50 % of the floor; streaming >= 250 k samples/s on one core
(500 machines x 500 Hz).

Run: ``.venv/bin/python benchmarks/bench_estimator.py``
"""

from __future__ import annotations

import platform
import time
from collections.abc import Callable

import numpy as np

from cnctwin.spindle import RPM_TO_RAD_S, SpindleModel, StreamingTorqueEstimator

FS = 500.0
N = 2_000_000


def _best(fn: Callable[[], object], repeat: int = 5) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main() -> None:
    rng = np.random.default_rng(0)
    n = 2400 + np.cumsum(rng.normal(0, 2, N))
    i = rng.normal(4.0, 0.3, N)
    model = SpindleModel(1.04, 8.42e-5, 0.35, j_kgm2=0.01)
    kt, b, tf, j = model.kt_nm_per_a, model.b_nm_per_rpm, model.tau_f_nm, model.j_kgm2

    def floor() -> np.ndarray:
        return kt * i - b * n - tf * np.sign(n) - j * np.gradient(n * RPM_TO_RAD_S, 1 / FS)

    def floor_linear() -> np.ndarray:
        return kt * i - b * n

    def vectorized() -> np.ndarray:
        return model.cutting_torque(i, n, fs_hz=FS)

    def streaming(chunk: int, n_samples: int) -> Callable[[], None]:
        def run() -> None:
            est = StreamingTorqueEstimator(model, fs_hz=FS)
            for k in range(0, n_samples, chunk):
                est.update(i[k : k + chunk], n[k : k + chunk])
            est.flush()
        return run

    # correctness in the same run: all paths agree
    ref = vectorized()
    np.testing.assert_allclose(floor(), ref, rtol=1e-12, atol=1e-12)
    est = StreamingTorqueEstimator(model, fs_hz=FS)
    out = np.concatenate([*(est.update(i[k:k + 50], n[k:k + 50]) for k in range(0, 200_000, 50)),
                          est.flush()])
    np.testing.assert_array_equal(out, model.cutting_torque(i[:200_000], n[:200_000]))

    rows: list[tuple[str, float]] = []
    t = _best(floor_linear)
    rows.append(("floor: numpy `kt*i - b*n` (2 reads, 1 write)", N / t))
    t_floor = _best(floor)
    rows.append(("floor: numpy full model incl. np.gradient", N / t_floor))
    t_vec = _best(vectorized)
    rows.append(("SpindleModel.cutting_torque (vectorized)", N / t_vec))
    n_stream = 500_000
    t = _best(streaming(50, n_stream), repeat=3)
    rows.append(("StreamingTorqueEstimator, 50-cycle chunks", n_stream / t))
    n_one = 50_000
    t = _best(streaming(1, n_one), repeat=3)
    rows.append(("StreamingTorqueEstimator, 1-cycle chunks", n_one / t))

    print(f"# {platform.processor() or platform.machine()}, numpy {np.__version__}, N = {N}")
    print("| path | samples/s | vs full-model floor |")
    print("|---|---|---|")
    for name, rate in rows:
        print(f"| {name} | {rate / 1e6:.2f} M | {rate * t_floor / N * 100:.0f} % |")
    print(f"\nvectorized / floor = {t_floor / t_vec * 100:.0f} % (goal >= 50 %)")
    print(f"50-cycle streaming = {rows[3][1] / 250e3:.1f}x the 250 k samples/s goal")


if __name__ == "__main__":
    main()
