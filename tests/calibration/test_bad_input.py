"""Bad input to the own-machine workflow: one clear message, exit 2, nothing half-written."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from tests.calibration._campaign import REFERENCE, cli

DATA = Path(__file__).resolve().parents[1] / "data" / "real"
TRACE = DATA / "sinumerik-trace" / "Tav23362_2140_frenata_15_4_26_EmgTest.xml"
pytestmark = pytest.mark.xdist_group("calibration_bad_input")


@pytest.fixture(scope="module")
def campaign(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("bad")
    assert cli("simulate", "air_cut_sweep", "--out", d / "one", "--option",
               "speeds_rpm=[2400]") == 0
    assert cli("simulate", "air_cut_sweep", "--out", d / "ac", "--option",
               "speeds_rpm=[400, 800, 1200, 1600, 2000, 2400, 2800, 3200]") == 0
    assert cli("simulate", "drilling_validation", "--out", d / "dv", "--option",
               'cuts=[["aisi1045", 2400, 0.16]]') == 0
    return d


def _err(capsys: pytest.CaptureFixture[str], *args: object) -> str:
    code = cli(*args)
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err
    return err


def test_too_few_plateaus_says_what_to_record(campaign: Path, tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    m = tmp_path / "m.toml"
    err = _err(capsys, "calibrate", "spindle", "--air-cut", campaign / "one" /
               "air_cut_sweep.json", "--reference", campaign / "dv" / f"{REFERENCE}.json",
               "--dynamometer", campaign / "dv" / f"dynamometer_{REFERENCE[6:]}.csv",
               "--machine", m)
    assert "need at least 6 constant-speed plateaus between 500 and 7000 rpm" in err
    assert "found 1 at 2400 rpm" in err
    assert "air_cut_sweep.json" in err
    assert not m.exists() and not list(tmp_path.iterdir())


def test_dynamometer_without_overlap(campaign: Path, tmp_path: Path,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    csv = campaign / "dv" / f"dynamometer_{REFERENCE[6:]}.csv"
    lines = csv.read_text(encoding="utf-8").splitlines()
    short = tmp_path / "short.csv"
    short.write_text("\n".join(lines[:1000]) + "\n", encoding="utf-8")  # 1 s, before the cut
    m = tmp_path / "m.toml"
    err = _err(capsys, "calibrate", "spindle", "--air-cut", campaign / "ac" /
               "air_cut_sweep.json", "--reference", campaign / "dv" / f"{REFERENCE}.json",
               "--dynamometer", short, "--machine", m)
    assert "does not overlap the cut" in err
    assert not m.exists()


def test_reference_without_torque(campaign: Path, tmp_path: Path,
                                  capsys: pytest.CaptureFixture[str]) -> None:
    err = _err(capsys, "calibrate", "spindle", "--air-cut", campaign / "ac" /
               "air_cut_sweep.json", "--reference", campaign / "dv" / f"{REFERENCE}.json",
               "--machine", tmp_path / "m.toml")
    assert "--dynamometer CSV or --torque-nm VALUE" in err


def test_recording_without_spindle_signals(campaign: Path, tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    err = _err(capsys, "calibrate", "spindle", "--air-cut", TRACE, "--reference",
               campaign / "dv" / f"{REFERENCE}.json", "--torque-nm", "3.9",
               "--machine", tmp_path / "m.toml")
    assert "SP1" in err and str(TRACE.name) in err
    assert not (tmp_path / "m.toml").exists()


def test_axes_on_a_recording_where_nothing_moves(campaign: Path, tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    err = _err(capsys, "calibrate", "axes", campaign / "one" / "air_cut_sweep.json",
               "--machine", tmp_path / "m.toml")
    assert "no feed axis moves" in err
    assert not (tmp_path / "m.toml").exists()


def test_damaged_machine_file_is_left_as_it_was(campaign: Path, tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    m = tmp_path / "m.toml"
    m.write_text("[spindle]\nkt_nm_per_a = { value = 1.0, unit = \"Nm/A\"\n", encoding="utf-8")
    before = m.read_bytes()
    err = _err(capsys, "calibrate", "spindle", "--air-cut", campaign / "ac" /
               "air_cut_sweep.json", "--reference", campaign / "dv" / f"{REFERENCE}.json",
               "--dynamometer", campaign / "dv" / f"dynamometer_{REFERENCE[6:]}.csv",
               "--machine", m)
    assert str(m) in err and "not valid TOML" in err
    assert m.read_bytes() == before
    m.write_text("[axes.X1]\nkv_m_min_per_mm = 250.0\n", encoding="utf-8")
    err = _err(capsys, "twin", "compare", campaign / "ac" / "air_cut_sweep.json", "--machine",
               m, "--out", tmp_path / "cmp")
    assert "axes.X1.kv_m_min_per_mm = 250.0 is out of range; allowed 0.05 ... 20" in err
    assert not (tmp_path / "cmp").exists()


def test_unsupported_gcode_word_names_line_and_word(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    prog = tmp_path / "part.mpf"
    prog.write_text("G90 G94\nG1 X10 F1000\nG5 X3 Y4\nM30\n", encoding="utf-8")
    err = _err(capsys, "simulate", "--program", prog, "--out", tmp_path / "out")
    assert "part.mpf" in err and "line 3" in err and "G5" in err
    assert not (tmp_path / "out").exists()


def test_a_real_process_prints_one_line_and_exits_2(tmp_path: Path) -> None:
    bad = tmp_path / "m.toml"
    bad.write_text("colour = 1\n", encoding="utf-8")
    r = subprocess.run([sys.executable, "-m", "cnctwin", "twin", "compare", str(bad),
                        "--machine", str(bad), "--out", str(tmp_path / "o")],
                       capture_output=True, text=True, check=False)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    assert r.stderr.strip().count("\n") == 0 and "unknown keys ['colour']" in r.stderr
