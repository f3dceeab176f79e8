"""Fleet jobs on Dask: the same job on the single-process path, 1 and 2 workers, in one run.

Measures, on one synthetic fleet (``cnctwin simulate fleet``), the ``fleet health`` job (the
heaviest: loop identification per axis, spindle air plateau and hole record per recording):

* wall time of the single-process batch path (``run_job(client=None)``) and of a fresh
  LocalCluster with 1 and with 2 worker processes (one thread each), cluster start excluded;
* HF samples (cycles x signals) and cycles per second per worker; parallel efficiency
  = (T1 / T2) / 2;
* peak resident memory of each worker (``ru_maxrss``) over its memory after the imports
  (before the job), next to the largest partition's size in memory: a worker holds one
  partition at a time;
* on paper from the measured cost per recorded cycle: CPU-hours and cores for 100 and 1000
  machines x 1 year of 500 Hz recording.

Results equal across the three paths (checked). Updates the "Fleet" section of BENCHMARKS.md.

    .venv/bin/python benchmarks/bench_fleet.py [--machines 8 --days 3 --cycles-per-day 2]
"""

# ruff: noqa: E402  (the thread limits must be set before numpy is imported)
from __future__ import annotations

import os

# one BLAS/OpenMP thread everywhere, as Dask gives its workers, so that "per worker" and the
# single-process path compare one core with one core (set before numpy is imported)
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import pandas as pd

from _common import REPO, cpu_model, pin_one_core, replace_section

CYCLES_PER_YEAR = 500 * 86_400 * 365  # 500 Hz, around the clock (upper bound)


def _rss_mb() -> float:
    import psutil

    return float(psutil.Process().memory_info().rss) / 2**20


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _warm(_: Any = None) -> float:
    """Import what a task needs (and compile numba kernels) so the job time is the work."""
    import cnctwin.fleet.jobs
    import cnctwin.servo.health
    import cnctwin.usecases.holes  # noqa: F401

    return _rss_mb()


def _partition_mb(store: str, part: Any) -> float:
    import cnctwin.store

    with cnctwin.store.open(store, read_only=True) as st:
        recs = [st.load(r) for r in part.recording_ids]
    return sum(float(r.hf.memory_usage(deep=True).sum()) for r in recs) / 2**20


def _run_cluster(n: int, parts: list[Any], store: str) -> tuple[float, pd.DataFrame, list[Any]]:
    from cnctwin.fleet import fleet_client, health_partition, run_job

    with fleet_client(n_workers=n) as client:
        client.wait_for_workers(n)
        base = client.run(_warm)
        # one throw-away partition per worker: numba kernels compiled, caches warm
        run_job(health_partition, parts[:n], client=client, store_url=store)
        t0 = time.perf_counter()
        table = run_job(health_partition, parts, client=client, store_url=store)
        dt = time.perf_counter() - t0
        peak = client.run(_peak_rss_mb)
        mem = [(w, base[w], peak[w]) for w in sorted(base)]
    return dt, table, mem


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--machines", type=int, default=8)
    ap.add_argument("--days", type=int, default=3)
    ap.add_argument("--cycles-per-day", type=int, default=2)
    ap.add_argument("--no-update", action="store_true", help="do not touch BENCHMARKS.md")
    args = ap.parse_args()

    from cnctwin.fleet import health_partition, partitions, run_job

    cnctwin = str(Path(sys.executable).parent / "cnctwin")
    with tempfile.TemporaryDirectory() as tmp:
        fleet, store = Path(tmp) / "fleet", str(Path(tmp) / "store")
        subprocess.run([cnctwin, "simulate", "fleet", "--machines", str(args.machines),
                        "--days", str(args.days), "--cycles-per-day", str(args.cycles_per_day),
                        "--seed", "3", "--out", str(fleet)], check=True,
                       stdout=subprocess.DEVNULL)
        subprocess.run([cnctwin, "fleet", "ingest", str(fleet), "--store", store], check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        parts = partitions(store)
        import cnctwin.store as cstore

        with cstore.open(store, read_only=True) as st:
            cat = st.recordings()
        n_cycles = int(cat["n_cycles"].sum())
        n_values = int(sum(c * len(json.loads(cols)) for c, cols in
                           zip(cat["n_cycles"], cat["columns"], strict=True)))
        part_mb = max(_partition_mb(store, p) for p in parts)

        t1, r1, mem1 = _run_cluster(1, parts, store)
        t2, r2, mem2 = _run_cluster(2, parts, store)
        pinned = pin_one_core()  # after the clusters: their workers must not inherit it
        _warm()
        run_job(health_partition, parts[:1], client=None, store_url=store)
        t0 = time.perf_counter()
        single = run_job(health_partition, parts, client=None, store_url=store)
        t_single = time.perf_counter() - t0

    key = ["machine", "day", "component", "parameter"]
    for r in (r1, r2):
        pd.testing.assert_frame_equal(r.sort_values(key, ignore_index=True),
                                      single.sort_values(key, ignore_index=True))
    eff = (t1 / t2) / 2
    cores = os.cpu_count() or 1
    s_per_cycle = t1 / n_cycles  # one worker
    rows = [
        ("single process (batch functions, no Dask)", t_single, 1),
        ("LocalCluster, 1 worker", t1, 1),
        ("LocalCluster, 2 workers", t2, 2),
    ]
    lines = [
        "## Fleet",
        "",
        f"`benchmarks/bench_fleet.py` ({pd.Timestamp.now(tz='UTC'):%Y-%m-%d}, {cpu_model()}, "
        f"{cores} vCPU, shared with other jobs). Job: `fleet health` over "
        f"{args.machines} machines x {args.days} days x {args.cycles_per_day} part cycles "
        f"= {len(parts)} partitions, {len(cat)} recordings, {n_cycles:,} cycles "
        f"({n_cycles / 500:.0f} s at 500 Hz), {n_values:,} HF values. Cluster start and one "
        "warm-up task per worker excluded; results identical on all three paths (checked). "
        f"One BLAS/OpenMP thread per process everywhere; the single-process path pinned to one "
        f"core ({pinned}).",
        "",
        "| path | wall s | cycles/s per worker | HF values/s per worker | parallel efficiency |",
        "|---|---|---|---|---|",
    ]
    for name, t, n in rows:
        e = f"{eff:.0%} of linear" if n == 2 else ("baseline" if "1 worker" in name else "")
        lines.append(f"| {name} | {t:.1f} | {n_cycles / t / n:,.0f} | "
                     f"{n_values / t / n:,.0f} | {e} |")
    lines += [
        "",
        f"Goal: >= 80 % of linear on this machine's {cores} cores: "
        f"**{'met' if eff >= 0.8 else 'not met'}** ({eff:.0%}).",
        "",
        "Peak memory per worker (resident set, `ru_maxrss`) against its memory after the "
        f"imports; largest partition in memory {part_mb:.0f} MB:",
        "",
        "| cluster | worker | after imports MB | peak MB | growth MB |",
        "|---|---|---|---|---|",
    ]
    for label, mem in (("1 worker", mem1), ("2 workers", mem2)):
        for w, b, p in mem:
            lines.append(f"| {label} | {w.rsplit(':', 1)[-1]} | {b:.0f} | {p:.0f} | "
                         f"{p - b:.0f} |")
    cpu_h_100 = 100 * CYCLES_PER_YEAR * s_per_cycle / 3600
    lines += [
        "",
        "On paper, from the measured cost per recorded cycle on one worker "
        f"({s_per_cycle * 1e6:.1f} us per cycle of all signals; the job's cost grows with the "
        "recorded time), for 500 Hz recorded around the clock (an upper bound: a machine that "
        "records two shifts needs 2/3 of it):",
        "",
        "| fleet | CPU-hours per year of data | cores to keep up in real time | "
        "hours on 2 cores | hours on 64 cores |",
        "|---|---|---|---|---|",
    ]
    for m in (100, 1000):
        cpu_h = m * CYCLES_PER_YEAR * s_per_cycle / 3600
        realtime = m * 500 * s_per_cycle
        lines.append(f"| {m} machines x 1 year | {cpu_h:,.0f} | {realtime:.1f} | "
                     f"{cpu_h / 2 / eff:,.0f} | {cpu_h / 64 / eff:,.0f} |")
    lines += ["", f"(100 machines: {cpu_h_100:,.0f} CPU-h; hours on N cores = CPU-h / N / "
              "measured efficiency.)"]
    text = "\n".join(lines)
    print(text)
    if not args.no_update:
        replace_section(REPO / "BENCHMARKS.md", "## Fleet", text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
