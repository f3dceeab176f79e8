"""Tests of the anomaly detectors (cnctwin.usecases.anomaly).

The conformance part follows river's ``check_estimator`` idea: every detector in DETECTORS is
checked for the shared contract through its ``_unit_test_params``.
"""

from __future__ import annotations

import pickle

import numpy as np
import pandas as pd
import pytest

from cnctwin import ConfigError
from cnctwin.usecases.anomaly import (
    DETECTORS,
    Detector,
    EnvelopeDetector,
    PhysicsResidualDetector,
    SpectralDetector,
    TappingDetector,
    backtest,
)

FS = 500.0


def _stream(n: int = 3000, seed: int = 0) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    t = np.arange(n) / FS
    current = 4.0 + 0.05 * np.sin(2 * np.pi * 80 * t) + rng.normal(0, 0.02, n)
    return pd.DataFrame(
        {
            "current_a": current,
            "predicted_current_a": np.full(n, 4.0),
            "progress": (np.arange(n) % 500) / 500.0,
            "z_error_mm": rng.normal(0, 1e-4, n),
            "speed_rpm": np.where((np.arange(n) // 250) % 2 == 0, 400.0, -400.0),
        }
    )


@pytest.mark.parametrize("cls", DETECTORS, ids=lambda c: c.__name__)
def test_detector_conformance(cls: type[Detector]) -> None:
    df = _stream()
    det = cls(**cls._unit_test_params())
    det.learn_many(df.iloc[:2000])
    twin = pickle.loads(pickle.dumps(det))  # pickling keeps the learned state
    batch = det.score_many(df.iloc[2000:])
    one = np.array([twin.score_one(r) for r in df.iloc[2000:].to_dict("records")])
    np.testing.assert_array_equal(batch, one)  # batch == streaming, exactly
    assert batch.dtype == np.float64
    assert isinstance(det.score_one({str(k): v for k, v in df.iloc[0].items()}), float)
    fresh = det.clone()
    assert repr(fresh) == repr(det)  # same parameters
    with pytest.raises(ConfigError, match="missing"):
        det.score_many(df.drop(columns=list(det.inputs)[:1]))


def test_physics_residual_detects_step_with_short_delay() -> None:
    df = _stream(6000)
    onset = 4000
    df.loc[onset:, "current_a"] += 0.3  # a 0.3 A excess over the twin (~7 % of 4 A)
    t = np.arange(len(df)) / FS
    res = backtest(PhysicsResidualDetector(), df, time_s=t, learn_until_s=4.0,
                   fault_onsets_s=[onset / FS])
    assert res.misses == 0
    assert res.false_alarms == 0
    assert res.delays_s[0] < 0.1  # EWMA of 25 samples: ~20 ms to cross 5 sigma


def test_envelope_flags_only_outside_learned_band() -> None:
    df = _stream()
    det = EnvelopeDetector()
    det.learn_many(df.iloc[:2000])
    assert np.all(det.score_many(df.iloc[2000:2500]) <= 0.0)
    bad = df.iloc[2500:2600].copy()
    bad["current_a"] += 1.0
    assert np.all(det.score_many(bad) > 0.0)


def test_spectral_detects_injected_chatter_line() -> None:
    df = _stream(6000)
    t = np.arange(len(df)) / FS
    df.loc[4000:, "current_a"] += 0.3 * np.sin(2 * np.pi * 187.0 * t[4000:])  # chatter at 187 Hz
    res = backtest(SpectralDetector(), df, time_s=t, learn_until_s=4.0,
                   fault_onsets_s=[8.0])
    assert res.misses == 0 and res.false_alarms == 0
    assert res.delays_s[0] < 128 / FS + 0.05  # within one window


def test_tapping_detector_sees_fluctuation_only_in_reverse() -> None:
    rng = np.random.default_rng(2)
    df = _stream(6000)
    rev = (df["speed_rpm"] < 0).to_numpy() & (np.arange(len(df)) >= 4000)
    df.loc[rev, "current_a"] += rng.normal(0, 0.3, rev.sum())
    df.loc[rev, "z_error_mm"] += rng.normal(0, 5e-3, rev.sum())
    det = TappingDetector()
    det.learn_many(df.iloc[:4000])
    scores = det.score_many(df.iloc[4000:])
    fwd = (df["speed_rpm"].iloc[4000:] > 0).to_numpy()
    assert np.all(scores[fwd] <= 0.0)
    assert np.max(scores[~fwd]) > 5.0


def test_backtest_counts_false_alarms_per_hour() -> None:
    df = _stream(6000)
    df.loc[5000:5010, "current_a"] += 1.0  # a glitch with no fault behind it
    t = np.arange(len(df)) / FS
    res = backtest(PhysicsResidualDetector(smoothing=1.0), df, time_s=t, learn_until_s=4.0)
    assert res.false_alarms == 1
    assert res.false_alarms_per_hour == pytest.approx(3600.0 / res.monitored_s)
