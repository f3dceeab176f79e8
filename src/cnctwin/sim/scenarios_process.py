"""Cutting-process scenarios of the thesis: the drilling validation cuts (Table 4.1), the
tool-wear run (Sect. 5.1) and the loose tap (Sect. 5.4)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from cnctwin.exceptions import ConfigError
from cnctwin.sim.config import (
    ProgressFn,
    ScenarioConfig,
    ScenarioResult,
    _replace,
)
from cnctwin.sim.cutting import (
    drill_torque_nm,
)
from cnctwin.sim.faults import Fault, LooseTool, fault_to_dict
from cnctwin.sim.gcode import parse_program
from cnctwin.sim.machine import Machine
from cnctwin.sim.processes import (
    DrillingProcess,
    TappingProcess,
    _DynamometerDAQ,
    _Progress,
    _TruthParquet,
)
from cnctwin.sim.programs import (
    drilling_validation_program,
    hole_pattern,
    tapping_program,
)
from cnctwin.sim.runner import (
    _base_truth,
    _collect,
    _faults_from,
    _make_sink,
    _prepare,
    _sim_seed,
    _simulate,
    _sink_files,
    _write_program,
    _write_truth,
)
from cnctwin.sim.sensors import (
    thermal_camera_channel,
    write_thermal_camera_csv,
)
from cnctwin.sim.tool import (
    flank_wear_um,
    free_cooling,
)

__all__ = ["THESIS_VALIDATION_CUTS", "drilling_validation", "loose_tap", "tool_wear_run"]


THESIS_VALIDATION_CUTS: tuple[tuple[str, float, float], ...] = (
    ("aisi1045", 2400.0, 0.16),
    ("grey_cast_iron", 2400.0, 0.30),
    ("aisi1045", 2800.0, 0.14),
    ("grey_cast_iron", 3200.0, 0.40),
    ("aisi1045", 3200.0, 0.125),
)
"""Thesis drilling cuts (§4.3 calibration + Table 4.1): material, speed [rpm], feed [mm/rev]."""


def drilling_validation(
    out: str | Path | None = None,
    *,
    seed: int = 0,
    overrides: Mapping[str, Any] | None = None,
    machine: Machine | None = None,
    depth_mm: float = 20.0,
    cuts: Sequence[tuple[str, float, float]] = THESIS_VALIDATION_CUTS,
    fmt: str = "c4a",
    max_file_mb: float | None = None,
    chunk_cycles: int = 50_000,
    progress: ProgressFn | None = None,
) -> ScenarioResult:
    """The thesis drilling cuts with the dynamometer attached (thesis §4.3, Table 4.1).

    Per cut (material, rpm, mm/rev) one program
    (:func:`~cnctwin.sim.programs.drilling_validation_program`, G95, CYCLE81, 8.5 mm carbide
    drill), one recording and one dynamometer CSV on its own clock. Truth per cut: the model's
    mean full-engagement torque, the first full-engagement cycle, the last cycle in the
    material, the simulated mean torque and the dynamometer session clock.

    Parameters
    ----------
    out : str or path-like, optional
        Output folder (recordings, ``truth.json``, sensor files); None keeps everything in memory.
    seed : int, default 0
        Random seed of the noise and of every drawn hidden value.
    overrides : mapping, optional
        Dotted machine/process parameters set on top of ``machine`` (``{"spindle.kt_nm_per_a":
        0.9}``).
    machine : Machine, optional
        Base machine description; default :meth:`Machine.thesis_default`.
    depth_mm : float, default 20.0
        Hole depth [mm].
    cuts : sequence of (str, float, float)
        (material, speed [rpm], feed [mm/rev]) per cut, in order; default the five cuts of
        thesis Table 4.1 (steel and cast iron, 2400-3200 rpm).
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
        Recordings (or their files), the hidden truth and the scenario's options.
    """
    cfg = ScenarioConfig.build(overrides, machine=machine)
    o = _prepare(out)
    res = ScenarioResult("drilling_validation",
                         truth={**_base_truth("drilling_validation", seed, overrides, cfg),
                                "depth_mm": depth_mm, "cuts": []})
    for i, (mat, n, f) in enumerate(cuts):
        if mat not in cfg.materials:
            raise ConfigError(f"cut {i}: unknown material {mat!r}; known: {sorted(cfg.materials)}")
        material = cfg.materials[mat]
        tag = f"{i + 1}_{mat}_{int(n)}rpm_{f:g}".replace(".", "p")
        text = drilling_validation_program(n, f, depth_mm)
        prog = parse_program(text)
        _write_program(o, f"drill_{tag}.mpf", text, res.paths)
        rng = np.random.default_rng([seed, i, 1])
        daq = _DynamometerDAQ(cfg.dynamometer, np.random.default_rng([seed, i, 2]), o,
                              f"dynamometer_{tag}")
        tp = _TruthParquet(o / f"truth_per_cycle_{tag}.parquet") if o is not None else None
        pf = _Progress(progress, f"{mat} {n:.0f} rpm",
                       done=i / len(cuts), share=1.0 / len(cuts))
        hook = DrillingProcess(cfg, material=material, feed_mm_per_rev=f, speed_rpm=n,
                               hole_depth_mm=depth_mm, surface_z_mm=0.0, faults=(), rng=rng,
                               truth=tp, daq=daq, progress=pf)
        sink, path = _make_sink(o, f"drill_{tag}", fmt, max_file_mb)
        sim = _simulate(prog, cfg, seed=_sim_seed(seed, i), hook=hook, sink=sink,
                        chunk_cycles=chunk_cycles)
        daq.close()
        hole = hook.hole_rows()[0] if hook.holes else {}
        res.truth["cuts"].append({
            "material": mat, "speed_rpm": n, "feed_mm_per_rev": f,
            "model_mean_torque_nm": float(drill_torque_nm(f, n, drill=cfg.drill,
                                                          material=material,
                                                          model=cfg.drilling)),
            "simulated_mean_torque_nm": hole.get("mean_cutting_torque_nm"),
            "cut_first_cycle": hole.get("cut_first_cycle"),
            "full_engagement_first_cycle": hole.get("full_engagement_first_cycle"),
            "cut_last_cycle": hole.get("cut_last_cycle"),
            "recording": path.name if path is not None else None,
            "dynamometer": daq.sessions,
        })
        _collect(res, sim, sink, path, daq, tp)
    _write_truth(o, res.truth, res.paths)
    return res


def _wear_program(n_holes: int, holes_per_set: int, gap_s: float, **kw: Any) -> str:
    """:func:`~cnctwin.sim.programs.hole_pattern` with a ``G4`` pause before each set > 1."""
    text = hole_pattern(n_holes, set_size=holes_per_set, **kw)
    if gap_s <= 0:
        return text
    lines = []
    for line in text.splitlines():
        if line.startswith("; set ") and line.strip() != "; set 1":
            lines.append(f"G4 F{gap_s:g}")
        lines.append(line)
    return "\n".join(lines) + "\n"


def tool_wear_run(
    out: str | Path | None = None,
    *,
    seed: int = 0,
    overrides: Mapping[str, Any] | None = None,
    machine: Machine | None = None,
    n_holes: int = 2676,
    holes_per_set: int = 6,
    start_hole: int = 0,
    depth_mm: float = 20.0,
    speed_rpm: float = 2400.0,
    feed_mm_per_min: float = 400.0,
    gap_between_sets_s: float = 4.0,
    cycle: str = "CYCLE81",
    walk_direction_rad: float = 0.7,
    faults: Sequence[Fault | Mapping[str, Any]] = (),
    dynamometer: bool = True,
    initial_tool_temperature_c: float | None = None,
    fmt: str = "parquet",
    max_file_mb: float | None = 500.0,
    chunk_cycles: int = 50_000,
    progress: ProgressFn | None = None,
) -> ScenarioResult:
    """Tool-wear run: AISI 1045, 20 mm holes, 2400 rpm, 400 mm/min, sets of 6 (thesis §5.1-5.3).

    Program :func:`~cnctwin.sim.programs.hole_pattern` (CYCLE81, holes in sets of
    ``holes_per_set`` along Y) with a ``G4 F gap_between_sets_s`` pause between sets (the
    spindle keeps turning, the tool cools). Streamed to ``out`` chunk by chunk with bounded
    memory: the recording (Parquet chunk directory by default, or chained Capture4Analysis
    files), the dynamometer (one CSV session per set, own clock), the thermal camera (one
    reading per hole, ``delay_s`` after extraction, own clock), ``holes.csv`` (true wear,
    temperatures, model and simulated torque per hole) and ``truth_per_cycle.parquet``.

    Machine time (default 4 s pause, [D]): per hole the feed from the R plane (2 mm above
    the surface) to 20 mm depth takes 22 mm / 400 mm/min = 3.30 s; the G0 retract to the
    10 mm retract plane, the 12 mm step to the next hole (15 mm X, 60 mm Y back between sets)
    and the G0 down to the R plane take 0.70 s with the jerk-limited rapid of the default
    machine, so 4.0 s per hole and 2676 x 4.0 s = 10 690 s = 2.97 h without pauses. The
    issue's "about 3.5 h of machining" (12 600 s; the thesis itself gives no duration) leaves
    (12 600 - 10 690) s / 445 pauses = 4.3 s per pause: ``G4 F4`` -> 12 471 s = 3.46 h as
    planned by the interpolator (the former 30 s gave 6.7 h).

    Tool temperature with 4 s pauses (lumped model, time constant R C = 24 s): the first sets
    from a cold tool rise by ~+300 degC through the set as in thesis Fig. 5.5, but after ~10
    sets the run settles at a hot level with only a ~65 K rise through each set and an equal
    drop between sets - 4 s of extra cooling against 24 s of drilling cannot reset the tool. A
    large set pattern at every set (thesis Fig. 5.3) needs pauses of the order of the time
    constant (30 s: +230 K per set, 6.7 h); pass ``gap_between_sets_s=30`` for that reading.

    Parameters
    ----------
    gap_between_sets_s : float, default 4
        ``G4`` pause before each set after the first [s].
    start_hole : int, default 0
        Holes the drill had already drilled (wear of hole k is ``flank_wear_um(start_hole+k)``).
    faults : sequence
        :class:`~cnctwin.sim.faults.ToolBreakage`, :class:`~cnctwin.sim.faults.Chatter`,
        :class:`~cnctwin.sim.faults.HardnessChange` ... (or dicts with ``type``); hole numbers
        count from ``start_hole``.
    dynamometer : bool, default True
        Record the dynamometer.
    initial_tool_temperature_c : float, optional
        Tool-tip temperature at the start [degC]; default ambient (cold tool). With
        ``start_hole`` it continues a run simulated in pieces without a cold restart (pass the
        previous piece's ``truth["final_tool_temperature_c"]``).

    out : str or path-like, optional
        Output folder (recordings, ``truth.json``, sensor files); None keeps everything in memory.
    seed : int, default 0
        Random seed of the noise and of every drawn hidden value.
    overrides : mapping, optional
        Dotted machine/process parameters set on top of ``machine`` (``{"spindle.kt_nm_per_a":
        0.9}``).
    machine : Machine, optional
        Base machine description; default :meth:`Machine.thesis_default`.
    n_holes : int, default 2676
        Holes drilled (thesis: 2676).
    holes_per_set : int, default 6
        Holes per set (one workpiece), then a pause.
    depth_mm : float, default 20.0
        Hole depth [mm].
    speed_rpm : float, default 2400.0
        Spindle speed [rpm].
    feed_mm_per_min : float, default 400.0
        Feed [mm/min].
    cycle : str, default 'CYCLE81'
        Drilling cycle of the program (``CYCLE81``, ``CYCLE83``).
    walk_direction_rad : float, default 0.7
        Direction of the drill's static walk in the X/Y plane [rad].
    fmt : str, default 'parquet'
        Recording format: ``'c4a'`` (Capture4Analysis JSON) or ``'parquet'`` (chunk directory).
    max_file_mb : float, default 500.0
        Split a Capture4Analysis recording into files of at most this size [MB]; None: one file.
    chunk_cycles : int, default 50000
        Cycles simulated and written per chunk (bounds memory).
    progress : callable, optional
        Called with (fraction done 0..1, message) while the scenario runs.

    Returns
    -------
    ScenarioResult
        Recordings (or their files), the hidden truth and the scenario's options.
    """
    cfg = ScenarioConfig.build(overrides, machine=machine)
    o = _prepare(out)
    flist = _faults_from(faults)
    feed = feed_mm_per_min / speed_rpm
    text = _wear_program(n_holes, holes_per_set, gap_between_sets_s, depth_mm=depth_mm,
                         speed_rpm=speed_rpm, feedrate_mm_min=feed_mm_per_min, cycle=cycle)
    prog = parse_program(text)
    gap_blocks = [k for k, b in enumerate(prog.blocks) if b.kind == "dwell"]
    res = ScenarioResult("tool_wear_run", truth={
        **_base_truth("tool_wear_run", seed, overrides, cfg), "n_holes": n_holes,
        "holes_per_set": holes_per_set, "start_hole": start_hole, "depth_mm": depth_mm,
        "speed_rpm": speed_rpm, "feed_mm_per_rev": feed, "feed_mm_per_min": feed_mm_per_min,
        "gap_between_sets_s": gap_between_sets_s, "cycle": cycle,
        "walk_direction_rad": walk_direction_rad, "faults": [fault_to_dict(f) for f in flist]})
    _write_program(o, "tool_wear_run.mpf", text, res.paths)
    daq = (_DynamometerDAQ(cfg.dynamometer, np.random.default_rng([seed, 2]), o, "dynamometer")
           if dynamometer else None)
    tp = _TruthParquet(o / "truth_per_cycle.parquet") if o is not None else None
    pf = _Progress(progress, "wear run")
    hook = DrillingProcess(cfg, material=cfg.materials["aisi1045"], feed_mm_per_rev=feed,
                           speed_rpm=speed_rpm, hole_depth_mm=depth_mm,
                           walk_direction_rad=walk_direction_rad, surface_z_mm=0.0,
                           faults=flist, rng=np.random.default_rng([seed, 1]), truth=tp,
                           daq=daq, daq_off_blocks=gap_blocks, progress=pf,
                           first_hole=start_hole,
                           initial_tool_temperature_c=initial_tool_temperature_c)
    sink, path = _make_sink(o, "tool_wear_run", fmt, max_file_mb)
    sim = _simulate(prog, cfg, seed=seed, hook=hook, sink=sink, chunk_cycles=chunk_cycles)
    if daq is not None:
        daq.close()
    rows = hook.hole_rows()
    th = cfg.tool_thermal
    for r in rows:
        r["set"] = (r["hole"] - start_hole) // holes_per_set
        r["position_in_set"] = (r["hole"] - start_hole) % holes_per_set
        # camera reading delay_s after extraction: the tool cools freely (the same model:
        # one node, or the tip with its holder)
        holder_c = r.get("tool_holder_temperature_extraction_c", th.ambient_temperature_c)
        r["tool_temperature_camera_c"] = free_cooling(
            r["tool_temperature_extraction_c"], holder_c, cfg.camera.delay_s, th)
    cam = None
    if rows:
        cam = thermal_camera_channel([r["extraction_s"] for r in rows],
                                     [r["hole"] for r in rows],
                                     [r["tool_temperature_camera_c"] for r in rows],
                                     camera=cfg.camera, rng=np.random.default_rng([seed, 3]))
    res.truth["holes"] = rows
    res.truth["fault_onsets_s"] = hook.onsets
    res.truth["final_wear_um"] = float(flank_wear_um(start_hole + n_holes - 1, curve=cfg.wear))
    res.truth["initial_tool_temperature_c"] = hook.initial_temperature_c
    res.truth["final_tool_temperature_c"] = hook.temperature_c
    res.truth["dynamometer_sessions"] = daq.sessions if daq is not None else []
    res.truth["n_cycles"] = sim.trajectory["n_cycles"]
    if sim.recording is not None:
        rec = sim.recording
        if daq is not None:
            for k, ch in enumerate(daq.channels):
                rec.external["dynamometer" if k == 0 else f"dynamometer_{k + 1:04d}"] = ch
        if cam is not None:
            rec.external["thermal_camera"] = cam
        res.recordings.append(rec)
        res.per_cycle.append(sim.truth["per_cycle"])
    if o is not None and path is not None:
        res.recording_paths.append(path)
        res.paths += _sink_files(sink, path)
        if daq is not None:
            res.paths += daq.paths
        if cam is not None:
            res.paths.append(write_thermal_camera_csv(cam, o / "thermal_camera.csv"))
        p = o / "holes.csv"
        pd.DataFrame(rows).to_csv(p, index=False)
        res.paths.append(p)
        if tp is not None and tp.close() is not None:
            res.paths.append(tp.path)
    _write_truth(o, res.truth, res.paths)
    return res


def loose_tap(
    out: str | Path | None = None,
    *,
    seed: int = 0,
    overrides: Mapping[str, Any] | None = None,
    machine: Machine | None = None,
    n_holes: int = 4,
    loose_from_hole: int = 2,
    depth_mm: float = 12.0,
    speed_rpm: float = 400.0,
    fmt: str = "c4a",
    max_file_mb: float | None = None,
    chunk_cycles: int = 50_000,
    progress: ProgressFn | None = None,
) -> ScenarioResult:
    """Rigid tapping M8x1.25 in steel; the tap comes loose on extraction (thesis §5.4, Fig 5.10).

    Program :func:`~cnctwin.sim.programs.tapping_program` (CYCLE84): the spindle is in position
    control coupled to Z. From hole ``loose_from_hole`` (0-based) on, a
    :class:`~cnctwin.sim.faults.LooseTool` (override its fields with ``loose_tool.<field>``)
    adds a fluctuating torque (spindle current) and axial force (Z disturbance -> Z ENC_POS)
    while the tap reverses out. Truth per hole: cut and extraction cycle ranges; fault onset.

    Parameters
    ----------
    out : str or path-like, optional
        Output folder (recordings, ``truth.json``, sensor files); None keeps everything in memory.
    seed : int, default 0
        Random seed of the noise and of every drawn hidden value.
    overrides : mapping, optional
        Dotted machine/process parameters set on top of ``machine`` (``{"spindle.kt_nm_per_a":
        0.9}``).
    machine : Machine, optional
        Base machine description; default :meth:`Machine.thesis_default`.
    n_holes : int, default 4
        Tapped holes.
    loose_from_hole : int, default 2
        First hole (0-based) whose tap slips in its holder on extraction.
    depth_mm : float, default 12.0
        Thread depth [mm].
    speed_rpm : float, default 400.0
        Tapping speed [rpm].
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
        Recordings (or their files), the hidden truth and the scenario's options.
    """
    ov = dict(overrides or {})
    lt = {k.split(".", 1)[1]: ov.pop(k) for k in list(ov) if k.startswith("loose_tool.")}
    cfg = ScenarioConfig.build(ov, machine=machine)
    fault = _replace(LooseTool(start_hole=loose_from_hole), lt, "loose_tool")
    o = _prepare(out)
    text = tapping_program(n_holes, pitch_mm=cfg.tap.pitch_mm, depth_mm=depth_mm,
                           speed_rpm=speed_rpm)
    prog = parse_program(text)
    res = ScenarioResult("loose_tap", truth={
        **_base_truth("loose_tap", seed, overrides, cfg), "n_holes": n_holes,
        "depth_mm": depth_mm, "speed_rpm": speed_rpm, "faults": [fault_to_dict(fault)]})
    _write_program(o, "loose_tap.mpf", text, res.paths)
    daq = _DynamometerDAQ(cfg.dynamometer, np.random.default_rng([seed, 2]), o, "dynamometer")
    tp = _TruthParquet(o / "truth_per_cycle.parquet") if o is not None else None
    pf = _Progress(progress, "tapping")
    hook = TappingProcess(cfg, material=cfg.materials["aisi1045"], surface_z_mm=0.0,
                          faults=(fault,), rng=np.random.default_rng([seed, 1]), truth=tp,
                          daq=daq, progress=pf)
    sink, path = _make_sink(o, "loose_tap", fmt, max_file_mb)
    sim = _simulate(prog, cfg, seed=seed, hook=hook, sink=sink, chunk_cycles=chunk_cycles)
    daq.close()
    res.truth["holes"] = hook.hole_rows()
    res.truth["fault_onsets_s"] = hook.onsets
    res.truth["dynamometer_sessions"] = daq.sessions
    _collect(res, sim, sink, path, daq, tp)
    _write_truth(o, res.truth, res.paths)
    return res


