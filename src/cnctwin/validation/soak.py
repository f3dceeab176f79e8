"""Trust on a healthy machine: what the edge runtime reported on varied production, tallied.

A soak replays simulated production (:func:`cnctwin.sim.programs.production_program`) of a
calibrated machine through ``cnctwin edge run`` and counts what an operator would see:
alarms (each a false alarm: the machine is healthy), holes (against the program's
drilling-cycle calls), and the cutting torque while no tool can cut (the tip above the
workpiece surface; the speed-change cycles the runtime flags are not shown as torque). The
benchmark ``benchmarks/bench_soak.py`` runs many draws and reports rates per machine-hour;
the test suite runs a few (``tests/edge/test_trust.py``).
"""

from __future__ import annotations

import json
import math
import tomllib
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np

from cnctwin.exceptions import ConfigError
from cnctwin.recording import Recording

__all__ = ["SoakTally", "air_torque_bound_nm", "current_noise_a", "tally_run"]


@dataclass(frozen=True)
class SoakTally:
    """What one replayed draw gave.

    Attributes
    ----------
    machine_s : float
        Machine time of the recording [s].
    alarms : int
        Alarm results (on a healthy machine each is false) [-].
    holes_expected, holes_found : int
        Drilling-cycle calls of the program, hole results of the run [-].
    plunge_holes : int
        Holes labelled ``plunge`` (a Z plunge outside a drilling cycle) [-].
    air_cycles : int
        Cycles with the tip above the surface and an unflagged torque [-].
    air_torque_max_nm : float
        Largest ``|torque|`` over them [Nm].
    air_torque_bound_nm : float
        The bound they must stay within (:func:`air_torque_bound_nm`) [Nm].
    air_over_bound : int
        Air cycles above the bound [-].
    flagged_cycles : int
        Cycles whose torque is flagged (speed change, standstill) [-].
    """

    machine_s: float
    alarms: int
    holes_expected: int
    holes_found: int
    plunge_holes: int
    air_cycles: int
    air_torque_max_nm: float
    air_torque_bound_nm: float
    air_over_bound: int
    flagged_cycles: int


def air_torque_bound_nm(machine_file: str | PathLike[str], *, current_a: float,
                        speed_rpm: float, noise_a: float, k: float = 4.0) -> float:
    """Bound of ``|cutting torque|`` while no tool cuts: ``k`` standard uncertainties.

    ``u^2 = u(tau_f)^2 + (n u(B))^2 + (I u(Kt))^2 + (Kt sigma_I)^2``: the calibration's
    stated uncertainties of the machine file (``[spindle]``) and the current sensor's noise
    ``sigma_I`` (one sample).

    Parameters
    ----------
    machine_file : path
        Calibrated machine file.
    current_a, speed_rpm : float
        Largest air current [A] and speed [rpm] the bound must cover.
    noise_a : float
        Standard deviation of one current sample (noise and ripple) [A].
    k : float, default 4
        Coverage factor (4: ~6e-5 of normal samples beyond it) [-].

    Returns
    -------
    float
        [Nm]

    Raises
    ------
    ConfigError
        The file has no calibrated spindle.
    """
    path = Path(machine_file)
    doc = tomllib.loads(path.read_text(encoding="utf-8"))
    sp = doc.get("spindle", {})

    def val(key: str) -> tuple[float, float]:
        e = sp.get(key)
        if not isinstance(e, dict) or "value" not in e:
            raise ConfigError(f"{path}: [spindle] {key} is not calibrated; run cnctwin "
                              "calibrate spindle first")
        return float(e["value"]), float(e.get("uncertainty", 0.0))

    kt, u_kt = val("kt_nm_per_a")
    _, u_b = val("viscous_friction_nm_per_rpm")
    _, u_tf = val("coulomb_friction_nm")
    u = math.sqrt(u_tf**2 + (speed_rpm * u_b) ** 2 + (current_a * u_kt) ** 2
                  + (kt * noise_a) ** 2)
    return k * u


def current_noise_a(truth: str | PathLike[str]) -> float:
    """Standard deviation of one spindle current sample of a simulated run [A].

    White noise and the stator-frequency ripple (a sine of amplitude ``a`` has the standard
    deviation ``a / sqrt(2)``), from the run's ``truth.json``.

    Parameters
    ----------
    truth : path
        The simulator's ``truth.json``.

    Returns
    -------
    float
    """
    sp = json.loads(Path(truth).read_text(encoding="utf-8"))["machine"]["spindle"]
    return math.sqrt(sp["current_noise_a"] ** 2 + sp["ripple_amplitude_a"] ** 2 / 2.0)


def tally_run(results: str | PathLike[str], rec: Recording, *, holes_expected: int,
              machine_file: str | PathLike[str], noise_a: float,
              surface_z_mm: float = 0.0, clearance_mm: float = 0.5) -> SoakTally:
    """Tally an ``edge run``'s ``results.jsonl`` against the draw's truth.

    Parameters
    ----------
    results : path
        The run's ``results.jsonl``.
    rec : Recording
        The replayed recording (``ENC_POS|Z1`` gives where the tip is).
    holes_expected : int
        Drilling-cycle calls of the program.
    machine_file : path
        The calibrated machine file the run used.
    noise_a : float
        Current sensor noise (one sample) [A].
    surface_z_mm, clearance_mm : float
        The tip is in air above ``surface_z_mm + clearance_mm`` [mm].

    Returns
    -------
    SoakTally
    """
    alarms = holes = plunges = 0
    cyc: list[np.ndarray] = []
    tq: list[np.ndarray] = []
    fl: list[np.ndarray] = []
    cur: list[np.ndarray] = []
    spd: list[np.ndarray] = []
    with open(results, encoding="utf-8") as fh:
        for line in fh:
            m = json.loads(line)
            kind = m.get("kind")
            if kind == "alarm":
                alarms += 1
            elif kind == "hole":
                holes += 1
                plunges += m["row"].get("cycle") == "plunge"
            elif kind == "torque":
                size = int(m["n"])
                cyc.append(np.arange(m["first_cycle"], m["first_cycle"] + size))
                tq.append(np.asarray(m["torque_nm"], dtype=np.float64))
                fl.append(np.asarray(m.get("flags", np.zeros(size)), dtype=np.int64))
                cur.append(np.asarray(m["current_a"], dtype=np.float64))
                spd.append(np.asarray(m["speed_rpm"], dtype=np.float64))
    c = np.concatenate(cyc) if cyc else np.empty(0, dtype=np.int64)
    t = np.concatenate(tq) if tq else np.empty(0)
    f = np.concatenate(fl) if fl else np.empty(0, dtype=np.int64)
    i = np.concatenate(cur) if cur else np.empty(0)
    n = np.concatenate(spd) if spd else np.empty(0)
    z = rec.hf["ENC_POS|Z1"].to_numpy(dtype=np.float64)
    pos = np.searchsorted(rec.cycles, c)
    ok = (pos < rec.cycles.size) & (rec.cycles[np.minimum(pos, rec.cycles.size - 1)] == c)
    air = np.zeros(c.size, dtype=bool)
    air[ok] = z[pos[ok]] > surface_z_mm + clearance_mm
    air &= f == 0
    bound = air_torque_bound_nm(
        machine_file, current_a=float(np.nanmax(np.abs(i[air]))) if air.any() else 0.0,
        speed_rpm=float(np.nanmax(np.abs(n[air]))) if air.any() else 0.0, noise_a=noise_a)
    a = np.abs(t[air])
    return SoakTally(machine_s=rec.n_cycles * rec.meta.cycle_time_s, alarms=alarms,
                     holes_expected=holes_expected, holes_found=holes,
                     plunge_holes=plunges, air_cycles=int(air.sum()),
                     air_torque_max_nm=float(a.max()) if a.size else 0.0,
                     air_torque_bound_nm=bound, air_over_bound=int((a > bound).sum()),
                     flagged_cycles=int((f != 0).sum()))
