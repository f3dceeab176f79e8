"""Cutting hooks of the scenarios: drilling, tapping, milling and air, with the shared
bookkeeping (hole numbering, faults, the truth table, the dynamometer DAQ, progress).

Each hook is called by :func:`cnctwin.sim.simulation.simulate` once per chunk with a
:class:`~cnctwin.sim.simulation.CuttingInput` and returns the process load.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from cnctwin.recording import ExternalChannel
from cnctwin.sim.config import (
    ProgressFn,
    ScenarioConfig,
)
from cnctwin.sim.cutting import (
    Material,
    drill_thrust_n,
    drill_torque_nm,
    drilling_load,
    lip_height_difference_um,
    milling_load,
    rotating_force_n,
    tapping_load,
)
from cnctwin.sim.faults import Fault, LooseTool, ToolBreakage, apply_faults, hardness_factor
from cnctwin.sim.sensors import (
    DYNAMOMETER_CSV_HEADER,
    Dynamometer,
    dynamometer_channel_from_rows,
    dynamometer_csv_decimals,
    dynamometer_rows,
    format_csv_fixed_bytes,
)
from cnctwin.sim.simulation import CuttingInput, CuttingOutput
from cnctwin.sim.tool import (
    flank_wear_um,
    tool_temperature,
    tool_temperatures,
)

__all__ = ["DrillingProcess", "HoleNumbers", "MillingProcess", "TappingProcess"]


# ----------------------------------------------------------------------------- streaming helpers
def _runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """Half-open index ranges [a, b) where ``mask`` is True."""
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(),
                    strict=True))


class _DynamometerDAQ:
    """The dynamometer DAQ fed chunk by chunk; one file (session) per run of ``on`` cycles.

    Each session has its own clock (own t = 0 at ``clock_offset_s`` after the session start on
    the recording time base, drifting by ``clock_drift_ppm``); consecutive chunks are sampled
    without gaps (the last true sample of a chunk is kept for the next one).
    """

    def __init__(self, sensor: Dynamometer, rng: np.random.Generator, out: Path | None,
                 stem: str) -> None:
        self.sensor = sensor
        self.rng = rng
        self.out = out
        self.stem = stem
        self.sessions: list[dict[str, Any]] = []
        self.channels: list[ExternalChannel] = []
        self.paths: list[Path] = []
        self._rows: list[NDArray[np.float64]] = []
        self._fh: IO[bytes] | None = None
        self._decimals = dynamometer_csv_decimals(fs_hz=sensor.fs_hz,
                                                  force_noise_n=sensor.force_noise_n,
                                                  torque_noise_nm=sensor.torque_noise_nm)
        self._open = False
        self._last: tuple[float, NDArray[np.float64]] | None = None
        self._last_own = -math.inf

    def feed(self, time_s: NDArray[np.float64], values: NDArray[np.float64],
             on: NDArray[np.bool_] | None = None) -> None:
        """``values`` shape (4, n): fx, fy, fz [N], mz [Nm] on the recording time ``time_s``."""
        n = time_s.size
        mask = np.ones(n, dtype=bool) if on is None else on
        for a, b in _runs(mask):
            if not (a == 0 and self._open):
                self._close_session()
                self._open_session(float(time_s[a]))
            t = time_s[a:b]
            v = values[:, a:b]
            if self._last is not None:
                t = np.concatenate([[self._last[0]], t])
                v = np.concatenate([self._last[1][:, None], v], axis=1)
            self._last = (float(t[-1]), v[:, -1].copy())
            if t.size >= 2:
                self._sample(t, v)
            if b < n:
                self._close_session()

    def _open_session(self, t0: float) -> None:
        k = len(self.sessions) + 1
        name = f"{self.stem}.csv" if k == 1 else f"{self.stem}_{k:04d}.csv"
        self.sessions.append({"file": name, "start_s": t0,
                              "clock_offset_s": t0 + self.sensor.clock_offset_s,
                              "clock_drift_ppm": self.sensor.clock_drift_ppm,
                              "fs_hz": self.sensor.fs_hz})
        self._open = True
        self._last = None
        self._last_own = -math.inf
        self._rows = []
        if self.out is not None:
            p = self.out / name
            self._fh = p.open("wb")
            self._fh.write(DYNAMOMETER_CSV_HEADER)
            self.paths.append(p)

    def _sample(self, t: NDArray[np.float64], v: NDArray[np.float64]) -> None:
        sensor = dataclasses.replace(self.sensor,
                                     clock_offset_s=self.sessions[-1]["clock_offset_s"])
        rows = dynamometer_rows(t, (v[0], v[1], v[2], v[3]), sensor=sensor, rng=self.rng)
        # samples already taken at the end of the previous chunk (own times increase)
        rows = rows[int(np.searchsorted(rows[:, 0], self._last_own + 1e-12, side="right")):]
        if not rows.shape[0]:
            return
        self._last_own = float(rows[-1, 0])
        if self._fh is not None:
            # fixed point below the noise, straight to the binary file (session 3: no pandas,
            # no str copy; the DAQ was 30 % of the wear run's time, benchmarks/bench_scenario.py)
            self._fh.write(format_csv_fixed_bytes(rows, self._decimals).data)
        else:
            self._rows.append(rows)

    def _close_session(self) -> None:
        if not self._open:
            return
        self._open = False
        if self._fh is not None:
            self._fh.close()
            self._fh = None
        elif self._rows:
            self.channels.append(dynamometer_channel_from_rows(self._rows,
                                                               fs_hz=self.sensor.fs_hz))
        self._rows = []

    def close(self) -> None:
        """End the last session."""
        self._close_session()


class _TruthParquet:
    """Per-cycle truth rows streamed to one Parquet file (one row group per chunk)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._writer: Any = None

    def write(self, frame: dict[str, NDArray[Any]]) -> None:
        import pyarrow as pa
        import pyarrow.parquet as pq

        table = pa.table(frame)
        if self._writer is None:
            # lz4 without dictionary, pages v2: ~7x faster than zstd with dictionary and 20 %
            # smaller on these float columns (benchmarks/bench_sim.py, session 2); the cycle
            # delta-encoded and the float32 truth byte-stream-split: -40 % bytes (session 3)
            enc = {f.name: "BYTE_STREAM_SPLIT" for f in table.schema
                   if pa.types.is_floating(f.type)}
            enc.update({f.name: "DELTA_BINARY_PACKED" for f in table.schema
                        if pa.types.is_integer(f.type)})
            self._writer = pq.ParquetWriter(self.path, table.schema, compression="lz4",
                                            use_dictionary=False, write_batch_size=65_536,
                                            data_page_version="2.0", column_encoding=enc)
        self._writer.write_table(table)

    def close(self) -> Path | None:
        if self._writer is None:
            return None
        self._writer.close()
        return self.path


@dataclass
class _Progress:
    """Progress of one program: ``time_s`` of ``total_s`` machine time (the planned duration
    the hook gets with every chunk, so the program is not planned twice)."""

    fn: ProgressFn | None
    label: str
    done: float = 0.0
    share: float = 1.0

    def __call__(self, time_s: float, total_s: float) -> None:
        if self.fn is not None and total_s > 0:
            frac = self.done + self.share * min(time_s / total_s, 1.0)
            self.fn(min(frac, 1.0), f"{self.label} {time_s:.0f}/{total_s:.0f} s")


@dataclass
class HoleNumbers:
    """The program's hole numbers, shared by the cutting hooks of a tool table's tools.

    Each hook numbers the holes it cuts from this one counter, so the drill's, the tap's and
    the next drill's holes count on as the program's (and as the edge counts them), and a
    fault names the program's hole.

    Attributes
    ----------
    next : int
        Number of the next hole.
    """

    next: int = 0

    def take(self) -> int:
        """The next hole's number (and count it)."""
        self.next += 1
        return self.next - 1


class _Process:
    """Shared bookkeeping of the cutting hooks (hole counting, truth, DAQ, progress).

    ``hole_numbers``: the program's counter shared with the other tools' hooks (a tool
    table); then a tool's own faults (:class:`ToolBreakage`, :class:`LooseTool` from a hole)
    act only in the hook that cut their hole, and ``first_hole`` counts this tool's earlier
    holes (its wear). Without it the hook numbers its own holes from ``first_hole``.
    ``block_depths_mm``: the programmed depth of each cycle block (program block index ->
    [mm]), the depth a :class:`ToolBreakage`'s fraction is of in that block's hole.
    """

    def __init__(self, *, surface_z_mm: float, faults: Sequence[Fault],
                 rng: np.random.Generator, truth: _TruthParquet | None,
                 daq: _DynamometerDAQ | None, daq_off_blocks: Sequence[int] = (),
                 progress: _Progress | None = None, first_hole: int = 0,
                 hole_numbers: HoleNumbers | None = None,
                 block_depths_mm: Mapping[int, float] | None = None) -> None:
        self.surface_z_mm = surface_z_mm
        self.faults = tuple(faults)
        self.rng = rng
        self.truth_out = truth
        self.daq = daq
        self.daq_off_blocks = np.asarray(daq_off_blocks, dtype=np.int64)
        self.progress = progress
        self.first_hole = first_hole
        self.onsets: list[float | None] = [None] * len(self.faults)
        self.holes: dict[int, dict[str, Any]] = {}
        self._numbers = hole_numbers
        self.block_depths_mm = dict(block_depths_mm or {})
        self._count = 0  # holes this tool cut
        self._own: dict[int, int] = {}  # hole number -> this tool's hole count (its wear)
        self._hole = -1  # number of the current hole
        self._hole_xy: tuple[float, float] | None = None
        self._inside = False
        self._prev: dict[str, float] = {}

    def _velocity(self, key: str, x: NDArray[np.float64], dt: float) -> NDArray[np.float64]:
        prev = self._prev.get(key, float(x[0]))
        self._prev[key] = float(x[-1])
        return np.diff(x, prepend=prev) / dt

    def _hole_index(self, depth: NDArray[np.float64], ci: CuttingInput) -> NDArray[np.int64]:
        """Hole number per cycle: a new hole at each entry at a new XY position (0.5 mm)."""
        inside = depth > 0.0
        prev = np.concatenate([[self._inside], inside[:-1]])
        self._inside = bool(inside[-1])
        out = np.full(depth.size, self._hole, dtype=np.int64)
        x, y = ci.des_pos["X1"], ci.des_pos["Y1"]
        for e in np.flatnonzero(inside & ~prev):
            xy = (float(x[e]), float(y[e]))
            if self._hole_xy is None or math.hypot(xy[0] - self._hole_xy[0],
                                                   xy[1] - self._hole_xy[1]) > 0.5:
                own = self.first_hole + self._count
                self._count += 1
                self._hole = own if self._numbers is None else self._numbers.take()
                self._own[self._hole] = own
                self._hole_xy = xy
                self.holes[self._hole] = {
                    "hole": self._hole, "x_mm": xy[0], "y_mm": xy[1],
                    "cut_first_cycle": int(ci.cycle[e]), "cut_first_s": float(ci.time_s[e]),
                }
                out[e:] = self._hole
        return out

    def _hole_progress(self, depth: NDArray[np.float64], ci: CuttingInput,
                       default_mm: float | None) -> NDArray[np.float64] | None:
        """Tip depth over the executing cycle's programmed depth (``block_depths_mm``, else
        ``default_mm``) [-], 0..1; None without either."""
        d = np.full(depth.size, np.nan if default_mm is None else float(default_mm))
        if self.block_depths_mm:
            bi = np.asarray(ci.block_index)
            for b in np.unique(bi):
                if int(b) in self.block_depths_mm:
                    d[bi == b] = self.block_depths_mm[int(b)]
        if not np.isfinite(d).any():
            return None
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.clip(np.nan_to_num(depth / d, nan=0.0), 0.0, 1.0)

    def _tool_holes(self, hole: NDArray[np.int64]) -> NDArray[np.int64]:
        """This tool's hole count per sample (its wear) from the hole numbers (-1: none)."""
        if self._numbers is None:
            return hole
        out = np.full(hole.size, -1, dtype=np.int64)
        for h in np.unique(hole[hole >= 0]):
            out[hole == h] = self._own[int(h)]
        return out

    def _acts_here(self, fault: Fault) -> bool:
        """Whether ``fault`` acts on this tool: a broken or loose tool is the one that cut the
        fault's hole; the workpiece's hardness and time-based faults act on every tool."""
        if self._numbers is None:
            return True
        if isinstance(fault, ToolBreakage):
            return fault.hole in self.holes
        if isinstance(fault, LooseTool) and fault.start_hole is not None:
            return fault.start_hole in self.holes
        return True

    def _faults(self, load: Any, ci: CuttingInput, hole: NDArray[np.int64],
                speed: NDArray[np.float64], progress: NDArray[np.float64] | None) -> Any:
        idx = [q for q, f in enumerate(self.faults) if self._acts_here(f)]
        if not idx:
            return load
        load, on = apply_faults([self.faults[q] for q in idx], load, time_s=ci.time_s,
                                hole=hole, speed_rpm=speed, hole_progress=progress,
                                rng=self.rng)
        for q, o in zip(idx, on, strict=True):
            if o is not None and self.onsets[q] is None:
                self.onsets[q] = o
        return load

    def _emit(self, ci: CuttingInput, load: Any, forces: dict[str, NDArray[np.float64]],
              truth: dict[str, NDArray[Any]], keep: NDArray[np.bool_]) -> CuttingOutput:
        if self.daq is not None:
            on = None
            if self.daq_off_blocks.size:
                on = ~np.isin(np.asarray(ci.block_index), self.daq_off_blocks)
            self.daq.feed(ci.time_s, np.vstack([load.fx_n, load.fy_n, load.thrust_n,
                                                load.torque_nm]), on)
        if self.progress is not None:
            self.progress(float(ci.time_s[-1]), ci.duration_s)
        if self.truth_out is not None:
            if keep.any():
                frame: dict[str, NDArray[Any]] = {"cycle": ci.cycle[keep]}
                for k, v in truth.items():
                    dtype = np.int32 if k == "hole" else np.float32
                    frame[k] = np.asarray(v)[keep].astype(dtype)
                self.truth_out.write(frame)
            truth = {}
        return CuttingOutput(spindle_torque_nm=load.torque_nm, force_n=forces,
                             truth={k: np.asarray(v, dtype=np.float64)
                                    for k, v in truth.items()})

    def hole_rows(self) -> list[dict[str, Any]]:
        """Per-hole truth, in hole order."""
        return [self.holes[k] for k in sorted(self.holes)]


class DrillingProcess(_Process):
    """Cutting hook for drilling (:func:`cnctwin.sim.cutting.drilling_load`).

    Per chunk: tool-tip depth below ``surface_z_mm`` from the expected actual Z position, feed
    per revolution from its velocity and the commanded speed, the hole number (a new hole at
    each entry at a new XY position), flank wear of that hole (:func:`flank_wear_um` of
    ``first_hole`` + holes drilled), hardness faults, the lumped tool-tip temperature (state
    carried across chunks), random fluctuation, lip ripple and drill walk, then the faults.
    Outputs: spindle load torque; forces ``Z1`` = thrust (pushes the tool up), ``X1``/``Y1`` =
    walk + rotating lateral force (hole-position deviations through the servo).

    Parameters
    ----------
    cfg : ScenarioConfig
        Drill, drilling model, wear curve, tool thermal model.
    material : Material
        Workpiece.
    feed_mm_per_rev, speed_rpm : float
        Programmed feed and speed (for the per-hole model torque in the truth).
    hole_depth_mm : float
        Programmed depth (progress of :class:`~cnctwin.sim.faults.ToolBreakage`) [mm].
    walk_direction_rad : float, default 0.7
        Direction of the static walk force in XY [rad] (lip asymmetry of this drill).
    initial_tool_temperature_c : float, optional
        Tool-tip temperature at the start [degC]; default the ambient temperature (cold tool).
    """

    def __init__(self, cfg: ScenarioConfig, *, material: Material, feed_mm_per_rev: float,
                 speed_rpm: float, hole_depth_mm: float, walk_direction_rad: float = 0.7,
                 initial_tool_temperature_c: float | None = None, **kw: Any) -> None:
        super().__init__(**kw)
        self.cfg = cfg
        self.material = material
        self.feed_mm_per_rev = feed_mm_per_rev
        self.speed_rpm = speed_rpm
        self.hole_depth_mm = hole_depth_mm
        self.walk_direction_rad = walk_direction_rad
        self.initial_temperature_c = (cfg.tool_thermal.ambient_temperature_c
                                      if initial_tool_temperature_c is None
                                      else float(initial_tool_temperature_c))
        self.temperature_c = self.initial_temperature_c
        self.holder_temperature_c = cfg.tool_thermal.ambient_temperature_c
        self._acc: dict[int, list[float]] = {}
        # chisel-edge skid direction per hole (uniform): own stream, drawn once per new hole
        self._dir_rng = np.random.default_rng(int(self.rng.integers(2**32)))
        self._entry_dir: dict[int, float] = {}

    def _entry_directions(self, hole: NDArray[np.int64]) -> NDArray[np.float64]:
        for h in np.unique(hole[hole >= 0]):
            if int(h) not in self._entry_dir:
                self._entry_dir[int(h)] = float(self._dir_rng.uniform(-math.pi, math.pi))
        out = np.zeros(hole.size)
        for h in np.unique(hole[hole >= 0]):
            out[hole == h] = self._entry_dir[int(h)]
        return out

    def __call__(self, ci: CuttingInput) -> CuttingOutput:
        cfg = self.cfg
        dt = ci.cycle_time_s
        z = ci.position["Z1"]
        vz = self._velocity("Z1", z, dt)
        n = ci.spindle_speed_rpm
        feed = np.where(vz < -1e-9, -vz * 60.0 / np.maximum(np.abs(n), 1.0), 0.0)
        depth = self.surface_z_mm - z
        hole = self._hole_index(depth, ci)
        own = self._tool_holes(hole)
        wear = np.where(own >= 0, flank_wear_um(np.maximum(own, 0), curve=cfg.wear), 0.0)
        hard = hardness_factor(self.faults, hole)
        angle = np.deg2rad(ci.spindle_pos_deg)
        kw: dict[str, Any] = {"drill": cfg.drill, "material": self.material, "wear_um": wear,
                              "hardness_factor": hard, "spindle_angle_rad": angle,
                              "model": cfg.drilling, "dt_s": dt}
        # tool temperature from the fault-free mean load (one pass, only where the tip is in
        # the material: outside it the load is exactly 0), then the load with it
        idx = np.flatnonzero(depth > 0.0)
        power = np.zeros(depth.size)
        if idx.size:
            sub = {**kw, "wear_um": wear[idx], "spindle_angle_rad": angle[idx],
                   "hardness_factor": np.broadcast_to(hard, depth.shape)[idx]}
            base = drilling_load(depth[idx], n[idx], feed[idx], rng=None, **sub)
            power[idx] = np.abs(base.torque_nm * n[idx]) * 2.0 * math.pi / 60.0
        if cfg.tool_thermal.two_node:
            temp, holder = tool_temperatures(power, dt_s=dt, thermal=cfg.tool_thermal,
                                             initial_c=self.temperature_c,
                                             initial_holder_c=self.holder_temperature_c)
            self.holder_temperature_c = float(holder[-1])
        else:
            temp = tool_temperature(power, dt_s=dt, thermal=cfg.tool_thermal,
                                    initial_c=self.temperature_c)
            holder = None
        self.temperature_c = float(temp[-1])
        load = drilling_load(depth, n, feed, rng=self.rng, tool_temperature_c=temp,
                             walk_direction_rad=self.walk_direction_rad,
                             entry_direction_rad=self._entry_directions(hole), **kw)
        load = self._faults(load, ci, hole, n,
                            self._hole_progress(depth, ci, self.hole_depth_mm))
        self._holes_update(ci, hole, depth, feed, load, temp, wear, hard, holder)
        truth = {"hole": hole, "tip_depth_mm": depth, "cutting_torque_nm": load.torque_nm,
                 "thrust_n": load.thrust_n, "fx_n": load.fx_n, "fy_n": load.fy_n,
                 "tool_temperature_c": temp, "wear_um": wear}
        keep = (depth > 0.0) | (load.torque_nm != 0.0)
        return self._emit(ci, load, {"X1": load.fx_n, "Y1": load.fy_n, "Z1": load.thrust_n},
                          truth, keep)

    def _holes_update(self, ci: CuttingInput, hole: NDArray[np.int64],
                      depth: NDArray[np.float64], feed: NDArray[np.float64], load: Any,
                      temp: NDArray[np.float64], wear: NDArray[np.float64],
                      hard: NDArray[np.float64], holder: NDArray[np.float64] | None) -> None:
        cone = self.cfg.drill.cone_length_mm
        for h in np.unique(hole[(hole >= 0) & (depth > 0.0)]):
            row = self.holes[int(h)]
            sel = (hole == h) & (depth > 0.0)
            idx = np.flatnonzero(sel)
            row["cut_last_cycle"] = int(ci.cycle[idx[-1]])
            row["extraction_s"] = float(ci.time_s[idx[-1]])
            row["tool_temperature_extraction_c"] = float(temp[idx[-1]])
            if holder is not None:  # the tool holder node (ToolThermal.two_node)
                row["tool_holder_temperature_extraction_c"] = float(holder[idx[-1]])
            row["tool_temperature_max_c"] = max(row.get("tool_temperature_max_c", -1e9),
                                                float(temp[sel].max()))
            full = sel & (depth >= cone) & (feed > 0.0)
            if full.any() and "full_engagement_first_cycle" not in row:
                row["full_engagement_first_cycle"] = int(ci.cycle[np.argmax(full)])
            acc = self._acc.setdefault(int(h), [0.0, 0.0, 0.0])
            acc[0] += float(load.torque_nm[full].sum())
            acc[1] += float(load.thrust_n[full].sum())
            acc[2] += float(full.sum())
            if acc[2]:
                row["mean_cutting_torque_nm"] = acc[0] / acc[2]
                row["mean_thrust_n"] = acc[1] / acc[2]
            w, hf = float(wear[idx[0]]), float(hard[idx[0]])
            row["wear_um"] = w
            row["hardness_factor"] = hf
            common: dict[str, Any] = {"drill": self.cfg.drill, "material": self.material,
                                      "wear_um": w,
                      "hardness_factor": hf, "model": self.cfg.drilling}
            row["model_torque_nm"] = float(drill_torque_nm(self.feed_mm_per_rev,
                                                           self.speed_rpm, **common))
            row["model_thrust_n"] = float(drill_thrust_n(self.feed_mm_per_rev,
                                                         self.speed_rpm, **common))
            row.update(self._quality_truth(int(h), row["model_thrust_n"], w))

    def _quality_truth(self, hole: int, thrust_n: float, wear_um: float) -> dict[str, float]:
        """Hidden hole-quality truth of one hole (forces and tool-tip geometry).

        Tool-tip values from the lateral forces and the drill's tip stiffness k
        (:attr:`~cnctwin.sim.tool.Drill.tip_stiffness_n_per_um`): the hole is started where the
        chisel-edge skid force pushes the free tip, e = F_entry,peak / k (position error);
        once the margins guide the drill the static walk shifts the axis by
        F_walk / (g k) (straightness, g = ``guided_stiffness_gain``) and the rotating force
        makes the tip orbit with F_rot / (g k) plus the radial run-out (hole oversize is twice
        the orbit radius). The sub-micrometre slide deviation (which the X/Y encoders see) is
        not included. Forces at full engagement with the programmed feed.
        """
        d, mdl = self.cfg.drill, self.cfg.drilling
        wear_rel = min(max(wear_um / mdl.walk_wear_ref_um, 0.0), 2.0)
        f_rot = float(rotating_force_n(thrust_n, self.feed_mm_per_rev, wear_um, drill=d,
                                       model=mdl))
        f_ent = mdl.entry_force_ratio * (1.0 + mdl.entry_wear_gain * wear_rel) * thrust_n
        f_walk = (mdl.walk_force_ratio_new + (mdl.walk_force_ratio_worn
                                              - mdl.walk_force_ratio_new) * wear_rel) * thrust_n
        k = d.tip_stiffness_n_per_um
        ang = self._entry_dir.get(hole, 0.0)
        e_um = f_ent / k
        orbit = d.radial_runout_um + f_rot / (d.guided_stiffness_gain * k)
        return {
            "entry_direction_rad": ang,
            "entry_force_peak_n": f_ent,
            "rotating_force_n": f_rot,
            "walk_force_n": f_walk,
            "lip_height_difference_um": float(lip_height_difference_um(wear_um, model=mdl)),
            "tip_position_error_x_um": e_um * math.cos(ang),
            "tip_position_error_y_um": e_um * math.sin(ang),
            "tip_position_error_um": e_um,
            "tip_straightness_um": f_walk / (d.guided_stiffness_gain * k),
            "tip_orbit_radius_um": orbit,
            "hole_oversize_um": 2.0 * orbit,
        }


class TappingProcess(_Process):
    """Cutting hook for rigid tapping (:func:`cnctwin.sim.cutting.tapping_load`).

    The spindle runs in position control coupled to Z (interpolator); the commanded speed is
    negative while the tap reverses out. Faults (e.g. :class:`~cnctwin.sim.faults.LooseTool`)
    act on the torque and on the axial force, which is the Z disturbance force;
    ``block_depths_mm`` (the cycles' thread depths) places a
    :class:`~cnctwin.sim.faults.ToolBreakage` at its depth fraction (without it the tap
    breaks on entering the next hole).
    """

    def __init__(self, cfg: ScenarioConfig, *, material: Material, **kw: Any) -> None:
        super().__init__(**kw)
        self.cfg = cfg
        self.material = material

    def __call__(self, ci: CuttingInput) -> CuttingOutput:
        z = ci.position["Z1"]
        depth = self.surface_z_mm - z
        n = ci.spindle_speed_rpm
        hole = self._hole_index(depth, ci)
        hard = hardness_factor(self.faults, hole)
        load = tapping_load(depth, n, tap=self.cfg.tap, material=self.material,
                            hardness_factor=hard)
        load = self._faults(load, ci, hole, n, self._hole_progress(depth, ci, None))
        for h in np.unique(hole[(hole >= 0) & (depth > 0.0)]):
            row = self.holes[int(h)]
            sel = (hole == h) & (depth > 0.0)
            row["cut_last_cycle"] = int(ci.cycle[np.flatnonzero(sel)[-1]])
            ext = sel & (n < 0.0)
            if ext.any():
                row.setdefault("extraction_first_cycle", int(ci.cycle[np.argmax(ext)]))
                row["extraction_last_cycle"] = int(ci.cycle[np.flatnonzero(ext)[-1]])
        truth = {"hole": hole, "tip_depth_mm": depth, "cutting_torque_nm": load.torque_nm,
                 "thrust_n": load.thrust_n}
        keep = (depth > 0.0) | (load.torque_nm != 0.0)
        return self._emit(ci, load, {"Z1": load.thrust_n}, truth, keep)


class MillingProcess(_Process):
    """Cutting hook for end milling (:func:`cnctwin.sim.cutting.milling_load`).

    Axial depth = ``surface_z_mm`` minus the expected actual Z; feed per tooth from the XY path
    speed and the commanded spindle speed; feed direction from the XY velocity; full slot
    (immersion 0..pi) unless ``entry_angle_rad``/``exit_angle_rad`` are given. Forces on the
    tool are the X1/Y1 disturbance forces (Z1: axial force).
    """

    def __init__(self, cfg: ScenarioConfig, *, material: Material,
                 entry_angle_rad: float = 0.0, exit_angle_rad: float = math.pi,
                 **kw: Any) -> None:
        super().__init__(**kw)
        self.cfg = cfg
        self.material = material
        self.entry_angle_rad = entry_angle_rad
        self.exit_angle_rad = exit_angle_rad
        self._direction = 0.0

    def __call__(self, ci: CuttingInput) -> CuttingOutput:
        dt = ci.cycle_time_s
        vx = self._velocity("X1", ci.position["X1"], dt)
        vy = self._velocity("Y1", ci.position["Y1"], dt)
        v_mm_min = np.hypot(vx, vy) * 60.0
        n = np.abs(ci.spindle_speed_rpm)
        flutes = self.cfg.end_mill.flutes
        c = np.where((n > 1.0) & (v_mm_min > 1e-3), v_mm_min / np.maximum(n, 1.0) / flutes, 0.0)
        moving = v_mm_min > 1e-3
        direction = np.where(moving, np.arctan2(vy, vx), np.nan)
        direction = pd.Series(direction).ffill().fillna(self._direction).to_numpy()
        self._direction = float(direction[-1])
        depth = np.maximum(self.surface_z_mm - ci.position["Z1"], 0.0)
        hole = np.zeros(depth.size, dtype=np.int64)
        hard = hardness_factor(self.faults, hole)
        load = milling_load(np.deg2rad(ci.spindle_pos_deg), c, depth, direction,
                            tool=self.cfg.end_mill, material=self.material,
                            entry_angle_rad=self.entry_angle_rad,
                            exit_angle_rad=self.exit_angle_rad, hardness_factor=hard)
        load = self._faults(load, ci, hole, ci.spindle_speed_rpm, None)
        truth = {"axial_depth_mm": depth, "feed_per_tooth_mm": c,
                 "cutting_torque_nm": load.torque_nm, "fx_n": load.fx_n, "fy_n": load.fy_n,
                 "axial_force_n": load.thrust_n}
        keep = depth > 0.0
        return self._emit(ci, load, {"X1": load.fx_n, "Y1": load.fy_n, "Z1": load.thrust_n},
                          truth, keep)


class _NoLoad(_Process):
    """Air cut: no process load; reports progress."""

    def __call__(self, ci: CuttingInput) -> CuttingOutput:
        if self.progress is not None:
            self.progress(float(ci.time_s[-1]), ci.duration_s)
        return CuttingOutput(spindle_torque_nm=np.zeros(len(ci)))


