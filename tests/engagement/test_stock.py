"""The Z-map engagement against the closed-form geometry of a straight cut.

A flat end mill of radius R moving in a straight line: a slot immerses 0..pi; a side step of
radial width ae with the material on the left of the feed immerses 0..arccos(1 - ae/R) (up
milling), on the right pi - arccos(1 - ae/R)..pi (down milling); the removed volume per mm of
travel is ae x ap (Altintas, *Manufacturing Automation*, 2nd ed., ch. 2.4). Tolerances: the
angle to one bin (1 deg) plus the cell's share of ae; the volume of a slot to 1 %, of a side
step to one cell (0.1 mm) of ae.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from cnctwin.engagement import Stock, ZMap, parse_stock
from cnctwin.exceptions import ConfigError
from cnctwin.sim.cutting import MATERIALS, EndMill, mean_milling_load, milling_load

R = 8.0
STEP = 1000.0 / 60.0 * 0.002  # 1000 mm/min at 2 ms


def _path(y: float, z: float = -2.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    x = np.arange(-12.0, 92.0, STEP)
    return x, np.full_like(x, y), np.full_like(x, z)


def _middle(x: np.ndarray) -> np.ndarray:
    return (x > 20.0) & (x < 70.0)


@pytest.fixture
def stock() -> Stock:
    return Stock(0.0, 0.0, -20.0, 80.0, 60.0, 0.0)


def test_slot_is_full_immersion_at_the_programmed_depth(stock: Stock) -> None:
    zm = ZMap(stock)
    x, y, z = _path(30.0)
    e = zm.sweep(x, y, z, diameter_mm=2 * R)
    m = _middle(x)
    assert np.all(e.entry_rad[m] == 0.0) and np.all(e.exit_rad[m] == pytest.approx(math.pi))
    assert e.axial_depth_mm[m] == pytest.approx(2.0, abs=1e-6)
    vol_per_mm = e.removed_mm3[m].sum() / (x[m][-1] - x[m][0])
    assert vol_per_mm == pytest.approx(2 * R * 2.0, rel=0.01)
    # outside the stock nothing is engaged
    assert not e.engaged[x < -R - 0.5].any()


@pytest.mark.parametrize("ae", [0.5, 3.0, 6.0])
def test_side_steps_left_and_right(stock: Stock, ae: float) -> None:
    zm = ZMap(stock)
    x, y, z = _path(30.0)
    zm.sweep(x, y, z, diameter_mm=2 * R)  # the slot
    m = _middle(x)
    tol = math.pi / 180 + math.acos(1 - (ae + 0.1) / R) - math.acos(1 - ae / R)
    left = zm.sweep(x, y + ae, z, diameter_mm=2 * R)  # material on the left of +X: +Y side
    assert np.all(left.entry_rad[m] == 0.0)
    assert np.median(left.exit_rad[m]) == pytest.approx(math.acos(1 - ae / R), abs=tol)
    # the wall moves in whole cells: ae to one cell (0.1 mm) times ap
    assert left.removed_mm3[m].sum() / (x[m][-1] - x[m][0]) == pytest.approx(ae * 2.0,
                                                                              abs=0.1 * 2.0)
    right = zm.sweep(x, y - ae, z, diameter_mm=2 * R)
    assert np.all(right.exit_rad[m] == pytest.approx(math.pi))
    assert np.median(right.entry_rad[m]) == pytest.approx(math.pi - math.acos(1 - ae / R),
                                                          abs=tol)


def test_a_second_pass_cuts_air_and_a_deeper_one_cuts_only_the_new_depth(stock: Stock) -> None:
    zm = ZMap(stock)
    x, y, z = _path(30.0)
    zm.sweep(x, y, z, diameter_mm=2 * R)
    again = zm.sweep(x, y, z, diameter_mm=2 * R)
    assert not again.engaged.any() and again.removed_mm3.sum() == 0.0
    deeper = zm.sweep(x, y, z - 1.5, diameter_mm=2 * R)
    m = _middle(x)
    assert deeper.axial_depth_mm[m] == pytest.approx(1.5, abs=1e-5)
    assert np.all(deeper.entry_rad[m] == 0.0)


def test_milling_with_the_zmap_matches_the_closed_form_mean() -> None:
    """Instantaneous model over a revolution = closed-form mean (Altintas eq. 2.47)."""
    tool = EndMill()
    mat = MATERIALS["aisi1045"]
    assert mat.milling is not None
    ang = np.linspace(0.0, 2 * math.pi, 20000, endpoint=False)
    for e0, e1 in [(0.0, math.pi), (0.0, 0.9), (2.2, math.pi)]:
        inst = milling_load(ang, 0.1, 2.0, 0.7, tool=tool, material=mat, entry_angle_rad=e0,
                            exit_angle_rad=e1)
        mean = mean_milling_load(0.1, 2.0, e0, e1, feed_direction_rad=0.7, diameter_mm=16.0,
                                 flutes=2, coefficients=mat.milling)
        assert float(mean.torque_nm) == pytest.approx(inst.torque_nm.mean(), rel=1e-3)
        assert float(mean.fx_n) == pytest.approx(inst.fx_n.mean(), rel=1e-3, abs=0.05)
        assert float(mean.fy_n) == pytest.approx(inst.fy_n.mean(), rel=1e-3, abs=0.05)


def test_stock_text_and_errors() -> None:
    s = parse_stock("-20, 0, -30, 80, 80, 0")
    assert (s.x0_mm, s.z0_mm, s.z1_mm) == (-20.0, -30.0, 0.0)
    assert parse_stock(s.as_text()) == s
    with pytest.raises(ConfigError, match="six numbers"):
        parse_stock("0,0,0,10,10")
    with pytest.raises(ConfigError, match=r"Z1 = -5\.0 must be greater than Z0"):
        parse_stock("0,0,0,10,10,-5")
