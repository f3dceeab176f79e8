"""Issue #4 item 7: recover hidden spindle parameters from simulated campaigns with TwinChain.

For randomly drawn, seeded spindles (torque constant, viscous and Coulomb friction, pole count,
base speed, magnet temperature coefficient; realistic ranges below) the simulator
(:mod:`cnctwin.sim.scenarios`) runs

* the air-cut sweep (thesis §3.2.2; 80 speeds 100-8000 rpm, 3 s dwell: denser below the
  field-weakening onset than the thesis' 126 speeds up to 18000 rpm, which spend most of their
  plateaus above it),
* a short warm-up (thesis §4.2, 3 min at 5000 rpm),
* the drilling validation (thesis §4.3/Table 4.1) twice: cold (its first cut, steel 2400 rpm
  0.16 mm/rev, is the calibration cut) and after a warm-up drift (the whole machine 10-25 K
  warmer: ``spindle.ambient_temperature_c``), whose five cuts are validated.

The pipeline (:class:`cnctwin.twin.TwinChain`) sees only the Recordings. The truth is the
drawn overrides (Kt at 20 degC magnet temperature, B and tau_f at 22 degC, the simulator's
references) and, per validation cut, the simulator's per-cycle true cutting torque
(``ScenarioResult.per_cycle``) averaged over the window the pipeline chose.

Asserted (issue #4 item 7): improved method Kt, B, tau_f within 2 % and every validation cut's
mean cutting torque within 2 %; the improved method's errors are lower than the thesis
method's on the same data. Results: docs/validation-spindle.md (``python
tests/test_twin_sim.py`` regenerates the table).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest

from cnctwin.sim import scenarios as sc
from cnctwin.twin import TwinChain

N_DRAWS = 20
SEEDS = list(range(100, 100 + N_DRAWS))
TOL_PCT = 2.0  # issue #4 item 7


def draw_spindle(seed: int) -> tuple[dict[str, Any], float]:
    """Hidden spindle parameters (simulator overrides) and the warm-up drift [K].

    Ranges: Kt 0.85-1.2 Nm/A and B 6e-5 - 1.1e-4 Nm/rpm, tau_f 0.25-0.5 Nm around the thesis
    values (1.04, 8.42e-5, 0.35; Eq. 4.4); 4/6/8 poles; base speed 5500-7500 rpm (thesis
    datasheet 7000 rpm, §4.1), realized through the DC-link voltage so that the no-load
    voltage limit sits at the base speed (u = p omega psi, m = 1.05: 380-730 V); NdFeB
    remanence coefficient -0.09 ... -0.12 %/K (docs/reference/physics-and-performance.md §2).
    """
    g = np.random.default_rng(seed)
    kt = float(g.uniform(0.85, 1.2))
    base = float(g.uniform(5500.0, 7500.0))
    vdc = kt / (1.5 * math.sqrt(2.0)) * base * 2.0 * math.pi / 60.0 * math.sqrt(3.0) / 1.05
    ov = {
        "spindle.kt_nm_per_a": kt,
        "spindle.viscous_friction_nm_per_rpm": float(g.uniform(6e-5, 1.1e-4)),
        "spindle.coulomb_friction_nm": float(g.uniform(0.25, 0.5)),
        "spindle.pole_count": int(g.choice([4, 6, 8])),
        "spindle.base_speed_rpm": base,
        "spindle.dc_link_v": vdc,
        "spindle.magnet_temp_coeff_per_k": float(g.uniform(-0.0012, -0.0009)),
    }
    return ov, float(g.uniform(10.0, 25.0))


@dataclass
class Outcome:
    seed: int
    poles: int
    drift_k: float
    method: str
    kt_err_pct: float
    b_err_pct: float
    tau_f_err_pct: float
    cut_err_pct: list[float]
    fit_range_rpm: tuple[float, float]


def run_draw(seed: int) -> list[Outcome]:
    """Simulate one campaign and run both presets on it."""
    ov, drift = draw_spindle(seed)
    sweep = sc.air_cut_sweep(seed=seed, overrides=ov, n_speeds=80, max_speed_rpm=8000.0,
                             min_speed_rpm=100.0, dwell_s=3.0).recording
    warm_up = sc.warm_up(seed=seed, overrides=ov, speeds_rpm=(5000.0,),
                         minutes=3.0).recordings[0]
    cold = sc.drilling_validation(seed=seed, overrides=ov)
    warm = sc.drilling_validation(seed=seed + 10_000,
                                  overrides={**ov, "spindle.ambient_temperature_c":
                                             22.0 + drift})
    kt = ov["spindle.kt_nm_per_a"]
    b = ov["spindle.viscous_friction_nm_per_rpm"]
    tf = ov["spindle.coulomb_friction_nm"]
    out = []
    for chain in (TwinChain.thesis_method(), TwinChain.improved_method()):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            chain.calibrate(sweep, cold.recordings[0], warm_up=warm_up)
            chain.run_model_from_measured(warm.recordings)
        m = chain.model
        v = chain.results.validation
        assert len(v) == len(warm.recordings), "one cut per validation recording"
        errs = []
        for _, row in v.iterrows():
            true = warm.per_cycle[int(row["recording"])]["cutting_torque_nm"]
            t_mean = float(true.loc[int(row["start_cycle"]):int(row["end_cycle"])].mean())
            errs.append(100.0 * (row["predicted_torque_nm"] / t_mean - 1.0))
        out.append(Outcome(
            seed, int(ov["spindle.pole_count"]), drift, chain.name,
            100.0 * (m.kt_nm_per_a / kt - 1.0), 100.0 * (m.b_nm_per_rpm / b - 1.0),
            100.0 * (m.tau_f_nm / tf - 1.0), errs, chain.results.fit_range_rpm,
        ))
    return out


@pytest.fixture(scope="module")
def outcomes() -> list[Outcome]:
    res: list[Outcome] = []
    for s in SEEDS:
        res += run_draw(s)
    return res


def _max(o: Outcome) -> float:
    return max(abs(o.kt_err_pct), abs(o.b_err_pct), abs(o.tau_f_err_pct),
               *(abs(e) for e in o.cut_err_pct))


@pytest.mark.slow
def test_improved_method_recovers_parameters_within_2_pct(outcomes: list[Outcome]) -> None:
    imp = [o for o in outcomes if o.method == "improved"]
    assert len(imp) == N_DRAWS
    for o in imp:
        assert abs(o.kt_err_pct) < TOL_PCT, o
        assert abs(o.b_err_pct) < TOL_PCT, o
        assert abs(o.tau_f_err_pct) < TOL_PCT, o
        assert max(abs(e) for e in o.cut_err_pct) < TOL_PCT, o


@pytest.mark.slow
def test_improved_method_beats_thesis_method(outcomes: list[Outcome]) -> None:
    th = [o for o in outcomes if o.method == "thesis"]
    imp = [o for o in outcomes if o.method == "improved"]

    def rms(vals: list[float]) -> float:
        return float(np.sqrt(np.mean(np.square(vals))))

    for name in ("kt_err_pct", "b_err_pct", "tau_f_err_pct"):
        assert rms([getattr(o, name) for o in imp]) < rms([getattr(o, name) for o in th]), name
    cuts_t = [e for o in th for e in o.cut_err_pct]
    cuts_i = [e for o in imp for e in o.cut_err_pct]
    assert rms(cuts_i) < rms(cuts_t)
    assert max(map(abs, cuts_i)) < max(map(abs, cuts_t))
    # per draw: the worst error of the improved method is lower
    for a, b in zip(th, imp, strict=True):
        assert _max(b) < _max(a), (a, b)


def markdown_table(outcomes: list[Outcome]) -> str:
    """The per-draw table of docs/validation-spindle.md."""
    lines = [
        "| seed | poles | drift [K] | method | Kt [%] | B [%] | tau_f [%] | "
        "cuts [%] (5 validation cuts) | fit range [rpm] |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for o in outcomes:
        cuts = " ".join(f"{e:+.2f}" for e in o.cut_err_pct)
        lines.append(
            f"| {o.seed} | {o.poles} | {o.drift_k:.1f} | {o.method} | {o.kt_err_pct:+.2f} | "
            f"{o.b_err_pct:+.2f} | {o.tau_f_err_pct:+.2f} | {cuts} | "
            f"{o.fit_range_rpm[0]:.0f}-{o.fit_range_rpm[1]:.0f} |"
        )
    for method in ("thesis", "improved"):
        sel = [o for o in outcomes if o.method == method]
        if not sel:
            continue

        def stat(vals: list[float]) -> str:
            a = np.abs(vals)
            return f"{np.sqrt(np.mean(np.square(vals))):.2f} / {a.max():.2f}"

        lines.append(
            f"| **all** | | | **{method}** rms / max | {stat([o.kt_err_pct for o in sel])} | "
            f"{stat([o.b_err_pct for o in sel])} | {stat([o.tau_f_err_pct for o in sel])} | "
            f"{stat([e for o in sel for e in o.cut_err_pct])} | |"
        )
    return "\n".join(lines)


if __name__ == "__main__":  # pragma: no cover - regenerates the docs table
    res: list[Outcome] = []
    for s in SEEDS:
        res += run_draw(s)
    print(markdown_table(res))
