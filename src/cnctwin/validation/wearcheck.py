"""Validation of the wear and tool-temperature use cases against a simulated run's hidden truth.

Issue #6 point 2: on the simulated tool-wear run (hidden wear curve) the analysis, reading only
the recording, must recover the flank-wear curve from a few measured points, show the
moving-average trend and the within-set pattern, forecast the remaining life, and the tool
temperature soft sensor must follow the camera. :func:`validate_wear` scores one run; the
truth (``ScenarioResult.truth["holes"]`` or ``holes.csv``) is used for the few "microscope"
readings, the camera-independent truth and the scoring only.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike

from cnctwin.exceptions import ConfigError
from cnctwin.recording import Recording, RecordingMeta, cycles_to_time, meta_from_dict
from cnctwin.usecases.holes import hole_record
from cnctwin.usecases.wear import (
    WearEstimator,
    forecast_remaining_life,
    moving_average,
    relative_increase,
    set_pattern,
)

__all__ = ["WearValidation", "hole_record_chunked", "validate_wear"]


@dataclass
class WearValidation:
    """Scores of the wear and tool-temperature analysis against the hidden truth.

    Attributes
    ----------
    n_holes : int
        Holes in the hole record (and in the truth).
    measured_holes : list of int
        Holes whose true wear was given to the estimator (the "microscope" readings).
    wear_rms_um, wear_max_um : float
        RMS and largest error of the estimated against the true wear per hole [µm].
    wear_rms_set_um : float
        RMS error against the set mean of the true wear (the estimator works on set means) [µm].
    final_wear_true_um, final_wear_est_um : float
        Wear at the last hole [µm].
    trend_corr : float
        Correlation of the 15-hole moving average of the estimated torque with the true wear.
    trend_rms_pct : float
        RMS difference of the relative increase of the 15-hole moving averages, estimated
        torque against true cutting torque, in percentage points [%].
    rise_est, rise_true : float
        Last vs first hole of a set (:func:`~cnctwin.usecases.wear.set_pattern`) of the
        estimated and of the true cutting torque [-].
    forecasts : pandas.DataFrame
        Per forecast point: ``at_hole``, ``n_measured`` (measured points up to it: the
        estimator is recalibrated on those only, no look-ahead), ``forecast_hole``,
        ``low``/``high`` (90 %), ``true_hole`` (true crossing of the limit), ``error_holes``.
    limit_um : float
        Wear limit of the forecast [µm].
    thermal : dict
        Soft sensor: ``tau_s``, ``c_eff_j_per_k``, ``ambient_c``, ``fit_rmse_c`` (on the
        calibration readings), ``camera_rmse_c`` (all readings), ``truth_rmse_c`` (against the
        noise-free camera temperature), ``n_calibration``; empty without camera.
    """

    n_holes: int
    measured_holes: list[int]
    wear_rms_um: float
    wear_max_um: float
    wear_rms_set_um: float
    final_wear_true_um: float
    final_wear_est_um: float
    trend_corr: float
    trend_rms_pct: float
    rise_est: float
    rise_true: float
    forecasts: pd.DataFrame
    limit_um: float
    thermal: dict[str, float] = field(default_factory=dict)
    wear_est_um: Any = None

    def table(self) -> pd.DataFrame:
        """The scores as a two-column table (quantity, value)."""
        rows: list[tuple[str, str]] = [
            ("holes", f"{self.n_holes}"),
            ("measured wear points (holes)", ", ".join(map(str, self.measured_holes))),
            ("wear RMS error [µm]", f"{self.wear_rms_um:.1f}"),
            ("wear max error [µm]", f"{self.wear_max_um:.1f}"),
            ("wear RMS error vs set-mean truth [µm]", f"{self.wear_rms_set_um:.1f}"),
            ("final wear true / estimated [µm]",
             f"{self.final_wear_true_um:.1f} / {self.final_wear_est_um:.1f}"),
            ("MA-15 trend: correlation with true wear", f"{self.trend_corr:.3f}"),
            ("MA-15 relative increase, RMS vs true torque [%-points]",
             f"{self.trend_rms_pct:.2f}"),
            ("set pattern: last vs first hole, estimated / true",
             f"{self.rise_est:+.2%} / {self.rise_true:+.2%}"),
        ]
        for r in self.forecasts.itertuples(index=False):
            rows.append((f"forecast of {self.limit_um:g} µm at hole {r.at_hole}",
                         f"hole {r.forecast_hole:.0f} (90 %: {r.low:.0f}-{r.high:.0f}), "
                         f"true {r.true_hole:.0f}, error {r.error_holes:+.0f} holes "
                         f"({r.n_measured} measured points so far)"))
        th = self.thermal
        if th:
            rows += [
                ("soft sensor tau / C_eff / ambient",
                 f"{th['tau_s']:.1f} s / {th['c_eff_j_per_k']:.1f} J/K / {th['ambient_c']:.1f} °C"),
                ("soft sensor RMS vs camera, calibration / all readings [°C]",
                 f"{th['fit_rmse_c']:.1f} / {th['camera_rmse_c']:.1f}"),
                ("soft sensor RMS vs noise-free camera temperature [°C]",
                 f"{th['truth_rmse_c']:.1f}"),
            ]
        return pd.DataFrame(rows, columns=["quantity", "value"])


def _spread(n: int, k: int, lo: float, hi: float) -> list[int]:
    return sorted({round(float(x)) for x in np.linspace(lo * (n - 1), hi * (n - 1), k)})


def validate_wear(
    holes: pd.DataFrame,
    truth_holes: pd.DataFrame,
    *,
    camera: Any = None,
    n_measured: int = 5,
    measured_range: tuple[float, float] = (0.15, 0.95),
    baseline: int | None = None,
    set_size: int = 6,
    limit_um: float = 250.0,
    forecast_at: ArrayLike = (0.6, 0.75, 0.9),
    forecast_window: float = 0.3,
    thermal_calibration_sets: int = 4,
) -> WearValidation:
    """Score the wear estimator, trend, set pattern, forecast and soft sensor of one run.

    Parameters
    ----------
    holes : pandas.DataFrame
        Hole record of the recording (:func:`~cnctwin.usecases.holes.hole_record`).
    truth_holes : pandas.DataFrame
        The simulator's per-hole truth (``hole``, ``wear_um``, ``mean_cutting_torque_nm``,
        ``tool_temperature_camera_c``), same holes in the same order.
    camera : ExternalChannel or DataFrame, optional
        Thermal-camera readings (``hole``, ``temperature_c``); enables the soft-sensor check.
    n_measured : int, default 5
        Measured wear points for the calibration, spread evenly over ``measured_range``.
    measured_range : (float, float)
        Fractions of the run between which the measured points lie.
    baseline : int, optional
        New-tool holes of :func:`~cnctwin.usecases.wear.relative_increase`; default 5 % of
        the run rounded to whole sets (at least one set).
    limit_um : float, default 250
        Wear limit of the forecast [µm] (the thesis' drill ended at ~277 µm).
    forecast_at : array-like
        Fractions of the run at which a forecast is made from the estimates so far.
    forecast_window : float, default 0.3
        The forecast fits the last ``forecast_window`` x run length holes (quadratic).
    thermal_calibration_sets : int, default 4
        Sets of camera readings used to calibrate the soft sensor (the rest is validation).

    set_size : int, default 6
        Holes per set.

    Returns
    -------
    WearValidation
    """
    from cnctwin.usecases.thermal import ToolThermalModel, merge_camera

    n = len(holes)
    if n != len(truth_holes) or n < 4 * set_size:
        raise ConfigError(f"hole record ({n}) and truth ({len(truth_holes)}) must hold the same "
                          f"holes, at least {4 * set_size}")
    true_w = truth_holes["wear_um"].to_numpy(dtype=np.float64)
    torque = holes["torque_mean_nm"].to_numpy(dtype=np.float64)
    if baseline is None:
        baseline = max(set_size, round(0.05 * n / set_size) * set_size)
    inc = relative_increase(torque, baseline=baseline, set_size=set_size)
    meas = _spread(n, n_measured, *measured_range)
    est = WearEstimator().fit(inc[meas], true_w[meas], fit_offset=True)
    w = est.predict(inc)
    err = w - true_w
    set_mean = pd.Series(true_w).groupby(np.arange(n) // set_size).transform("mean").to_numpy()
    # trend: 15-hole moving averages, relative to their first set
    ma_est = moving_average(torque, window=15)
    true_tq = truth_holes["mean_cutting_torque_nm"].to_numpy(dtype=np.float64)
    ma_true = moving_average(true_tq, window=15)
    rel_est = ma_est / np.nanmean(ma_est[:baseline]) - 1.0
    rel_true = ma_true / np.nanmean(ma_true[:baseline]) - 1.0
    trend_rms = float(np.sqrt(np.nanmean((rel_est - rel_true) ** 2))) * 100.0
    trend_corr = float(np.corrcoef(ma_est, true_w)[0, 1])
    rise_est = set_pattern(torque, set_size=set_size).rise_last_vs_first
    rise_true = set_pattern(true_tq, set_size=set_size).rise_last_vs_first
    # forecast from the estimates so far
    idx = holes["hole"].to_numpy(dtype=np.float64)
    above = np.flatnonzero(true_w >= limit_um)
    true_cross = float(idx[above[0]]) if above.size else float("inf")
    win = max(int(forecast_window * n), 4 * set_size)
    rows = []
    for f in np.atleast_1d(np.asarray(forecast_at, dtype=np.float64)):
        k = int(f * n)
        # no look-ahead: recalibrate on the measured points drilled so far
        past = [i for i in meas if i < k]
        if len(past) < 2:
            continue
        wk = WearEstimator().fit(inc[past], true_w[past], fit_offset=len(past) >= 3).predict(
            inc[:k])
        fc = forecast_remaining_life(idx[:k], wk, limit_um=limit_um, window=win, degree=2)
        rows.append({"at_hole": int(idx[k - 1]), "n_measured": len(past),
                     "forecast_hole": fc.index_at_limit,
                     "low": idx[k - 1] + fc.remaining_low, "high": idx[k - 1] + fc.remaining_high,
                     "true_hole": true_cross, "error_holes": fc.index_at_limit - true_cross})
    thermal: dict[str, float] = {}
    if camera is not None:
        merged = merge_camera(holes, camera)
        cam = merged["camera_temperature_c"].to_numpy(dtype=np.float64)
        calib = np.where(np.arange(n) < thermal_calibration_sets * set_size, cam, np.nan)
        m = ToolThermalModel().fit(merged, calib, fit_ambient=True)
        pred = m.predict(merged)
        ok = np.isfinite(cam)
        truth_t = truth_holes["tool_temperature_camera_c"].to_numpy(dtype=np.float64)
        thermal = {
            "tau_s": m.tau_s, "c_eff_j_per_k": m.c_eff_j_per_k, "ambient_c": m.ambient_c,
            "fit_rmse_c": m.rmse_c, "n_calibration": float(m.n_points),
            "camera_rmse_c": float(np.sqrt(np.mean((pred[ok] - cam[ok]) ** 2))),
            "truth_rmse_c": float(np.sqrt(np.mean((pred - truth_t) ** 2))),
        }
    return WearValidation(
        n, [int(idx[i]) for i in meas], float(np.sqrt(np.mean(err**2))),
        float(np.max(np.abs(err))), float(np.sqrt(np.mean((w - set_mean) ** 2))),
        float(true_w[-1]), float(w[-1]), trend_corr, trend_rms, rise_est, rise_true,
        pd.DataFrame(rows), limit_um, thermal, w,
    )


def hole_record_chunked(
    directory: str | Path, *, files_per_window: int = 10, verbose: bool = False
) -> pd.DataFrame:
    """Hole record of a simulator Parquet chunk directory without loading it whole.

    The full 2676-hole run is ~13 million cycles; :func:`~cnctwin.usecases.holes.hole_record`
    is run on windows of ``files_per_window`` HF chunk files plus one file of overlap, and each
    hole is taken from the window in whose main part its cut starts (a window starting in the
    middle of a hole leaves that hole to the previous window, which reaches one chunk file
    beyond). Holes are renumbered in order; sets of 6.

    Parameters
    ----------
    directory : str or path
        A :class:`~cnctwin.sim.recorder.ParquetChunkSink` directory (``meta.json``,
        ``hf_*.parquet``, ``events.parquet``).
    files_per_window : int, default 10
        HF chunk files per window (50 000 cycles each by default: 10 files ~ 300 MB).
    verbose : bool, default False
        Print one line per window.

    Returns
    -------
    pandas.DataFrame
    """
    directory = Path(directory)
    if not (directory / "meta.json").is_file():
        raise ConfigError(f"{directory} has no meta.json; pass a directory written by the "
                          "simulator's ParquetChunkSink (tool_wear_run(out, fmt='parquet'))")
    doc = json.loads((directory / "meta.json").read_text(encoding="utf-8"))
    files: list[str] = doc["hf_files"]
    anchors = meta_from_dict(doc).time_anchors
    origin = anchors[0][1]
    events = pd.read_parquet(directory / "events.parquet") if (
        directory / "events.parquet").exists() else None
    # a window starts mid-hole: holes whose cut starts in its first `margin` cycles are taken
    # from the previous window, which runs one chunk file (100 s) beyond its main part
    margin = round(10.0 / float(doc["cycle_time_s"]))
    parts = []
    for i in range(0, len(files), files_per_window):
        names = files[i:i + files_per_window + 1]  # one file of overlap
        frames = [pd.read_parquet(directory / n) for n in names]
        main_end = (int(frames[files_per_window]["cycle"].iloc[0])
                    if len(frames) > files_per_window else None)
        hf = pd.concat(frames, ignore_index=True).set_index("cycle")
        del frames
        f32 = [c for c in doc.get("float32_columns", []) if c in hf.columns]
        if f32:
            hf[f32] = hf[f32].astype(np.float64)
        if "time" not in hf.columns:
            hf.insert(0, "time", cycles_to_time(hf.index.to_numpy(), anchors,
                                                cycle_time_s=doc["cycle_time_s"]))
        c0, c1 = int(hf.index[0]), int(hf.index[-1])
        ev = None
        if events is not None and "cycle" in events.columns:
            ev = events[(events["cycle"] >= c0) & (events["cycle"] <= c1)].reset_index(drop=True)
        meta = RecordingMeta(machine=doc["machine"], cycle_time_s=doc["cycle_time_s"],
                             axis_map={int(k): v for k, v in doc["axis_map"].items()},
                             source_files=[str(directory / n) for n in names],
                             source_format=doc["source_format"], time_anchors=anchors,
                             attrs=doc["attrs"])
        rec = Recording(hf, events=ev, meta=meta)
        h = hole_record(rec, time_origin=origin, store=False)
        del rec, hf
        keep = h["cut_start_cycle"] >= (c0 + margin if i else c0)
        if main_end is not None:
            keep &= h["cut_start_cycle"] < main_end + margin
        parts.append(h[keep])
        if verbose:
            print(f"  window {i // files_per_window + 1}/"
                  f"{(len(files) + files_per_window - 1) // files_per_window}: "
                  f"{int(keep.sum())} holes", flush=True)
    out = pd.concat(parts, ignore_index=True).sort_values("cut_start_cycle")
    out = out.reset_index(drop=True)
    out["hole"] = np.arange(len(out))
    out["set"] = out["hole"] // 6
    out["position_in_set"] = out["hole"] % 6
    return out
