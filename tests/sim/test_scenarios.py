"""Scenarios end to end: files, truth.json, thesis numbers, reproducibility, CLI."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from cnctwin.cli import main
from cnctwin.exceptions import ConfigError
from cnctwin.sim.cutting import THESIS_DRILLING_CUTS
from cnctwin.sim.scenarios import (
    ScenarioConfig,
    air_cut_sweep,
    drilling_validation,
    loose_tap,
    tool_wear_run,
)


@pytest.fixture(scope="module")
def drilling(tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    out = tmp_path_factory.mktemp("drill")
    return out, drilling_validation(out, seed=7)


def test_drilling_validation_dynamometer_means(drilling) -> None:  # type: ignore[no-untyped-def]
    # thesis Table 4.1 / §4.3: mean dynamometer torque over the first 0.6 s of the cut
    out, res = drilling
    truth = json.loads((out / "truth.json").read_text())
    clock = truth["dynamometer"]
    expected = {(m, n, f): t for m, n, f, t in THESIS_DRILLING_CUTS}
    for cut, rec in zip(truth["cuts"], res.recordings, strict=True):
        dyn = rec.external["dynamometer"]
        assert (out / cut["dynamometer_csv"]).exists() and (out / cut["recording"]).exists()
        own = np.asarray(dyn.data.index)
        t_rec = own * (1 + clock["clock_drift_ppm"] * 1e-6) + clock["clock_offset_s"]
        t0 = cut["full_engagement_first_cycle"] * 0.002
        t1 = min(t0 + 0.6, cut["cut_last_cycle"] * 0.002)
        mean = dyn.data["mz_nm"].to_numpy()[(t_rec >= t0) & (t_rec < t1)].mean()
        key = (cut["material"], cut["speed_rpm"], cut["feed_mm_per_rev"])
        assert mean == pytest.approx(expected[key], rel=0.03)


def test_drilling_current_tracks_torque(drilling) -> None:  # type: ignore[no-untyped-def]
    # thesis Table 4.1: measured mean spindle currents 3.66-5.29 A for these cuts
    _, res = drilling
    for cut, rec in zip(res.truth["cuts"], res.recordings, strict=True):
        i = rec.hf["CURRENT|SP1"].to_numpy()
        a = cut["full_engagement_first_cycle"] - int(rec.cycles[0])
        mean_i = i[a:a + 300].mean()
        assert 3.2 < mean_i < 5.6


def test_same_seed_identical_and_overrides_recorded(tmp_path: Path) -> None:
    a = loose_tap(seed=3, n_holes=2, loose_from_hole=1)
    b = loose_tap(seed=3, n_holes=2, loose_from_hole=1)
    np.testing.assert_array_equal(a.recording.hf["CURRENT|SP1"], b.recording.hf["CURRENT|SP1"])
    c = loose_tap(tmp_path, seed=3, n_holes=2, loose_from_hole=1,
                  overrides={"spindle.kt_nm_per_a": 1.1})
    truth = json.loads((tmp_path / "truth.json").read_text())
    assert truth["machine"]["spindle"]["kt_nm_per_a"] == 1.1
    assert not np.array_equal(a.recording.hf["CURRENT|SP1"], c.recording.hf["CURRENT|SP1"])
    with pytest.raises(ConfigError, match="unknown override"):
        ScenarioConfig.build({"drill.colour": "red"})


def test_loose_tap_fluctuates_on_extraction() -> None:
    # thesis §5.4 / Fig. 5.10: fluctuations in torque, current and Z position on extraction
    res = loose_tap(seed=1, n_holes=3, loose_from_hole=2)
    onset = res.truth["fault_onsets_s"][0]
    assert onset is not None
    rec = res.recording
    t = rec.time_s
    z_err = (rec.hf["ENC_POS|Z1"] - rec.hf["DES_POS|Z1"]).to_numpy()
    cur = rec.hf["CURRENT|SP1"].to_numpy()
    after = (t >= onset + 0.15) & (t < onset + 0.6)  # after the reversal transient
    period = rec.duration_s / 3 + 0.002  # holes are identical: same phase of the previous hole
    before = (t >= onset - period + 0.15) & (t < onset - period + 0.6)
    assert np.std(np.diff(z_err[after])) > 5 * np.std(np.diff(z_err[before]))
    assert np.std(np.diff(cur[after])) > 2 * np.std(np.diff(cur[before]))


def test_tool_wear_run_streams_sets_and_camera(tmp_path: Path) -> None:
    res = tool_wear_run(tmp_path, seed=2, n_holes=12)
    assert len(list(tmp_path.glob("wear_set_*.json"))) == 2
    assert len(list(tmp_path.glob("dynamometer_set_*.csv"))) == 2
    cam = res.recordings[-1].external["thermal_camera"].data
    assert len(cam) == 12
    temps = [h["tool_temperature_extraction_c"] for h in res.truth["holes"]]
    # thesis Fig. 5.5: tool tip temperature rises through each set of 6 (+~300 degC)
    assert np.all(np.diff(temps[:6]) > 0) and np.all(np.diff(temps[6:]) > 0)
    assert temps[5] == pytest.approx(325.0, abs=75.0)
    assert (tmp_path / "holes.csv").exists() and (tmp_path / "thermal_camera.csv").exists()


def test_air_cut_sweep_and_cli(tmp_path: Path) -> None:
    res = air_cut_sweep(n_speeds=5, max_speed_rpm=9000, dwell_s=1.0)
    assert len(res.truth["steps"]) == 5
    assert set(res.recording.lf["signal"]) >= {"MOTOR_TEMP|SP1", "IQ_ACT|SP1"}
    code = main(["simulate", "air_cut_sweep", "--out", str(tmp_path), "--seed", "1",
                 "--set", "spindle.pole_count=6", "--option", "n_speeds=3",
                 "--option", "dwell_s=0.5"])
    assert code == 0
    truth = json.loads((tmp_path / "truth.json").read_text())
    assert truth["machine"]["spindle"]["pole_count"] == 6
    assert (tmp_path / "air_cut_sweep.json").exists()
