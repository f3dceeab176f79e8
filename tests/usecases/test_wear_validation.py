"""Wear, trend, set pattern, remaining life and tool-temperature soft sensor on a simulated run
with a hidden wear curve (issue #6, point 2).

The full 2676-hole run is tests/usecases/test_wear_full.py (~50 s); this faster check (~15 s)
covers the whole tool life at a finer scale per hole: the same simulator, a 300-hole run with
the thesis wear
curve compressed to 300 holes (0 -> ~277 µm, the thesis end value, thesis §5.1), written to
``tmp_path`` through the Parquet chunk sink and read back like a user's recording. The analysis
sees the recording and the camera CSV; the truth gives only 5 "microscope" wear readings and the
scores.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cnctwin.iotools import read_recording
from cnctwin.sim.scenarios import tool_wear_run
from cnctwin.usecases.holes import hole_record
from cnctwin.validation.wearcheck import WearValidation, validate_wear

pytestmark = pytest.mark.slow

N_HOLES = 300


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> tuple[WearValidation, pd.DataFrame]:
    out = tmp_path_factory.mktemp("wear300")
    ov = {"wear.n_end": float(N_HOLES), "wear.run_in_holes": 40.0 * N_HOLES / 2676,
          "wear.rate_um_per_hole": 147.0 / N_HOLES}
    res = tool_wear_run(out, n_holes=N_HOLES, seed=4, overrides=ov, fmt="parquet",
                        dynamometer=False)
    rec = read_recording(res.recording_paths[0])
    holes = hole_record(rec, store=False)
    del rec
    camera = pd.read_csv(Path(out) / "thermal_camera.csv")
    truth = pd.read_csv(Path(out) / "holes.csv")
    return validate_wear(holes, truth, camera=camera, n_measured=5), truth


def _independent_rise(torque_nm: np.ndarray, set_size: int = 6) -> float:
    """Last hole of a set over the first, each relative to its set mean, averaged over the
    complete sets: thesis §5.1's within-set pattern, written out without cnctwin's code."""
    n_sets = torque_nm.size // set_size
    sets = torque_nm[: n_sets * set_size].reshape(n_sets, set_size)
    rel = sets / sets.mean(axis=1, keepdims=True)
    return float(rel[:, -1].mean() / rel[:, 0].mean() - 1.0)


def _wear_curve_recovered_from_five_points(validation: WearValidation) -> None:
    v = validation
    assert v.n_holes == N_HOLES and len(v.measured_holes) == 5
    # measured (seed 1 and 4): RMS 4-5 µm over 0-277 µm; the largest errors in the run-in,
    # where the wear grows within a set faster than a set mean can follow. Tolerances:
    assert v.wear_rms_um < 10.0
    assert v.wear_rms_set_um < 8.0
    assert abs(v.final_wear_est_um - v.final_wear_true_um) < 20.0


def _trend_and_set_pattern(validation: WearValidation, truth: pd.DataFrame) -> None:
    v = validation
    # thesis Fig. 5.3: the 15-hole moving average rises with the wear
    assert v.trend_corr > 0.99
    # relative increase of the moving average follows the true cutting torque's (measured
    # 0.6 %-points RMS); tolerance 2 %-points
    assert v.trend_rms_pct < 2.0
    # within-set pattern (tool heating, thesis §5.1/5.2) as in the simulator's true cutting
    # torque per hole (holes.csv), computed here without cnctwin's set_pattern; +-0.5 %-points
    rise = _independent_rise(truth["mean_cutting_torque_nm"].to_numpy(dtype=np.float64))
    assert rise > 0.002  # the heating effect is there to be found
    assert v.rise_true == pytest.approx(rise, abs=1e-12)
    assert v.rise_est == pytest.approx(rise, abs=0.005)


def _remaining_life_forecast(validation: WearValidation) -> None:
    fc = validation.forecasts.set_index("at_hole")
    assert np.isfinite(fc["true_hole"]).all()
    # measured: +42, +20, +5 holes at 60 / 75 / 90 % of the run, the estimator recalibrated on
    # the 3-4 measured points drilled so far (no look-ahead); the accelerating wear phase is not
    # in the data at 60 %, so the forecast is late there and tightens towards the end
    err = fc["error_holes"].abs().to_numpy()
    assert err[-1] <= 10.0
    assert err[1] <= 30.0
    assert err[-1] <= err[0]


def _tool_temperature_soft_sensor(validation: WearValidation) -> None:
    th = validation.thermal
    # calibrated on the first 4 sets of camera readings, predicts all 300 holes;
    # camera noise 4 °C (simulator ThermalCamera). Measured 3.1 °C on the calibration sets,
    # 8.1 °C on all readings, 6.8 °C against the noise-free temperature; tolerance 10 °C
    assert th["fit_rmse_c"] < 8.0
    assert th["camera_rmse_c"] < 10.0
    assert th["truth_rmse_c"] < 10.0


def test_300_hole_run_against_hidden_truth(run: tuple[WearValidation, pd.DataFrame]) -> None:
    # one test: with pytest-xdist every worker running a test of this module would build the
    # module fixture (the simulated run) again
    validation, truth = run
    _wear_curve_recovered_from_five_points(validation)
    _trend_and_set_pattern(validation, truth)
    _remaining_life_forecast(validation)
    _tool_temperature_soft_sensor(validation)
