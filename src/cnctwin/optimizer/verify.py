"""Simulate a program on the twin and check every limit the optimizer respects.

Checked on the simulated recording (what the drives would see) and its per-cycle truth:

* spindle S1 torque and power: the load over :data:`~cnctwin.sim.part.S1_WINDOW_S` (RMS
  torque, mean power; :func:`~cnctwin.sim.part.s1_load`) against the S1 curve at that speed
  (rated torque up to the base speed, rated power above); S1 is a thermal rating, so a short
  run-up above it is not a violation;
* spindle peak torque (current limit x Kt) and current (current limit), instantaneous;
* feed-axis current against each drive's current limit, instantaneous;
* chip thickness of each end mill (feed per tooth x sin(phi)_max of the engagement) against
  the tool table's ``max_chip_mm``.

Each violation names the program line of the block where it peaks.
"""

from __future__ import annotations

import math
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from cnctwin.engagement import Stock
from cnctwin.machine import MachineFile, ToolTable
from cnctwin.optimizer.constraints import Limits
from cnctwin.sim.gcode import Program
from cnctwin.sim.materials import MaterialSource
from cnctwin.sim.part import S1_WINDOW_S, block_lines, s1_load

__all__ = ["S1_WINDOW_S", "VerifyRun", "load_violations", "verify_run"]

@dataclass
class VerifyRun:
    """One simulated run of a program (what :func:`verify_run` returns).

    Attributes
    ----------
    cycle_time_s : float
        Simulated machine time [s].
    violations : list of dict
        ``line``, ``block``, ``limit``, ``value``, ``allowed``, ``time_s``.
    time_s : numpy.ndarray
        Time of each cycle [s].
    spindle_torque_nm : numpy.ndarray
        Spindle motor torque (``TORQUE``) [Nm].
    cutting_torque_nm : numpy.ndarray
        True cutting torque (the simulator's truth) [Nm].
    path_feed_mm_min : numpy.ndarray
        Path feed of X/Y/Z from the position set points [mm/min].
    line : numpy.ndarray of int
        Program line per cycle.
    result : Any
        The :class:`~cnctwin.sim.config.ScenarioResult`.
    """

    cycle_time_s: float
    violations: list[dict[str, Any]] = field(default_factory=list)
    time_s: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    spindle_torque_nm: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    cutting_torque_nm: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    path_feed_mm_min: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    line: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    result: Any = None


def load_violations(rec: Any, text: str, *, mfile: MachineFile, limits: Limits,
                    tool_peaks: dict[str, Any] | None = None
                    ) -> tuple[list[dict[str, Any]], NDArray[np.int64]]:
    """Every limit a simulated run exceeds, with the line where it peaks.

    Parameters
    ----------
    rec : Recording
        The simulated recording.
    text : str
        The program text (lines).
    mfile : MachineFile
        The machine.
    limits : Limits
        Spindle S1 curve and peak torque.
    tool_peaks : dict, optional
        The simulation's ``limits["tools"]`` (peak chip thickness per end mill and its
        limit, from :func:`cnctwin.sim.part.part_program`).

    Returns
    -------
    violations : list of dict
    line : numpy.ndarray of int
        Program line per cycle.
    """
    m = mfile.machine
    sp = m.spindle_name
    line = block_lines(rec, text).per_cycle(rec.cycles)
    t = np.asarray(rec.time_s, dtype=np.float64)
    win = round(S1_WINDOW_S / m.cycle_time_s)
    out: list[dict[str, Any]] = []

    def add(i: int, limit: str, value: float, allowed: float) -> None:
        out.append({"line": int(line[i]), "block": text.splitlines()[line[i] - 1].strip()
                    if 0 < line[i] <= len(text.splitlines()) else "", "limit": limit,
                    "value": float(value), "allowed": float(allowed), "time_s": float(t[i])})

    torque = np.abs(rec.signal("TORQUE", sp).to_numpy(dtype=np.float64))
    speed = np.abs(rec.signal("CMD_SPEED", sp).to_numpy(dtype=np.float64))
    tq_mean = s1_load(torque, window_cycles=win, rms=True)
    n_mean = s1_load(speed, window_cycles=win, rms=False)
    s1 = limits.s1_torque_nm(n_mean)
    i = int(np.argmax(tq_mean - s1))
    if tq_mean[i] > s1[i] * 1.001:
        add(i, "spindle S1 torque", tq_mean[i], s1[i])
    if rec.has("POWER", sp):
        pw = s1_load(np.abs(rec.signal("POWER", sp).to_numpy(dtype=np.float64)),
                     window_cycles=win, rms=False)
        i = int(np.argmax(pw))
        if pw[i] > limits.s1_power_w * 1.001:
            add(i, "spindle S1 power", pw[i], limits.s1_power_w)
    i = int(np.nanargmax(torque))
    if torque[i] > limits.peak_torque_nm * 1.001:
        add(i, "spindle peak torque", torque[i], limits.peak_torque_nm)
    cur = np.abs(rec.signal("CURRENT", sp).to_numpy(dtype=np.float64))
    i = int(np.nanargmax(cur))
    if cur[i] > m.spindle.current_limit_a * 1.001:
        add(i, "spindle current", cur[i], m.spindle.current_limit_a)
    for ax in m.axes:
        if not rec.has("CURRENT", ax.name):
            continue
        c = np.abs(rec.signal("CURRENT", ax.name).to_numpy(dtype=np.float64))
        i = int(np.nanargmax(c))
        if c[i] > ax.current_limit_a * 1.001:
            add(i, f"{ax.name} current", c[i], ax.current_limit_a)
    for tname, tv in (tool_peaks or {}).items():
        chip = tv["chip_mm"]
        if chip["limit"] is not None and chip["peak"] > chip["limit"] * 1.001:
            out.append({"line": chip["line"], "block": chip["block"] or "",
                        "limit": f"{tname} chip thickness", "value": float(chip["peak"]),
                        "allowed": float(chip["limit"]), "time_s": math.nan})
    return out, line


def verify_run(program: Program, mfile: MachineFile, material: MaterialSource,
               tools: ToolTable, stock: Stock, *, limits: Limits, seed: int = 0,
               progress: Any = None) -> VerifyRun:
    """Simulate a program on the machine and check its loads.

    Parameters
    ----------
    program : Program
        The program (its ``text`` is simulated).
    mfile : MachineFile
        The machine.
    material : MaterialSource
        Workpiece material.
    tools : ToolTable
        Tool table.
    stock : Stock
        Raw part.
    limits : Limits
        Limits to check.
    seed : int, default 0
        Seed of the simulation.
    progress : callable, optional
        Called with (fraction 0..1, message).

    Returns
    -------
    VerifyRun
    """
    from cnctwin.sim.part import part_program

    with tempfile.TemporaryDirectory(prefix="cnctwin-opt-") as tmp:
        p = Path(tmp) / f"{program.name}.mpf"
        p.write_text(program.text, encoding="utf-8")
        res = part_program(None, program=p, seed=seed, machine=mfile.machine,
                           material=material.material, tools=tools, stock=stock,
                           progress=progress)
    rec = res.recording
    per_cycle = pd.concat(res.per_cycle) if res.per_cycle else None
    viol, line = load_violations(rec, program.text, mfile=mfile, limits=limits,
                                 tool_peaks=res.truth["limits"].get("tools"))
    cyc = np.asarray(rec.cycles, dtype=np.int64)
    ct = np.zeros(cyc.size)
    if per_cycle is not None and "cutting_torque_nm" in per_cycle:
        ct = np.nan_to_num(per_cycle["cutting_torque_nm"].reindex(pd.Index(cyc)).to_numpy(
            dtype=np.float64))
    dt = mfile.machine.cycle_time_s
    pos = [rec.signal("DES_POS", a).to_numpy(dtype=np.float64) for a in ("X1", "Y1", "Z1")
           if rec.has("DES_POS", a)]
    v = np.zeros(cyc.size)
    if pos and cyc.size > 1:
        d = np.sqrt(sum(np.diff(x, prepend=x[0]) ** 2 for x in pos))
        v = d / dt * 60.0
    return VerifyRun(cycle_time_s=float(res.truth["limits"]["cycle_time_s"]), violations=viol,
                     time_s=np.asarray(rec.time_s, dtype=np.float64),
                     spindle_torque_nm=rec.signal("TORQUE", mfile.machine.spindle_name
                                                  ).to_numpy(dtype=np.float64),
                     cutting_torque_nm=ct, path_feed_mm_min=v, line=line, result=res)
