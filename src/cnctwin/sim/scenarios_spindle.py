"""Spindle scenarios of the thesis: the air-cut sweep (Sect. 3.2.2) and the warm-up runs
(Sect. 4.2)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from cnctwin.exceptions import ConfigError
from cnctwin.recording import Recording
from cnctwin.sim.config import (
    ProgressFn,
    ScenarioConfig,
    ScenarioResult,
)
from cnctwin.sim.gcode import parse_program
from cnctwin.sim.machine import Machine
from cnctwin.sim.processes import (
    _NoLoad,
    _Progress,
)
from cnctwin.sim.programs import (
    AIR_CUT_SPEEDS_RPM,
    air_cut_sweep_program,
    warm_up_program,
)
from cnctwin.sim.runner import (
    _base_truth,
    _EventTee,
    _make_sink,
    _prepare,
    _sim_seed,
    _simulate,
    _sink_files,
    _write_program,
    _write_recording,
    _write_truth,
)

__all__ = ["air_cut_sweep", "warm_up"]


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


