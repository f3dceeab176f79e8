"""The live tool-life tracker's rules, and the tool table's tool-life keys (issue 27)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from cnctwin.exceptions import ConfigError
from cnctwin.machine import read_tool_table
from cnctwin.usecases.tool_life import ToolLifeLimits, ToolLifeTracker


def test_usage_limit_counts_down_exactly_and_time_follows_the_hole_period() -> None:
    tr = ToolLifeTracker({3: ToolLifeLimits(name="TAP M8", life_holes=10)})
    for k in range(4):
        st = tr.update(3, 2.0, 10.0 + 4.0 * k)
    assert (st.used_holes, st.remaining_holes, st.remaining_low, st.remaining_high) == (
        4, 6.0, 6.0, 6.0)
    assert st.basis == "usage" and st.hole_period_s == 4.0 and st.remaining_s == 24.0
    assert math.isnan(st.wear_um)  # no wear calibration: no wear invented


def test_without_limits_the_remaining_life_is_unknown_and_says_why() -> None:
    tr = ToolLifeTracker({})
    st = tr.update(7, 1.0, 0.0)
    assert st.basis == "none" and math.isnan(st.remaining_holes)
    assert "life_holes" in st.reason
    payload = st.as_payload()
    assert payload["remaining_holes"] is None and payload["never_reaches_limit"] is False


def test_wear_forecast_of_a_known_quadratic_wear_law() -> None:
    """Torque grows with a known quadratic wear law (no noise, no sets): the forecast of the
    hole where VB reaches the limit is the law's own crossing."""
    slope = 1000.0  # µm per unit relative torque increase
    lim = ToolLifeLimits(wear_limit_um=200.0, wear_um_per_increase=slope, baseline_holes=10)
    tr = ToolLifeTracker({1: lim}, set_size=None, forecast_every=1)
    tau0 = 5.0
    # VB(n) = 0.5 n + 0.002 n^2 (µm), torque = tau0 (1 + (VB(n) - VB_baseline) / slope)
    n = np.arange(150, dtype=float)
    vb = 0.5 * n + 0.002 * n**2
    base = vb[:10].mean()
    for k in range(150):
        st = tr.update(1, tau0 * (1.0 + (vb[k] - base) / slope), 4.0 * k)
    # the law crosses 200 µm (above the baseline mean) at n = 216.1
    true_cross = float(n[-1]) + 1.0
    while 0.5 * true_cross + 0.002 * true_cross**2 - base < 200.0:
        true_cross += 0.01
    assert st.basis == "wear"
    assert 149 + st.remaining_holes == pytest.approx(true_cross, abs=0.5)
    assert st.remaining_low <= st.remaining_holes <= st.remaining_high
    assert st.wear_um == pytest.approx(vb[-1] - base, abs=1e-6)


def test_the_nearer_limit_wins(tmp_path: Path) -> None:
    lim = ToolLifeLimits(life_holes=40, wear_limit_um=10.0, wear_um_per_increase=100.0,
                         baseline_holes=5)
    tr = ToolLifeTracker({1: lim}, set_size=None, min_trend_holes=4)
    for k in range(12):  # the torque already 20 % up: the wear limit (10 µm) is passed
        st = tr.update(1, 1.0 if k < 5 else 1.2, float(k))
    assert st.basis == "wear" and st.remaining_holes == 0.0


@pytest.mark.parametrize(("extra", "message"), [
    ("wear_limit_um = 300\n", "needs wear_um_per_increase"),
    ("life_holes = 10.5\n", "whole number"),
    ("wear_std_um = -1\n", "must be >= 0"),
    ("wear_limt_um = 300\n", "not a tool key"),
])
def test_tool_table_life_keys_are_checked(tmp_path: Path, extra: str, message: str) -> None:
    p = tmp_path / "tools.toml"
    p.write_text('[tools.1]\nkind = "drill"\ndiameter_mm = 8.5\n' + extra)
    with pytest.raises(ConfigError, match=message) as exc:
        read_tool_table(p)
    assert str(p) in str(exc.value)


def test_tool_table_life_keys_are_read(tmp_path: Path) -> None:
    p = tmp_path / "tools.toml"
    p.write_text('[tools.1]\nkind = "drill"\ndiameter_mm = 8.5\nlife_holes = 3000\n'
                 'wear_limit_um = 300\nwear_um_per_increase = 900\nwear_offset_um = -4\n'
                 'wear_std_um = 3\nwear_baseline_holes = 12\n')
    lim = ToolLifeLimits.from_tool(read_tool_table(p).get(1))
    assert (lim.life_holes, lim.wear_limit_um, lim.wear_um_per_increase, lim.wear_offset_um,
            lim.wear_std_um, lim.baseline_holes) == (3000, 300.0, 900.0, -4.0, 3.0, 12)
    assert lim.wear_model
