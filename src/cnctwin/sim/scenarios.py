"""Ready-made simulation scenarios of the thesis experiments (one function call each).

Every scenario runs the simulator's orchestrator :func:`cnctwin.sim.simulate` on a G-code
program from :mod:`cnctwin.sim.programs` (interpolator -> spindle drive + feed-axis servo) with a
cutting-process hook built here from :mod:`~cnctwin.sim.cutting`, :mod:`~cnctwin.sim.tool` and
:mod:`~cnctwin.sim.faults`:

* drilling (:class:`DrillingProcess`): the load follows the tool-tip depth below the surface
  (expected actual Z position); the thrust is the Z disturbance force, the drill walk and the
  rotating lateral force are X/Y disturbance forces, so hole-position deviations show up in the
  X/Y ``ENC_POS`` through the servo; wear per hole, tool-tip temperature, faults;
* milling (:class:`MillingProcess`): the mechanistic end-milling forces on X/Y (Z: axial);
* rigid tapping (:class:`TappingProcess`): spindle in position control, torque reversing on
  extraction; a loose tap adds a fluctuating torque and axial force while the tap reverses.

Outputs with ``out`` (a directory):

* the recording as Capture4Analysis JSON (chained files above ``max_file_mb``) or, with
  ``fmt="parquet"``, a Parquet chunk directory (:class:`~cnctwin.sim.recorder.ParquetChunkSink`);
  both stream chunk by chunk and read back with :func:`cnctwin.read_recording`;
* external sensors on their own clocks as CSV (``dynamometer*.csv``:
  ``time_s,fx_n,fy_n,fz_n,mz_nm``; ``thermal_camera.csv``: ``time_s,hole,temperature_c``);
* ``truth.json``: every true parameter (machine incl. spindle and servo, materials, tools, wear
  curve, sensor clocks, faults and their onsets) and the per-hole / per-step ground truth;
* ``truth_per_cycle.parquet``: per-cycle hidden process values (cutting torque, thrust,
  lateral forces, tool temperature, wear, hole) of the cycles with the tool in the workpiece.

Without ``out`` everything stays in memory: ``result.recordings`` (with the external channels
attached) and ``result.per_cycle`` (the simulator's per-cycle truth incl. the process values).

Scenarios (:data:`SCENARIOS`), by family in their own modules: spindle
(:mod:`~cnctwin.sim.scenarios_spindle`: :func:`air_cut_sweep`, :func:`warm_up`), cutting
process (:mod:`~cnctwin.sim.scenarios_process`: :func:`drilling_validation`,
:func:`tool_wear_run`, :func:`loose_tap`), feed axes (:mod:`~cnctwin.sim.scenarios_servo`:
:func:`milling_square_circle`, :func:`axis_test`); a user's program:
:func:`~cnctwin.sim.part.part_program`. The hooks are in :mod:`~cnctwin.sim.processes` and
:mod:`~cnctwin.sim.stockcut`, the configuration in :mod:`~cnctwin.sim.config`, the running
(sinks, truth files) in :mod:`~cnctwin.sim.runner`. This module keeps the names together.

Overrides (every physical parameter): every :meth:`Machine.with_overrides` key
(``spindle.kt_nm_per_a``, ``axes.X1.kv_m_min_per_mm``), ``material.<key>.<field>`` and
``material.<key>.milling.<field>``, ``drill.<field>``, ``tap.<field>``, ``end_mill.<field>``,
``drilling.<field>`` (:class:`~cnctwin.sim.cutting.DrillingModel`), ``wear.<field>``
(:class:`~cnctwin.sim.tool.WearCurve`), ``tool_thermal.<field>``, ``dynamometer.<field>``,
``camera.<field>``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from cnctwin.exceptions import ConfigError
from cnctwin.sim.config import (
    START_CYCLE,
    START_TIME,
    ProgressFn,
    ScenarioConfig,
    ScenarioResult,
    random_loop_overrides,
    random_spindle_overrides,
)
from cnctwin.sim.machine import Machine
from cnctwin.sim.part import drive_limits_check, part_program
from cnctwin.sim.processes import (
    DrillingProcess,
    MillingProcess,
    TappingProcess,
)
from cnctwin.sim.scenarios_process import (
    drilling_validation,
    loose_tap,
    tool_wear_run,
)
from cnctwin.sim.scenarios_servo import axis_test, milling_square_circle
from cnctwin.sim.scenarios_spindle import air_cut_sweep, warm_up

__all__ = [
    "SCENARIOS",
    "START_CYCLE",
    "START_TIME",
    "DrillingProcess",
    "MillingProcess",
    "ScenarioConfig",
    "ScenarioResult",
    "TappingProcess",
    "air_cut_sweep",
    "axis_test",
    "drilling_validation",
    "drive_limits_check",
    "loose_tap",
    "milling_square_circle",
    "part_program",
    "random_loop_overrides",
    "random_spindle_overrides",
    "run_scenario",
    "tool_wear_run",
    "warm_up",
]



SCENARIOS: dict[str, Callable[..., ScenarioResult]] = {
    "air_cut_sweep": air_cut_sweep,
    "warm_up": warm_up,
    "drilling_validation": drilling_validation,
    "tool_wear_run": tool_wear_run,
    "loose_tap": loose_tap,
    "milling_square_circle": milling_square_circle,
    "axis_test": axis_test,
}
"""Scenario name -> function (:func:`part_program` runs a user's program instead)."""


def run_scenario(
    name: str,
    out: str | Path | None = None,
    *,
    seed: int = 0,
    overrides: Mapping[str, Any] | None = None,
    progress: ProgressFn | None = None,
    machine: Machine | None = None,
    **options: Any,
) -> ScenarioResult:
    """Run a scenario by name (:data:`SCENARIOS`); ``options`` go to the scenario function.

    ``machine`` is the base machine (e.g. from a machine file), ``overrides`` apply on top.

    Parameters
    ----------
    name : str
        Scenario name (``cnctwin simulate --list`` prints them).
    out : str or path, optional
        Output folder; None keeps the recordings in memory.
    seed : int, default 0
        Random seed (noise, hidden parameters where the scenario draws them).
    overrides : mapping, optional
        Dotted machine parameters set on top of ``machine`` (``{"spindle.kt_nm_per_a": 0.9}``).
    progress : callable, optional
        Called with (fraction done 0..1, message) on long scenarios.
    machine : Machine, optional
        The base machine; default the simulator's machine.
    **options
        Scenario options (see the scenario's function).

    Returns
    -------
    ScenarioResult
        Recordings (or their files), the truth of the hidden parameters and the scenario's
        options.

    Raises
    ------
    ConfigError
        Unknown scenario or option (the message lists the valid ones).
    """
    import inspect

    try:
        fn = SCENARIOS[name]
    except KeyError:
        raise ConfigError(f"unknown scenario {name!r}; known: {', '.join(SCENARIOS)}") from None
    params = inspect.signature(fn).parameters
    valid = [p for p in params if p not in ("out", "seed", "overrides", "progress", "machine")]
    bad = sorted(set(options) - set(valid))
    if bad:
        raise ConfigError(f"scenario {name!r} has no option(s) {bad}; options: {valid}")
    for key, value in options.items():
        default = params[key].default
        if isinstance(default, bool):
            ok = isinstance(value, bool)
            want = "true or false"
        elif isinstance(default, int):
            ok = isinstance(value, int) and not isinstance(value, bool)
            want = "an integer"
        elif isinstance(default, float):
            ok = isinstance(value, int | float) and not isinstance(value, bool)
            want = "a number"
        elif isinstance(default, str):
            ok = isinstance(value, str)
            want = "a string"
        else:
            continue
        if not ok:
            raise ConfigError(f"scenario {name!r} option {key} must be {want} (default "
                              f"{default!r}), not {value!r}")
    if machine is not None:
        options["machine"] = machine
    return fn(out, seed=seed, overrides=overrides, progress=progress, **options)
