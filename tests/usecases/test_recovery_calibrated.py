"""Use cases through a calibrated machine file, on a simulated machine whose parameters are
drawn at random (issue 13, point 3: the twin must not check itself).

Per seed, everything hidden is drawn at random: the spindle (Kt, viscous and Coulomb friction,
Stribeck term, inertia; :func:`random_spindle_overrides`), the X/Y position loops
(:func:`random_loop_overrides`), the wear rate, the tool's thermal model with a second node
(the holder, which the one-node soft sensor does not assume) and the drill's lip-height
difference and entry force. The simulator also carries effects no estimator assumes: the
magnet temperature coefficient, Kt saturation, a viscous roll-off and the Stribeck term of the
friction, two motor thermal nodes. The analysis gets what a user has:

1. the calibration campaign's files (air cut, one drilling cut with the dynamometer, the axis
   test program), calibrated with ``cnctwin calibrate spindle`` / ``calibrate axes`` into a
   machine file;
2. a 60-hole tool-wear run (wear curve compressed: 0 to ~250 µm), analysed with
   ``cnctwin holes --machine`` and ``cnctwin wear --machine --measured`` (5 "microscope"
   readings), the camera CSV for the tool-temperature soft sensor and the machine file's
   axes for the hole quality.

Tolerances and what was measured (seeds 3, 5, 11; docs/validation-usecases.md, "Through a
calibrated machine file"): cutting torque per hole against the simulator's true cutting
torque over the same cut window within 1 % (measured <= 0.31 %; the thesis machine's
parameters: 12-28 %); wear RMS 20 µm (11-12 µm); tool temperature RMS against the noise-free
camera reading 10 °C (3-6 °C; 1-3 °C before the holder node, when the sensor's model was the
simulator's); tool-tip position error median 12 %, largest 25 % (4-9 %, 12-21 %; the test with
the hidden axis description gets <= 10 %: the difference is the axes' model error).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd
import pytest

from cnctwin.iotools import read_recording, read_thermal_camera_csv
from cnctwin.machine import load_machine
from cnctwin.machine.tools import Drill
from cnctwin.usecases.holes import hole_record
from cnctwin.usecases.quality import hole_quality
from cnctwin.usecases.thermal import ToolThermalModel, merge_camera
from tests.calibration._campaign import calibrate, cli, hidden_machine, sets, simulate_campaign

pytestmark = pytest.mark.slow

N_HOLES = 60
MEASURED = (0, 15, 30, 45, 59)


def _hidden_use(seed: int) -> dict[str, float]:
    rng = np.random.default_rng(1000 + seed)
    return {"wear.n_end": float(N_HOLES), "wear.run_in_holes": 12.0,
            "wear.rate_um_per_hole": float(rng.uniform(120, 180)) / N_HOLES,
            "tool_thermal.heat_fraction": float(rng.uniform(0.07, 0.13)),
            "tool_thermal.heat_capacity_j_per_k": float(rng.uniform(2.5, 4.5)),
            "tool_thermal.resistance_k_per_w": float(rng.uniform(5.0, 9.0)),
            "tool_thermal.holder_heat_capacity_j_per_k": float(rng.uniform(40, 120)),
            "tool_thermal.tip_to_holder_k_per_w": float(rng.uniform(6, 14)),
            "tool_thermal.holder_to_ambient_k_per_w": float(rng.uniform(1.5, 3.0)),
            "drilling.lip_height_difference_um": float(rng.uniform(4, 16)),
            "drilling.entry_force_ratio": float(rng.uniform(0.02, 0.05))}


@pytest.fixture(scope="module", params=[3, 11])
def run(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
        ) -> dict[str, Any]:
    seed = int(request.param)
    d = tmp_path_factory.mktemp(f"recovery{seed}")
    hidden = hidden_machine(seed)
    simulate_campaign(d, seed, hidden)
    machine = d / "machine.toml"
    calibrate(d, machine)
    assert cli("simulate", "tool_wear_run", "--out", d / "tw", "--seed", seed,
               *sets({**hidden, **_hidden_use(seed)}), "--option", f"n_holes={N_HOLES}",
               "--option", "dynamometer=false") == 0
    rec_path = d / "tw" / "tool_wear_run"
    truth = pd.read_csv(d / "tw" / "holes.csv")
    assert cli("holes", rec_path, "--machine", machine, "--out", d / "holes.csv") == 0
    assert cli("holes", rec_path, "--out", d / "holes_thesis.csv") == 0  # the default spindle
    measured = ",".join(f"{k}:{truth['wear_um'][k]:.1f}" for k in MEASURED)
    assert cli("wear", rec_path, "--machine", machine, "--measured", measured,
               "--baseline", 6, "--out", d / "wear") == 0
    return {"seed": seed, "dir": d, "machine": machine, "rec_path": rec_path, "truth": truth,
            "holes": pd.read_csv(d / "holes.csv"),
            "holes_thesis": pd.read_csv(d / "holes_thesis.csv"),
            "wear": pd.read_csv(d / "wear" / "wear.csv")}


def _true_window_torque(run: dict[str, Any], holes: pd.DataFrame) -> np.ndarray:
    """The simulator's true cutting torque averaged over each hole's cut window."""
    tr = pd.read_parquet(run["dir"] / "tw" / "truth_per_cycle.parquet",
                         columns=["cycle", "cutting_torque_nm"]).set_index("cycle")
    torque = tr["cutting_torque_nm"]
    return np.array([torque.reindex(range(a, b + 1)).fillna(0.0).mean()
                     for a, b in zip(holes["cut_start_cycle"], holes["cut_end_cycle"],
                                     strict=True)])


def test_cutting_torque_per_hole(run: dict[str, Any]) -> None:
    h, h0 = run["holes"], run["holes_thesis"]
    assert len(h) == N_HOLES
    ref = _true_window_torque(run, h)
    err = np.abs(h["torque_mean_nm"].to_numpy() / ref - 1.0)
    err_thesis = np.abs(h0["torque_mean_nm"].to_numpy() / ref - 1.0)
    assert err.max() < 0.01, err.max()
    assert err.max() < err_thesis.max()


def test_wear_from_five_readings(run: dict[str, Any]) -> None:
    e = run["wear"]["wear_um"].to_numpy() - run["truth"]["wear_um"].to_numpy()
    assert run["truth"]["wear_um"].iloc[-1] > 200.0  # the run reaches a worn tool
    assert float(np.sqrt(np.mean(e**2))) < 20.0


def test_tool_temperature_soft_sensor_on_a_two_node_tool(run: dict[str, Any]) -> None:
    h, truth = run["holes"], run["truth"]
    assert "tool_holder_temperature_extraction_c" in truth  # the holder node is on
    cam = read_thermal_camera_csv(run["dir"] / "tw" / "thermal_camera.csv")
    merged = merge_camera(h, cam)
    camera = merged["camera_temperature_c"].to_numpy(dtype=np.float64)
    calib = np.where(np.arange(len(h)) < 24, camera, np.nan)  # the first 4 sets
    model = ToolThermalModel().fit(merged, calib, fit_ambient=True)
    pred = model.predict(merged)
    rms = float(np.sqrt(np.mean((pred - truth["tool_temperature_camera_c"].to_numpy()) ** 2)))
    assert rms < 10.0, rms


def test_hole_quality_with_the_calibrated_axes(run: dict[str, Any]) -> None:
    rec = read_recording(run["rec_path"])
    mf = load_machine(run["machine"])
    q = hole_quality(rec, hole_record(rec, store=False), machine=mf.machine, drill=Drill())
    t = run["truth"]
    tip = np.abs(q["tip_position_error_est_um"].to_numpy()
                 / t["tip_position_error_um"].to_numpy() - 1.0)
    assert np.median(tip) < 0.12 and tip.max() < 0.25, (np.median(tip), tip.max())
    # each hole within 2 % + 3 of its stated standard errors (the encoders' measuring noise,
    # issue 29; test_quality.py)
    err = np.abs(q["rotating_force_est_n"].to_numpy() - t["rotating_force_n"].to_numpy())
    allowed = 0.02 * t["rotating_force_n"].to_numpy() + 3.0 * q["rotating_force_se_n"].to_numpy()
    assert np.all(err <= allowed), (err, allowed)
