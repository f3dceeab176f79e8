"""Hole quality (thesis chapter 5.3, Figures 5.6-5.9) on constructed and simulated recordings."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from cnctwin.exceptions import ConfigError, SignalNotFoundError
from cnctwin.recording import Recording
from cnctwin.sim.scenarios import tool_wear_run
from cnctwin.usecases.figures import (
    plot_anomaly_scores,
    plot_deviation_paths,
    plot_hole_means,
    plot_set_temperature,
)
from cnctwin.usecases.holes import hole_record
from cnctwin.usecases.quality import deviation_paths, hole_quality


def _three_holes() -> Recording:
    """Three 10 mm holes at X=5, Y=7 (500 Hz, feed 5 mm/s); hole 1 offset, hole 2 bent."""
    fs = 500.0
    one = np.concatenate([np.full(100, 2.0), np.linspace(2.0, -10.0, 1200),
                          np.full(50, -10.0), np.linspace(-10.0, 2.0, 60), np.full(100, 2.0)])
    z = np.tile(one, 3)
    n = z.size
    seg = one.size
    x_des = np.full(n, 5.0)
    y_des = np.full(n, 7.0)
    ex = np.zeros(n)
    ey = np.zeros(n)
    ex[seg : 2 * seg] = 0.02  # hole 1: 20 µm off in X
    # hole 2: 15 µm sideways bump in Y at half depth (cut = samples 100..1300 of the hole)
    k = np.arange(seg)
    ey[2 * seg : 3 * seg] = 0.015 * np.exp(-(((k - 700) / 60.0) ** 2))
    cur = np.where(np.gradient(z) < 0, 2.0, 1.0)
    rec = Recording.from_arrays(
        np.arange(n),
        {"DES_POS|Z1": z, "ENC_POS|Z1": z, "DES_POS|X1": x_des, "ENC_POS|X1": x_des + ex,
         "DES_POS|Y1": y_des, "ENC_POS|Y1": y_des + ey, "CURRENT|SP1": cur,
         "CMD_SPEED|SP1": np.full(n, 1000.0)},
        cycle_time_s=1 / fs,
    )
    return rec


def test_position_error_and_straightness() -> None:
    rec = _three_holes()
    holes = hole_record(rec)
    assert len(holes) == 3
    q = hole_quality(rec, holes, tolerance_mm=0.01)
    np.testing.assert_allclose(q["position_error_mm"].iloc[:2], [0.0, 0.02], atol=1e-9)
    # a Gaussian bump of 15 µm: straightness = 15 µm minus its mean over the cut
    # (mean = 15 µm * 60 * sqrt(pi) / 1200 samples = 1.33 µm)
    mean_bump = 0.015 * 60 * math.sqrt(math.pi) / 1200
    assert q["straightness_mm"].iloc[2] == pytest.approx(0.015 - mean_bump, rel=0.02)
    assert q["straightness_mm"].iloc[1] == pytest.approx(0.0, abs=1e-9)
    assert list(q["position_oot"]) == [False, True, False]
    assert list(q["straightness_oot"]) == [False, False, True]
    assert list(q["out_of_tolerance"]) == [False, True, True]
    # depth: the fallback surface is the feed start (Z = 2), so 12 mm below it
    q2 = hole_quality(rec, holes, nominal_depth_mm=12.0, depth_tolerance_mm=0.05)
    np.testing.assert_allclose(q2["depth_error_mm"], 0.0, atol=0.02)
    assert not q2["depth_oot"].any()


def test_paths_are_normalized_to_the_hole_top() -> None:
    rec = _three_holes()
    holes = hole_record(rec)
    p = deviation_paths(rec, holes)
    assert set(p["hole"]) == {0, 1, 2}
    first = p.groupby("hole").first()
    np.testing.assert_allclose(first[["des_x_mm", "des_y_mm", "des_z_mm"]], 0.0, atol=0.01)
    np.testing.assert_allclose(first["enc_x_mm"], [0.0, 0.02, 0.0], atol=1e-9)
    assert p.groupby("hole")["des_z_mm"].min().round(3).tolist() == [-12.0] * 3
    for view in ("3d", "xz", "yz", "xy"):
        fig = plot_deviation_paths(p, view=view)
        assert len(fig.axes) == 3
    with pytest.raises(ConfigError, match="view"):
        plot_deviation_paths(p, view="zz")


def test_errors() -> None:
    rec = _three_holes()
    holes = hole_record(rec)
    with pytest.raises(ConfigError, match="tolerance"):
        hole_quality(rec, holes, tolerance_mm=0.0)
    bare = rec.select(signals=["DES_POS", "CURRENT", "CMD_SPEED"])
    with pytest.raises(SignalNotFoundError, match="ENC_POS"):
        deviation_paths(bare, holes)


def test_simulated_holes_in_tolerance() -> None:
    res = tool_wear_run(n_holes=6, seed=4)
    rec = res.recording
    holes = hole_record(rec)
    q = hole_quality(rec, holes, tolerance_mm=0.01)
    # the lateral drilling force is taken by the stiff X/Y position loops: sub-micrometre
    # offsets, far inside a 10 µm tolerance, so no hole is flagged
    assert not q["out_of_tolerance"].any()
    assert (q["position_error_mm"] < 0.001).all()
    assert (q["straightness_mm"] < 0.001).all()
    # figures of the use-cases render
    holes["camera_temperature_c"] = np.linspace(100, 300, 6)
    assert len(plot_set_temperature(rec, holes, predicted_c=np.linspace(90, 310, 6)).axes) == 2
    assert len(plot_hole_means(holes, wear_um=np.arange(6.0)).axes) == 3
    assert len(plot_anomaly_scores([0, 1, 2], [0, 1, -1], alarms_s=[1.0],
                                   fault_onsets_s=[0.9], learn_until_s=0.5).axes) == 1


# ----------------------------------------------------------------------------- dynamic indicators
def test_axis_stiffness_model_matches_the_servo_kernel() -> None:
    # the linear disturbance model of feed_axis_dynamic_stiffness against the numba servo
    # (125 us loops, quantised 10 nm encoder, regularised friction) under a 40 Hz force of
    # 60 N with hidden random loop gains, slide mass and friction; 5 % tolerance
    import dataclasses

    from cnctwin.sim.machine import Machine
    from cnctwin.sim.servo import simulate_servo
    from cnctwin.usecases.quality import feed_axis_dynamic_stiffness

    rng = np.random.default_rng(17)
    for _ in range(3):
        ax = dataclasses.replace(
            Machine.thesis_default().axis("X1"),
            speed_kp_nm_s_per_rad=float(rng.uniform(1.0, 2.2)),
            speed_ti_s=float(rng.uniform(0.005, 0.012)),
            mass_kg=float(rng.uniform(200.0, 600.0)),
            coulomb_n=float(rng.uniform(80.0, 220.0)),
            kv_m_min_per_mm=float(rng.uniform(1.5, 4.0)))
        f_hz = float(rng.uniform(25.0, 60.0))
        n = 3000
        t = np.arange(n) * 0.002
        force = 60.0 * np.sin(2 * np.pi * f_hz * t)
        tr = simulate_servo(np.zeros((1, n)), [ax], force_n=force[None, :])
        d = tr.axis("ENC_POS", "X1")[1000:] * 1000.0  # um, after the start transient
        tt = t[1000:]
        a = np.column_stack([np.ones_like(tt), np.cos(2 * np.pi * f_hz * tt),
                             np.sin(2 * np.pi * f_hz * tt)])
        c, *_ = np.linalg.lstsq(a, d, rcond=None)
        measured = 60.0 / math.hypot(c[1], c[2])
        model = float(feed_axis_dynamic_stiffness(ax, f_hz).stiffness_n_per_um[0])
        assert measured == pytest.approx(model, rel=0.05)


@pytest.mark.parametrize("seed", [1, 3])
def test_hole_quality_recovers_hidden_walk_and_runout(seed: int) -> None:
    # hidden: lip-height difference, wear asymmetry, entry (chisel-edge) force ratio, worn walk
    # ratio, walk direction, X/Y loop gains and friction (random_loop_overrides); wear
    # accelerated (22 um/hole) so 12 holes go from new to ~240 um. The analysis gets the
    # recording, the machine and the drill description, not the drilling model.
    from cnctwin.sim.scenarios import ScenarioConfig, random_loop_overrides

    rng = np.random.default_rng(seed)
    ov = {"wear.rate_um_per_hole": 22.0, "wear.run_in_um": 0.0,
          "drilling.lip_height_difference_um": float(rng.uniform(4, 16)),
          "drilling.wear_asymmetry": float(rng.uniform(0.1, 0.3)),
          "drilling.entry_force_ratio": float(rng.uniform(0.02, 0.05)),
          "drilling.walk_force_ratio_worn": float(rng.uniform(0.03, 0.08)),
          **random_loop_overrides(seed)}
    res = tool_wear_run(n_holes=12, seed=seed, overrides=ov, dynamometer=False,
                        walk_direction_rad=float(rng.uniform(-math.pi, math.pi)))
    cfg = ScenarioConfig.build(ov)
    rec = res.recording
    q = hole_quality(rec, hole_record(rec), machine=cfg.machine, drill=cfg.drill)
    t = pd.DataFrame(res.truth["holes"])
    assert len(q) == len(t) == 12

    def rel(est: str, true: str) -> np.ndarray:
        return np.abs(q[est].to_numpy() / t[true].to_numpy() - 1.0)

    # rotating (1x spindle) force from the lock-in amplitude x axis stiffness: <= 1 % without
    # measuring noise; with the encoders' noise (issue 29, 0.15 um) each hole's estimate
    # scatters by its stated standard error (3-8 % here): within 2 % + 3 of those
    err = np.abs(q["rotating_force_est_n"].to_numpy() - t["rotating_force_n"].to_numpy())
    allowed = 0.02 * t["rotating_force_n"].to_numpy() + 3.0 * q["rotating_force_se_n"].to_numpy()
    assert np.all(err <= allowed), (err, allowed)
    # chisel-edge entry force and its direction from the entry-window response fit: <= 5 %
    # and <= 0.04 rad without measuring noise; with it (issue 29) each hole scatters by its
    # stated standard error (6-20 % here): within 5 % + 3 standard errors, the direction
    # within 0.04 rad + 3 se / F
    f_true = t["entry_force_peak_n"].to_numpy()
    se = q["entry_force_se_n"].to_numpy()
    assert np.all(np.abs(q["entry_force_est_n"].to_numpy() - f_true) <= 0.05 * f_true + 3 * se)
    dang = np.angle(np.exp(1j * (q["entry_force_direction_rad"] - t["entry_direction_rad"])))
    assert np.all(np.abs(dang) <= 0.04 + 3.0 * se / q["entry_force_est_n"].to_numpy())
    # tool-tip hole position error (F_entry / k_tip) per hole, the same way
    tip = t["tip_position_error_um"].to_numpy()
    assert np.all(np.abs(q["tip_position_error_est_um"].to_numpy() - tip)
                  <= 0.05 * tip + 3.0 * q["tip_position_error_se_um"].to_numpy())
    # static walk: weakest (a ramp that the speed-loop integral mostly absorbs): the sum over
    # the run within 30 %
    assert q["walk_force_est_n"].sum() / t["walk_force_n"].sum() == pytest.approx(1.0, abs=0.3)
    # growth with wear: the slide run-out (um) tracks the wear (0.99 without measuring noise;
    # the 3-8 % scatter of each hole's run-out takes ~0.02 off) and the true force ratio within
    # 3 standard errors of the ratio (+ 2 %)
    assert np.corrcoef(q["runout_um"], t["wear_um"])[0, 1] > 0.97
    a0, a1 = q["runout_um"].iloc[0], q["runout_um"].iloc[-1]
    s0, s1 = q["runout_se_um"].iloc[0], q["runout_se_um"].iloc[-1]
    true_growth = t["rotating_force_n"].iloc[-1] / t["rotating_force_n"].iloc[0]
    assert abs(a1 / a0 / true_growth - 1.0) <= 0.02 + 3.0 * math.hypot(s0 / a0, s1 / a1)
    # sub-micrometre, above the 10 nm encoder resolution
    assert q["runout_um"].min() > 0.02 and q["runout_um"].max() < 1.0
    # flags: a tolerance between the smallest and largest tip error splits the holes
    tol = float(t["tip_position_error_um"].median()) / 1000.0
    q2 = hole_quality(rec, hole_record(rec), machine=cfg.machine, drill=cfg.drill,
                      tip_tolerance_mm=tol)
    truth_flags = t["tip_position_error_um"].to_numpy() > 1000.0 * tol
    assert (q2["tip_position_oot"].to_numpy() == truth_flags).mean() >= 0.9
    from cnctwin.usecases.figures import plot_hole_quality

    assert len(plot_hole_quality(q2, truth=t).axes) == 3
