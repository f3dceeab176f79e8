"""Cutting through a stock: the tool table decides the process, the Z-map the engagement.

:class:`StockMillingProcess` mills with the engagement the Z-map gives per cycle (a second
pass over cut material cuts air, a side step cuts at partial immersion);
:class:`ToolDispatch` hands each run of cycles to the hook of the active tool (drill, tap,
end mill; no tool or an unknown one cuts air), so a program that mills and drills simulates
both. Drills and taps remove their diameter from the Z-map too, so a later pass sees the
hole.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from cnctwin.engagement import ZMap, runs_of
from cnctwin.sim.config import ScenarioConfig
from cnctwin.sim.cutting import Material, cycle_mean_milling_load, max_chip_factor
from cnctwin.sim.faults import hardness_factor
from cnctwin.sim.processes import _Process, _Progress
from cnctwin.sim.simulation import CuttingInput, CuttingOutput
from cnctwin.sim.tool import EndMill

__all__ = ["StockMillingProcess", "ToolDispatch", "kinds_from_program", "slice_input"]

CuttingHookFn = Callable[[CuttingInput], CuttingOutput]


def slice_input(ci: CuttingInput, lo: int, hi: int) -> CuttingInput:
    """Cycles ``lo:hi`` of a hook input (every per-cycle array sliced).

    Parameters
    ----------
    ci : CuttingInput
        One chunk's hook input.
    lo, hi : int
        First and one-past-last cycle index within the chunk.

    Returns
    -------
    CuttingInput
        Views of the arrays (no copies).
    """
    return dataclasses.replace(
        ci, cycle=ci.cycle[lo:hi], offset=ci.offset[lo:hi], time_s=ci.time_s[lo:hi],
        des_pos={k: v[lo:hi] for k, v in ci.des_pos.items()},
        position={k: v[lo:hi] for k, v in ci.position.items()},
        spindle_speed_rpm=ci.spindle_speed_rpm[lo:hi], spindle_pos_deg=ci.spindle_pos_deg[lo:hi],
        spindle_mode=ci.spindle_mode[lo:hi], tool=ci.tool[lo:hi],
        block_index=ci.block_index[lo:hi])


class StockMillingProcess(_Process):
    """End milling through a Z-map: engagement per cycle from the stock, removal as it cuts.

    Feed per tooth from the XY speed of the expected actual position and the commanded
    spindle speed; entry/exit angles, axial depth and feed direction from
    :meth:`cnctwin.engagement.ZMap.sweep`; forces from
    :func:`~cnctwin.sim.cutting.milling_load` integrated over each cycle's rotation
    (:func:`~cnctwin.sim.cutting.cycle_mean_milling_load`). An end mill moving only down
    into material (a plunge: no XY feed) is swept (the material goes) but has no load
    model: its cycles are counted in :attr:`plunge_cycles` and flagged in the truth
    (``plunge_depth_mm``).
    """

    def __init__(self, cfg: ScenarioConfig, *, material: Material, zmap: ZMap, tool: EndMill,
                 hardness_along_x: tuple[tuple[float, float], ...] = (),
                 break_at_x_mm: float | None = None, **kw: Any) -> None:
        super().__init__(**kw)
        self.cfg = cfg
        self.material = material
        self.zmap = zmap
        self.tool = tool
        self.hardness_along_x = tuple(sorted((float(x), float(f)) for x, f in hardness_along_x))
        self.break_at_x_mm = break_at_x_mm
        self.broken_cycle: int | None = None
        self.plunge_cycles = 0
        self.peak_chip_mm = 0.0
        self.peak_chip_cycle: int | None = None

    def __call__(self, ci: CuttingInput) -> CuttingOutput:
        dt = ci.cycle_time_s
        x, y, z = ci.position["X1"], ci.position["Y1"], ci.position["Z1"]
        vx = self._velocity("X1", x, dt)
        vy = self._velocity("Y1", y, dt)
        eng = self.zmap.sweep(x, y, z, diameter_mm=self.tool.diameter_mm)
        v_mm_min = np.hypot(vx, vy) * 60.0
        n = np.abs(ci.spindle_speed_rpm)
        c = np.where((n > 1.0) & (v_mm_min > 1e-3),
                     v_mm_min / np.maximum(n, 1.0) / self.tool.flutes, 0.0)
        hard = np.broadcast_to(hardness_factor(self.faults, np.zeros(len(ci), dtype=np.int64)),
                               (len(ci),)).astype(np.float64)
        if self.hardness_along_x:  # hidden hardness steps along the part: factor from X on
            xs = np.array([p[0] for p in self.hardness_along_x])
            fs = np.array([p[1] for p in self.hardness_along_x])
            k = np.searchsorted(xs, x, side="right") - 1
            hard = hard * np.where(k >= 0, fs[np.maximum(k, 0)], 1.0)
        step = np.abs(ci.spindle_speed_rpm) / 60.0 * 2.0 * np.pi * dt
        load = cycle_mean_milling_load(
            np.deg2rad(ci.spindle_pos_deg), step, c, eng.axial_depth_mm,
            eng.feed_direction_rad, tool=self.tool, material=self.material,
            entry_angle_rad=eng.entry_rad, exit_angle_rad=eng.exit_rad, hardness_factor=hard)
        if self.break_at_x_mm is not None:  # the cutter breaks: from there on it cuts nothing
            gone = (x >= self.break_at_x_mm) | (self.broken_cycle is not None)
            if gone.any() and self.broken_cycle is None:
                self.broken_cycle = int(ci.cycle[int(np.argmax(gone))])
            if gone.any():
                for arr in (load.torque_nm, load.fx_n, load.fy_n, load.thrust_n):
                    arr[gone] = 0.0
        chip = np.where(eng.engaged, c * max_chip_factor(eng.entry_rad, eng.exit_rad), 0.0)
        if chip.size and chip.max() > self.peak_chip_mm:
            j = int(np.argmax(chip))
            self.peak_chip_mm, self.peak_chip_cycle = float(chip[j]), int(ci.cycle[j])
        plunge = np.where(c <= 0.0, eng.center_depth_mm, 0.0)  # no XY feed: no milling load
        self.plunge_cycles += int(np.count_nonzero(plunge > 0.0))
        truth = {"axial_depth_mm": eng.axial_depth_mm, "feed_per_tooth_mm": c,
                 "entry_angle_rad": eng.entry_rad, "exit_angle_rad": eng.exit_rad,
                 "radial_immersion": eng.radial_fraction, "removed_mm3": eng.removed_mm3,
                 "plunge_depth_mm": plunge, "cutting_torque_nm": load.torque_nm,
                 "hardness_factor": hard,
                 "fx_n": load.fx_n, "fy_n": load.fy_n, "axial_force_n": load.thrust_n}
        keep = eng.engaged | (plunge > 0.0)
        return self._emit(ci, load, {"X1": load.fx_n, "Y1": load.fy_n, "Z1": load.thrust_n},
                          truth, keep)


class ToolDispatch:
    """Cutting hook that hands each run of cycles to the active tool's hook.

    Parameters
    ----------
    hooks : mapping
        T number -> cutting hook; a tool without one (T0, or a tool that only moves in air)
        gets no load.
    sweeps : mapping, optional
        T number -> ``(zmap, diameter_mm)`` to remove the tool's material from the Z-map
        while its own hook does not (drills, taps).
    progress : callable, optional
        Progress reporter (called once per chunk).
    """

    def __init__(self, hooks: Mapping[int, CuttingHookFn], *,
                 sweeps: Mapping[int, tuple[ZMap, float]] | None = None,
                 progress: _Progress | None = None) -> None:
        self.hooks = dict(hooks)
        self.sweeps = dict(sweeps or {})
        self.progress = progress

    def __call__(self, ci: CuttingInput) -> CuttingOutput:
        n = len(ci)
        tool = np.asarray(ci.tool, dtype=np.int64)
        torque = np.zeros(n)
        forces: dict[str, NDArray[np.float64]] = {}
        truths: list[pd.DataFrame] = []
        for t, lo, hi in runs_of(tool):
            hook = self.hooks.get(t)
            if t in self.sweeps:
                zmap, dia = self.sweeps[t]
                zmap.sweep(ci.position["X1"][lo:hi], ci.position["Y1"][lo:hi],
                           ci.position["Z1"][lo:hi], diameter_mm=dia)
            if hook is None:
                continue
            out = hook(slice_input(ci, int(lo), int(hi)))
            torque[lo:hi] = out.spindle_torque_nm
            for ax, f in out.force_n.items():
                forces.setdefault(ax, np.zeros(n))[lo:hi] = f
            if out.truth:
                frame = pd.DataFrame({k: np.broadcast_to(np.asarray(v, dtype=np.float64),
                                                         (hi - lo,))
                                      for k, v in out.truth.items()},
                                     index=pd.RangeIndex(int(lo), int(hi)))
                truths.append(frame)
        if self.progress is not None:
            self.progress(float(ci.time_s[-1]), ci.duration_s)
        truth: dict[str, NDArray[np.float64]] = {}
        if truths:
            tab = pd.concat(truths).reindex(pd.RangeIndex(n))
            truth = {str(k): tab[k].to_numpy(dtype=np.float64) for k in tab.columns}
            truth["tool"] = tool.astype(np.float64)
        return CuttingOutput(spindle_torque_nm=torque, force_n=forces, truth=truth)


def kinds_from_program(blocks: Any) -> dict[int, str]:
    """Tool kinds a program implies without a tool table: drilling/tapping cycles or milling.

    Parameters
    ----------
    blocks : sequence of Block
        Parsed program blocks.

    Returns
    -------
    dict
        T number -> ``"drill"``, ``"tap"`` or ``"end_mill"`` (a tool that runs a drilling cycle
        is a drill, a tapping cycle a tap; any other tool that moves at feed mills).
    """
    kinds: dict[int, str] = {}
    moving: set[int] = set()
    active = 0
    for b in blocks:
        if b.tool_change and b.tool is not None:
            active = int(b.tool)
        if b.kind == "drill_cycle":
            kinds[active] = "drill"
        elif b.kind == "tap_cycle":
            kinds.setdefault(active, "tap")
        elif b.kind in ("linear", "arc_cw", "arc_ccw"):
            moving.add(active)
    for t in moving:
        kinds.setdefault(t, "end_mill")
    return kinds
