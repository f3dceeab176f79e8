"""cnctwin.analysis.correlation: thesis Fig. 3.7 (correlation rises as the cutoff drops)."""

from __future__ import annotations

import itertools
import warnings

import numpy as np
import pandas as pd
import pytest

from cnctwin.analysis.correlation import correlation_matrix, plot_correlation_heatmaps
from cnctwin.analysis.filters import FilterWarning
from cnctwin.exceptions import ConfigError

FS = 500.0


def _frame(seed: int = 0) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    t = np.arange(5000) / FS
    torque = 4.0 + 0.5 * np.sin(2 * np.pi * 0.5 * t)  # slow trend shared by all
    return pd.DataFrame({
        "CURRENT|SP1": torque / 1.04 + rng.normal(0, 0.5, t.size),
        "TORQUE|SP1": torque + rng.normal(0, 0.5, t.size),
        "mz_nm": torque + rng.normal(0, 0.8, t.size),
        "label": ["x"] * t.size,
    })


def test_correlation_increases_with_lower_cutoff() -> None:
    mats = correlation_matrix(_frame(), fs_hz=FS)
    assert list(mats) == ["raw", "lowpass 100 Hz", "lowpass 50 Hz", "lowpass 10 Hz"]
    r = [float(m.to_numpy()[0, 2]) for m in mats.values()]  # CURRENT|SP1 vs mz_nm
    assert all(a < b for a, b in itertools.pairwise(r))
    # white noise: a 10 Hz low-pass keeps ~4 % of its power (10 / 250 Hz) while the 0.5 Hz
    # trend passes -> expected r ~ 0.88; raw r ~ 0.3
    assert r[-1] > 0.8 and r[0] < 0.4
    assert "label" not in mats["raw"].columns


def test_nan_repair_is_reported_and_figure_builds() -> None:
    df = _frame()
    df.iloc[10:20, 0] = np.nan
    with pytest.warns(FilterWarning, match="10 missing"):
        mats = correlation_matrix(df, fs_hz=FS, cutoffs_hz=(None, 10.0))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fig = plot_correlation_heatmaps(mats)
    assert len([a for a in fig.axes if a.get_visible()]) == 3  # 2 panels + colorbar
    with pytest.raises(ConfigError):
        correlation_matrix(df[["CURRENT|SP1"]], fs_hz=FS)


def test_heatmaps_fit_a_report_page_at_a_readable_size() -> None:
    """Issue 16, point 3: four 10-signal matrices (the demo's Fig. 3.7 analogue) were drawn
    in one row ~38 in wide and shrunk to the report's 11 in: 2 pt labels. Now at most two
    panels per row and the figure no wider than the page, so 8 pt stays 8 pt."""
    from cnctwin.analysis.correlation import PAGE_WIDTH_IN

    names = [f"SIG{i}|X1" for i in range(10)]
    m = pd.DataFrame(np.eye(10), index=names, columns=names)
    fig = plot_correlation_heatmaps({k: m for k in ("raw", "lowpass 10 Hz", "a", "b")})
    width_in, _ = fig.get_size_inches()
    assert width_in <= PAGE_WIDTH_IN + 0.5
    shrink = min(1.0, PAGE_WIDTH_IN / width_in)
    label_pt = min(t.get_fontsize() for a in fig.axes[:4] for t in a.get_xticklabels())
    assert label_pt * shrink >= 7.0
