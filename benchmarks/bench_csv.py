"""Flat CSV reader (KIT layout) against the CSV parsers it is built on, on the same file.

Measures in one run, on a recording written by ``cnctwin.iotools.write_csv`` (the simulated
tool-wear run, thesis §5.1: 78 HF signals at 500 Hz, NC block and call events; ``--holes``
sets its length):

* floor: ``pyarrow.csv.read_csv`` of ``_hfdata.csv`` with default options (the C++ parser
  the reader is built on, in its best case: types inferred, no file lines, no checks);
* baseline: ``pandas.read_csv`` (C engine) of the same file, what a user would write by hand;
* ``read_flat_csv(stem)``: the whole reader: header, events, the HF table with the file line
  of every row, number checks per column, sorting and duplicate rules, the Recording.

All CPU and wall time, best of ``--repeat``. Run:
``.venv/bin/python benchmarks/bench_csv.py [--holes 12] [--repeat 3]``
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import tempfile
from pathlib import Path

from _common import best_wall_cpu, cpu_model


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--holes", type=int, default=12)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    import pandas as pd
    import pyarrow.csv as pacsv

    from cnctwin.iotools import read_flat_csv, write_csv
    from cnctwin.sim import scenarios as sc

    rec = sc.tool_wear_run(n_holes=args.holes, holes_per_set=6, dynamometer=False,
                           seed=0).recording
    tmp = Path(tempfile.mkdtemp(prefix="bench_csv_"))
    try:
        files = write_csv(rec, tmp / "T01")
        hf = files["hfdata"]
        mb = hf.stat().st_size / 1e6
        n = rec.n_cycles
        rows: list[tuple[str, float, float]] = []

        def floor() -> None:
            pacsv.read_csv(hf)

        def pandas_c() -> None:
            pd.read_csv(hf, engine="c")

        def reader() -> None:
            r = read_flat_csv(tmp / "T01")
            assert r.n_cycles == n, (r.n_cycles, n)

        for label, fn in (("floor: pyarrow.csv.read_csv of _hfdata.csv", floor),
                          ("baseline: pandas.read_csv (C engine) of _hfdata.csv", pandas_c),
                          ("read_flat_csv (header, events, checks, Recording)", reader)):
            rows.append((label, *best_wall_cpu(fn, args.repeat)))
        load = os.getloadavg() if hasattr(os, "getloadavg") else (float("nan"),) * 3
        print(f"machine: {cpu_model()}, {os.cpu_count()} vCPU; load average "
              f"{load[0]:.1f}/{load[1]:.1f}/{load[2]:.1f}; python {platform.python_version()}")
        with hf.open(encoding="utf-8") as fh:
            n_cols = len(fh.readline().split(","))
        print(f"input: _hfdata.csv of the simulated tool-wear run, {args.holes} holes, {n} rows "
              f"x {n_cols} columns, {mb:.1f} MB (+ header and event files); "
              f"best of {args.repeat}")
        print()
        print("| path | wall [s] | CPU [s] | MB/s (wall) | rows/s (wall) |")
        print("|---|---|---|---|---|")
        for label, w, c in rows:
            print(f"| {label} | {w:.3f} | {c:.3f} | {mb / w:,.0f} | {n / w:,.0f} |")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
