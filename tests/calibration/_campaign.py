"""A hidden machine's calibration campaign, run through the command line as a user types it.

The hidden parameters are drawn from a seed (:func:`random_spindle_overrides`,
:func:`random_loop_overrides`) and reach the simulator only as ``--set`` options; the
calibration sees nothing but the files the simulator wrote.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from cnctwin.cli import main
from cnctwin.sim.scenarios import random_loop_overrides, random_spindle_overrides

# the air cut a user is told to record: up and back down through 200-5000 rpm, 3 s each
_UP = list(range(200, 5001, 200))
SPEEDS_RPM = _UP + _UP[-2::-1]
REFERENCE = "drill_1_aisi1045_2400rpm_0p16"


def hidden_machine(seed: int) -> dict[str, Any]:
    """The hidden spindle and X1/Y1 loop parameters of ``seed``."""
    return {**random_spindle_overrides(seed), **random_loop_overrides(seed)}


def sets(overrides: dict[str, Any]) -> list[str]:
    """``--set KEY=VALUE`` options."""
    return [x for k, v in overrides.items() for x in ("--set", f"{k}={v}")]


def cli(*args: object) -> int:
    """Run ``cnctwin ARGS`` in this process (the same parser and exit codes as the shell)."""
    return main([str(a) for a in args])


def simulate_campaign(d: Path, seed: int, hidden: dict[str, Any]) -> None:
    """Air cut, one drilling cut with the dynamometer, the axis test program."""
    s = sets(hidden)
    assert cli("simulate", "air_cut_sweep", "--out", d / "ac", "--seed", seed, *s,
               "--option", f"speeds_rpm={SPEEDS_RPM}") == 0
    assert cli("simulate", "drilling_validation", "--out", d / "dv", "--seed", seed, *s,
               "--option", 'cuts=[["aisi1045", 2400, 0.16]]') == 0
    assert cli("simulate", "axis_test", "--out", d / "at", "--seed", seed, *s,
               "--option", 'axes=["X1", "Y1"]') == 0


def calibrate(d: Path, machine: Path) -> None:
    """``cnctwin calibrate spindle`` and ``cnctwin calibrate axes`` on the campaign."""
    assert cli("calibrate", "spindle", "--air-cut", d / "ac" / "air_cut_sweep.json",
               "--reference", d / "dv" / f"{REFERENCE}.json",
               "--dynamometer", d / "dv" / f"dynamometer_{REFERENCE[6:]}.csv",
               "--machine", machine) == 0
    assert cli("calibrate", "axes", d / "at" / "axis_test.json", "--machine", machine) == 0
