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
    """

    lag_s: float
    lag_samples: float
    drift_ppm: float
    correlation: float
    fs_hz: float
    n_overlap: int
    polarity: int


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
    # normalise by the energies of the overlapping parts (normalized cross-correlation), so
    # the changing overlap length does not tilt the peak; ignore short overlaps
    r_lo = np.maximum(lags, 0)
    r_hi = np.minimum(lags + o.size, r.size)
    o_lo = np.maximum(-lags, 0)
    o_hi = o_lo + np.maximum(r_hi - r_lo, 0)
    overlap = r_hi - r_lo
    cr = np.concatenate([[0.0], np.cumsum(r * r)])
    co = np.concatenate([[0.0], np.cumsum(o * o)])
    valid = overlap > 0.2 * min(r.size, o.size)
    e_r = cr[np.clip(r_hi, 0, r.size)] - cr[np.clip(r_lo, 0, r.size)]
    e_o = co[np.clip(o_hi, 0, o.size)] - co[np.clip(o_lo, 0, o.size)]
    den = np.sqrt(np.maximum(e_r * e_o, 0.0))
    valid &= den > 0
    c = np.where(valid, c / np.where(den > 0, den, 1.0), 0.0)
    score = np.where(allowed & valid, c, 0.0)
    if polarity == "positive":
        k = int(np.argmax(score))
        sign = 1
    elif polarity == "negative":
        k = int(np.argmin(score))
        sign = -1
    else:
        k = int(np.argmax(np.abs(score)))
        sign = 1 if score[k] >= 0 else -1
    delta = 0.0
    if 0 < k < c.size - 1:
        y0, y1, y2 = sign * c[k - 1], sign * c[k], sign * c[k + 1]
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

    Returns
    -------
    Alignment

    Notes
    -----
    The other source is resampled (linear interpolation) onto a uniform grid at the reference
    rate, both are de-meaned, and the lag maximizing :func:`scipy.signal.correlate` is mapped
    to seconds with :func:`scipy.signal.correlation_lags`. A parabola through the peak and its
    two neighbours refines it to a fraction of a sample. Lags whose overlap is shorter than
    20 % of the shorter record are ignored.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(1)
    >>> f = lambda t: np.sin(2.1 * t) + np.sin(5.3 * t) + 0.5 * np.sin(13.7 * t)
    >>> t_ref = np.arange(0, 20, 0.002); t_dyn = np.arange(0, 18, 0.001)
    >>> a = align(t_ref, f(t_ref), t_dyn, f(t_dyn + 0.5), max_lag_s=2.0)
    >>> round(a.lag_s, 3)
    0.5
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
    offset, sign = _peak_offset(ref_t, ref, oth_t, oth, fs_hz, max_lag_s, polarity)
    drift = 0.0
    if estimate_drift:
        if not 0.05 <= drift_window_fraction <= 0.5:
            raise ConfigError(
                f"drift_window_fraction must be in [0.05, 0.5], not {drift_window_fraction!r}"
            )
        span = oth_t[-1] - oth_t[0]
        w = drift_window_fraction * span
        pol: Literal["positive", "negative"] = "positive" if sign > 0 else "negative"
        centres: list[float] = []
        offs: list[float] = []
        for lo in (oth_t[0], oth_t[-1] - w):
            m = (oth_t >= lo) & (oth_t <= lo + w)
            # search near the global estimate: +-5 % of the window
            o_k, _ = _peak_offset(
                ref_t, ref, oth_t[m], oth[m], fs_hz, 0.05 * w, pol, center_s=offset
            )
            centres.append(lo + w / 2.0)
            offs.append(o_k)
        slope = (offs[1] - offs[0]) / (centres[1] - centres[0])
        drift = slope * 1e6
        offset = offs[0] - slope * centres[0]
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
    )


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

    Returns
    -------
    Recording
        A copy whose channel has ``offset_s``, ``drift_ppm`` and ``aligned=True`` set; the
        estimate and its correlation are also noted in ``meta.issues``.
    """
    data = _channel(rec, channel_name)
    if channel_column not in data.columns:
        raise SignalNotFoundError(
            f"column {channel_column!r} is not in external channel {channel_name!r}; it has: "
            f"{', '.join(map(str, data.columns))}"
        )
    ref = rec.signal(reference_signal).to_numpy(dtype=np.float64)
    a = align(
        rec.time_s,
        ref,
        np.asarray(data.index, dtype=np.float64),
        data[channel_column].to_numpy(dtype=np.float64),
        max_lag_s=max_lag_s,
        estimate_drift=estimate_drift,
        lowpass_hz=lowpass_hz,
        polarity=polarity,
    )
    out = rec.copy()
    ch = out.external[channel_name]
    out.external[channel_name] = dataclasses.replace(
        ch, offset_s=a.lag_s, drift_ppm=a.drift_ppm, aligned=True
    )
    out.meta.issues.append(
        f"external channel {channel_name!r} aligned to {reference_signal} by cross-correlation: "
        f"offset {a.lag_s:.5f} s, drift {a.drift_ppm:.2f} ppm, correlation {a.correlation:.3f}"
    )
    return out


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
