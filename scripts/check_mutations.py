"""Re-apply issue 29's 20 reviewed mutations one at a time and check that the tests kill each.

A review of the round-2 code (issue 29, point 6) found 20 single mutations that no test
noticed; ``tests/test_mutation_killers.py`` (and one assertion of ``tests/edge/test_opcua.py``)
now carry an independent truth for each. This script keeps that claim checkable on today's
code: it exports ``HEAD`` into a temporary directory (``git archive``), applies each mutation
there alone (an exact text replacement that must match once, so a mutation whose code has
moved is reported, not silently skipped), runs the covering tests with ``PYTHONPATH``
pointing at the copy, and reports KILLED (the tests fail) or ALIVE (they pass). The working
tree is never touched. Exit status 1 if any mutation survives or no longer applies.

Usage::

    .venv/bin/python scripts/check_mutations.py [--only NAME_PART]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
KILLERS = "tests/test_mutation_killers.py"


@dataclass(frozen=True)
class Mutation:
    """One mutation: ``old`` replaced by ``new`` in ``path``; ``tests`` should then fail."""

    name: str
    path: str
    old: str
    new: str
    tests: tuple[str, ...] = (KILLERS,)


MUTATIONS = [
    Mutation("calibration: B and tau_f without Kt's relative uncertainty",
             "src/cnctwin/calibration/spindle.py",
             'ref = abs(value) * rel_kt if name != "kt_nm_per_a" else u_kt_ref',
             'ref = 0.0 if name != "kt_nm_per_a" else u_kt_ref'),
    Mutation("calibration: _pool as a plain mean", "src/cnctwin/calibration/axes.py",
             "mean = float(np.sum(w * v) / np.sum(w))", "mean = float(np.mean(v))"),
    Mutation("machine file: written in place, no temporary file",
             "src/cnctwin/machine/file.py",
             "fd, tmp = tempfile.mkstemp(prefix=f\".{p.name}.\", dir=p.parent)",
             "fd = os.open(p, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644); tmp = str(p)"),
    Mutation("machine file: no fsync", "src/cnctwin/machine/file.py",
             "            os.fsync(fh.fileno())\n        os.replace(tmp, p)",
             "            pass\n        os.replace(tmp, p)"),
    Mutation("calibration: PT2 pair tolerance 0.15 -> 0.05", "src/cnctwin/calibration/axes.py",
             "abs(a.value - b.value) <= 0.15 * max(", "abs(a.value - b.value) <= 0.05 * max("),
    Mutation("speed law: kt_extrapolated at 0.2 of the range", "src/cnctwin/spindle.py",
             "tol = 0.02 * hi", "tol = 0.2 * hi"),
    Mutation("speed law: base-speed uncertainty without Kt", "src/cnctwin/calibration/spindle.py",
             'u_i = np.hypot(speeds["kt_se"].to_numpy(dtype=np.float64), k * rel_kt)',
             'u_i = speeds["kt_se"].to_numpy(dtype=np.float64)'),
    Mutation("twin compare: current-to-force without Kt", "src/cnctwin/compare.py",
             "1.0 / per_force if unit == \"Nm\" else ax.kt_nm_per_a / per_force)",
             "1.0 / per_force if unit == \"Nm\" else 1.0 / per_force)"),
    Mutation("twin compare: the spindle's air current never flagged", "src/cnctwin/compare.py",
             "    if abs(mean_pct) > 100.0 * rel_limit:\n        reasons.append(f\"air current",
             "    if False:\n        reasons.append(f\"air current"),
    Mutation("twin compare: the Stribeck term left out", "src/cnctwin/compare.py",
             "+ s.stribeck_torque_nm * np.exp(-n / s.stribeck_speed_rpm))",
             "+ 0.0 * np.exp(-n / s.stribeck_speed_rpm))"),
    Mutation("fleet drift: friction threshold 0.25 -> 0.35", "src/cnctwin/fleet/drift.py",
             'DriftRule("friction_rise", "coulomb_a", 0.25),',
             'DriftRule("friction_rise", "coulomb_a", 0.35),'),
    Mutation("fleet drift: z without the reference's uncertainty", "src/cnctwin/fleet/drift.py",
             "sigma = math.hypot(u if math.isfinite(u) else 0.0, ref_u if math.isfinite(ref_u)",
             "sigma = math.hypot(u if math.isfinite(u) else 0.0, 0.0 if math.isfinite(ref_u)"),
    Mutation("fleet ingest: directory hash without file names", "src/cnctwin/fleet/ingest.py",
             'h.update(str(f.relative_to(p)).encode() + b"\\0")', "pass"),
    Mutation("MTConnect: from = first - 1 after a wrap accepted", "src/cnctwin/edge/mtconnect.py",
             "if s < first or s > self._next:", "if s < first - 1 or s > self._next:"),
    Mutation("MTConnect: a page one observation short", "src/cnctwin/edge/mtconnect.py",
             "while j < stop and len(out) < count:", "while j < stop and len(out) < count - 1:"),
    Mutation("OPC 40501: the first NC call as ActiveProgram", "src/cnctwin/edge/opcua.py",
             "name = names[-1]", "name = names[0]"),
    Mutation("OPC 40501: Messages created as an AlertType (BaseObjectType)",
             "src/cnctwin/edge/opcua_machinetool.py",
             "objecttype=ua.NodeId(38, mt),", "objecttype=ua.NodeId(58, 0),",
             ("tests/edge/test_opcua.py::test_opcua_matches_batch",)),
    Mutation("dashboard: token minimum length 16 -> 8", "src/cnctwin/web/auth.py",
             "if len(token) < 16:", "if len(token) < 8:"),
    Mutation("MTConnect agent: /sample without its token", "src/cnctwin/edge/mtconnect_server.py",
             "        if self.token is not None:\n            given =",
             "        if self.token is not None and not path.lstrip('/').startswith('sample'):"
             "\n            given ="),
    Mutation("dashboard: any session cookie accepted", "src/cnctwin/web/auth.py",
             "        exp = self._ids.get(sid)\n        if exp is None:\n            return False",
             "        exp = self._ids.get(sid)\n        if exp is None:\n            return True"),
    Mutation("edge: the checkpoint written in place", "src/cnctwin/edge/runtime.py",
             '    tmp = p.with_suffix(".tmp")\n    with tmp.open("wb") as fh:',
             '    tmp = p\n    with tmp.open("wb") as fh:'),
]


def _export(dest: Path) -> None:
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", "HEAD"], check=True,
                             capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", help="run the mutations whose name contains this text")
    a = ap.parse_args(argv)
    todo = [m for m in MUTATIONS if a.only is None or a.only in m.name]
    python = ROOT / ".venv" / "bin" / "python"
    if not python.exists():
        print(f"{python} not found: run `make .venv/.installed` first", file=sys.stderr)
        return 2
    bad = 0
    with tempfile.TemporaryDirectory(prefix="cnctwin-mutations-") as tmp:
        base = Path(tmp)
        _export(base)
        env = {**os.environ, "PYTHONPATH": str(base / "src") + os.pathsep + str(base)}
        check = subprocess.run([str(python), "-c", "import cnctwin; print(cnctwin.__file__)"],
                               cwd=base, env=env, capture_output=True, text=True, check=True)
        if not check.stdout.strip().startswith(str(base)):
            print(f"the copy's cnctwin is not the one imported ({check.stdout.strip()})",
                  file=sys.stderr)
            return 2
        for k, m in enumerate(todo, 1):
            f = base / m.path
            text = f.read_text(encoding="utf-8")
            if text.count(m.old) != 1:
                print(f"[{k:2d}/{len(todo)}] NO LONGER APPLIES ({text.count(m.old)} matches in "
                      f"{m.path}): {m.name}")
                bad += 1
                continue
            f.write_text(text.replace(m.old, m.new), encoding="utf-8")
            t0 = time.monotonic()
            r = subprocess.run([str(python), "-m", "pytest", "-q", "-x", "-rf", "-p",
                                "no:cacheprovider", *m.tests], cwd=base, env=env,
                               capture_output=True, text=True)
            # which test failed, and on what (a mutation that breaks the import is no kill)
            failed = [ln for ln in r.stdout.splitlines() if ln.startswith("FAILED ")]
            f.write_text(text, encoding="utf-8")
            verdict = "KILLED" if r.returncode == 1 else (
                "ALIVE" if r.returncode == 0 else f"ERROR (pytest exit {r.returncode})")
            if verdict != "KILLED":
                bad += 1
                print(r.stdout[-2000:], file=sys.stderr)
            print(f"[{k:2d}/{len(todo)}] {verdict:6s} {time.monotonic() - t0:5.1f} s  {m.name}",
                  flush=True)
            for ln in failed:
                print(f"          {ln[:150]}")
    print(f"{len(todo) - bad} of {len(todo)} mutations killed")
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())
