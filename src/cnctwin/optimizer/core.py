"""Feed-rate optimization of a user's program on their calibrated twin (``cnctwin optimize``).

1. :func:`~cnctwin.optimizer.engagement_pass.engagement_pass`: the engagement of every
   control cycle of the programmed run (interpolator + Z-map, no drives).
2. :func:`~cnctwin.optimizer.constraints.feed_limits`: per cycle the highest feed within the
   spindle's S1 torque and power across speed (the calibrated law: friction B n + tau_f),
   its peak torque (current limit x Kt), the tool's chip thickness, torque and force per
   tooth, the feed axes' S1 force, the machine's path feed, with the margin of the
   calibration's uncertainty.
3. :func:`plan_feeds`: per block the lowest of those over its cycles; a G64 (continuous path)
   G1 block is split where the engagement changes (air and cut, or the feed limit by more
   than ``split_ratio``), pieces shorter than ``split_min_mm`` merged into the slower
   neighbour; G1/G2/G3 in air at the machine's path feed; never below ``min_feed_mm_min``.
   Drilling and tapping cycles keep their feed.
4. :func:`~cnctwin.optimizer.program_edit.rewrite_program`: only F changes.
5. Both programs are simulated on the machine (the verification; its limits check names any
   violation with its line).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cnctwin.engagement import Stock, runs_of
from cnctwin.exceptions import ConfigError
from cnctwin.machine import MachineFile, ToolTable
from cnctwin.optimizer.constraints import (
    CONSTRAINTS,
    LIBRARY_MATERIAL_UNCERTAINTY,
    Limits,
    feed_limits,
    limits_from_machine,
)
from cnctwin.optimizer.engagement_pass import EngagementTrace, engagement_pass
from cnctwin.optimizer.program_edit import Piece, rewrite_program
from cnctwin.sim.gcode import Block, Program, parse_program
from cnctwin.sim.materials import MaterialSource

__all__ = ["LinePlan", "OptimizeResult", "optimize_program", "plan_feeds"]

ProgressFn = Callable[[float, str], None]
_SPLITTABLE_WORDS = frozenset({"N", "G", "X", "Y", "Z", "F"})


@dataclass(frozen=True)
class LinePlan:
    """The optimizer's decision for one program line.

    Attributes
    ----------
    line : int
        Line in the programmed program.
    text : str
        Its text.
    feed_old_mm_min : float or None
        Programmed path feed [mm/min] (G95: F x S).
    feed_new_mm_min : float
        New feed of its slowest piece [mm/min].
    binding : str
        The limit that sets it (:data:`~cnctwin.optimizer.constraints.CONSTRAINTS`), or
        ``"air"`` (no cut: the machine's path feed).
    pieces : list of dict
        ``feed_mm_min``, ``binding``, ``length_mm`` per piece (one piece: not split).
    """

    line: int
    text: str
    feed_old_mm_min: float | None
    feed_new_mm_min: float
    binding: str
    pieces: list[dict[str, Any]]

    def to_dict(self) -> dict[str, Any]:
        """JSON form (the ``lines`` of optimize.json)."""
        return {"line": self.line, "text": self.text, "feed_old_mm_min": self.feed_old_mm_min,
                "feed_new_mm_min": self.feed_new_mm_min, "binding": self.binding,
                "split": len(self.pieces), "pieces": self.pieces}


@dataclass
class OptimizeResult:
    """What :func:`optimize_program` returns.

    Attributes
    ----------
    text : str
        The optimized program.
    lines : list of LinePlan
        Per changed motion line.
    limits : Limits
        The limits and margin used.
    cycle_time_s : dict
        ``programmed`` and ``optimized`` machine time [s] (interpolated; simulated when
        verified).
    violations : list of dict
        Limits the simulated optimized program exceeds (``line``, ``limit``, ``value``,
        ``allowed``); empty when verified and within every limit.
    trace : EngagementTrace
        The engagement of the programmed run.
    runs : dict
        ``programmed`` / ``optimized`` :class:`~cnctwin.sim.config.ScenarioResult` of the
        verification (empty without it).
    """

    text: str
    lines: list[LinePlan]
    limits: Limits
    cycle_time_s: dict[str, float]
    violations: list[dict[str, Any]] = field(default_factory=list)
    trace: EngagementTrace | None = None
    runs: dict[str, Any] = field(default_factory=dict)


def _old_feed(blk: Block) -> float | None:
    if blk.feed_mode == "G95":
        if blk.feed_mm_per_rev is None or not blk.speed_rpm:
            return None
        return float(blk.feed_mm_per_rev * blk.speed_rpm)
    return None if blk.feedrate_mm_min is None else float(blk.feedrate_mm_min)


def _splittable(blk: Block, incremental: bool) -> bool:
    return (blk.kind == "linear" and not blk.exact_stop and not incremental
            and set(blk.words) <= _SPLITTABLE_WORDS)


def plan_feeds(program: Program, trace: EngagementTrace, tools: ToolTable,
               material: MaterialSource, limits: Limits, *, min_feed_mm_min: float = 10.0,
               air_feed_mm_min: float | None = None, split_min_mm: float = 2.0,
               split_ratio: float = 0.25) -> tuple[dict[int, list[Piece]], list[LinePlan]]:
    """The new feed of every milling block (and its pieces).

    Parameters
    ----------
    program : Program
        The programmed program.
    trace : EngagementTrace
        Its engagement per cycle.
    tools : ToolTable
        Tools (end mills are optimized; drills and taps keep their feed).
    material : MaterialSource
        The workpiece material (milling coefficients).
    limits : Limits
        Machine limits with the margin.
    min_feed_mm_min : float, default 10
        Lowest feed written [mm/min].
    air_feed_mm_min : float, optional
        Feed of G1/G2/G3 moves in air; default the machine's path feed.
    split_min_mm : float, default 2
        Shortest piece of a split block [mm].
    split_ratio : float, default 0.25
        Relative change of the feed limit that starts a new piece [-].

    Returns
    -------
    plan : dict
        Block index -> pieces (for :func:`~cnctwin.optimizer.program_edit.rewrite_program`).
    lines : list of LinePlan
    """
    coef = material.material.milling
    if coef is None:
        raise ConfigError(f"material {material.material.name!r} has no milling coefficients: "
                          "give a material file with a [milling] table")
    air = float(air_feed_mm_min or limits.path_max_mm_min)
    n = len(trace)
    flim = np.full(n, np.inf)
    bind = np.full(n, -1, dtype=np.int64)
    t_a = np.zeros(n)
    t_b = np.zeros(n)
    for t in np.unique(trace.tool):
        if int(t) not in tools or tools.get(int(t)).kind != "end_mill":
            continue
        sel = trace.tool == t
        fl = feed_limits(trace.entry_rad[sel], trace.exit_rad[sel], trace.axial_depth_mm[sel],
                         trace.speed_rpm[sel], tool=tools.get(int(t)), coefficients=coef,
                         limits=limits)
        flim[sel] = fl.feed_mm_min
        bind[sel] = fl.binding
        t_a[sel] = fl.torque_a_nm
        t_b[sel] = fl.torque_b_nm_per_mm
    machine_cap = limits.path_max_mm_min
    incremental = any("91" in b.words.get("G", ()) for b in program.blocks)
    plan: dict[int, list[Piece]] = {}
    lines: list[LinePlan] = []
    for bi, lo, hi in runs_of(trace.block_index):
        if bi in plan or bi >= len(program.blocks):
            continue
        blk = program.blocks[bi]
        if blk.kind not in ("linear", "arc_cw", "arc_ccw"):
            continue
        t = int(trace.tool[lo])
        if t not in tools or tools.get(t).kind != "end_mill":
            continue
        f = flim[lo:hi]
        b = bind[lo:hi]
        runs = _segments(f, trace, lo, hi, split_ratio, split_min_mm) if _splittable(
            blk, incremental) else [(0, hi - lo)]
        pieces: list[Piece] = []
        info: list[dict[str, Any]] = []
        n_rev = blk.speed_rpm or 0.0
        for k, (a, e) in enumerate(runs):
            seg = f[a:e]
            if np.isfinite(seg).any():
                j = int(np.argmin(seg))
                feed = min(float(seg[j]), machine_cap)
                why = CONSTRAINTS[int(b[a + j])] if seg[j] <= machine_cap else "machine feed"
            else:
                feed, why = min(air, machine_cap), "air"
            feed = max(math.floor(feed), min_feed_mm_min)
            fval = feed / n_rev if blk.feed_mode == "G95" and n_rev else float(feed)
            last = k == len(runs) - 1
            end = None if last else {"X": float(trace.x_mm[lo + e - 1]),
                                     "Y": float(trace.y_mm[lo + e - 1]),
                                     "Z": float(trace.z_mm[lo + e - 1])}
            if end is not None:
                end = _on_line(blk, end)
            pieces.append(Piece(end=end, feed=math.floor(fval * 1e4) / 1e4
                                if blk.feed_mode == "G95" else fval))
            length = float(np.sum(np.hypot(np.diff(trace.x_mm[lo + a:lo + e]),
                                           np.diff(trace.y_mm[lo + a:lo + e]))))
            # the mean cutting torque predicted at this feed (what the adaptive feed holds)
            z = tools.get(t).flutes
            n_cyc = np.abs(trace.speed_rpm[lo + a:lo + e])
            cut = np.isfinite(seg) & (t_b[lo + a:lo + e] > 0.0) & (n_cyc > 1.0)
            torque = (float(np.median(t_a[lo + a:lo + e][cut] + t_b[lo + a:lo + e][cut]
                                      * feed / (n_cyc[cut] * z)))
                      if cut.any() else None)
            info.append({"feed_mm_min": float(feed), "binding": why, "length_mm": length,
                         "tool": t, "cutting_torque_nm": torque})
        plan[bi] = pieces
        slow = min(range(len(info)), key=lambda i: info[i]["feed_mm_min"])
        lines.append(LinePlan(line=blk.line, text=blk.text.strip(), feed_old_mm_min=_old_feed(blk),
                              feed_new_mm_min=info[slow]["feed_mm_min"],
                              binding=info[slow]["binding"], pieces=info))
    return plan, lines


def _on_line(blk: Block, p: Mapping[str, float]) -> dict[str, float]:
    """Project a point onto the block's straight path (the set point lies on it)."""
    s = np.array([blk.start.get(a, 0.0) for a in "XYZ"])
    e = np.array([blk.target.get(a, blk.start.get(a, 0.0)) for a in "XYZ"])
    d = e - s
    ll = float(d @ d)
    t = 0.0 if ll == 0.0 else float(np.clip((np.array([p[a] for a in "XYZ"]) - s) @ d / ll,
                                            0.0, 1.0))
    q = s + t * d
    return {a: float(q[i]) for i, a in enumerate("XYZ") if a in blk.target}


def _segments(f: NDArray[np.float64], trace: EngagementTrace, lo: int, hi: int, ratio: float,
              min_mm: float) -> list[tuple[int, int]]:
    """Runs of cycles (relative to ``lo``) with one feed class, short ones merged."""
    step = -math.log(1.0 - ratio)
    cls = np.where(np.isfinite(f), np.floor(np.log(np.maximum(f, 1e-9)) / step), np.inf)
    cuts = np.flatnonzero(cls[1:] != cls[:-1]) + 1
    bounds = [0, *cuts.tolist(), f.size]
    segs = [[a, e] for a, e in itertools.pairwise(bounds)]
    x = trace.x_mm[lo:hi]
    y = trace.y_mm[lo:hi]
    z = trace.z_mm[lo:hi]
    dist = np.concatenate([[0.0], np.cumsum(np.sqrt(np.diff(x) ** 2 + np.diff(y) ** 2
                                                     + np.diff(z) ** 2))])

    def length(s: list[int]) -> float:
        return float(dist[s[1] - 1] - dist[s[0]])

    def level(s: list[int]) -> float:
        v = f[s[0]:s[1]]
        return float(np.min(v)) if np.isfinite(v).any() else math.inf

    changed = True
    while changed and len(segs) > 1:
        changed = False
        for i, s in enumerate(segs):
            if length(s) >= min_mm:
                continue
            # merge into the slower neighbour (its feed is then the lower of the two)
            left = segs[i - 1] if i > 0 else None
            right = segs[i + 1] if i + 1 < len(segs) else None
            if right is None or (left is not None and level(left) <= level(right)):
                assert left is not None
                left[1] = s[1]
            else:
                right[0] = s[0]
            del segs[i]
            changed = True
            break
    return [(a, e) for a, e in segs]


def optimize_program(program: str | Program, mfile: MachineFile, material: MaterialSource,
                     tools: ToolTable, stock: Stock, *, min_feed_mm_min: float = 10.0,
                     air_feed_mm_min: float | None = None, verify: bool = True, seed: int = 0,
                     name: str = "program", progress: ProgressFn | None = None
                     ) -> OptimizeResult:
    """Optimize the feeds of a program on a machine, and verify the result on its twin.

    Parameters
    ----------
    program : str or Program
        Program text or parsed program.
    mfile : MachineFile
        The (calibrated) machine.
    material : MaterialSource
        The workpiece material (from :func:`~cnctwin.sim.materials.resolve_material`).
    tools : ToolTable
        The tool table.
    stock : Stock
        The raw part.
    min_feed_mm_min : float, default 10
        Lowest feed written [mm/min].
    air_feed_mm_min : float, optional
        Feed of G1/G2/G3 moves in air; default the machine's path feed.
    verify : bool, default True
        Simulate both programs on the machine (cycle times, violations).
    seed : int, default 0
        Seed of the verification runs.
    name : str
        Program name.
    progress : callable, optional
        Called with (fraction 0..1, message).

    Returns
    -------
    OptimizeResult
    """
    prog = parse_program(program, name=name) if isinstance(program, str) else program
    for b in prog.blocks:
        if b.tool is not None and "T" in b.words:
            tools.get(int(b.tool), line=b.line, text=b.text)
    u_mat = material.uncertainty.get("ktc_n_per_mm2")
    if u_mat is not None and material.material.milling is not None:
        u_rel = u_mat / max(material.material.milling.ktc_n_per_mm2, 1e-12)
    else:
        u_rel = LIBRARY_MATERIAL_UNCERTAINTY if material.origin == "library" else 0.10
    limits = limits_from_machine(mfile, material_uncertainty=u_rel)

    def stage(lo: float, hi: float, what: str) -> ProgressFn | None:
        if progress is None:
            return None
        return lambda f, _m: progress(lo + (hi - lo) * f, what)

    trace = engagement_pass(prog, mfile.machine, tools, stock,
                            progress=stage(0.0, 0.3 if verify else 0.9, "engagement"))
    plan, lines = plan_feeds(prog, trace, tools, material, limits,
                             min_feed_mm_min=min_feed_mm_min, air_feed_mm_min=air_feed_mm_min)
    text = rewrite_program(prog, plan)
    new_prog = parse_program(text, name=name)
    res = OptimizeResult(text=text, lines=lines, limits=limits, trace=trace,
                         cycle_time_s={"programmed": trace.duration_s})
    if not verify:
        from cnctwin.sim.simulation import iter_chunks

        n_new = sum(len(t.block_index) for t in iter_chunks(new_prog, mfile.machine, 500_000))
        res.cycle_time_s["optimized"] = n_new * mfile.machine.cycle_time_s
        return res
    from cnctwin.optimizer.verify import verify_run

    for key, src, lo in (("programmed", prog, 0.3), ("optimized", new_prog, 0.65)):
        run = verify_run(src, mfile, material, tools, stock, limits=limits, seed=seed,
                         progress=stage(lo, lo + 0.35, f"simulating the {key} program"))
        res.runs[key] = run
        res.cycle_time_s[key] = run.cycle_time_s
    res.violations = res.runs["optimized"].violations
    return res
