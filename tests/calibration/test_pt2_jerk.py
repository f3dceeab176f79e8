"""The PT2 jerk filter (MD32402 = 1) is identified, or refused with the reason (issue 13).

The NC's second-order jerk filter is two PT1 stages of MD32410 / 2. Before, the calibration
reported it as 'no jerk filter' and put its lag into the balancing time.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from cnctwin.machine import load_machine
from tests.calibration._campaign import cli

pytestmark = pytest.mark.xdist_group("pt2_jerk")


@pytest.mark.parametrize(("mode", "seed"), [(3, 1), (4, 2), (0, 3)])
def test_pt2_identified_and_the_twin_holds(mode: int, seed: int, tmp_path: Path) -> None:
    jt = round(float(np.random.default_rng([seed, 32402]).uniform(0.006, 0.016)), 4)
    s = ["--set", "axes.X1.jerk_filter_type=1", "--set", f"axes.X1.jerk_time_s={jt}",
         "--set", f"axes.X1.ffw_mode={mode}"]
    assert cli("simulate", "axis_test", "--out", tmp_path / "a", "--seed", seed, *s,
               "--option", 'axes=["X1"]') == 0
    m = tmp_path / "m.toml"
    assert cli("calibrate", "axes", tmp_path / "a" / "axis_test.json", "--machine", m) == 0
    mf = load_machine(m)
    assert mf.value("axes.X1.jerk_filter_type") == 1
    assert mf.value("axes.X1.ffw_mode") == mode
    assert mf.value("axes.X1.jerk_time_s") == pytest.approx(jt, rel=0.10)
    assert cli("simulate", "axis_test", "--out", tmp_path / "b", "--seed", seed + 10, *s,
               "--option", 'axes=["X1"]', "--option", "feeds_mm_min=[700, 3000]") == 0
    assert cli("twin", "compare", tmp_path / "b" / "axis_test.json", "--machine", m,
               "--out", tmp_path / "c") == 0
    x1 = json.loads((tmp_path / "c" / "compare.json").read_text())["axes"]["X1"]
    assert x1["residual_ratio"] <= 0.2 and x1["flagged"] is False


def test_pt2_beside_pt1_balancing_is_refused_with_the_reason(tmp_path: Path) -> None:
    s = ["--set", "axes.X1.jerk_filter_type=1", "--set", "axes.X1.jerk_time_s=0.012",
         "--set", "axes.X1.ffw_mode=1"]
    assert cli("simulate", "axis_test", "--out", tmp_path / "a", *s,
               "--option", 'axes=["X1"]') == 0
    m = tmp_path / "m.toml"
    assert cli("calibrate", "axes", tmp_path / "a" / "axis_test.json", "--machine", m) == 0
    rec = load_machine(m).record("axes.X1.jerk_time_s")
    assert rec is not None and not rec.identified and "MD32402" in rec.reason
