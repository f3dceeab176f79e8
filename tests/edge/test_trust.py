"""A live twin you can trust on a healthy machine (issue 24), through the command line.

A hidden spindle (``random_spindle_overrides(7)``) is calibrated as the README says (air-cut
sweep, one drilling cut with the dynamometer, ``cnctwin calibrate spindle``); then varied
production drawn at random (``production_program``: drilling, peck drilling, tapping, milling
entries by plunge, ramp and helix, speed and tool changes, air moves), each draw with its own
noise seed, is replayed through ``cnctwin edge run`` with the default detectors. Truth: the
program (its drilling-cycle calls are the holes) and the tip position (above the surface no
tool cuts). The long version with rates per machine-hour is ``benchmarks/bench_soak.py``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from cnctwin.iotools import read_recording
from cnctwin.sim.programs import production_program
from cnctwin.sim.scenarios import random_spindle_overrides
from cnctwin.validation.soak import current_noise_a, tally_run
from tests.calibration._campaign import REFERENCE, cli, sets

pytestmark = pytest.mark.slow

SPEEDS = list(range(200, 5001, 400)) + list(range(4600, 199, -400))
# the plunge of the issue: a milling plunge (G1 Z-1) and a contour before 4 CYCLE81 holes,
# a run-up at the start and braking at the end
PLUNGE_PART = """T1 M6
S2400 M3
G0 X0 Y0 Z5
G1 Z-1 F200
G1 X40 F400
G0 Z5
G0 X10 Y20
F400
MCALL CYCLE81(10, 0, 2, -20)
X10 Y20
X30 Y20
X50 Y20
X70 Y20
MCALL
G0 Z50
M5
M30
"""


@pytest.fixture(scope="module")
def machine(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    d = tmp_path_factory.mktemp("trust")
    hidden = sets(random_spindle_overrides(7))
    assert cli("simulate", "air_cut_sweep", "--out", d / "ac", "--seed", 7, *hidden,
               "--option", f"speeds_rpm={SPEEDS}") == 0
    assert cli("simulate", "drilling_validation", "--out", d / "dv", "--seed", 7, *hidden,
               "--option", 'cuts=[["aisi1045", 2400, 0.16]]') == 0
    m = d / "machine.toml"
    assert cli("calibrate", "spindle", "--air-cut", d / "ac" / "air_cut_sweep.json",
               "--reference", d / "dv" / f"{REFERENCE}.json",
               "--dynamometer", d / "dv" / f"dynamometer_{REFERENCE[6:]}.csv",
               "--machine", m) == 0
    return {"dir": d, "machine": m, "sets": hidden}


def _run(machine: dict[str, Any], name: str, text: str, seed: int) -> tuple[Path, Path, float]:
    d: Path = machine["dir"]
    part = d / f"{name}.mpf"
    part.write_text(text, encoding="utf-8")
    assert cli("simulate", "--program", part, "--machine", machine["machine"], "--material",
               "aisi1045", "--seed", seed, *machine["sets"], "--out", d / f"sim_{name}") == 0
    rec = d / f"sim_{name}" / f"{name}.json"
    assert cli("edge", "run", "--source", rec, "--machine", machine["machine"],
               "--out", d / f"edge_{name}", "--no-twin") == 0
    return (rec, d / f"edge_{name}" / "results.jsonl",
            current_noise_a(d / f"sim_{name}" / "truth.json"))


def test_milling_plunge_is_no_hole_and_braking_no_torque(machine: dict[str, Any]) -> None:
    """The issue's case: 5 holes for 4 CYCLE81 calls (the G1 Z-1 plunge was hole 0) and a
    cutting torque of -16 to +12 Nm on the run-up and the braking."""
    rec, results, noise = _run(machine, "plunge", PLUNGE_PART, 3)
    t = tally_run(results, read_recording(rec), holes_expected=4,
                  machine_file=machine["machine"], noise_a=noise)
    rows = [json.loads(x)["row"] for x in results.read_text().splitlines()
            if json.loads(x)["kind"] == "hole"]
    assert [(r["x_mm"], r["y_mm"], r["cycle"]) for r in rows] == [
        (10.0, 20.0, "CYCLE81"), (30.0, 20.0, "CYCLE81"), (50.0, 20.0, "CYCLE81"),
        (70.0, 20.0, "CYCLE81")]
    assert t.alarms == 0
    # run-up and braking: each ~0.17 s of ramp plus 0.3 s of settling flagged, not a cut
    assert t.flagged_cycles > 300
    # everywhere the tip is above the part: within the calibration's uncertainty (k = 4)
    assert t.air_over_bound == 0, t
    assert t.air_torque_bound_nm < 0.5


@pytest.mark.parametrize("seed", [102])
def test_varied_production_gives_no_false_result(machine: dict[str, Any], seed: int) -> None:
    """A random draw (CYCLE81 at two depths, CYCLE83 pecks, a helix and a ramp entry, speed
    changes): no alarm, the program's holes exactly (the pecks of a hole are one hole), and
    no torque above the bound while the tip is above the part. Measured: 0 alarms, 12/12
    holes, air |torque| <= 0.21 Nm against a 0.25 Nm bound."""
    prog = production_program(seed, operations=8)
    rec, results, noise = _run(machine, f"draw{seed}", prog.text, seed)
    t = tally_run(results, read_recording(rec), holes_expected=prog.holes,
                  machine_file=machine["machine"], noise_a=noise)
    assert t.alarms == 0
    assert t.holes_found == t.holes_expected == 12 and t.plunge_holes == 0
    assert t.air_over_bound == 0, t
