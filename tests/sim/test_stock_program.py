"""A user's program with a tool table and a stock, through ``cnctwin simulate`` (issue 25.1-2).

Truths compared with: the closed-form slot torque T = z a R / (2 pi) [Ktc c 2 + Kte pi]
(Altintas eq. 2.47) with the material's coefficients; the thesis drilling torque 3.97 Nm at
2400 rpm 0.16 mm/rev in AISI 1045 (thesis §4.3); the machine file's tool-change time.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cnctwin.cli import main
from cnctwin.engagement import parse_stock
from cnctwin.machine import read_tool_table
from cnctwin.sim.cutting import MATERIALS
from cnctwin.sim.programs import PRODUCTION_TOOLS
from cnctwin.sim.scenarios import part_program

TOOLS = """
[tools.1]
kind = "drill"
diameter_mm = 8.5

[tools.2]
kind = "end_mill"
diameter_mm = 16
flutes = 2
helix_deg = 30
max_chip_mm = 0.2
"""

MIXED = """; mill a slot and a side step, then drill two holes
G90 G17 G94
T2 M6
S3000 M3
G0 X-12 Y20 Z5
G0 Z-2
G1 X70 F600
G1 Y23
G1 X-12
G0 Z10
T1 M6
S2400 M3
G95 F0.16
MCALL CYCLE81(10, 0, 2, -20)
X20 Y60
X40 Y60
MCALL
G0 Z50
M30
"""


@pytest.fixture
def files(tmp_path: Path) -> tuple[Path, Path]:
    (tmp_path / "tools.toml").write_text(TOOLS)
    (tmp_path / "mixed.mpf").write_text(MIXED)
    return tmp_path / "mixed.mpf", tmp_path / "tools.toml"


def test_a_program_that_mills_and_drills_simulates_both(files: tuple[Path, Path]) -> None:
    prog, tools = files
    res = part_program(None, program=prog, material="aisi1045", tools=read_tool_table(tools),
                       stock=parse_stock("-20,0,-30,80,80,0"), seed=3)
    t = pd.concat(res.per_cycle)
    tool = t["tool"].to_numpy()
    torque = t["cutting_torque_nm"].to_numpy()
    imm = t["radial_immersion"].to_numpy()
    k = MATERIALS["aisi1045"].milling
    assert k is not None
    c = 600.0 / (3000.0 * 2)
    slot = 2 * 2.0 * 8.0 / (2 * math.pi) * (k.ktc_n_per_mm2 * c * 2 + k.kte_n_per_mm * math.pi)
    sel = (tool == 2) & (imm > 0.999)
    assert sel.sum() > 2000
    # mean over whole revolutions of the instantaneous model: within 3 % of the closed form
    assert np.nanmean(torque[sel]) == pytest.approx(slot / 1000.0, rel=0.03)
    # the side step (3 mm of 16, material on the left going -X... both directions) is partial
    side = (tool == 2) & (imm > 0.05) & (imm < 0.5)
    assert side.sum() > 1000
    assert np.nanmedian(imm[side]) == pytest.approx(3.0 / 16.0, abs=0.03)
    # the drill drills: two holes at the thesis torque (3.97 Nm, 10 % for the model's scatter)
    holes = res.truth["holes"]
    assert [h["tool"] for h in holes] == [1, 1]
    assert holes[0]["mean_cutting_torque_nm"] == pytest.approx(3.97, rel=0.10)


def test_cli_simulates_with_tools_and_a_negative_stock_corner(
        files: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    prog, tools = files
    out = tmp_path / "out"
    code = main(["simulate", "--program", str(prog), "--material", "aisi1045", "--tools",
                 str(tools), "--stock", "-20,0,-30,80,80,0", "--out", str(out)])
    assert code == 0
    truth = json.loads((out / "truth.json").read_text())
    assert truth["process"] == "stock" and truth["stock"] == "-20,0,-30,80,80,0"
    assert set(truth["tools"]) == {"1", "2"}
    assert truth["limits"]["cycle_time_s"] > 0


@pytest.mark.parametrize(("table", "message"), [
    ('[tools.2]\nkind = "end_mill"\ndiameter = 16\n', "did you mean 'diameter_mm'"),
    ('[tools.2]\nkind = "end_mill"\ndiameter_mm = 16\n', "lacks flutes, helix_deg, max_chip_mm"),
    ('[tools.2]\nkind = "reamer"\ndiameter_mm = 16\n', "kind must be one of"),
    ('[tools.1]\nkind = "drill"\ndiameter_mm = 8.5\n', "line 3: 'T2 M6': T2 is not in the tool"),
])
def test_bad_tool_tables_name_file_tool_and_key(
        files: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str],
        table: str, message: str) -> None:
    prog, tools = files
    tools.write_text(table)
    code = main(["simulate", "--program", str(prog), "--material", "aisi1045", "--tools",
                 str(tools), "--stock", "-20,0,-30,80,80,0", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2
    assert message in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


def test_stock_without_tools_and_a_material_file_without_milling(
        files: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    prog, _ = files
    assert main(["simulate", "--program", str(prog), "--material", "aisi1045", "--stock",
                 "0,0,-30,80,80,0", "--out", str(tmp_path / "o")]) == 2
    assert "--stock needs --tools" in capsys.readouterr().err
    mat = tmp_path / "m.toml"
    mat.write_text("[milling]\nktc_n_per_mm2 = 1000\n")
    assert main(["simulate", "--program", str(prog), "--material", str(mat), "--out",
                 str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "milling lacks krc_n_per_mm2" in err and str(mat) in err


def test_every_library_material_mills(tmp_path: Path) -> None:
    prog = tmp_path / "slot.mpf"
    prog.write_text("G90 G94\nT2 M6\nS3000 M3\nG0 X-10 Y0 Z-1\nG1 X40 F600\nG0 Z10\nM30\n")
    for name in MATERIALS:
        res = part_program(None, program=prog, material=name)
        t = pd.concat(res.per_cycle)
        assert np.nanmax(t["cutting_torque_nm"].to_numpy()) > 0.2, name


def test_a_tool_change_stops_the_spindle_and_takes_its_time(tmp_path: Path) -> None:
    text = "G90 G94\nT1 M6\nS3000 M3\nG4 F1\nT2 M6\nS2400 M3\nG4 F1\nM30\n"
    prog = tmp_path / "tc.mpf"
    prog.write_text(text)
    res = part_program(None, program=prog)
    rec = res.recording
    speed = rec.signal("CMD_SPEED", "SP1").to_numpy()
    ev = rec.events[rec.events["kind"] == "block"]
    t6 = float(ev[ev["gcode"].str.contains("T2 M6")]["cycle"].iloc[0])
    t_s = float(ev[ev["gcode"].str.contains("S2400")]["cycle"].iloc[0])
    # the change waits for the spindle to stop (3000 rpm at the ramp) and then 4 s (default)
    assert (t_s - t6) * 0.002 >= 4.0
    i = int(np.searchsorted(rec.cycles, t_s))
    assert abs(speed[i - 5]) < 50.0  # stopped before the new tool starts


def test_limits_compare_ratings_with_what_they_rate(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    """A run-up peaks above the S1 torque for < 1 s: no warning; a 13 s slot at 15 mm depth
    in steel (closed form ~29 Nm + friction > 25 Nm S1) warns, naming its line."""
    runup = tmp_path / "runup.mpf"
    runup.write_text("G90 G94\nT1 M6\nS3000 M3\nG4 F2\nM30\n")
    assert main(["simulate", "--program", str(runup), "--out", str(tmp_path / "a")]) == 0
    out, err = capsys.readouterr()
    assert "warning" not in err
    assert "spindle torque  peak" in out and "(limit 49.92)" in out and "line 3: S3000 M3" in out
    heavy = tmp_path / "heavy.mpf"
    heavy.write_text("G90 G94\nT2 M6\nS3000 M3\nG0 X-10 Y0 Z-15\nG1 X250 F1200\nG0 Z10\nM30\n")
    assert main(["simulate", "--program", str(heavy), "--material", "aisi1045", "--out",
                 str(tmp_path / "b")]) == 0
    err = capsys.readouterr().err
    assert "line 5 (G1 X250 F1200): spindle torque over 10 s" in err
    assert "exceeds the rated (S1) torque 25 Nm" in err


DRILL_TAP_DRILL = """; two holes drilled, two tapped, one drilled with a second drill
G90 G17 G94
T1 M6
S2400 M3
F384
MCALL CYCLE81(10, 0, 2, -10)
X20 Y20
X40 Y20
MCALL
G0 Z10
T2 M6
S400 M3
MCALL CYCLE84(10, 0, 2, -10, , 0, 3, , 1.25, 0, 400, 400)
X20 Y20
X40 Y20
MCALL
G0 Z10
T4 M6
S2400 M3
F384
MCALL CYCLE81(10, 0, 2, -10)
X60 Y20
MCALL
G0 Z50
M30
"""


def test_a_tool_table_numbers_the_programs_holes_and_breaks_the_tool_that_cut(
        tmp_path: Path) -> None:
    """With a tool table the holes count on over every drill and tap in the program's order
    (as the edge counts them and as ``faults`` name them); a breakage in hole 3 breaks the
    tap that cut it, not the drill T4 of hole 4; a harder stock from hole 3 on acts on both
    (the faulted soak with milling found the fault put on tool 1's hole 3 instead)."""
    (tmp_path / "tools.toml").write_text(PRODUCTION_TOOLS)  # T1, T4 drills, T2 a tap
    (tmp_path / "p.mpf").write_text(DRILL_TAP_DRILL)
    tools = read_tool_table(tmp_path / "tools.toml")

    def per_hole(faults: list[dict[str, object]]) -> tuple[list[tuple[int, int]], dict]:
        res = part_program(None, program=tmp_path / "p.mpf", material="aisi1045", tools=tools,
                           seed=3, faults=faults)
        t = pd.concat(res.per_cycle)
        mean = t[t["hole"] >= 0].groupby("hole")["cutting_torque_nm"].apply(
            lambda v: float(np.abs(v).mean()))
        return [(h["tool"], h["hole"]) for h in res.truth["holes"]], mean.to_dict()

    order, healthy = per_hole([])
    assert order == [(1, 0), (1, 1), (2, 2), (2, 3), (4, 4)]
    _, broken = per_hole([{"type": "ToolBreakage", "hole": 3, "depth_fraction": 0.3}])
    assert broken[2] == pytest.approx(healthy[2], rel=1e-9)  # the tap's first hole: as before
    assert broken[3] < 0.6 * healthy[3]  # the tap broke in hole 3
    assert broken[4] == pytest.approx(healthy[4], rel=0.05)  # T4 is another tool: it drills
    _, hard = per_hole([{"type": "HardnessChange", "hole": 3, "factor": 1.5}])
    assert hard[2] == pytest.approx(healthy[2], rel=1e-9)
    assert hard[3] > 1.3 * healthy[3] and hard[4] > 1.3 * healthy[4]
