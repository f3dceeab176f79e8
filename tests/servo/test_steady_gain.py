"""Kv from the NC's own relation and the steady-state speed gain (issue 29, point 2).

The fitted first order + delay of ``fit_speed_loop`` is a model of a PI speed loop with a
current loop; its gain is biased by a few 1e-4 on the simulator (Kv errors of 0.03-0.08 %
against a stated statistical error of 0.003 %, so calibrate axes added a 1 % floor). The
steady-state ratio needs no loop model: travel over the integral of the command.
"""

from __future__ import annotations

import numpy as np
import pytest

import cnctwin.sim as sim
from cnctwin.exceptions import IdentificationError
from cnctwin.servo import identify_axis
from cnctwin.servo.identify import constant_velocity_runs, steady_speed_gain

DT = 0.002


def _synthetic(gain: float, delay_cycles: int, tau_cycles: float, seed: int
               ) -> tuple[np.ndarray, np.ndarray, list[slice]]:
    """A speed command of plateaus; the actual speed = gain x PT1(delay(command)) + noise."""
    rng = np.random.default_rng(seed)
    levels = [0, 50, 0, -80, 0, 120, 0, -30, 0, 200, 0]  # mm/s
    cmd = np.repeat(np.array(levels, float), 300)
    v = np.zeros_like(cmd)
    a = DT / (tau_cycles * DT + DT)
    for k in range(1, cmd.size):
        u = cmd[k - delay_cycles] if k >= delay_cycles else 0.0
        v[k] = v[k - 1] + a * (gain * u - v[k - 1])
    enc = np.cumsum(v) * DT + rng.normal(0.0, 2e-4, v.size)  # 0.2 um measuring noise
    enc = np.round(enc / 1e-4) * 1e-4  # 0.1 um resolution
    runs = constant_velocity_runs(cmd, [slice(0, cmd.size)])
    return cmd + rng.normal(0.0, 0.01, cmd.size), enc, runs


@pytest.mark.parametrize("seed", range(5))
def test_the_steady_gain_of_a_lagging_loop_is_its_gain(seed: int) -> None:
    # truth by construction: 0.8512, the real Capture4Analysis file's ratio
    # (docs/real-data-servo.md)
    cmd, enc, runs = _synthetic(0.8512, 3, 2.0, seed)
    g, se, n = steady_speed_gain(cmd, enc, runs, lag_cycles=3 + 2.0 + 0.5, cycle_time_s=DT)
    assert n == 5
    assert 0 < se < 1e-4
    assert abs(g - 0.8512) <= 3 * se + 1e-6
    # the jackknife error is the scatter, not a bound: a wrong gain of 1e-4 lies far outside
    assert abs(g - 0.8513) > 3 * se


def test_fewer_than_three_runs_are_refused() -> None:
    cmd, enc, runs = _synthetic(1.0, 1, 0.0, 0)
    with pytest.raises(IdentificationError, match=">= 3 constant-velocity runs; found 2"):
        steady_speed_gain(cmd, enc, runs[:2], lag_cycles=1.5, cycle_time_s=DT)


SQUARE = """G90 G0 X0 Y0 Z5
G1 X40 F2400
X0
X40 F4800
X0
X40 F1200
X0
M30
"""


@pytest.mark.parametrize("seed", range(3))
def test_kv_of_a_hidden_loop_from_the_nc_relation_and_the_steady_gain(seed: int) -> None:
    rng = np.random.default_rng(500 + seed)
    kv = float(rng.uniform(1.0, 3.0))
    machine = sim.Machine.thesis_default().with_overrides({
        "axes.X1.kv_m_min_per_mm": kv,
        "axes.X1.equiv_speedctrl_time_s": float(rng.uniform(0.001, 0.004))})
    rec = sim.simulate(SQUARE, machine, seed=seed).recording
    ident = identify_axis(rec, "X1", n_bootstrap=20)
    est = ident.params["kv_m_min_mm"]
    assert ident.kv_exact
    assert "constant-velocity runs" in ident.params["speed_gain"].method
    # the statistical error is the whole uncertainty here: the truth within 3 of it, and it
    # is small (the 1 % floor it replaces was 100x too wide)
    assert abs(est.value - kv) <= 3 * est.stderr
    assert est.stderr < 1e-4 * kv


def test_the_loop_lag_is_taken_out_of_a_drifting_command() -> None:
    """A command that still drifts within its runs (0.02 mm/s per cycle): the travel lags it by
    the loop's equivalent time (a PT1 + delay follows a ramp exactly that late), so the ratio
    is exact with the lag and 0.1 % off without it (0.02 x 5.5 / ~100 mm/s)."""
    gain, delay, tau = 0.97, 3, 2.0
    levels = [100.0, -120.0, 90.0, -110.0]
    cmd = np.concatenate([np.zeros(50)] + [lv + np.sign(lv) * 0.02 * np.arange(400)
                                           for lv in levels])
    v = np.zeros_like(cmd)
    a = 1.0 / (tau + 1.0)
    for k in range(1, cmd.size):
        u = cmd[k - delay] if k >= delay else 0.0
        v[k] = v[k - 1] + a * (gain * u - v[k - 1])
    # the position integrates the speed (trapezoid): a backward difference of it is the mean
    # speed of the last cycle, half a cycle late; the PT1 above lags a ramp by tau cycles
    enc = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]))]) * DT
    runs = [slice(50 + 400 * i + 100, 50 + 400 * (i + 1)) for i in range(len(levels))]
    g, _, _ = steady_speed_gain(cmd, enc, runs, lag_cycles=delay + tau + 0.5, cycle_time_s=DT)
    g0, _, _ = steady_speed_gain(cmd, enc, runs, lag_cycles=0.0, cycle_time_s=DT)
    assert abs(g / gain - 1) < 1e-5
    assert abs(g0 / gain - 1) > 5e-4
