"""Physical behaviour of the spindle drive model (thesis ch. 3.2 and 4)."""

from __future__ import annotations

import numpy as np
import pytest

from cnctwin.exceptions import ConfigError
from cnctwin.sim.spindle import SpindleMotor, SpindleTrace, simulate_spindle

MOTOR = SpindleMotor()


def _steady_mean_currents(speeds: np.ndarray, seconds: float = 2.0) -> dict[str, np.ndarray]:
    """Air cut at each speed (one continuous run, short enough to stay cold)."""
    state = None
    n = int(seconds / 0.002)
    iq, iabs, idd = [], [], []
    rng = np.random.default_rng(0)
    for s in speeds:
        tr = simulate_spindle(np.full(n, s), 0.0, MOTOR, state=state, rng=rng)
        state = tr.state
        sl = slice(n // 2, None)
        iq.append(tr.current_a[sl].mean())
        iabs.append(tr.current_abs_a[sl].mean())
        idd.append(tr.id_a[sl].mean())
    return {"iq": np.array(iq), "iabs": np.array(iabs), "id": np.array(idd)}


@pytest.fixture(scope="module")
def sweep() -> tuple[np.ndarray, dict[str, np.ndarray]]:
    speeds = np.array([200, 500, 1100, 1500, 2000, 2500, 3000, 3500, 4000, 4500, 5000,
                       6000, 7000, 8000, 9000, 12000, 16000], dtype=float)
    return speeds, _steady_mean_currents(speeds)


def test_iq_linear_between_1100_and_5000_rpm(sweep: tuple) -> None:
    # thesis §4.3 / Fig. 4.2: linear speed-current region 1100-5000 rpm, slope B/Kt = 8.1e-5
    # A/rpm and intercept tau_f/Kt = 0.34 A (Eq. 4.2)
    speeds, cur = sweep
    sel = (speeds >= 1100) & (speeds <= 5000)
    slope, icpt = np.polyfit(speeds[sel], cur["iq"][sel], 1)
    fit = slope * speeds[sel] + icpt
    ss_res = np.sum((cur["iq"][sel] - fit) ** 2)
    ss_tot = np.sum((cur["iq"][sel] - cur["iq"][sel].mean()) ** 2)
    assert 1 - ss_res / ss_tot > 0.99
    assert slope == pytest.approx(8.1e-5, rel=0.10)
    assert icpt == pytest.approx(0.34, abs=0.03)
    # departs from the line at low speed (Stribeck, thesis §4.1) ...
    line = np.polyval([slope, icpt], speeds)
    assert cur["iq"][speeds == 200][0] - line[speeds == 200][0] > 0.03
    # ... and above ~5000 rpm (current limitation / field weakening, Fig. 4.1, 3.8a)
    for s in (7000, 9000, 12000):
        assert line[speeds == s][0] - cur["iq"][speeds == s][0] > 0.05


def test_field_weakening_id_and_abs_current(sweep: tuple) -> None:
    # thesis Fig. 3.8c: |I| rises dramatically after the 7000 rpm field-weakening speed
    speeds, cur = sweep
    assert np.all(np.abs(cur["id"][speeds <= 6000]) < 0.05)
    assert cur["id"][speeds == 8000][0] < -1.0
    assert cur["iabs"][speeds == 9000][0] > 5 * cur["iabs"][speeds == 6000][0]
    assert np.all(np.diff(cur["iabs"][speeds >= 7000]) > 0)


def test_cutting_current_reproduces_thesis_eq_4_4() -> None:
    # thesis §4.3: steel 2400 rpm, 3.97 Nm cutting torque -> 4.36 A mean current (Eq. 4.3/4.4)
    n = 1500
    tr = simulate_spindle(np.full(n, 2400.0), np.r_[np.zeros(500), np.full(1000, 3.97)], MOTOR,
                          rng=np.random.default_rng(1))
    assert tr.current_a[900:].mean() == pytest.approx(4.36, rel=0.02)


def test_current_falls_while_motor_warms() -> None:
    # thesis §4.2 / Fig. 4.4: 20+ min at 5000 rpm, temperature rises, current falls
    n = 20 * 60 * 500
    cmd = np.minimum(np.arange(n) * 20.0, 5000.0)
    tr = simulate_spindle(cmd, 0.0, MOTOR, rng=np.random.default_rng(2))
    minute = 30000
    first = tr.current_a[minute:2 * minute].mean()
    last = tr.current_a[-minute:].mean()
    assert last < 0.97 * first
    assert tr.motor_temperature_c[-1] - tr.motor_temperature_c[minute] > 5.0
    assert tr.kt_nm_per_a[-1] < tr.kt_nm_per_a[minute]  # NdFeB flux falls with temperature


@pytest.mark.parametrize(("poles", "speed", "alias_hz"), [(4, 9000.0, 200.0), (4, 3200.0, 106.67),
                                                           (8, 5000.0, 166.67)])
def test_stator_frequency_line_folds_about_250_hz(poles: int, speed: float,
                                                  alias_hz: float) -> None:
    # thesis Eq. 4.1 f = N poles / 120; docs/reference/physics-and-performance.md §2 alias table
    motor = SpindleMotor(pole_count=poles, ripple_amplitude_a=0.1)
    tr = simulate_spindle(np.full(12000, speed), 0.0, motor, rng=np.random.default_rng(3))
    x = tr.current_a[4000:] - tr.current_a[4000:].mean()
    f = np.fft.rfftfreq(x.size, 0.002)
    p = np.abs(np.fft.rfft(x * np.hanning(x.size)))
    assert f[np.argmax(p[5:]) + 5] == pytest.approx(alias_hz, abs=0.5)


def test_chunked_equals_one_shot_and_seed_reproducible() -> None:
    cmd = np.linspace(0, 9000, 3000)
    load = np.r_[np.zeros(1500), np.full(1500, 2.0)]
    one = simulate_spindle(cmd, load, MOTOR, rng=np.random.default_rng(5))
    g = np.random.default_rng(5)
    a = simulate_spindle(cmd[:1234], load[:1234], MOTOR, rng=g)
    b = simulate_spindle(cmd[1234:], load[1234:], MOTOR, rng=g, state=a.state)
    both = SpindleTrace.concatenate([a, b])
    for name in ("current_a", "speed_rpm", "motor_temperature_c", "iq_smoothed_a"):
        np.testing.assert_array_equal(getattr(one, name), getattr(both, name))
    again = simulate_spindle(cmd, load, MOTOR, rng=np.random.default_rng(5))
    np.testing.assert_array_equal(one.current_a, again.current_a)


def test_output_buffer_gives_the_same_trace_as_views() -> None:
    # simulate() reuses one buffer (18 trace fields x cycles) between chunks
    cmd = np.linspace(0, 6000, 2000)
    fresh = simulate_spindle(cmd, 1.0, MOTOR, rng=np.random.default_rng(2))
    buf = np.full((18, cmd.size), np.nan)
    into = simulate_spindle(cmd, 1.0, MOTOR, rng=np.random.default_rng(2), out=buf)
    for name in ("speed_rpm", "current_a", "torque_nm", "power_w", "voltage_v"):
        np.testing.assert_array_equal(getattr(into, name), getattr(fresh, name))
        assert np.shares_memory(getattr(into, name), buf)
    with pytest.raises(ConfigError, match="out must be"):
        simulate_spindle(cmd, 1.0, MOTOR, out=np.empty((cmd.size, 18)))


def test_rigid_tapping_follows_position_command() -> None:
    n = 1500
    pos = np.cumsum(np.r_[np.linspace(0, 2.4, 100), np.full(n - 100, 2.4)])  # deg per cycle
    tr = simulate_spindle(np.zeros(n), 0.5, MOTOR, position_cmd_deg=pos, mode=1,
                          rng=np.random.default_rng(4))
    # 2.4 deg/2 ms = 200 rpm; with speed feedforward the lag is a few degrees at most
    assert np.max(np.abs(tr.position_deg[200:] - pos[200:])) < 3.0
    # and it lags (never leads) the command while accelerating: no setpoint ahead of time
    assert np.median(pos[20:100] - tr.position_deg[20:100]) >= 0.0
    assert tr.speed_rpm[-200:].mean() == pytest.approx(200.0, rel=0.02)


@pytest.mark.parametrize("direction", [1.0, -1.0])
def test_position_control_torque_balances_load_and_friction(direction: float) -> None:
    """In position control (rigid tapping) at constant speed the drive must deliver friction
    plus load, with the sign of the motion: I = (tau_f + B n + tau_load) / Kt, as in speed
    control (thesis Eq. 4.4 read backwards). Session 2 found a 6 Nm peak-to-peak 500 Hz sawtooth
    and wrong-signed current here (setpoint held a whole cycle ahead inside the 125 us loop)."""
    n = 2000
    pos = direction * 4.8 * np.arange(n)  # 4.8 deg per 2 ms cycle = 400 rpm
    for load in (0.0, 1.0):
        pc = simulate_spindle(np.zeros(n), direction * load, MOTOR, position_cmd_deg=pos,
                              mode=1, rng=np.random.default_rng(3))
        sc = simulate_spindle(np.full(n, direction * 400.0), direction * load, MOTOR,
                              rng=np.random.default_rng(3))
        i_pos = np.mean(pc.current_a[1000:])
        i_speed = np.mean(sc.current_a[1000:])
        assert np.sign(i_pos) == direction
        # same mean current as in speed control within 0.03 A (the current noise is 0.03 A rms)
        assert i_pos == pytest.approx(i_speed, abs=0.03)
        # torque setpoint and current agree (Kt = 1.04 Nm/A within 5 %)
        t_pos = np.mean(pc.torque_setpoint_nm[1000:])
        assert t_pos / i_pos == pytest.approx(MOTOR.kt_nm_per_a, rel=0.05)
        # following error at the cycle instants: < 0.1 deg with full speed feedforward
        assert np.max(np.abs(pc.position_deg[1000:] - pos[1000:])) < 0.1


def test_spos_moves_to_the_nearest_turn_with_limited_acceleration() -> None:
    """Taking over position control at standstill (SPOS) moves the spindle to the programmed
    angle modulo 360 with MD35300/MD35210 speed and acceleration, not with a current-limited
    jump of many turns."""
    motor = SpindleMotor()
    n = 1500
    state = simulate_spindle(np.zeros(50), 0.0, motor, rng=np.random.default_rng(1)).state
    # rotate the spindle to an arbitrary angle many turns away from the command
    turn = simulate_spindle(np.r_[np.full(700, 300.0), np.zeros(800)], 0.0, motor, state=state,
                            rng=np.random.default_rng(2))
    start = turn.position_deg[-1]
    target = 90.0
    tr = simulate_spindle(np.zeros(n), 0.0, motor, state=turn.state, position_cmd_deg=np.full(
        n, target), mode=1, rng=np.random.default_rng(5))
    err = (tr.position_deg[-1] - target + 180.0) % 360.0 - 180.0
    assert abs(err) < 0.05
    assert abs(tr.position_deg[-1] - start) <= 180.0 + 0.05  # nearest turn, not thousands of deg
    # acceleration torque J a = 0.015 kg m^2 * 30 rev/s^2 * 2 pi = 2.8 Nm -> a few A, far from
    # the 48 A current limit
    assert np.max(np.abs(tr.current_a)) < 8.0
    assert np.max(np.abs(tr.speed_rpm)) < motor.spos_speed_rpm + 20.0


def test_lf_values_are_smoothed_and_consistent() -> None:
    tr = simulate_spindle(np.full(3000, 3000.0), 0.0, MOTOR, rng=np.random.default_rng(6))
    assert tr.speed_smoothed_rpm[-1] == pytest.approx(3000.0, abs=1.0)
    assert np.std(tr.iq_smoothed_a[-500:]) < 0.2 * np.std(tr.current_a[-500:])
    assert tr.load_pct[-1] == pytest.approx(100 * abs(tr.torque_setpoint_nm[-1]) / 25.0)


def test_flux_linkage_consistent_with_kt() -> None:
    m = SpindleMotor()
    assert 1.5 * np.sqrt(2) * m.pole_pairs * m.flux_linkage_vs == pytest.approx(1.04)
    with pytest.raises(ConfigError, match="pole_count"):
        simulate_spindle([0.0], 0.0, SpindleMotor(pole_count=3))


@pytest.mark.parametrize(("interpolated", "lo", "hi"), [(True, 0.99, 1.01), (False, 0.9, 0.98)])
def test_run_up_current_is_newtons(interpolated: bool, lo: float, hi: float) -> None:
    """The current sampled at the end of each 2 ms cycle of a constant run-up is
    (J alpha + tau_friction) / Kt (Newton, thesis Eq. 3.1) within 1 % when the drive
    interpolates the speed setpoint over the cycle (``speed_setpoint_interpolation``, the
    default); a setpoint stepped once per cycle kicks the speed controller every 2 ms and
    the end-of-cycle sample reads low (the spindle inertia came out 3-6 % low from it)."""
    import dataclasses

    motor = dataclasses.replace(SpindleMotor(), current_noise_a=0.0, speed_noise_rpm=0.0,
                                torque_noise_nm=0.0, ripple_amplitude_a=0.0,
                                ripple_high_speed_a=0.0,
                                speed_setpoint_interpolation=interpolated)
    alpha = 300.0  # rad/s^2: 0 -> 2865 rpm in 1 s
    t = np.arange(700) * 0.002
    cmd = np.where(t > 0.2, alpha * (t - 0.2), 0.0) * 60.0 / (2.0 * np.pi)
    tr = simulate_spindle(cmd, 0.0, motor)
    k = (t > 0.6) & (t < 1.3)  # settled on the ramp, 1100-2300 rpm
    newton = (motor.inertia_kg_m2 * alpha + tr.friction_nm[k]) / tr.kt_nm_per_a[k]
    assert lo < np.mean(tr.current_a[k]) / np.mean(newton) < hi
