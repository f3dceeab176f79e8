"""Ready-made simulation scenarios of the thesis experiments (one function call each).

Every scenario runs the simulator's orchestrator :func:`cnctwin.sim.simulate` on a G-code
program from :mod:`cnctwin.sim.programs` (interpolator -> spindle drive + feed-axis servo) with a
cutting-process hook built here from :mod:`~cnctwin.sim.cutting`, :mod:`~cnctwin.sim.tool` and
:mod:`~cnctwin.sim.faults`:

* drilling (:class:`DrillingProcess`): the load follows the tool-tip depth below the surface
  (expected actual Z position); the thrust is the Z disturbance force, the drill walk and the
  rotating lateral force are X/Y disturbance forces, so hole-position deviations show up in the
  X/Y ``ENC_POS`` through the servo; wear per hole, tool-tip temperature, faults;
* milling (:class:`MillingProcess`): the mechanistic end-milling forces on X/Y (Z: axial);
* rigid tapping (:class:`TappingProcess`): spindle in position control, torque reversing on
  extraction; a loose tap adds a fluctuating torque and axial force while the tap reverses.

Outputs with ``out`` (a directory):

* the recording as Capture4Analysis JSON (chained files above ``max_file_mb``) or, with
  ``fmt="parquet"``, a Parquet chunk directory (:class:`~cnctwin.sim.recorder.ParquetChunkSink`);
  both stream chunk by chunk and read back with :func:`cnctwin.read_recording`;
* external sensors on their own clocks as CSV (``dynamometer*.csv``:
  ``time_s,fx_n,fy_n,fz_n,mz_nm``; ``thermal_camera.csv``: ``time_s,hole,temperature_c``);
* ``truth.json``: every true parameter (machine incl. spindle and servo, materials, tools, wear
  curve, sensor clocks, faults and their onsets) and the per-hole / per-step ground truth;
* ``truth_per_cycle.parquet``: per-cycle hidden process values (cutting torque, thrust,
  lateral forces, tool temperature, wear, hole) of the cycles with the tool in the workpiece.

Without ``out`` everything stays in memory: ``result.recordings`` (with the external channels
attached) and ``result.per_cycle`` (the simulator's per-cycle truth incl. the process values).

Scenarios (:data:`SCENARIOS`): :func:`air_cut_sweep`, :func:`warm_up`,
:func:`drilling_validation`, :func:`tool_wear_run`, :func:`loose_tap`,
:func:`milling_square_circle`.

Overrides (every physical parameter): every :meth:`Machine.with_overrides` key
(``spindle.kt_nm_per_a``, ``axes.X1.kv_m_min_per_mm``), ``material.<key>.<field>`` and
``material.<key>.milling.<field>``, ``drill.<field>``, ``tap.<field>``, ``end_mill.<field>``,
``drilling.<field>`` (:class:`~cnctwin.sim.cutting.DrillingModel`), ``wear.<field>``
(:class:`~cnctwin.sim.tool.WearCurve`), ``tool_thermal.<field>``, ``dynamometer.<field>``,
``camera.<field>``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from cnctwin.exceptions import ConfigError
from cnctwin.recording import Recording
from cnctwin.sim.config import (
    START_CYCLE,
    START_TIME,
    ProgressFn,
    ScenarioConfig,
    ScenarioResult,
    _replace,
    random_loop_overrides,
    random_spindle_overrides,
)
from cnctwin.sim.cutting import (
    drill_torque_nm,
)
from cnctwin.sim.faults import Fault, LooseTool, fault_to_dict
from cnctwin.sim.gcode import parse_program
from cnctwin.sim.machine import Machine
from cnctwin.sim.part import drive_limits_check, part_program
from cnctwin.sim.processes import (
    DrillingProcess,
    MillingProcess,
    TappingProcess,
    _DynamometerDAQ,
    _NoLoad,
    _Progress,
    _TruthParquet,
)
from cnctwin.sim.programs import (
    AIR_CUT_SPEEDS_RPM,
    air_cut_sweep_program,
    axis_test_program,
    circle_path,
    drilling_validation_program,
    hole_pattern,
    square_path,
    tapping_program,
    warm_up_program,
)
from cnctwin.sim.recorder import ParquetChunkSink
from cnctwin.sim.runner import (
    _FORMATS,
    _base_truth,
    _collect,
    _EventTee,
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

__all__ = [
    "SCENARIOS",
    "START_CYCLE",
    "START_TIME",
    "DrillingProcess",
    "MillingProcess",
    "ScenarioConfig",
    "ScenarioResult",
    "TappingProcess",
    "air_cut_sweep",
    "axis_test",
    "drilling_validation",
    "drive_limits_check",
    "loose_tap",
    "milling_square_circle",
    "part_program",
    "random_loop_overrides",
    "random_spindle_overrides",
    "run_scenario",
    "tool_wear_run",
    "warm_up",
]


# ----------------------------------------------------------------------------- scenarios
def air_cut_sweep(
    out: str | Path | None = None,
    *,
    seed: int = 0,
    overrides: Mapping[str, Any] | None = None,
    machine: Machine | None = None,
    n_speeds: int = 126,
    max_speed_rpm: float = 18000.0,
    min_speed_rpm: float | None = None,
    speeds_rpm: Sequence[float] | None = None,
    dwell_s: float = 3.0,
    settle_s: float = 0.5,
    fmt: str = "c4a",
    max_file_mb: float | None = None,
    chunk_cycles: int = 50_000,
    progress: ProgressFn | None = None,
) -> ScenarioResult:
    """Air cut at ``n_speeds`` constant spindle speeds up to 18000 rpm (thesis §3.2.2, Fig. 3.8).

    Program :func:`cnctwin.sim.programs.air_cut_sweep_program` (``S.. M3`` then ``G4 F dwell_s`` per
    speed; the NC waits for the speed ramp). Default speeds
    :data:`~cnctwin.sim.programs.AIR_CUT_SPEEDS_RPM`; otherwise ``n_speeds`` equally spaced from
    ``min_speed_rpm`` (default ``max_speed_rpm / n_speeds``).

    Truth ``steps``: per speed the cycle range of the steady window (the dwell after
    ``settle_s``).

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
    n_speeds : int, default 126
        Number of plateaus (thesis: 126).
    max_speed_rpm : float, default 18000.0
        Highest speed [rpm].
    min_speed_rpm : float, optional
        Lowest speed [rpm]; default the first step.
    speeds_rpm : sequence, optional
        Explicit plateau speeds in order [rpm] (replaces ``n_speeds``/min/max; a speed may repeat).
    dwell_s : float, default 3.0
        Time at each speed [s].
    settle_s : float, default 0.5
        Time after a speed change before the plateau counts [s].
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
    if speeds_rpm is not None:
        speeds = np.asarray(speeds_rpm, dtype=np.float64)
        if speeds.ndim != 1 or speeds.size == 0 or not np.all(speeds > 0):
            raise ConfigError(f"speeds_rpm must be a list of positive speeds, not {speeds_rpm!r}")
    elif n_speeds == 126 and max_speed_rpm == 18000.0 and min_speed_rpm is None:
        speeds = np.asarray(AIR_CUT_SPEEDS_RPM)
    else:
        lo = min_speed_rpm if min_speed_rpm is not None else max_speed_rpm / n_speeds
        speeds = np.round(np.linspace(lo, max_speed_rpm, n_speeds), 0)
    text = air_cut_sweep_program([float(s) for s in speeds], dwell_s=dwell_s)
    prog = parse_program(text)
    res = ScenarioResult("air_cut_sweep", truth=_base_truth("air_cut_sweep", seed, overrides, cfg))
    _write_program(o, "air_cut_sweep.mpf", text, res.paths)
    sink, path = _make_sink(o, "air_cut_sweep", fmt, max_file_mb)
    tee = _EventTee(sink) if sink is not None else None
    prog_fn = _Progress(progress, "air cut")
    hook = _NoLoad(surface_z_mm=0.0, faults=(), rng=np.random.default_rng(seed), truth=None,
                   daq=None, progress=prog_fn)
    sim = _simulate(prog, cfg, seed=seed, hook=hook, sink=tee, chunk_cycles=chunk_cycles)
    if sim.recording is not None:
        events = sim.recording.events
        res.recordings.append(sim.recording)
        res.per_cycle.append(sim.truth["per_cycle"])
    else:
        assert tee is not None
        events = tee.event_table()
    res.truth["steps"] = _steady_windows(events, settle_cycles=round(settle_s /
                                                                      cfg.machine.cycle_time_s))
    res.truth["n_cycles"] = sim.trajectory["n_cycles"]
    if path is not None:
        res.recording_paths.append(path)
        res.paths += _sink_files(tee, path)
    _write_truth(o, res.truth, res.paths)
    return res


def _steady_windows(events: pd.DataFrame, *, settle_cycles: int) -> list[dict[str, Any]]:
    """Dwell windows after each ``S.. M3`` from the NC block events."""
    blocks = events[events["kind"] == "block"].sort_values("cycle", kind="stable")
    rows = blocks[["cycle", "gcode"]].to_numpy()
    out: list[dict[str, Any]] = []
    speed: float | None = None
    for k, (cyc, gcode) in enumerate(rows):
        g = str(gcode)
        for word in g.split():
            if word.startswith("S") and word[1:].replace(".", "", 1).isdigit():
                speed = float(word[1:])
        if g.startswith("G4") and speed is not None and k + 1 < len(rows):
            first = int(cyc) + settle_cycles
            last = int(rows[k + 1][0]) - 1
            if last > first:
                out.append({"speed_rpm": speed, "first_cycle": first, "last_cycle": last})
    return out


def warm_up(
    out: str | Path | None = None,
    *,
    seed: int = 0,
    overrides: Mapping[str, Any] | None = None,
    machine: Machine | None = None,
    speeds_rpm: Sequence[float] = (5000.0, 7000.0),
    minutes: float = 25.0,
    fmt: str = "c4a",
    max_file_mb: float | None = 200.0,
    chunk_cycles: int = 50_000,
    progress: ProgressFn | None = None,
) -> ScenarioResult:
    """Spindle turning ``minutes`` at each speed from a cold start (thesis §4.2, Fig. 4.4).

    One recording per speed (program :func:`cnctwin.sim.programs.warm_up_program`); the motor
    warms up and the current falls. Truth ``runs``: per minute the rotor and stator
    temperature, Kt and the friction torque. Each run is simulated in memory (it needs the
    per-cycle drive truth; ~1.5 GB peak for 25 min) and then written.

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
    speeds_rpm : sequence, default (5000.0, 7000.0)
        Speeds, one recording each, each from a cold motor [rpm].
    minutes : float, default 25.0
        Time at each speed [min].
    fmt : str, default 'c4a'
        Recording format: ``'c4a'`` (Capture4Analysis JSON) or ``'parquet'`` (chunk directory).
    max_file_mb : float, default 200.0
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
    res = ScenarioResult("warm_up", truth={**_base_truth("warm_up", seed, overrides, cfg),
                                           "minutes": minutes, "runs": []})
    ct = cfg.machine.cycle_time_s
    for i, s in enumerate(speeds_rpm):
        text = warm_up_program(float(s), minutes=minutes)
        prog = parse_program(text)
        stem = f"warm_up_{int(s)}rpm"
        _write_program(o, f"{stem}.mpf", text, res.paths)
        pf = _Progress(progress, f"{s:.0f} rpm", done=i / len(speeds_rpm),
                       share=1.0 / len(speeds_rpm))
        hook = _NoLoad(surface_z_mm=0.0, faults=(), rng=np.random.default_rng(seed), truth=None,
                       daq=None, progress=pf)
        sim = _simulate(prog, cfg, seed=_sim_seed(seed, i), hook=hook, sink=None,
                        chunk_cycles=chunk_cycles)
        rec = sim.recording
        assert rec is not None
        pc = sim.truth["per_cycle"]
        minute = round(60.0 / ct)
        pick = pc.iloc[minute - 1::minute]
        res.truth["runs"].append({
            "speed_rpm": float(s),
            "rotor_temperature_c_per_min": pick["spindle_rotor_temperature_c"].tolist(),
            "kt_nm_per_a_per_min": pick["spindle_kt_nm_per_a"].tolist(),
            "friction_nm_per_min": pick["spindle_friction_nm"].tolist(),
            "stator_temperature_c_per_min": _lf_per_minute(rec, "MOTOR_TEMP|SP1", minute),
            "recording": f"{stem}.json" if fmt == "c4a" else stem,
        })
        if o is not None:
            res.recording_paths.append(_write_recording(rec, o, stem, fmt, max_file_mb,
                                                        res.paths))
            del rec, sim, pc
        else:
            res.recordings.append(rec)
            res.per_cycle.append(pc)
    _write_truth(o, res.truth, res.paths)
    return res


def _lf_per_minute(rec: Recording, signal: str, minute: int) -> list[float]:
    lf = rec.lf
    if lf is None or not len(lf):
        return []
    s = lf[lf["signal"] == signal]
    c = s["cycle"].to_numpy() - int(rec.cycles[0])
    v = s["value"].to_numpy()
    targets = np.arange(minute - 1, int(rec.cycles[-1] - rec.cycles[0]) + 1, minute)
    idx = np.searchsorted(c, targets, side="right") - 1
    return [float(v[k]) for k in idx if k >= 0]


def _write_recording(rec: Recording, out: Path, stem: str, fmt: str,
                     max_file_mb: float | None, paths: list[Path]) -> Path:
    """Write an in-memory recording as C4A (chained) or a Parquet chunk directory."""
    if fmt not in _FORMATS:
        raise ConfigError(f"fmt must be one of {_FORMATS}, not {fmt!r}")
    if fmt == "c4a":
        from cnctwin.iotools.capture4analysis import write_capture4analysis

        path = out / f"{stem}.json"
        paths += list(write_capture4analysis(rec, path, max_file_mb=max_file_mb))
        return path
    from cnctwin.sim.recorder import RecordedChunk

    path = out / stem
    sink = ParquetChunkSink(path)
    cols = [c for c in rec.hf.columns if c != "time"]
    sink.open(cols, rec.meta)
    step = 50_000
    cyc = rec.cycles
    for a in range(0, cyc.size, step):
        part = rec.hf.iloc[a:a + step]
        lf = rec.lf if a == 0 and rec.lf is not None else pd.DataFrame(columns=["cycle"])
        ev = rec.events if a == 0 and rec.events is not None else pd.DataFrame(columns=["kind"])
        sink.write(RecordedChunk(cycles=cyc[a:a + step],
                                 hf={c: part[c].to_numpy() for c in cols}, lf=lf, events=ev))
    sink.close(rec.meta)
    paths.append(path)
    return path


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


SCENARIOS: dict[str, Callable[..., ScenarioResult]] = {
    "air_cut_sweep": air_cut_sweep,
    "warm_up": warm_up,
    "drilling_validation": drilling_validation,
    "tool_wear_run": tool_wear_run,
    "loose_tap": loose_tap,
    "milling_square_circle": milling_square_circle,
    "axis_test": axis_test,
}
"""Scenario name -> function (:func:`part_program` runs a user's program instead)."""


def run_scenario(
    name: str,
    out: str | Path | None = None,
    *,
    seed: int = 0,
    overrides: Mapping[str, Any] | None = None,
    progress: ProgressFn | None = None,
    machine: Machine | None = None,
    **options: Any,
) -> ScenarioResult:
    """Run a scenario by name (:data:`SCENARIOS`); ``options`` go to the scenario function.

    ``machine`` is the base machine (e.g. from a machine file), ``overrides`` apply on top.

    Parameters
    ----------
    name : str
        Scenario name (``cnctwin simulate --list`` prints them).
    out : str or path, optional
        Output folder; None keeps the recordings in memory.
    seed : int, default 0
        Random seed (noise, hidden parameters where the scenario draws them).
    overrides : mapping, optional
        Dotted machine parameters set on top of ``machine`` (``{"spindle.kt_nm_per_a": 0.9}``).
    progress : callable, optional
        Called with (fraction done 0..1, message) on long scenarios.
    machine : Machine, optional
        The base machine; default the simulator's machine.
    **options
        Scenario options (see the scenario's function).

    Returns
    -------
    ScenarioResult
        Recordings (or their files), the truth of the hidden parameters and the scenario's
        options.

    Raises
    ------
    ConfigError
        Unknown scenario or option (the message lists the valid ones).
    """
    import inspect

    try:
        fn = SCENARIOS[name]
    except KeyError:
        raise ConfigError(f"unknown scenario {name!r}; known: {', '.join(SCENARIOS)}") from None
    params = inspect.signature(fn).parameters
    valid = [p for p in params if p not in ("out", "seed", "overrides", "progress", "machine")]
    bad = sorted(set(options) - set(valid))
    if bad:
        raise ConfigError(f"scenario {name!r} has no option(s) {bad}; options: {valid}")
    for key, value in options.items():
        default = params[key].default
        if isinstance(default, bool):
            ok = isinstance(value, bool)
            want = "true or false"
        elif isinstance(default, int):
            ok = isinstance(value, int) and not isinstance(value, bool)
            want = "an integer"
        elif isinstance(default, float):
            ok = isinstance(value, int | float) and not isinstance(value, bool)
            want = "a number"
        elif isinstance(default, str):
            ok = isinstance(value, str)
            want = "a string"
        else:
            continue
        if not ok:
            raise ConfigError(f"scenario {name!r} option {key} must be {want} (default "
                              f"{default!r}), not {value!r}")
    if machine is not None:
        options["machine"] = machine
    return fn(out, seed=seed, overrides=overrides, progress=progress, **options)
