"""Signal relations on synthetic recordings with known structure (reference loop stand-in)."""

from __future__ import annotations

import numpy as np
import pytest

from cnctwin.recording import Recording
from cnctwin.servo import check_relations
from cnctwin.servo._common import jerk_filter_average, quantum

from ._refloop import RefLoop, run, standard_des


def test_relations_hold_on_reference_loop() -> None:
    rec = run(RefLoop(kv_1_s=40.0, ffw_weight=0.9), standard_des())
    rep = check_relations(rec, "X1")
    assert rep["ctrl_diff2"].checkable
    assert rep["ctrl_diff2"].fraction_within == 1.0
    assert rep["speed_command"].details["c"] == pytest.approx(1.0, abs=1e-9)
    assert rep["speed_command"].details["a"] == pytest.approx(40.0 * 60.0, rel=1e-9)  # mm/min
    ffw = rep["vel_ffw"]
    assert ffw.details["detected_unit"] == "mm/min"
    assert ffw.details["weight"] == pytest.approx(0.9, abs=0.01)
    # CONT_DEV / following error not recorded -> reported with reason, not invented
    assert not rep["contour_deviation"].checkable
    assert "CONT_DEV|X1" in rep["contour_deviation"].reason
    assert not rep["following_error"].checkable
    assert rep["following_error"].details["computed_rms"] > 0


def test_ctrl_diff2_misalignment_is_seen() -> None:
    rec = run(RefLoop(), standard_des())
    shifted = rec.hf["CTRL_DIFF2|X1"].to_numpy().copy()
    rec.hf["CTRL_DIFF2|X1"] = np.roll(shifted, 1)
    r = check_relations(rec, "X1")["ctrl_diff2"]
    assert r.details["best_lag_cycles"] == 1
    assert r.fraction_within < 0.9
    assert "time misalignment" in r.meaning


def test_contour_deviation_model_fitted() -> None:
    # CONT_DEV built as ENC_model - ENC with a delay-2 PT1-5 model of DES (cycles)
    rec = run(RefLoop(), standard_des())
    des = rec.hf["DES_POS|X1"].to_numpy()
    enc = rec.hf["ENC_POS|X1"].to_numpy()
    from cnctwin.servo._common import delay, pt1

    model = pt1(delay(des, 2.0), 5.0)
    rec.hf["CONT_DEV|X1"] = model - enc
    r = check_relations(rec, "X1")["contour_deviation"]
    assert r.details["model_delay_s"] == pytest.approx(0.004, abs=2e-4)
    assert r.details["model_pt1_s"] == pytest.approx(0.010, abs=2e-4)
    assert r.rms < 1e-6


def test_quantum_and_moving_average() -> None:
    x = np.round(np.sin(np.linspace(0, 6, 5000)) * 1e4) / 1e4
    assert quantum(x) == pytest.approx(1e-4, rel=1e-6)
    assert quantum(np.random.default_rng(0).normal(size=1000)) == 0.0
    # integer window = mean of the last W samples; fractional: weight f on sample k-m
    ramp = np.arange(100.0)
    expected = (sum(range(45, 51)) + 0.5 * 44) / 6.5
    assert jerk_filter_average(ramp, 6.5)[50] == pytest.approx(expected)
    assert jerk_filter_average(ramp, 4.0)[50] == pytest.approx(np.mean(ramp[47:51]))


def test_missing_axis_signals() -> None:
    rec = Recording.from_arrays(np.arange(50), {"DES_POS|Y1": np.zeros(50)})
    rep = check_relations(rec, "Y1")
    assert all(not r.checkable for r in rep.relations.values())
    assert "ENC_POS|Y1" in rep["ctrl_diff2"].reason


def test_constant_velocity_runs_by_construction() -> None:
    """Known runs: a 100-cycle hold at 30, a 39-cycle hold (too short), a step within 2 %
    (same run) and NaN breaking a run; the compiled kernel returns them with the first
    quarter dropped (``cnctwin.servo.identify.constant_velocity_runs``)."""
    import numpy as np

    from cnctwin.servo.identify import constant_velocity_runs

    v = np.r_[np.zeros(10), np.full(100, 30.0), np.zeros(5), np.full(39, -20.0), np.zeros(5),
              np.full(60, 50.0), np.full(60, 50.9), np.full(3, np.nan), np.full(80, -40.0)]
    runs = constant_velocity_runs(v, [slice(0, v.size)])
    assert runs == [slice(10 + 25, 110), slice(159 + 30, 279), slice(282 + 20, 362)]
    # a second segment is searched on its own and offset by its start
    runs2 = constant_velocity_runs(v, [slice(0, 100), slice(159, v.size)])
    assert runs2 == [slice(10 + 22, 100), slice(159 + 30, 279), slice(282 + 20, 362)]
