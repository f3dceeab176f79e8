"""Detectors against simulated faults at hidden, seeded random times (issue #6, point 5).

Each trial draws the fault time from ``default_rng([seed, 6])`` (which hole / which moment),
simulates the run, and replays the recording through a detector taught on a fixed number of
first holes; only the backtest compares the alarms with the simulator's true onset. Figures
stated here are the measured ones written in docs/validation-usecases.md; the tolerances are
what the assertions allow.
"""

from __future__ import annotations

import numpy as np
import pytest

from cnctwin.sim.faults import LooseTool, loose_tool_signature
from cnctwin.usecases.figures import plot_loose_tap
from cnctwin.validation.trials import (
    fault_free_run,
    fault_trial,
    loose_tap_trial,
    summarize_trials,
)

pytestmark = pytest.mark.slow

SEEDS = range(4)


def test_loose_tool_signature_is_stick_slip() -> None:
    # sawtooth torque of half range A_T, one drop per slip period, axial pull right after a slip
    f = LooseTool(torque_amplitude_nm=1.0, axial_force_amplitude_n=300.0, freq_hz=40.0,
                  amplitude_spread=0.0)
    t = np.arange(0, 1.0, 1e-4)
    tq, ax = loose_tool_signature(f, t)
    assert tq.max() == pytest.approx(1.0, abs=0.01) and tq.min() == pytest.approx(-1.0, abs=0.01)
    drops = np.flatnonzero(np.diff(tq) > 1.0)  # the release at each slip
    assert drops.size == 39  # 40 Hz over 1 s
    assert ax.min() == pytest.approx(-300.0, abs=1.0) and ax.max() <= 0.0
    # chunk-independent: the same slip amplitudes whether computed in one piece or two
    tq2 = np.concatenate([loose_tool_signature(f, t[:3333])[0],
                          loose_tool_signature(f, t[3333:])[0]])
    np.testing.assert_array_equal(tq, tq2)


def test_loose_tap_detected_at_hidden_hole() -> None:
    trials = [loose_tap_trial(s) for s in SEEDS]
    trials += [loose_tap_trial(s, with_fault=False) for s in SEEDS]
    drawn = [t.hidden["loose_from_hole"] for t in trials[:4]]
    assert len(set(drawn)) > 1  # the hidden hole really varies with the seed
    summary = summarize_trials(trials).set_index("fault")
    lt = summary.loc["loose_tool"]
    # measured: every loose extraction found 0.16-0.17 s after the onset (the rolling window
    # is 0.1 s); no alarm on tight extractions. Tolerance: delay < 0.3 s, no miss, no false alarm
    assert lt["misses"] == 0 and lt["detected"] == lt["with_fault"] >= 3
    assert lt["delay_max_s"] < 0.3
    assert lt["false_alarms"] == 0
    assert summary.loc["tapping_no_fault", "false_alarms"] == 0
    # Figure 5.10 analogue: Z encoder position, spindle current and dynamometer torque
    t = next(t for t in trials if t.onset_s is not None)
    assert t.onset_s is not None
    fig = plot_loose_tap(t.scenario.recordings[0], around_s=t.onset_s, onset_s=t.onset_s,
                         alarms_s=t.result.alarms_s)
    assert len(fig.axes) == 4


@pytest.mark.parametrize(
    ("kind", "max_delay_s"),
    # measured (docs/validation-usecases.md): breakage 0.002 s (the broken drill drops the
    # current below the envelope within a sample), hardness change 0.23-0.25 s (EWMA of 20 ms
    # plus the hole entry), chatter 0.26-0.33 s (128-sample window, 3 spectra in a row)
    [("breakage", 0.05), ("hardness", 0.5), ("chatter", 0.5)],
)
def test_drilling_faults_at_hidden_times(kind: str, max_delay_s: float) -> None:
    trials = [fault_trial(kind, s) for s in SEEDS]
    hidden = [tuple(t.hidden.values()) for t in trials]
    assert len(set(hidden)) == len(hidden)  # a different hidden draw per seed
    row = summarize_trials(trials).iloc[0]
    assert row["misses"] == 0 and row["detected"] == 4
    assert row["delay_max_s"] < max_delay_s
    # false alarms before the onset: measured 0 for every kind over 8 seeds (chatter: 3 in 8
    # before the spectral detector restarted its window per hole)
    assert row["false_alarms"] == 0


def test_fault_free_drilling_runs_raise_no_alarm() -> None:
    trials = [fault_trial("none", s) for s in SEEDS]
    row = summarize_trials(trials).iloc[0]
    assert row["with_fault"] == 0
    assert row["false_alarms"] == 0  # measured 0 in 4 x 6 scored holes (0.025 h)


def test_chatter_detector_fault_free_drilling_has_no_false_alarm() -> None:
    # 108 scored fault-free holes (~0.09 h of cutting): the spectral detector restarts per hole,
    # so the step between joined cuts (the 3 false alarms of the 8-seed trials before) is gone.
    # The 300-hole run of docs/validation-usecases.md: 0 alarms in 0.37 h (95 % bound 8 /h).
    res = fault_free_run(11, n_holes=120)
    assert res["spectral"].false_alarms == 0
    assert res["spectral"].healthy_s > 300.0
