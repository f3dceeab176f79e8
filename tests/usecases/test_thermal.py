"""Tool-tip temperature soft sensor (thesis chapter 5.2, Figure 5.5).

Synthetic truth: hidden tau and C_eff drawn at random, readings with 4 °C noise (the simulated
FLIR camera's noise); the fit must recover them. Simulated wear run: the simulator's tool model
is continuous in time (heat enters during the 3 s cut, cools all the time), the soft sensor
steps once per hole, so the tolerances are wider and the bias is stated.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from cnctwin.exceptions import ConfigError, IdentificationError
from cnctwin.sim.scenarios import tool_wear_run
from cnctwin.usecases.holes import hole_records
from cnctwin.usecases.thermal import (
    ToolThermalModel,
    estimate_camera_offset,
    merge_camera,
    simulate_tool_temperature,
)


def _synthetic(seed: int) -> tuple[pd.DataFrame, float, float]:
    rng = np.random.default_rng(seed)
    tau = float(rng.uniform(15.0, 40.0))
    c_eff = float(rng.uniform(25.0, 60.0))
    n = 36
    gaps = np.where(np.arange(n) % 6 == 0, 60.0, 4.8) + rng.uniform(-0.2, 0.2, n)
    end = np.cumsum(gaps)
    energy = 2900.0 * (1 + 0.1 * np.arange(n) / n) * rng.uniform(0.97, 1.03, n)
    holes = pd.DataFrame({"hole": np.arange(n), "end_s": end, "energy_j": energy})
    return holes, tau, c_eff


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_recovers_hidden_tau_and_capacity(seed: int) -> None:
    holes, tau, c_eff = _synthetic(seed)
    dt = np.concatenate([[np.inf], np.diff(holes["end_s"])])
    truth = simulate_tool_temperature(holes["energy_j"], dt, tau_s=tau, c_eff_j_per_k=c_eff)
    rng = np.random.default_rng(100 + seed)
    cam = truth + rng.normal(0.0, 4.0, truth.size)
    cam[rng.choice(truth.size, 6, replace=False)] = np.nan  # some holes without a reading
    m = ToolThermalModel().fit(holes, cam)
    # 30 readings, 4 °C noise, 100-350 °C span: tau within 10 % (its standard error is
    # 3-4 %), C_eff within 5 %
    assert m.tau_s == pytest.approx(tau, rel=0.10)
    assert m.c_eff_j_per_k == pytest.approx(c_eff, rel=0.05)
    assert m.rmse_c == pytest.approx(4.0, rel=0.35)
    assert abs(m.tau_s - tau) < 4 * m.std["tau_s"]
    pred = m.predict(holes)
    assert np.sqrt(np.mean((pred - truth) ** 2)) < 2.5


def test_fit_ambient() -> None:
    holes, tau, c_eff = _synthetic(5)
    dt = np.concatenate([[np.inf], np.diff(holes["end_s"])])
    truth = simulate_tool_temperature(holes["energy_j"], dt, tau_s=tau, c_eff_j_per_k=c_eff,
                                      ambient_c=31.0)
    m = ToolThermalModel().fit(holes, truth, fit_ambient=True)
    assert m.ambient_c == pytest.approx(31.0, abs=0.1)
    assert m.tau_s == pytest.approx(tau, rel=1e-3)


def test_errors() -> None:
    holes, _, _ = _synthetic(1)
    with pytest.raises(IdentificationError, match="not calibrated"):
        ToolThermalModel().predict(holes)
    with pytest.raises(IdentificationError, match="at least 3"):
        ToolThermalModel().fit(holes, np.r_[[100.0, 120.0], np.full(34, np.nan)])
    with pytest.raises(ConfigError, match="energy_j"):
        ToolThermalModel().fit(holes.drop(columns="energy_j"), np.ones(36))


def test_camera_offset_from_reading_pattern() -> None:
    ext = np.cumsum(np.where(np.arange(24) % 6 == 0, 60.0, 4.8))
    reading_own = ext + 0.3 + 12.5  # camera clock 12.5 s behind, read 0.3 s after extraction
    off = estimate_camera_offset(ext, reading_own, max_delay_s=2.0)
    shifted = reading_own + off
    j = np.searchsorted(ext, shifted) - 1
    assert (shifted - ext[j] > 0).all() and (shifted - ext[j] <= 2.0).all()
    assert off == pytest.approx(-12.5, abs=0.31)


@pytest.fixture(scope="module")
def wear_run():  # type: ignore[no-untyped-def]
    # hidden tool thermal parameters (not the defaults): R C = 29.7 s, C / eta = 41.25 J/K
    return tool_wear_run(n_holes=18, seed=2, overrides={
        "tool_thermal.resistance_k_per_w": 9.0, "tool_thermal.heat_fraction": 0.08})


def test_soft_sensor_on_simulated_camera(wear_run) -> None:  # type: ignore[no-untyped-def]
    res = wear_run
    holes = hole_records(res.recordings)
    cam = res.recording.external["thermal_camera"]
    by_hole = merge_camera(holes, cam)
    by_time = merge_camera(holes, cam, on="time")
    assert by_time.attrs["camera_unmatched"] == 0
    np.testing.assert_array_equal(by_time["camera_temperature_c"],
                                  by_hole["camera_temperature_c"])
    m = ToolThermalModel().fit(by_hole, by_hole["camera_temperature_c"])
    th = res.truth["tool_thermal"]
    tau = th["resistance_k_per_w"] * th["heat_capacity_j_per_k"]
    c_eff = th["heat_capacity_j_per_k"] / th["heat_fraction"]
    # per-hole stepping vs continuous heating (3 s cut, 0.4 s to the reading): tau within 10 %,
    # C_eff biased high (heat lost during the cut looks like a larger capacity) within 15 %
    assert m.tau_s == pytest.approx(tau, rel=0.10)
    assert m.c_eff_j_per_k == pytest.approx(c_eff, rel=0.15)
    # camera noise 4 °C (simulator ThermalCamera.noise_c): residual at that level
    assert m.rmse_c < 6.0
    truth = pd.DataFrame(res.truth["holes"])["tool_temperature_camera_c"].to_numpy()
    pred = m.predict(holes)
    assert np.sqrt(np.mean((pred - truth) ** 2)) < 8.0
    # thesis Figure 5.5: about 300 °C after 6 consecutive holes
    assert 250 < pred[5] < 400
