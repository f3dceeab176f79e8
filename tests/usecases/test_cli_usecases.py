"""``cnctwin holes|wear|anomalies`` through the entry point on simulated recordings."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pandas as pd
import pytest

from cnctwin.cli import main
from cnctwin.sim.scenarios import tool_wear_run


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    out = tmp_path_factory.mktemp("cliwear")
    res = tool_wear_run(out, n_holes=12, seed=7, fmt="c4a")
    return out, res.truth


def _files(d: Path) -> list[str]:
    # the wear run is one recording (Parquet chunk directory); older layouts: one file per set
    files = sorted(d.glob("wear_set_*.json")) or sorted(d.glob("tool_wear_run*.json"))
    return [str(p) for p in files]


def test_holes(run_dir, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:  # type: ignore[no-untyped-def]
    d, _ = run_dir
    csv = tmp_path / "holes.csv"
    figs = tmp_path / "figs"
    assert main(["holes", *_files(d), "--out", str(csv), "--figures", str(figs)]) == 0
    out = capsys.readouterr().out
    assert "12 holes" in out
    h = pd.read_csv(csv)
    assert list(h["hole"]) == list(range(12))
    assert list(h["set"]) == [0] * 6 + [1] * 6
    assert sorted(p.name for p in figs.iterdir()) == [
        "deviation_3d.png", "deviation_xy.png", "deviation_xz.png", "deviation_yz.png",
        "hole_means.png"]


def test_wear(run_dir, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:  # type: ignore[no-untyped-def]
    d, truth = run_dir
    w = {r["hole"]: r["wear_um"] for r in truth["holes"]}
    measured = ",".join(f"{h}:{w[h]:.2f}" for h in (5, 11))
    code = main(["wear", *_files(d), "--measured", measured, "--baseline", "6",
                 "--out", str(tmp_path)])
    assert code == 0
    out = capsys.readouterr().out
    assert "estimated wear at the last hole" in out
    t = pd.read_csv(tmp_path / "wear.csv")
    assert "wear_um" in t.columns and len(t) == 12
    assert (tmp_path / "wear_trend.png").exists()
    assert main(["wear", *_files(d)]) == 0
    assert "--measured" in capsys.readouterr().out


def test_wear_bad_measured(run_dir, capsys: pytest.CaptureFixture[str]) -> None:  # type: ignore[no-untyped-def]
    d, _ = run_dir
    assert main(["wear", *_files(d), "--measured", "5=40"]) == 2
    assert "HOLE:UM" in capsys.readouterr().err
    assert main(["wear", *_files(d), "--measured", "500:40"]) == 2
    assert "not in the record" in capsys.readouterr().err


@pytest.mark.parametrize("detector", ["envelope", "physics", "spectral"])
def test_anomalies(run_dir, tmp_path: Path, detector: str,  # type: ignore[no-untyped-def]
                   capsys: pytest.CaptureFixture[str]) -> None:
    d, _ = run_dir
    code = main(["anomalies", *_files(d), "--detector", detector, "--learn-s", "40",
                 "--out", str(tmp_path)])
    assert code == 0
    out = capsys.readouterr().out
    assert "anomaly replay" in out
    assert (tmp_path / f"anomalies_{detector}.png").exists()
    assert (tmp_path / "alarms.csv").exists()


@pytest.mark.parametrize("detector", ["adaptive", "physics-torque"])
def test_anomalies_wear_adaptive_fault_free(run_dir, tmp_path: Path,  # type: ignore[no-untyped-def]
                                            detector: str) -> None:
    # fault-free 12-hole run: no alarm (physics-torque scores from the first hole, no teach-in)
    d, _ = run_dir
    assert main(["anomalies", *_files(d), "--detector", detector, "--out", str(tmp_path)]) == 0
    assert len(pd.read_csv(tmp_path / "alarms.csv")) == 0
    assert (tmp_path / f"anomalies_{detector}.png").exists()


def test_missing_file(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["holes", "/nonexistent/x.json"]) == 2
    assert "not found" in capsys.readouterr().err


def test_anomalies_tapping_on_simulated_loose_tap(tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    from cnctwin.sim.scenarios import loose_tap

    # tap loose from hole 3 of 5 (0-based); teach-in on the first 2 holes (~8.7 s)
    res = loose_tap(tmp_path / "sim", seed=2, n_holes=5, loose_from_hole=3)
    onset = res.truth["fault_onsets_s"][0]
    code = main(["anomalies", str(tmp_path / "sim" / "loose_tap.json"), "--detector",
                 "tapping", "--learn-s", "8.7", "--out", str(tmp_path / "a")])
    assert code == 0
    alarms = pd.read_csv(tmp_path / "a" / "alarms.csv")
    # first alarm within 0.3 s of the hidden onset (docs/validation-usecases.md: 0.16-0.17 s);
    # none before it; then one per loose extraction (holes 3 and 4)
    assert len(alarms) == 2
    assert onset < alarms["alarm_s"].iloc[0] < onset + 0.3
    assert "anomaly replay" in capsys.readouterr().out


REAL = Path(__file__).parents[1] / "data" / "real"


def test_cli_on_real_files(capsys: pytest.CaptureFixture[str]) -> None:
    # the real Capture4Analysis example holds no drilling: holes reports no hole (exit 2) or,
    # should the segmentation find plunges, prints the table (exit 0); it must not crash
    c4a = REAL / "capture4analysis" / "example_data_ff429d74-6482-4d4f-80e1-31419d9bd56c.json"
    code = main(["holes", str(c4a)])
    cap = capsys.readouterr()
    assert (code == 2 and "no hole found" in cap.err) or (code == 0 and "holes" in cap.out)
    # the UMich mill (10 Hz, no spindle speed the reader maps): the spectral detector scales its
    # band to the sampling rate; unfinished experiment 4 replays without error
    exp4 = REAL / "umich-cnc-mill" / "experiment_04.csv"
    assert main(["anomalies", str(exp4), "--detector", "spectral"]) == 0
    out = capsys.readouterr().out
    assert "spindle speed NaN" in out
    assert "band_hz=(0.4, 4.8)" in out


@pytest.mark.parametrize(("detector", "needs"), [
    ("physics", "predicted_current_a"),
    ("tapping", "speed_rpm"),
])
def test_a_detector_without_its_input_says_not_scored(
        detector: str, needs: str, capsys: pytest.CaptureFixture[str]) -> None:
    """UMich records no spindle speed the reader maps: physics and tapping cannot judge it.
    Before, both returned a score of exactly 0 on every sample and reported '0 alarms'."""
    exp1 = REAL / "umich-cnc-mill" / "experiment_01.csv"
    code = main(["anomalies", str(exp1), "--detector", detector])
    err = capsys.readouterr().err
    assert code == 2
    assert "not scored" in err and needs in err and "spindle speed" in err
    assert "alarms" not in err and "Traceback" not in err


def test_replay_refuses_a_stream_without_a_needed_input() -> None:
    import numpy as np

    from cnctwin.exceptions import NotScoredError
    from cnctwin.usecases.replay import _check_inputs, make_detector

    data = pd.DataFrame({"current_a": np.ones(10), "predicted_current_a": np.full(10, np.nan),
                         "speed_rpm": np.full(10, 2400.0)})
    with pytest.raises(NotScoredError, match="predicted_current_a"):
        _check_inputs(make_detector("physics", fs_hz=500.0), "physics", data)
    data["predicted_current_a"] = 1.0
    _check_inputs(make_detector("physics", fs_hz=500.0), "physics", data)  # finite: scored


def test_physics_prediction_says_whose_spindle_it_uses(run_dir, tmp_path: Path,  # type: ignore[no-untyped-def]
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    """Without a machine file the prediction uses the thesis machine and says so; with one,
    the machine's calibrated spindle (issue 13: never the thesis machine silently)."""
    from cnctwin.machine import MachineFile, ParameterRecord, Provenance, save_machine

    d, _ = run_dir
    assert main(["anomalies", *_files(d), "--detector", "physics"]) == 0
    assert "not calibrated to this machine" in capsys.readouterr().out
    m = tmp_path / "m.toml"
    prov = Provenance.now("test", ["air.json", "cut.json"])
    save_machine(MachineFile().with_records(
        {"spindle.kt_nm_per_a": ParameterRecord(1.04, 0.004, prov)}), m)
    assert main(["anomalies", *_files(d), "--detector", "physics", "--machine", str(m)]) == 0
    assert "not calibrated to this machine" not in capsys.readouterr().out
    bare = tmp_path / "bare.toml"
    save_machine(MachineFile(), bare)
    assert main(["anomalies", *_files(d), "--detector", "physics", "--machine",
                 str(bare)]) == 2
    assert "the spindle is not calibrated" in capsys.readouterr().err
