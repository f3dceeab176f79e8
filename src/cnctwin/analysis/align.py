"""Time alignment of two sources with different rates and clocks (edge HF vs dynamometer).

The thesis merges the 500 Hz edge signals and the rotary dynamometer "in common time axis"
with a cross-correlation algorithm (§3.2.2). :func:`align` does that with
:func:`scipy.signal.correlate` and :func:`scipy.signal.correlation_lags`, refines the peak to
a fraction of a sample by a parabola, and can estimate a clock drift by aligning the start
and the end of the record separately.

Convention (same as :class:`~cnctwin.recording.ExternalChannel`): a sample of the *other*
source at its own time ``t`` happened at reference time ``t * (1 + drift_ppm * 1e-6) + lag_s``.
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass
from typing import Literal

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray
from scipy import signal as sps

from cnctwin.analysis.filters import lowpass
from cnctwin.exceptions import (
    CnctwinWarning,
    ConfigError,
    IdentificationError,
    SignalNotFoundError,
)
from cnctwin.recording import Recording
from cnctwin.signals import parse_column

__all__ = ["Alignment", "AlignmentWarning", "align", "align_external", "external_on_hf"]


class AlignmentWarning(CnctwinWarning):
    """An alignment that is weak (low correlation, peak at the search limit, unaligned use)."""


@dataclass(frozen=True)
class Alignment:
    """Result of :func:`align`.

    Attributes
    ----------
    lag_s : float
        Offset of the other clock: other time ``t`` is reference time
        ``t * (1 + drift_ppm * 1e-6) + lag_s`` [s].
    lag_samples : float
        ``lag_s`` in samples of the reference rate (fractional).
    drift_ppm : float
        Clock drift of the other source [ppm] (0 unless estimated).
    correlation : float
        Pearson correlation of the two signals on the common grid after alignment (signed).
    fs_hz : float
        Common (reference) sample rate the correlation was computed at [Hz].
    n_overlap : int
        Samples of the common grid where both signals exist after alignment.
    polarity : int
        +1 if the signals move together, -1 if one is the negative of the other.
    drift_estimated : bool
        True if ``drift_ppm`` was estimated; False for a lag-only alignment (not asked for,
        or asked for but ill-posed: see ``note``).
    note : str
        Why a requested drift estimate fell back to lag-only alignment ("" otherwise).
    """

    lag_s: float
    lag_samples: float
    drift_ppm: float
    correlation: float
    fs_hz: float
    n_overlap: int
    polarity: int
    drift_estimated: bool = False
    note: str = ""


def _uniform(
    t_s: NDArray[np.float64], x: NDArray[np.float64], fs_hz: float, t0: float, n: int
) -> NDArray[np.float64]:
    grid = t0 + np.arange(n) / fs_hz
    return np.interp(grid, t_s, x)


def _clean(
    t: ArrayLike, x: ArrayLike, name: str
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    tt = np.asarray(t, dtype=np.float64)
    xx = np.asarray(x, dtype=np.float64)
    if tt.shape != xx.shape or tt.ndim != 1:
        raise ConfigError(f"{name}: time and values must be 1-D arrays of the same length")
    ok = np.isfinite(tt) & np.isfinite(xx)
    tt, xx = tt[ok], xx[ok]
    if tt.size < 16:
        raise IdentificationError(f"{name}: only {tt.size} finite samples; need at least 16")
    if np.any(np.diff(tt) <= 0):
        order = np.argsort(tt, kind="stable")
        tt, xx = tt[order], xx[order]
        keep = np.concatenate([[True], np.diff(tt) > 0])
        tt, xx = tt[keep], xx[keep]
    return tt, xx


def _peak_offset(
    ref_t: NDArray[np.float64],
    ref: NDArray[np.float64],
    oth_t: NDArray[np.float64],
    oth: NDArray[np.float64],
    fs_hz: float,
    max_lag_s: float | None,
    polarity: Literal["auto", "positive", "negative"],
    center_s: float = 0.0,
    min_overlap_fraction: float = 0.5,
) -> tuple[float, int]:
    """Offset (other own time -> reference time) at the correlation peak, sub-sample."""
    n_r = int(np.floor((ref_t[-1] - ref_t[0]) * fs_hz)) + 1
    n_o = int(np.floor((oth_t[-1] - oth_t[0]) * fs_hz)) + 1
    r = _uniform(ref_t, ref, fs_hz, ref_t[0], n_r)
    o = _uniform(oth_t, oth, fs_hz, oth_t[0], n_o)
    r = r - r.mean()
    o = o - o.mean()
    c = sps.correlate(r, o, mode="full", method="auto")
    lags = sps.correlation_lags(r.size, o.size, mode="full")
    # lag k: r[m + k] ~ o[m]  ->  offset = ref_t0 + k/fs - oth_t0
    offsets = ref_t[0] + lags / fs_hz - oth_t[0]
    allowed = np.ones(c.size, dtype=bool)
    if max_lag_s is not None:
        allowed = np.abs(offsets - center_s) <= max_lag_s
        if not allowed.any():
            raise IdentificationError(
                f"no lag within {max_lag_s:g} s of {center_s:g} s; the records' own times start "
                f"{ref_t[0]:.3f} s and {oth_t[0]:.3f} s; raise max_lag_s"
            )
    # plain (de-meaned, not overlap-normalized) correlation over lags whose overlap covers at
    # least min_overlap_fraction of the shorter record: normalizing by the energy of the
    # overlap lets short partial overlaps of a single pulse win (one-hole recordings)
    overlap = np.minimum(lags + o.size, r.size) - np.maximum(lags, 0)
    valid = overlap >= max(min_overlap_fraction * min(r.size, o.size), 1.0)
    if not (allowed & valid).any():
        raise IdentificationError(
            f"no lag with an overlap of at least {min_overlap_fraction:.0%} of the shorter "
            "record; the two sources do not overlap in time (check their clocks) or lower "
            "min_overlap_fraction"
        )
    score = np.where(allowed & valid, c, 0.0)
    if polarity == "positive":
        score = np.where(allowed & valid, c, -np.inf)
        k = int(np.argmax(score))
        sign = 1
    elif polarity == "negative":
        score = np.where(allowed & valid, c, np.inf)
        k = int(np.argmin(score))
        sign = -1
    else:
        k = int(np.argmax(np.abs(score)))
        sign = 1 if score[k] >= 0 else -1
    # refine near the peak on a fixed support: the plain correlation of de-meaned records is
    # tilted by the overlap that changes with the lag, which moves the vertex of a broad peak
    # (a single pulse) by samples; summing over the same samples of ``o`` for every lag near
    # the peak removes the tilt (the de-meaning constant then adds the same to every lag)
    half = max(2, round(0.05 * fs_hz))
    lag0 = int(lags[k])
    m0 = max(0, -lag0) + half
    m1 = min(o.size, r.size - lag0) - half
    loc = np.arange(max(0, k - half), min(c.size, k + half + 1))
    if m1 - m0 >= 8:
        cf = np.array([float(np.dot(r[m0 + int(lags[j]):m1 + int(lags[j])], o[m0:m1]))
                       for j in loc])
        cf = np.where((allowed & valid)[loc], sign * cf, -np.inf)
        j = int(np.argmax(cf))
        k = int(loc[j])
        y = cf
    else:
        j = k - int(loc[0])
        y = np.where((allowed & valid)[loc], sign * c[loc], -np.inf)
    delta = 0.0
    if 0 < j < y.size - 1 and np.isfinite(y[j - 1]) and np.isfinite(y[j + 1]):
        y0, y1, y2 = y[j - 1], y[j], y[j + 1]
        den = y0 - 2 * y1 + y2
        if den < 0:
            delta = float(np.clip(0.5 * (y0 - y2) / den, -0.5, 0.5))
    if max_lag_s is not None and (k == 0 or not allowed[k - 1] or k == c.size - 1
                                  or not allowed[k + 1]):
        warnings.warn(
            f"correlation peak at the search limit (max_lag_s={max_lag_s:g} s); the true lag may "
            "lie outside: raise max_lag_s",
            AlignmentWarning,
            stacklevel=3,
        )
    return float(offsets[k] + delta / fs_hz), sign


def _pearson_after(
    ref_t: NDArray[np.float64],
    ref: NDArray[np.float64],
    oth_t: NDArray[np.float64],
    oth: NDArray[np.float64],
    lag_s: float,
    drift_ppm: float,
) -> tuple[float, int]:
    mapped = oth_t * (1.0 + drift_ppm * 1e-6) + lag_s
    inside = (ref_t >= mapped[0]) & (ref_t <= mapped[-1])
    if inside.sum() < 3:
        return float("nan"), int(inside.sum())
    o = np.interp(ref_t[inside], mapped, oth)
    r = ref[inside]
    if r.std() == 0 or o.std() == 0:
        return float("nan"), int(inside.sum())
    return float(np.corrcoef(r, o)[0, 1]), int(inside.sum())


def align(
    reference_t_s: ArrayLike,
    reference: ArrayLike,
    other_t_s: ArrayLike,
    other: ArrayLike,
    *,
    max_lag_s: float | None,
    estimate_drift: bool = False,
    fs_hz: float | None = None,
    lowpass_hz: float | None = None,
    polarity: Literal["auto", "positive", "negative"] = "auto",
    drift_window_fraction: float = 0.35,
    min_overlap_fraction: float = 0.5,
    max_drift_ppm: float = 1000.0,
) -> Alignment:
    """Estimate the clock offset (and optionally drift) of ``other`` against ``reference``.

    Parameters
    ----------
    reference_t_s, reference : array-like
        Reference times [s] (e.g. ``Recording.time_s``) and values (e.g. spindle current).
    other_t_s, other : array-like
        The other source's own times [s] and values (e.g. dynamometer torque), any rate.
    max_lag_s : float or None
        Largest ``|lag_s|`` searched [s]; ``None`` searches every overlap.
    estimate_drift : bool, default False
        Also estimate a linear clock drift: the first and last ``drift_window_fraction`` of
        the other record are aligned separately and the drift is the change of offset over
        the distance of the window centres.
    fs_hz : float, optional
        Common grid rate [Hz]; default the reference's median rate.
    lowpass_hz : float, optional
        Zero-phase low-pass both signals first [Hz]; default: the other source is low-passed
        at 0.4x the grid rate when it is sampled faster (anti-alias before resampling).
    polarity : {'auto', 'positive', 'negative'}, default 'auto'
        Which peak to take: largest positive, largest negative or largest absolute
        correlation (for sources with opposite sign conventions).
    drift_window_fraction : float, default 0.35
        Length of the start/end windows for the drift estimate, as a fraction of the other
        record.
    min_overlap_fraction : float, default 0.5
        Lags whose overlap is shorter than this fraction of the shorter record are not
        considered.
    max_drift_ppm : float, default 1000
        A drift estimate beyond this is rejected as ill-posed [ppm] (quartz clocks drift
        tens of ppm).

    Returns
    -------
    Alignment
        ``drift_estimated`` False and ``note`` set when a requested drift estimate was
        ill-posed and the result is the lag-only alignment.

    Notes
    -----
    The other source is resampled (linear interpolation) onto a uniform grid at the reference
    rate, both are de-meaned, and the lag maximizing :func:`scipy.signal.correlate` is mapped
    to seconds with :func:`scipy.signal.correlation_lags`. A parabola through the peak and its
    two neighbours refines it to a fraction of a sample. The correlation is the plain one (not
    normalized by the energy of each overlap, which lets a short partial overlap of a single
    pulse win); lags with less than ``min_overlap_fraction`` overlap are ignored.

    A drift needs two timing references far apart: the other signal must change level (Schmitt
    trigger at 40 %/60 % of its 5-99 % range) at least three times, i.e. hold at least two
    events, and the start and end windows must each hold such an edge. One pulse (a one-hole
    drilling recording) gives only the rise and fall of the same cut, whose widths differ between
    current and torque (speed loop, inertia, drill exit), so the drift is ill-posed: then, as
    when a window alignment fails or the drift exceeds ``max_drift_ppm``, the lag-only
    alignment is returned with ``drift_estimated=False``, the reason in ``note`` and an
    :class:`AlignmentWarning`.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(1)
    >>> f = lambda t: np.sin(2.1 * t) + np.sin(5.3 * t) + 0.5 * np.sin(13.7 * t)
    >>> t_ref = np.arange(0, 20, 0.002); t_dyn = np.arange(0, 18, 0.001)
    >>> a = align(t_ref, f(t_ref), t_dyn, f(t_dyn + 0.5), max_lag_s=2.0)
    >>> abs(a.lag_s - 0.5) < 0.002   # one sample of the 500 Hz reference
    True
    """
    ref_t, ref = _clean(reference_t_s, reference, "reference")
    oth_t, oth = _clean(other_t_s, other, "other")
    if fs_hz is None:
        fs_hz = 1.0 / float(np.median(np.diff(ref_t)))
    fs_oth = 1.0 / float(np.median(np.diff(oth_t)))
    if lowpass_hz is not None:
        ref = lowpass(ref, lowpass_hz, fs_hz=1.0 / float(np.median(np.diff(ref_t))))
        oth = lowpass(oth, lowpass_hz, fs_hz=fs_oth)
    elif fs_oth > 1.01 * fs_hz:
        oth = lowpass(oth, 0.4 * fs_hz, fs_hz=fs_oth)
    if not 0.0 < min_overlap_fraction <= 1.0:
        raise ConfigError(f"min_overlap_fraction must be in (0, 1], not {min_overlap_fraction!r}")
    offset, sign = _peak_offset(ref_t, ref, oth_t, oth, fs_hz, max_lag_s, polarity,
                                min_overlap_fraction=min_overlap_fraction)
    drift = 0.0
    estimated = False
    note = ""
    if estimate_drift:
        if not 0.05 <= drift_window_fraction <= 0.5:
            raise ConfigError(
                f"drift_window_fraction must be in [0.05, 0.5], not {drift_window_fraction!r}"
            )
        est = _drift_from_windows(ref_t, ref, oth_t, oth, fs_hz, offset, sign,
                                  drift_window_fraction, max_drift_ppm)
        if isinstance(est, str):
            note = f"drift not estimated ({est}); lag-only alignment"
            warnings.warn(note, AlignmentWarning, stacklevel=2)
        else:
            offset, drift = est
            estimated = True
    r, n_ov = _pearson_after(ref_t, ref, oth_t, oth, offset, drift)
    if np.isfinite(r) and abs(r) < 0.3:
        warnings.warn(
            f"weak alignment: correlation {r:.2f} after alignment (lag {offset:.4f} s); check "
            "that the two signals see the same events",
            AlignmentWarning,
            stacklevel=2,
        )
    return Alignment(
        lag_s=offset,
        lag_samples=offset * fs_hz,
        drift_ppm=drift,
        correlation=r,
        fs_hz=float(fs_hz),
        n_overlap=n_ov,
        polarity=sign,
        drift_estimated=estimated,
        note=note,
    )


def _edges(t: NDArray[np.float64], x: NDArray[np.float64]) -> NDArray[np.float64]:
    """Times where ``x`` switches between its low and high level (Schmitt trigger at 40 % and
    60 % of its 5-99 % range)."""
    lo, hi = np.quantile(x, [0.05, 0.99])
    if not hi > lo:
        return np.empty(0)
    v = (x - lo) / (hi - lo)
    state = np.where(v > 0.6, 1, np.where(v < 0.4, 0, -1))
    idx = np.where(state >= 0, np.arange(v.size), -1)
    np.maximum.accumulate(idx, out=idx)
    known = idx >= 0
    on = state[idx[known]] == 1
    return np.asarray(t[known][1:][np.diff(on.astype(np.int8)) != 0], dtype=np.float64)


def _drift_from_windows(
    ref_t: NDArray[np.float64],
    ref: NDArray[np.float64],
    oth_t: NDArray[np.float64],
    oth: NDArray[np.float64],
    fs_hz: float,
    offset: float,
    sign: int,
    fraction: float,
    max_drift_ppm: float,
) -> tuple[float, float] | str:
    """(offset, drift_ppm) from the start and end windows, or why that is ill-posed."""
    span = oth_t[-1] - oth_t[0]
    w = fraction * span
    edges = _edges(oth_t, oth)
    if edges.size < 3:
        return (f"the other signal has {edges.size} level change(s), i.e. at most one event "
                "(one cut); a drift needs at least two separated events")
    pol: Literal["positive", "negative"] = "positive" if sign > 0 else "negative"
    centres: list[float] = []
    offs: list[float] = []
    for lo in (oth_t[0], oth_t[-1] - w):
        if not np.any((edges >= lo) & (edges <= lo + w)):
            return (f"the window {lo:.3f}-{lo + w:.3f} s of the other record holds no event "
                    "edge")
        m = (oth_t >= lo) & (oth_t <= lo + w)
        # search near the global estimate: +-5 % of the window
        try:
            o_k, _ = _peak_offset(ref_t, ref, oth_t[m], oth[m], fs_hz, 0.05 * w, pol,
                                  center_s=offset)
        except IdentificationError as exc:
            return f"window {lo:.3f}-{lo + w:.3f} s: {exc}"
        centres.append(lo + w / 2.0)
        offs.append(o_k)
    slope = (offs[1] - offs[0]) / (centres[1] - centres[0])
    if abs(slope * 1e6) > max_drift_ppm:
        return f"the estimate {slope * 1e6:.0f} ppm exceeds max_drift_ppm={max_drift_ppm:g}"
    return offs[0] - slope * centres[0], slope * 1e6


def _channel(rec: Recording, channel_name: str) -> pd.DataFrame:
    if channel_name not in rec.external:
        raise SignalNotFoundError(
            f"external channel {channel_name!r} is not in this recording; it has: "
            f"{', '.join(rec.external) or 'none'}"
        )
    return rec.external[channel_name].data


def align_external(
    rec: Recording,
    channel_name: str,
    *,
    reference_signal: str = "CURRENT|SP1",
    channel_column: str = "mz_nm",
    max_lag_s: float | None = None,
    estimate_drift: bool = False,
    lowpass_hz: float | None = 20.0,
    polarity: Literal["auto", "positive", "negative"] = "auto",
    blank_speed_changes: bool = True,
    accel_limit_rpm_per_s: float = 50.0,
    min_overlap_fraction: float = 0.5,
) -> Recording:
    """Align an external channel (dynamometer) to the recording's HF time base.

    Parameters
    ----------
    rec : Recording
        Recording holding the HF reference signal and the external channel.
    channel_name : str
        Key in ``rec.external`` (``"dynamometer"``).
    reference_signal : str, default 'CURRENT|SP1'
        HF column to correlate with.
    channel_column : str, default 'mz_nm'
        Column of the channel's data to correlate (dynamometer torque).
    max_lag_s : float or None, default None
        Largest offset searched [s]; ``None`` = any overlap.
    estimate_drift : bool, default False
        Also estimate a clock drift (see :func:`align`).
    lowpass_hz : float or None, default 20.0
        Low-pass both signals before correlating [Hz] (the thesis compares the two sources
        low-passed, Fig. 3.6b; 20 Hz keeps the cut edges that carry the timing).
    polarity : {'auto', 'positive', 'negative'}, default 'auto'
        Sign of the relation (see :func:`align`).
    blank_speed_changes : bool, default True
        Leave out reference samples within 0.2 s of a change of the spindle speed (run-ups,
        run-downs), when the HF ``CMD_SPEED`` of the reference's axis is recorded (the LF
        speed is too coarse).
    accel_limit_rpm_per_s : float, default 50
        Speed change rate above which a sample counts as a run-up [rpm/s].
    min_overlap_fraction : float, default 0.5
        Smallest overlap of the two records considered (see :func:`align`).

    Returns
    -------
    Recording
        A copy whose channel has ``offset_s``, ``drift_ppm`` and ``aligned=True`` set; the
        estimate and its correlation are also noted in ``meta.issues``, and so is a drift
        estimate that fell back to lag-only alignment (one-hole recordings).

    Notes
    -----
    A spindle run-up or run-down draws the inertia current (tens of A) that the dynamometer
    never sees; left in, it dominates the correlation of a short drilling recording. Those
    samples are bridged by linear interpolation (ends held), so only the cutting load carries
    the timing.
    """
    data = _channel(rec, channel_name)
    if channel_column not in data.columns:
        raise SignalNotFoundError(
            f"column {channel_column!r} is not in external channel {channel_name!r}; it has: "
            f"{', '.join(map(str, data.columns))}"
        )
    ref = rec.signal(reference_signal).to_numpy(dtype=np.float64)
    if blank_speed_changes:
        blank = _speed_changing(rec, reference_signal, accel_limit_rpm_per_s)
        if blank.any():
            # bridge the blanked samples on the uniform HF grid (ends held), so the low-pass
            # in align() sees evenly spaced samples
            ref = np.asarray(pd.Series(np.where(blank, np.nan, ref)).interpolate(
                limit_direction="both"), dtype=np.float64)
    a = align(
        rec.time_s,
        ref,
        np.asarray(data.index, dtype=np.float64),
        data[channel_column].to_numpy(dtype=np.float64),
        max_lag_s=max_lag_s,
        estimate_drift=estimate_drift,
        lowpass_hz=lowpass_hz,
        polarity=polarity,
        min_overlap_fraction=min_overlap_fraction,
    )
    out = rec.copy()
    ch = out.external[channel_name]
    out.external[channel_name] = dataclasses.replace(
        ch, offset_s=a.lag_s, drift_ppm=a.drift_ppm, aligned=True
    )
    out.meta.issues.append(
        f"external channel {channel_name!r} aligned to {reference_signal} by cross-correlation: "
        f"offset {a.lag_s:.5f} s, drift {a.drift_ppm:.2f} ppm, correlation {a.correlation:.3f}"
        + (f"; {a.note}" if a.note else "")
    )
    return out


def _speed_changing(rec: Recording, reference_signal: str,
                    accel_limit_rpm_per_s: float) -> NDArray[np.bool_]:
    """Samples within 0.2 s of a spindle speed change (all False without an HF speed)."""
    _, axis = parse_column(reference_signal)
    col = f"CMD_SPEED|{axis or 'SP1'}"
    if not rec.has(col):
        return np.zeros(len(rec.hf), dtype=bool)
    speed = rec.hf[col].to_numpy(dtype=np.float64)
    speed = np.asarray(pd.Series(speed).ffill().bfill().fillna(0.0), dtype=np.float64)
    ramp = np.abs(np.gradient(speed) * rec.fs_hz) > accel_limit_rpm_per_s if speed.size > 1 \
        else np.zeros(speed.size, dtype=bool)
    k = max(1, round(0.4 * rec.fs_hz))
    out = np.convolve(ramp.astype(np.float64), np.ones(k), mode="same") > 0
    if out.all():
        return np.zeros(out.size, dtype=bool)
    return np.asarray(out, dtype=bool)


def external_on_hf(
    rec: Recording,
    channel_name: str,
    *,
    columns: list[str] | None = None,
) -> pd.DataFrame:
    """An external channel resampled onto the HF cycles (linear interpolation).

    Parameters
    ----------
    rec : Recording
        Recording with the channel.
    channel_name : str
        Key in ``rec.external``.
    columns : list of str, optional
        Columns to resample; default all numeric columns.

    Returns
    -------
    pandas.DataFrame
        Indexed by the HF cycle; NaN where the HF cycle lies outside the channel's span.
        Uses the channel's ``offset_s``/``drift_ppm``; warns (:class:`AlignmentWarning`) if
        the channel was never aligned.
    """
    data = _channel(rec, channel_name)
    ch = rec.external[channel_name]
    if not ch.aligned:
        warnings.warn(
            f"external channel {channel_name!r} is not aligned (offset_s={ch.offset_s}); "
            "run align_external first or set offset_s and aligned=True",
            AlignmentWarning,
            stacklevel=2,
        )
    cols = columns if columns is not None else [
        c for c in data.columns if pd.api.types.is_numeric_dtype(data[c])
    ]
    t_ch = ch.time_on_recording_s()
    t_hf = rec.time_s
    out = pd.DataFrame(index=rec.hf.index.copy())
    order = np.argsort(t_ch, kind="stable")
    t_sorted = t_ch[order]
    for c in cols:
        if c not in data.columns:
            raise SignalNotFoundError(
                f"column {c!r} is not in external channel {channel_name!r}; it has: "
                f"{', '.join(map(str, data.columns))}"
            )
        v = data[c].to_numpy(dtype=np.float64)[order]
        ok = np.isfinite(v)
        vals = np.interp(t_hf, t_sorted[ok], v[ok], left=np.nan, right=np.nan)
        out[c] = vals
    return out
