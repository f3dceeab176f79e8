"""Digital filters for 500 Hz edge signals (scipy.signal SOS form, frequencies in Hz).

Every function takes the sample rate explicitly (``fs_hz``) and frequencies in Hz, as
``scipy.signal.butter(..., fs=...)`` does. Filters are Butterworth designs in second-order
sections (SOS), which stay numerically sound at low cutoffs where transfer-function (``b, a``)
coefficients do not.

* ``zero_phase=True`` (offline analysis) runs the filter forward and backward
  (:func:`scipy.signal.sosfiltfilt`): no delay, squared magnitude response, not causal.
* ``zero_phase=False`` runs it once, causally (:func:`scipy.signal.sosfilt`), starting in the
  steady state of the first sample, which is exactly what :class:`CausalFilter` does chunk by
  chunk on a stream, so a streamed result equals the one-shot result.

Numerical hazards (a cutoff very close to 0 Hz or to Nyquist, a signal too short for the
forward-backward padding) emit :class:`FilterWarning`; impossible requests raise
:class:`~cnctwin.exceptions.ConfigError`.
"""

from __future__ import annotations

import warnings
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import signal as sps

from cnctwin.exceptions import CnctwinWarning, ConfigError

__all__ = [
    "CausalFilter",
    "FilterWarning",
    "bandpass",
    "bandstop",
    "design_sos",
    "extract_stator_component",
    "fold_frequency",
    "highpass",
    "lowpass",
    "remove_stator_component",
    "stator_frequency_hz",
]

BType = Literal["lowpass", "highpass", "bandpass", "bandstop"]
_BTYPES: tuple[str, ...] = ("lowpass", "highpass", "bandpass", "bandstop")


class FilterWarning(CnctwinWarning):
    """A filter request that works but is numerically hazardous (see the message)."""


def design_sos(
    btype: BType,
    freqs_hz: float | tuple[float, float],
    *,
    fs_hz: float,
    order: int = 4,
) -> NDArray[np.float64]:
    """Design a digital Butterworth filter as second-order sections.

    Parameters
    ----------
    btype : {'lowpass', 'highpass', 'bandpass', 'bandstop'}
        Filter type.
    freqs_hz : float or (float, float)
        Cutoff [Hz] (low/high pass) or (low, high) band edges [Hz] (band pass/stop).
    fs_hz : float
        Sample rate [Hz].
    order : int, default 4
        Butterworth order (band filters get twice as many poles, as in scipy).

    Returns
    -------
    numpy.ndarray
        SOS array of shape (n_sections, 6).

    Raises
    ------
    ConfigError
        If a frequency is not strictly between 0 and Nyquist (``fs_hz / 2``), band edges are
        not increasing, or the type or order is invalid.
    """
    if btype not in _BTYPES:
        raise ConfigError(f"btype must be one of {', '.join(_BTYPES)}, not {btype!r}")
    if not np.isfinite(fs_hz) or fs_hz <= 0:
        raise ConfigError(f"fs_hz must be a positive sample rate in Hz, not {fs_hz!r}")
    if int(order) != order or order < 1:
        raise ConfigError(f"order must be a positive integer, not {order!r}")
    nyq = fs_hz / 2.0
    band = btype in ("bandpass", "bandstop")
    freqs = np.atleast_1d(np.asarray(freqs_hz, dtype=np.float64))
    if band and freqs.size != 2:
        raise ConfigError(f"{btype} needs two band edges (low_hz, high_hz), got {freqs_hz!r}")
    if not band and freqs.size != 1:
        raise ConfigError(f"{btype} needs one cutoff in Hz, got {freqs_hz!r}")
    if np.any(~np.isfinite(freqs)) or np.any(freqs <= 0) or np.any(freqs >= nyq):
        raise ConfigError(
            f"{btype} frequencies {freqs.tolist()} Hz must lie strictly between 0 and the "
            f"Nyquist frequency {nyq:g} Hz (fs_hz={fs_hz:g}); lower the cutoff or resample"
        )
    if band and not freqs[0] < freqs[1]:
        raise ConfigError(f"band edges must increase (low_hz < high_hz), got {freqs.tolist()}")
    rel = freqs / nyq
    if np.any(rel < 1e-3):
        warnings.warn(
            f"{btype} edge {freqs.min():g} Hz is below 0.1 % of Nyquist ({nyq:g} Hz): the "
            "filter has very long transients; decimate before filtering",
            FilterWarning,
            stacklevel=3,
        )
    if np.any(rel > 0.98):
        warnings.warn(
            f"{btype} edge {freqs.max():g} Hz is within 2 % of Nyquist ({nyq:g} Hz): the "
            "response near the edge is unreliable",
            FilterWarning,
            stacklevel=3,
        )
    wn: float | NDArray[np.float64] = freqs if band else float(freqs[0])
    sos = sps.butter(int(order), wn, btype=btype, fs=fs_hz, output="sos")
    return np.asarray(sos, dtype=np.float64)


def _as_signal(x: ArrayLike, axis: int) -> NDArray[np.float64]:
    arr = np.asarray(x, dtype=np.float64)
    if arr.ndim == 0:
        raise ConfigError("filters need an array of samples, not a scalar")
    if arr.shape[axis] == 0:
        raise ConfigError("cannot filter an empty signal")
    bad = ~np.isfinite(arr)
    if bad.any():
        first = int(np.flatnonzero(bad.reshape(-1))[0])
        raise ConfigError(
            f"signal has {int(bad.sum())} non-finite samples (first at flat index {first}); "
            "an IIR filter would spread them over the whole output. Fill or cut the gaps first "
            "(e.g. pandas interpolate, or Recording.select around them)"
        )
    return arr


def _apply(
    sos: NDArray[np.float64], x: ArrayLike, *, zero_phase: bool, axis: int
) -> NDArray[np.float64]:
    arr = _as_signal(x, axis)
    n = arr.shape[axis]
    if zero_phase:
        padlen = 3 * (2 * len(sos) + 1)
        if n <= padlen:
            warnings.warn(
                f"signal of {n} samples is shorter than the default forward-backward padding "
                f"({padlen + 1} samples); padding reduced to {n - 1}, edges are less reliable",
                FilterWarning,
                stacklevel=3,
            )
            padlen = n - 1
        return np.asarray(sps.sosfiltfilt(sos, arr, axis=axis, padlen=padlen), dtype=np.float64)
    first = np.take(arr, [0], axis=axis)
    zi = _steady_state_zi(sos, first, axis)
    y, _ = sps.sosfilt(sos, arr, axis=axis, zi=zi)
    return np.asarray(y, dtype=np.float64)


def _steady_state_zi(
    sos: NDArray[np.float64], first: NDArray[np.float64], axis: int
) -> NDArray[np.float64]:
    """Initial state so that a constant input equal to ``first`` gives a constant output."""
    zi0 = sps.sosfilt_zi(sos)  # (n_sections, 2)
    # zi must have shape (n_sections, ..., 2, ...) with the 2 in the position of `axis`.
    f = np.moveaxis(first, axis, -1)  # (..., 1)
    zi = zi0[(slice(None),) + (None,) * (f.ndim - 1) + (slice(None),)] * f[None, ...]
    return np.moveaxis(zi, -1, axis + 1 if axis >= 0 else axis)


def lowpass(
    x: ArrayLike,
    cutoff_hz: float,
    *,
    fs_hz: float,
    order: int = 4,
    zero_phase: bool = True,
    axis: int = -1,
) -> NDArray[np.float64]:
    """Butterworth low-pass filter.

    Parameters
    ----------
    x : array-like
        Samples, uniformly spaced at ``fs_hz``.
    cutoff_hz : float
        -3 dB cutoff of one pass [Hz] (with ``zero_phase`` the two passes give -6 dB there).
    fs_hz : float
        Sample rate [Hz].
    order : int, default 4
        Butterworth order.
    zero_phase : bool, default True
        Forward-backward (offline, no delay) or causal single pass (streaming-equivalent).
    axis : int, default -1
        Time axis.

    Returns
    -------
    numpy.ndarray
        Filtered samples, same shape as ``x`` [unit of x].

    Notes
    -----
    Thesis Fig. 3.6b shows the edge and dynamometer signals low-pass filtered at 10 Hz.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(2000) / 500.0
    >>> y = lowpass(np.sin(2 * np.pi * 2 * t) + np.sin(2 * np.pi * 100 * t), 10, fs_hz=500)
    >>> bool(np.abs(y[200:-200] - np.sin(2 * np.pi * 2 * t[200:-200])).max() < 0.01)
    True
    """
    sos = design_sos("lowpass", cutoff_hz, fs_hz=fs_hz, order=order)
    return _apply(sos, x, zero_phase=zero_phase, axis=axis)


def highpass(
    x: ArrayLike,
    cutoff_hz: float,
    *,
    fs_hz: float,
    order: int = 4,
    zero_phase: bool = True,
    axis: int = -1,
) -> NDArray[np.float64]:
    """Butterworth high-pass filter; parameters as in :func:`lowpass`.

    Parameters
    ----------
    x : array-like
        Samples, uniformly spaced at ``fs_hz``.
    cutoff_hz : float
        -3 dB cutoff of one pass [Hz].
    fs_hz : float
        Sample rate [Hz].
    order : int, default 4
        Butterworth order.
    zero_phase : bool, default True
        Forward-backward (offline, no delay) or causal single pass (streaming-equivalent).
    axis : int, default -1
        Time axis.

    Returns
    -------
    numpy.ndarray
        Filtered samples, same shape as ``x`` [unit of x].
    """
    sos = design_sos("highpass", cutoff_hz, fs_hz=fs_hz, order=order)
    return _apply(sos, x, zero_phase=zero_phase, axis=axis)


def bandpass(
    x: ArrayLike,
    low_hz: float,
    high_hz: float,
    *,
    fs_hz: float,
    order: int = 4,
    zero_phase: bool = True,
    axis: int = -1,
) -> NDArray[np.float64]:
    """Butterworth band-pass filter between ``low_hz`` and ``high_hz`` [Hz].

    Other parameters as in :func:`lowpass`. Thesis Fig. 4.3a band-passes the stator-frequency
    component of the spindle current.

    Parameters
    ----------
    x : array-like
        Samples, uniformly spaced at ``fs_hz``.
    low_hz, high_hz : float
        Band edges [Hz], ``0 < low_hz < high_hz <`` Nyquist.
    fs_hz : float
        Sample rate [Hz].
    order : int, default 4
        Butterworth order.
    zero_phase : bool, default True
        Forward-backward (offline, no delay) or causal single pass (streaming-equivalent).
    axis : int, default -1
        Time axis.

    Returns
    -------
    numpy.ndarray
        Filtered samples, same shape as ``x`` [unit of x].
    """
    sos = design_sos("bandpass", (low_hz, high_hz), fs_hz=fs_hz, order=order)
    return _apply(sos, x, zero_phase=zero_phase, axis=axis)


def bandstop(
    x: ArrayLike,
    low_hz: float,
    high_hz: float,
    *,
    fs_hz: float,
    order: int = 4,
    zero_phase: bool = True,
    axis: int = -1,
) -> NDArray[np.float64]:
    """Butterworth band-stop filter between ``low_hz`` and ``high_hz`` [Hz].

    Other parameters as in :func:`lowpass`.

    Parameters
    ----------
    x : array-like
        Samples, uniformly spaced at ``fs_hz``.
    low_hz, high_hz : float
        Band edges [Hz], ``0 < low_hz < high_hz <`` Nyquist.
    fs_hz : float
        Sample rate [Hz].
    order : int, default 4
        Butterworth order.
    zero_phase : bool, default True
        Forward-backward (offline, no delay) or causal single pass (streaming-equivalent).
    axis : int, default -1
        Time axis.

    Returns
    -------
    numpy.ndarray
        Filtered samples, same shape as ``x`` [unit of x].
    """
    sos = design_sos("bandstop", (low_hz, high_hz), fs_hz=fs_hz, order=order)
    return _apply(sos, x, zero_phase=zero_phase, axis=axis)


class CausalFilter:
    """A causal SOS filter that keeps its state between chunks (edge streaming).

    Feeding a signal chunk by chunk through :meth:`process` gives exactly the samples of the
    one-shot causal filter (``lowpass(x, ..., zero_phase=False)`` and friends): both start in
    the steady state of the first sample, so there is no start-up transient.

    Parameters
    ----------
    btype : {'lowpass', 'highpass', 'bandpass', 'bandstop'}
        Filter type.
    freqs_hz : float or (float, float)
        Cutoff or band edges [Hz].
    fs_hz : float
        Sample rate [Hz].
    order : int, default 4
        Butterworth order.

    Examples
    --------
    >>> import numpy as np
    >>> x = np.random.default_rng(0).normal(size=1000)
    >>> f = CausalFilter("lowpass", 20.0, fs_hz=500.0)
    >>> y = np.concatenate([f.process(c) for c in np.array_split(x, 7)])
    >>> bool(np.allclose(y, lowpass(x, 20.0, fs_hz=500.0, zero_phase=False)))
    True
    """

    def __init__(
        self,
        btype: BType,
        freqs_hz: float | tuple[float, float],
        *,
        fs_hz: float,
        order: int = 4,
    ) -> None:
        self.btype = btype
        self.freqs_hz = freqs_hz
        self.fs_hz = float(fs_hz)
        self.order = int(order)
        self.sos = design_sos(btype, freqs_hz, fs_hz=fs_hz, order=order)
        self._zi: NDArray[np.float64] | None = None

    def reset(self) -> None:
        """Forget the state; the next chunk starts in the steady state of its first sample."""
        self._zi = None

    def process(self, chunk: ArrayLike) -> NDArray[np.float64]:
        """Filter the next chunk of samples (time along the last axis).

        Parameters
        ----------
        chunk : array-like
            Next samples; 1-D, or 2-D with channels first and time last. Empty chunks are
            allowed and return an empty array.

        Returns
        -------
        numpy.ndarray
            Filtered samples, same shape as ``chunk``.
        """
        arr = np.asarray(chunk, dtype=np.float64)
        if arr.ndim == 0:
            raise ConfigError("CausalFilter.process needs an array of samples, not a scalar")
        if arr.shape[-1] == 0:
            return arr.copy()
        arr = _as_signal(arr, -1)
        if self._zi is None:
            self._zi = _steady_state_zi(self.sos, arr[..., :1], -1)
        y, self._zi = sps.sosfilt(self.sos, arr, axis=-1, zi=self._zi)
        return np.asarray(y, dtype=np.float64)


def fold_frequency(f_hz: ArrayLike, fs_hz: float) -> NDArray[np.float64]:
    """Apparent frequency of a tone after sampling at ``fs_hz`` (alias folded about Nyquist).

    Parameters
    ----------
    f_hz : array-like
        True frequency [Hz] (sign ignored).
    fs_hz : float
        Sample rate [Hz].

    Returns
    -------
    numpy.ndarray
        Folded frequency in [0, fs_hz/2] [Hz].

    Notes
    -----
    ``f_a = |f - fs * round(f / fs)|``. At 500 Hz sampling (Nyquist 250 Hz) a 333 Hz stator
    line (8 poles, 5000 rpm) appears at 167 Hz (docs/reference/physics-and-performance.md §2).

    Examples
    --------
    >>> float(fold_frequency(333.3, 500.0).round(1)), float(fold_frequency(467.0, 500.0))
    (166.7, 33.0)
    """
    if not np.isfinite(fs_hz) or fs_hz <= 0:
        raise ConfigError(f"fs_hz must be a positive sample rate in Hz, not {fs_hz!r}")
    f = np.abs(np.asarray(f_hz, dtype=np.float64))
    return np.asarray(np.abs(f - fs_hz * np.round(f / fs_hz)), dtype=np.float64)


def stator_frequency_hz(speed_rpm: ArrayLike, poles: int) -> NDArray[np.float64]:
    """Electrical (stator) frequency of a synchronous motor, thesis Eq. (4.1).

    Parameters
    ----------
    speed_rpm : array-like
        Mechanical (synchronous) speed [rpm]; the sign is ignored.
    poles : int
        Number of magnetic POLES (not pole pairs), e.g. 4 for a two-pole-pair motor.

    Returns
    -------
    numpy.ndarray
        Stator frequency ``f = |N| * poles / 120`` [Hz].

    Notes
    -----
    Thesis Eq. (4.1) is written ``f = N p / 120`` and the text calls ``p`` "the number of pole
    pairs". The formula with the constant 120 is correct when ``p`` is the number of *poles*
    (f = N/60 * pole_pairs = N * poles / 120); with pole pairs the constant would be 60. This
    function takes the number of poles.

    Examples
    --------
    >>> float(stator_frequency_hz(2400.0, 4))
    80.0
    """
    if int(poles) != poles or poles < 2 or poles % 2:
        raise ConfigError(f"poles must be an even integer >= 2 (number of poles), not {poles!r}")
    return np.asarray(np.abs(np.asarray(speed_rpm, dtype=np.float64)) * poles / 120.0)


def _stator_band(
    speed_rpm: ArrayLike, poles: int, fs_hz: float, bandwidth_hz: float
) -> tuple[float, float, float]:
    speed = np.asarray(speed_rpm, dtype=np.float64)
    if speed.size == 0 or not np.isfinite(speed).any():
        raise ConfigError("speed_rpm has no finite value to compute the stator frequency from")
    n = float(np.nanmedian(np.abs(speed)))
    f_alias = float(fold_frequency(stator_frequency_hz(n, poles), fs_hz))
    if bandwidth_hz <= 0:
        raise ConfigError(f"bandwidth_hz must be positive, not {bandwidth_hz!r}")
    return f_alias, f_alias - bandwidth_hz / 2.0, f_alias + bandwidth_hz / 2.0


def remove_stator_component(
    current: ArrayLike,
    speed_rpm: ArrayLike,
    *,
    poles: int,
    fs_hz: float,
    bandwidth_hz: float = 10.0,
    order: int = 2,
    zero_phase: bool = True,
) -> NDArray[np.float64]:
    """Remove the (folded) stator-frequency line from a spindle current, thesis Fig. 4.3b.

    Parameters
    ----------
    current : array-like
        Spindle current samples at constant speed [A].
    speed_rpm : float or array-like
        Spindle speed [rpm]; the median of an array is used (one plateau, one line).
    poles : int
        Number of motor poles (see :func:`stator_frequency_hz`).
    fs_hz : float
        Sample rate [Hz].
    bandwidth_hz : float, default 10.0
        Width of the stop band centred on the folded stator frequency [Hz].
    order : int, default 2
        Butterworth order of the band stop.
    zero_phase : bool, default True
        Forward-backward filtering.

    Returns
    -------
    numpy.ndarray
        Current without the stator line [A]. A band stop does not touch DC, so the mean is
        kept, as the thesis observes (Fig. 4.3b).

    Notes
    -----
    The stator line at ``f = N * poles / 120`` (Eq. 4.1) is usually above Nyquist at 500 Hz
    and appears at :func:`fold_frequency`. If the folded line lies within half a bandwidth of
    0 Hz, removing it would remove the mean as well: the current is returned unchanged with a
    :class:`FilterWarning`. Near Nyquist a low-pass below the band replaces the band stop.
    """
    x = _as_signal(current, -1)
    f_alias, lo, hi = _stator_band(speed_rpm, poles, fs_hz, bandwidth_hz)
    nyq = fs_hz / 2.0
    if lo <= 0.0:
        warnings.warn(
            f"the folded stator line is at {f_alias:.2f} Hz, within {bandwidth_hz / 2:g} Hz of "
            "DC: removing it would change the mean; current returned unchanged",
            FilterWarning,
            stacklevel=2,
        )
        return x.copy()
    if hi >= nyq:
        return lowpass(x, lo, fs_hz=fs_hz, order=order, zero_phase=zero_phase)
    return bandstop(x, lo, hi, fs_hz=fs_hz, order=order, zero_phase=zero_phase)


def extract_stator_component(
    current: ArrayLike,
    speed_rpm: ArrayLike,
    *,
    poles: int,
    fs_hz: float,
    bandwidth_hz: float = 10.0,
    order: int = 2,
    zero_phase: bool = True,
) -> NDArray[np.float64]:
    """Band-pass the (folded) stator-frequency line of a spindle current, thesis Fig. 4.3a.

    Parameters as in :func:`remove_stator_component`; returns the line alone [A] (zero mean).
    Raises :class:`~cnctwin.exceptions.ConfigError` if the band touches 0 Hz or Nyquist.

    Parameters
    ----------
    current : array-like
        Spindle current samples at constant speed [A].
    speed_rpm : float or array-like
        Spindle speed [rpm]; the median of an array is used (one plateau, one line).
    poles : int
        Number of motor poles (see :func:`stator_frequency_hz`).
    fs_hz : float
        Sample rate [Hz].
    bandwidth_hz : float, default 10.0
        Width of the pass band centred on the folded stator frequency [Hz].
    order : int, default 2
        Butterworth order of the band pass.
    zero_phase : bool, default True
        Forward-backward filtering.

    Returns
    -------
    numpy.ndarray
        The stator line alone [A] (zero mean).
    """
    x = _as_signal(current, -1)
    _, lo, hi = _stator_band(speed_rpm, poles, fs_hz, bandwidth_hz)
    return bandpass(x, lo, hi, fs_hz=fs_hz, order=order, zero_phase=zero_phase)
