"""Real-data validation on the Vicomtech turning tool-wear table (tests/data/real/...).

Numbers were computed with cnctwin on the real file and checked by hand; they are recorded in
docs/real-data-wear.md. Source: Vicomtech/dataset-machine-tool-wear (CC BY-SA 4.0).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

from cnctwin import FormatError
from cnctwin.iotools.vicomtech import read_vicomtech
from cnctwin.usecases.vicomtech import cnc_wear_features, tracking_table, wear_validation

Table = tuple[pd.DataFrame, dict[str, Any]]

VICOMTECH = (
    Path(__file__).parents[1] / "data" / "real" / "vicomtech-turning-wear"
    / "Dataset_Machine_tool_wear.csv"
)


@pytest.fixture(scope="module")
def table() -> Table:
    return read_vicomtech(VICOMTECH)


def test_reader_facts(table: Table) -> None:
    data, meta = table
    assert meta["n_segments"] == 2054  # README.source.txt: 2054 one-second segments
    assert len(meta["tools"]) == 13  # 13 tools
    # Vb is non-decreasing within every tool (rows are in time order)
    assert all(np.all(np.diff(g["Vb"].to_numpy()) >= 0) for _, g in data.groupby("tool"))
    assert data.loc[data.tool == 4, "Vb"].max() == pytest.approx(792.346)
    assert len(cnc_wear_features(data)) == 29


def test_cnc_features_beat_plain_baselines_leave_one_tool_out(table: Table) -> None:
    data, _ = table
    res = wear_validation(data)
    # Measured: model 48.4 um, training-mean baseline 80.0 um, usage-counter baseline 66.1 um
    assert res.mae_um == pytest.approx(48.4, abs=1.0)
    assert res.baseline_mean_mae_um == pytest.approx(80.0, abs=0.5)
    assert res.baseline_usage_mae_um == pytest.approx(66.1, abs=0.5)
    assert res.mae_um < res.baseline_usage_mae_um < res.baseline_mean_mae_um


def test_spindle_torque_tracks_cutting_force_per_tool(table: Table) -> None:
    data, _ = table
    t = tracking_table(data)
    tool14 = t[(t.tool == 14) & (t.signal == "TV2.S_MEAN")].iloc[0]
    assert tool14.r == pytest.approx(0.976, abs=0.002)  # best-tracking tool
    med = t.groupby("signal")["r2"].median()
    # Within one tool F_c varies only a few %, so per-tool R^2 is modest: medians 0.48-0.61
    assert 0.4 < med["TV2.S_MEAN"] < 0.55
    assert 0.55 < med["TV50.S_MEAN"] < 0.65


def test_bad_file_names_missing_column(tmp_path: Path) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text("a,b\n1,2\n")
    with pytest.raises(FormatError, match="missing columns"):
        read_vicomtech(bad)
