"""Worn/unworn and unfinished-run validation on the real UMich CNC mill data.

Numbers are those written in docs/real-data-umich.md. The feature of experiment 1 is checked
against an independent pass over the raw CSV with the stdlib csv module.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cnctwin.iotools import read_umich_dataset
from cnctwin.recording import Recording
from cnctwin.usecases.umich import (
    feature_table,
    loeo_classification,
    unfinished_backtest,
)

DATA = Path(__file__).parents[1] / "data" / "real" / "umich-cnc-mill"


@pytest.fixture(scope="module")
def recs() -> list[Recording]:
    return read_umich_dataset(DATA)


@pytest.fixture(scope="module")
def table(recs: list[Recording]) -> pd.DataFrame:
    return feature_table(recs)


def test_features_match_raw_csv(table: pd.DataFrame) -> None:
    with (DATA / "experiment_01.csv").open(newline="") as fh:
        rows = [r for r in csv.DictReader(fh)
                if r["Machining_Process"].startswith("Layer")
                and float(r["M1_CURRENT_FEEDRATE"]) != 50 and float(r["X1_ActualPosition"]) != 198]
    sp = np.mean([float(r["S1_CurrentFeedback"]) for r in rows])
    ex = np.mean([abs(float(r["X1_ActualPosition"]) - float(r["X1_CommandPosition"]))
                  for r in rows])
    one = table.set_index("experiment").loc[1]
    assert one["n_rows"] == len(rows) == 991
    assert one["spindle_current_a"] == pytest.approx(sp, rel=1e-12)
    assert one["x_following_error_mm"] == pytest.approx(ex, rel=1e-12)
    assert sp == pytest.approx(21.1158, abs=1e-4)
    assert list(table["n_rows"]) == [991, 210, 726, 123, 27, 853, 159, 259, 388, 410, 1355,
                                     1557, 523, 72]
    assert int(table["worn"].sum()) == 8 and len(table) == 14


def test_loeo_is_no_better_than_the_baseline(table: pd.DataFrame) -> None:
    # docs/real-data-umich.md, table "worn vs unworn": the drive features do not beat the
    # majority class on a held-out experiment
    r = loeo_classification(table)
    assert r.accuracy == pytest.approx(8 / 14)
    assert r.balanced_accuracy == pytest.approx(0.5417, abs=1e-4)
    assert r.baseline_accuracy == pytest.approx(8 / 14)
    assert r.baseline_balanced_accuracy == 0.5
    c = loeo_classification(table, classifier="centroid")
    assert c.accuracy == pytest.approx(8 / 14)
    fin = table[table["finalized"]].reset_index(drop=True)
    rf = loeo_classification(fin)
    assert rf.accuracy == pytest.approx(4 / 10)
    assert rf.baseline_accuracy == pytest.approx(6 / 10)
    raw = loeo_classification(table, normalize_feed=False)
    assert raw.accuracy == pytest.approx(6 / 14)


def test_unfinished_runs_backtest(recs: list[Recording]) -> None:
    bt = unfinished_backtest(recs).set_index("experiment")
    unfinished = bt[~bt["finalized"]]
    # every unfinished experiment raises an alarm before its record ends
    assert list(unfinished.index) == [4, 5, 7, 16]
    assert list(unfinished["alarms"]) == [1, 1, 6, 2]
    np.testing.assert_allclose(unfinished["lead_s"], [5.9, 2.7, 14.5, 4.1], atol=0.051)
    # ... but the finished ones alarm as well: 93 alarms in 647.4 s scored
    fin = bt[bt["finalized"] & (bt["alarms"] >= 0)]
    assert int(fin["alarms"].sum()) == 93
    assert float(fin["scored_s"].sum()) == pytest.approx(647.4, abs=0.05)
    rate_fin = fin["alarms"].sum() / fin["scored_s"].sum()
    rate_unf = unfinished["alarms"].sum() / unfinished["scored_s"].sum()
    assert rate_fin == pytest.approx(0.1437, abs=1e-3)
    assert rate_unf == pytest.approx(10 / 38.1, abs=1e-3)
    # experiments 9 and 10 have no other finished run at their feedrate: not scored
    assert list(bt.loc[[9, 10], "alarms"]) == [-1, -1]
    assert math.isnan(float(bt["lead_s"].loc[9]))
