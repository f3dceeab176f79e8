"""cnctwin.analysis.filters: SOS Butterworth filters, streaming equivalence, stator line."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy import signal as sps

from cnctwin.analysis.filters import (
    CausalFilter,
    FilterWarning,
    bandpass,
    bandstop,
    extract_stator_component,
    fold_frequency,
    highpass,
    lowpass,
    remove_stator_component,
    stator_frequency_hz,
)
from cnctwin.exceptions import ConfigError

FS = 500.0
T = np.arange(5000) / FS


def _tone(f: float, amp: float = 1.0) -> np.ndarray:
    return amp * np.sin(2 * np.pi * f * T)


def _gain(y: np.ndarray, f: float) -> float:
    """Amplitude of the tone at f in the steady middle of y (least squares)."""
    m = slice(1000, -1000)
    basis = np.column_stack([np.sin(2 * np.pi * f * T[m]), np.cos(2 * np.pi * f * T[m])])
    coef, *_ = np.linalg.lstsq(basis, y[m], rcond=None)
    return float(np.hypot(*coef))


def test_lowpass_highpass_gains_match_butterworth() -> None:
    # 4th-order Butterworth: |H(fc)| = 1/sqrt(2) per pass; zero-phase squares it -> 0.5
    x = _tone(10.0) + _tone(100.0)
    y = lowpass(x, 10.0, fs_hz=FS)
    assert _gain(y, 10.0) == pytest.approx(0.5, abs=0.01)
    assert _gain(y, 100.0) < 1e-4
    y1 = lowpass(x, 10.0, fs_hz=FS, zero_phase=False)
    assert _gain(y1, 10.0) == pytest.approx(1 / np.sqrt(2), abs=0.01)
    yh = highpass(x, 50.0, fs_hz=FS)
    assert _gain(yh, 100.0) == pytest.approx(1.0, abs=0.01)
    assert _gain(yh, 10.0) < 1e-4


def test_band_filters() -> None:
    x = _tone(20.0) + _tone(80.0) + _tone(200.0)
    bp = bandpass(x, 70.0, 90.0, fs_hz=FS)
    assert _gain(bp, 80.0) == pytest.approx(1.0, abs=0.02)
    assert _gain(bp, 20.0) < 1e-3 and _gain(bp, 200.0) < 1e-3
    bs = bandstop(x, 70.0, 90.0, fs_hz=FS)
    assert _gain(bs, 80.0) < 1e-3
    assert _gain(bs, 20.0) == pytest.approx(1.0, abs=0.01)


def test_zero_phase_has_no_delay_causal_has() -> None:
    x = _tone(5.0)
    zp = lowpass(x, 20.0, fs_hz=FS)
    c = sps.correlate(zp[500:-500], x[500:-500], mode="full")
    lag = sps.correlation_lags(4000, 4000)[np.argmax(c)]
    assert lag == 0
    causal = lowpass(x, 20.0, fs_hz=FS, zero_phase=False)
    assert np.argmax(causal[1000:1200]) > np.argmax(x[1000:1200])  # delayed


@pytest.mark.parametrize("btype,freqs", [("lowpass", 20.0), ("bandstop", (40.0, 60.0))])
def test_causal_filter_chunked_equals_one_shot(btype: str, freqs: float | tuple) -> None:
    rng = np.random.default_rng(0)
    x = 3.0 + rng.normal(size=3001)
    one_shot = {"lowpass": lambda: lowpass(x, 20.0, fs_hz=FS, zero_phase=False),
                "bandstop": lambda: bandstop(x, 40.0, 60.0, fs_hz=FS, zero_phase=False)}[btype]()
    f = CausalFilter(btype, freqs, fs_hz=FS)  # type: ignore[arg-type]
    sizes = rng.integers(0, 120, 200)
    bounds = np.concatenate([[0], np.cumsum(sizes)])
    edges = [*bounds[bounds < x.size].tolist(), x.size]
    y = np.concatenate([f.process(x[a:b]) for a, b in itertools.pairwise(edges)])
    np.testing.assert_allclose(y, one_shot, rtol=1e-12, atol=1e-12)
    # steady-state start: a constant input gives a constant output (no start-up transient)
    f.reset()
    np.testing.assert_allclose(f.process(np.full(50, 2.5)), 2.5)


def test_causal_filter_multichannel() -> None:
    rng = np.random.default_rng(1)
    x = rng.normal(size=(3, 400))
    f = CausalFilter("lowpass", 30.0, fs_hz=FS)
    y = np.concatenate([f.process(x[:, :150]), f.process(x[:, 150:])], axis=1)
    np.testing.assert_allclose(y, lowpass(x, 30.0, fs_hz=FS, zero_phase=False), atol=1e-12)


def test_fold_frequency_table_physics_doc() -> None:
    # docs/reference/physics-and-performance.md §2: alias at 500 Hz sampling
    f = stator_frequency_hz(np.array([2400, 3200, 5000, 7000]), 8)
    np.testing.assert_allclose(f, [160, 213.33, 333.33, 466.67], atol=0.01)
    np.testing.assert_allclose(fold_frequency(f, FS), [160, 213.33, 166.67, 33.33], atol=0.01)
    assert float(fold_frequency(stator_frequency_hz(7000, 6), FS)) == pytest.approx(150.0)
    assert float(fold_frequency(500.0, FS)) == 0.0
    with pytest.raises(ConfigError, match="even"):
        stator_frequency_hz(1000, 3)


def test_remove_stator_component_keeps_mean_thesis_fig_4_3() -> None:
    # Fig. 4.3b: removing the stator line does not change the mean current
    n = 3200.0
    f_alias = float(fold_frequency(stator_frequency_hz(n, 4), FS))  # 106.7 Hz
    rng = np.random.default_rng(2)
    i = 0.6 + 0.1 * np.sin(2 * np.pi * f_alias * T) + rng.normal(0, 0.005, T.size)
    clean = remove_stator_component(i, n, poles=4, fs_hz=FS)
    assert clean.mean() == pytest.approx(i.mean(), abs=1e-3)
    assert _gain(clean, f_alias) < 0.005
    line = extract_stator_component(i, np.full(T.size, n), poles=4, fs_hz=FS)
    assert _gain(line, f_alias) == pytest.approx(0.1, rel=0.03)


def test_remove_stator_near_dc_warns_and_keeps_signal() -> None:
    x = np.ones(1000)
    with pytest.warns(FilterWarning, match="DC"):
        out = remove_stator_component(x, 15000.0 + 30.0, poles=4, fs_hz=FS)  # alias 1 Hz
    np.testing.assert_array_equal(out, x)


def test_hazards_and_errors() -> None:
    with pytest.raises(ConfigError, match="Nyquist"):
        lowpass(np.ones(100), 250.0, fs_hz=FS)
    with pytest.raises(ConfigError, match="increase"):
        bandpass(np.ones(100), 50.0, 40.0, fs_hz=FS)
    with pytest.raises(ConfigError, match="non-finite"):
        lowpass(np.array([1.0, np.nan, 1.0] * 20), 10.0, fs_hz=FS)
    with pytest.warns(FilterWarning, match="Nyquist"):
        lowpass(np.ones(1000), 248.0, fs_hz=FS)
    with pytest.warns(FilterWarning, match="padding"):
        lowpass(np.ones(10), 10.0, fs_hz=FS)
    with pytest.warns(FilterWarning, match="0.1 %"):
        lowpass(np.ones(1000), 0.1, fs_hz=FS)
