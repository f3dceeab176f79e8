"""Any user part program on a machine description (``cnctwin simulate --program``), and the
check of its peak loads against the drives' limits."""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from cnctwin.engagement import Stock, ZMap
from cnctwin.exceptions import ConfigError, GCodeError
from cnctwin.machine.tooltable import ToolTable
from cnctwin.recording import Recording
from cnctwin.sim.config import (
    START_CYCLE,
    START_TIME,
    ProgressFn,
    ScenarioConfig,
    ScenarioResult,
)
from cnctwin.sim.cutting import Material
from cnctwin.sim.faults import Fault, fault_to_dict
from cnctwin.sim.gcode import Program, parse_program
from cnctwin.sim.machine import Machine
from cnctwin.sim.processes import (
    DrillingProcess,
    HoleNumbers,
    MillingProcess,
    TappingProcess,
    _NoLoad,
    _Progress,
)
from cnctwin.sim.runner import (
    _base_truth,
    _collect,
    _faults_from,
    _make_sink,
    _prepare,
    _write_program,
    _write_truth,
)
from cnctwin.sim.simulation import simulate
from cnctwin.sim.stockcut import StockMillingProcess, ToolDispatch

__all__ = ["PART_KEYS", "S1_WINDOW_S", "BlockLines", "LiveOverride", "block_lines",
           "drive_limits_check", "part_program", "s1_load"]


PART_KEYS = {"part.hardness_along_x": "hidden hardness steps along X: [[x_mm, factor], ...] "
                                      "(the factor applies from x_mm on)",
             "part.break_at_x_mm": "the end mill breaks when it passes this X [mm]"}
"""``--set`` keys of a part program's hidden workpiece and tool (end mills on a stock)."""


@dataclass
class LiveOverride:
    """A control that plays the program at a feed override decided while it runs.

    Attributes
    ----------
    requested : callable
        ``requested() -> float | None``: the override to apply next [%] (the PLC's value
        after its heartbeat check and clamp), asked before each chunk; None stops the
        program there (a stop or feed-hold request the control obeyed).
    chunk_cycles : int, default 10
        Control cycles per chunk (10 = 20 ms: how often the override is read).
    tee : object, optional
        A second sink that sees every recorded chunk as it is simulated (e.g. a real-time
        OPC UA server); ``open``, ``write``, ``close`` as a recorder sink.
    rate_pct_per_s : float, default 200
        The control's override ramp [%/s].
    log : list
        Filled per chunk: ``cycle``, ``requested_pct``, ``applied_pct`` (mean),
        ``cutting_torque_nm`` and ``hardness_factor`` (hidden truth, mean over the chunk),
        ``speed_rpm`` (commanded), ``tool``.
    """

    requested: Any
    chunk_cycles: int = 10
    tee: Any = None
    rate_pct_per_s: float = 200.0
    log: list[dict[str, Any]] = dataclasses.field(default_factory=list)


_DRILL_WORDS = ("CYCLE81", "CYCLE82", "CYCLE83", "G81", "G82", "G83")


@dataclass(frozen=True)
class BlockLines:
    """Which program line (and block text) runs in a cycle, from a recording's block events.

    Attributes
    ----------
    cycles : numpy.ndarray of int64
        First cycle of each block event, sorted.
    lines : numpy.ndarray of int64
        1-based program line of each (from the byte offset ``seek_offset``).
    blocks : list of str
        The block text of each (``gcode``).
    """

    cycles: NDArray[np.int64]
    lines: NDArray[np.int64]
    blocks: list[str]

    def at(self, cycle: int) -> tuple[int | None, str | None]:
        """The line and block text executing in ``cycle`` (None before the first block)."""
        k = int(np.searchsorted(self.cycles, int(cycle), side="right")) - 1
        return (None, None) if k < 0 else (int(self.lines[k]), self.blocks[k])

    def per_cycle(self, cycles: NDArray[np.int64]) -> NDArray[np.int64]:
        """The line per cycle (0 before the first block)."""
        k = np.searchsorted(self.cycles, np.asarray(cycles, dtype=np.int64), side="right") - 1
        if self.lines.size == 0:
            return np.zeros(k.size, dtype=np.int64)
        return np.where(k >= 0, self.lines[np.maximum(k, 0)], 0)


def block_lines(rec: Recording, program_text: str) -> BlockLines:
    """The :class:`BlockLines` of a recording of ``program_text``.

    Parameters
    ----------
    rec : Recording
        Its block events (``cycle``, ``seek_offset``, ``gcode``).
    program_text : str
        The program (line numbers from the byte offsets).

    Returns
    -------
    BlockLines
    """
    blocks = rec.events[rec.events["kind"] == "block"].sort_values("cycle", kind="stable")
    data = program_text.encode("utf-8")
    offs = blocks["seek_offset"].to_numpy(dtype=np.int64)
    return BlockLines(cycles=blocks["cycle"].to_numpy(dtype=np.int64),
                      lines=np.array([data[: max(int(o), 0)].count(b"\n") + 1 for o in offs],
                                     dtype=np.int64),
                      blocks=[str(g) for g in blocks["gcode"]])


S1_WINDOW_S = 10.0
"""Averaging window of the S1 (thermal) checks [s]. [E] a motor spindle's thermal time
constant is minutes; 10 s is conservative for the blocks of a part program."""


def s1_load(v: NDArray[np.float64], *, window_cycles: int, rms: bool) -> NDArray[np.float64]:
    """Load over the trailing S1 window: mean (power) or root mean square (current, torque).

    Parameters
    ----------
    v : numpy.ndarray
        Instantaneous load per cycle (NaN counts as 0).
    window_cycles : int
        Window length [cycles]; before the program starts the load counts as 0 (idle), so
        a program shorter than the window is averaged over the whole window.
    rms : bool
        Root mean square (the copper losses of current and torque) instead of the mean.

    Returns
    -------
    numpy.ndarray
        Same length as ``v``.
    """
    x = np.nan_to_num(np.asarray(v, dtype=np.float64))
    if x.size == 0:
        return x
    n = max(1, int(window_cycles))
    y = x * x if rms else x
    c = np.concatenate([np.zeros(n), np.cumsum(y)])
    out = (c[n:] - c[:-n]) / n
    return np.sqrt(np.maximum(out, 0.0)) if rms else out


def drive_limits_check(rec: Recording, machine: Machine, program_text: str) -> dict[str, Any]:
    """Spindle and axis loads of a simulated program against the drives' limits.

    Parameters
    ----------
    rec : Recording
        The simulated recording (CURRENT, TORQUE, POWER per axis; block events).
    machine : Machine
        Its description (current limits, rated torque and current, base speed).
    program_text : str
        The program (to name the line of the block where a limit is exceeded).

    Returns
    -------
    dict
        ``cycle_time_s``; ``spindle``: per quantity (``torque_nm``, ``power_w``,
        ``current_a``) the instantaneous ``peak`` and the ``s1`` load (the largest
        :func:`s1_load` over :data:`S1_WINDOW_S`: RMS of current and torque, mean power),
        each with its ``limit`` and the line and block where it occurs;
        ``limits``; per feed axis the peak current; ``warnings``: one line per exceeded
        limit naming the program line and block.

    Notes
    -----
    Ratings are compared with what they rate: the S1 (continuous, thermal) torque, current
    and power ``rated torque x base speed`` with the load over :data:`S1_WINDOW_S`
    (:func:`s1_load`; a run-up that needs more than the rated torque for a few hundred
    milliseconds is within the drive's rating), the peak torque (current limit x Kt) and the
    current limit with the instantaneous values; the feed drives' current limit with the
    instantaneous current.
    """
    sp = machine.spindle
    name = machine.spindle_name
    bl = block_lines(rec, program_text)

    def where(idx: int) -> dict[str, Any]:
        cyc = int(rec.cycles[idx])
        line, block = bl.at(cyc)
        return {"cycle": cyc, "time_s": float(rec.time_s[idx]), "line": line, "block": block}

    p_s1 = sp.rated_torque_nm * sp.base_speed_rpm * 2.0 * math.pi / 60.0
    t_peak = sp.current_limit_a * sp.kt_nm_per_a
    out: dict[str, Any] = {"cycle_time_s": float(rec.n_cycles * machine.cycle_time_s),
                           "spindle": {}, "axes": {}, "warnings": [],
                           "limits": {"spindle_current_limit_a": sp.current_limit_a,
                                      "spindle_rated_current_a": sp.rated_current_a,
                                      "spindle_rated_torque_nm": sp.rated_torque_nm,
                                      "spindle_peak_torque_nm": t_peak,
                                      "spindle_s1_power_w": p_s1,
                                      "s1_window_s": S1_WINDOW_S}}
    win = round(S1_WINDOW_S / machine.cycle_time_s)
    checks = [("CURRENT", "current_a", sp.current_limit_a, "current limit", sp.rated_current_a,
               "rated (S1) current", "A"),
              ("TORQUE", "torque_nm", t_peak, "peak torque", sp.rated_torque_nm,
               "rated (S1) torque", "Nm"),
              ("POWER", "power_w", None, "", p_s1, "S1 power", "W")]
    for code, key, peak_lim, peak_what, s1_lim, s1_what, unit in checks:
        if not rec.has(code, name):
            continue
        v = np.abs(rec.signal(code, name).to_numpy(dtype=np.float64))
        if not np.isfinite(v).any():
            continue
        i = int(np.nanargmax(v))
        mean = s1_load(v, window_cycles=win, rms=code != "POWER")
        j = int(np.argmax(mean))
        out["spindle"][key] = {"peak": float(v[i]), **where(i), "limit": peak_lim,
                               "s1": {"mean": float(mean[j]), "limit": s1_lim,
                                      "window_s": S1_WINDOW_S, **where(j)}}
        what = key.rsplit("_", 1)[0]
        if peak_lim is not None and v[i] > peak_lim:
            w = where(i)
            out["warnings"].append(
                f"line {w['line']} ({w['block']}): spindle {what} {v[i]:.4g} {unit} exceeds "
                f"the {peak_what} {peak_lim:.4g} {unit} at t = {w['time_s']:.2f} s")
        if mean[j] > s1_lim:
            w = where(j)
            out["warnings"].append(
                f"line {w['line']} ({w['block']}): spindle {what} over "
                f"{S1_WINDOW_S:g} s {mean[j]:.4g} {unit} exceeds the {s1_what} {s1_lim:.4g} "
                f"{unit} at t = {w['time_s']:.2f} s")
    for ax in machine.axes:
        if not rec.has("CURRENT", ax.name):
            continue
        v = np.abs(rec.signal("CURRENT", ax.name).to_numpy(dtype=np.float64))
        if not np.isfinite(v).any():
            continue
        i = int(np.nanargmax(v))
        out["axes"][ax.name] = {"current_a": {"peak": float(v[i]), **where(i)},
                                "current_limit_a": ax.current_limit_a}
        if v[i] > ax.current_limit_a:
            w = where(i)
            out["warnings"].append(
                f"line {w['line']} ({w['block']}): {ax.name} current {v[i]:.4g} A exceeds the "
                f"current limit {ax.current_limit_a:.4g} A at t = {w['time_s']:.2f} s")
    return out


def _chip_check(lim: dict[str, Any], hook: ToolDispatch, rec: Recording,
                tools: ToolTable | None, text: str) -> None:
    """Peak chip thickness of each end mill (feed per tooth x sin(phi)_max) vs its limit."""
    bl = block_lines(rec, text)
    out = lim.setdefault("tools", {})
    for t, h in sorted(hook.hooks.items()):
        if not isinstance(h, StockMillingProcess) or h.peak_chip_cycle is None:
            continue
        spec = tools.tools.get(t) if tools is not None else None
        limit = spec.max_chip_mm if spec is not None else None
        line, block = bl.at(h.peak_chip_cycle)
        out[f"T{t}"] = {"chip_mm": {"peak": h.peak_chip_mm, "limit": limit, "line": line,
                                    "block": block}}
        if limit is not None and h.peak_chip_mm > limit:
            lim["warnings"].append(
                f"line {line} ({block}): T{t} chip thickness {h.peak_chip_mm:.4g} mm exceeds "
                f"the tool's max_chip_mm {limit:.4g} mm")


def _check_tools(prog: Program, tools: ToolTable, path: Path) -> None:
    """Every T the program selects is in the table (the error names the line)."""
    for b in prog.blocks:
        if b.tool is not None and b.tool != 0 and "T" in b.words:
            try:
                tools.get(int(b.tool), line=b.line, text=b.text)
            except ConfigError as exc:
                raise ConfigError(f"{path}: {exc}") from None


def _milling_in_drilling(prog: Program, surface_z_mm: float) -> list[str]:
    """Lines of a drilling program (no tool table) that move in XY below the surface."""
    out = []
    for b in prog.blocks:
        if b.kind not in ("linear", "arc_cw", "arc_ccw"):
            continue
        z0 = b.start.get("Z", math.inf)
        z1 = b.target.get("Z", z0)
        moves_xy = any(abs(b.target.get(a, b.start.get(a, 0.0)) - b.start.get(a, 0.0)) > 1e-9
                       for a in ("X", "Y"))
        if moves_xy and min(z0, z1) < surface_z_mm:
            out.append(f"line {b.line} ({b.text.strip()}): moves in XY below the surface in a "
                       "drilling program; without --tools it is simulated without a milling "
                       "load (give a tool table to mill it)")
    return out


def _drill_conditions(prog: Program, tool: int) -> tuple[float, float, float]:
    """Feed [mm/rev], speed [rpm] and depth [mm] of a drill's first cycle (for the truth)."""
    active = 0
    for b in prog.blocks:
        if b.tool_change and b.tool is not None:
            active = int(b.tool)
        if active == tool and b.kind == "drill_cycle" and b.cycle is not None:
            n = b.speed_rpm or 1.0
            f = (b.feed_mm_per_rev if b.feed_mm_per_rev is not None
                 else (b.feedrate_mm_min or 0.0) / n)
            return float(f or 0.1), float(n), float(b.cycle.z_ref_mm - b.cycle.z_bottom_mm)
    return 0.1, 1.0, 20.0


def _tool_hooks(cfg: ScenarioConfig, prog: Program, tools: ToolTable, stock: Stock | None, *,
                material: Material, surface_z_mm: float, faults: Sequence[Fault],
                rng: np.random.Generator, progress: _Progress,
                first_hole: int, hidden: Mapping[str, Any] | None = None) -> ToolDispatch:
    """One hook per tool of the table the program uses, by its kind."""
    zmap = ZMap(stock) if stock is not None else None
    used = sorted({int(b.tool) for b in prog.blocks if b.tool is not None})
    hooks: dict[int, Any] = {}
    sweeps: dict[int, tuple[ZMap, float]] = {}
    numbers = HoleNumbers(first_hole)  # the program's holes, over every drill and tap
    depths = {i: float(b.cycle.z_ref_mm - b.cycle.z_bottom_mm) for i, b in enumerate(prog.blocks)
              if b.kind in ("drill_cycle", "tap_cycle") and b.cycle is not None}
    first_drill = True
    for t in used:
        if t not in tools:
            continue
        spec = tools.get(t)
        common: dict[str, Any] = {"surface_z_mm": surface_z_mm, "rng": rng, "truth": None,
                                  "daq": None}
        if spec.kind == "drill":
            c = dataclasses.replace(cfg, drill=spec.drill(cfg.drill))
            feed, speed, depth = _drill_conditions(prog, t)
            hooks[t] = DrillingProcess(c, material=material, feed_mm_per_rev=feed,
                                       speed_rpm=speed, hole_depth_mm=depth, faults=faults,
                                       first_hole=first_hole if first_drill else 0,
                                       hole_numbers=numbers, block_depths_mm=depths,
                                       **common)
            first_drill = False
            if zmap is not None:
                sweeps[t] = (zmap, spec.diameter_mm)
        elif spec.kind == "tap":
            c = dataclasses.replace(cfg, tap=spec.tap(cfg.tap))
            hooks[t] = TappingProcess(c, material=material, faults=faults,
                                      hole_numbers=numbers, block_depths_mm=depths, **common)
            if zmap is not None:
                sweeps[t] = (zmap, spec.diameter_mm)
        elif material.milling is None:
            raise ConfigError(f"material {material.name!r} has no milling coefficients and "
                              f"T{t} is an end mill: give a material file with [milling]")
        elif zmap is not None:
            hooks[t] = StockMillingProcess(cfg, material=material, zmap=zmap,
                                           tool=spec.end_mill(), faults=(),
                                           **dict(hidden or {}), **common)
        else:
            c = dataclasses.replace(cfg, end_mill=spec.end_mill())
            hooks[t] = MillingProcess(c, material=material, faults=(), **common)
    if faults and not any(isinstance(h, DrillingProcess | TappingProcess)
                          for h in hooks.values()):
        raise ConfigError("faults are simulated in drilling and tapping: the tool table has no "
                          "drill or tap this program uses")
    return ToolDispatch(hooks, sweeps=sweeps, progress=progress)


def part_program(
    out: str | Path | None = None,
    *,
    program: str | Path,
    seed: int = 0,
    overrides: Mapping[str, Any] | None = None,
    machine: Machine | None = None,
    material: str | Material | None = None,
    tools: ToolTable | None = None,
    stock: Stock | None = None,
    surface_z_mm: float = 0.0,
    fmt: str = "c4a",
    max_file_mb: float | None = None,
    chunk_cycles: int = 50_000,
    progress: ProgressFn | None = None,
    start_time: pd.Timestamp | str | None = None,
    first_hole: int = 0,
    faults: Sequence[Fault | Mapping[str, Any]] = (),
    live: LiveOverride | None = None,
) -> ScenarioResult:
    """Any part program of the supported G-code subset on a machine description.

    Parameters
    ----------
    out : str or path, optional
        Output directory; ``None`` keeps ``result.recording`` in memory.
    program : str or path
        The program file (``.mpf``).
    seed : int
        Seed of every random stream.
    overrides : mapping, optional
        Dotted overrides on top of ``machine``; and the hidden workpiece of end mills on a
        stock (:data:`PART_KEYS`): ``part.hardness_along_x`` = [[x_mm, factor], ...],
        ``part.break_at_x_mm`` (in ``truth.json``: ``part``, ``breakage_cycle``).
    machine : Machine, optional
        The machine (e.g. loaded from a machine file); default the thesis machine.
    material : str or Material, optional
        Workpiece material (``aisi1045``, ``grey_cast_iron``, ``al7050``, with the overrides
        of ``material.<key>.*``, or a :class:`~cnctwin.sim.cutting.Material`); without it the
        program runs in air (no process load). Without ``tools`` and ``stock``, a program
        with a drilling cycle drills (every feed move below the surface with the drilling
        model; XY moves below the surface are then named in the truth's ``limits.warnings``,
        they are milled only with a tool table) and any other program mills a full slot
        below ``surface_z_mm``.
    tools : ToolTable, optional
        The tool table: each cycle is cut by the active tool's kind (drill, tap, end mill
        with its diameter and flutes), so a program that drills and mills simulates both. A
        T number the table lacks raises :class:`ConfigError` naming the line.
    stock : Stock, optional
        The raw part: end mills cut what the Z-map (:class:`~cnctwin.engagement.ZMap`)
        still holds (engagement angles and depth per cycle; a second pass cuts air), drills
        start at its top (``surface_z_mm`` is then ``stock.z1_mm``). Needs ``tools``.
    surface_z_mm : float, default 0
        Workpiece top surface [mm] without a stock.
    start_time : Timestamp or str, optional
        UTC time of the first cycle; default the scenarios' common start time.
    first_hole : int, default 0
        Holes the drill has made before this program (its flank wear starts there).
    faults : sequence, default ()
        Faults of a drilling program (:class:`~cnctwin.sim.faults.ToolBreakage`,
        :class:`~cnctwin.sim.faults.HardnessChange`, :class:`~cnctwin.sim.faults.Chatter`,
        :class:`~cnctwin.sim.faults.LooseTool`, or dicts with ``type``: ``--option
        faults='[{"type": "ToolBreakage", "hole": 3}]'``); hole numbers count the program's
        holes from ``first_hole`` (with ``tools``: over every drill and tap, each tool's
        holes in the program's order; a broken or loose tool is the one that cut the
        fault's hole, a hardness change acts on every tool; a breakage's ``depth_fraction``
        is of its cycle's programmed depth, without ``tools`` of 20 mm). In ``truth.json``
        under ``faults``.
    fmt : str, default 'c4a'
        Recording format: ``'c4a'`` (Capture4Analysis JSON) or ``'parquet'`` (chunk directory).
    max_file_mb : float, optional
        Split a Capture4Analysis recording into files of at most this size [MB]; None: one file.
    chunk_cycles : int, default 50000
        Cycles simulated and written per chunk (bounds memory).
    progress : callable, optional
        Called with (fraction done 0..1, message) while the scenario runs.
    live : LiveOverride, optional
        Play the program at a feed override decided while it runs
        (:class:`~cnctwin.sim.override.OverridePlayer`): the adaptive feed's closed loop.
        Truth ``live``: ``stopped_cycle`` (a stop request ended the program) and the
        per-chunk log is in ``live.log``.

    Returns
    -------
    ScenarioResult
        Truth ``limits``: :func:`drive_limits_check` (cycle time, peaks and the warnings
        naming the program line where a limit is exceeded); of a drilling program ``holes``:
        every entry of the tool into the part at a new X/Y (``hole``, the number the
        ``faults`` use, ``x_mm``, ``y_mm``, ``cut_first_cycle``; milling entries count here).

    Raises
    ------
    GCodeError
        An unsupported word or cycle, naming the line and the word.
    """
    path = Path(program)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read the program: {exc}") from None
    try:
        prog = parse_program(text)
    except GCodeError as exc:
        raise ConfigError(f"{path}: {exc}; the supported subset is listed in "
                          "docs/simulator.md") from None
    ov = dict(overrides or {})
    part = {k: ov.pop(k) for k in list(ov) if k.startswith("part.")}
    bad = sorted(set(part) - set(PART_KEYS))
    if bad:
        raise ConfigError(f"--set {bad[0]}: not a key; part keys: "
                          + "; ".join(f"{k} ({v})" for k, v in PART_KEYS.items()))
    hidden = _part_keys(part)
    if hidden and stock is None:
        raise ConfigError(f"--set {sorted(part)[0]} needs --stock and --tools (the hidden "
                          "workpiece is cut by end mills on a stock)")
    cfg = ScenarioConfig.build(ov, machine=machine)
    if stock is not None:
        if tools is None:
            raise ConfigError("--stock needs --tools TOOLS.toml: the Z-map cuts with each "
                              "tool's diameter")
        surface_z_mm = stock.z1_mm
    if tools is not None:
        _check_tools(prog, tools, path)
    flist = _faults_from(faults)
    if flist and material is None:
        raise ConfigError("faults need a cutting load: give --material (a program in air has "
                          "no process to break or wear)")
    o = _prepare(out)
    stem = path.stem
    upper = text.upper()
    hook: Any
    pf = _Progress(progress, stem)
    rng = np.random.default_rng([seed, 1])
    if material is None:
        kind = "air"
        hook = _NoLoad(surface_z_mm=surface_z_mm, faults=(), rng=rng, truth=None, daq=None,
                       progress=pf)
    else:
        if isinstance(material, Material):
            mat = material
        elif material in cfg.materials:
            mat = cfg.materials[material]
        else:
            raise ConfigError(f"unknown material {material!r}; known: {sorted(cfg.materials)}")
        if tools is not None:
            kind = "stock" if stock is not None else "tools"
            hook = _tool_hooks(cfg, prog, tools, stock, material=mat,
                               surface_z_mm=surface_z_mm, faults=flist, rng=rng, progress=pf,
                               first_hole=first_hole, hidden=hidden)
        elif any(w in upper for w in _DRILL_WORDS):
            kind = "drilling"
            speeds = [float(v) for v in re.findall(r"\bS(\d+(?:\.\d*)?)", upper)] or [1.0]
            feeds = [float(v) for v in re.findall(r"\bF(\d*\.?\d+)", upper)] or [0.1]
            hook = DrillingProcess(cfg, material=mat, feed_mm_per_rev=feeds[0],
                                   speed_rpm=max(speeds), hole_depth_mm=20.0,
                                   surface_z_mm=surface_z_mm, faults=flist, rng=rng,
                                   truth=None, daq=None, progress=pf, first_hole=first_hole)
        else:
            if mat.milling is None:
                raise ConfigError(f"material {material!r} has no milling coefficients; the "
                                  "program has no drilling cycle, so it mills: choose al7050")
            if flist:
                raise ConfigError("faults are simulated in drilling programs (a drilling "
                                  "cycle); this program mills")
            kind = "milling"
            hook = MillingProcess(cfg, material=mat, surface_z_mm=surface_z_mm, faults=(),
                                  rng=rng, truth=None, daq=None, progress=pf)
    mat_name = material.name if isinstance(material, Material) else material
    res = ScenarioResult("part_program", truth={
        **_base_truth("part_program", seed, overrides, cfg),
        **({"part": part} if part else {}), "program": str(path),
        "process": kind, "material": mat_name, "faults": [fault_to_dict(f) for f in flist],
        **({"stock": stock.as_text()} if stock is not None else {}),
        **({"tools": {str(k): dataclasses.asdict(v) for k, v in tools.tools.items()}}
           if tools is not None else {})})
    _write_program(o, path.name, text, res.paths)
    sink, rpath = _make_sink(o, stem, fmt, max_file_mb)
    source: Any = prog
    if live is not None:
        source, hook, sink = _live(prog, cfg.machine, live, hook, sink, res)
    try:
        sim = simulate(source, cfg.machine, seed=seed, start_cycle=START_CYCLE,
                       start_time=START_TIME if start_time is None else start_time,
                       cutting=hook, sink=sink, chunk_cycles=chunk_cycles)
    except GCodeError as exc:  # found while running it (a speed above the machine's limit)
        raise ConfigError(f"{path}: {exc} (the machine's limits: --machine FILE, or the "
                          "thesis machine without one)") from None
    _collect(res, sim, sink, rpath, None, None)
    rec = res.recording
    if isinstance(hook, DrillingProcess):  # every entry of the tool into the part at a new
        # X/Y, with its cycle
        res.truth["holes"] = [{k: (float(v) if isinstance(v, np.floating) else v)
                               for k, v in row.items()} for row in hook.hole_rows()]
    elif isinstance(hook, _LiveHook):
        hook = hook.inner
    if isinstance(hook, ToolDispatch):
        rows = []
        broken = [h.broken_cycle for h in hook.hooks.values()
                  if isinstance(h, StockMillingProcess) and h.broken_cycle is not None]
        if broken:
            res.truth["breakage_cycle"] = int(min(broken))
        for t, h in sorted(hook.hooks.items()):
            if isinstance(h, DrillingProcess | TappingProcess):
                rows += [{"tool": t, **{k: (float(v) if isinstance(v, np.floating) else v)
                                        for k, v in row.items()}} for row in h.hole_rows()]
            if isinstance(h, StockMillingProcess) and h.plunge_cycles:
                res.truth.setdefault("notes", []).append(
                    f"T{t}: {h.plunge_cycles} cycles plunging straight down into material "
                    "(end mill; no load model for a plunge: ramp or helix in, or drill first)")
        res.truth["holes"] = sorted(rows, key=lambda r: int(r["hole"]))  # the program's order
    res.truth["limits"] = drive_limits_check(rec, cfg.machine, text)
    if isinstance(hook, ToolDispatch):
        _chip_check(res.truth["limits"], hook, rec, tools, text)
    if kind == "drilling":
        res.truth["limits"]["warnings"] += _milling_in_drilling(prog, surface_z_mm)
    _write_truth(o, res.truth, res.paths)
    return res




def _part_keys(part: Mapping[str, Any]) -> dict[str, Any]:
    """``part.*`` values checked, as :class:`StockMillingProcess` arguments."""
    out: dict[str, Any] = {}
    if "part.hardness_along_x" in part:
        v = part["part.hardness_along_x"]
        ok = isinstance(v, list) and all(
            isinstance(p, list) and len(p) == 2
            and all(isinstance(q, int | float) and not isinstance(q, bool) for q in p)
            and p[1] > 0 for p in v)
        if not ok:
            raise ConfigError(f"--set part.hardness_along_x={v!r}: give [[x_mm, factor], ...] "
                              "with positive factors, e.g. [[60, 1.15], [110, 0.95]]")
        out["hardness_along_x"] = tuple((float(p[0]), float(p[1])) for p in v)
    if "part.break_at_x_mm" in part:
        b = part["part.break_at_x_mm"]
        if isinstance(b, bool) or not isinstance(b, int | float) or not math.isfinite(b):
            raise ConfigError(f"--set part.break_at_x_mm={b!r}: give an X position [mm]")
        out["break_at_x_mm"] = float(b)
    return out


class _LiveHook:
    """The cutting hook, keeping each chunk's hidden cutting torque and hardness."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.last: dict[str, float] = {}

    def __call__(self, ci: Any) -> Any:
        out = self.inner(ci)
        t = getattr(out, "truth", None) or {}
        self.last = {k: float(np.nanmean(t[k])) if k in t and np.size(t[k])
                     and np.isfinite(t[k]).any() else 0.0
                     for k in ("cutting_torque_nm", "hardness_factor")}
        self.last["speed_rpm"] = float(np.mean(np.abs(ci.spindle_speed_rpm))) if len(ci) \
            else 0.0
        return out


class _TeeSink:
    def __init__(self, inner: Any, tee: Any) -> None:
        self.inner, self.tee = inner, tee

    def open(self, columns: list[str], meta: Any) -> None:
        self.inner.open(columns, meta)
        self.tee.open(columns, meta)

    def write(self, chunk: Any) -> None:
        self.inner.write(chunk)
        self.tee.write(chunk)

    def close(self, meta: Any) -> Any:
        self.tee.close(meta)
        return self.inner.close(meta)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


def _live(prog: Program, machine: Machine, live: LiveOverride, hook: Any, sink: Any,
          res: ScenarioResult) -> tuple[Any, Any, Any]:
    """The program as override-played chunks, the hook and sink that log each chunk."""
    from cnctwin.sim.override import OverridePlayer, plan_of

    limits = {ax.name: (ax.max_velocity_mm_min, ax.max_accel_mm_s2, ax.max_jerk_mm_s3)
              for ax in machine.axes}
    player = OverridePlayer(plan_of(prog, machine), prog, min_pct=0.0, max_pct=200.0,
                            rate_pct_per_s=live.rate_pct_per_s, axis_limits=limits)
    lhook = _LiveHook(hook)

    def chunks() -> Any:
        while not player.done:
            req = live.requested()
            if req is None:  # a stop the control obeyed: the program ends here
                res.truth["live"] = {"stopped_cycle": START_CYCLE + player.cycle}
                return
            first = player.cycle
            c = player.step(live.chunk_cycles, float(req))
            if c.block_index.size == 0:
                return
            yield c
            if live.log and "cutting_torque_nm" not in live.log[-1]:
                live.log[-1].update(lhook.last)
            live.log.append({"cycle": START_CYCLE + first, "requested_pct": float(req),
                             "applied_pct": float(np.mean(c.override_pct))
                             if c.override_pct.size else 100.0,
                             "tool": int(np.asarray(c.tool)[-1]) if np.size(c.tool) else 0})
        res.truth.setdefault("live", {"stopped_cycle": None})

    if live.tee is not None and sink is None:
        raise ConfigError("a live run with a second sink (tee) needs an output directory")
    out_sink = _TeeSink(sink, live.tee) if live.tee is not None else sink
    return chunks(), lhook, out_sink
