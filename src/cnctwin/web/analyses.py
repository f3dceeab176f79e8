"""The dashboard's use-case views: thin calls into :mod:`cnctwin.usecases` and the spindle twin.

Nothing here analyses a signal itself: the per-hole record is
:func:`cnctwin.usecases.holes.hole_records`, the trends are :mod:`cnctwin.usecases.wear`,
the tool temperature :class:`cnctwin.usecases.thermal.ToolThermalModel`,
the hole quality :func:`cnctwin.usecases.quality.hole_quality`, the anomalies a detector of
:mod:`cnctwin.usecases.anomaly` replayed by its ``backtest``, and the cutting torque
:meth:`cnctwin.spindle.SpindleModel.cutting_torque`. This module only picks the inputs, says
why a view is empty, and turns tables into JSON-ready rows.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from cnctwin.exceptions import CnctwinError, ConfigError
from cnctwin.recording import Recording, find_gaps, jsonable
from cnctwin.spindle import SpindleModel

__all__ = [
    "DETECTORS",
    "anomalies",
    "cutting_torque",
    "hole_table",
    "jsonable",
    "records",
    "trends",
]

DETECTORS: tuple[str, ...] = ("physics", "envelope", "spectral", "tapping")
"""Detectors the anomaly view offers (:mod:`cnctwin.usecases.anomaly`)."""


def records(df: pd.DataFrame) -> list[dict[str, Any]]:
    """Rows of ``df`` as JSON-ready dicts.

    Parameters
    ----------
    df : pandas.DataFrame
        A table.

    Returns
    -------
    list of dict
        JSON-ready rows.
    """
    cols = [str(c) for c in df.columns]
    return [{c: jsonable(v) for c, v in zip(cols, row, strict=True)}
            for row in df.itertuples(index=False, name=None)]


def hole_table(recs: Sequence[Recording], *, model: SpindleModel | None,
               set_size: int = 6) -> pd.DataFrame:
    """The per-hole record of recordings in time order (:func:`hole_records`).

    With ``model`` the torque columns use the calibrated spindle twin; without it the
    library's default (thesis parameter set, noted in ``attrs["spindle_model"]``).

    Parameters
    ----------
    recs : sequence
        Recordings in time order.
    model : SpindleModel, optional
        Spindle model for the torque; default the thesis machine's.
    set_size : int, default 6
        Holes per set.

    Returns
    -------
    pandas.DataFrame
    """
    from cnctwin.usecases.holes import hole_records

    return hole_records(list(recs), model=model, set_size=set_size)


def trends(holes: pd.DataFrame, recs: Sequence[Recording], *, set_size: int = 6,
           baseline: int = 30, window: int = 15) -> dict[str, Any]:
    """Per-hole trends: torque and current with moving averages, relative increase (wear
    indicator), within-set pattern, tool temperature, hole quality.

    Each part that cannot be computed is replaced by a note saying why (too few holes, no
    camera channel, ...), never by invented values.

    Parameters
    ----------
    holes : pandas.DataFrame
        Hole table.
    recs : sequence
        The recordings (camera channel).
    set_size : int, default 6
        Holes per set.
    baseline : int, default 30
        New-tool holes for the relative increase.
    window : int, default 15
        Moving-average window [holes].

    Returns
    -------
    dict
        Trend arrays, set pattern, tool temperature, hole quality and notes.
    """
    from cnctwin.usecases.wear import moving_average, relative_increase, set_pattern

    out: dict[str, Any] = {"n_holes": len(holes), "notes": []}
    notes: list[str] = out["notes"]
    if holes.empty:
        notes.append("no hole in this recording (no plunge of the Z axis)")
        return out
    torque = holes["torque_mean_nm"].to_numpy(dtype=np.float64)
    current = holes["current_mean_a"].to_numpy(dtype=np.float64)
    out["hole"] = holes["hole"].to_numpy().tolist()
    out["torque_mean_nm"] = torque
    out["current_mean_a"] = current
    out["window"] = window
    if len(holes) >= window:
        out["torque_ma_nm"] = moving_average(torque, window=window)
        out["current_ma_a"] = moving_average(current, window=window)
    else:  # a centred window over all of them is one flat line: not a trend
        notes.append(f"{window}-hole moving average needs at least {window} holes "
                     f"(this has {len(holes)})")
    out["energy_j"] = holes["energy_j"].to_numpy(dtype=np.float64)
    base = min(baseline, len(holes))
    try:
        out["relative_increase"] = relative_increase(
            torque, baseline=base, set_size=set_size if len(holes) >= set_size else None)
        out["baseline_holes"] = base
    except CnctwinError as exc:
        notes.append(f"relative increase not computed: {exc}")
    if len(holes) >= set_size:
        pat = set_pattern(torque, set_size=set_size)
        out["set_pattern"] = {"position_mean": pat.position_mean, "n_sets": pat.n_sets,
                              "rise_last_vs_first": pat.rise_last_vs_first}
    else:
        notes.append(f"within-set pattern needs one complete set of {set_size} holes")
    out["temperature"] = _temperature(holes, recs, notes)
    out["quality"] = _quality(holes, recs, notes)
    return {k: jsonable(v) if k not in ("notes",) else v for k, v in out.items()}


def _temperature(holes: pd.DataFrame, recs: Sequence[Recording],
                 notes: list[str]) -> dict[str, Any] | None:
    from cnctwin.usecases.thermal import ToolThermalModel, merge_camera

    cams = [r.external["thermal_camera"] for r in recs if "thermal_camera" in r.external]
    if not cams:
        notes.append("tool temperature: no thermal-camera channel to calibrate the soft sensor "
                     "(ToolThermalModel needs camera readings)")
        return None
    if len(cams) != len(recs):
        notes.append("tool temperature: only some recordings have a camera channel; not shown")
        return None
    try:
        cam_df = pd.concat([c.data for c in cams])
        merged = merge_camera(holes, cam_df if len(cams) > 1 else cams[0])
        camera = merged["camera_temperature_c"].to_numpy(dtype=np.float64)
        model = ToolThermalModel().fit(merged, camera, fit_ambient=True)
        return {"hole": merged["hole"].to_numpy(), "camera_c": camera,
                "predicted_c": model.predict(merged), "tau_s": model.tau_s,
                "c_eff_j_per_k": model.c_eff_j_per_k, "ambient_c": model.ambient_c,
                "rmse_c": model.rmse_c, "n_points": model.n_points}
    except CnctwinError as exc:
        notes.append(f"tool temperature not computed: {exc}")
        return None


def _quality(holes: pd.DataFrame, recs: Sequence[Recording],
             notes: list[str]) -> list[dict[str, Any]] | None:
    from cnctwin.usecases.quality import hole_quality

    parts = []
    for r in recs:
        c0, c1 = int(r.cycles[0]), int(r.cycles[-1])
        mine = holes[(holes["cut_start_cycle"] >= c0) & (holes["cut_end_cycle"] <= c1)]
        if mine.empty:
            continue
        try:
            parts.append(hole_quality(r, mine))
        except CnctwinError as exc:
            notes.append(f"hole quality not computed: {exc}")
            return None
    return records(pd.concat(parts, ignore_index=True)) if parts else None


def cutting_torque(rec: Recording, model: SpindleModel, *, spindle: str = "SP1",
                   ) -> tuple[NDArray[np.float64], str]:
    """Cutting torque of every HF sample from the calibrated spindle twin [Nm].

    ``SpindleModel.cutting_torque`` is applied to each gap-free run of cycles separately so
    the inertia term's dOmega/dt is never taken across missing cycles. Returns the torque and
    the speed source used.

    Parameters
    ----------
    rec : Recording
        The recording.
    model : SpindleModel
        Calibrated spindle model.
    spindle : str, default 'SP1'
        Spindle axis name.

    Returns
    -------
    tuple
        (torque per HF row [Nm], the speed signal used).
    """
    from cnctwin.analysis.segments import spindle_speed_rpm

    cur_col = f"CURRENT|{spindle}"
    if not rec.has(cur_col):
        raise ConfigError(f"cutting torque needs {cur_col}; this recording has no spindle "
                          "current")
    current = rec.hf[cur_col].to_numpy(dtype=np.float64)
    speed, source = spindle_speed_rpm(rec, spindle)
    out = np.empty(current.size)
    cyc = rec.cycles
    starts = [0] + [int(np.searchsorted(cyc, g.before_cycle)) for g in find_gaps(cyc)]
    ends = [*starts[1:], cyc.size]
    for a, b in zip(starts, ends, strict=True):
        with np.errstate(invalid="ignore"):
            out[a:b] = model.cutting_torque(current[a:b], speed[a:b], fs_hz=rec.fs_hz)
    return out, source


def anomalies(recs: Sequence[Recording], holes: pd.DataFrame, *, detector: str = "physics",
              learn_s: float | None = None, threshold: float = 0.0) -> dict[str, Any]:
    """Replay recordings through a detector: teach on the first part, score the rest.

    The replay of ``cnctwin anomalies`` (:func:`~cnctwin.usecases.replay.replay_detector`)
    with the scores of a clone taught on the same rows, for the detectors the page offers
    (:data:`DETECTORS`).

    Parameters
    ----------
    recs : sequence
        Recordings in time order.
    holes : pandas.DataFrame
        Their hole table.
    detector : str, default 'physics'
        Detector name (``physics``, ``envelope``, ``spectral``, ``tapping``).
    learn_s : float, optional
        Teach-in length [s]; default the first third.
    threshold : float, default 0.0
        Alarm threshold; 0 = the detector's own.

    Returns
    -------
    dict
        Alarms, scores (decimated) and notes.
    """
    from cnctwin.usecases.replay import replay_detector

    if detector not in DETECTORS:
        raise ConfigError(f"detector {detector!r} is not known; use one of "
                          f"{', '.join(DETECTORS)}")
    rep = replay_detector(recs, holes, detector=detector, learn_until_s=learn_s,
                          threshold=threshold, scores=True)
    res = rep.result
    return {
        "detector": repr(rep.detector), "learn_until_s": rep.learn_until_s,
        "threshold": threshold, "monitored_s": res.monitored_s, "alarms_s": res.alarms_s,
        "alarm_holes": rep.alarm_holes, "score_time_s": rep.score_time_s, "score": rep.score,
        "issues": rep.issues,
    }
