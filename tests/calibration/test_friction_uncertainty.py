"""The spindle friction's stated uncertainty against independent truths (issue 29, point 2).

* The thermal friction fit's (and the one-way Stribeck fit's) standard errors against the
  scatter of the estimates over 400 independent noise draws (a Monte Carlo truth, not the
  code's formula): its offset's
  standard error came out ~1e-10 A because the covariance was inverted from a normal matrix
  whose columns span ten decades (the air cut's ``n E`` column ~1e8 A rpm^2 s against the
  column of ones); the Coulomb friction's statistical term was then nil.
* The lack-of-fit test that admits a fit variant to the model-form spread, against the
  printed F table (NIST/SEMATECH e-Handbook of Statistical Methods, section 1.3.6.7.3:
  F(0.95; 20, 30) = 1.932): one side of the critical value counts, the other does not.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from cnctwin.calibration.spindle import LACK_OF_FIT_LEVEL, _lack_of_fit
from cnctwin.spindle import FrictionFit
from cnctwin.twin import FrictionCurve, fit_friction_stribeck, fit_friction_thermal

# an air cut up and back down through 400-4000 rpm, the friction energy dissipated before
# each plateau as friction_energy gives it [A rpm s] (3 s held and the ramps: ~6 s at each
# speed); values of a simulated spindle (seed 3000 of the calibration campaign: 2.1e5 at
# the last plateau)
_UP = np.arange(400.0, 4001.0, 200.0)
_GRID = tuple(np.geomspace(100.0, 2000.0, 40))
A_TRUE, B_TRUE, S_TRUE, NS_TRUE, G_TRUE = 7.8e-5, 0.161, 0.10, _GRID[19], -4.5e-8
SIGMA_A = 1.1e-3  # scatter of a plateau mean [A] (the fit's residual rms on that spindle)


def _sweep() -> tuple[np.ndarray, np.ndarray]:
    speeds = np.concatenate([_UP, _UP[::-1]])
    current = A_TRUE * speeds + B_TRUE
    energy = np.concatenate([[0.0], np.cumsum(current * speeds * 6.0)[:-1]])
    return speeds, energy


def _truth(speeds: np.ndarray, energy: np.ndarray) -> np.ndarray:
    return (A_TRUE * speeds * (1.0 + G_TRUE * energy) + B_TRUE
            + S_TRUE * np.exp(-speeds / NS_TRUE))


def test_thermal_fit_standard_errors_equal_the_scatter_of_its_estimates() -> None:
    speeds, energy = _sweep()
    assert energy.max() > 1.5e5  # n E reaches ~1e8 A rpm^2 s, as on the spindle
    clean = _truth(speeds, energy)
    rng = np.random.default_rng(29)
    est, se = [], []
    for _ in range(400):
        y = clean + SIGMA_A * rng.standard_normal(speeds.size)
        line = fit_friction_thermal(speeds, y, energy, 300.0, 4100.0,
                                    decay_grid_rpm=_GRID).curve.line
        est.append((line.slope_a_per_rpm, line.offset_a))
        se.append((line.slope_std, line.offset_std))
    scatter = np.std(np.array(est), axis=0, ddof=1)
    stated = np.sqrt(np.mean(np.square(se), axis=0))
    # 400 draws: the scatter's own relative standard error is ~3.5 %; the grid search over
    # the decay speed (not in the covariance) adds a little: 20 %
    assert stated == pytest.approx(scatter, rel=0.20), (stated, scatter)
    assert np.mean(np.array(est), axis=0) == pytest.approx([A_TRUE, B_TRUE], rel=0.01)


def test_stribeck_fit_standard_errors_equal_the_scatter_of_its_estimates() -> None:
    # the one-way air cut (no speed held twice): line + Stribeck term, no drift; the line's
    # own standard errors (through the Stribeck-corrected means) carried neither s nor n_s
    speeds = np.arange(300.0, 4001.0, 200.0)
    clean = A_TRUE * speeds + B_TRUE + S_TRUE * np.exp(-speeds / NS_TRUE)
    rng = np.random.default_rng(30)
    est, se = [], []
    for _ in range(400):
        y = clean + SIGMA_A * rng.standard_normal(speeds.size)
        line = fit_friction_stribeck(speeds, y, 250.0, 4100.0, decay_grid_rpm=_GRID).line
        est.append((line.slope_a_per_rpm, line.offset_a))
        se.append((line.slope_std, line.offset_std))
    scatter = np.std(np.array(est), axis=0, ddof=1)
    stated = np.sqrt(np.mean(np.square(se), axis=0))
    assert stated == pytest.approx(scatter, rel=0.20), (stated, scatter)


def _curve(n_points: int, rss: float) -> FrictionCurve:
    line = FrictionFit(slope_a_per_rpm=8e-5, offset_a=0.3, r2=0.99,
                       norm_residuals=float(np.sqrt(rss)), n_points=n_points,
                       slope_std=1e-7, offset_std=1e-3, lo_rpm=300.0, hi_rpm=4000.0)
    return FrictionCurve(line, stribeck_a=0.1, stribeck_speed_rpm=400.0,
                         model="stribeck+thermal", n_coefficients=5)


@pytest.mark.parametrize(("ratio", "counted"), [(1.92, True), (1.945, False)])
def test_a_variant_counts_up_to_the_f_tables_critical_value(ratio: float,
                                                             counted: bool) -> None:
    assert LACK_OF_FIT_LEVEL == 0.95
    chosen = _curve(35, 30 * 1e-6)            # 30 residual degrees of freedom, s^2 = 1e-6
    variant = _curve(25, 20 * 1e-6 * ratio)   # 20 degrees of freedom, s^2 = ratio * 1e-6
    table = _lack_of_fit(pd.DataFrame({"variant": ["chosen", "wider"]}), [chosen, variant])
    assert table["counted"].tolist() == [True, counted]
    assert table["residual_ratio"].iloc[1] == pytest.approx(ratio, rel=1e-12)
