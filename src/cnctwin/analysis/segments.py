"""Segmentation of recordings: cutting regions and constant-speed plateaus.

* :func:`cutting_regions` finds where the tool cuts: the smoothed spindle current rises above
  its air-cut level (Schmitt trigger with hysteresis), optionally confirmed by the Z axis
  moving down into the part and labelled with the NC block active at the start.
* :func:`speed_plateaus` finds the constant-speed plateaus of an air-cut sweep (thesis §3.2.2:
  126 speeds up to 18000 rpm), excluding run-up transients.

Both read only the :class:`~cnctwin.recording.Recording` and return one row per segment with
``start_cycle``/``end_cycle`` (inclusive, on the unwrapped cycle counter).
"""

from __future__ import annotations

import itertools

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray

from cnctwin._jit import lazy_njit
from cnctwin.analysis.filters import lowpass
from cnctwin.exceptions import ConfigError, SignalNotFoundError
from cnctwin.recording import Recording
from cnctwin.signals import lookup, parse_column

__all__ = [
    "centered_mean",
    "cutting_regions",
    "hysteresis_mask",
    "lf_on_hf",
    "runs",
    "runs_of",
    "samples_since",
    "speed_plateaus",
    "spindle_actual_speed_rpm",
    "spindle_speed_rpm",
]

SEGMENT_COLUMNS: tuple[str, ...] = ("start_cycle", "end_cycle", "duration_s", "start_s", "end_s")


def hysteresis_mask(x: ArrayLike, *, high: float, low: float) -> NDArray[np.bool_]:
    """Schmitt trigger: True from where ``x > high`` until ``x < low``.

    Parameters
    ----------
    x : array-like
        Signal.
    high : float
        Switch-on threshold.
    low : float
        Switch-off threshold (``low <= high``).

    Returns
    -------
    numpy.ndarray of bool
        State per sample; the state before the first crossing is off.

    Examples
    --------
    >>> hysteresis_mask([0, 2, 1.5, 0.9, 1.5, 0], high=1.8, low=1.0).tolist()
    [False, True, True, False, False, False]
    """
    if low > high:
        raise ConfigError(f"low threshold {low} must not exceed high threshold {high}")
    v = np.asarray(x, dtype=np.float64)
    state = np.where(v > high, 1, np.where(v < low, 0, -1))
    idx = np.where(state >= 0, np.arange(v.size), -1)
    np.maximum.accumulate(idx, out=idx)
    out = np.zeros(v.size, dtype=bool)
    known = idx >= 0
    out[known] = state[idx[known]] == 1
    return out


def runs(mask: ArrayLike) -> NDArray[np.int64]:
    """Start and end (inclusive) indices of the True runs of a boolean array, shape (n, 2).

    Parameters
    ----------
    mask : array-like
        Boolean per sample.

    Returns
    -------
    numpy.ndarray
        ``(k, 2)`` first and last index (inclusive) of each run of True.
    """
    m = np.asarray(mask, dtype=bool)
    if m.size == 0:
        return np.empty((0, 2), dtype=np.int64)
    d = np.diff(np.concatenate([[0], m.astype(np.int8), [0]]))
    starts = np.flatnonzero(d == 1)
    ends = np.flatnonzero(d == -1) - 1
    return np.column_stack([starts, ends]).astype(np.int64)


def runs_of(values: ArrayLike) -> list[tuple[int, int, int]]:
    """Runs of equal values: ``(value, first, end)`` per run, in order (tools, blocks).

    Parameters
    ----------
    values : array-like of int
        One value per cycle (the active tool, the block index).

    Returns
    -------
    list of (int, int, int)
        The run's value, its first index and one past its last.
    """
    v = np.asarray(values, dtype=np.int64)
    if v.size == 0:
        return []
    b = np.concatenate([[0], np.flatnonzero(np.diff(v)) + 1, [v.size]])
    return [(int(v[lo]), int(lo), int(hi)) for lo, hi in itertools.pairwise(b)]


def samples_since(mask: ArrayLike, *, before: int) -> NDArray[np.int64]:
    """Samples since the last True at or before each sample, carried across blocks.

    Parameters
    ----------
    mask : array-like of bool
        Events per sample (a speed change, an axis moving, ...).
    before : int
        Samples since the last event at the end of the previous block (a large number if
        there was none); the block's first sample counts ``before + 1`` without an event.

    Returns
    -------
    numpy.ndarray of int64
        0 at an event, then 1, 2, ...; pass the last value as ``before`` of the next block.

    Examples
    --------
    >>> samples_since([False, True, False, False], before=5).tolist()
    [6, 0, 1, 2]
    """
    m = np.ascontiguousarray(mask, dtype=np.bool_).reshape(-1)
    out = np.empty(m.size, dtype=np.int64)
    _since(m, int(before), out)
    return out


def _since_py(m: NDArray[np.bool_], before: int, out: NDArray[np.int64]) -> int:
    """:func:`samples_since` as one loop (compiled: the edge calls it on every chunk);
    returns the last count."""
    c = before
    for k in range(m.size):
        c = 0 if m[k] else c + 1
        out[k] = c
    return c


_since = lazy_njit(_since_py)


def lf_on_hf(rec: Recording, code: str, axis: str | None) -> pd.Series | None:
    """An LF drive value (catalog code or alias) held on the HF cycles, or None if absent.

    LF signal names are matched by catalog code or alias (``IQ_ACT``, ``r0078``,
    ``ActualIq``) with an optional ``|AXIS`` suffix that must equal ``axis`` when present.

    Parameters
    ----------
    rec : Recording
        The recording.
    code : str
        Low-frequency signal code.
    axis : str, optional
        Axis name, or None for a channel signal.

    Returns
    -------
    pandas.Series or None
        The value held on each HF row; None if not recorded.
    """
    if rec.lf.empty:
        return None
    names = [str(s) for s in rec.lf["signal"].unique()]
    hits: list[str] = []
    for name in names:
        base, ax = parse_column(name)
        try:
            spec = lookup(base)
        except SignalNotFoundError:
            continue
        if spec.code == code and (ax is None or axis is None or ax == axis):
            hits.append(name)
    if not hits:
        return None
    hits.sort(key=lambda n: 0 if n.endswith(f"|{axis}") else 1)
    wide = rec.lf_wide()
    return wide[hits[0]].rename(f"{code}|{axis}" if axis else code)


def spindle_speed_rpm(rec: Recording, spindle: str = "SP1", *, prefer_actual: bool = False
                      ) -> tuple[NDArray[np.float64], str]:
    """Spindle speed on the HF cycles and where it came from.

    Uses the HF speed command ``CMD_SPEED|<spindle>`` if present, else the LF smoothed actual
    speed (``SPEED_SMOOTHED``, r0063) held on the HF rows, else an HF actual speed
    ``SPEED_ACT|<spindle>`` in rpm (the KIT merged files). With ``prefer_actual`` the
    encoder's speed (:func:`spindle_actual_speed_rpm`) comes first.

    Parameters
    ----------
    rec : Recording
        The recording.
    spindle : str, default 'SP1'
        Spindle axis name.
    prefer_actual : bool, default False
        The rotor's own speed from ``ENC_POS`` where recorded (what ``J dOmega/dt`` needs;
        the command leads it by the speed loop's lag).

    Returns
    -------
    speed_rpm : numpy.ndarray
        Speed [rpm] per HF row (NaN before the first LF value).
    source : str
        Column used.

    Raises
    ------
    SignalNotFoundError
        If neither is recorded.
    """
    if prefer_actual:
        enc = spindle_actual_speed_rpm(rec, spindle)
        if enc is not None:
            return enc, f"d(ENC_POS|{spindle})/dt"
    col = f"CMD_SPEED|{spindle}"
    if rec.has(col):
        return rec.hf[col].to_numpy(dtype=np.float64), col
    lf = lf_on_hf(rec, "SPEED_SMOOTHED", spindle)
    if lf is not None:
        return lf.to_numpy(dtype=np.float64), f"SPEED_SMOOTHED|{spindle} (LF)"
    act = f"SPEED_ACT|{spindle}"
    if rec.has(act) and rec.meta.units.get(act, "rpm") == "rpm":
        return rec.hf[act].to_numpy(dtype=np.float64), act
    raise SignalNotFoundError(
        f"no spindle speed for {spindle!r}: neither HF {col!r} nor the LF smoothed speed "
        f"(SPEED_SMOOTHED / r0063) is recorded; HF columns: {', '.join(rec.columns)}"
    )


def spindle_actual_speed_rpm(rec: Recording, spindle: str = "SP1") -> NDArray[np.float64] | None:
    """Actual spindle speed from its encoder angle ``ENC_POS|<spindle>`` [rpm], or None.

    The angle is recorded modulo 360 deg; each cycle's increment is unwrapped to the whole
    turns nearest what the speed command (``CMD_SPEED``, if recorded) makes it turn, so speeds
    above 15 000 rpm (more than half a turn per 2 ms cycle) come out right too. The speed of
    a cycle is the central difference of the unwrapped angle (the backward one at the ends).

    Parameters
    ----------
    rec : Recording
        The recording.
    spindle : str, default 'SP1'
        Spindle axis name.

    Returns
    -------
    numpy.ndarray or None
        Speed [rpm] per HF row (NaN where the angle is missing or next to a counter gap);
        None when ``ENC_POS|<spindle>`` is not recorded in degrees.

    Notes
    -----
    The physics of the rotor, ``J dOmega/dt = tau_m - tau_friction``, holds for the actual
    speed: the command leads it by the speed loop's lag, which on 0.1 s run-ups of an air
    cut biases an inertia fitted on the command by several per cent.
    """
    col = f"ENC_POS|{spindle}"
    if not rec.has(col) or rec.meta.units.get(col, "deg") != "deg":
        return None
    ang = rec.hf[col].to_numpy(dtype=np.float64)
    if ang.size < 2:
        return np.full(ang.size, np.nan)
    dt = rec.meta.cycle_time_s
    step = rec.cycles[1:] - rec.cycles[:-1]
    d = np.diff(ang)
    cmd_col = f"CMD_SPEED|{spindle}"
    expect = np.zeros(d.size)
    if rec.has(cmd_col):
        c = rec.hf[cmd_col].to_numpy(dtype=np.float64)
        expect = np.nan_to_num(0.5 * (c[1:] + c[:-1])) * 6.0 * dt  # deg per cycle
    d = d - 360.0 * np.round((d - expect) / 360.0)
    d[step != 1] = np.nan  # a counter gap: the turns in between are unknown
    v = np.full(ang.size, np.nan)
    v[1:-1] = 0.5 * (d[1:] + d[:-1])
    v[0], v[-1] = d[0], d[-1]
    return v / (6.0 * dt)


def _segments_frame(
    rec: Recording, spans: NDArray[np.int64], extra: dict[str, list[object]] | None = None
) -> pd.DataFrame:
    c = rec.cycles
    t = rec.time_s
    starts = spans[:, 0] if spans.size else np.empty(0, dtype=np.int64)
    ends = spans[:, 1] if spans.size else np.empty(0, dtype=np.int64)
    df = pd.DataFrame(
        {
            "start_cycle": c[starts],
            "end_cycle": c[ends],
            "duration_s": (c[ends] - c[starts] + 1) * rec.meta.cycle_time_s,
            "start_s": t[starts],
            "end_s": t[ends],
        }
    )
    for k, v in (extra or {}).items():
        df[k] = pd.Series(v, index=df.index)
    return df


def centered_mean(x: ArrayLike, window: int) -> NDArray[np.float64]:
    """Mean over a centred window of ``window`` samples, fewer at the ends and without NaNs.

    pandas' ``Series.rolling(window, center=True, min_periods=1).mean()`` (sample i averages
    the finite values of i - window//2 to i + (window-1)//2; NaN where there are none) from
    two cumulative sums, without a Series (~0.2 ms less per call of a few thousand samples).

    Parameters
    ----------
    x : array-like of float
        Samples (finite or NaN).
    window : int
        Window length [samples] (at least 1).

    Returns
    -------
    numpy.ndarray of float64
        The means, as long as ``x``.
    """
    a = np.asarray(x, dtype=np.float64).ravel()
    w = max(int(window), 1)
    n = a.size
    ok = ~np.isnan(a)
    c = np.concatenate(([0.0], np.cumsum(np.where(ok, a, 0.0))))
    k = np.concatenate(([0], np.cumsum(ok)))
    i = np.arange(n)
    lo = np.maximum(i - w // 2, 0)
    hi = np.minimum(i + (w - 1) // 2 + 1, n)
    cnt = k[hi] - k[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        out: NDArray[np.float64] = np.where(cnt > 0, (c[hi] - c[lo]) / cnt, np.nan)
    return out


def _rolling(x: NDArray[np.float64], n: int, how: str) -> NDArray[np.float64]:
    if how == "mean":
        return centered_mean(x, n)
    s = pd.Series(x).rolling(max(int(n), 1), center=True, min_periods=1)
    return np.asarray(getattr(s, how)().to_numpy(), dtype=np.float64)


def speed_plateaus(
    rec: Recording,
    *,
    spindle: str = "SP1",
    tolerance_rpm: float = 5.0,
    min_duration_s: float = 1.0,
    settle_s: float = 0.5,
    min_speed_rpm: float = 1.0,
    window_s: float = 0.2,
) -> pd.DataFrame:
    """Constant-speed plateaus of the spindle (air-cut sweep), run-ups excluded.

    Parameters
    ----------
    rec : Recording
        Recording with ``CMD_SPEED|<spindle>`` (or the LF smoothed speed).
    spindle : str, default 'SP1'
        Spindle axis name.
    tolerance_rpm : float, default 5.0
        Largest speed change inside a ``window_s`` window that still counts as constant [rpm].
    min_duration_s : float, default 1.0
        Shortest plateau kept (after removing ``settle_s``) [s].
    settle_s : float, default 0.5
        Time cut from the start of each plateau so the speed loop and the current have
        settled after the run-up [s].
    min_speed_rpm : float, default 1.0
        Plateaus slower than this (spindle stopped) are dropped [rpm].
    window_s : float, default 0.2
        Width of the centred window used to test constancy [s].

    Returns
    -------
    pandas.DataFrame
        One row per plateau: ``start_cycle``, ``end_cycle`` (inclusive), ``duration_s``,
        ``start_s``, ``end_s``, ``speed_rpm`` (median), ``speed_std_rpm``, ``n_cycles``,
        sorted by time. ``attrs['speed_source']`` names the speed column used.

    Notes
    -----
    A sample is steady when the speed's max-min over the centred window is at most
    ``tolerance_rpm``; runs of steady samples are split wherever the median level changes by
    more than ``tolerance_rpm`` between consecutive samples (a jump without ramp). Counter gaps
    split plateaus as well.
    """
    speed, source = spindle_speed_rpm(rec, spindle)
    if speed.size == 0:
        raise ConfigError("recording has no HF cycles")
    n_win = max(3, round(window_s * rec.fs_hz))
    filled = np.asarray(pd.Series(speed).ffill().bfill(), dtype=np.float64)
    rng = _rolling(filled, n_win, "max") - _rolling(filled, n_win, "min")
    steady = (rng <= tolerance_rpm) & np.isfinite(speed) & (np.abs(filled) >= min_speed_rpm)
    # split on counter gaps
    c = rec.cycles
    gap_after = np.zeros(c.size, dtype=bool)
    gap_after[:-1] = np.diff(c) > 1
    steady_split = steady.copy()
    spans_list: list[tuple[int, int]] = []
    for s, e in runs(steady_split):
        cut = np.flatnonzero(gap_after[s:e])
        bounds = [s, *(s + cut + 1).tolist(), e + 1]
        for a, b in itertools.pairwise(bounds):
            spans_list.append((a, b - 1))
    n_settle = round(settle_s * rec.fs_hz)
    n_min = round(min_duration_s * rec.fs_hz)
    rows: list[tuple[int, int]] = []
    med: list[float] = []
    std: list[float] = []
    for s, e in spans_list:
        s2 = s + n_settle
        e2 = e - n_win // 2
        if e2 - s2 + 1 < max(n_min, 1):
            continue
        seg = speed[s2 : e2 + 1]
        rows.append((s2, e2))
        med.append(float(np.median(seg)))
        std.append(float(np.std(seg)))
    spans = np.asarray(rows, dtype=np.int64).reshape(-1, 2)
    df = _segments_frame(rec, spans)
    df["speed_rpm"] = med
    df["speed_std_rpm"] = std
    df["n_cycles"] = (spans[:, 1] - spans[:, 0] + 1) if spans.size else []
    df.attrs["speed_source"] = source
    return df


def cutting_regions(
    rec: Recording,
    *,
    spindle: str = "SP1",
    z_axis: str | None = "Z1",
    current_threshold: float | None = None,
    min_duration_s: float = 0.2,
    smooth_hz: float = 5.0,
    hysteresis: float = 0.5,
    baseline_quantile: float = 0.1,
    accel_limit_rpm_per_s: float = 200.0,
    merge_gap_s: float = 0.1,
    require_z_down: bool = True,
    min_z_depth_mm: float = 0.01,
    air_from_z: bool = True,
    z_feed_mm_per_s: float = 0.2,
) -> pd.DataFrame:
    """Cutting regions: spindle current above its air-cut level while the spindle turns.

    Parameters
    ----------
    rec : Recording
        Recording with ``CURRENT|<spindle>``; ``CMD_SPEED|<spindle>`` (or the LF speed) and
        ``ENC_POS|<z_axis>`` are used when present.
    spindle : str, default 'SP1'
        Spindle axis name.
    z_axis : str or None, default 'Z1'
        Feed axis into the part; ``None`` ignores axis positions.
    current_threshold : float, optional
        Switch-on threshold on the excess current |I| - baseline [A]. Default: automatic,
        the larger of 8 robust standard deviations of the air-cut excess and 30 % of the
        99.5th percentile of the excess.
    min_duration_s : float, default 0.2
        Shortest region kept [s].
    smooth_hz : float, default 5.0
        Zero-phase low-pass applied to |I| before thresholding [Hz].
    hysteresis : float, default 0.5
        Switch-off threshold as a fraction of the switch-on threshold.
    baseline_quantile : float, default 0.1
        Without air samples from the Z axis (see ``air_from_z``), the air-cut baseline at
        each commanded speed is this quantile of the smoothed |I| at that speed (speeds
        rounded to 10 rpm); this assumes the spindle spends at least this fraction of its
        time at each cutting speed in air.
    accel_limit_rpm_per_s : float, default 200.0
        Samples where the commanded speed changes faster than this (run-ups, where the
        inertia draws current) are never cutting [rpm/s].
    merge_gap_s : float, default 0.1
        Regions separated by less than this are merged [s].
    require_z_down : bool, default True
        If the Z position is recorded, keep only regions during which Z moves down into the
        part: the lowest Z inside the region is at least ``min_z_depth_mm`` below the Z at
        its start (a retract at the end does not matter).
    min_z_depth_mm : float, default 0.01
        Smallest downward Z travel that confirms a cut [mm].
    air_from_z : bool, default True
        If the Z position is recorded, take the air-cut level and the noise from the
        samples where the spindle turns at constant speed and Z does *not* feed down (a
        drill can only cut while it moves into the part; ``1 / smooth_hz`` is left out
        around every downward move, where the smoothing rings): per speed the mean |I| of
        those samples is the baseline, the robust spread of the smoothed |I| the noise.
        Where fewer than 0.1 s of such samples exist at a speed, ``baseline_quantile``
        applies.
    z_feed_mm_per_s : float, default 0.2
        Z speed below ``-z_feed_mm_per_s`` counts as feeding down [mm/s].

    Returns
    -------
    pandas.DataFrame
        One row per region: ``start_cycle``, ``end_cycle`` (inclusive), ``duration_s``,
        ``start_s``, ``end_s``, ``speed_rpm`` (median commanded), ``mean_current_a``,
        ``baseline_a`` (air-cut level), ``z_start_mm``, ``z_end_mm`` (NaN without Z),
        ``block`` (NC block active at the start, "" without events). ``attrs`` hold the
        thresholds used and ``noise_from`` ('z_air', 'lower_half' or 'rolling_std').

    Notes
    -----
    Thesis §4.3 averages current and torque over the first 0.6 s of each cutting region
    (Fig. 4.5); the regions here provide those starts.

    In a one-hole recording (thesis Fig. 4.5) the drill is in the material for most of the
    time at speed, so statistics of all samples at the cutting speed describe the cut, not
    the air: their lower half is cut current and an 8-sigma threshold from it lies above
    the cut. The air level therefore comes from the Z axis (samples not feeding down)
    where it is recorded; without Z the noise is the smaller of the lower-half spread and
    the 10th percentile of the 0.4 s rolling standard deviation of the smoothed current
    (a stretch of air is quiet, a cut is not).
    """
    i_col = f"CURRENT|{spindle}"
    current = rec.signal(i_col).to_numpy(dtype=np.float64)
    if current.size < 8:
        raise ConfigError(f"recording has only {current.size} cycles; cannot segment")
    fs = rec.fs_hz
    a = np.abs(pd.Series(current).interpolate(limit_direction="both").to_numpy())
    sm = lowpass(a, smooth_hz, fs_hz=fs, order=2) if a.size > 30 else a
    try:
        speed, _ = spindle_speed_rpm(rec, spindle)
        speed = np.asarray(pd.Series(speed).ffill().bfill().fillna(0.0), dtype=np.float64)
    except SignalNotFoundError:
        speed = np.full(a.size, np.nan)
    has_speed = bool(np.isfinite(speed).all())
    z_col = f"ENC_POS|{z_axis}" if z_axis else None
    z = rec.hf[z_col].to_numpy(dtype=np.float64) if z_col and rec.has(z_col) else None
    air = _air_from_z(z, fs, z_feed_mm_per_s, 1.0 / smooth_hz) \
        if z is not None and air_from_z else None
    if has_speed:
        key = np.round(speed / 10.0) * 10.0
        baseline = np.empty_like(sm)
        accel = np.gradient(lowpass(speed, min(10.0, 0.4 * fs), fs_hz=fs, order=2)
                            if speed.size > 30 else speed) * fs
        dilate = max(1, round(0.3 * fs))
        ramp = _rolling((np.abs(accel) > accel_limit_rpm_per_s).astype(np.float64),
                        2 * dilate + 1, "max") > 0
        turning = (np.abs(speed) > 1.0) & ~ramp
        n_air_min = max(3, round(0.1 * fs))
        for k in np.unique(key):
            m = key == k
            mq = m & turning
            if air is not None and np.count_nonzero(mq & air) >= n_air_min:
                baseline[m] = np.mean(a[mq & air])
                continue
            ref = sm[mq] if mq.any() else sm[m]
            baseline[m] = np.quantile(ref, baseline_quantile)
    else:
        baseline = np.full_like(sm, np.quantile(sm, baseline_quantile))
        turning = np.ones(sm.size, dtype=bool)
    excess = sm - baseline
    quiet_air = turning & air if air is not None else None
    if quiet_air is not None and np.count_nonzero(quiet_air) >= max(3, round(0.1 * fs)):
        q = excess[quiet_air]
        sigma = 1.4826 * float(np.median(np.abs(q - np.median(q))))
        noise_from = "z_air"
    else:
        noise_from = "lower_half"
        quiet = excess[turning & (excess <= np.quantile(excess[turning], 0.5))] \
            if turning.any() else excess
        sigma = 1.4826 * float(np.median(np.abs(quiet - np.median(quiet)))) if quiet.size \
            else 0.0
        if turning.sum() > round(0.4 * fs):
            roll = float(np.quantile(_rolling(sm, round(0.4 * fs), "std")[turning], 0.1))
            if roll < sigma:
                sigma, noise_from = roll, "rolling_std"
    if current_threshold is None:
        p995 = float(np.quantile(excess[turning], 0.995)) if turning.any() else 0.0
        high = max(8.0 * sigma, 0.3 * p995, 1e-9)
    else:
        high = float(current_threshold)
    low = hysteresis * high
    mask = hysteresis_mask(np.where(turning, excess, -np.inf), high=high, low=low)
    spans = runs(mask)
    # merge short gaps
    n_gap = round(merge_gap_s * fs)
    merged: list[list[int]] = []
    for s, e in spans.tolist():
        if merged and s - merged[-1][1] - 1 <= n_gap:
            merged[-1][1] = e
        else:
            merged.append([s, e])
    n_min = round(min_duration_s * fs)
    keep: list[tuple[int, int]] = []
    for s, e in merged:
        if e - s + 1 < n_min:
            continue
        if z is not None and require_z_down:
            seg_z = z[s : e + 1]
            depth = z[s] - np.nanmin(seg_z) if np.isfinite(seg_z).any() else 0.0
            if not depth > min_z_depth_mm:
                continue
        keep.append((s, e))
    arr = np.asarray(keep, dtype=np.int64).reshape(-1, 2)
    df = _segments_frame(rec, arr)
    df["speed_rpm"] = [float(np.median(speed[s : e + 1])) for s, e in keep]
    df["mean_current_a"] = [float(np.mean(current[s : e + 1])) for s, e in keep]
    df["baseline_a"] = [float(np.median(baseline[s : e + 1])) for s, e in keep]
    df["z_start_mm"] = [float(z[s]) if z is not None else np.nan for s, _ in keep]
    df["z_end_mm"] = [float(z[e]) if z is not None else np.nan for _, e in keep]
    df["block"] = _blocks_at(rec, df["start_cycle"].to_numpy())
    df.attrs.update(
        {"threshold_a": high, "release_a": low, "noise_sigma_a": sigma, "smooth_hz": smooth_hz,
         "noise_from": noise_from}
    )
    return df


def _air_from_z(z: NDArray[np.float64], fs_hz: float, feed_mm_per_s: float,
                margin_s: float) -> NDArray[np.bool_]:
    """Samples where Z does not feed down (``margin_s`` around every downward move)."""
    zf = np.asarray(pd.Series(z).interpolate(limit_direction="both"), dtype=np.float64)
    if not np.isfinite(zf).all():
        return np.zeros(z.size, dtype=bool)
    v = np.gradient(lowpass(zf, min(10.0, 0.4 * fs_hz), fs_hz=fs_hz, order=2)
                    if zf.size > 30 else zf) * fs_hz
    down = (v < -feed_mm_per_s).astype(np.float64)
    n = 2 * max(1, round(margin_s * fs_hz)) + 1
    return np.asarray(_rolling(down, n, "max") == 0, dtype=bool)


def _blocks_at(rec: Recording, cycles: NDArray[np.int64]) -> list[str]:
    ev = rec.events
    if ev.empty or "kind" not in ev.columns:
        return [""] * len(cycles)
    blocks = ev[ev["kind"] == "block"].sort_values("cycle")
    if blocks.empty:
        return [""] * len(cycles)
    bc = blocks["cycle"].to_numpy(dtype=np.int64)
    text = blocks["gcode"].astype(str).to_numpy()
    idx = np.searchsorted(bc, cycles, side="right") - 1
    return [str(text[i]) if i >= 0 else "" for i in idx]
