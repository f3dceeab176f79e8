"""Start-up of the command line: ``cnctwin --help`` and a bad-input exit, beside the imports
every subcommand used to pull in to register its options (issue 24, point 8: 3.5 s).

Each is a fresh ``python`` process (the import cache is cold in the sense that matters: no
module is loaded yet; the OS file cache is warm after the first repetition). Baseline, in the
same run: a process that imports what ``cnctwin --help`` imported before the change
(``cnctwin.iotools`` with pandas and scipy, the simulator's scenarios with numba, the edge
runtime) and builds the parser.

Run: ``.venv/bin/python benchmarks/bench_cli_startup.py --repeat 7``; prints the median and
the minimum wall time of each [s].
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time

CASES = {
    "cnctwin --help": [sys.executable, "-m", "cnctwin", "--help"],
    "cnctwin info missing.json (exit 2)": [sys.executable, "-m", "cnctwin", "info",
                                            "/nonexistent/missing.json"],
    "baseline: the old eager imports + parser": [
        sys.executable, "-c",
        "import cnctwin.iotools, cnctwin.sim.scenarios, cnctwin.edge, cnctwin.cli as c; "
        "c.build_parser()"],
}


def wall_s(cmd: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=False)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=7)
    a = ap.parse_args()
    print(f"{'case':<44} {'median s':>9} {'min s':>7}")
    for name, cmd in CASES.items():
        wall_s(cmd)  # warm the OS file cache
        t = [wall_s(cmd) for _ in range(a.repeat)]
        print(f"{name:<44} {statistics.median(t):9.3f} {min(t):7.3f}")


if __name__ == "__main__":
    main()
