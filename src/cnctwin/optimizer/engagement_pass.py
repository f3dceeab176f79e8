"""The program's engagement along its path: interpolate it and sweep the stock, no drives.

The engagement (entry and exit angle, axial depth) depends on where the tool goes, not on
how fast, so one pass of the interpolator over the programmed program and of each tool
through the Z-map gives it for every control cycle; the feed limits
(:func:`cnctwin.optimizer.constraints.feed_limits`) then scale with the feed analytically.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from cnctwin.engagement import Stock, ZMap, runs_of
from cnctwin.machine import Machine, ToolTable
from cnctwin.sim.gcode import Program
from cnctwin.sim.simulation import iter_chunks

__all__ = ["EngagementTrace", "engagement_pass"]


@dataclass(frozen=True)
class EngagementTrace:
    """Per control cycle of the programmed run (what :func:`engagement_pass` returns).

    Attributes
    ----------
    block_index : numpy.ndarray of int
        Executing block.
    tool : numpy.ndarray of int
        Active tool.
    x_mm, y_mm, z_mm : numpy.ndarray
        Tool position set point [mm].
    speed_rpm : numpy.ndarray
        Commanded spindle speed [rpm].
    path_feed_mm_min : numpy.ndarray
        Path velocity of the interpolator [mm/min].
    entry_rad, exit_rad, axial_depth_mm : numpy.ndarray
        Engagement of an end mill (NaN / 0 for drills, taps and air).
    removed_mm3 : numpy.ndarray
        Volume removed per cycle [mm^3].
    cycle_time_s : float
        Control cycle [s].
    seconds_per_cycle_of_work : float
        Wall time the pass took per control cycle [s] (the engagement model's speed).
    """

    block_index: NDArray[np.int64]
    tool: NDArray[np.int64]
    x_mm: NDArray[np.float64]
    y_mm: NDArray[np.float64]
    z_mm: NDArray[np.float64]
    speed_rpm: NDArray[np.float64]
    path_feed_mm_min: NDArray[np.float64]
    entry_rad: NDArray[np.float64]
    exit_rad: NDArray[np.float64]
    axial_depth_mm: NDArray[np.float64]
    removed_mm3: NDArray[np.float64]
    cycle_time_s: float
    seconds_per_cycle_of_work: float

    def __len__(self) -> int:
        return int(self.block_index.size)

    @property
    def duration_s(self) -> float:
        """Machine time of the program as interpolated [s]."""
        return len(self) * self.cycle_time_s


def engagement_pass(program: Program, machine: Machine, tools: ToolTable, stock: Stock, *,
                    chunk_cycles: int = 200_000,
                    progress: Callable[[float, str], None] | None = None) -> EngagementTrace:
    """Interpolate a program and sweep every tool through the stock.

    Parameters
    ----------
    program : Program
        Parsed program.
    machine : Machine
        Its axis and spindle limits plan the motion.
    tools : ToolTable
        Diameters and kinds.
    stock : Stock
        Raw part.
    chunk_cycles : int, default 200000
        Cycles interpolated per chunk.
    progress : callable, optional
        Called with (fraction 0..1, message).

    Returns
    -------
    EngagementTrace
    """
    import time

    t0 = time.perf_counter()
    zmap = ZMap(stock)
    cols: dict[str, list[NDArray[np.float64]]] = {k: [] for k in (
        "block", "tool", "x", "y", "z", "n", "v", "e0", "e1", "a", "vol")}
    x_name, y_name, z_name = "X1", "Y1", "Z1"
    for traj in iter_chunks(program, machine, chunk_cycles):
        x = traj.des_pos[x_name]
        y = traj.des_pos[y_name]
        zz = traj.des_pos[z_name]
        tool = np.asarray(traj.tool, dtype=np.int64)
        nn = x.size
        e0 = np.full(nn, np.nan)
        e1 = np.full(nn, np.nan)
        a = np.zeros(nn)
        vol = np.zeros(nn)
        for t, lo, hi in runs_of(tool):
            if t not in tools:
                continue
            spec = tools.get(t)
            eng = zmap.sweep(x[lo:hi], y[lo:hi], zz[lo:hi], diameter_mm=spec.diameter_mm)
            vol[lo:hi] = eng.removed_mm3
            if spec.kind == "end_mill":
                e0[lo:hi] = eng.entry_rad
                e1[lo:hi] = eng.exit_rad
                a[lo:hi] = eng.axial_depth_mm
        for key, val in (("block", traj.block_index), ("tool", tool), ("x", x), ("y", y),
                         ("z", zz), ("n", traj.spindle_speed_cmd_rpm),
                         ("v", traj.path_velocity_mm_min), ("e0", e0), ("e1", e1), ("a", a),
                         ("vol", vol)):
            cols[key].append(np.asarray(val))
        if progress is not None and math.isfinite(traj.duration_s) and traj.duration_s > 0:
            done = (traj.first_cycle + nn) * traj.cycle_time_s / traj.duration_s
            progress(min(done, 1.0), "engagement")
    cat = {k: (np.concatenate(v) if v else np.zeros(0)) for k, v in cols.items()}
    n_cyc = max(int(cat["block"].size), 1)
    return EngagementTrace(
        block_index=cat["block"].astype(np.int64), tool=cat["tool"].astype(np.int64),
        x_mm=cat["x"], y_mm=cat["y"], z_mm=cat["z"], speed_rpm=cat["n"],
        path_feed_mm_min=cat["v"], entry_rad=cat["e0"], exit_rad=cat["e1"],
        axial_depth_mm=cat["a"], removed_mm3=cat["vol"], cycle_time_s=machine.cycle_time_s,
        seconds_per_cycle_of_work=(time.perf_counter() - t0) / n_cyc)
