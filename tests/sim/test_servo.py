"""Tests of the feed-axis servo kernel (:mod:`cnctwin.sim.servo`).

Expected values come from the position-loop laws in docs/reference/physics-and-performance.md §1.2
(Kv definition MD32200, e = v / Kv without feedforward, jerk filter MD32402/MD32410) and from
statics (motor current = force x lead / (2 pi Kt)).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from numpy.typing import NDArray

from cnctwin.exceptions import ConfigError
from cnctwin.machine import FeedAxis, Machine
from cnctwin.sim.servo import N_KERNEL_OUTPUTS, ServoState, simulate_servo

TC = 0.002
FEED_MM_MIN = 400.0  # thesis feed (docs/reference/physics-and-performance.md §1.2, §3)
V_MM_S = FEED_MM_MIN / 60.0


def _ramp(n: int, *, accel_time_s: float = 0.1, start_s: float = 0.1) -> NDArray[np.float64]:
    """Position setpoint: rest, constant-acceleration start, then 400 mm/min [mm]."""
    t = np.clip(np.arange(n) * TC - start_s, 0.0, None)
    a = V_MM_S / accel_time_s
    return np.where(t < accel_time_s, 0.5 * a * t**2, 0.5 * a * accel_time_s**2
                    + V_MM_S * (t - accel_time_s))


def _x_axis(**changes: object) -> FeedAxis:
    return dataclasses.replace(Machine.thesis_default().axis("X1"), **changes)  # type: ignore[arg-type]


def test_following_error_without_ffw_is_v_over_kv() -> None:
    # docs/reference/physics-and-performance.md §1.2: e = v / Kv; 400 mm/min at Kv 2.5 (m/min)/mm
    # -> 0.160 mm
    ax = _x_axis(ffw_mode=0, jerk_filter_type=0)
    tr = simulate_servo(_ramp(2000)[None, :], [ax])
    fe = tr.axis("DES_POS", "X1") - tr.axis("ENC_POS", "X1")
    assert fe[-300:].mean() == pytest.approx(0.160, rel=0.02)
    # CMD_SPEED (mm/s, catalog unit) carries the whole feed: no feedforward
    assert tr.axis("CMD_SPEED", "X1")[-300:].mean() == pytest.approx(V_MM_S, rel=0.01)
    assert np.all(tr.axis("VEL_FFW", "X1") == 0.0)


@pytest.mark.parametrize("kv", [1.0, 2.5, 4.0])
def test_following_error_scales_with_kv(kv: float) -> None:
    # Kv definition (MD32200): Kv = 1 -> 1 mm following error at 1 m/min
    ax = _x_axis(ffw_mode=0, jerk_filter_type=0, kv_m_min_per_mm=kv)
    tr = simulate_servo(_ramp(3000)[None, :], [ax])
    fe = tr.axis("DES_POS", "X1") - tr.axis("ENC_POS", "X1")
    assert fe[-300:].mean() == pytest.approx(0.4 / kv, rel=0.02)


@pytest.mark.parametrize("mode", [1, 3])
def test_speed_ffw_removes_steady_controller_difference(mode: int) -> None:
    # §1.2 derived: with speed FFW the residual lag is ~ v x (MD32810 mismatch): a few um
    ax = _x_axis(ffw_mode=mode)
    tr = simulate_servo(_ramp(2000)[None, :], [ax])
    diff2 = tr.axis("CTRL_DIFF2", "X1")
    assert np.abs(diff2[-300:]).max() < 0.010
    assert np.abs(diff2[-300:].mean()) < 0.002
    assert tr.axis("VEL_FFW", "X1")[-1] == pytest.approx(V_MM_S, rel=1e-6)
    # DES_POS - ENC_POS = v x (jerk MA delay (m-1) Tc / 2 + balancing time MD32810)
    m = round(ax.jerk_time_s / TC)
    lag_s = (m - 1) * TC / 2 + ax.equiv_speedctrl_time_s
    fe = tr.axis("DES_POS", "X1") - tr.axis("ENC_POS", "X1")
    assert fe[-300:].mean() == pytest.approx(V_MM_S * lag_s, rel=0.02)


def test_ctrl_diff2_is_ctrl_pos_minus_enc_pos_exactly() -> None:
    # Catalog / thesis §3.1.2: CTRL_DIFF2 = CTRL_POS - ENC_POS
    tr = simulate_servo(_ramp(1500)[None, :], [_x_axis()], rng=np.random.default_rng(1))
    np.testing.assert_array_equal(
        tr.axis("CTRL_DIFF2", "X1"), tr.axis("CTRL_POS", "X1") - tr.axis("ENC_POS", "X1")
    )


def test_ctrl_diff_equals_ctrl_diff2_without_dsc() -> None:
    tr = simulate_servo(_ramp(800)[None, :], [_x_axis(dsc=False)])
    np.testing.assert_array_equal(tr.axis("CTRL_DIFF", "X1"), tr.axis("CTRL_DIFF2", "X1"))


@pytest.mark.parametrize("jerk_time_s", [0.008, 0.016, 0.032])
def test_moving_average_jerk_filter_delay_is_half_its_time(jerk_time_s: float) -> None:
    # B2 / 808D manual: type 2 = moving average over MD32410 / cycle samples; a moving average
    # over m samples delays a ramp by (m-1) Tc / 2 = T/2 - Tc/2 (within one cycle of T/2)
    ax = _x_axis(ffw_mode=0, jerk_filter_type=2, jerk_time_s=jerk_time_s)
    tr = simulate_servo(_ramp(1000)[None, :], [ax])
    lag_s = (tr.axis("DES_POS", "X1")[-100:] - tr.axis("CTRL_POS", "X1")[-100:]).mean() / V_MM_S
    assert lag_s == pytest.approx(jerk_time_s / 2 - TC / 2, abs=1e-6)
    assert abs(lag_s - jerk_time_s / 2) <= TC


def test_jerk_filter_off_when_time_not_above_one_cycle() -> None:
    # B2 p.377: active only if the time constant exceeds one position-control cycle
    ax = _x_axis(ffw_mode=0, jerk_filter_type=2, jerk_time_s=TC)
    tr = simulate_servo(_ramp(400)[None, :], [ax])
    np.testing.assert_array_equal(tr.axis("CTRL_POS", "X1"), tr.axis("DES_POS", "X1"))


def test_pt2_and_double_average_jerk_filters_delay() -> None:
    x = _ramp(1200)[None, :]
    t1 = simulate_servo(x, [_x_axis(ffw_mode=0, jerk_filter_type=1, jerk_time_s=0.03)])
    lag1 = (t1.axis("DES_POS", "X1") - t1.axis("CTRL_POS", "X1"))[-50:].mean() / V_MM_S
    assert lag1 == pytest.approx(0.03, rel=0.01)  # two PT1 stages of T/2: ramp lag T
    t4 = simulate_servo(x, [_x_axis(ffw_mode=0, jerk_filter_type=4, jerk_time_s=0.008)])
    lag4 = (t4.axis("DES_POS", "X1") - t4.axis("CTRL_POS", "X1"))[-50:].mean() / V_MM_S
    assert lag4 == pytest.approx(2 * 1.5 * TC, rel=1e-6)  # two 4-sample averages


def _circle(radius_mm: float = 10.0) -> NDArray[np.float64]:
    n = int(2 * np.pi * radius_mm / V_MM_S / TC) + 500
    t = np.arange(n) * TC
    phi = np.minimum(np.clip(t - 0.5, 0.0, None) * V_MM_S / radius_mm, 2 * np.pi)
    return np.vstack([radius_mm * np.cos(phi), radius_mm * np.sin(phi)])


def _square(side_mm: float = 5.0) -> NDArray[np.float64]:
    seg = int(side_mm / V_MM_S / TC)
    s = np.linspace(0.0, side_mm, seg, endpoint=False)
    z = np.zeros(seg)
    rest = np.zeros(200)
    x = np.concatenate([rest, s, z + side_mm, side_mm - s, z, rest])
    y = np.concatenate([rest, z, s, z + side_mm, side_mm - s, rest])
    return np.vstack([x, y])


@pytest.mark.parametrize("path", ["square", "circle"])
@pytest.mark.parametrize("mode", [0, 3])
def test_contour_deviation_small_while_following_error_grows(path: str, mode: int) -> None:
    # thesis §3.1.2, Figs 3.2/3.3: following error and controller difference follow the
    # corners/circle, contour deviation stays near 0
    des = _square() if path == "square" else _circle()
    m = Machine.thesis_default()
    axes = [dataclasses.replace(m.axis(n), ffw_mode=mode) for n in ("X1", "Y1")]
    tr = simulate_servo(des, axes, rng=np.random.default_rng(0))
    fe = tr.signals["DES_POS"] - tr.signals["ENC_POS"]
    cd = tr.signals["CONT_DEV"]
    fe_rms = np.sqrt((fe**2).mean(axis=1))
    cd_rms = np.sqrt((cd**2).mean(axis=1))
    assert np.all(cd_rms < 0.1 * fe_rms)
    assert np.all(np.abs(fe).max(axis=1) > 0.8 * V_MM_S * m.axis("X1").position_equivalent_time_s)


def test_quadrant_glitch_at_reversal() -> None:
    # A3 (docs/reference/physics-and-performance.md §1.2): friction at axis reversal -> quadrant
    # errors
    des = _circle()
    m = Machine.thesis_default()
    tr = simulate_servo(des, [m.axis("X1"), m.axis("Y1")])
    cd_x = tr.axis("CONT_DEV", "X1")
    k_rev = int((0.5 + np.pi * 10.0 / V_MM_S) / TC)  # X reverses at phi = pi
    near = np.abs(cd_x[k_rev - 50 : k_rev + 100]).max()
    assert near > 0.001  # a glitch of a few um
    assert near > 20 * np.median(np.abs(cd_x))


def test_force_step_current_from_statics() -> None:
    # statics: Iq = F x lead / (2 pi Kt); 2 kN thrust, 10 mm lead, 1.4 Nm/A -> 2.27 A
    z = Machine.thesis_default().axis("Z1")
    n = 2000
    f = np.zeros((1, n))
    f[0, 1000:] = 2000.0
    tr = simulate_servo(np.zeros((1, n)), [z], force_n=f)
    expected = -2000.0 * z.screw_pitch_mm / 1000 / (2 * np.pi) / z.kt_nm_per_a
    assert tr.axis("CURRENT", "Z1")[-200:].mean() == pytest.approx(expected, rel=1e-3)
    assert tr.axis("TORQUE", "Z1")[-200:].mean() == pytest.approx(-2000.0, rel=1e-3)  # N
    cd = tr.axis("CONT_DEV", "Z1")
    assert np.abs(cd[1000:1100]).max() > 0.001  # the step shows up in CONT_DEV ...
    assert abs(cd[-1]) < 1e-4  # ... and the PI speed loop removes it


def test_chunked_equals_one_shot() -> None:
    m = Machine.thesis_default()
    des = _circle()
    axes = [m.axis("X1"), m.axis("Y1")]
    force = np.full_like(des, 50.0)
    one = simulate_servo(des, axes, force_n=force, rng=np.random.default_rng(7))
    rng = np.random.default_rng(7)
    state: ServoState | None = None
    parts = []
    for lo, hi in [(0, 1), (1, 777), (777, 2000), (2000, des.shape[1])]:
        tr = simulate_servo(des[:, lo:hi], axes, force_n=force[:, lo:hi], state=state, rng=rng)
        state = tr.state
        parts.append(tr)
    for code, arr in one.signals.items():
        np.testing.assert_array_equal(np.concatenate([p.signals[code] for p in parts], axis=1),
                                      arr, err_msg=code)


def test_velocity_units_per_second() -> None:
    # catalog and real C4A file (docs/real-data-servo.md §1.1): VEL_FFW/CMD_SPEED in deg/s on
    # rotary axes and mm/s on linear axes; LF SPEED_SMOOTHED (r0063) in rpm: 60 deg/s = 10 rpm
    m = Machine.thesis_default()
    c = m.axis("C1")
    n = 1500
    des = np.clip(np.arange(n) * TC - 0.2, 0, None) * 60.0  # 60 deg/s
    tr = simulate_servo(des[None, :], [dataclasses.replace(c, jerk_filter_type=0)])
    assert tr.axis("VEL_FFW", "C1")[-1] == pytest.approx(60.0, rel=1e-6)
    assert tr.axis("CMD_SPEED", "C1")[-1] == pytest.approx(60.0, rel=1e-3)
    assert tr.axis("SPEED_SMOOTHED", "C1")[-1] == pytest.approx(10.0, rel=1e-3)
    x = m.axis("X1")
    des_x = np.clip(np.arange(n) * TC - 0.2, 0, None) * 400.0 / 60.0  # 400 mm/min
    tx = simulate_servo(des_x[None, :], [dataclasses.replace(x, jerk_filter_type=0)])
    assert tx.axis("VEL_FFW", "X1")[-1] == pytest.approx(400.0 / 60.0, rel=1e-6)  # mm/s
    assert tx.axis("SPEED_SMOOTHED", "X1")[-1] == pytest.approx(400.0, rel=1e-3)  # mm/min


def test_shape_errors() -> None:
    with pytest.raises(ConfigError, match="rows"):
        simulate_servo(np.zeros((2, 10)), [_x_axis()])
    with pytest.raises(ConfigError, match="force_n"):
        simulate_servo(np.zeros((1, 10)), [_x_axis()], force_n=np.zeros((1, 5)))


def test_output_buffer_gives_the_same_trace_as_views() -> None:
    # simulate() reuses one output buffer between chunks (servo.py simulate_servo ``out``)
    m = Machine.thesis_default()
    des = _circle()
    axes = [m.axis("X1"), m.axis("Y1")]
    fresh = simulate_servo(des, axes, rng=np.random.default_rng(3))
    buf = np.full((2, N_KERNEL_OUTPUTS, des.shape[1]), np.nan)
    into = simulate_servo(des, axes, rng=np.random.default_rng(3), out=buf)
    for code, arr in fresh.signals.items():
        np.testing.assert_array_equal(into.signals[code], arr, err_msg=code)
        if code != "DES_POS":
            assert np.shares_memory(into.signals[code], buf)
    with pytest.raises(ConfigError, match="out must be"):
        simulate_servo(des, axes, out=np.empty((2, N_KERNEL_OUTPUTS, 10)))
