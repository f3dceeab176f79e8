"""The jerk filter's grid compares shapes, not the rounding of the setpoint lag (issue 29).

The 200-draw calibration campaign (docs/validation-calibration.md) found three 8-cycle moving
averages on axes with speed and torque feedforward (``ffw_mode`` 2: a balancing PT1 of
MD32800, ~0.28 cycles) fitted as 6.5 cycles + a PT1 of 1 cycle, 17-18 % short. The total lag
(3.5 + 0.28 = 3.78 cycles) fell between the fixed delays of the start grid, where 7 cycles +
a PT1 of 1 (4.0) beat 8 cycles (3.5) and no start near 8 cycles was refined. Now every grid
point carries the delay that gives it the recording's own lag.

Truths: the DC lag of a moving average of w cycles is (w - 1) / 2 cycles, of a backward-Euler
PT1 of T cycles T, of a PT2 2 D T, of a delay the delay (hand calculation, a ramp through each
filter); the hidden jerk time of the campaign's seed 3120, through the command line.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cnctwin.cli import main
from cnctwin.machine import load_machine
from cnctwin.servo.identify import chain_lag_cycles
from cnctwin.sim.scenarios import random_loop_overrides


@pytest.mark.parametrize(("jerk_type", "params", "lag"), [
    ("moving_average", [8.0, 0.0, 0.0, 0.0, 0.0], 3.5),
    ("moving_average", [8.0, 1.25, 0.278, 0.5, 0.3], 3.5 + 1.25 + 0.278 + 0.5 + 0.3),
    ("double_moving_average", [6.0, 3.0, 0.0, 0.0, 0.0, 0.0], 2.5 + 1.0),
    ("pt2", [4.0, 0.7, 0.0, 0.0, 0.0, 0.0], 2 * 0.7 * 4.0),
    ("none", [2.5, 3.0, 0.0, 0.0], 5.5),
])
def test_chain_lag_is_the_filters_dc_group_delay(jerk_type: str, params: list[float],
                                                 lag: float) -> None:
    assert chain_lag_cycles(jerk_type, np.array(params)) == pytest.approx(lag, abs=1e-9)


def test_an_8_cycle_average_with_a_balancing_pt1_is_found_through_the_cli(
        tmp_path: Path) -> None:
    hidden = {k: v for k, v in random_loop_overrides(3120).items() if k.startswith("axes.Y1")}
    assert hidden["axes.Y1.ffw_mode"] == 2 and hidden["axes.Y1.jerk_filter_type"] == 2
    jerk = float(hidden["axes.Y1.jerk_time_s"])  # 15.42 ms: round(7.71) = 8 cycles
    sets = [x for k, v in hidden.items() for x in ("--set", f"{k}={v}")]
    assert main(["simulate", "axis_test", "--out", str(tmp_path / "at"), "--seed", "3120",
                 *sets, "--option", 'axes=["Y1"]']) == 0
    machine = tmp_path / "machine.toml"
    assert main(["calibrate", "axes", str(tmp_path / "at" / "axis_test.json"),
                 "--machine", str(machine)]) == 0
    rec = load_machine(machine).record("axes.Y1.jerk_time_s")
    assert rec is not None and rec.identified
    # the filter spans whole cycles: 8 x 2 ms (before: 13.08 ms, -18 %)
    assert rec.value == pytest.approx(8 * 0.002, rel=0.01)
    assert rec.uncertainty is not None
    assert abs(rec.value - jerk) <= 1.96 * rec.uncertainty
