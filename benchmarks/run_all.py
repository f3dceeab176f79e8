"""Run every benchmark in this folder, one after the other (``make bench``).

Each ``bench_*.py`` measures one claim side by side with its baseline or physical limit in the
same run and updates its own section of BENCHMARKS.md. Run one alone for its options, e.g.
``.venv/bin/python benchmarks/bench_sim.py --holes 2676``.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).parent


def main() -> int:
    failed = []
    for script in sorted(HERE.glob("bench_*.py")):
        print(f"\n=== {script.name} ===", flush=True)
        if subprocess.call([sys.executable, str(script)], cwd=HERE.parent) != 0:
            failed.append(script.name)
    if failed:
        print(f"\nfailed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
