"""Tool wear curve and tool-tip temperature (thesis §5.1, §5.2)."""

from __future__ import annotations

import numpy as np
import pytest

from cnctwin.sim.tool import ToolThermal, WearCurve, flank_wear_um, tool_temperature


def test_wear_curve_three_phases_and_end_point() -> None:
    # thesis §5.1: ~277 um flank wear after 2676 holes
    n = np.arange(0, 2677)
    vb = flank_wear_um(n)
    assert vb[-1] == pytest.approx(277.0, abs=0.5)
    rate = np.diff(vb)
    assert np.all(rate > 0)
    assert rate[:20].mean() > 2 * rate[1000:1100].mean()  # run-in faster than steady
    assert rate[-50:].mean() > 2 * rate[1000:1100].mean()  # accelerating at the end
    assert flank_wear_um(100, curve=WearCurve(accel_um=0.0)) < vb[100] + 1e-9


def test_tool_temperature_rises_about_300_c_over_six_holes() -> None:
    # thesis §5.2 / Fig. 5.5: about +300 degC over 6 consecutive holes
    dt = 0.002
    p_hole = np.r_[np.full(int(3.0 / dt), 1000.0), np.zeros(int(3.0 / dt))]  # 3 s cut, 3 s out
    temp = tool_temperature(np.tile(p_hole, 6), dt_s=dt)
    after = temp[int(3.0 / dt) - 1 :: p_hole.size]
    assert np.all(np.diff(after) > 0)
    assert after[-1] - 25.0 == pytest.approx(300.0, rel=0.25)


def test_tool_temperature_chunking() -> None:
    p = np.random.default_rng(0).uniform(0, 1000, 2000)
    th = ToolThermal()
    one = tool_temperature(p, dt_s=0.002, thermal=th)
    a = tool_temperature(p[:700], dt_s=0.002, thermal=th)
    b = tool_temperature(p[700:], dt_s=0.002, thermal=th, initial_c=float(a[-1]))
    np.testing.assert_allclose(np.r_[a, b], one, rtol=1e-12)


def test_drill_tip_stiffness_cantilever_in_series() -> None:
    # solid rod (ratio 1), D 10 mm, E 600 GPa, L 50 mm: 3 E I / L^3 with I = pi D^4 / 64
    # = 490.87 mm^4 -> 7068.6 N/mm = 7.07 N/um by hand; a 1e9 N/um spindle adds nothing,
    # an equal one halves it; doubling L divides the drill part by 8
    from cnctwin.sim.tool import Drill

    stiff = Drill(diameter_mm=10.0, effective_diameter_ratio=1.0, overhang_mm=50.0,
                  youngs_modulus_gpa=600.0, spindle_stiffness_n_per_um=1e9)
    assert stiff.tip_stiffness_n_per_um == pytest.approx(7.0686, rel=1e-4)
    half = Drill(diameter_mm=10.0, effective_diameter_ratio=1.0, overhang_mm=50.0,
                 spindle_stiffness_n_per_um=7.0686)
    assert half.tip_stiffness_n_per_um == pytest.approx(7.0686 / 2, rel=1e-4)
    long = Drill(diameter_mm=10.0, effective_diameter_ratio=1.0, overhang_mm=100.0,
                 spindle_stiffness_n_per_um=1e9)
    assert long.tip_stiffness_n_per_um == pytest.approx(7.0686 / 8, rel=1e-4)
    # thesis drill defaults (8.5 mm, 0.8 D effective, 50 mm, 30 N/um spindle): 1.44 N/um
    assert Drill().tip_stiffness_n_per_um == pytest.approx(1.44, abs=0.01)
