"""Simulator throughput on one core: machine-seconds simulated per CPU-second and wall-second.

Runs the full machine (5 feed axes + motor spindle, 125 us inner loops, drilling cutting loads
on) on an N-hole drilling program, streaming 50 000-cycle chunks to disk, and reports side by
side in one sitting:

* the physical baseline (real time, 1x) and the issue's goal (>= 1000x real time so that the
  2676-hole wear run, ~3.5 h of machining, takes < 15 s);
* ``simulate()`` now with the default Parquet chunk sink and with Arrow IPC chunk files, with
  the time per component (interpolator, cutting hook, spindle, servo, writer, the rest =
  orchestration/LF/events), measured inside the same run;
* optionally ``simulate()`` as of an older commit (``--before-rev``: its ``src`` exported with
  ``git archive`` and run in a child process pinned to the same core, alternating with the
  new runs);
* the same ``simulate()`` with the pre-optimisation kernels (:mod:`cnctwin.sim._reference`)
  and the first Parquet settings (float64 + time, zstd-1 with dictionary) as the baseline;
* peak memory (max RSS of the process) while streaming the runs;
* with ``--writer``: the chunk writer alone on one 50 000-cycle chunk of the run (CPU per
  chunk and bytes per cycle for the sink settings of each round and the codec options).

Rates are machine-seconds per CPU-second of this process (``time.process_time``), the honest
measure on the shared 2 vCPU machine, and per wall-second.

Usage::

    NUMBA_NUM_THREADS=1 .venv/bin/python benchmarks/bench_sim.py --holes 600 \
        --before-rev acb83dd --writer [--write BENCHMARKS.md]
    NUMBA_NUM_THREADS=1 .venv/bin/python benchmarks/bench_sim.py --holes 2676 \
        --baseline-holes 20 --repeat 1     # the full wear run; peak RSS while streaming it
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as dt
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the frozen kernels: tests/sim

import numpy as np
from tests.sim.reference_kernels import servo_kernel_reference, spindle_kernel_reference

import cnctwin.sim.servo as servo_mod
import cnctwin.sim.simulation as sim_mod
import cnctwin.sim.spindle as spindle_mod
from _common import cpu_model, export_rev, pin_one_core, replace_section
from cnctwin.sim.cutting import drilling_load
from cnctwin.sim.machine import Machine
from cnctwin.sim.recorder import ParquetChunkSink, RecordedChunk
from cnctwin.sim.simulation import CuttingInput, CuttingOutput, simulate

WEAR_RUN_HOLES = 2676
WEAR_RUN_S = 3.5 * 3600.0
GOAL_X = 1000.0


def drilling_program(holes: int, *, depth_mm: float = 20.0, pitch_mm: float = 15.0) -> str:
    """G-code: ``holes`` holes of ``depth_mm`` at F400, S2400 (thesis wear-run settings)."""
    lines = ["G90 G17 G54", "T6 M6", "S2400 M3", "G0 X0 Y0 Z2"]
    side = int(np.ceil(np.sqrt(holes)))
    for i in range(holes):
        x, y = (i % side) * pitch_mm, (i // side) * pitch_mm
        lines += [f"G0 X{x:.3f} Y{y:.3f}", f"G1 Z{-depth_mm:.3f} F400", "G0 Z2"]
    lines += ["M5", "M30"]
    return "\n".join(lines) + "\n"


def cutting_hook(ci: CuttingInput) -> CuttingOutput:
    """Drilling loads (engineer C's Kienzle model) from the expected tip position."""
    z = ci.position["Z1"]
    depth = -z
    vz = np.gradient(z) / ci.cycle_time_s * 60.0  # mm/min
    feed = np.where(ci.spindle_speed_rpm > 1.0, -vz / np.maximum(ci.spindle_speed_rpm, 1.0), 0.0)
    load = drilling_load(depth, ci.spindle_speed_rpm, feed, material="aisi1045",
                         dt_s=ci.cycle_time_s)
    return CuttingOutput(spindle_torque_nm=load.torque_nm,
                         force_n={"Z1": load.thrust_n, "X1": load.fx_n, "Y1": load.fy_n})


def _maxrss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


class _Timers:
    """CPU seconds per component, collected by wrapping the functions simulate() calls."""

    def __init__(self) -> None:
        self.cpu: dict[str, float] = {}

    def wrap(self, name: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        def timed(*args: Any, **kwargs: Any) -> Any:
            t0 = time.process_time()
            try:
                return fn(*args, **kwargs)
            finally:
                self.cpu[name] = self.cpu.get(name, 0.0) + time.process_time() - t0
        return timed

    def wrap_iter(self, name: str, fn: Callable[..., Iterator[Any]]) -> Callable[..., Any]:
        def timed(*args: Any, **kwargs: Any) -> Iterator[Any]:
            it = fn(*args, **kwargs)
            while True:
                t0 = time.process_time()
                try:
                    item = next(it)
                except StopIteration:
                    self.cpu[name] = self.cpu.get(name, 0.0) + time.process_time() - t0
                    return
                self.cpu[name] = self.cpu.get(name, 0.0) + time.process_time() - t0
                yield item
        return timed


class _ArrowChunkSink(ParquetChunkSink):
    """The chunk sink with Arrow IPC (Feather v2, lz4) HF files."""

    def __init__(self, directory: Path) -> None:
        super().__init__(directory, file_format="arrow")


class _LegacyParquetSink(ParquetChunkSink):
    """The sink as it was before the speed work: float64 with a ``time`` column, zstd level 1
    with dictionary and full statistics, LF values held until close."""

    def __init__(self, directory: Path) -> None:
        super().__init__(directory, float32_codes=())
        self._lf_frames: list[Any] = []

    def write(self, chunk: RecordedChunk) -> None:
        import pyarrow as pa
        import pyarrow.parquet as pq

        from cnctwin.recording import cycles_to_time

        assert self._meta is not None
        c = chunk.cycles
        time_ = cycles_to_time(c, self._meta.time_anchors, cycle_time_s=self._meta.cycle_time_s)
        arrays = [pa.array(c), pa.array(time_)] + [pa.array(chunk.hf[k]) for k in self._columns]
        table = pa.Table.from_arrays(arrays, names=["cycle", "time", *self._columns])
        path = self.directory / f"hf_{len(self.files):06d}.parquet"
        pq.write_table(table, path, compression="zstd", compression_level=1,
                       use_dictionary=True, write_statistics=True)
        self.files.append(path)
        if len(chunk.lf):
            self._lf_frames.append(chunk.lf)
        if len(chunk.events):
            self._events.append(chunk.events)

    def close(self, meta: Any) -> None:
        for lf in self._lf_frames:
            self._write_lf(lf)
        self._lf_frames = []
        super().close(meta)


class _PrevRoundParquetSink(ParquetChunkSink):
    """The Parquet sink as the previous round left it (commit acb83dd): float32 drive values,
    no ``time``, pages v2, lz4 on every column, nullable columns, pyarrow's default write batch
    of 1024 rows, LF dictionary-encoded throughout."""

    def write(self, chunk: RecordedChunk) -> None:
        import pyarrow as pa
        import pyarrow.parquet as pq

        c = chunk.cycles
        arrays = [pa.array(c)] + [
            pa.array(chunk.hf[k].astype(np.float32) if k in self._f32 else chunk.hf[k])
            for k in self._columns
        ]
        table = pa.Table.from_arrays(arrays, names=["cycle", *self._columns])
        path = self.directory / f"hf_{len(self.files):06d}.parquet"
        pq.write_table(table, path, compression="lz4", use_dictionary=False,
                       write_statistics=["cycle"], data_page_version="2.0")
        self.files.append(path)
        if len(chunk.lf):
            schema = pa.schema([("cycle", pa.int64()), ("time", pa.timestamp("ns", tz="UTC")),
                                ("signal", pa.string()), ("value", pa.float64()),
                                ("text", pa.string())])
            table = pa.Table.from_pandas(chunk.lf[list(schema.names)], schema=schema,
                                         preserve_index=False)
            if self._lf_writer is None:
                self._lf_writer = pq.ParquetWriter(self.directory / "lf.parquet", schema,
                                                   compression="lz4")
            self._lf_writer.write_table(table)
        if len(chunk.events):
            self._events.append(chunk.events)


@contextlib.contextmanager
def _reference_kernels() -> Iterator[None]:
    old = servo_mod._servo_kernel, spindle_mod._kernel
    servo_mod._servo_kernel = servo_kernel_reference
    spindle_mod._kernel = spindle_kernel_reference
    try:
        yield
    finally:
        servo_mod._servo_kernel, spindle_mod._kernel = old


def _timed_run(prog: str, m: Machine, sink_cls: type[ParquetChunkSink]) -> dict[str, Any]:
    timers = _Timers()
    saved = sim_mod.simulate_servo, sim_mod.simulate_spindle, sim_mod._chunks_from
    sim_mod.simulate_servo = timers.wrap("servo (5 axes)", saved[0])
    sim_mod.simulate_spindle = timers.wrap("spindle", saved[1])
    sim_mod._chunks_from = timers.wrap_iter("interpolator", saved[2])
    hook = timers.wrap("cutting hook", cutting_hook)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            sink = sink_cls(Path(tmp) / "run")
            wname = "writer (HF chunks + streamed LF)"
            sink.write = timers.wrap(wname, sink.write)  # type: ignore[method-assign]
            sink.close = timers.wrap(wname, sink.close)  # type: ignore[method-assign]
            c0, w0 = time.process_time(), time.perf_counter()
            res = simulate(prog, m, cutting=hook, sink=sink, chunk_cycles=50_000)
            cpu, wall = time.process_time() - c0, time.perf_counter() - w0
            disk = sum(f.stat().st_size for f in Path(tmp, "run").iterdir())
    finally:
        sim_mod.simulate_servo, sim_mod.simulate_spindle, sim_mod._chunks_from = saved
    parts = dict(timers.cpu)
    parts["rest (orchestration, LF frame, events)"] = cpu - sum(parts.values())
    ms = float(res.trajectory["duration_s"])
    return {"cpu": cpu, "wall": wall, "machine_s": ms, "cycles": res.trajectory["n_cycles"],
            "parts": parts, "disk_mb": disk / 1e6}


def _median_run(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The run with the median CPU time (its components are reported), with all CPU times."""
    ordered = sorted(runs, key=lambda d: d["cpu"])
    med = dict(ordered[len(ordered) // 2])
    med["all_cpu"] = [d["cpu"] for d in runs]
    return med


def _warm_up(m: Machine) -> None:
    """Compile / load the numba caches of both kernel sets, import pyarrow."""
    with tempfile.TemporaryDirectory() as tmp:
        simulate(drilling_program(1), m, cutting=cutting_hook,
                 sink=_ArrowChunkSink(Path(tmp) / "w"))
        simulate(drilling_program(1), m, cutting=cutting_hook,
                 sink=ParquetChunkSink(Path(tmp) / "w2"))
        with _reference_kernels():
            simulate(drilling_program(1), m, cutting=cutting_hook)


def _child_run(src: Path, holes: int) -> dict[str, Any]:
    """One Parquet run of ``simulate()`` from the source tree ``src`` in a child process."""
    env = dict(os.environ, PYTHONPATH=str(src), NUMBA_NUM_THREADS="1")
    out = subprocess.run([sys.executable, __file__, "--child", "--holes", str(holes)],
                         env=env, capture_output=True, text=True, check=True).stdout
    return dict(json.loads(out.strip().splitlines()[-1]))


def run(holes: int, baseline_holes: int, repeat: int = 3,
        before_rev: str | None = None) -> dict[str, Any]:
    m = Machine.thesis_default()
    _warm_up(m)
    rss0 = _maxrss_mb()
    prog = drilling_program(holes)
    arrow, parquet, before = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        src = export_rev(before_rev, Path(tmp)) if before_rev else None
        if src is not None:
            _child_run(src, 1)  # compile the old kernels into its numba cache
        for _ in range(repeat):  # interleaved, so that load changes hit all alike
            parquet.append(_timed_run(prog, m, ParquetChunkSink))
            arrow.append(_timed_run(prog, m, _ArrowChunkSink))
            if src is not None:
                before.append(_child_run(src, holes))
    new = _median_run(parquet)
    new["peak_rss_mb"] = _maxrss_mb()
    new["rss_before_mb"] = rss0
    with _reference_kernels():
        base = _timed_run(drilling_program(baseline_holes), m, _LegacyParquetSink)
    return {"holes": holes, "baseline_holes": baseline_holes, "new": new,
            "arrow": _median_run(arrow), "base": base, "repeat": repeat,
            "before": _median_run(before) if before else None, "before_rev": before_rev,
            "loadavg": os.getloadavg()}


def _capture_chunk(m: Machine) -> tuple[RecordedChunk, list[str], Any]:
    """One full 50 000-cycle chunk (HF + LF + events) of the drilling run."""
    got: list[Any] = []

    class _Keep(ParquetChunkSink):
        def write(self, chunk: RecordedChunk) -> None:
            if not got:
                got.append((chunk, list(self._columns), self._meta))

    with tempfile.TemporaryDirectory() as tmp:
        simulate(drilling_program(40), m, cutting=cutting_hook,
                 sink=_Keep(Path(tmp) / "c"), chunk_cycles=50_000)
    chunk, columns, meta = got[0]
    hf = {k: np.array(v, copy=True) for k, v in chunk.hf.items()}  # own the arrays
    return RecordedChunk(chunk.cycles.copy(), hf, chunk.lf, chunk.events), columns, meta


WRITER_VARIANTS: dict[str, Callable[[Path], ParquetChunkSink]] = {
    "first round: Parquet float64 + time, zstd-1 + dictionary, statistics":
        lambda d: _LegacyParquetSink(d),
    "previous round (acb83dd): Parquet float32 drive values, lz4, pages v2": _PrevRoundParquetSink,
    "**now: Parquet (default)**: + REQUIRED columns, one write batch, per-column codec, "
    "delta cycle": ParquetChunkSink,
    "now: Parquet, zstd-1": lambda d: ParquetChunkSink(d, compression="zstd"),
    "now: Parquet, uncompressed": lambda d: ParquetChunkSink(d, compression="none"),
    "now: Arrow IPC (Feather v2), lz4": lambda d: ParquetChunkSink(d, file_format="arrow"),
    "now: Arrow IPC, zstd-1": lambda d: ParquetChunkSink(d, file_format="arrow",
                                                         compression="zstd"),
    "now: Arrow IPC, uncompressed": lambda d: ParquetChunkSink(d, file_format="arrow",
                                                               compression="none"),
}


def writer_bench(m: Machine, files: int = 10, repeat: int = 5) -> list[dict[str, Any]]:
    """CPU per chunk and bytes per cycle of each sink variant: ``files`` copies of one chunk
    per sink (a Parquet sink re-learns its codecs on every 10th file), median of ``repeat``."""
    chunk, columns, meta = _capture_chunk(m)
    n = chunk.cycles.size
    cpu: dict[str, list[float]] = {name: [] for name in WRITER_VARIANTS}
    size: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(repeat):
            for i, (name, make) in enumerate(WRITER_VARIANTS.items()):
                d = Path(tmp) / f"w{r}_{i}"
                sink = make(d)
                sink.open(columns, meta)
                c0 = time.process_time()
                for _ in range(files):
                    sink.write(chunk)
                sink.close(meta)
                cpu[name].append((time.process_time() - c0) / files)
                size[name] = sum(f.stat().st_size for f in d.iterdir()) / files / n
                shutil.rmtree(d)
    return [{"name": k, "cpu_ms": 1e3 * sorted(v)[len(v) // 2], "b_per_cycle": size[k]}
            for k, v in cpu.items()]


def table(r: dict[str, Any]) -> str:
    new, base, arrow = r["new"], r["base"], r["arrow"]

    def rate(d: dict[str, Any], key: str = "cpu") -> float:
        return float(d["machine_s"] / d[key])

    def proj(d: dict[str, Any]) -> str:
        return f"{WEAR_RUN_S / rate(d):.1f} s"

    out = [
        "| what | machine-s per CPU-s | per wall-s | 3.5 h wear run (CPU, projected) |",
        "|---|---|---|---|",
        "| physical baseline: real time | 1x | 1x | 3.5 h |",
        f"| issue goal | >= {GOAL_X:.0f}x | | < 15 s |",
        f"| **simulate() now**: {r['holes']} holes, 5 axes + spindle, cutting on, Parquet "
        f"chunk sink (the default) | **{rate(new):.0f}x** | {rate(new, 'wall'):.0f}x | "
        f"{proj(new)} |",
    ]
    for name, cpu in new["parts"].items():
        b = base["parts"].get(name, float("nan")) * new["machine_s"] / base["machine_s"]
        out.append(f"| &nbsp;&nbsp;{name}: {cpu:.3f} s CPU ({100 * cpu / new['cpu']:.0f} %), "
                   f"{1e5 * cpu / new['machine_s']:.1f} ms per 100 machine-s; baseline "
                   f"{1e5 * b / new['machine_s']:.0f} ms | {new['machine_s'] / cpu:.0f}x | | |")
    aw = arrow["parts"].get("writer (HF chunks + streamed LF)", float("nan"))
    out.append(
        f"| simulate() now, Arrow IPC chunk files (`file_format='arrow'`) | {rate(arrow):.0f}x "
        f"| {rate(arrow, 'wall'):.0f}x | {proj(arrow)} |")
    out.append(f"| &nbsp;&nbsp;Arrow writer: {aw:.3f} s CPU, "
               f"{1e5 * aw / arrow['machine_s']:.1f} ms per 100 machine-s | "
               f"{arrow['machine_s'] / aw:.0f}x | | |")
    if r.get("before"):
        bf = r["before"]
        out.append(f"| simulate() before this round (commit {r['before_rev']}, Parquet, same "
                   f"program, alternating child process) | {rate(bf):.0f}x | "
                   f"{rate(bf, 'wall'):.0f}x | {proj(bf)} |")
    out.append(
        f"| simulate() baseline (reference kernels, float64 + time, zstd-1 + dictionary): "
        f"{r['baseline_holes']} holes | {rate(base):.0f}x | {rate(base, 'wall'):.0f}x | "
        f"{proj(base)} |")
    out.append("")
    cpus = ", ".join(f"{c:.2f}" for c in new["all_cpu"])
    acpus = ", ".join(f"{c:.2f}" for c in arrow["all_cpu"])
    bcpus = (", ".join(f"{c:.2f}" for c in r["before"]["all_cpu"]) + " before; "
             if r.get("before") else "")
    out.append(
        f"Run: {new['cycles']:.0f} cycles = {new['machine_s']:.1f} s machine time in "
        f"{new['cpu']:.2f} s CPU / {new['wall']:.2f} s wall; Parquet {new['disk_mb']:.0f} MB "
        f"({new['disk_mb'] * 1e6 / new['cycles']:.0f} B/cycle), Arrow "
        f"{arrow['disk_mb']:.0f} MB; peak RSS {new['peak_rss_mb']:.0f} MB (after warm-up "
        f"{new['rss_before_mb']:.0f} MB) while streaming 50 000-cycle chunks. Baseline "
        f"component times scaled to the same machine time. Median of {r['repeat']} runs (CPU s: "
        f"{cpus} Parquet; {acpus} Arrow; {bcpus}load average at the end "
        f"{r['loadavg'][0]:.1f}).")
    return "\n".join(out)


def writer_table(rows: list[dict[str, Any]], wear_cycles: float) -> str:
    out = ["| chunk sink settings (HF + LF of one 50 000-cycle chunk) | CPU per chunk "
           "(= per 100 machine-s) | B/cycle | 3.5 h wear run on disk |", "|---|---|---|---|"]
    for row in rows:
        out.append(f"| {row['name']} | {row['cpu_ms']:.1f} ms | {row['b_per_cycle']:.0f} | "
                   f"{row['b_per_cycle'] * wear_cycles / 1e9:.2f} GB |")
    return "\n".join(out)


def write_section(path: Path, body: str, pinned: str) -> None:
    head = (f"## Simulator\n\n`benchmarks/bench_sim.py` ({dt.date.today().isoformat()}, "
            f"{cpu_model()}, 2 vCPU shared with other jobs, one core: "
            f"NUMBA_NUM_THREADS=1, {pinned}). Where the time goes, what was tried and what "
            "is next: docs/simulator.md section 6.\n\n")
    replace_section(path, "## Simulator", head + body)


def _child_main(holes: int) -> None:
    """One timed Parquet run, JSON on stdout (used with an older source on PYTHONPATH)."""
    pin_one_core()
    m = Machine.thesis_default()
    with tempfile.TemporaryDirectory() as tmp:
        simulate(drilling_program(1), m, cutting=cutting_hook,
                 sink=ParquetChunkSink(Path(tmp) / "w"))
        c0, w0 = time.process_time(), time.perf_counter()
        res = simulate(drilling_program(holes), m, cutting=cutting_hook,
                       sink=ParquetChunkSink(Path(tmp) / "r"), chunk_cycles=50_000)
        cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    print(json.dumps({"cpu": cpu, "wall": wall, "machine_s": float(res.trajectory["duration_s"]),
                      "cycles": int(res.trajectory["n_cycles"])}))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--holes", type=int, default=600, help="holes in the drilling program")
    ap.add_argument("--baseline-holes", type=int, default=None,
                    help="holes for the baseline run (default: min(holes, 600))")
    ap.add_argument("--before-rev", default=None,
                    help="also time simulate() as of this git commit (child process)")
    ap.add_argument("--writer", action="store_true", help="also run the writer benchmark")
    ap.add_argument("--write", type=Path, help="update the 'Simulator' section of this file")
    ap.add_argument("--repeat", type=int, default=3, help="runs of the new path (median)")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        _child_main(args.holes)
        return
    pinned = pin_one_core()
    r = run(args.holes, args.baseline_holes or min(args.holes, 600), args.repeat,
            args.before_rev)
    body = table(r)
    if args.writer:
        rows = writer_bench(Machine.thesis_default())
        body += ("\n\nWriter alone (`--writer`, median of 5, 10 files per sink):\n\n"
                 + writer_table(rows, WEAR_RUN_S / 0.002))
    print(body)
    if args.write:
        write_section(args.write, body, pinned)
        print(f"wrote {args.write}", file=sys.stderr)


if __name__ == "__main__":
    main()
