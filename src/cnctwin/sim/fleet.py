"""A synthetic fleet: many machines over many days, with hidden faults on some of them.

:func:`plan_fleet` draws, from one seed, each machine's position loops and spindle (the same
ranges as :func:`~cnctwin.sim.scenarios.random_loop_overrides` and
:func:`~cnctwin.sim.scenarios.random_spindle_overrides`) and the faults injected on some
machines from a day on; :func:`simulate_fleet_cycle` runs one recorded part cycle of one
machine on one day (:data:`FLEET_PROGRAM`: a spindle plateau, X and Y moves at two feeds in
both directions, three drilled holes in AISI 1045) and writes it as a recording file. The
cycles are independent, so a caller can run them on any executor (``cnctwin simulate fleet``
runs them on the fleet's Dask cluster).

Faults (``kind`` of :class:`FleetFault`, the names of ``truth.json``):

* ``friction_rise``: the axis' Coulomb friction x :data:`FRICTION_RISE_FACTOR`;
* ``kv_drop``: the axis' servo gain Kv (MD32200) x :data:`KV_DROP_FACTOR`;
* ``worn_tool``: the drill is exchanged for one that has drilled :data:`WORN_TOOL_HOLES` holes
  (flank wear near the thesis' end of life, §5.1), so every hole needs more torque.

A fault persists from its day on.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from cnctwin.exceptions import ConfigError
from cnctwin.sim.scenarios import part_program, random_loop_overrides, random_spindle_overrides

__all__ = [
    "FAULT_KINDS",
    "FLEET_PROGRAM",
    "FRICTION_RISE_FACTOR",
    "KV_DROP_FACTOR",
    "WORN_TOOL_HOLES",
    "FleetCycle",
    "FleetFault",
    "FleetPlan",
    "plan_fleet",
    "simulate_fleet_cycle",
]

FAULT_KINDS = ("friction_rise", "kv_drop", "worn_tool")
"""The injected fault kinds (``truth.json`` names)."""

FRICTION_RISE_FACTOR = 1.8
"""Coulomb friction of an axis with a ``friction_rise`` fault, relative to its own [-]."""

KV_DROP_FACTOR = 0.7
"""Kv of an axis with a ``kv_drop`` fault, relative to its own [-]."""

WORN_TOOL_HOLES = 2600
"""Holes a drill has made when a ``worn_tool`` fault exchanges it (thesis end of life: 2676)."""

BASE_TOOL_HOLES = 200
"""Holes a healthy machine's drill has made at the fleet's first day (past its run-in)."""

FLEET_PROGRAM = """; cnctwin synthetic fleet part cycle
T1 D1 M6
G0 G90 X0 Y0 Z30
S4000 M3
G4 F1
G1 X80 F3000
G1 X0
G1 X80 F8000
G1 X0
G1 Y80 F3000
G1 Y0
G1 Y80 F8000
G1 Y0
S2000 F0.1 G95
G0 Z5
MCALL CYCLE81(5, 0, 2, -6)
X20 Y20
X40 Y20
X60 Y20
MCALL
G0 Z30
M5
M30
"""
"""The part cycle every machine runs (about 21 s; 3 holes of 6 mm depth)."""

HOLES_PER_CYCLE = 3
FAULT_AXES = ("X1", "Y1")


@dataclass(frozen=True)
class FleetFault:
    """A fault injected on one machine from one day on.

    Attributes
    ----------
    machine : str
        Machine name.
    kind : str
        One of :data:`FAULT_KINDS`.
    from_day : str
        First day with the fault (``YYYY-MM-DD``, UTC).
    axis : str or None
        Axis of ``friction_rise`` and ``kv_drop``; None for ``worn_tool``.
    """

    machine: str
    kind: str
    from_day: str
    axis: str | None


@dataclass(frozen=True)
class FleetCycle:
    """One recorded part cycle: which machine, day, cycle of the day and what it runs with.

    Attributes
    ----------
    machine, day : str
        Machine name and UTC day (``YYYY-MM-DD``).
    index : int
        Cycle of the day (0-based).
    start_time : str
        UTC start time (ISO 8601).
    seed : int
        Seed of the cycle's random streams.
    overrides : dict
        ``Machine.with_overrides`` keys: the machine's drawn parameters and active faults.
    first_hole : int
        Holes the drill has made before this cycle.
    """

    machine: str
    day: str
    index: int
    start_time: str
    seed: int
    overrides: dict[str, Any]
    first_hole: int

    @property
    def relative_path(self) -> str:
        """Path of the cycle's recording under the fleet directory."""
        return f"{self.machine}/{self.day}/cycle_{self.index:03d}.parquet"


@dataclass(frozen=True)
class FleetPlan:
    """Everything a synthetic fleet is made of.

    Attributes
    ----------
    machines : list of str
        Machine names.
    days : list of str
        UTC days (``YYYY-MM-DD``).
    cycles : list of FleetCycle
        Every recorded part cycle.
    faults : list of FleetFault
        The injected faults (``truth.json``).
    parameters : dict
        Machine name -> its drawn overrides (without faults).
    seed : int
        The seed the plan was drawn from.
    """

    machines: list[str]
    days: list[str]
    cycles: list[FleetCycle]
    faults: list[FleetFault]
    parameters: dict[str, dict[str, Any]] = field(repr=False)
    seed: int = 0

    def truth(self) -> dict[str, Any]:
        """The plan as ``truth.json`` content: ``faults`` (the interface's list) and more."""
        return {
            "faults": [asdict(f) for f in self.faults],
            "machines": self.machines,
            "days": self.days,
            "cycles_per_day": len(self.cycles) // max(1, len(self.machines) * len(self.days)),
            "seed": self.seed,
            "parameters": self.parameters,
            "fault_factors": {"friction_rise": FRICTION_RISE_FACTOR, "kv_drop": KV_DROP_FACTOR,
                              "worn_tool_holes": WORN_TOOL_HOLES},
            "program": "fleet_part.mpf",
        }

    def write(self, out: str | Path) -> list[Path]:
        """Write ``truth.json`` and the part program into ``out``; returns the paths."""
        o = Path(out)
        o.mkdir(parents=True, exist_ok=True)
        truth = o / "truth.json"
        truth.write_text(json.dumps(self.truth(), indent=1), encoding="utf-8")
        prog = o / "fleet_part.mpf"
        prog.write_text(FLEET_PROGRAM, encoding="utf-8")
        return [truth, prog]


def plan_fleet(
    *,
    machines: int,
    days: int,
    cycles_per_day: int = 2,
    seed: int = 0,
    start_day: str = "2026-03-02",
    fault_fraction: float = 0.4,
) -> FleetPlan:
    """Draw a fleet: machine parameters, injected faults and the recorded cycles.

    Parameters
    ----------
    machines : int
        Number of machines (``M001``, ``M002``, ...).
    days : int
        Number of consecutive days; faults start on day 2 or later, so every machine has at
        least one healthy day to compare with.
    cycles_per_day : int, default 2
        Recorded part cycles per machine and day (spread over the day from 06:00 UTC).
    seed : int, default 0
        Seed of every draw.
    start_day : str, default '2026-03-02'
        First day (UTC).
    fault_fraction : float, default 0.4
        Fraction of machines with a fault (one fault each; the kinds take turns, so a fleet of
        three or more faulty machines has every kind).

    Returns
    -------
    FleetPlan

    Raises
    ------
    ConfigError
        For fewer than one machine, fewer than two days or cycle, or a fraction outside
        [0, 1].
    """
    if machines < 1 or days < 2 or cycles_per_day < 1:
        raise ConfigError(f"a fleet needs >= 1 machine, >= 2 days and >= 1 cycle per day "
                          f"(got {machines}, {days}, {cycles_per_day}): the first day is every "
                          "machine's healthy reference")
    if not 0.0 <= fault_fraction <= 1.0:
        raise ConfigError(f"fault_fraction must be in [0, 1], not {fault_fraction}")
    rng = np.random.default_rng([seed, 0xF1EE7])
    names = [f"M{i + 1:03d}" for i in range(machines)]
    first = pd.Timestamp(start_day, tz="UTC").normalize()
    day_list = [(first + pd.Timedelta(days=d)).strftime("%Y-%m-%d") for d in range(days)]
    params: dict[str, dict[str, Any]] = {}
    for i, name in enumerate(names):
        params[name] = {**random_loop_overrides(seed * 10_007 + i, axes=FAULT_AXES),
                        **random_spindle_overrides(seed * 10_007 + i)}
    n_faulty = round(fault_fraction * machines)
    faulty = sorted(rng.choice(machines, size=n_faulty, replace=False).tolist())
    faults: list[FleetFault] = []
    for k, i in enumerate(faulty):
        kind = FAULT_KINDS[k % len(FAULT_KINDS)]
        from_day = day_list[int(rng.integers(1, days))]
        axis = str(rng.choice(FAULT_AXES)) if kind != "worn_tool" else None
        faults.append(FleetFault(names[i], kind, from_day, axis))
    by_machine = {f.machine: f for f in faults}
    spacing_s = 16 * 3600 / cycles_per_day
    cycles: list[FleetCycle] = []
    for i, name in enumerate(names):
        holes = BASE_TOOL_HOLES
        for d, day in enumerate(day_list):
            fault = by_machine.get(name)
            active = fault is not None and day >= fault.from_day
            over = dict(params[name])
            if active and fault is not None and fault.kind == "friction_rise":
                key = f"axes.{fault.axis}.coulomb_n"
                over[key] = round(float(over[key]) * FRICTION_RISE_FACTOR, 2)
            if active and fault is not None and fault.kind == "kv_drop":
                key = f"axes.{fault.axis}.kv_m_min_per_mm"
                over[key] = round(float(over[key]) * KV_DROP_FACTOR, 4)
            for k in range(cycles_per_day):
                t0 = (pd.Timestamp(day, tz="UTC") + pd.Timedelta(hours=6)
                      + pd.Timedelta(seconds=k * spacing_s))
                worn = active and fault is not None and fault.kind == "worn_tool"
                cycles.append(FleetCycle(
                    machine=name, day=day, index=k, start_time=t0.isoformat(),
                    seed=int(seed * 1_000_003 + i * 10_007 + d * 101 + k),
                    overrides=over, first_hole=WORN_TOOL_HOLES if worn else holes))
                holes += HOLES_PER_CYCLE
    return FleetPlan(names, day_list, cycles, faults, params, seed)


def simulate_fleet_cycle(cycle: FleetCycle, out: str | Path) -> Path:
    """Simulate one part cycle and write its recording (Parquet) under ``out``.

    Parameters
    ----------
    cycle : FleetCycle
        The cycle (:func:`plan_fleet`).
    out : str or path
        Fleet directory; the program ``fleet_part.mpf`` is written there if missing.

    Returns
    -------
    Path
        The recording (a Parquet recording directory, ``out / cycle.relative_path``), written
        under a hidden temporary name and renamed when complete.
    """
    from cnctwin.iotools.parquet import write_parquet

    o = Path(out)
    prog = o / "fleet_part.mpf"
    if not prog.exists():
        o.mkdir(parents=True, exist_ok=True)
        tmp_prog = prog.with_name(f".{prog.name}.{cycle.seed}.tmp")
        tmp_prog.write_text(FLEET_PROGRAM, encoding="utf-8")
        tmp_prog.replace(prog)
    res = part_program(None, program=prog, seed=cycle.seed, overrides=cycle.overrides,
                       material="aisi1045", start_time=cycle.start_time,
                       first_hole=cycle.first_hole)
    rec = res.recording
    rec.meta.machine = cycle.machine
    rec.meta.source_files = [cycle.relative_path]
    path = o / cycle.relative_path
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    write_parquet(rec, tmp)
    shutil.rmtree(path, ignore_errors=True)
    tmp.replace(path)
    return path
