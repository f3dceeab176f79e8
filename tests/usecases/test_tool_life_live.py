"""The live tool life of the edge against a hidden wear curve (issue 27: tool life out to the
plant, from the wear model; OPC 40501 ToolLife/Prognoses and MTConnect CuttingTool carry it).

As a user does it, through the CLI: tool A (a simulated 200-hole life of the thesis drill,
§5.1 wear curve compressed to 200 holes, seed 11) is measured under the microscope at four
holes (the simulator's true wear); ``cnctwin wear --measured ... --out`` writes the tool-table
keys; tool B, a second drill of the same kind (seed 12: independent noise and scatter, the
same hidden wear law), is drilled with ``cnctwin edge run --tools``; its ``tool_life``
results are compared with B's hidden truth (``holes.csv``).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

pytestmark = pytest.mark.slow

N = 200
LIMIT_UM = 230.0
WEAR = {"wear.n_end": float(N), "wear.run_in_holes": 40.0 * N / 2676,
        "wear.rate_um_per_hole": 147.0 / N}


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    res = subprocess.run([sys.executable, "-m", "cnctwin", *args], capture_output=True,
                         text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    return res


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    from cnctwin.edge import save_spindle_model
    from cnctwin.sim.scenarios import tool_wear_run
    from cnctwin.spindle import SpindleModel

    d = tmp_path_factory.mktemp("tool_life")
    out: dict[str, Any] = {"dir": d}
    for name, seed in (("a", 11), ("b", 12)):
        res = tool_wear_run(d / name, n_holes=N, seed=seed, overrides=WEAR, fmt="parquet",
                            dynamometer=False)
        out[name] = Path(res.recording_paths[0])
        out[f"{name}_truth"] = pd.read_csv(d / name / "holes.csv")
    # tool A under the microscope at four holes across its life
    truth_a = out["a_truth"]
    measured = ",".join(f"{h}:{truth_a['wear_um'][h]:.1f}" for h in (15, 70, 125, 180))
    _cli("wear", str(out["a"]), "--measured", measured, "--limit-um", f"{LIMIT_UM:g}",
         "--out", str(d / "calib"))
    keys = (d / "calib" / "wear_calibration.toml").read_text()
    (d / "tools.toml").write_text('[tools.1]\nkind = "drill"\ndiameter_mm = 20\n'
                                  'name = "DRILL D20 B"\nlife_holes = 1000\n' + keys)
    model = save_spindle_model(SpindleModel.from_parameters("thesis_spinner_840dsl"),
                               d / "spindle.json")
    _cli("edge", "run", "--source", str(out["b"]), "--out", str(d / "edge"), "--model",
         str(model), "--machine", "m1", "--tools", str(d / "tools.toml"), "--quiet",
         "--no-anomaly")
    rows = [json.loads(x) for x in (d / "edge" / "results.jsonl").read_text().splitlines()]
    out["life"] = pd.DataFrame([r for r in rows if r["kind"] == "tool_life"])
    return out


def test_live_tool_life_follows_the_hidden_wear_of_a_second_tool(runs: dict[str, Any]
                                                                 ) -> None:
    life, truth = runs["life"], runs["b_truth"]
    # one tool_life result per hole, counting the usages exactly
    assert len(life) == N
    assert life["used_holes"].tolist() == list(range(1, N + 1))
    assert (life["tool"] == 1).all()
    # the wear estimate against B's hidden wear, after the 30 baseline holes: calibrated on
    # another tool, measured 3.4-6.0 µm RMS and 10-17 µm at worst over 75-250 µm in four
    # pairs of draws (the set means lag the wear by half a set where it accelerates);
    # tolerance 8 µm RMS, 20 µm at any hole
    est = life["wear_um"].to_numpy(dtype=float)
    true = truth["wear_um"].to_numpy(dtype=float)
    ok = np.isfinite(est)
    assert ok[30:].all() and not ok[:30].any()
    err = est[ok] - true[ok]
    assert np.sqrt(np.mean(err**2)) < 8.0
    assert np.abs(err).max() < 20.0


def test_remaining_life_forecast_against_the_true_end_of_life(runs: dict[str, Any]) -> None:
    """The forecast of the hole at which B reaches the wear limit, from the holes drilled so
    far. The accelerating end of life (exponent 6 of the hidden curve) is not in the data
    before it starts, so early forecasts are late; what is asserted is what was measured
    (docs/tool-life.md records the figures), with tolerances."""
    life, truth = runs["life"], runs["b_truth"]
    true_end = int(np.argmax(truth["wear_um"].to_numpy() >= LIMIT_UM))
    assert 0.8 * N < true_end < N  # the limit lies inside the run
    hole = life["hole"].to_numpy(dtype=float)
    rem = life["remaining_holes"].to_numpy(dtype=float)
    lo = life["remaining_low"].to_numpy(dtype=float)
    wear_basis = (life["basis"] == "wear").to_numpy()
    # the wear model's forecast once its trend reaches the limit sooner than the planned
    # 1000 holes (measured from hole 53-65: before, the early trend never reaches it)
    assert wear_basis[80:].all()
    at = {k: int(k * true_end) for k in (0.6, 0.8, 0.9)}
    errors = {k: hole[i] + rem[i] - true_end for k, i in at.items()}
    # late but tightening, in four pairs of draws (seeds 11/12, 21/22, 31/32, 41/42):
    # +25..+55 holes at 60 % of the life, +6..+15 at 80 %, +5..+8 at 90 %; the 90 %
    # interval's early end within 0-8 holes after the true end from 80 % on. The interval
    # holds the trend's statistics and the wear estimate's uncertainty, not the onset of
    # accelerated wear (docs/tool-life.md): asserted is the measured lateness, not a coverage
    assert 0.0 <= errors[0.9] <= 10.0
    assert 0.0 <= errors[0.8] <= 20.0
    assert errors[0.9] <= errors[0.6]
    early = hole[at[0.9]] + lo[at[0.9]] - true_end
    assert -10.0 <= early <= 6.0
    # the remaining time: the holes at the tool's hole period (4 s per hole, thesis program)
    period = life["hole_period_s"].to_numpy(dtype=float)[at[0.8]]
    assert 3.5 < period < 4.5
    assert life["remaining_s"][at[0.8]] == pytest.approx(rem[at[0.8]] * period)
