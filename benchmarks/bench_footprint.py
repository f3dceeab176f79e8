"""Footprint of `make demo` and of an edge process (issue 16, point 4).

Measures, in one run:

* the install size of a virtual environment with cnctwin and its run-time dependencies only
  (what `make demo` installs) beside the full development install (`make test`:
  ``.[all,dev]``), when the environments are given;
* the peak resident memory of ``cnctwin demo`` (the whole demo, the maximum RSS of the child
  process from ``getrusage``), with this checkout's code and, with ``--baseline REV``, with an
  older commit's package source on ``PYTHONPATH`` (same interpreter and dependencies);
* the resident memory of a process after ``import cnctwin.edge`` (what every edge worker
  pays before it processes anything) and which heavy libraries that import loads.

Run: ``.venv/bin/python benchmarks/bench_footprint.py [--demo-venv /tmp/vdemo]
[--baseline 196575f]``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import tempfile
import time
from pathlib import Path

from _common import REPO, cpu_model, export_rev


def _tree_mb(path: Path) -> float:
    total = 0
    for root, _dirs, files in os.walk(path):
        for f in files:
            with contextlib.suppress(OSError):
                total += os.lstat(os.path.join(root, f)).st_size
    return total / 2**20


def _site_packages(venv: Path) -> Path:
    return next((venv / "lib").glob("python3*/site-packages"))


def _demo_peak_mb(python: str, out: Path, pythonpath: str | None) -> tuple[float, float]:
    """(peak RSS [MB], wall [s]) of ``cnctwin demo`` run as a child process."""
    env = dict(os.environ)
    if pythonpath:
        env["PYTHONPATH"] = pythonpath
    code = ("import resource, subprocess, sys, time; t = time.perf_counter(); "
            "r = subprocess.run([sys.executable, '-m', 'cnctwin', 'demo', '--out', sys.argv[1]],"
            " capture_output=True); w = time.perf_counter() - t; "
            "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, w, r.returncode)")
    res = subprocess.run([python, "-c", code, str(out)], capture_output=True, text=True,
                         env=env, cwd=REPO, check=True)
    kb, wall, rc = res.stdout.split()
    if rc != "0":
        raise SystemExit(f"cnctwin demo failed (exit {rc})")
    return int(kb) / 1024, float(wall)


def _edge_import(python: str) -> dict[str, object]:
    code = ("import json, resource, sys; import cnctwin.edge, cnctwin.edge.runtime; "
            "print(json.dumps({'rss_mb': resource.getrusage(resource.RUSAGE_SELF).ru_maxrss "
            "/ 1024, 'loaded': sorted(m for m in ('matplotlib', 'distributed', 'fastapi', "
            "'sklearn', 'scipy', 'pandas', 'numba', 'pyarrow') if m in sys.modules)}))")
    out = subprocess.run([python, "-c", code], capture_output=True, text=True, check=True,
                         cwd=REPO).stdout
    return dict(json.loads(out))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--demo-venv", type=Path, help="a venv with `pip install -e .` only")
    ap.add_argument("--full-venv", type=Path, default=REPO / ".venv",
                    help="the development venv (default .venv)")
    ap.add_argument("--baseline", help="commit whose package source to compare with")
    args = ap.parse_args()
    print(f"machine: {cpu_model()}, {os.cpu_count()} CPUs; {time.strftime('%Y-%m-%d')}")
    if args.demo_venv is not None:
        print(f"install size, demo venv (pip install -e .): "
              f"{_tree_mb(_site_packages(args.demo_venv)):.0f} MB site-packages, "
              f"{_tree_mb(args.demo_venv):.0f} MB in all")
    print(f"install size, full venv (.[all,dev]): "
          f"{_tree_mb(_site_packages(args.full_venv)):.0f} MB site-packages, "
          f"{_tree_mb(args.full_venv):.0f} MB in all")
    python = str((args.demo_venv or args.full_venv) / "bin" / "python")
    with tempfile.TemporaryDirectory() as tmp:
        peak, wall = _demo_peak_mb(python, Path(tmp) / "now", None)
        print(f"cnctwin demo, this checkout: peak RSS {peak:.0f} MB, {wall:.1f} s wall")
        if args.baseline:
            (Path(tmp) / "base").mkdir()
            src = export_rev(args.baseline, Path(tmp) / "base")
            peak_b, wall_b = _demo_peak_mb(python, Path(tmp) / "base-out", str(src))
            print(f"cnctwin demo, {args.baseline}: peak RSS {peak_b:.0f} MB, {wall_b:.1f} s wall")
    edge = _edge_import(python)
    print(f"import cnctwin.edge: max RSS {edge['rss_mb']:.0f} MB; heavy libraries loaded: "
          f"{', '.join(edge['loaded']) or 'none'}")  # type: ignore[arg-type]


if __name__ == "__main__":
    main()
