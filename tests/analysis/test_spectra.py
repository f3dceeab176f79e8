"""cnctwin.analysis.spectra: amplitude calibration and dominant lines."""

from __future__ import annotations

import numpy as np
import pytest

from cnctwin.analysis.spectra import amplitude_spectrum, dominant_frequency, dominant_line
from cnctwin.exceptions import ConfigError

FS = 500.0


def test_amplitude_is_window_corrected() -> None:
    t = np.arange(1000) / FS
    x = 2.0 + 0.3 * np.sin(2 * np.pi * 80 * t) + 0.1 * np.sin(2 * np.pi * 13 * t)
    # both tones sit on bins; leakage of the other tone through the sidelobes and the linear
    # detrend (a sine of 26 cycles projects ~0.1 % onto a line) stay below 0.5 %
    for window in ("hann", "boxcar", "hamming"):
        s = amplitude_spectrum(x, fs_hz=FS, window=window)
        assert s.amplitude[np.argmin(np.abs(s.freq_hz - 80))] == pytest.approx(0.3, rel=5e-3)
        assert s.amplitude[np.argmin(np.abs(s.freq_hz - 13))] == pytest.approx(0.1, rel=5e-3)
    assert s.resolution_hz == pytest.approx(0.5)
    # detrend removes the mean (2.0 -> residue of the sines' projection only)
    assert amplitude_spectrum(x, fs_hz=FS).amplitude[0] < 1e-4
    raw = amplitude_spectrum(x, fs_hz=FS, detrend=False, window="boxcar")
    assert raw.amplitude[0] == pytest.approx(2.0)


def test_dominant_frequency_off_bin_and_range() -> None:
    t = np.arange(1500) / FS
    x = 0.2 * np.sin(2 * np.pi * 37.3 * t) + 0.1 * np.sin(2 * np.pi * 151.0 * t)
    # bins of 0.33 Hz; the log-parabola refinement brings a Hann peak within 0.05 Hz
    assert dominant_frequency(x, fs_hz=FS) == pytest.approx(37.3, abs=0.05)
    assert dominant_frequency(x, fs_hz=FS, fmin_hz=100) == pytest.approx(151.0, abs=0.05)
    line = dominant_line(x, fs_hz=FS)
    assert line.ratio_to_next == pytest.approx(2.0, rel=0.2)
    with pytest.raises(ConfigError):
        dominant_frequency(x, fs_hz=FS, fmin_hz=300)
    with pytest.raises(ConfigError):
        amplitude_spectrum([1.0, 2.0], fs_hz=FS)
