"""cnctwin.spindle on synthetic recordings whose truth is generated here with numpy.

The synthetic air-cut sweep follows thesis §3.2.2/§4.1 qualitatively: current linear in speed
(Eq. 4.2 with a = 8.1e-5 A/rpm, b = 0.34 A) between a low-speed region where the stator line is
not the dominant spectral line and a current-limitation bend (here at 5000 rpm, thesis Fig. 4.1),
plus a Stribeck-like excess at low speed and a ripple at the folded stator frequency (Eq. 4.1).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from cnctwin.analysis.filters import fold_frequency, stator_frequency_hz
from cnctwin.analysis.segments import cutting_regions, speed_plateaus
from cnctwin.exceptions import ConfigError, IdentificationError
from cnctwin.recording import ExternalChannel, Recording
from cnctwin.spindle import (
    CutMeasurement,
    FrictionFit,
    SpindleModel,
    StreamingTorqueEstimator,
    air_cut_correlation,
    air_cut_statistics,
    calibrate,
    calibrate_from_recording,
    fit_friction,
    identify_inertia,
    linear_region,
    linear_region_from_recording,
    measure_cut,
    plot_air_cut,
    plot_air_cut_correlation,
    validation_table,
)

FS = 500.0
A_TRUE, B_TRUE = 8.1e-5, 0.34  # thesis Eq. (4.2)
N_BEND = 5000.0  # current limitation (thesis Fig. 4.1)
POLES = 4
SPEEDS = np.arange(300.0, 9001.0, 150.0)


def _air_cut_current(n: np.ndarray) -> np.ndarray:
    """Mean air-cut current: linear, Stribeck excess below ~900 rpm, flat above the bend."""
    return A_TRUE * np.minimum(n, N_BEND) + B_TRUE + 0.05 * np.exp(-n / 300.0)


def make_sweep(seed: int = 0, plateau_s: float = 2.0) -> Recording:
    rng = np.random.default_rng(seed)
    speed_parts, cur_parts = [], []
    prev = 0.0
    t_global = 0.0
    for n in SPEEDS:
        # ramp at 3000 rpm/s
        n_ramp = max(2, int(abs(n - prev) / 3000.0 * FS))
        ramp = np.linspace(prev, n, n_ramp, endpoint=False)
        speed_parts.append(ramp)
        cur_parts.append(_air_cut_current(ramp) + 0.3)  # inertia draws current on ramps
        k = int(plateau_s * FS)
        t = t_global + np.arange(k) / FS
        f_alias = float(fold_frequency(stator_frequency_hz(n, POLES), FS))
        ripple_amp = 0.005 + 0.03 / (1.0 + np.exp(-(n - 1100.0) / 30.0))
        i = (
            _air_cut_current(np.array([n]))[0]
            + rng.normal(0.0, 0.003)  # plateau-to-plateau scatter of the mean
            + ripple_amp * np.sin(2 * np.pi * f_alias * t + rng.uniform(0, 6.28))
            + 0.02 * np.sin(2 * np.pi * 13.0 * t)  # fixed mechanical line
            + rng.normal(0.0, 0.01, k)
        )
        speed_parts.append(np.full(k, n) + rng.normal(0, 0.2, k))
        cur_parts.append(i)
        t_global += (n_ramp + k) / FS
        prev = n
    speed = np.concatenate(speed_parts)
    current = np.concatenate(cur_parts)
    kt = 1.04
    return Recording.from_arrays(
        np.arange(speed.size) + 1000,
        {
            "CMD_SPEED|SP1": speed,
            "CURRENT|SP1": current,
            "TORQUE|SP1": kt * current,
            "POWER|SP1": kt * current * speed * 2 * np.pi / 60,
        },
    )


@pytest.fixture(scope="module")
def sweep() -> Recording:
    return make_sweep()


def test_speed_plateaus_find_every_speed(sweep: Recording) -> None:
    p = speed_plateaus(sweep)
    assert len(p) == SPEEDS.size
    np.testing.assert_allclose(p["speed_rpm"], SPEEDS, atol=0.5)
    # 2 s plateaus minus 0.5 s settle minus half the 0.2 s window at each end of the steady
    # run, which itself starts and ends half a window inside the plateau: 2 - 0.5 - 0.3 = 1.2
    assert p["duration_s"].min() == pytest.approx(1.2, abs=0.01)


def test_air_cut_statistics_and_figures(sweep: Recording) -> None:
    stats = air_cut_statistics(sweep)
    assert len(stats) == SPEEDS.size
    for col in ("CURRENT|SP1 mean", "CURRENT|SP1 min", "TORQUE|SP1 max", "POWER|SP1 mean"):
        assert col in stats
    # the plateau means recover the generating curve within 4x the 0.003 A scatter
    np.testing.assert_allclose(stats["current_a"], _air_cut_current(SPEEDS), atol=0.012)
    corr = air_cut_correlation(stats)
    assert corr.loc["CURRENT|SP1 mean", "TORQUE|SP1 mean"] == pytest.approx(1.0, abs=1e-9)
    fig = plot_air_cut(stats)
    assert len([a for a in fig.axes if a.get_visible()]) == 3
    fig2 = plot_air_cut_correlation(stats)
    assert fig2.axes


def test_linear_region_with_spectra_recovers_limits_and_poles(sweep: Recording) -> None:
    region = linear_region_from_recording(sweep)
    # pole count estimated from the spectra (truth 4)
    assert region.poles == POLES
    # lower limit: the ripple overtakes the 13 Hz line at 1100 rpm; first plateau above is
    # 1200 rpm (grid 150 rpm) -> exact within one grid step
    assert 1100.0 <= region.lo_rpm <= 1250.0
    # upper limit: bend at 5000 rpm; departure of 0.012 A per 150 rpm vs 0.003 A scatter
    # -> within one grid step either side
    assert 4850.0 <= region.hi_rpm <= 5150.0
    assert "stator" in region.reason_lo and "departs" in region.reason_hi
    assert region.table["stator_dominant"].iloc[:3].sum() == 0


def test_linear_region_given_wrong_poles_fails_honestly(sweep: Recording) -> None:
    with pytest.raises(IdentificationError):
        linear_region_from_recording(sweep, poles=6)


def test_linear_region_without_spectra(sweep: Recording) -> None:
    stats = air_cut_statistics(sweep)
    region = linear_region(stats)
    assert region.poles is None
    # Stribeck excess 0.05 exp(-n/300) exceeds 3 sigma (~0.009 A) below ~550 rpm
    assert 450.0 <= region.lo_rpm <= 1050.0
    assert 4850.0 <= region.hi_rpm <= 5150.0


def test_fit_friction_recovers_eq_4_2_line(sweep: Recording) -> None:
    stats = air_cut_statistics(sweep)
    region = linear_region_from_recording(sweep)
    fit = fit_friction(stats["speed_rpm"], stats["current_a"], region.lo_rpm, region.hi_rpm)
    # standard errors: slope ~5e-7 A/rpm (0.7 %), offset ~0.002 A; tolerances ~4 sigma
    assert fit.slope_a_per_rpm == pytest.approx(A_TRUE, rel=0.03)
    assert fit.offset_a == pytest.approx(B_TRUE, abs=0.01)
    assert fit.r2 > 0.99
    assert fit.slope_std < 2e-6
    assert fit.n_points == pytest.approx(26, abs=2)


def test_fit_friction_statistics_on_exact_line() -> None:
    n = np.array([1000.0, 2000.0, 3000.0, 4000.0])
    i = 8.1e-5 * n + 0.34 + np.array([0.01, -0.01, -0.01, 0.01])
    fit = fit_friction(n, i)
    # residuals are orthogonal to [1, n] -> the line is exactly recovered, norm = 0.02
    assert fit.slope_a_per_rpm == pytest.approx(8.1e-5, rel=1e-9)
    assert fit.norm_residuals == pytest.approx(0.02, rel=1e-9)
    with pytest.raises(IdentificationError):
        fit_friction(n, i, lo_rpm=3500)


# ------------------------------------------------------------------ drilling with dynamometer
KT_TRUE = 1.12
HOLES = [(3.0, 6.0), (10.0, 13.0), (17.0, 20.0)]  # cut start/end [s]
DYN_OFFSET_S = 1.7345  # dynamometer own t=0 is 1.7345 s after the first HF cycle


def make_drilling(seed: int = 1) -> tuple[Recording, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = np.arange(0, 24.0, 1 / FS)
    n = np.full(t.size, 2400.0)
    tau_c = np.zeros(t.size)
    z = np.full(t.size, 5.0)
    for s, e in HOLES:
        m = (t >= s) & (t < e)
        # torque builds up over 0.1 s while the drill point enters, then 3.97 Nm (thesis)
        tau_c[m] = 3.97 * np.minimum(1.0, (t[m] - s) / 0.1) * (1 + 0.02 * (t[m] - s))
        z[m] = -400.0 / 60.0 * (t[m] - s)
        after = (t >= e) & (t < e + 1.0)
        z[after] = np.linspace(z[m][-1], 5.0, after.sum())
    b_nm = A_TRUE * KT_TRUE
    tf = B_TRUE * KT_TRUE
    current = (b_nm * n + tf + tau_c) / KT_TRUE + rng.normal(0, 0.03, t.size)
    rec = Recording.from_arrays(
        np.arange(t.size), {"CMD_SPEED|SP1": n, "CURRENT|SP1": current, "ENC_POS|Z1": z}
    )
    t_dyn = np.arange(0, 21.0, 1e-3)
    tau_dyn = np.interp(t_dyn + DYN_OFFSET_S, t, tau_c) + rng.normal(0, 0.03, t_dyn.size)
    rec.external["dynamometer"] = ExternalChannel(
        name="dynamometer",
        data=pd.DataFrame({"mz_nm": tau_dyn}, index=pd.Index(t_dyn, name="time_s")),
        units={"mz_nm": "Nm"},
        fs_hz=1000.0,
    )
    return rec, tau_c


def test_cutting_regions_find_the_holes() -> None:
    rec, _ = make_drilling()
    reg = cutting_regions(rec)
    assert len(reg) == len(HOLES)
    # smoothing at 5 Hz and the Schmitt trigger delay the edges by < 60 ms
    np.testing.assert_allclose(reg["start_s"], [h[0] for h in HOLES], atol=0.06)
    np.testing.assert_allclose(reg["end_s"], [h[1] for h in HOLES], atol=0.1)
    assert (reg["z_end_mm"] < reg["z_start_mm"]).all()


def test_calibrate_from_recording_recovers_kt() -> None:
    rec, _ = make_drilling()
    fit = FrictionFit(A_TRUE, B_TRUE, 1.0, 0.0, 10, 0.0, 0.0, 1100.0, 5000.0)
    model = calibrate_from_recording(fit, rec)
    # per-sample relation is exact; noise 0.03 A / 0.03 Nm over 300 samples -> < 0.2 %;
    # a 1-cycle alignment error during the 0.1 s ramp-in costs < 0.5 %
    assert model.kt_nm_per_a == pytest.approx(KT_TRUE, rel=0.01)
    assert model.b_nm_per_rpm == pytest.approx(A_TRUE * KT_TRUE, rel=0.01)
    assert model.tau_f_nm == pytest.approx(B_TRUE * KT_TRUE, rel=0.01)


def test_validation_on_the_other_holes() -> None:
    rec, _ = make_drilling()
    fit = FrictionFit(A_TRUE, B_TRUE, 1.0, 0.0, 10, 0.0, 0.0, 1100.0, 5000.0)
    model = calibrate_from_recording(fit, rec)
    from cnctwin.analysis.align import align_external

    aligned = align_external(rec, "dynamometer")
    assert aligned.external["dynamometer"].offset_s == pytest.approx(DYN_OFFSET_S, abs=0.002)
    regions = cutting_regions(aligned)
    cuts = [measure_cut(aligned, regions.iloc[k], workpiece="steel", feed_mm_per_rev=0.167)
            for k in (1, 2)]
    table = validation_table(cuts, model)
    assert list(table.columns[:5]) == ["workpiece", "speed_rpm", "feed_mm_per_rev",
                                       "current_a", "torque_nm"]
    assert (table["error_pct"] < 1.0).all()


def test_calibrate_rejects_air_cut_window() -> None:
    fit = FrictionFit(A_TRUE, B_TRUE, 1.0, 0.0, 10, 0.0, 0.0, 1100.0, 5000.0)
    with pytest.raises(IdentificationError, match="does not exceed"):
        calibrate(fit, A_TRUE * 2400 + B_TRUE, 1.0, 2400.0)


# ------------------------------------------------------------------ inertia, streaming, temp
def _runup(j: float, seed: int = 2) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = np.arange(0, 6.0, 1 / FS)
    n = np.interp(t, [0, 0.5, 1.5, 3.0, 4.0, 5.0, 6.0], [0, 0, 3000, 3000, 1000, 1000, 1000])
    w = n * 2 * np.pi / 60
    acc = np.gradient(w, 1 / FS)
    tau = j * acc + 8.42e-5 * n + 0.35 * np.sign(n) + rng.normal(0, 0.02, t.size)
    return n, tau


def test_identify_inertia_from_runup() -> None:
    j_true = 0.012
    n, tau = _runup(j_true)
    # ramp 3000 rpm/s = 314 rad/s^2 -> J * 314 = 3.8 Nm against 0.02 Nm noise
    assert identify_inertia(n, tau, fs_hz=FS) == pytest.approx(j_true, rel=0.03)
    model = SpindleModel(1.04, 8.42e-5, 0.35)
    assert identify_inertia(n, tau, fs_hz=FS, model=model) == pytest.approx(j_true, rel=0.03)
    with pytest.raises(IdentificationError, match="run-ups"):
        identify_inertia(np.full(1000, 2000.0), np.full(1000, 0.5), fs_hz=FS)


def test_identify_inertia_from_recording() -> None:
    n, tau = _runup(0.02)
    rec = Recording.from_arrays(np.arange(n.size), {"CMD_SPEED|SP1": n, "TORQUE|SP1": tau})
    assert identify_inertia(rec) == pytest.approx(0.02, rel=0.03)


def test_cutting_torque_removes_inertia_on_runup() -> None:
    n, tau_m = _runup(0.012, seed=3)
    model = SpindleModel(1.0, 8.42e-5, 0.35, j_kgm2=0.012)
    est = model.cutting_torque(tau_m / 1.0, n)
    # no cut -> estimate is noise (0.02 Nm) except the ramp corners where the discrete
    # derivative smears one sample
    assert np.median(np.abs(est)) < 0.03
    est_no_j = model.cutting_torque(tau_m, n, accel_term=False)
    assert np.abs(est_no_j).max() > 3.0


@pytest.mark.parametrize("chunk", [1, 2, 7, 50, 333])
def test_streaming_equals_vectorized(chunk: int) -> None:
    rng = np.random.default_rng(chunk)
    n = 2400 + np.cumsum(rng.normal(0, 5, 2001))
    i = rng.normal(4.0, 0.2, n.size)
    temp = np.linspace(25, 45, n.size)
    model = SpindleModel(1.04, 8.42e-5, 0.35, j_kgm2=0.01, kt_temp_coeff_per_k=-0.001,
                         reference_temperature_c=25.0)
    ref = model.cutting_torque(i, n, temperature_c=temp)
    est = StreamingTorqueEstimator(model, fs_hz=500.0)
    parts = [est.update(i[k:k + chunk], n[k:k + chunk], temp[k:k + chunk])
             for k in range(0, n.size, chunk)]
    out = np.concatenate([*parts, est.flush()])
    np.testing.assert_array_equal(out, ref)
    assert est.n_samples == 0  # flush resets


def test_streaming_without_inertia_has_no_delay() -> None:
    model = SpindleModel(1.04, 8.42e-5, 0.35)
    est = StreamingTorqueEstimator(model)
    assert est.delay_samples == 0
    out = est.update([4.32], [2400.0])
    assert out.size == 1 and est.flush().size == 0


def test_temperature_compensation_of_kt() -> None:
    # docs/reference/physics-and-performance.md §2: NdFeB ~ -0.1 %/K -> 40 K warm-up lowers Kt by
    # ~4 %
    model = SpindleModel(1.04, 8.42e-5, 0.35, kt_temp_coeff_per_k=-0.001,
                         reference_temperature_c=20.0)
    hot = float(model.cutting_torque(4.32, 2400.0, temperature_c=60.0))
    cold = float(model.cutting_torque(4.32, 2400.0))
    assert cold - hot == pytest.approx(0.04 * 1.04 * 4.32, rel=1e-9)
    with pytest.raises(ConfigError, match="reference_temperature_c"):
        SpindleModel(1.0, 0.0, 0.0, kt_temp_coeff_per_k=-0.001).cutting_torque(
            1.0, 1.0, temperature_c=30.0)


def test_validation_table_accepts_mappings_and_measurements() -> None:
    model = SpindleModel(1.04, 8.42e-5, 0.35)
    cuts: list[CutMeasurement | dict[str, object]] = [
        CutMeasurement("Steel", 3200.0, 0.125, 3.66, 3.18),
        {"workpiece": "Cast iron", "speed_rpm": 2400.0, "current_a": 4.32, "torque_nm": 3.99},
    ]
    table = validation_table(cuts, model)
    assert table["predicted_torque_nm"].round(2).tolist() == [3.19, 3.94]  # Table 4.1
    with pytest.raises(ConfigError):
        validation_table([{"speed_rpm": 1.0}], model)
    with pytest.raises(KeyError, match="valid"):
        SpindleModel.from_parameters("nope")


# ------------------------------------------------------------------ real recording
def test_real_capture4analysis_spindle(c4a_file) -> None:  # type: ignore[no-untyped-def]
    """docs/real-data-spindle.md: a tool change, no rotation -> nothing to calibrate on."""
    from cnctwin.analysis.correlation import correlation_matrix
    from cnctwin.iotools import read_capture4analysis

    rec = read_capture4analysis(c4a_file)
    assert speed_plateaus(rec).empty
    assert cutting_regions(rec).empty
    with pytest.raises(IdentificationError, match="plateau"):
        air_cut_statistics(rec)
    mats = correlation_matrix(rec.hf[["CURRENT|SP1", "TORQUE|SP1"]], fs_hz=rec.fs_hz)
    assert mats["raw"].iloc[0, 1] == pytest.approx(0.9986, abs=5e-4)
    i = rec.hf["CURRENT|SP1"].to_numpy()
    t = rec.hf["TORQUE|SP1"].to_numpy()
    slope = float(np.polyfit(i, t, 1)[0])
    assert slope == pytest.approx(1.369, abs=0.002)  # torque setpoint / actual Iq, not Kt


# ------------------------------------------------------------------ full simulated sweep (§3.2.2)
@pytest.fixture(scope="module")
def full_sweep():  # type: ignore[no-untyped-def]
    """Simulated air cut up to 18000 rpm like the thesis' (126 speeds, 3 s); here 45 speeds of
    2 s to keep the test short. Default spindle: B/Kt = 8.1e-5 A/rpm, tau_f/Kt = 0.34 A
    (thesis Eq. 4.2), base speed 7000 rpm, bearing roll-off (the thesis' current-limitation
    bend, Fig. 4.1) from 5000 rpm."""
    from cnctwin.sim import scenarios as sc

    res = sc.air_cut_sweep(seed=7, n_speeds=45, dwell_s=2.0)
    return res.recording, res.truth["machine"]["spindle"]


def test_linear_region_on_a_full_sweep_to_18000_rpm(full_sweep) -> None:  # type: ignore[no-untyped-def]
    """Issue #4 item 4 / issue point 3: the longest rising run used to win, which on a sweep to
    18000 rpm is the flat stretch above field weakening (11200-18000 rpm here)."""
    from cnctwin.spindle import field_weakening_onset_rpm

    rec, sp = full_sweep
    region = linear_region_from_recording(rec)
    stats = air_cut_statistics(rec, speed_plateaus(rec))
    fw = field_weakening_onset_rpm(stats)
    # field weakening read from the data (LF |I| leaves Iq, thesis Fig. 3.8c): just above the
    # base speed of 7000 rpm (first plateau past it on the 400 rpm grid)
    assert fw is not None and sp["base_speed_rpm"] <= fw <= sp["base_speed_rpm"] + 400.0
    # upper limit: below the bend where Iq leaves the line (roll-off from 5000 rpm), within
    # one plateau step (400 rpm) of it
    assert sp["viscous_rolloff_speed_rpm"] - 400.0 <= region.hi_rpm <= \
        sp["viscous_rolloff_speed_rpm"]
    assert "departs from the line" in region.reason_hi
    # lower limit: stator line dominant (Eq. 4.1) and above the Stribeck excess (400 rpm decay
    # speed, 0.15 Nm: still 3 % of the friction current at 1200 rpm)
    assert region.poles == sp["pole_count"]
    assert 2 * sp["stribeck_speed_rpm"] <= region.lo_rpm <= 1600.0
    # the thesis' straight line over the region: within 5 % of the truth (slope 2-4 % low,
    # offset 2-3 % high from the curvature left at both ends, docs/validation-spindle.md)
    fit = fit_friction(stats["speed_rpm"].abs(), stats["current_a"], region.lo_rpm,
                       region.hi_rpm)
    kt = sp["kt_nm_per_a"]
    assert fit.slope_a_per_rpm == pytest.approx(sp["viscous_friction_nm_per_rpm"] / kt, rel=0.05)
    assert fit.offset_a == pytest.approx(sp["coulomb_friction_nm"] / kt, rel=0.05)


def test_air_cut_statistics_fig_3_8_and_3_9_on_the_full_sweep(full_sweep) -> None:  # type: ignore[no-untyped-def]
    """Issue #4 item 3: per speed mean/min/max of the six Fig. 3.8 quantities and the
    correlation matrix of the means (Fig. 3.9) on the simulated sweep."""
    rec, _ = full_sweep
    stats = air_cut_statistics(rec)
    six = ("CURRENT|SP1", "TORQUE|SP1", "CURRENT_ABS_SMOOTHED|SP1 (LF)",
           "TORQUE_UTIL|SP1 (LF)", "POWER|SP1", "LOAD|SP1")  # Fig. 3.8 a-f
    for name in six:
        lo, mean, hi = (stats[f"{name} {s}"].to_numpy() for s in ("min", "mean", "max"))
        assert np.all(lo <= mean) and np.all(mean <= hi), name
    corr = air_cut_correlation(stats)
    assert {f"{n} mean" for n in six} <= set(corr.index)
    # HF current and LF Iq are the same q-axis current; LOAD is the torque in % of rated
    assert corr.loc["CURRENT|SP1 mean", "IQ_ACT|SP1 (LF) mean"] > 0.99
    assert corr.loc["TORQUE|SP1 mean", "LOAD|SP1 mean"] > 0.99
    # the smoothed absolute current leaves Iq above field weakening (Fig. 3.8c): their means
    # correlate far less than Iq with the HF current
    assert corr.loc["CURRENT_ABS_SMOOTHED|SP1 (LF) mean", "IQ_ACT|SP1 (LF) mean"] < 0.9


def test_cutting_torque_sign_in_reverse_rotation() -> None:
    # issue 16 (a surviving mutant): friction always opposes the rotation. Thesis Eq. 4.4
    # by hand with Kt 1.04 Nm/A, B 8.42e-5 Nm/rpm, tau_f 0.35 Nm:
    #   forward  n = +2400 rpm, I = +3.0 A: 3.12 - 0.20208 - 0.35 = +2.56792 Nm
    #   reverse  n = -2400 rpm, I = -3.0 A: -3.12 + 0.20208 + 0.35 = -2.56792 Nm
    # (tapping: the extraction turns the spindle the other way; the cut torque changes sign)
    m = SpindleModel(1.04, 8.42e-5, 0.35)
    tau = m.cutting_torque(np.array([3.0, -3.0]), np.array([2400.0, -2400.0]))
    np.testing.assert_allclose(tau, [2.56792, -2.56792], rtol=1e-12)
    # and the inverse: the current the twin predicts in reverse is negative by the same law
    np.testing.assert_allclose(m.predict_current_a(-2.56792, -2400.0), -3.0, rtol=1e-12)


def test_fit_friction_range_is_inclusive_and_errors_match_scipy() -> None:
    # issue 16 (surviving mutants): the upper bound of the speed range is inclusive, and the
    # standard errors of slope and offset are the ordinary least-squares ones. Independent
    # truth: scipy.stats.linregress (its stderr and intercept_stderr).
    from scipy.stats import linregress

    n = np.array([1000.0, 2000.0, 3000.0, 4000.0, 5000.0])
    i = 8.1e-5 * n + 0.34 + np.array([0.012, -0.007, -0.015, 0.004, 0.009])
    fit = fit_friction(n, i, lo_rpm=2000.0, hi_rpm=4000.0)
    assert fit.n_points == 3 and (fit.lo_rpm, fit.hi_rpm) == (2000.0, 4000.0)
    ref = linregress(n[1:4], i[1:4])
    assert fit.slope_a_per_rpm == pytest.approx(ref.slope, rel=1e-12)
    assert fit.offset_a == pytest.approx(ref.intercept, rel=1e-12)
    assert fit.slope_std == pytest.approx(ref.stderr, rel=1e-9)
    assert fit.offset_std == pytest.approx(ref.intercept_stderr, rel=1e-9)
    full = fit_friction(n, i)
    ref = linregress(n, i)
    assert full.offset_std == pytest.approx(ref.intercept_stderr, rel=1e-9)
    assert full.r2 == pytest.approx(ref.rvalue**2, rel=1e-12)


def test_streaming_against_the_hand_formula() -> None:
    """An independent truth for the streaming estimator (not the vectorized one): thesis Eq.
    4.4 by hand. A speed ramp 2000 -> 2500 rpm over 1 s at 500 Hz (dOmega/dt = 500 rpm/s =
    52.36 rad/s^2) with I = 4 A: tau = 1.04 x 4 - 8.42e-5 n - 0.35 - 0.01 x 52.36 Nm; at the
    ramp's middle (n = 2250 rpm) 4.16 - 0.18945 - 0.35 - 0.5236 = 3.0970 Nm."""
    model = SpindleModel(1.04, 8.42e-5, 0.35, j_kgm2=0.01)
    n = np.linspace(2000.0, 2500.0, 501)
    i = np.full(n.size, 4.0)
    est = StreamingTorqueEstimator(model, fs_hz=500.0)
    out = np.concatenate([est.update(i[k:k + 7], n[k:k + 7]) for k in range(0, n.size, 7)]
                         + [est.flush()])
    dw = 500.0 * 2.0 * np.pi / 60.0  # rad/s^2
    hand = 1.04 * 4.0 - 8.42e-5 * n - 0.35 - 0.01 * dw
    np.testing.assert_allclose(out[1:-1], hand[1:-1], rtol=0, atol=1e-9)  # inner samples
    assert out[250] == pytest.approx(4.16 - 8.42e-5 * 2250.0 - 0.35 - 0.01 * dw, abs=1e-9)
    assert out[250] == pytest.approx(3.0970, abs=1e-4)


def test_stribeck_term_of_the_calibrated_friction() -> None:
    """The low-speed friction the improved calibration identifies (``tau_s exp(-|n|/n_s)``,
    the simulator's law, docs/simulator.md): the air current it predicts gives zero cutting
    torque at every speed and direction, batch and streaming alike; at 300 rpm the term is
    0.23 exp(-300/500) = 0.126 Nm, which the model without it showed as a cut (the soak's
    air torque over its bound at 300-500 rpm, BENCHMARKS.md "Soak")."""
    m = SpindleModel(0.99, 7.6e-5, 0.38, j_kgm2=0.02, stribeck_torque_nm=0.23,
                     stribeck_speed_rpm=500.0)
    n = np.array([-2400.0, -300.0, 0.0, 300.0, 600.0, 2400.0])
    np.testing.assert_allclose(m.stribeck_nm(n), 0.23 * np.exp(-np.abs(n) / 500.0) * np.sign(n))
    assert float(m.stribeck_nm(300.0)) == pytest.approx(0.1262, abs=1e-4)
    i = m.predict_current_a(0.0, n)
    np.testing.assert_allclose(m.cutting_torque(i, n, accel_term=False), 0.0, atol=1e-12)
    plain = SpindleModel(0.99, 7.6e-5, 0.38)
    assert float(plain.cutting_torque(i[3], 300.0)) == pytest.approx(0.1262, abs=1e-4)
    np.testing.assert_allclose(m.friction_torque_nm(n) - plain.friction_torque_nm(n),
                               m.stribeck_nm(n))
    ramp = np.linspace(200.0, 800.0, 501)
    cur = m.predict_current_a(1.0, ramp)
    est = StreamingTorqueEstimator(m)
    out = np.concatenate([est.update(cur[k:k + 37], ramp[k:k + 37]) for k in range(0, 501, 37)]
                         + [est.flush()])
    np.testing.assert_array_equal(out, m.cutting_torque(cur, ramp))
    assert "Stribeck 0.23 Nm" in m.describe()
    with pytest.raises(ConfigError):
        SpindleModel(1.0, 8e-5, 0.3, stribeck_torque_nm=-0.1)
    with pytest.raises(ConfigError):
        SpindleModel(1.0, 8e-5, 0.3, stribeck_torque_nm=0.1, stribeck_speed_rpm=0.0)
