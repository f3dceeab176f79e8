"""Issue 25 acceptance, through the command line only, on a hidden machine and material.

The spindle (Kt, friction, inertia: ``random_spindle_overrides``) and the six milling
coefficients (+-30 % around the library's AISI 1045) are drawn at random and hidden in the
simulator (``--set``); the machine file is what ``cnctwin calibrate spindle`` makes of an
air cut and one reference cut. A calibration program
(slots and side steps at four feeds per tooth) is simulated and ``cnctwin calibrate
material`` fits the coefficients into the machine file; a pocket program at a conservative
feed (slot, side steps, corners, air moves; a different program) is optimized with them and
the optimized program is simulated on the hidden material. Tolerances: 5 % on each
coefficient, >= 25 % shorter, no limit
exceeded; a program already at its limits changes its feeds by <= 3 %.
"""

from __future__ import annotations

import json
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

from cnctwin.cli import main
from cnctwin.sim.scenarios import random_spindle_overrides

SPEEDS = list(range(200, 5001, 400)) + list(range(4600, 199, -400))
REFERENCE = "drill_1_aisi1045_2400rpm_0p16"
KEYS = ("ktc_n_per_mm2", "krc_n_per_mm2", "kac_n_per_mm2", "kte_n_per_mm", "kre_n_per_mm",
        "kae_n_per_mm")
LIBRARY = (1931.0, 755.7, 645.4, 56.58, 25.51, 21.91)

TOOLS = """
[tools.1]
kind = "drill"
diameter_mm = 8.5

[tools.2]
kind = "end_mill"
diameter_mm = 16
flutes = 2
helix_deg = 30
max_chip_mm = 0.15
"""

CALIBRATION = """; slots and side steps at four feeds per tooth, 3000 rpm
G90 G17 G94 G64
T2 M6
S3000 M3
G0 X-12 Y10 Z5
G0 Z-2
G1 X30 F180
G1 X70 F360
G1 X110 F540
G1 X150 F720
G0 Z5
G0 X-12 Y30
G0 Z-3
G1 X30 F240
G1 X70 F480
G1 X110 F720
G1 X150 F900
G0 Z5
G0 X-12 Y16
G0 Z-2
G1 X30 F300
G1 X70 F600
G1 X110 F900
G1 X150 F1200
G0 Z5
G0 X-12 Y40
G0 Z-3
G1 X40 F300
G1 X80 F600
G1 X150 F900
G0 Z50
M30
"""
CAL_STOCK = "0,0,-30,160,60,0"

POCKET = """; pocket 60 x 24 x 6 mm in three levels and a deep slot, at a conservative feed
G90 G17 G94 G64
T2 M6
S2400 M3
G0 X-12 Y10 Z5
G0 Z-2
G1 X70 F250
G1 Y18 F250
G1 X10 F250
G1 Y24 F250
G2 X16 Y30 CR=6 F250
G1 X70 F250
G0 Z5
G0 X-12 Y10
G0 Z-4
G1 X70 F250
G1 Y18 F250
G1 X10 F250
G1 Y24 F250
G1 X70 F250
G0 Z5
G0 X-12 Y10
G0 Z-6
G1 X70 F250
G1 Y24 F250
G1 X10 F250
G0 Z5
; a deep slot: the spindle's S1 torque binds before the chip does
G0 X-12 Y42
G0 Z-10
G1 X70 F250
G0 Z50
M30
"""
POCKET_STOCK = "0,0,-30,80,50,0"


def _run(args: list[str]) -> None:
    assert main(args) == 0, args


def _feeds(text: str) -> dict[int, float]:
    """Feed of each G1/G2/G3 line that is not an inserted piece."""
    out = {}
    for i, line in enumerate(text.splitlines(), start=1):
        m = re.search(r"\bF(\d+\.?\d*)", line)
        if m and re.match(r"G[123]\b", line) and "cnctwin" not in line:
            out[i] = float(m.group(1))
    return out


@pytest.fixture(scope="module")
def hidden(tmp_path_factory: pytest.TempPathFactory) -> dict[str, object]:
    """Hidden spindle (random_spindle_overrides) and hidden material; the machine file is the
    spindle calibration a user makes (air cut + one reference cut with a dynamometer)."""
    tmp = tmp_path_factory.mktemp("opt")
    rng = np.random.default_rng(2025)
    truth = {k: float(b * rng.uniform(0.7, 1.3)) for k, b in zip(KEYS, LIBRARY, strict=True)}
    spindle = [a for k, v in random_spindle_overrides(25).items() for a in ("--set", f"{k}={v}")]
    sets = spindle + [a for k, v in truth.items()
                      for a in ("--set", f"material.aisi1045.milling.{k}={v}")]
    (tmp / "tools.toml").write_text(TOOLS)
    (tmp / "cal.mpf").write_text(CALIBRATION)
    (tmp / "pocket.mpf").write_text(POCKET)
    machine = tmp / "m.toml"
    _run(["simulate", "air_cut_sweep", "--out", str(tmp / "ac"), "--seed", "25", *spindle,
          "--option", f"speeds_rpm={SPEEDS}"])
    _run(["simulate", "drilling_validation", "--out", str(tmp / "dv"), "--seed", "25",
          *spindle, "--option", 'cuts=[["aisi1045", 2400, 0.16]]'])
    _run(["calibrate", "spindle", "--air-cut", str(tmp / "ac" / "air_cut_sweep.json"),
          "--reference", str(tmp / "dv" / f"{REFERENCE}.json"), "--dynamometer",
          str(tmp / "dv" / f"dynamometer_{REFERENCE[6:]}.csv"), "--machine", str(machine)])
    _run(["simulate", "--program", str(tmp / "cal.mpf"), "--material", "aisi1045", "--tools",
          str(tmp / "tools.toml"), "--stock", CAL_STOCK, "--machine", str(machine), "--seed",
          "7", "--out", str(tmp / "cal"), *sets])
    _run(["calibrate", "material", str(tmp / "cal" / "cal.json"), "--material", "aisi1045",
          "--program", str(tmp / "cal.mpf"), "--tools", str(tmp / "tools.toml"), "--stock",
          CAL_STOCK, "--machine", str(machine)])
    _run(["optimize", str(tmp / "pocket.mpf"), "--machine", str(machine), "--material",
          "aisi1045", "--tools", str(tmp / "tools.toml"), "--stock", POCKET_STOCK, "--out",
          str(tmp / "opt")])
    for name, prog in (("before", tmp / "pocket.mpf"), ("after", tmp / "opt" / "optimized.mpf")):
        _run(["simulate", "--program", str(prog), "--material", "aisi1045", "--tools",
              str(tmp / "tools.toml"), "--stock", POCKET_STOCK, "--machine", str(machine),
              "--seed", "8", "--out", str(tmp / name), *sets])
    return {"tmp": tmp, "truth": truth, "sets": sets}


def test_calibrate_material_recovers_the_hidden_coefficients(hidden: dict[str, object]) -> None:
    """Each of the six within 5 % (the issue's tolerance) and within 4 standard errors plus
    2 % (the engagement's discretisation: 2 deg bins, 0.2 mm cells)."""
    tmp = hidden["tmp"]
    truth = hidden["truth"]
    assert isinstance(tmp, Path) and isinstance(truth, dict)
    doc = tomllib.loads((tmp / "m.toml").read_text())
    mill = doc["materials"]["aisi1045"]["milling"]
    for k in KEYS:
        rec = mill[k]
        assert "uncertainty" in rec and rec["provenance"]["method"].startswith("cnctwin")
        assert rec["value"] == pytest.approx(truth[k], rel=0.05), k
        assert abs(rec["value"] - truth[k]) <= 4 * rec["uncertainty"] + 0.02 * truth[k], k


def test_the_optimized_program_is_faster_and_within_every_limit(
        hidden: dict[str, object]) -> None:
    tmp = hidden["tmp"]
    assert isinstance(tmp, Path)
    before = json.loads((tmp / "before" / "truth.json").read_text())["limits"]
    after = json.loads((tmp / "after" / "truth.json").read_text())["limits"]
    assert after["cycle_time_s"] <= 0.75 * before["cycle_time_s"]
    assert after["warnings"] == []
    chip = after["tools"]["T2"]["chip_mm"]
    assert chip["peak"] <= chip["limit"]
    rep = json.loads((tmp / "opt" / "optimize.json").read_text())
    assert rep["violations"] == []
    assert rep["cycle_time_s"]["optimized"] < rep["cycle_time_s"]["programmed"]
    binds = {ln["binding"] for ln in rep["lines"]}
    assert {"chip thickness", "spindle S1 torque"} <= binds
    assert binds <= {
        "chip thickness", "spindle S1 torque", "spindle S1 power", "spindle peak torque",
        "tool torque", "force per tooth", "axis current", "machine feed", "air"}
    # only F changed: every original line is still there without its F word
    original = [re.sub(r"\s*F\d+\.?\d*", "", ln).strip()
                for ln in (tmp / "pocket.mpf").read_text().splitlines()]
    new = [re.sub(r"\s*F\d+\.?\d*", "", ln).strip()
           for ln in (tmp / "opt" / "optimized.mpf").read_text().splitlines()
           if "cnctwin: line" not in ln]
    assert new == original
    assert (tmp / "opt" / "report.html").stat().st_size > 10_000


def test_a_program_at_its_limits_keeps_its_feeds(hidden: dict[str, object]) -> None:
    tmp = hidden["tmp"]
    assert isinstance(tmp, Path)
    _run(["optimize", str(tmp / "opt" / "optimized.mpf"), "--machine", str(tmp / "m.toml"),
          "--material", "aisi1045", "--tools", str(tmp / "tools.toml"), "--stock",
          POCKET_STOCK, "--out", str(tmp / "again"), "--no-verify"])
    first = _feeds((tmp / "opt" / "optimized.mpf").read_text())
    second = _feeds((tmp / "again" / "optimized.mpf").read_text())
    cut = {k: v for k, v in first.items() if v < 20000}  # the cutting lines
    assert cut
    for line, f in cut.items():
        assert second[line] == pytest.approx(f, rel=0.03), line


@pytest.mark.parametrize(("change", "message"), [
    ({"tools": '[tools.1]\nkind = "drill"\ndiameter_mm = 8.5\n'},
     "line 3: 'T2 M6': T2 is not in the tool table"),
    ({"stock": None}, "p.mpf: give --stock: the optimizer needs the raw part"),
    ({"material": "[kienzle]\nkc1_n_per_mm2 = 1500\nmc = 0.2\n"}, "no [milling] table"),
    ({"program": "G90 G18\nM30\n"}, "line 1"),
])
def test_bad_input_is_one_line_and_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                          change: dict[str, str | None], message: str) -> None:
    (tmp_path / "tools.toml").write_text(change.get("tools") or TOOLS)
    (tmp_path / "p.mpf").write_text(change.get("program") or POCKET)
    mat = "aisi1045"
    if "material" in change:
        (tmp_path / "m.toml").write_text(change["material"] or "")
        mat = str(tmp_path / "m.toml")
    args = ["optimize", str(tmp_path / "p.mpf"), "--material", mat, "--tools",
            str(tmp_path / "tools.toml"), "--out", str(tmp_path / "o"), "--no-verify"]
    if "stock" not in change:
        args += ["--stock", POCKET_STOCK]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


def test_optimize_json_carries_the_torque_the_adaptive_feed_holds(
        hidden: dict[str, object], tmp_path: Path) -> None:
    """Every cutting piece of optimize.json carries the mean cutting torque planned at its new
    feed (issue 26: the adaptive feed's target ``target_from``). The first slot (Y10, 2 mm
    deep into fresh stock, 0..pi immersion) by the closed form with the *hidden* coefficients
    (Altintas eq. 2.47 for a full slot: T = z a r / (2 pi) (Kte pi + Ktc 2 c)): within 5 %
    (the calibration's own error is below 3.5 %)."""
    from cnctwin.edge.adaptive import planned_torque, read_adaptive_config

    tmp = hidden["tmp"]
    truth = hidden["truth"]
    assert isinstance(tmp, Path) and isinstance(truth, dict)
    rep = json.loads((tmp / "opt" / "optimize.json").read_text())
    first = rep["lines"][0]
    assert first["text"].startswith("G1 X70")
    piece = max(first["pieces"], key=lambda p: p["length_mm"])  # the steady full slot
    assert piece["tool"] == 2
    c = piece["feed_mm_min"] / (2400.0 * 2)
    z, a, r = 2, 2.0, 8.0
    expected = z * a * r / (2.0 * np.pi) * (truth["kte_n_per_mm"] * np.pi
                                            + truth["ktc_n_per_mm2"] * 2.0 * c) / 1000.0
    assert piece["cutting_torque_nm"] == pytest.approx(expected, rel=0.05)
    # the adaptive configuration reads it per tool (length-weighted over the tool's cuts)
    torques = [p["cutting_torque_nm"] for ln in rep["lines"] for p in ln["pieces"]
               if p.get("cutting_torque_nm")]
    target = planned_torque(tmp / "opt" / "optimize.json", 2)
    assert min(torques) <= target <= max(torques)
    cfg = tmp_path / "adaptive.toml"
    cfg.write_text(f'[tools.2]\ntarget_from = "{tmp / "opt" / "optimize.json"}"\n')
    assert read_adaptive_config(cfg).tools[2]["target_nm"] == pytest.approx(target)
    cfg.write_text(f'[tools.1]\ntarget_from = "{tmp / "opt" / "optimize.json"}"\n')
    with pytest.raises(Exception, match="plans no cut with T1"):
        read_adaptive_config(cfg)
