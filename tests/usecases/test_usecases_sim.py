"""Use-cases validated on simulated runs with hidden truth (issue #6).

Shorter runs than the thesis (2676 holes take minutes): the same simulator and models with the
wear curve compressed to 60 holes (``wear.n_end = 60``: 0 -> ~277 µm, the thesis end value), and
24-hole runs with faults at hidden times. The analyses read only the Recording; the truth is used
for the "microscope" points and for scoring.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from cnctwin.sim.faults import Chatter, ToolBreakage
from cnctwin.sim.scenarios import tool_wear_run
from cnctwin.usecases.anomaly import SpectralDetector, backtest
from cnctwin.usecases.holes import hole_record
from cnctwin.usecases.wear import WearEstimator, forecast_remaining_life, relative_increase

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def wear60():  # type: ignore[no-untyped-def]
    ov = {"wear.n_end": 60.0, "wear.run_in_holes": 3.0, "wear.rate_um_per_hole": 147 / 60}
    return tool_wear_run(n_holes=60, seed=11, overrides=ov)


def test_wear_estimator_recovers_hidden_wear(wear60) -> None:  # type: ignore[no-untyped-def]
    rec = wear60.recording
    truth = pd.DataFrame(wear60.truth["holes"])
    h = hole_record(rec)
    assert len(h) == 60
    # temperature-corrected increase: set means remove the heating pattern of each set of 6
    inc = relative_increase(h["torque_mean_nm"], baseline=6, set_size=6)
    measured = [11, 29, 41, 59]  # four "microscope" readings
    est = WearEstimator().fit(inc[measured], truth["wear_um"].iloc[measured])
    wear = est.predict(inc)
    err = np.abs(wear - truth["wear_um"].to_numpy())
    # 0-277 µm over the run: mean error 15 µm (measured), stated tolerance 25 µm; the largest
    # errors sit in the run-in phase where wear grows fastest within a set (per-hole truth vs
    # the set-mean estimate)
    assert err.mean() < 25.0
    set_mean = truth["wear_um"].groupby(truth["hole"] // 6).transform("mean").to_numpy()
    assert np.abs(wear - set_mean).max() < 45.0
    # forecast at hole 47 from the last 24 holes (linear): the 250 µm crossing is at hole 57
    # in the truth; forecast 61.4 (measured), tolerance +-6 holes
    true_cross = int(np.argmax(truth["wear_um"].to_numpy() >= 250.0))
    fc = forecast_remaining_life(h["hole"][:48], wear[:48], limit_um=250.0, window=24,
                                 degree=1)
    assert abs(fc.index_at_limit - true_cross) <= 6


def _cut_stream(rec, holes: pd.DataFrame) -> pd.DataFrame:  # type: ignore[no-untyped-def]
    cyc = rec.cycles
    t = rec.time_s
    cur = rec.hf["CURRENT|SP1"].to_numpy()
    parts = []
    for _, x in holes.iterrows():
        lo = int(np.searchsorted(cyc, x["cut_start_cycle"]))
        hi = int(np.searchsorted(cyc, x["cut_end_cycle"], side="right"))
        parts.append(pd.DataFrame({"time_s": t[lo:hi], "current_a": cur[lo:hi]}))
    return pd.concat(parts, ignore_index=True)


@pytest.mark.parametrize(
    ("fault", "max_delay"),
    [(ToolBreakage(hole=17), 0.5), (Chatter(start_s=150.0), 0.5), (None, None)],
)
def test_faults_at_hidden_times(fault, max_delay) -> None:  # type: ignore[no-untyped-def]
    # A hardness change is no case for this band-power detector: it saw a 15 % step within
    # 5 s on 4 of seeds 0-7 (2 of 8 once the drive interpolates its speed setpoint, issue 29),
    # so the one seed asserted here was luck. The load monitors (envelope, adaptive, physics)
    # catch it on 8 of 8 draws within 2 s: tests/usecases/test_trials.py, test_monitoring.py,
    # docs/validation-usecases.md.
    # 30 s pauses between sets: the fault times and the scored span below were set with them
    res = tool_wear_run(n_holes=24, seed=5, faults=[fault] if fault else [],
                        gap_between_sets_s=30.0)
    rec = res.recording
    holes = hole_record(rec)
    onsets = [o for o in res.truth["fault_onsets_s"] if o is not None]
    data = _cut_stream(rec, holes)
    # teach-in on the first two sets (12 holes), score the cuts of the last two
    learn_until = float(holes["start_s"].iloc[12]) - 1.0
    bt = backtest(SpectralDetector(fs_hz=rec.fs_hz, band_hz=(100.0, 240.0)), data,
                  time_s=data["time_s"], learn_until_s=learn_until, fault_onsets_s=onsets,
                  max_delay_s=5.0)
    # 12 holes x 3.0 s of cutting scored. Measured: breakage 0.13 s, chatter 0.25 s after
    # onset; false alarms 1-5 per run, 2 in the fault-free run (hole-entry transients)
    assert bt.monitored_s == pytest.approx(76.8, abs=0.5)  # span of the scored cuts [s]
    if fault is None:
        assert onsets == []
        assert bt.false_alarms <= 2
        return
    assert len(onsets) == 1
    assert bt.misses == 0
    assert bt.delays_s[0] < max_delay
    assert bt.false_alarms <= 5
