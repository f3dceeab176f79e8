"""Figures of thesis chapter 5 from hole records (matplotlib, Agg; each returns a Figure).

* :func:`plot_hole_means`: per-hole means and their 15-hole moving average (Figures 5.2/5.3).
* :func:`plot_set_temperature`: spindle current of one set of 6 holes with the tool-tip
  temperature per hole, measured and predicted (Figure 5.5).
* :func:`plot_deviation_paths`: desired and encoder paths per hole in 3D, X-Z, Y-Z or X-Y
  (Figures 5.6-5.9).
* :func:`plot_hole_quality`: per-hole run-out, force and tool-tip estimates (with truth).
* :func:`plot_anomaly_scores`: a detector score over time with alarms and fault onsets.
* :func:`plot_loose_tap`: Z encoder position, spindle current and dynamometer torque around a
  loose-tap event (Figure 5.10).

Figures are built on :class:`matplotlib.figure.Figure` directly (no pyplot state, no GUI
backend needed); nothing is shown or saved here: call ``fig.savefig(path)``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from numpy.typing import ArrayLike

from cnctwin.exceptions import ConfigError
from cnctwin.recording import Recording
from cnctwin.usecases.wear import moving_average

__all__ = [
    "plot_anomaly_scores",
    "plot_deviation_paths",
    "plot_hole_means",
    "plot_hole_quality",
    "plot_loose_tap",
    "plot_set_temperature",
]

_VIEWS = {"3d": ("x", "y", "z"), "xz": ("x", "z"), "yz": ("y", "z"), "xy": ("x", "y")}


def plot_hole_means(
    holes: pd.DataFrame,
    *,
    columns: Sequence[str] = ("current_mean_a", "torque_mean_nm"),
    window: int = 15,
    wear_um: ArrayLike | None = None,
) -> Figure:
    """Per-hole values with their moving average (thesis Figures 5.2 and 5.3).

    Parameters
    ----------
    holes : pandas.DataFrame
        Hole record.
    columns : sequence of str
        Columns to plot, one panel each.
    window : int, default 15
        Moving-average window [holes] (thesis Figure 5.3).
    wear_um : array-like, optional
        Estimated or measured wear per hole, drawn on a right axis of the last panel [µm].

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig = Figure(figsize=(9, 2.6 * len(columns)), layout="constrained")
    axs = fig.subplots(len(columns), 1, sharex=True, squeeze=False)[:, 0]
    x = holes["hole"].to_numpy()
    for ax, col in zip(axs, columns, strict=True):
        y = holes[col].to_numpy(dtype=np.float64)
        ax.plot(x, y, ".", ms=2, alpha=0.5, label="per hole")
        ax.plot(x, moving_average(y, window=window), "-", lw=1.5,
                label=f"moving average ({window})")
        ax.set_ylabel(col)
        ax.legend(loc="upper left", fontsize=8)
        ax.grid(alpha=0.3)
    if wear_um is not None:
        tw = axs[-1].twinx()
        tw.plot(x, np.asarray(wear_um, dtype=np.float64), "r-", lw=1, label="wear")
        tw.set_ylabel("flank wear [µm]", color="r")
    axs[-1].set_xlabel("hole")
    return fig


def plot_set_temperature(
    rec: Recording,
    holes: pd.DataFrame,
    *,
    set_index: int | None = None,
    spindle: str = "SP1",
    predicted_c: ArrayLike | None = None,
) -> Figure:
    """Spindle current of one set with the tool-tip temperature of each hole (Figure 5.5).

    Parameters
    ----------
    rec : Recording
        Recording holding the set.
    holes : pandas.DataFrame
        Hole record (with ``camera_temperature_c`` from
        :func:`~cnctwin.usecases.thermal.merge_camera` if measured).
    set_index : int, optional
        Set to draw; default the first set inside ``rec``.
    spindle : str, default 'SP1'
        Spindle axis.
    predicted_c : array-like, optional
        Soft-sensor temperature per row of ``holes`` [°C].

    Returns
    -------
    matplotlib.figure.Figure
    """
    c0, c1 = int(rec.cycles[0]), int(rec.cycles[-1])
    h = holes.copy()
    if predicted_c is not None:
        h["predicted_c"] = np.asarray(predicted_c, dtype=np.float64)
    h = h[(h["cut_start_cycle"] >= c0) & (h["cut_end_cycle"] <= c1)]
    if h.empty:
        raise ConfigError("no hole of the table lies inside this recording")
    s = int(h["set"].iloc[0]) if set_index is None else set_index
    h = h[h["set"] == s]
    if h.empty:
        raise ConfigError(f"set {s} is not in this recording")
    lo = int(h["start_cycle"].min()) - 250
    hi = int(h["end_cycle"].max()) + 250
    part = rec.select(cycles=(lo, hi))
    t0 = rec.cycles[0]
    t = (part.cycles - t0) * rec.meta.cycle_time_s
    fig = Figure(figsize=(9, 4), layout="constrained")
    ax = fig.add_subplot()
    ax.plot(t, part.hf[f"CURRENT|{spindle}"], lw=0.5, color="C0")
    ax.set_xlabel("time [s]")
    ax.set_ylabel(f"CURRENT|{spindle} [A]", color="C0")
    tw = ax.twinx()
    te = (h["end_cycle"].to_numpy() - t0) * rec.meta.cycle_time_s
    if "camera_temperature_c" in h.columns:
        tw.plot(te, h["camera_temperature_c"], "o", color="C3", label="camera")
    if "predicted_c" in h.columns:
        tw.plot(te, h["predicted_c"], "s--", color="C1", mfc="none", label="soft sensor")
    tw.set_ylabel("tool-tip temperature [°C]", color="C3")
    tw.legend(loc="upper left", fontsize=8)
    ax.set_title(f"set {s}: holes {int(h['hole'].min())}-{int(h['hole'].max())}")
    return fig


def plot_deviation_paths(
    paths: pd.DataFrame,
    *,
    view: str = "3d",
    holes: Sequence[int] | None = None,
    lateral_scale: float = 1000.0,
) -> Figure:
    """Desired vs encoder path of each hole, top of the hole at (0, 0, 0) (Figures 5.6-5.9).

    Parameters
    ----------
    paths : pandas.DataFrame
        Output of :func:`~cnctwin.usecases.quality.deviation_paths`.
    view : {'3d', 'xz', 'yz', 'xy'}
        Figure 5.6 (3D), 5.7 (X-Z), 5.8 (Y-Z) or 5.9 (X-Y).
    holes : sequence of int, optional
        Holes to draw, one panel each (a)-(f); default the first six.
    lateral_scale : float, default 1000
        X and Y are drawn in mm times this factor (1000: µm), Z in mm.

    Returns
    -------
    matplotlib.figure.Figure
    """
    if view not in _VIEWS:
        raise ConfigError(f"view must be one of {sorted(_VIEWS)}, not {view!r}")
    ids = list(holes) if holes is not None else sorted(paths["hole"].unique())[:6]
    if not ids:
        raise ConfigError("no hole to draw")
    ncol = min(3, len(ids))
    nrow = -(-len(ids) // ncol)
    fig = Figure(figsize=(4 * ncol, 3.4 * nrow), layout="constrained")
    unit = "µm" if lateral_scale == 1000.0 else f"mm x {lateral_scale:g}"
    dims = _VIEWS[view]
    for k, hid in enumerate(ids):
        p = paths[paths["hole"] == hid]
        if view == "3d":
            ax = fig.add_subplot(nrow, ncol, k + 1, projection="3d")
        else:
            ax = fig.add_subplot(nrow, ncol, k + 1)
        for kind, style in (("des", "--"), ("enc", "-")):
            vals = [p[f"{kind}_{d}_mm"].to_numpy() * (lateral_scale if d != "z" else 1.0)
                    for d in dims]
            ax.plot(*vals, style, lw=1, label="desired" if kind == "des" else "encoder")
        labels = [f"{d.upper()} [{unit if d != 'z' else 'mm'}]" for d in dims]
        ax.set_xlabel(labels[0])
        ax.set_ylabel(labels[1])
        if view == "3d":
            ax.set_zlabel(labels[2])
        ax.set_title(f"({chr(ord('a') + k)}) hole {hid}", fontsize=9)
        if k == 0:
            ax.legend(fontsize=7)
    return fig


def plot_anomaly_scores(
    time_s: ArrayLike,
    scores: ArrayLike,
    *,
    threshold: float = 0.0,
    alarms_s: Sequence[float] = (),
    fault_onsets_s: Sequence[float] = (),
    learn_until_s: float | None = None,
    title: str = "",
) -> Figure:
    """Detector score over time with threshold, alarms and true fault onsets.

    Parameters
    ----------
    time_s : array-like
        Sample times [s].
    scores : array-like
        Detector score per sample.
    threshold : float, default 0.0
        Alarm threshold.
    alarms_s : sequence, default ()
        Alarm times [s].
    fault_onsets_s : sequence, default ()
        True fault onsets [s] (simulated runs).
    learn_until_s : float, optional
        End of the teach-in [s] (shaded).
    title : str, default ''
        Figure title.

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig = Figure(figsize=(9, 3), layout="constrained")
    ax = fig.add_subplot()
    ax.plot(np.asarray(time_s), np.asarray(scores), lw=0.6)
    ax.axhline(threshold, color="k", lw=0.8, ls=":")
    for a in alarms_s:
        ax.axvline(a, color="C3", lw=0.8)
    for o in fault_onsets_s:
        ax.axvline(o, color="C2", lw=1.2, ls="--")
    if learn_until_s is not None:
        ax.axvspan(float(np.min(time_s)), learn_until_s, color="0.9")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("score")
    ax.set_title(title or "anomaly score (red: alarms, green dashed: fault onsets)")
    return fig


def _tapping_torque_on_hf(rec: Recording, z_axis: str) -> np.ndarray | None:
    """Dynamometer torque on the HF clock of a tapping recording, or None if not alignable.

    In rigid tapping the spindle current is dominated by the reversal (inertia), so the
    current-based :func:`cnctwin.twin.align_dynamometer` finds no clean lag. Here the clock
    offset comes from the engagement instead: |Mz| against "Z below the surface", the
    surface being the Z encoder position at the cut starts of the hole record.
    """
    import warnings

    from cnctwin.analysis.align import AlignmentWarning, align
    from cnctwin.usecases.holes import hole_record

    try:
        holes = hole_record(rec)
        z = rec.hf[f"ENC_POS|{z_axis}"].to_numpy(dtype=float)
        idx = np.searchsorted(rec.cycles, holes["cut_start_cycle"].to_numpy(dtype=np.int64))
        surface = float(np.median(z[np.clip(idx, 0, z.size - 1)]))
        dyn = rec.external["dynamometer"].data
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", AlignmentWarning)
            al = align(rec.time_s, (z < surface).astype(float), dyn.index.to_numpy(float),
                       np.abs(dyn["mz_nm"].to_numpy()), max_lag_s=None, polarity="positive")
    except Exception:  # no hole or no dynamometer data: leave the panel out, do not guess
        return None
    t_dyn = dyn.index.to_numpy(float) + al.lag_s
    return np.interp(rec.time_s, t_dyn, dyn["mz_nm"].to_numpy(), left=np.nan, right=np.nan)


def plot_loose_tap(
    rec: Recording,
    *,
    around_s: float,
    span_s: tuple[float, float] = (-1.0, 2.0),
    onset_s: float | None = None,
    alarms_s: Sequence[float] = (),
    z_axis: str = "Z1",
    spindle: str = "SP1",
) -> Figure:
    """Z encoder position, spindle current and dynamometer torque around an event (Fig. 5.10).

    Panels: Z ``ENC_POS``, Z following error (``DES_POS - ENC_POS``, where the fluctuation of
    the encoder position is visible at µm scale), spindle current, dynamometer torque.

    Parameters
    ----------
    rec : Recording
        Tapping recording; the dynamometer (external channel ``dynamometer``, column ``mz_nm``)
        is drawn when present, its clock aligned on the engagement (|Mz| against Z below the
        surface).
    around_s : float
        Centre of the plot, recording time from the first sample [s] (e.g. the first alarm).
    span_s : (float, float)
        Window relative to ``around_s`` [s].
    onset_s : float, optional
        True fault onset to mark [s].
    alarms_s : sequence of float
        Alarms to mark [s].

    z_axis : str, default 'Z1'
        Tapping (feed) axis.
    spindle : str, default 'SP1'
        Spindle axis name.

    Returns
    -------
    matplotlib.figure.Figure
    """
    t = rec.time_s
    sel = (t >= around_s + span_s[0]) & (t <= around_s + span_s[1])
    if not sel.any():
        raise ConfigError(f"no samples within {span_s} s of {around_s:.2f} s")
    panels: list[tuple[str, np.ndarray]] = [
        (f"ENC_POS|{z_axis} [mm]", rec.hf[f"ENC_POS|{z_axis}"].to_numpy(dtype=float)[sel]),
        (f"{z_axis} following error [µm]",
         1e3 * (rec.hf[f"DES_POS|{z_axis}"] - rec.hf[f"ENC_POS|{z_axis}"]).to_numpy()[sel]),
        (f"CURRENT|{spindle} [A]", rec.hf[f"CURRENT|{spindle}"].to_numpy(dtype=float)[sel]),
    ]
    if "dynamometer" in rec.external:
        mz = _tapping_torque_on_hf(rec, z_axis)
        if mz is not None:
            panels.append(("dynamometer torque Mz [Nm]", mz[sel]))
    fig = Figure(figsize=(9, 2.2 * len(panels)), layout="constrained")
    axs = fig.subplots(len(panels), 1, sharex=True, squeeze=False)[:, 0]
    x = t[sel]
    for ax, (label, y) in zip(axs, panels, strict=True):
        ax.plot(x, y, lw=0.7)
        ax.set_ylabel(label, fontsize=8)
        ax.grid(alpha=0.3)
        if onset_s is not None:
            ax.axvline(onset_s, color="C2", ls="--", lw=1.2)
        for a_s in alarms_s:
            if x[0] <= a_s <= x[-1]:
                ax.axvline(a_s, color="C3", lw=0.8)
    axs[-1].set_xlabel("time [s]")
    axs[0].set_title("loose tap: green dashed = true onset (hidden), red = alarm", fontsize=9)
    return fig


def plot_hole_quality(quality: pd.DataFrame, *, truth: pd.DataFrame | None = None) -> Figure:
    """Dynamic hole-quality indicators per hole (companion of Figures 5.6-5.9).

    Parameters
    ----------
    quality : pandas.DataFrame
        Output of :func:`~cnctwin.usecases.quality.hole_quality` (with ``machine`` and
        ``drill`` for the force and tool-tip panels).
    truth : pandas.DataFrame, optional
        Simulator per-hole truth (``truth.json`` ``holes``) drawn as markers.

    Returns
    -------
    matplotlib.figure.Figure
        (a) X/Y run-out at the spindle frequency [µm]; (b) estimated rotating, entry and walk
        forces [N]; (c) estimated tool-tip position error and hole oversize [µm] with the
        tolerances of ``quality.attrs``.
    """
    if "runout_um" not in quality.columns:
        raise ConfigError("quality table has no run-out columns; the hole record needs "
                          "speed_rpm (hole_quality adds them)")
    fig = Figure(figsize=(9, 8), layout="constrained")
    axs = fig.subplots(3, 1, sharex=True)
    h = quality["hole"].to_numpy()
    axs[0].plot(h, quality["runout_x_um"], ".-", label="X")
    axs[0].plot(h, quality["runout_y_um"], ".-", label="Y")
    axs[0].set_ylabel("run-out 1x [µm]")
    axs[0].legend(fontsize=7)
    pairs = (("rotating_force_est_n", "rotating_force_n", "rotating"),
             ("entry_force_est_n", "entry_force_peak_n", "entry"),
             ("walk_force_est_n", "walk_force_n", "walk"))
    for est, true, lab in pairs:
        if est in quality.columns:
            line = axs[1].plot(h, quality[est], ".-", label=f"{lab} (est.)")[0]
            if truth is not None and true in truth.columns:
                axs[1].plot(truth["hole"], truth[true], "x", color=line.get_color(),
                            label=f"{lab} (truth)")
    axs[1].set_ylabel("force [N]")
    axs[1].legend(fontsize=7, ncol=2)
    for est, true, lab, tol in (
            ("tip_position_error_est_um", "tip_position_error_um", "position error",
             "tip_tolerance_mm"),
            ("hole_oversize_est_um", "hole_oversize_um", "oversize", "oversize_tolerance_mm")):
        if est in quality.columns:
            line = axs[2].plot(h, quality[est], ".-", label=f"{lab} (est.)")[0]
            if truth is not None and true in truth.columns:
                axs[2].plot(truth["hole"], truth[true], "x", color=line.get_color(),
                            label=f"{lab} (truth)")
            if tol in quality.attrs:
                axs[2].axhline(1000.0 * float(quality.attrs[tol]), color=line.get_color(),
                               ls=":", lw=1)
    axs[2].set_ylabel("tool tip [µm]")
    axs[2].set_xlabel("hole")
    axs[2].legend(fontsize=7, ncol=2)
    return fig
