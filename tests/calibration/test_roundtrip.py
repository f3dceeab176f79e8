"""Hidden round trip through the command line (issue 12 acceptance).

8 machines with hidden spindle and loop parameters drawn at random from their seed are
simulated (air cut, one drilling cut with the dynamometer, the axis test program);
``cnctwin calibrate spindle`` and ``cnctwin calibrate axes`` recover them from the files:

* accuracy: Kt, viscous and Coulomb friction within 2 %, Kv within 5 %, jerk time within 10 %
  of the hidden values (issue 12), every seed; the spindle inertia within 2 % (it was 1-6 %
  low while the simulated drive stepped its speed setpoint; 0.2 % since) and the X1/Y1
  Coulomb friction within 5 % (issue 29; the axes' viscous friction: coverage only);
* honesty: each hidden value inside its stated 95 % interval (value +- 1.96 standard
  uncertainties) in at least 7 of the 8 seeds (the 200-draw campaign with its coverage per
  parameter is ``benchmarks/bench_calibration_coverage.py``, docs/validation-calibration.md; 8 seeds
  keep this test at about a minute of the suite's 15).

Two physical referrals are applied to the hidden values before comparing, because the
machine file states what the recordings can show:

* Kt is stated at ``spindle.kt_ref_temperature_c`` (the motor temperature of the air cut);
  the hidden Kt holds at 20 degC and changes by the magnet coefficient
  ``magnet_temp_coeff_per_k`` (-0.11 %/K, NdFeB) in between.
* A moving-average jerk filter spans whole 2 ms cycles (the simulator, like the NC, uses
  round(MD32410 / T_c) samples), so the accuracy is checked against that effective length;
  the 95 % interval (which includes the half-cycle quantisation) is checked against the
  hidden MD32410 itself. A filter of 2 cycles, y[k] = (x[k] + x[k-1]) / 2, is exactly a
  linearly interpolated half-cycle delay: no recording can tell it from the balancing delay.
  There the calibration must say so (``identified = false`` with the reason) and the seed
  counts as outside the interval.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from cnctwin.machine import Machine, MachineFile, load_machine
from tests.calibration._campaign import calibrate, hidden_machine, simulate_campaign

N_SEEDS = 8
MIN_INSIDE = 7
DT = 0.002

TOLERANCE = {  # relative, issue 12; issue 29: J and the axis friction, their coverage too
    "spindle.kt_nm_per_a": 0.02,
    "spindle.viscous_friction_nm_per_rpm": 0.02,
    "spindle.coulomb_friction_nm": 0.02,
    "spindle.inertia_kg_m2": 0.02,
    "axes.X1.kv_m_min_per_mm": 0.05,
    "axes.Y1.kv_m_min_per_mm": 0.05,
    "axes.X1.jerk_time_s": 0.10,
    "axes.Y1.jerk_time_s": 0.10,
    "axes.X1.coulomb_n": 0.05,
    "axes.Y1.coulomb_n": 0.05,
    # the viscous axis friction from the axis test's few speeds: 8-12 % mean, 45 % max error
    # over 100 draws (docs/validation-calibration.md), its interval covers: only that is
    # asserted
    "axes.X1.viscous_n_per_mm_s": float("inf"),
    "axes.Y1.viscous_n_per_mm_s": float("inf"),
}


def _run_seed(seed: int, base: Path) -> dict[str, tuple[float, float, float, float]]:
    """key -> (hidden for accuracy, hidden for the interval, value, standard uncertainty)."""
    d = base / f"seed{seed}"
    hidden = hidden_machine(seed)
    simulate_campaign(d, seed, hidden)
    machine = d / "machine.toml"
    calibrate(d, machine)
    mf = load_machine(machine)
    default = Machine.thesis_default()
    out = {}
    for key in TOLERANCE:
        rec = mf.record(key)
        assert rec is not None, f"seed {seed}: {key} not in the machine file"
        if key not in hidden:  # not drawn: the thesis machine's value (viscous axis friction)
            hidden[key] = MachineFile().value(key)
        two_cycles = key.endswith("jerk_time_s") and round(float(hidden[key]) / DT) <= 2
        if two_cycles and not rec.identified:
            assert "half-cycle delay" in rec.reason
            continue
        assert rec.identified, f"seed {seed}: {key} not identified: {rec.reason}"
        assert rec.uncertainty is not None and rec.uncertainty > 0, key
        h = float(hidden[key])
        h_acc = h
        if key == "spindle.kt_nm_per_a":
            sp = default.spindle
            t_ref = mf.value("spindle.kt_ref_temperature_c")
            h = h_acc = h * (1.0 + sp.magnet_temp_coeff_per_k * (t_ref - sp.kt_ref_temperature_c))
        if key.endswith("jerk_time_s"):
            h_acc = round(h / DT) * DT
        out[key] = (h_acc, h, rec.value, rec.uncertainty)
    return out


@pytest.mark.slow
def test_hidden_round_trip_through_the_cli(tmp_path: Path) -> None:
    results = {seed: _run_seed(seed, tmp_path) for seed in range(N_SEEDS)}
    inside = dict.fromkeys(TOLERANCE, 0)
    for seed, res in results.items():
        for key, (h_acc, h, v, u) in res.items():  # keys missing: not identifiable, outside
            rel = abs(v - h_acc) / abs(h_acc)
            assert rel <= TOLERANCE[key], (
                f"seed {seed}: {key} = {v:.6g}, hidden {h_acc:.6g}: {100 * rel:.2f} % > "
                f"{100 * TOLERANCE[key]:g} %")
            inside[key] += abs(v - h) <= 1.96 * u
    for key, n in inside.items():
        assert n >= MIN_INSIDE, (f"{key}: hidden value inside the stated 95 % interval in {n} "
                                 f"of {N_SEEDS} seeds")
