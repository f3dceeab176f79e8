"""Dashboard plot data: min/max decimation of a 10 M-sample signal to 2000 px, side by side
with the naive ways of getting it to a browser, in one run.

Measured on the same float64 signal (10 M samples = 5.6 h at 500 Hz, a random walk with
isolated one-sample spikes):

* **envelope** ``cnctwin.web.decimate.envelope_decimate(x, y, px=2000)``: the min and max
  sample of each of 2000 buckets (what the dashboard sends);
* **endpoint work** ``cnctwin.web.app.plot_payload`` (range cut, gap split, envelope) plus the
  ``orjson`` serialisation of its JSON: what one plot request costs the server, HTTP aside;
* baseline **full JSON**: ``orjson.dumps`` of all 10 M (x, y) pairs, what a page without
  server-side decimation must download (and the browser then parse and draw);
* baseline **pandas resample**: ``Series.resample(span/2000).agg(["min", "max"])`` on a
  DatetimeIndex, the usual one-liner (it gives each bucket's extremes but not where they are,
  so the drawn peaks move by up to a bucket).

Each is checked to keep the global min and max (the spikes). Best of 5 (full JSON: best of 2).

Run: ``.venv/bin/python benchmarks/bench_web.py [--samples N] [--px 2000]``
"""

from __future__ import annotations

import argparse
import platform
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import orjson
import pandas as pd

from _common import cpu_model
from cnctwin.web.app import plot_payload
from cnctwin.web.decimate import envelope_decimate


def _best(fn: Callable[[], Any], repeat: int) -> tuple[float, Any]:
    best, out = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    ap.add_argument("--samples", type=int, default=10_000_000)
    ap.add_argument("--px", type=int, default=2000)
    args = ap.parse_args()
    n, px = args.samples, args.px
    rng = np.random.default_rng(0)
    y = np.cumsum(rng.standard_normal(n)) * 0.01
    spikes = rng.integers(0, n, 50)
    y[spikes] += rng.choice([-40.0, 40.0], spikes.size)
    cycles = np.arange(n, dtype=np.int64) + 5_000_000
    x = (cycles - cycles[0]) * 0.002
    lo, hi = float(y.min()), float(y.max())

    t_env, env = _best(lambda: envelope_decimate(x, y, px=px), 5)
    assert env.y.min() == lo and env.y.max() == hi

    def endpoint() -> bytes:
        p = plot_payload(x, cycles, y, px=px, start_s=None, end_s=None)
        return orjson.dumps(p, option=orjson.OPT_SERIALIZE_NUMPY)

    t_end, body = _best(endpoint, 5)

    t_full, full = _best(lambda: orjson.dumps({"x": x, "y": y},
                                              option=orjson.OPT_SERIALIZE_NUMPY), 2)
    s = pd.Series(y, index=pd.to_datetime(x, unit="s"))
    rule = pd.Timedelta(seconds=(x[-1] - x[0]) / px)
    t_pd, agg = _best(lambda: s.resample(rule).agg(["min", "max"]), 5)
    assert float(agg["min"].min()) == lo and float(agg["max"].max()) == hi
    del full

    rows = [
        ("**envelope** `envelope_decimate` (min/max of 2000 buckets, positions kept)", t_env,
         f"{env.n_points} points"),
        ("**endpoint** `plot_payload` + orjson (what one plot request costs)", t_end,
         f"{len(body) / 1e3:.0f} kB JSON"),
        ("baseline: full-resolution JSON (`orjson.dumps` of 10 M x, y)", t_full,
         f"{(x.nbytes + y.nbytes) / 1e6:.0f} MB arrays -> JSON"),
        ("baseline: pandas `resample(span/2000).agg(['min','max'])`", t_pd,
         f"{2 * len(agg)} values, no positions"),
    ]
    print(f"machine: {cpu_model()}, {platform.python_version()}, numpy {np.__version__}, "
          f"pandas {pd.__version__}; {n / 1e6:g} M samples -> {px} px")
    print("| path | time | samples/s | vs envelope | output |")
    print("|---|---|---|---|---|")
    for name, t, out in rows:
        print(f"| {name} | {t * 1e3:.1f} ms | {n / t / 1e6:.0f} M | {t / t_env:.1f}x | {out} |")
    full_bytes = len(orjson.dumps({"x": x[:1_000_000], "y": y[:1_000_000]},
                                  option=orjson.OPT_SERIALIZE_NUMPY)) * n / 1_000_000
    print(f"full-resolution JSON would be ~{full_bytes / 1e6:.0f} MB to download; the envelope "
          f"{len(body) / 1e3:.0f} kB ({full_bytes / len(body):.0f}x smaller)")


if __name__ == "__main__":
    main()
