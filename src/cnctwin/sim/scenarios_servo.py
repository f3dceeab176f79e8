"""Feed-axis scenarios: the milling square and circle of the position-loop identification
(thesis Sect. 3.1.2) and the axis test program of ``cnctwin calibrate axes``."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from cnctwin.sim.config import (
    ProgressFn,
    ScenarioConfig,
    ScenarioResult,
    random_loop_overrides,
)
from cnctwin.sim.faults import Fault, fault_to_dict
from cnctwin.sim.gcode import parse_program
from cnctwin.sim.machine import Machine
from cnctwin.sim.processes import (
    MillingProcess,
    _DynamometerDAQ,
    _NoLoad,
    _Progress,
    _TruthParquet,
)
from cnctwin.sim.programs import (
    axis_test_program,
    circle_path,
    square_path,
)
from cnctwin.sim.runner import (
    _base_truth,
    _collect,
    _faults_from,
    _make_sink,
    _prepare,
    _simulate,
    _write_program,
    _write_truth,
)

__all__ = ["axis_test", "milling_square_circle"]


def _milling_program(side_mm: float, radius_mm: float, gap_mm: float,
                     air_moves_mm_min: Sequence[float] = (), air_stroke_mm: float = 60.0,
                     **kw: Any) -> str:
    """Square (first corner at the origin) then circle right of it, one program; optional
    air moves of X and Y at the clearance height first (out and back at each feed)."""
    sq = square_path(side_mm, **kw).splitlines()
    sq = [line for line in sq if line.strip() not in ("M30", "M5 M9")]
    if air_moves_mm_min:
        at = next(i for i, line in enumerate(sq) if line.startswith("G0 X"))
        air = ["; air moves clear of the part (approach at feed)"]
        for f in air_moves_mm_min:
            air += [f"G1 X{air_stroke_mm:g} F{f:g}", "X0", f"Y{air_stroke_mm:g}", "Y0"]
        sq = sq[:at + 1] + air + sq[at + 1:]
    center = (side_mm + gap_mm + radius_mm, side_mm / 2.0)
    ci = circle_path(radius_mm, center_xy=center, **kw).splitlines()
    ci = [line for line in ci if not line.startswith(("G90", "T", "S"))]
    return "\n".join(sq + ci) + "\n"


def milling_square_circle(
    out: str | Path | None = None,
    *,
    seed: int = 0,
    overrides: Mapping[str, Any] | None = None,
    machine: Machine | None = None,
    randomize_loop: bool = False,
    side_mm: float = 40.0,
    radius_mm: float = 20.0,
    speed_rpm: float = 6000.0,
    feed_per_tooth_mm: float = 0.167,
    depth_mm: float = 0.5,
    air_moves_mm_min: Sequence[float] = (),
    faults: Sequence[Fault | Mapping[str, Any]] = (),
    fmt: str = "c4a",
    max_file_mb: float | None = None,
    chunk_cycles: int = 50_000,
    progress: ProgressFn | None = None,
) -> ScenarioResult:
    """Milling a square and a circle in Al7050-T7451 (thesis §3.1.2, Figs. 3.2 and 3.3).

    16 mm two-flute carbide end mill (``end_mill.*``), 0.5 mm axial depth, 0.167 mm/tooth
    (F = fz z n = 2004 mm/min at the assumed 6000 rpm), full-slot cut; programs
    :func:`~cnctwin.sim.programs.square_path` (G64) and :func:`~cnctwin.sim.programs.circle_path`
    (G3). The recording has every position-loop signal per axis (``DES_POS``, ``CTRL_POS``,
    ``ENC_POS``, ``CTRL_DIFF``, ``CTRL_DIFF2``, ``CONT_DEV``, ``VEL_FFW``, ``TORQUE_FFW``,
    ``CMD_SPEED``, ``CURRENT``, ``TORQUE``, ``LOAD``, ``POWER``).

    Parameters
    ----------
    out : str or path, optional
        Output directory; ``None`` keeps ``result.recording`` in memory.
    seed : int
        Seed of every random stream (and of the loop draw with ``randomize_loop``).
    overrides : mapping, optional
        Dotted overrides, e.g. ``{"axes.X1.kv_m_min_per_mm": 3.1}``.
    machine : Machine, optional
        Base machine (e.g. one with hidden loop parameters); overrides apply on top.
    randomize_loop : bool, default False
        Draw the X/Y loop parameters with :func:`random_loop_overrides` (``seed``) before
        ``overrides``; the drawn values are in ``truth["loop_overrides"]``.
    side_mm : float, default 40.0
        Side of the square [mm].
    radius_mm : float, default 20.0
        Radius of the circle [mm].
    speed_rpm : float, default 6000.0
        Spindle speed [rpm].
    feed_per_tooth_mm : float, default 0.167
        Feed per tooth [mm].
    depth_mm : float, default 0.5
        Axial depth of cut [mm].
    air_moves_mm_min : sequence of float, default ()
        Feeds of air moves before the square: X and Y out 60 mm and back at each feed at the
        clearance height, spindle on (a CAM program's approach moves; what friction from a
        production recording needs, docs/validation-calibration.md). Default none: the
        thesis program, every X/Y move at constant feed in the cut.
    faults : sequence or mapping, default ()
        Faults to inject (:mod:`cnctwin.sim.faults`), objects or their dicts.
    fmt : str, default 'c4a'
        Recording format: ``'c4a'`` (Capture4Analysis JSON) or ``'parquet'`` (chunk directory).
    max_file_mb : float, optional
        Split a Capture4Analysis recording into files of at most this size [MB]; None: one file.
    chunk_cycles : int, default 50000
        Cycles simulated and written per chunk (bounds memory).
    progress : callable, optional
        Called with (fraction done 0..1, message) while the scenario runs.

    Returns
    -------
    ScenarioResult
        Truth: the paths (corners, circle centre/radius), the feed, the machine (all loop
        parameters) and the per-cycle cutting forces (``per_cycle`` / Parquet).
    """
    drawn = random_loop_overrides(seed) if randomize_loop else {}
    ov = {**drawn, **dict(overrides or {})}
    cfg = ScenarioConfig.build(ov, machine=machine)
    o = _prepare(out)
    flist = _faults_from(faults)
    gap = 30.0
    text = _milling_program(side_mm, radius_mm, gap, air_moves_mm_min=air_moves_mm_min,
                            speed_rpm=speed_rpm,
                            feed_per_tooth_mm=feed_per_tooth_mm,
                            n_flutes=cfg.end_mill.flutes, depth_mm=depth_mm,
                            tool=cfg.end_mill.tool_number)
    prog = parse_program(text)
    feed = feed_per_tooth_mm * cfg.end_mill.flutes * speed_rpm
    res = ScenarioResult("milling_square_circle", truth={
        **_base_truth("milling_square_circle", seed, overrides, cfg),
        "loop_overrides": drawn, "material": "al7050", "speed_rpm": speed_rpm,
        "feed_per_tooth_mm": feed_per_tooth_mm, "feed_mm_min": feed, "depth_mm": depth_mm,
        "air_moves_mm_min": [float(f) for f in air_moves_mm_min],
        "square": {"corners_mm": [[0.0, 0.0], [side_mm, 0.0], [side_mm, side_mm],
                                  [0.0, side_mm]], "direction": "ccw"},
        "circle": {"center_mm": [side_mm + gap + radius_mm, side_mm / 2.0],
                   "radius_mm": radius_mm, "direction": "ccw"},
        "faults": [fault_to_dict(f) for f in flist]})
    _write_program(o, "milling_square_circle.mpf", text, res.paths)
    daq = _DynamometerDAQ(cfg.dynamometer, np.random.default_rng([seed, 2]), o, "dynamometer")
    tp = _TruthParquet(o / "truth_per_cycle.parquet") if o is not None else None
    pf = _Progress(progress, "milling")
    hook = MillingProcess(cfg, material=cfg.materials["al7050"], surface_z_mm=0.0,
                          faults=flist, rng=np.random.default_rng([seed, 1]), truth=tp,
                          daq=daq, progress=pf)
    sink, path = _make_sink(o, "milling_square_circle", fmt, max_file_mb)
    sim = _simulate(prog, cfg, seed=seed, hook=hook, sink=sink, chunk_cycles=chunk_cycles)
    daq.close()
    res.truth["fault_onsets_s"] = hook.onsets
    res.truth["dynamometer_sessions"] = daq.sessions
    _collect(res, sim, sink, path, daq, tp)
    _write_truth(o, res.truth, res.paths)
    return res


def axis_test(
    out: str | Path | None = None,
    *,
    seed: int = 0,
    overrides: Mapping[str, Any] | None = None,
    machine: Machine | None = None,
    randomize_loop: bool = False,
    axes: Sequence[str] = ("X1", "Y1", "Z1"),
    stroke_mm: float = 60.0,
    feeds_mm_min: Sequence[float] = (500.0, 1000.0, 2000.0, 4000.0, 8000.0),
    fmt: str = "c4a",
    max_file_mb: float | None = None,
    chunk_cycles: int = 50_000,
    progress: ProgressFn | None = None,
) -> ScenarioResult:
    """Feed axes back and forth in air at several feeds
    (:func:`~cnctwin.sim.programs.axis_test_program`).

    The calibration program for ``cnctwin calibrate axes``: constant-velocity strokes in both
    directions at every feed (friction, steady following error) with jerk-limited starts and
    stops (jerk filter, speed loop). No cutting, spindle off.

    Parameters
    ----------
    out : str or path, optional
        Output directory; ``None`` keeps ``result.recording`` in memory.
    seed : int
        Seed of every random stream (and of the loop draw with ``randomize_loop``).
    overrides : mapping, optional
        Dotted overrides (``axes.Y1.coulomb_n``).
    machine : Machine, optional
        Base machine; overrides apply on top.
    randomize_loop : bool, default False
        Draw the X/Y loop parameters with :func:`random_loop_overrides` first.
    axes, stroke_mm, feeds_mm_min
        As :func:`~cnctwin.sim.programs.axis_test_program`.
    fmt : str, default 'c4a'
        Recording format: ``'c4a'`` (Capture4Analysis JSON) or ``'parquet'`` (chunk directory).
    max_file_mb : float, optional
        Split a Capture4Analysis recording into files of at most this size [MB]; None: one file.
    chunk_cycles : int, default 50000
        Cycles simulated and written per chunk (bounds memory).
    progress : callable, optional
        Called with (fraction done 0..1, message) while the scenario runs.

    Returns
    -------
    ScenarioResult
        Truth: the machine (all loop and friction parameters), the feeds.
    """
    drawn = random_loop_overrides(seed) if randomize_loop else {}
    cfg = ScenarioConfig.build({**drawn, **dict(overrides or {})}, machine=machine)
    o = _prepare(out)
    text = axis_test_program(axes, stroke_mm=stroke_mm, feeds_mm_min=feeds_mm_min)
    prog = parse_program(text)
    res = ScenarioResult("axis_test", truth={
        **_base_truth("axis_test", seed, overrides, cfg), "loop_overrides": drawn,
        "axes": list(axes), "stroke_mm": stroke_mm, "feeds_mm_min": list(feeds_mm_min)})
    _write_program(o, "axis_test.mpf", text, res.paths)
    sink, path = _make_sink(o, "axis_test", fmt, max_file_mb)
    hook = _NoLoad(surface_z_mm=0.0, faults=(), rng=np.random.default_rng(seed), truth=None,
                   daq=None, progress=_Progress(progress, "axis test"))
    sim = _simulate(prog, cfg, seed=seed, hook=hook, sink=sink, chunk_cycles=chunk_cycles)
    _collect(res, sim, sink, path, None, None)
    _write_truth(o, res.truth, res.paths)
    return res


