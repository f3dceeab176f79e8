"""The tool-wear scenario as a user runs it, on one core: ``cnctwin simulate tool_wear_run``.

Where ``bench_sim.py`` measures ``simulate()`` (the machine with its recording), this measures
the whole scenario command with everything it writes: the 500 Hz recording (Parquet chunk
directory), the 1 kHz dynamometer CSV sessions (own clock), the per-cycle truth Parquet, the
thermal camera CSV, ``holes.csv`` and ``truth.json``. Side by side in one sitting:

* the physical baseline (the machining time itself, 1x) and the issue's goal (the 2676-hole wear
  run, ~3.5 h of machining, in under 15 s);
* the command now, in a child process pinned to one core (``sched_setaffinity``), CPU = user +
  system time of the child (``getrusage``), wall, peak RSS and bytes written per output kind;
* optionally the same command from an older commit (``--before-rev``: its ``src`` exported with
  ``git archive``), alternating with the new runs so that load changes hit both alike;
* with ``--parts``: CPU per component of the new run (servo, spindle, interpolator, cutting
  model, dynamometer DAQ, per-cycle truth, recording writer), measured by wrapping the
  functions in one extra run.

Usage::

    .venv/bin/python benchmarks/bench_scenario.py --holes 2676 --repeat 3 \
        --before-rev bc9582e --parts --write BENCHMARKS.md
    .venv/bin/python benchmarks/bench_scenario.py --holes 300   # quick A/B while developing
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as dt
import io
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from _common import cpu_model, export_rev, pin_one_core, replace_section

GOAL_S = 15.0
FULL_HOLES = 2676


def _disk(out: Path) -> dict[str, float]:
    kinds = {"recording": 0, "dynamometer CSV": 0, "truth per cycle": 0, "other": 0}
    for f in out.rglob("*"):
        if not f.is_file():
            continue
        size = f.stat().st_size
        if f.parent != out:
            kinds["recording"] += size
        elif f.name.startswith("dynamometer"):
            kinds["dynamometer CSV"] += size
        elif f.name == "truth_per_cycle.parquet":
            kinds["truth per cycle"] += size
        else:
            kinds["other"] += size
    return {k: v / 1e6 for k, v in kinds.items()}


def _run_cli(out: Path, holes: int) -> None:
    from cnctwin.cli import main as cli_main

    with contextlib.redirect_stdout(io.StringIO()):
        rc = cli_main(["simulate", "tool_wear_run", "--out", str(out), "--seed", "1",
                       "--format", "parquet", "--option", f"n_holes={holes}"])
    if rc:
        raise SystemExit(f"cnctwin simulate exited with {rc}")


def _wrapped_parts() -> tuple[dict[str, float], Callable[[], None]]:
    """Wrap the scenario's components with CPU timers (the current source tree only)."""
    import cnctwin.sim.scenarios as sc
    import cnctwin.sim.simulation as sim_mod
    from cnctwin.sim.recorder import ParquetChunkSink

    cpu: dict[str, float] = {}
    saved: list[tuple[Any, str, Any]] = []

    def wrap(owner: Any, attr: str, name: str) -> None:
        fn = getattr(owner, attr)
        saved.append((owner, attr, fn))

        def timed(*args: Any, **kwargs: Any) -> Any:
            t0 = time.process_time()
            try:
                return fn(*args, **kwargs)
            finally:
                cpu[name] = cpu.get(name, 0.0) + time.process_time() - t0
        setattr(owner, attr, timed)

    wrap(sim_mod, "simulate_servo", "servo (5 axes, 125 us loops)")
    wrap(sim_mod, "simulate_spindle", "spindle (125 us loops)")
    wrap(sc._DynamometerDAQ, "feed", "dynamometer DAQ (1 kHz CSV)")
    wrap(sc._TruthParquet, "write", "truth per cycle (Parquet)")
    wrap(sc, "drilling_load", "cutting model (drilling_load)")
    wrap(ParquetChunkSink, "write", "recording writer (HF chunks)")

    def restore() -> None:
        for owner, attr, fn in reversed(saved):
            setattr(owner, attr, fn)
    return cpu, restore


def _child_main(holes: int, parts: bool) -> None:
    pinned = pin_one_core()
    with tempfile.TemporaryDirectory() as tmp:
        _run_cli(Path(tmp) / "warm", 6)  # numba caches, imports
        cpu_parts: dict[str, float] = {}
        restore: Callable[[], None] = lambda: None  # noqa: E731
        if parts:
            cpu_parts, restore = _wrapped_parts()
        r0 = resource.getrusage(resource.RUSAGE_SELF)
        w0 = time.perf_counter()
        out = Path(tmp) / "run"
        _run_cli(out, holes)
        wall = time.perf_counter() - w0
        r1 = resource.getrusage(resource.RUSAGE_SELF)
        restore()
        truth = json.loads((out / "truth.json").read_text(encoding="utf-8"))
        disk = _disk(out)
    print(json.dumps({
        "user": r1.ru_utime - r0.ru_utime, "sys": r1.ru_stime - r0.ru_stime, "wall": wall,
        "machine_s": truth["n_cycles"] * 0.002, "cycles": truth["n_cycles"], "disk_mb": disk,
        "peak_rss_mb": r1.ru_maxrss / 1024.0, "parts": cpu_parts, "pinned": pinned}))


def _child(src: Path, holes: int, *, parts: bool = False) -> dict[str, Any]:
    env = dict(os.environ, PYTHONPATH=str(src), NUMBA_NUM_THREADS="1")
    cmd = [sys.executable, __file__, "--child", "--holes", str(holes)] + (
        ["--parts"] if parts else [])
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True).stdout
    return dict(json.loads(out.strip().splitlines()[-1]))


def _median(runs: list[dict[str, Any]]) -> dict[str, Any]:
    ordered = sorted(runs, key=lambda d: d["user"] + d["sys"])
    med = dict(ordered[len(ordered) // 2])
    med["all"] = [(d["user"] + d["sys"], d["wall"]) for d in runs]
    return med


def run(holes: int, repeat: int, before_rev: str | None, parts: bool) -> dict[str, Any]:
    src_now = Path(__file__).resolve().parents[1] / "src"
    new, before = [], []
    with tempfile.TemporaryDirectory() as tmp:
        src_before = export_rev(before_rev, Path(tmp)) if before_rev else None
        if src_before is not None:
            _child(src_before, 1)  # fill its numba cache
        for _ in range(repeat):
            new.append(_child(src_now, holes))
            if src_before is not None:
                before.append(_child(src_before, holes))
    res: dict[str, Any] = {"holes": holes, "repeat": repeat, "new": _median(new),
                           "before": _median(before) if before else None,
                           "before_rev": before_rev, "loadavg": os.getloadavg()}
    if parts:
        res["parts"] = _child(src_now, holes, parts=True)
    res["command"] = _whole_command(holes)
    return res


def _whole_command(holes: int) -> dict[str, Any]:
    """The command itself as a user starts it (``taskset -c 0 cnctwin simulate ...``): wall
    and CPU including the interpreter start, the imports and loading the numba cache."""
    exe = Path(sys.executable).with_name("cnctwin")
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [str(exe), "simulate", "tool_wear_run", "--out", str(Path(tmp) / "run"),
               "--seed", "1", "--format", "parquet", "--option", f"n_holes={holes}"]
        if hasattr(os, "sched_getaffinity"):
            cmd = ["taskset", "-c", str(min(os.sched_getaffinity(0))), *cmd]
        r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        w0 = time.perf_counter()
        subprocess.run(cmd, check=True, capture_output=True)
        wall = time.perf_counter() - w0
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return {"wall": wall, "user": r1.ru_utime - r0.ru_utime, "sys": r1.ru_stime - r0.ru_stime}


def table(r: dict[str, Any]) -> str:
    def row(name: str, d: dict[str, Any]) -> str:
        cpu = d["user"] + d["sys"]
        scale = FULL_HOLES / r["holes"]
        return (f"| {name} | {d['machine_s'] / cpu:.0f}x | {d['machine_s'] / d['wall']:.0f}x | "
                f"{cpu:.1f} s ({d['user']:.1f} user + {d['sys']:.1f} sys) / {d['wall']:.1f} s"
                f" | {cpu * scale:.1f} s / {d['wall'] * scale:.1f} s | "
                f"{sum(d['disk_mb'].values()):.0f} MB | {d['peak_rss_mb']:.0f} MB |")

    new = r["new"]
    out = [
        f"`cnctwin simulate tool_wear_run --option n_holes={r['holes']} --format parquet` "
        f"({new['cycles']} cycles = {new['machine_s']:.0f} s = {new['machine_s'] / 3600:.2f} h "
        "machine time), child process on one core, median of "
        f"{r['repeat']} alternating runs:",
        "",
        "| what | machine-s per CPU-s | per wall-s | CPU / wall | 2676 holes (CPU / wall) | "
        "written | peak RSS |",
        "|---|---|---|---|---|---|---|",
        "| physical baseline: the machining itself | 1x | 1x | | 3.46 h | | |",
        f"| issue goal: the 2676-hole run under {GOAL_S:.0f} s | | | | < {GOAL_S:.0f} s | "
        "< 2 GB memory |  |",
        row("**now**", new),
    ]
    if r.get("before"):
        out.append(row(f"before (commit {r['before_rev']})", r["before"]))
    if r.get("command"):
        c = r["command"]
        cpu = c["user"] + c["sys"]
        full = (f"{cpu:.1f} s / {c['wall']:.1f} s" if r["holes"] == FULL_HOLES
                else "(start-up does not scale)")
        out.append(f"| the whole command now, as typed (interpreter start, imports, numba cache "
                   f"load; one run) | {new['machine_s'] / cpu:.0f}x | "
                   f"{new['machine_s'] / c['wall']:.0f}x | {cpu:.1f} s / {c['wall']:.1f} s | "
                   f"{full} | | |")
    out.append("")
    disk = ", ".join(f"{k} {v:.0f} MB" for k, v in new["disk_mb"].items())
    allr = "; ".join(f"{c:.1f}/{w:.1f}" for c, w in new["all"])
    line = f"Written now: {disk}. CPU/wall s of the runs: now {allr}"
    if r.get("before"):
        line += "; before " + "; ".join(f"{c:.1f}/{w:.1f}" for c, w in r["before"]["all"])
        bd = ", ".join(f"{k} {v:.0f} MB" for k, v in r["before"]["disk_mb"].items())
        line += f" (before wrote {bd})"
    out.append(line + f". Load average at the end {r['loadavg'][0]:.1f}.")
    if r.get("parts"):
        p = r["parts"]
        cpu = p["user"] + p["sys"]
        out += ["", f"CPU per component (one extra run with timers, {cpu:.1f} s CPU in all):", "",
                "| component | CPU | share | ms per 100 machine-s |", "|---|---|---|---|"]
        rest = cpu
        for name, c in sorted(p["parts"].items(), key=lambda kv: -kv[1]):
            rest -= c
            out.append(f"| {name} | {c:.2f} s | {100 * c / cpu:.0f} % | "
                       f"{1e5 * c / p['machine_s']:.1f} |")
        out.append(f"| rest (process hook, holes, LF, events, camera, truth.json, system) | "
                   f"{rest:.2f} s | {100 * rest / cpu:.0f} % | {1e5 * rest / p['machine_s']:.1f} |")
    return "\n".join(out)


def write_section(path: Path, body: str) -> None:
    title = "## Simulator: the tool-wear scenario command"
    head = (f"{title}\n\n`benchmarks/bench_scenario.py` ({dt.date.today().isoformat()}, "
            f"{cpu_model()}, 2 vCPU shared with other jobs, child pinned to one core, "
            "NUMBA_NUM_THREADS=1). Where the time goes, what was tried and what is next: "
            "docs/simulator.md section 6.\n\n")
    replace_section(path, title, head + body)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--holes", type=int, default=FULL_HOLES, help="holes of the wear run")
    ap.add_argument("--repeat", type=int, default=3, help="alternating runs (median)")
    ap.add_argument("--before-rev", default=None, help="also run this commit's source")
    ap.add_argument("--parts", action="store_true", help="CPU per component (extra run)")
    ap.add_argument("--write", type=Path, help="update this section of BENCHMARKS.md")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        _child_main(args.holes, args.parts)
        return
    r = run(args.holes, args.repeat, args.before_rev, args.parts)
    body = table(r)
    print(body)
    if args.write:
        write_section(args.write, body)


if __name__ == "__main__":
    main()
