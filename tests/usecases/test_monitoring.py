"""Wear-adaptive monitor and physics-expected torque (cnctwin.usecases.monitoring).

Synthetic streams check the mechanics (slow drift followed, steps not absorbed, breakage from
part 1); the simulated runs draw the faults at hidden, seeded times (trials.fault_trial) and
compare with the simulator's true onset only in the backtest. The measured figures quoted are
those of docs/validation-usecases.md; the tolerances are what the assertions allow.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from cnctwin import ConfigError
from cnctwin.usecases.anomaly import EnvelopeDetector, backtest
from cnctwin.usecases.monitoring import (
    KIENZLE_PARAMETERS,
    WearAdaptiveDetector,
    drilling_torque_nm,
    expected_torque_stream,
)

FS = 500.0
CUT = 600  # samples per synthetic cut


@pytest.mark.parametrize(
    ("speed_rpm", "feed_mm_per_rev", "measured_nm"),
    # thesis §4.3 (2400 rpm, 0.16 mm/rev) and Table 4.1 (steel rows): dynamometer means, 8.5 mm
    # TiAlN carbide drill in AISI 1045
    [(2400.0, 0.16, 3.97), (2800.0, 0.14, 3.37), (3200.0, 0.125, 3.18)],
)
def test_kienzle_handbook_torque_within_10_percent_of_thesis_cuts(
    speed_rpm: float, feed_mm_per_rev: float, measured_nm: float
) -> None:
    # handbook C45 constants (VDI 3323 / ISCAR: kc1.1 = 1500 N/mm^2, mc = 0.22), no fit to the
    # thesis: 3.60 / 3.24 / 2.97 Nm, 9 % / 4 % / 7 % below the dynamometer
    tq = float(drilling_torque_nm(feed_mm_per_rev, **KIENZLE_PARAMETERS["aisi1045"]))
    assert tq == pytest.approx(measured_nm, rel=0.10)
    assert tq < measured_nm  # a consistent bias, calibrated away by the wear index


def test_kienzle_torque_hand_value_and_point_engagement() -> None:
    # f = 0.16, kappa = 70 deg: h = 0.08 sin 70 = 0.075175 mm, kc = 1500 h^-0.22 = 2650.7 N/mm^2,
    # Mc = 0.16 x 2650.7 x 8.5^2 x sin 70 / 8000 = 3.599 Nm (hand calculation)
    assert float(drilling_torque_nm(0.16)) == pytest.approx(3.599, abs=0.002)
    cone = 4.25 / np.tan(np.radians(70.0))  # point length 1.547 mm
    part = drilling_torque_nm(0.16, depth_mm=[0.0, cone / 2, cone, 10.0])
    np.testing.assert_allclose(part / 3.599, [0.0, 0.25, 1.0, 1.0], atol=1e-3)


def _holes(n: int, *, drift_per_hole: float = 0.0, step_from: int | None = None,
           step: float = 1.0, break_in: int | None = None, seed: int = 0) -> pd.DataFrame:
    """Cut-only stream of n holes: quadratic entry over 10 % of the cut, then 4 Nm, times a
    wear factor (1 + drift)^hole, a step factor from ``step_from``, 3 % noise; ``break_in``:
    the torque falls to 10 % from the middle of that hole."""
    rng = np.random.default_rng(seed)
    p = np.linspace(0.0, 1.0, CUT)
    prof = 4.0 * np.clip(p / 0.1, 0.0, 1.0) ** 2
    parts = []
    for h in range(n):
        v = prof * (1.0 + drift_per_hole) ** h * (step if step_from is not None and
                                                  h >= step_from else 1.0)
        v = v * (1.0 + rng.normal(0.0, 0.03, CUT))
        if break_in == h:
            v[CUT // 2:] *= 0.1
        parts.append(pd.DataFrame({"torque_nm": v, "progress": p, "hole": h,
                                   "expected_torque_nm": np.where(p >= 0.1, 3.4, np.nan)}))
    d = pd.concat(parts, ignore_index=True)
    d["time_s"] = np.arange(len(d)) / FS
    return d


def _alarm_holes(det: WearAdaptiveDetector | EnvelopeDetector, d: pd.DataFrame,
                 teach_holes: int) -> set[int]:
    learn = d["hole"] < teach_holes
    det.learn_many(d[learn])
    s = det.score_many(d[~learn])
    return {int(h) for h in d.loc[~learn, "hole"][s > 0].unique()}


def test_slow_wear_followed_where_the_envelope_alarms() -> None:
    # +0.3 %/hole (the compressed simulated life reaches ~0.3 %/hole at its end): +82 % in 200
    d = _holes(200, drift_per_hole=0.003)
    env = EnvelopeDetector(signal="torque_nm", smoothing=10.0)
    assert len(_alarm_holes(env, d, 10)) > 150  # the teach-in baseline alarms on wear
    det = WearAdaptiveDetector()
    assert _alarm_holes(det, d, 10) == set()
    # the wear index followed the drift: (1.003)^199 = 1.82 over the teach-in level
    assert det.wear_index == pytest.approx(1.003 ** 189, rel=0.03)


def test_hardness_step_is_not_absorbed_until_acknowledged() -> None:
    d = _holes(80, drift_per_hole=0.002, step_from=50, step=1.10)  # +10 %: the smallest drawn
    det = WearAdaptiveDetector()
    hit = _alarm_holes(det, d, 10)
    assert min(hit) == 50
    assert set(range(50, 80)) <= hit  # every later hole alarms: the step is never learned
    det.acknowledge()  # the operator accepts the new material: the index re-settles
    rest = _holes(100, drift_per_hole=0.002, step_from=50, step=1.10, seed=1).iloc[80 * CUT:]
    assert set(np.unique(rest["hole"][det.score_many(rest) > 0])) <= {80, 81, 82}


def test_physics_mode_from_part_1_breakage_and_calibration() -> None:
    # the model says 3.4 Nm, the tool cuts 4.0 (+18 %): within the initial band, calibrated
    # over 3 holes; a breakage in hole 1 (before any calibration) is found at once
    d = _holes(40, drift_per_hole=0.002, break_in=1)
    t = d["time_s"].to_numpy()
    onset = float(t[CUT + CUT // 2])
    det = WearAdaptiveDetector(expected="expected_torque_nm")
    res = backtest(det, d, time_s=t, learn_until_s=-1.0, fault_onsets_s=[onset],
                   max_delay_s=0.5)
    assert res.misses == 0 and res.delays_s[0] < 0.05  # 90 % drop: a few samples
    assert res.false_alarms == 0  # nothing before the break (hole 0, first half of 1)
    clean = _holes(40, drift_per_hole=0.002)
    det2 = WearAdaptiveDetector(expected="expected_torque_nm")
    assert np.all(det2.score_many(clean) <= 0.0)
    assert det2.wear_index == pytest.approx(4.0 / 3.4 * 1.002 ** 39, rel=0.03)


def test_expected_stream_and_errors() -> None:
    holes = pd.DataFrame({"hole": [0], "feed_mm_min": [384.0], "speed_rpm": [2400.0],
                          "depth_mm": [20.0]})
    data = pd.DataFrame({"hole": [0, 0, 0, -1], "progress": [0.0, 0.5, 1.0, np.nan]})
    e = expected_torque_stream(data, holes)
    # 384 / 2400 = 0.16 mm/rev: 3.599 Nm at full engagement; NaN in the entry and outside
    assert np.isnan(e[0]) and np.isnan(e[3])
    np.testing.assert_allclose(e[1:3], 3.599, atol=0.002)
    with pytest.raises(ConfigError, match="KIENZLE_PARAMETERS"):
        expected_torque_stream(data, holes, material="unobtainium")
    with pytest.raises(ConfigError, match="tolerances"):
        WearAdaptiveDetector(tolerance=0.0)


@pytest.mark.slow
@pytest.mark.parametrize("monitor", ["adaptive", "physics"])
def test_drilling_faults_at_hidden_times_adaptive(monitor: str) -> None:
    from cnctwin.validation.trials import fault_trial, summarize_trials

    for kind, max_delay_s in (("breakage", 0.05), ("hardness", 0.5), ("none", None)):
        trials = [fault_trial(kind, s, monitor=monitor) for s in range(4)]
        row = summarize_trials(trials).iloc[0]
        # measured over 8 seeds: breakage 0.006-0.008 s, hardness (+13-24 %) 0.33 s, no false
        # alarm in 18 holes (physics: scored from hole 0, no teach-in)
        assert row["false_alarms"] == 0, kind
        if max_delay_s is not None:
            assert row["misses"] == 0 and row["detected"] == 4, kind
            assert row["delay_max_s"] < max_delay_s, kind


@pytest.mark.slow
def test_whole_tool_life_compressed_no_false_alarm_where_envelope_fails() -> None:
    from cnctwin.validation.trials import fault_free_run

    # the thesis wear curve (to ~277 µm, +28 % torque) compressed into 300 holes, fault-free
    res = fault_free_run(11, n_holes=300, compress_life=True,
                         monitors=("envelope", "adaptive", "physics"))
    assert res["envelope"].false_alarms > 100  # the teach-in baseline alarms on wear
    assert res["adaptive"].false_alarms == 0
    assert res["physics"].false_alarms == 0
    assert res["adaptive"].healthy_s > 0.35 * 3600.0  # 288 scored holes, 0.37 h
