"""Proof on the project simulator: recover hidden, randomly drawn loop parameters.

Square and circle milling paths (thesis §3.1.2, Fig. 3.2/3.3) are simulated with
``cnctwin.sim.simulate`` on a machine whose X1/Y1 loop parameters are drawn at random (seeded)
from realistic ranges (docs/reference/physics-and-performance.md §1.2: Kv 1-3 (m/min)/mm, MA jerk
filter of
3-12 position-control cycles (MD32410 type 2 is set in cycles: 1-16), FFW mode MD32620 0-4
(none, speed or torque feedforward with PT1 or dead-time balancing), weight 0.7-1, MD32810
1-4 ms, MD32910 0-4 ms, Coulomb 50-250 N, viscous 0.05-0.5 N/(mm/s)).
The analysis sees only the Recording. Tolerances (issue #5): Kv within 5 %, jerk-filter time
within 10 %, ENC_POS prediction residual RMS below 10 % of the following-error RMS.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import cnctwin.sim as sim  # an import bug of the project's own module must fail, not skip
from cnctwin.servo import KV_PER_S_PER_M_MIN_MM, identify_axis
from cnctwin.servo.geometry import circle_test, contour_error
from cnctwin.servo.predict import AxisLoopModel, prediction_residual

SQUARE = """G90 G0 X0 Y0 Z5
G1 Z-0.5 F300
G1 X40 F2400
Y40
X0
Y0
G1 X40 F4800
Y40
X0
Y0
M30
"""

CIRCLE = """G90 G0 X20 Y0 Z5
G1 Z-0.5 F300
G2 X20 Y0 I-20 J0 F3000
G2 X20 Y0 I-20 J0 F1500
M30
"""


def _draw(seed: int) -> dict[str, Any]:
    rng = np.random.default_rng(1000 + seed)
    mode = int(rng.choice([0, 1, 2, 3, 4]))
    return {
        "kv_m_min_per_mm": float(rng.uniform(1.0, 3.0)),
        "ffw_mode": mode,
        "ffw_weight": float(rng.uniform(0.7, 1.0)) if mode else 1.0,
        "jerk_filter_type": 2,
        "jerk_time_s": 0.002 * int(rng.integers(3, 13)),
        "dyn_match_time_s": float(rng.uniform(0.0, 0.004)),
        "equiv_speedctrl_time_s": float(rng.uniform(0.001, 0.004)),
        "coulomb_n": float(rng.uniform(50.0, 250.0)),
        "viscous_n_per_mm_s": float(rng.uniform(0.05, 0.5)),
    }


def _simulate(program: str, hidden: dict[str, Any], seed: int) -> Any:
    over = {f"axes.{ax}.{k}": v for ax in ("X1", "Y1") for k, v in hidden.items()}
    machine = sim.Machine.thesis_default().with_overrides(over)
    return sim.simulate(program, machine, seed=seed).recording


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("program", ["square", "circle"])
def test_recover_hidden_loop_parameters(seed: int, program: str) -> None:
    hidden = _draw(seed)
    rec = _simulate(SQUARE if program == "square" else CIRCLE, hidden, seed)
    ident = identify_axis(rec, "X1", n_bootstrap=30)
    kv_true = hidden["kv_m_min_per_mm"]
    assert ident.value("kv_m_min_mm") == pytest.approx(kv_true, rel=0.05)
    assert ident.value("kv_1_s") == pytest.approx(kv_true * KV_PER_S_PER_M_MIN_MM, rel=0.05)
    assert ident.value("jerk_time_s") == pytest.approx(hidden["jerk_time_s"], rel=0.10)
    assert ident.jerk_type == "moving_average"
    expected_mode = {0: "none", 1: "speed", 3: "speed", 2: "torque", 4: "torque"}
    assert ident.ffw_mode == expected_mode[hidden["ffw_mode"]]
    if hidden["ffw_mode"] != 0:
        assert ident.value("ffw_weight") == pytest.approx(hidden["ffw_weight"], abs=0.05)
    model = AxisLoopModel.from_identification(ident)
    rms, fe_rms, _ = prediction_residual(model, rec, "X1")
    assert rms < 0.10 * fe_rms
    if program == "square":
        # two feeds x two directions = 4 steady runs: friction force at the slide (TORQUE, N)
        assert ident.value("coulomb_torque") == pytest.approx(hidden["coulomb_n"], rel=0.15)


def test_square_contour_and_circle_test() -> None:
    hidden = _draw(0)
    sq = _simulate(SQUARE, hidden, 0)
    ce = contour_error(sq, path=np.array([[0, 0], [40, 0], [40, 40], [0, 40], [0, 0]]))
    # corners are rounded by the loop lag, straight sides are followed closely
    assert len(ce.corners) >= 3
    assert all(c.rounding_mm > 0 for c in ce.corners)
    assert ce.rms_mm < ce.max_abs_mm
    circ = _simulate(CIRCLE, hidden, 0)
    res = circle_test(circ, center=(0.0, 0.0), radius=20.0)
    assert res.n_samples > 500
    # a lagging loop shrinks the circle (Siemens A3: radius error ~ v^2/(2 R Kv^2) without FFW)
    assert res.radius_deviation_mm < 0.0
    assert res.circular_deviation_mz_mm <= res.circular_deviation_lsc_mm + 1e-12


@pytest.mark.parametrize("seed", [1, 4])
def test_kv_without_cmd_speed_from_steady_following_error(seed: int) -> None:
    """Recordings without CMD_SPEED (an edge device set up with fewer signals), feedforward
    off. With CTRL_POS, Kv comes from v = Kv (CTRL_POS - ENC_POS) on the constant-velocity runs
    (Siemens FB1 G2: following error = v / Kv without feedforward) and must be the hidden Kv
    within the 5 % of issue 5. Without CTRL_POS too, DES_POS - ENC_POS holds the setpoint
    chain's lag as well (this branch had no test, issue 16; it reported a Kv 7-16 % low):
    Kv is then not identified, with the reason, and the total lag is still given."""
    hidden = {**_draw(seed), "ffw_mode": 0, "ffw_weight": 1.0}
    rec = _simulate(SQUARE, hidden, seed)
    kv_true = hidden["kv_m_min_per_mm"]
    no_cmd = rec.copy()
    no_cmd.hf = rec.hf.drop(columns=[c for c in rec.columns
                                     if c.split("|")[0] in ("CMD_SPEED", "VEL_FFW")])
    ident = identify_axis(no_cmd, "X1", n_bootstrap=10)
    assert ident.value("kv_m_min_mm") == pytest.approx(kv_true, rel=0.05)
    assert "v = Kv*e" in ident.params["kv_m_min_mm"].method
    bare = no_cmd.copy()
    bare.hf = no_cmd.hf.drop(columns=[c for c in no_cmd.columns
                                      if c.split("|")[0] in ("CTRL_POS", "CTRL_DIFF",
                                                             "CTRL_DIFF2")])
    ident = identify_axis(bare, "X1", n_bootstrap=10)
    assert "kv_m_min_mm" not in ident.params
    assert "setpoint chain" in ident.not_identified["kv_m_min_mm"]
    # the total steady lag: 1/Kv plus the chain (jerk filter about half its length, the
    # dynamic response adaptation, the speed loop's equivalent time): above 1/Kv
    assert ident.value("lag_time_s") > 1.0 / (kv_true * KV_PER_S_PER_M_MIN_MM)
