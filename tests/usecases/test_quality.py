"""Hole quality (thesis chapter 5.3, Figures 5.6-5.9) on constructed and simulated recordings."""

from __future__ import annotations

import math

import numpy as np
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
