"""What a scenario is run with and what it returns: :class:`ScenarioConfig` (the hidden truth
of the machine, tools and materials, with dotted overrides) and :class:`ScenarioResult`.

Split from :mod:`cnctwin.sim.scenarios` (the override keys are listed there).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from cnctwin.exceptions import ConfigError
from cnctwin.recording import Recording
from cnctwin.sim.cutting import (
    MATERIALS,
    DrillingModel,
    Material,
)
from cnctwin.sim.machine import Machine
from cnctwin.sim.sensors import (
    Dynamometer,
    ThermalCamera,
)
from cnctwin.sim.tool import (
    Drill,
    EndMill,
    Tap,
    ToolThermal,
    WearCurve,
)

__all__ = [
    "START_CYCLE",
    "START_TIME",
    "ProgressFn",
    "ScenarioConfig",
    "ScenarioResult",
    "random_loop_overrides",
    "random_spindle_overrides",
]


ProgressFn = Callable[[float, str], None]
START_CYCLE = 5_000_000
"""CYCLE counter of the first recorded cycle of every scenario."""
START_TIME = pd.Timestamp("2024-05-06T08:00:00Z")
"""UTC time of the first recorded cycle."""


# ----------------------------------------------------------------------------- results
@dataclass
class ScenarioResult:
    """What a scenario produced.

    Attributes
    ----------
    name : str
        Scenario name.
    recordings : list of Recording
        Recordings kept in memory (only without ``out``), external channels attached.
    paths : list of Path
        Every file written (empty without ``out``).
    recording_paths : list of Path
        The first file (or Parquet directory) of each written recording, for
        :func:`cnctwin.read_recording`.
    truth : dict
        The true parameters and ground truth (also ``truth.json``).
    per_cycle : list of pandas.DataFrame
        Per recording, the simulator's per-cycle truth indexed by cycle (drive truth plus the
        process values of the hook) - only without ``out``.
    """

    name: str
    recordings: list[Recording] = field(default_factory=list)
    paths: list[Path] = field(default_factory=list)
    recording_paths: list[Path] = field(default_factory=list)
    truth: dict[str, Any] = field(default_factory=dict)
    per_cycle: list[pd.DataFrame] = field(default_factory=list)

    @property
    def recording(self) -> Recording:
        """The first recording: in memory, or read back from ``recording_paths[0]``."""
        if self.recordings:
            return self.recordings[0]
        if self.recording_paths:
            from cnctwin.iotools import read_recording

            return read_recording(self.recording_paths[0])
        raise ConfigError(f"scenario {self.name!r} kept no recording")


@dataclass(frozen=True)
class ScenarioConfig:
    """All true parameters of a scenario run (built from defaults + overrides)."""

    machine: Machine
    materials: dict[str, Material]
    drill: Drill
    tap: Tap
    end_mill: EndMill
    drilling: DrillingModel
    wear: WearCurve
    tool_thermal: ToolThermal
    dynamometer: Dynamometer
    camera: ThermalCamera

    @classmethod
    def build(
        cls, overrides: Mapping[str, Any] | None = None, *, machine: Machine | None = None
    ) -> ScenarioConfig:
        """Defaults (or ``machine``) with dotted-key ``overrides`` applied.

        Raises
        ------
        ConfigError
            For an unknown key (the message lists the valid keys) or a bad value.
        """
        ov = dict(overrides or {})
        machine_keys = {k: v for k, v in ov.items() if k.split(".")[0] not in _OWN_PREFIXES}
        base = machine if machine is not None else Machine.thesis_default()
        m = base.with_overrides(machine_keys) if machine_keys else base
        own: dict[str, dict[str, Any]] = {}
        mats: dict[str, dict[str, Any]] = {}
        mill: dict[str, dict[str, Any]] = {}
        for key, value in ov.items():
            parts = key.split(".")
            if parts[0] not in _OWN_PREFIXES:
                continue
            if parts[0] == "material":
                if len(parts) == 4 and parts[1] in MATERIALS and parts[2] == "milling":
                    mill.setdefault(parts[1], {})[parts[3]] = value
                elif len(parts) == 3 and parts[1] in MATERIALS:
                    mats.setdefault(parts[1], {})[parts[2]] = value
                else:
                    raise ConfigError(
                        f"override {key!r}: use material.<{'|'.join(MATERIALS)}>.<field> or "
                        "material.<key>.milling.<field>"
                    )
            elif len(parts) == 2:
                own.setdefault(parts[0], {})[parts[1]] = value
            else:
                raise ConfigError(f"override {key!r}: expected {parts[0]}.<field>")
        materials = {}
        for name, mat in MATERIALS.items():
            changes = dict(mats.get(name, {}))
            if name in mill:
                if mat.milling is None:
                    raise ConfigError(f"material {name!r} has no milling coefficients to override")
                changes["milling"] = _replace(mat.milling, mill[name], f"material.{name}.milling")
            materials[name] = _replace(mat, changes, f"material.{name}")
        return cls(
            machine=m,
            materials=materials,
            drill=_replace(Drill(), own.get("drill", {}), "drill"),
            tap=_replace(Tap(), own.get("tap", {}), "tap"),
            end_mill=_replace(EndMill(), own.get("end_mill", {}), "end_mill"),
            drilling=_replace(DrillingModel(), own.get("drilling", {}), "drilling"),
            wear=_replace(WearCurve(), own.get("wear", {}), "wear"),
            tool_thermal=_replace(ToolThermal(), own.get("tool_thermal", {}), "tool_thermal"),
            dynamometer=_replace(Dynamometer(), own.get("dynamometer", {}), "dynamometer"),
            camera=_replace(ThermalCamera(), own.get("camera", {}), "camera"),
        )

    def to_dict(self) -> dict[str, Any]:
        """Plain dict for truth.json."""
        return {
            "machine": self.machine.to_dict(),
            "spindle_derived": {
                "flux_linkage_vs": self.machine.spindle.flux_linkage_vs,
                "max_phase_voltage_v": self.machine.spindle.max_phase_voltage_v,
                "current_convention": "A rms (Kt = 1.5 sqrt(2) p psi_pm)",
            },
            "materials": {k: dataclasses.asdict(v) for k, v in self.materials.items()},
            "drill": dataclasses.asdict(self.drill),
            "tap": dataclasses.asdict(self.tap),
            "end_mill": dataclasses.asdict(self.end_mill),
            "drilling_model": dataclasses.asdict(self.drilling),
            "wear_curve": dataclasses.asdict(self.wear),
            "tool_thermal": dataclasses.asdict(self.tool_thermal),
            "dynamometer": dataclasses.asdict(self.dynamometer),
            "thermal_camera": dataclasses.asdict(self.camera),
        }


_OWN_PREFIXES = (
    "material",
    "drill",
    "tap",
    "end_mill",
    "drilling",
    "wear",
    "tool_thermal",
    "dynamometer",
    "camera",
)


def _replace(obj: Any, changes: Mapping[str, Any], prefix: str) -> Any:
    valid = {f.name for f in dataclasses.fields(obj)}
    bad = sorted(set(changes) - valid)
    if bad:
        raise ConfigError(
            f"unknown override keys {[f'{prefix}.{b}' for b in bad]}; valid: "
            f"{sorted(f'{prefix}.{v}' for v in valid)}"
        )
    try:
        return dataclasses.replace(obj, **changes) if changes else obj
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"override of {prefix}: {exc}") from exc


def random_loop_overrides(
    seed: int, *, axes: Sequence[str] = ("X1", "Y1")
) -> dict[str, float | int]:
    """Randomly drawn position-loop parameters (for identification tests), as overrides.

    Parameters
    ----------
    seed : int
        Seed of the draw.
    axes : sequence of str, default ('X1', 'Y1')
        Feed axes to randomise.

    Returns
    -------
    dict
        ``Machine.with_overrides`` keys: per axis Kv MD32200 U(1.5, 4) (m/min)/mm, FFW mode
        MD32620 from {1, 2, 3, 4}, jerk filter time MD32410 U(4, 16) ms (moving average),
        MD32810 U(1, 4) ms, MD32800 U(0.3, 0.8) ms, speed-controller gain x U(0.7, 1.4) and
        Coulomb friction U(80, 220) N. Ranges: docs/reference/physics-and-performance.md §1.2
        [S]/[E].
    """
    rng = np.random.default_rng([seed, 0x5EED])
    ref = Machine.thesis_default()
    out: dict[str, float | int] = {}
    for ax in axes:
        a = ref.axis(ax)
        p = f"axes.{ax}."
        out[p + "kv_m_min_per_mm"] = round(float(rng.uniform(1.5, 4.0)), 4)
        out[p + "ffw_mode"] = int(rng.choice([1, 2, 3, 4]))
        out[p + "jerk_filter_type"] = 2
        out[p + "jerk_time_s"] = round(float(rng.uniform(0.004, 0.016)), 5)
        out[p + "equiv_speedctrl_time_s"] = round(float(rng.uniform(0.001, 0.004)), 5)
        out[p + "equiv_currctrl_time_s"] = round(float(rng.uniform(0.0003, 0.0008)), 6)
        out[p + "speed_kp_nm_s_per_rad"] = round(
            float(a.speed_kp_nm_s_per_rad * rng.uniform(0.7, 1.4)), 4)
        out[p + "coulomb_n"] = round(float(rng.uniform(80.0, 220.0)), 2)
    return out


def random_spindle_overrides(seed: int) -> dict[str, float]:
    """Randomly drawn spindle parameters (for calibration tests), as overrides.

    Parameters
    ----------
    seed : int
        Seed of the draw.

    Returns
    -------
    dict
        ``Machine.with_overrides`` keys: Kt U(0.8, 1.3) Nm/A, viscous friction
        U(5e-5, 1.2e-4) Nm/rpm, Coulomb friction U(0.2, 0.5) Nm, Stribeck torque U(0.05, 0.25)
        Nm and speed U(250, 600) rpm, inertia U(0.010, 0.025) kg m^2: motor spindles of the
        thesis machine's class around its values (thesis Eq. 4.4: 1.04, 8.42e-5, 0.35) [E].
    """
    rng = np.random.default_rng([seed, 0x5B1D])
    return {
        "spindle.kt_nm_per_a": round(float(rng.uniform(0.8, 1.3)), 5),
        "spindle.viscous_friction_nm_per_rpm": float(f"{rng.uniform(5e-5, 1.2e-4):.5g}"),
        "spindle.coulomb_friction_nm": round(float(rng.uniform(0.2, 0.5)), 5),
        "spindle.stribeck_torque_nm": round(float(rng.uniform(0.05, 0.25)), 4),
        "spindle.stribeck_speed_rpm": round(float(rng.uniform(250.0, 600.0)), 1),
        "spindle.inertia_kg_m2": round(float(rng.uniform(0.010, 0.025)), 5),
    }


