"""Amplitude spectra and dominant lines of uniformly sampled signals.

Used to find the (folded) stator-frequency line of the spindle current (thesis §4.1, Eq. 4.1)
and to check which line dominates a constant-speed plateau.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import signal as sps

from cnctwin.exceptions import ConfigError

__all__ = ["DominantLine", "Spectrum", "amplitude_spectrum", "dominant_frequency", "dominant_line"]


@dataclass(frozen=True)
class Spectrum:
    """Single-sided amplitude spectrum.

    Attributes
    ----------
    freq_hz : numpy.ndarray
        Bin frequencies 0 .. fs/2 [Hz].
    amplitude : numpy.ndarray
        Amplitude of a sinusoid at each bin, corrected for the window's coherent gain
        [unit of the signal]; a tone ``A sin(2 pi f t)`` centred on a bin reads ``A``.
    fs_hz : float
        Sample rate [Hz].
    n_samples : int
        Samples used.
    window : str
        Window name.
    """

    freq_hz: NDArray[np.float64]
    amplitude: NDArray[np.float64]
    fs_hz: float
    n_samples: int
    window: str

    @property
    def resolution_hz(self) -> float:
        """Bin spacing fs/n [Hz]."""
        return self.fs_hz / self.n_samples


@dataclass(frozen=True)
class DominantLine:
    """The strongest line of a spectrum inside a frequency range.

    Attributes
    ----------
    freq_hz : float
        Peak frequency, refined between bins by a parabola through the log amplitudes [Hz].
    amplitude : float
        Amplitude at the peak bin [unit of the signal].
    ratio_to_next : float
        Peak amplitude divided by the strongest amplitude farther than ``3`` bins away;
        values near 1 mean two lines compete.
    """

    freq_hz: float
    amplitude: float
    ratio_to_next: float


def amplitude_spectrum(
    x: ArrayLike,
    *,
    fs_hz: float,
    window: str = "hann",
    detrend: bool = True,
) -> Spectrum:
    """Single-sided amplitude spectrum of a uniformly sampled signal.

    Parameters
    ----------
    x : array-like
        Samples (1-D), uniformly spaced at ``fs_hz``.
    fs_hz : float
        Sample rate [Hz].
    window : str, default 'hann'
        Any window name :func:`scipy.signal.get_window` accepts (``'boxcar'`` for none).
    detrend : bool, default True
        Remove a least-squares line before windowing, so the mean and slow drift do not leak
        into the low bins.

    Returns
    -------
    Spectrum

    Notes
    -----
    ``A_k = 2 |X_k| / sum(w)`` (DC and Nyquist bins not doubled): a sinusoid centred on a bin
    reads its amplitude whatever the window.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(1000) / 500.0
    >>> s = amplitude_spectrum(0.3 * np.sin(2 * np.pi * 80 * t), fs_hz=500.0)
    >>> float(s.freq_hz[s.amplitude.argmax()]), round(float(s.amplitude.max()), 3)
    (80.0, 0.3)
    """
    arr = np.asarray(x, dtype=np.float64)
    if arr.ndim != 1:
        raise ConfigError(f"amplitude_spectrum needs a 1-D signal, got shape {arr.shape}")
    if arr.size < 4:
        raise ConfigError(f"amplitude_spectrum needs at least 4 samples, got {arr.size}")
    if not np.all(np.isfinite(arr)):
        raise ConfigError("signal has non-finite samples; fill or cut them before the FFT")
    if not np.isfinite(fs_hz) or fs_hz <= 0:
        raise ConfigError(f"fs_hz must be a positive sample rate in Hz, not {fs_hz!r}")
    if detrend:
        arr = sps.detrend(arr, type="linear")
    try:
        w = sps.get_window(window, arr.size, fftbins=True)
    except ValueError as exc:
        raise ConfigError(f"unknown window {window!r}: {exc}") from exc
    spec = np.abs(np.fft.rfft(arr * w)) * (2.0 / w.sum())
    spec[0] /= 2.0
    if arr.size % 2 == 0:
        spec[-1] /= 2.0
    freq = np.asarray(np.fft.rfftfreq(arr.size, d=1.0 / fs_hz), dtype=np.float64)
    return Spectrum(freq, spec, float(fs_hz), int(arr.size), window)


def dominant_line(
    x: ArrayLike | Spectrum,
    *,
    fs_hz: float | None = None,
    fmin_hz: float = 1.0,
    fmax_hz: float | None = None,
    window: str = "hann",
) -> DominantLine:
    """The strongest spectral line in ``[fmin_hz, fmax_hz]``.

    Parameters
    ----------
    x : array-like or Spectrum
        Samples (then ``fs_hz`` is required) or a precomputed :class:`Spectrum`.
    fs_hz : float, optional
        Sample rate [Hz].
    fmin_hz : float, default 1.0
        Lowest frequency considered [Hz] (excludes DC and slow drift).
    fmax_hz : float, optional
        Highest frequency considered [Hz]; default Nyquist.
    window : str, default 'hann'
        Window for the spectrum.

    Returns
    -------
    DominantLine
    """
    if isinstance(x, Spectrum):
        spec = x
    else:
        if fs_hz is None:
            raise ConfigError("fs_hz is required when x is an array of samples")
        spec = amplitude_spectrum(x, fs_hz=fs_hz, window=window)
    hi = spec.fs_hz / 2.0 if fmax_hz is None else fmax_hz
    sel = np.flatnonzero((spec.freq_hz >= fmin_hz) & (spec.freq_hz <= hi))
    if sel.size == 0:
        raise ConfigError(
            f"no spectrum bin between {fmin_hz:g} and {hi:g} Hz (resolution "
            f"{spec.resolution_hz:g} Hz); widen the range or use a longer signal"
        )
    amp = spec.amplitude
    k = int(sel[np.argmax(amp[sel])])
    freq = float(spec.freq_hz[k])
    if 0 < k < amp.size - 1 and amp[k - 1] > 0 and amp[k + 1] > 0 and amp[k] > 0:
        a, b, c = np.log(amp[k - 1]), np.log(amp[k]), np.log(amp[k + 1])
        den = a - 2 * b + c
        if den < 0:
            delta = 0.5 * (a - c) / den
            freq += float(np.clip(delta, -0.5, 0.5)) * spec.resolution_hz
    others = sel[np.abs(sel - k) > 3]
    nxt = float(amp[others].max()) if others.size else 0.0
    ratio = float(amp[k] / nxt) if nxt > 0 else float("inf")
    return DominantLine(freq, float(amp[k]), ratio)


def dominant_frequency(
    x: ArrayLike,
    *,
    fs_hz: float,
    fmin_hz: float = 1.0,
    fmax_hz: float | None = None,
    window: str = "hann",
) -> float:
    """Frequency of the strongest line in ``[fmin_hz, fmax_hz]`` [Hz].

    Parameters as in :func:`dominant_line`; returns only the (interpolated) frequency.

    Parameters
    ----------
    x : array-like
        Samples, uniformly spaced at ``fs_hz``.
    fs_hz : float
        Sample rate [Hz].
    fmin_hz : float, default 1.0
        Lowest frequency considered [Hz] (excludes DC and slow drift).
    fmax_hz : float, optional
        Highest frequency considered [Hz]; default Nyquist.
    window : str, default 'hann'
        Window for the spectrum.

    Returns
    -------
    float
        Frequency of the line [Hz], interpolated between bins.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(2000) / 500.0
    >>> round(dominant_frequency(np.sin(2 * np.pi * 37.3 * t), fs_hz=500.0), 1)
    37.3
    """
    return dominant_line(x, fs_hz=fs_hz, fmin_hz=fmin_hz, fmax_hz=fmax_hz, window=window).freq_hz
