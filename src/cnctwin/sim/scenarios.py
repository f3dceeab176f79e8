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

Scenarios (:data:`SCENARIOS`): :func:`air_cut_sweep`, :func:`warm_up`,
:func:`drilling_validation`, :func:`tool_wear_run`, :func:`loose_tap`,
:func:`milling_square_circle`.

Overrides (every physical parameter): every :meth:`Machine.with_overrides` key
(``spindle.kt_nm_per_a``, ``axes.X1.kv_m_min_per_mm``), ``material.<key>.<field>`` and
``material.<key>.milling.<field>``, ``drill.<field>``, ``tap.<field>``, ``end_mill.<field>``,
``drilling.<field>`` (:class:`~cnctwin.sim.cutting.DrillingModel`), ``wear.<field>``
(:class:`~cnctwin.sim.tool.WearCurve`), ``tool_thermal.<field>``, ``dynamometer.<field>``,
``camera.<field>``.
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from cnctwin.exceptions import ConfigError, GCodeError
from cnctwin.recording import ExternalChannel, Recording
from cnctwin.sim.cutting import (
    MATERIALS,
    DrillingModel,
    Material,
    drill_thrust_n,
    drill_torque_nm,
    drilling_load,
    lip_height_difference_um,
    milling_load,
    rotating_force_n,
    tapping_load,
)
from cnctwin.sim.faults import Fault, LooseTool, apply_faults, fault_to_dict, hardness_factor
from cnctwin.sim.gcode import Program, parse_program
from cnctwin.sim.machine import Machine
from cnctwin.sim.programs import (
    AIR_CUT_SPEEDS_RPM,
    air_cut_sweep_program,
    axis_test_program,
    circle_path,
    drilling_validation_program,
    hole_pattern,
    square_path,
    tapping_program,
    warm_up_program,
)
from cnctwin.sim.recorder import Capture4AnalysisSink, ParquetChunkSink, RecordingSink
from cnctwin.sim.sensors import (
    DYNAMOMETER_CSV_HEADER,
    Dynamometer,
    ThermalCamera,
    dynamometer_channel_from_rows,
    dynamometer_csv_decimals,
    dynamometer_rows,
    format_csv_fixed_bytes,
    thermal_camera_channel,
    write_thermal_camera_csv,
)
from cnctwin.sim.simulation import CuttingInput, CuttingOutput, SimulationResult, simulate
from cnctwin.sim.tool import (
    Drill,
    EndMill,
    Tap,
    ToolThermal,
    WearCurve,
    flank_wear_um,
    free_cooling,
    tool_temperature,
    tool_temperatures,
)

__all__ = [
    "SCENARIOS",
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

ProgressFn = Callable[[float, str], None]
START_CYCLE = 5_000_000
"""CYCLE counter of the first recorded cycle of every scenario."""
START_TIME = pd.Timestamp("2024-05-06T08:00:00Z")
"""UTC time of the first recorded cycle."""
_FORMATS = ("c4a", "parquet")


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


# ----------------------------------------------------------------------------- streaming helpers
def _runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """Half-open index ranges [a, b) where ``mask`` is True."""
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(),
                    strict=True))


class _DynamometerDAQ:
    """The dynamometer DAQ fed chunk by chunk; one file (session) per run of ``on`` cycles.

    Each session has its own clock (own t = 0 at ``clock_offset_s`` after the session start on
    the recording time base, drifting by ``clock_drift_ppm``); consecutive chunks are sampled
    without gaps (the last true sample of a chunk is kept for the next one).
    """

    def __init__(self, sensor: Dynamometer, rng: np.random.Generator, out: Path | None,
                 stem: str) -> None:
        self.sensor = sensor
        self.rng = rng
        self.out = out
        self.stem = stem
        self.sessions: list[dict[str, Any]] = []
        self.channels: list[ExternalChannel] = []
        self.paths: list[Path] = []
        self._rows: list[NDArray[np.float64]] = []
        self._fh: IO[bytes] | None = None
        self._decimals = dynamometer_csv_decimals(fs_hz=sensor.fs_hz,
                                                  force_noise_n=sensor.force_noise_n,
                                                  torque_noise_nm=sensor.torque_noise_nm)
        self._open = False
        self._last: tuple[float, NDArray[np.float64]] | None = None
        self._last_own = -math.inf

    def feed(self, time_s: NDArray[np.float64], values: NDArray[np.float64],
             on: NDArray[np.bool_] | None = None) -> None:
        """``values`` shape (4, n): fx, fy, fz [N], mz [Nm] on the recording time ``time_s``."""
        n = time_s.size
        mask = np.ones(n, dtype=bool) if on is None else on
        for a, b in _runs(mask):
            if not (a == 0 and self._open):
                self._close_session()
                self._open_session(float(time_s[a]))
            t = time_s[a:b]
            v = values[:, a:b]
            if self._last is not None:
                t = np.concatenate([[self._last[0]], t])
                v = np.concatenate([self._last[1][:, None], v], axis=1)
            self._last = (float(t[-1]), v[:, -1].copy())
            if t.size >= 2:
                self._sample(t, v)
            if b < n:
                self._close_session()

    def _open_session(self, t0: float) -> None:
        k = len(self.sessions) + 1
        name = f"{self.stem}.csv" if k == 1 else f"{self.stem}_{k:04d}.csv"
        self.sessions.append({"file": name, "start_s": t0,
                              "clock_offset_s": t0 + self.sensor.clock_offset_s,
                              "clock_drift_ppm": self.sensor.clock_drift_ppm,
                              "fs_hz": self.sensor.fs_hz})
        self._open = True
        self._last = None
        self._last_own = -math.inf
        self._rows = []
        if self.out is not None:
            p = self.out / name
            self._fh = p.open("wb")
            self._fh.write(DYNAMOMETER_CSV_HEADER)
            self.paths.append(p)

    def _sample(self, t: NDArray[np.float64], v: NDArray[np.float64]) -> None:
        sensor = dataclasses.replace(self.sensor,
                                     clock_offset_s=self.sessions[-1]["clock_offset_s"])
        rows = dynamometer_rows(t, (v[0], v[1], v[2], v[3]), sensor=sensor, rng=self.rng)
        # samples already taken at the end of the previous chunk (own times increase)
        rows = rows[int(np.searchsorted(rows[:, 0], self._last_own + 1e-12, side="right")):]
        if not rows.shape[0]:
            return
        self._last_own = float(rows[-1, 0])
        if self._fh is not None:
            # fixed point below the noise, straight to the binary file (session 3: no pandas,
            # no str copy; the DAQ was 30 % of the wear run's time, benchmarks/bench_scenario.py)
            self._fh.write(format_csv_fixed_bytes(rows, self._decimals).data)
        else:
            self._rows.append(rows)

    def _close_session(self) -> None:
        if not self._open:
            return
        self._open = False
        if self._fh is not None:
            self._fh.close()
            self._fh = None
        elif self._rows:
            self.channels.append(dynamometer_channel_from_rows(self._rows,
                                                               fs_hz=self.sensor.fs_hz))
        self._rows = []

    def close(self) -> None:
        """End the last session."""
        self._close_session()


class _TruthParquet:
    """Per-cycle truth rows streamed to one Parquet file (one row group per chunk)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._writer: Any = None

    def write(self, frame: dict[str, NDArray[Any]]) -> None:
        import pyarrow as pa
        import pyarrow.parquet as pq

        table = pa.table(frame)
        if self._writer is None:
            # lz4 without dictionary, pages v2: ~7x faster than zstd with dictionary and 20 %
            # smaller on these float columns (benchmarks/bench_sim.py, session 2); the cycle
            # delta-encoded and the float32 truth byte-stream-split: -40 % bytes (session 3)
            enc = {f.name: "BYTE_STREAM_SPLIT" for f in table.schema
                   if pa.types.is_floating(f.type)}
            enc.update({f.name: "DELTA_BINARY_PACKED" for f in table.schema
                        if pa.types.is_integer(f.type)})
            self._writer = pq.ParquetWriter(self.path, table.schema, compression="lz4",
                                            use_dictionary=False, write_batch_size=65_536,
                                            data_page_version="2.0", column_encoding=enc)
        self._writer.write_table(table)

    def close(self) -> Path | None:
        if self._writer is None:
            return None
        self._writer.close()
        return self.path


@dataclass
class _Progress:
    """Progress of one program: ``time_s`` of ``total_s`` machine time (the planned duration
    the hook gets with every chunk, so the program is not planned twice)."""

    fn: ProgressFn | None
    label: str
    done: float = 0.0
    share: float = 1.0

    def __call__(self, time_s: float, total_s: float) -> None:
        if self.fn is not None and total_s > 0:
            frac = self.done + self.share * min(time_s / total_s, 1.0)
            self.fn(min(frac, 1.0), f"{self.label} {time_s:.0f}/{total_s:.0f} s")


class _Process:
    """Shared bookkeeping of the cutting hooks (hole counting, truth, DAQ, progress)."""

    def __init__(self, *, surface_z_mm: float, faults: Sequence[Fault],
                 rng: np.random.Generator, truth: _TruthParquet | None,
                 daq: _DynamometerDAQ | None, daq_off_blocks: Sequence[int] = (),
                 progress: _Progress | None = None, first_hole: int = 0) -> None:
        self.surface_z_mm = surface_z_mm
        self.faults = tuple(faults)
        self.rng = rng
        self.truth_out = truth
        self.daq = daq
        self.daq_off_blocks = np.asarray(daq_off_blocks, dtype=np.int64)
        self.progress = progress
        self.first_hole = first_hole
        self.onsets: list[float | None] = [None] * len(self.faults)
        self.holes: dict[int, dict[str, Any]] = {}
        self._hole = -1
        self._hole_xy: tuple[float, float] | None = None
        self._inside = False
        self._prev: dict[str, float] = {}

    def _velocity(self, key: str, x: NDArray[np.float64], dt: float) -> NDArray[np.float64]:
        prev = self._prev.get(key, float(x[0]))
        self._prev[key] = float(x[-1])
        return np.diff(x, prepend=prev) / dt

    def _hole_index(self, depth: NDArray[np.float64], ci: CuttingInput) -> NDArray[np.int64]:
        """Hole number per cycle: a new hole at each entry at a new XY position (0.5 mm)."""
        inside = depth > 0.0
        prev = np.concatenate([[self._inside], inside[:-1]])
        self._inside = bool(inside[-1])
        out = np.full(depth.size, self._hole, dtype=np.int64)
        x, y = ci.des_pos["X1"], ci.des_pos["Y1"]
        for e in np.flatnonzero(inside & ~prev):
            xy = (float(x[e]), float(y[e]))
            if self._hole_xy is None or math.hypot(xy[0] - self._hole_xy[0],
                                                   xy[1] - self._hole_xy[1]) > 0.5:
                self._hole += 1
                self._hole_xy = xy
                self.holes[self.first_hole + self._hole] = {
                    "hole": self.first_hole + self._hole, "x_mm": xy[0], "y_mm": xy[1],
                    "cut_first_cycle": int(ci.cycle[e]), "cut_first_s": float(ci.time_s[e]),
                }
                out[e:] = self._hole
        return np.where(out >= 0, out + self.first_hole, -1)

    def _faults(self, load: Any, ci: CuttingInput, hole: NDArray[np.int64],
                speed: NDArray[np.float64], progress: NDArray[np.float64] | None) -> Any:
        if not self.faults:
            return load
        load, on = apply_faults(self.faults, load, time_s=ci.time_s, hole=hole,
                                speed_rpm=speed, hole_progress=progress, rng=self.rng)
        for q, o in enumerate(on):
            if o is not None and self.onsets[q] is None:
                self.onsets[q] = o
        return load

    def _emit(self, ci: CuttingInput, load: Any, forces: dict[str, NDArray[np.float64]],
              truth: dict[str, NDArray[Any]], keep: NDArray[np.bool_]) -> CuttingOutput:
        if self.daq is not None:
            on = None
            if self.daq_off_blocks.size:
                on = ~np.isin(np.asarray(ci.block_index), self.daq_off_blocks)
            self.daq.feed(ci.time_s, np.vstack([load.fx_n, load.fy_n, load.thrust_n,
                                                load.torque_nm]), on)
        if self.progress is not None:
            self.progress(float(ci.time_s[-1]), ci.duration_s)
        if self.truth_out is not None:
            if keep.any():
                frame: dict[str, NDArray[Any]] = {"cycle": ci.cycle[keep]}
                for k, v in truth.items():
                    dtype = np.int32 if k == "hole" else np.float32
                    frame[k] = np.asarray(v)[keep].astype(dtype)
                self.truth_out.write(frame)
            truth = {}
        return CuttingOutput(spindle_torque_nm=load.torque_nm, force_n=forces,
                             truth={k: np.asarray(v, dtype=np.float64)
                                    for k, v in truth.items()})

    def hole_rows(self) -> list[dict[str, Any]]:
        """Per-hole truth, in hole order."""
        return [self.holes[k] for k in sorted(self.holes)]


class DrillingProcess(_Process):
    """Cutting hook for drilling (:func:`cnctwin.sim.cutting.drilling_load`).

    Per chunk: tool-tip depth below ``surface_z_mm`` from the expected actual Z position, feed
    per revolution from its velocity and the commanded speed, the hole number (a new hole at
    each entry at a new XY position), flank wear of that hole (:func:`flank_wear_um` of
    ``first_hole`` + holes drilled), hardness faults, the lumped tool-tip temperature (state
    carried across chunks), random fluctuation, lip ripple and drill walk, then the faults.
    Outputs: spindle load torque; forces ``Z1`` = thrust (pushes the tool up), ``X1``/``Y1`` =
    walk + rotating lateral force (hole-position deviations through the servo).

    Parameters
    ----------
    cfg : ScenarioConfig
        Drill, drilling model, wear curve, tool thermal model.
    material : Material
        Workpiece.
    feed_mm_per_rev, speed_rpm : float
        Programmed feed and speed (for the per-hole model torque in the truth).
    hole_depth_mm : float
        Programmed depth (progress of :class:`~cnctwin.sim.faults.ToolBreakage`) [mm].
    walk_direction_rad : float, default 0.7
        Direction of the static walk force in XY [rad] (lip asymmetry of this drill).
    initial_tool_temperature_c : float, optional
        Tool-tip temperature at the start [degC]; default the ambient temperature (cold tool).
    """

    def __init__(self, cfg: ScenarioConfig, *, material: Material, feed_mm_per_rev: float,
                 speed_rpm: float, hole_depth_mm: float, walk_direction_rad: float = 0.7,
                 initial_tool_temperature_c: float | None = None, **kw: Any) -> None:
        super().__init__(**kw)
        self.cfg = cfg
        self.material = material
        self.feed_mm_per_rev = feed_mm_per_rev
        self.speed_rpm = speed_rpm
        self.hole_depth_mm = hole_depth_mm
        self.walk_direction_rad = walk_direction_rad
        self.initial_temperature_c = (cfg.tool_thermal.ambient_temperature_c
                                      if initial_tool_temperature_c is None
                                      else float(initial_tool_temperature_c))
        self.temperature_c = self.initial_temperature_c
        self.holder_temperature_c = cfg.tool_thermal.ambient_temperature_c
        self._acc: dict[int, list[float]] = {}
        # chisel-edge skid direction per hole (uniform): own stream, drawn once per new hole
        self._dir_rng = np.random.default_rng(int(self.rng.integers(2**32)))
        self._entry_dir: dict[int, float] = {}

    def _entry_directions(self, hole: NDArray[np.int64]) -> NDArray[np.float64]:
        for h in np.unique(hole[hole >= 0]):
            if int(h) not in self._entry_dir:
                self._entry_dir[int(h)] = float(self._dir_rng.uniform(-math.pi, math.pi))
        out = np.zeros(hole.size)
        for h in np.unique(hole[hole >= 0]):
            out[hole == h] = self._entry_dir[int(h)]
        return out

    def __call__(self, ci: CuttingInput) -> CuttingOutput:
        cfg = self.cfg
        dt = ci.cycle_time_s
        z = ci.position["Z1"]
        vz = self._velocity("Z1", z, dt)
        n = ci.spindle_speed_rpm
        feed = np.where(vz < -1e-9, -vz * 60.0 / np.maximum(np.abs(n), 1.0), 0.0)
        depth = self.surface_z_mm - z
        hole = self._hole_index(depth, ci)
        wear = np.where(hole >= 0, flank_wear_um(np.maximum(hole, 0), curve=cfg.wear), 0.0)
        hard = hardness_factor(self.faults, hole)
        angle = np.deg2rad(ci.spindle_pos_deg)
        kw: dict[str, Any] = {"drill": cfg.drill, "material": self.material, "wear_um": wear,
                              "hardness_factor": hard, "spindle_angle_rad": angle,
                              "model": cfg.drilling, "dt_s": dt}
        # tool temperature from the fault-free mean load (one pass, only where the tip is in
        # the material: outside it the load is exactly 0), then the load with it
        idx = np.flatnonzero(depth > 0.0)
        power = np.zeros(depth.size)
        if idx.size:
            sub = {**kw, "wear_um": wear[idx], "spindle_angle_rad": angle[idx],
                   "hardness_factor": np.broadcast_to(hard, depth.shape)[idx]}
            base = drilling_load(depth[idx], n[idx], feed[idx], rng=None, **sub)
            power[idx] = np.abs(base.torque_nm * n[idx]) * 2.0 * math.pi / 60.0
        if cfg.tool_thermal.two_node:
            temp, holder = tool_temperatures(power, dt_s=dt, thermal=cfg.tool_thermal,
                                             initial_c=self.temperature_c,
                                             initial_holder_c=self.holder_temperature_c)
            self.holder_temperature_c = float(holder[-1])
        else:
            temp = tool_temperature(power, dt_s=dt, thermal=cfg.tool_thermal,
                                    initial_c=self.temperature_c)
            holder = None
        self.temperature_c = float(temp[-1])
        load = drilling_load(depth, n, feed, rng=self.rng, tool_temperature_c=temp,
                             walk_direction_rad=self.walk_direction_rad,
                             entry_direction_rad=self._entry_directions(hole), **kw)
        prog = np.clip(depth / self.hole_depth_mm, 0.0, 1.0)
        load = self._faults(load, ci, hole, n, prog)
        self._holes_update(ci, hole, depth, feed, load, temp, wear, hard, holder)
        truth = {"hole": hole, "tip_depth_mm": depth, "cutting_torque_nm": load.torque_nm,
                 "thrust_n": load.thrust_n, "fx_n": load.fx_n, "fy_n": load.fy_n,
                 "tool_temperature_c": temp, "wear_um": wear}
        keep = (depth > 0.0) | (load.torque_nm != 0.0)
        return self._emit(ci, load, {"X1": load.fx_n, "Y1": load.fy_n, "Z1": load.thrust_n},
                          truth, keep)

    def _holes_update(self, ci: CuttingInput, hole: NDArray[np.int64],
                      depth: NDArray[np.float64], feed: NDArray[np.float64], load: Any,
                      temp: NDArray[np.float64], wear: NDArray[np.float64],
                      hard: NDArray[np.float64], holder: NDArray[np.float64] | None) -> None:
        cone = self.cfg.drill.cone_length_mm
        for h in np.unique(hole[(hole >= 0) & (depth > 0.0)]):
            row = self.holes[int(h)]
            sel = (hole == h) & (depth > 0.0)
            idx = np.flatnonzero(sel)
            row["cut_last_cycle"] = int(ci.cycle[idx[-1]])
            row["extraction_s"] = float(ci.time_s[idx[-1]])
            row["tool_temperature_extraction_c"] = float(temp[idx[-1]])
            if holder is not None:  # the tool holder node (ToolThermal.two_node)
                row["tool_holder_temperature_extraction_c"] = float(holder[idx[-1]])
            row["tool_temperature_max_c"] = max(row.get("tool_temperature_max_c", -1e9),
                                                float(temp[sel].max()))
            full = sel & (depth >= cone) & (feed > 0.0)
            if full.any() and "full_engagement_first_cycle" not in row:
                row["full_engagement_first_cycle"] = int(ci.cycle[np.argmax(full)])
            acc = self._acc.setdefault(int(h), [0.0, 0.0, 0.0])
            acc[0] += float(load.torque_nm[full].sum())
            acc[1] += float(load.thrust_n[full].sum())
            acc[2] += float(full.sum())
            if acc[2]:
                row["mean_cutting_torque_nm"] = acc[0] / acc[2]
                row["mean_thrust_n"] = acc[1] / acc[2]
            w, hf = float(wear[idx[0]]), float(hard[idx[0]])
            row["wear_um"] = w
            row["hardness_factor"] = hf
            common: dict[str, Any] = {"drill": self.cfg.drill, "material": self.material,
                                      "wear_um": w,
                      "hardness_factor": hf, "model": self.cfg.drilling}
            row["model_torque_nm"] = float(drill_torque_nm(self.feed_mm_per_rev,
                                                           self.speed_rpm, **common))
            row["model_thrust_n"] = float(drill_thrust_n(self.feed_mm_per_rev,
                                                         self.speed_rpm, **common))
            row.update(self._quality_truth(int(h), row["model_thrust_n"], w))

    def _quality_truth(self, hole: int, thrust_n: float, wear_um: float) -> dict[str, float]:
        """Hidden hole-quality truth of one hole (forces and tool-tip geometry).

        Tool-tip values from the lateral forces and the drill's tip stiffness k
        (:attr:`~cnctwin.sim.tool.Drill.tip_stiffness_n_per_um`): the hole is started where the
        chisel-edge skid force pushes the free tip, e = F_entry,peak / k (position error);
        once the margins guide the drill the static walk shifts the axis by
        F_walk / (g k) (straightness, g = ``guided_stiffness_gain``) and the rotating force
        makes the tip orbit with F_rot / (g k) plus the radial run-out (hole oversize is twice
        the orbit radius). The sub-micrometre slide deviation (which the X/Y encoders see) is
        not included. Forces at full engagement with the programmed feed.
        """
        d, mdl = self.cfg.drill, self.cfg.drilling
        wear_rel = min(max(wear_um / mdl.walk_wear_ref_um, 0.0), 2.0)
        f_rot = float(rotating_force_n(thrust_n, self.feed_mm_per_rev, wear_um, drill=d,
                                       model=mdl))
        f_ent = mdl.entry_force_ratio * (1.0 + mdl.entry_wear_gain * wear_rel) * thrust_n
        f_walk = (mdl.walk_force_ratio_new + (mdl.walk_force_ratio_worn
                                              - mdl.walk_force_ratio_new) * wear_rel) * thrust_n
        k = d.tip_stiffness_n_per_um
        ang = self._entry_dir.get(hole, 0.0)
        e_um = f_ent / k
        orbit = d.radial_runout_um + f_rot / (d.guided_stiffness_gain * k)
        return {
            "entry_direction_rad": ang,
            "entry_force_peak_n": f_ent,
            "rotating_force_n": f_rot,
            "walk_force_n": f_walk,
            "lip_height_difference_um": float(lip_height_difference_um(wear_um, model=mdl)),
            "tip_position_error_x_um": e_um * math.cos(ang),
            "tip_position_error_y_um": e_um * math.sin(ang),
            "tip_position_error_um": e_um,
            "tip_straightness_um": f_walk / (d.guided_stiffness_gain * k),
            "tip_orbit_radius_um": orbit,
            "hole_oversize_um": 2.0 * orbit,
        }


class TappingProcess(_Process):
    """Cutting hook for rigid tapping (:func:`cnctwin.sim.cutting.tapping_load`).

    The spindle runs in position control coupled to Z (interpolator); the commanded speed is
    negative while the tap reverses out. Faults (e.g. :class:`~cnctwin.sim.faults.LooseTool`)
    act on the torque and on the axial force, which is the Z disturbance force.
    """

    def __init__(self, cfg: ScenarioConfig, *, material: Material, **kw: Any) -> None:
        super().__init__(**kw)
        self.cfg = cfg
        self.material = material

    def __call__(self, ci: CuttingInput) -> CuttingOutput:
        z = ci.position["Z1"]
        depth = self.surface_z_mm - z
        n = ci.spindle_speed_rpm
        hole = self._hole_index(depth, ci)
        hard = hardness_factor(self.faults, hole)
        load = tapping_load(depth, n, tap=self.cfg.tap, material=self.material,
                            hardness_factor=hard)
        load = self._faults(load, ci, hole, n, None)
        for h in np.unique(hole[(hole >= 0) & (depth > 0.0)]):
            row = self.holes[int(h)]
            sel = (hole == h) & (depth > 0.0)
            row["cut_last_cycle"] = int(ci.cycle[np.flatnonzero(sel)[-1]])
            ext = sel & (n < 0.0)
            if ext.any():
                row.setdefault("extraction_first_cycle", int(ci.cycle[np.argmax(ext)]))
                row["extraction_last_cycle"] = int(ci.cycle[np.flatnonzero(ext)[-1]])
        truth = {"hole": hole, "tip_depth_mm": depth, "cutting_torque_nm": load.torque_nm,
                 "thrust_n": load.thrust_n}
        keep = (depth > 0.0) | (load.torque_nm != 0.0)
        return self._emit(ci, load, {"Z1": load.thrust_n}, truth, keep)


class MillingProcess(_Process):
    """Cutting hook for end milling (:func:`cnctwin.sim.cutting.milling_load`).

    Axial depth = ``surface_z_mm`` minus the expected actual Z; feed per tooth from the XY path
    speed and the commanded spindle speed; feed direction from the XY velocity; full slot
    (immersion 0..pi) unless ``entry_angle_rad``/``exit_angle_rad`` are given. Forces on the
    tool are the X1/Y1 disturbance forces (Z1: axial force).
    """

    def __init__(self, cfg: ScenarioConfig, *, material: Material,
                 entry_angle_rad: float = 0.0, exit_angle_rad: float = math.pi,
                 **kw: Any) -> None:
        super().__init__(**kw)
        self.cfg = cfg
        self.material = material
        self.entry_angle_rad = entry_angle_rad
        self.exit_angle_rad = exit_angle_rad
        self._direction = 0.0

    def __call__(self, ci: CuttingInput) -> CuttingOutput:
        dt = ci.cycle_time_s
        vx = self._velocity("X1", ci.position["X1"], dt)
        vy = self._velocity("Y1", ci.position["Y1"], dt)
        v_mm_min = np.hypot(vx, vy) * 60.0
        n = np.abs(ci.spindle_speed_rpm)
        flutes = self.cfg.end_mill.flutes
        c = np.where((n > 1.0) & (v_mm_min > 1e-3), v_mm_min / np.maximum(n, 1.0) / flutes, 0.0)
        moving = v_mm_min > 1e-3
        direction = np.where(moving, np.arctan2(vy, vx), np.nan)
        direction = pd.Series(direction).ffill().fillna(self._direction).to_numpy()
        self._direction = float(direction[-1])
        depth = np.maximum(self.surface_z_mm - ci.position["Z1"], 0.0)
        hole = np.zeros(depth.size, dtype=np.int64)
        hard = hardness_factor(self.faults, hole)
        load = milling_load(np.deg2rad(ci.spindle_pos_deg), c, depth, direction,
                            tool=self.cfg.end_mill, material=self.material,
                            entry_angle_rad=self.entry_angle_rad,
                            exit_angle_rad=self.exit_angle_rad, hardness_factor=hard)
        load = self._faults(load, ci, hole, ci.spindle_speed_rpm, None)
        truth = {"axial_depth_mm": depth, "feed_per_tooth_mm": c,
                 "cutting_torque_nm": load.torque_nm, "fx_n": load.fx_n, "fy_n": load.fy_n,
                 "axial_force_n": load.thrust_n}
        keep = depth > 0.0
        return self._emit(ci, load, {"X1": load.fx_n, "Y1": load.fy_n, "Z1": load.thrust_n},
                          truth, keep)


class _NoLoad(_Process):
    """Air cut: no process load; reports progress."""

    def __call__(self, ci: CuttingInput) -> CuttingOutput:
        if self.progress is not None:
            self.progress(float(ci.time_s[-1]), ci.duration_s)
        return CuttingOutput(spindle_torque_nm=np.zeros(len(ci)))


# ----------------------------------------------------------------------------- running
class _EventTee:
    """Forward chunks to a sink and keep the (small) NC event table."""

    def __init__(self, sink: RecordingSink) -> None:
        self.sink = sink
        self.events: list[pd.DataFrame] = []
        # the tee keeps only each chunk's (fresh) events frame: buffer reuse stays safe
        self.keeps_chunks = getattr(sink, "keeps_chunks", True)

    def open(self, columns: list[str], meta: Any) -> None:
        self.sink.open(columns, meta)

    def write(self, chunk: Any) -> None:
        if len(chunk.events):
            self.events.append(chunk.events)
        self.sink.write(chunk)

    def close(self, meta: Any) -> Recording | None:
        return self.sink.close(meta)

    def event_table(self) -> pd.DataFrame:
        return pd.concat(self.events, ignore_index=True) if self.events else pd.DataFrame()


def _make_sink(out: Path | None, stem: str, fmt: str,
               max_file_mb: float | None) -> tuple[RecordingSink | None, Path | None]:
    if fmt not in _FORMATS:
        raise ConfigError(f"fmt must be one of {_FORMATS}, not {fmt!r}")
    if out is None:
        return None, None
    if fmt == "c4a":
        path = out / f"{stem}.json"
        return Capture4AnalysisSink(path, max_file_mb=max_file_mb), path
    path = out / stem
    return ParquetChunkSink(path), path


def _sink_files(sink: Any, path: Path | None) -> list[Path]:
    if sink is None:
        return []
    inner = sink.sink if isinstance(sink, _EventTee) else sink
    files = list(getattr(inner, "files", []))
    if isinstance(inner, ParquetChunkSink) and path is not None:
        return [path]
    return files


def _collect(res: ScenarioResult, sim: Any, sink: Any, path: Path | None,
             daq: _DynamometerDAQ | None, tp: _TruthParquet | None) -> None:
    """Keep a finished simulation in ``res``: the in-memory recording with its first
    dynamometer session attached and its per-cycle truth, or the files written."""
    if sim.recording is not None:
        rec = sim.recording
        if daq is not None and daq.channels:
            rec.external["dynamometer"] = daq.channels[0]
        res.recordings.append(rec)
        res.per_cycle.append(sim.truth["per_cycle"])
    if path is not None:
        res.recording_paths.append(path)
        res.paths += _sink_files(sink, path) + (daq.paths if daq is not None else [])
        if tp is not None and tp.close() is not None:
            res.paths.append(tp.path)


def _sim_seed(seed: int, *key: int) -> int:
    return int(np.random.SeedSequence([seed, *key]).generate_state(1)[0])


def _simulate(program: Program, cfg: ScenarioConfig, *, seed: int, hook: Any,
              sink: Any, chunk_cycles: int) -> SimulationResult:
    return simulate(program, cfg.machine, seed=seed, start_cycle=START_CYCLE,
                    start_time=START_TIME, cutting=hook, sink=sink, chunk_cycles=chunk_cycles)


def _prepare(out: str | Path | None) -> Path | None:
    if out is None:
        return None
    p = Path(out)
    p.mkdir(parents=True, exist_ok=True)
    return p


def _write_program(out: Path | None, name: str, text: str, paths: list[Path]) -> None:
    if out is not None:
        p = out / name
        p.write_text(text, encoding="utf-8")
        paths.append(p)


def _json_default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    if isinstance(o, pd.Timestamp):
        return o.isoformat()
    if isinstance(o, pd.DataFrame):
        return o.to_dict("records")
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def _write_truth(out: Path | None, truth: dict[str, Any], paths: list[Path]) -> None:
    if out is None:
        return
    p = out / "truth.json"
    p.write_text(json.dumps(truth, indent=1, default=_json_default), encoding="utf-8")
    paths.append(p)


def _base_truth(name: str, seed: int, overrides: Mapping[str, Any] | None,
                cfg: ScenarioConfig) -> dict[str, Any]:
    return {"scenario": name, "seed": seed, "overrides": dict(overrides or {}),
            "start_cycle": START_CYCLE, "start_time": START_TIME.isoformat(),
            "cycle_time_s": cfg.machine.cycle_time_s, **cfg.to_dict()}


def _faults_from(faults: Sequence[Fault | Mapping[str, Any]]) -> tuple[Fault, ...]:
    """Faults given as objects or as dicts with a ``type`` key (CLI / JSON)."""
    from cnctwin.sim import faults as fmod

    out: list[Fault] = []
    for f in faults:
        if isinstance(f, Mapping):
            d = dict(f)
            kind = d.pop("type", None)
            cls = getattr(fmod, str(kind), None)
            known = ("LooseTool", "ToolBreakage", "Chatter", "HardnessChange")
            if kind not in known or cls is None:
                raise ConfigError(f"fault {f!r}: 'type' must be LooseTool, ToolBreakage, "
                                  "Chatter or HardnessChange")
            try:
                out.append(cls(**d))
            except TypeError as exc:
                raise ConfigError(f"fault {f!r}: {exc}") from exc
        else:
            out.append(f)
    return tuple(out)


def _rec_time_s(cycle: int, cfg: ScenarioConfig) -> float:
    return (cycle - START_CYCLE) * cfg.machine.cycle_time_s


# ----------------------------------------------------------------------------- scenarios
def air_cut_sweep(
    out: str | Path | None = None,
    *,
    seed: int = 0,
    overrides: Mapping[str, Any] | None = None,
    machine: Machine | None = None,
    n_speeds: int = 126,
    max_speed_rpm: float = 18000.0,
    min_speed_rpm: float | None = None,
    speeds_rpm: Sequence[float] | None = None,
    dwell_s: float = 3.0,
    settle_s: float = 0.5,
    fmt: str = "c4a",
    max_file_mb: float | None = None,
    chunk_cycles: int = 50_000,
    progress: ProgressFn | None = None,
) -> ScenarioResult:
    """Air cut at ``n_speeds`` constant spindle speeds up to 18000 rpm (thesis §3.2.2, Fig. 3.8).

    Program :func:`cnctwin.sim.programs.air_cut_sweep_program` (``S.. M3`` then ``G4 F dwell_s`` per
    speed; the NC waits for the speed ramp). Default speeds
    :data:`~cnctwin.sim.programs.AIR_CUT_SPEEDS_RPM`; otherwise ``n_speeds`` equally spaced from
    ``min_speed_rpm`` (default ``max_speed_rpm / n_speeds``).

    Truth ``steps``: per speed the cycle range of the steady window (the dwell after
    ``settle_s``).

    Parameters
    ----------
    out : str or path-like, optional
        Output folder (recordings, ``truth.json``, sensor files); None keeps everything in memory.
    seed : int, default 0
        Random seed of the noise and of every drawn hidden value.
    overrides : mapping, optional
        Dotted machine/process parameters set on top of ``machine`` (``{"spindle.kt_nm_per_a":
        0.9}``).
    machine : Machine, optional
        Base machine description; default :meth:`Machine.thesis_default`.
    n_speeds : int, default 126
        Number of plateaus (thesis: 126).
    max_speed_rpm : float, default 18000.0
        Highest speed [rpm].
    min_speed_rpm : float, optional
        Lowest speed [rpm]; default the first step.
    speeds_rpm : sequence, optional
        Explicit plateau speeds in order [rpm] (replaces ``n_speeds``/min/max; a speed may repeat).
    dwell_s : float, default 3.0
        Time at each speed [s].
    settle_s : float, default 0.5
        Time after a speed change before the plateau counts [s].
    fmt : str, default 'c4a'
        Recording format: ``'c4a'`` (Capture4Analysis JSON) or ``'parquet'`` (chunk directory).
    max_file_mb : float, optional
        Split a Capture4Analysis recording into files of at most this size [MB]; None: one file.
    chunk_cycles : int, default 50000
        Cycles simulated and written per chunk (bounds memory).
    progress : callable, optional
        Called with (fraction done 0..1, message) while the scenario runs.

    Returns
    -------
    ScenarioResult
        Recordings (or their files), the hidden truth and the scenario's options.
    """
    cfg = ScenarioConfig.build(overrides, machine=machine)
    o = _prepare(out)
    if speeds_rpm is not None:
        speeds = np.asarray(speeds_rpm, dtype=np.float64)
        if speeds.ndim != 1 or speeds.size == 0 or not np.all(speeds > 0):
            raise ConfigError(f"speeds_rpm must be a list of positive speeds, not {speeds_rpm!r}")
    elif n_speeds == 126 and max_speed_rpm == 18000.0 and min_speed_rpm is None:
        speeds = np.asarray(AIR_CUT_SPEEDS_RPM)
    else:
        lo = min_speed_rpm if min_speed_rpm is not None else max_speed_rpm / n_speeds
        speeds = np.round(np.linspace(lo, max_speed_rpm, n_speeds), 0)
    text = air_cut_sweep_program([float(s) for s in speeds], dwell_s=dwell_s)
    prog = parse_program(text)
    res = ScenarioResult("air_cut_sweep", truth=_base_truth("air_cut_sweep", seed, overrides, cfg))
    _write_program(o, "air_cut_sweep.mpf", text, res.paths)
    sink, path = _make_sink(o, "air_cut_sweep", fmt, max_file_mb)
    tee = _EventTee(sink) if sink is not None else None
    prog_fn = _Progress(progress, "air cut")
    hook = _NoLoad(surface_z_mm=0.0, faults=(), rng=np.random.default_rng(seed), truth=None,
                   daq=None, progress=prog_fn)
    sim = _simulate(prog, cfg, seed=seed, hook=hook, sink=tee, chunk_cycles=chunk_cycles)
    if sim.recording is not None:
        events = sim.recording.events
        res.recordings.append(sim.recording)
        res.per_cycle.append(sim.truth["per_cycle"])
    else:
        assert tee is not None
        events = tee.event_table()
    res.truth["steps"] = _steady_windows(events, settle_cycles=round(settle_s /
                                                                      cfg.machine.cycle_time_s))
    res.truth["n_cycles"] = sim.trajectory["n_cycles"]
    if path is not None:
        res.recording_paths.append(path)
        res.paths += _sink_files(tee, path)
    _write_truth(o, res.truth, res.paths)
    return res


def _steady_windows(events: pd.DataFrame, *, settle_cycles: int) -> list[dict[str, Any]]:
    """Dwell windows after each ``S.. M3`` from the NC block events."""
    blocks = events[events["kind"] == "block"].sort_values("cycle", kind="stable")
    rows = blocks[["cycle", "gcode"]].to_numpy()
    out: list[dict[str, Any]] = []
    speed: float | None = None
    for k, (cyc, gcode) in enumerate(rows):
        g = str(gcode)
        for word in g.split():
            if word.startswith("S") and word[1:].replace(".", "", 1).isdigit():
                speed = float(word[1:])
        if g.startswith("G4") and speed is not None and k + 1 < len(rows):
            first = int(cyc) + settle_cycles
            last = int(rows[k + 1][0]) - 1
            if last > first:
                out.append({"speed_rpm": speed, "first_cycle": first, "last_cycle": last})
    return out


def warm_up(
    out: str | Path | None = None,
    *,
    seed: int = 0,
    overrides: Mapping[str, Any] | None = None,
    machine: Machine | None = None,
    speeds_rpm: Sequence[float] = (5000.0, 7000.0),
    minutes: float = 25.0,
    fmt: str = "c4a",
    max_file_mb: float | None = 200.0,
    chunk_cycles: int = 50_000,
    progress: ProgressFn | None = None,
) -> ScenarioResult:
    """Spindle turning ``minutes`` at each speed from a cold start (thesis §4.2, Fig. 4.4).

    One recording per speed (program :func:`cnctwin.sim.programs.warm_up_program`); the motor
    warms up and the current falls. Truth ``runs``: per minute the rotor and stator
    temperature, Kt and the friction torque. Each run is simulated in memory (it needs the
    per-cycle drive truth; ~1.5 GB peak for 25 min) and then written.

    Parameters
    ----------
    out : str or path-like, optional
        Output folder (recordings, ``truth.json``, sensor files); None keeps everything in memory.
    seed : int, default 0
        Random seed of the noise and of every drawn hidden value.
    overrides : mapping, optional
        Dotted machine/process parameters set on top of ``machine`` (``{"spindle.kt_nm_per_a":
        0.9}``).
    machine : Machine, optional
        Base machine description; default :meth:`Machine.thesis_default`.
    speeds_rpm : sequence, default (5000.0, 7000.0)
        Speeds, one recording each, each from a cold motor [rpm].
    minutes : float, default 25.0
        Time at each speed [min].
    fmt : str, default 'c4a'
        Recording format: ``'c4a'`` (Capture4Analysis JSON) or ``'parquet'`` (chunk directory).
    max_file_mb : float, default 200.0
        Split a Capture4Analysis recording into files of at most this size [MB]; None: one file.
    chunk_cycles : int, default 50000
        Cycles simulated and written per chunk (bounds memory).
    progress : callable, optional
        Called with (fraction done 0..1, message) while the scenario runs.

    Returns
    -------
    ScenarioResult
        Recordings (or their files), the hidden truth and the scenario's options.
    """
    cfg = ScenarioConfig.build(overrides, machine=machine)
    o = _prepare(out)
    res = ScenarioResult("warm_up", truth={**_base_truth("warm_up", seed, overrides, cfg),
                                           "minutes": minutes, "runs": []})
    ct = cfg.machine.cycle_time_s
    for i, s in enumerate(speeds_rpm):
        text = warm_up_program(float(s), minutes=minutes)
        prog = parse_program(text)
        stem = f"warm_up_{int(s)}rpm"
        _write_program(o, f"{stem}.mpf", text, res.paths)
        pf = _Progress(progress, f"{s:.0f} rpm", done=i / len(speeds_rpm),
                       share=1.0 / len(speeds_rpm))
        hook = _NoLoad(surface_z_mm=0.0, faults=(), rng=np.random.default_rng(seed), truth=None,
                       daq=None, progress=pf)
        sim = _simulate(prog, cfg, seed=_sim_seed(seed, i), hook=hook, sink=None,
                        chunk_cycles=chunk_cycles)
        rec = sim.recording
        assert rec is not None
        pc = sim.truth["per_cycle"]
        minute = round(60.0 / ct)
        pick = pc.iloc[minute - 1::minute]
        res.truth["runs"].append({
            "speed_rpm": float(s),
            "rotor_temperature_c_per_min": pick["spindle_rotor_temperature_c"].tolist(),
            "kt_nm_per_a_per_min": pick["spindle_kt_nm_per_a"].tolist(),
            "friction_nm_per_min": pick["spindle_friction_nm"].tolist(),
            "stator_temperature_c_per_min": _lf_per_minute(rec, "MOTOR_TEMP|SP1", minute),
            "recording": f"{stem}.json" if fmt == "c4a" else stem,
        })
        if o is not None:
            res.recording_paths.append(_write_recording(rec, o, stem, fmt, max_file_mb,
                                                        res.paths))
            del rec, sim, pc
        else:
            res.recordings.append(rec)
            res.per_cycle.append(pc)
    _write_truth(o, res.truth, res.paths)
    return res


def _lf_per_minute(rec: Recording, signal: str, minute: int) -> list[float]:
    lf = rec.lf
    if lf is None or not len(lf):
        return []
    s = lf[lf["signal"] == signal]
    c = s["cycle"].to_numpy() - int(rec.cycles[0])
    v = s["value"].to_numpy()
    targets = np.arange(minute - 1, int(rec.cycles[-1] - rec.cycles[0]) + 1, minute)
    idx = np.searchsorted(c, targets, side="right") - 1
    return [float(v[k]) for k in idx if k >= 0]


def _write_recording(rec: Recording, out: Path, stem: str, fmt: str,
                     max_file_mb: float | None, paths: list[Path]) -> Path:
    """Write an in-memory recording as C4A (chained) or a Parquet chunk directory."""
    if fmt not in _FORMATS:
        raise ConfigError(f"fmt must be one of {_FORMATS}, not {fmt!r}")
    if fmt == "c4a":
        from cnctwin.iotools.capture4analysis import write_capture4analysis

        path = out / f"{stem}.json"
        paths += list(write_capture4analysis(rec, path, max_file_mb=max_file_mb))
        return path
    from cnctwin.sim.recorder import RecordedChunk

    path = out / stem
    sink = ParquetChunkSink(path)
    cols = [c for c in rec.hf.columns if c != "time"]
    sink.open(cols, rec.meta)
    step = 50_000
    cyc = rec.cycles
    for a in range(0, cyc.size, step):
        part = rec.hf.iloc[a:a + step]
        lf = rec.lf if a == 0 and rec.lf is not None else pd.DataFrame(columns=["cycle"])
        ev = rec.events if a == 0 and rec.events is not None else pd.DataFrame(columns=["kind"])
        sink.write(RecordedChunk(cycles=cyc[a:a + step],
                                 hf={c: part[c].to_numpy() for c in cols}, lf=lf, events=ev))
    sink.close(rec.meta)
    paths.append(path)
    return path


THESIS_VALIDATION_CUTS: tuple[tuple[str, float, float], ...] = (
    ("aisi1045", 2400.0, 0.16),
    ("grey_cast_iron", 2400.0, 0.30),
    ("aisi1045", 2800.0, 0.14),
    ("grey_cast_iron", 3200.0, 0.40),
    ("aisi1045", 3200.0, 0.125),
)
"""Thesis drilling cuts (§4.3 calibration + Table 4.1): material, speed [rpm], feed [mm/rev]."""


def drilling_validation(
    out: str | Path | None = None,
    *,
    seed: int = 0,
    overrides: Mapping[str, Any] | None = None,
    machine: Machine | None = None,
    depth_mm: float = 20.0,
    cuts: Sequence[tuple[str, float, float]] = THESIS_VALIDATION_CUTS,
    fmt: str = "c4a",
    max_file_mb: float | None = None,
    chunk_cycles: int = 50_000,
    progress: ProgressFn | None = None,
) -> ScenarioResult:
    """The thesis drilling cuts with the dynamometer attached (thesis §4.3, Table 4.1).

    Per cut (material, rpm, mm/rev) one program
    (:func:`~cnctwin.sim.programs.drilling_validation_program`, G95, CYCLE81, 8.5 mm carbide
    drill), one recording and one dynamometer CSV on its own clock. Truth per cut: the model's
    mean full-engagement torque, the first full-engagement cycle, the last cycle in the
    material, the simulated mean torque and the dynamometer session clock.

    Parameters
    ----------
    out : str or path-like, optional
        Output folder (recordings, ``truth.json``, sensor files); None keeps everything in memory.
    seed : int, default 0
        Random seed of the noise and of every drawn hidden value.
    overrides : mapping, optional
        Dotted machine/process parameters set on top of ``machine`` (``{"spindle.kt_nm_per_a":
        0.9}``).
    machine : Machine, optional
        Base machine description; default :meth:`Machine.thesis_default`.
    depth_mm : float, default 20.0
        Hole depth [mm].
    cuts : sequence of (str, float, float)
        (material, speed [rpm], feed [mm/rev]) per cut, in order; default the five cuts of
        thesis Table 4.1 (steel and cast iron, 2400-3200 rpm).
    fmt : str, default 'c4a'
        Recording format: ``'c4a'`` (Capture4Analysis JSON) or ``'parquet'`` (chunk directory).
    max_file_mb : float, optional
        Split a Capture4Analysis recording into files of at most this size [MB]; None: one file.
    chunk_cycles : int, default 50000
        Cycles simulated and written per chunk (bounds memory).
    progress : callable, optional
        Called with (fraction done 0..1, message) while the scenario runs.

    Returns
    -------
    ScenarioResult
        Recordings (or their files), the hidden truth and the scenario's options.
    """
    cfg = ScenarioConfig.build(overrides, machine=machine)
    o = _prepare(out)
    res = ScenarioResult("drilling_validation",
                         truth={**_base_truth("drilling_validation", seed, overrides, cfg),
                                "depth_mm": depth_mm, "cuts": []})
    for i, (mat, n, f) in enumerate(cuts):
        if mat not in cfg.materials:
            raise ConfigError(f"cut {i}: unknown material {mat!r}; known: {sorted(cfg.materials)}")
        material = cfg.materials[mat]
        tag = f"{i + 1}_{mat}_{int(n)}rpm_{f:g}".replace(".", "p")
        text = drilling_validation_program(n, f, depth_mm)
        prog = parse_program(text)
        _write_program(o, f"drill_{tag}.mpf", text, res.paths)
        rng = np.random.default_rng([seed, i, 1])
        daq = _DynamometerDAQ(cfg.dynamometer, np.random.default_rng([seed, i, 2]), o,
                              f"dynamometer_{tag}")
        tp = _TruthParquet(o / f"truth_per_cycle_{tag}.parquet") if o is not None else None
        pf = _Progress(progress, f"{mat} {n:.0f} rpm",
                       done=i / len(cuts), share=1.0 / len(cuts))
        hook = DrillingProcess(cfg, material=material, feed_mm_per_rev=f, speed_rpm=n,
                               hole_depth_mm=depth_mm, surface_z_mm=0.0, faults=(), rng=rng,
                               truth=tp, daq=daq, progress=pf)
        sink, path = _make_sink(o, f"drill_{tag}", fmt, max_file_mb)
        sim = _simulate(prog, cfg, seed=_sim_seed(seed, i), hook=hook, sink=sink,
                        chunk_cycles=chunk_cycles)
        daq.close()
        hole = hook.hole_rows()[0] if hook.holes else {}
        res.truth["cuts"].append({
            "material": mat, "speed_rpm": n, "feed_mm_per_rev": f,
            "model_mean_torque_nm": float(drill_torque_nm(f, n, drill=cfg.drill,
                                                          material=material,
                                                          model=cfg.drilling)),
            "simulated_mean_torque_nm": hole.get("mean_cutting_torque_nm"),
            "cut_first_cycle": hole.get("cut_first_cycle"),
            "full_engagement_first_cycle": hole.get("full_engagement_first_cycle"),
            "cut_last_cycle": hole.get("cut_last_cycle"),
            "recording": path.name if path is not None else None,
            "dynamometer": daq.sessions,
        })
        _collect(res, sim, sink, path, daq, tp)
    _write_truth(o, res.truth, res.paths)
    return res


def _wear_program(n_holes: int, holes_per_set: int, gap_s: float, **kw: Any) -> str:
    """:func:`~cnctwin.sim.programs.hole_pattern` with a ``G4`` pause before each set > 1."""
    text = hole_pattern(n_holes, set_size=holes_per_set, **kw)
    if gap_s <= 0:
        return text
    lines = []
    for line in text.splitlines():
        if line.startswith("; set ") and line.strip() != "; set 1":
            lines.append(f"G4 F{gap_s:g}")
        lines.append(line)
    return "\n".join(lines) + "\n"


def tool_wear_run(
    out: str | Path | None = None,
    *,
    seed: int = 0,
    overrides: Mapping[str, Any] | None = None,
    machine: Machine | None = None,
    n_holes: int = 2676,
    holes_per_set: int = 6,
    start_hole: int = 0,
    depth_mm: float = 20.0,
    speed_rpm: float = 2400.0,
    feed_mm_per_min: float = 400.0,
    gap_between_sets_s: float = 4.0,
    cycle: str = "CYCLE81",
    walk_direction_rad: float = 0.7,
    faults: Sequence[Fault | Mapping[str, Any]] = (),
    dynamometer: bool = True,
    initial_tool_temperature_c: float | None = None,
    fmt: str = "parquet",
    max_file_mb: float | None = 500.0,
    chunk_cycles: int = 50_000,
    progress: ProgressFn | None = None,
) -> ScenarioResult:
    """Tool-wear run: AISI 1045, 20 mm holes, 2400 rpm, 400 mm/min, sets of 6 (thesis §5.1-5.3).

    Program :func:`~cnctwin.sim.programs.hole_pattern` (CYCLE81, holes in sets of
    ``holes_per_set`` along Y) with a ``G4 F gap_between_sets_s`` pause between sets (the
    spindle keeps turning, the tool cools). Streamed to ``out`` chunk by chunk with bounded
    memory: the recording (Parquet chunk directory by default, or chained Capture4Analysis
    files), the dynamometer (one CSV session per set, own clock), the thermal camera (one
    reading per hole, ``delay_s`` after extraction, own clock), ``holes.csv`` (true wear,
    temperatures, model and simulated torque per hole) and ``truth_per_cycle.parquet``.

    Machine time (default 4 s pause, [D]): per hole the feed from the R plane (2 mm above
    the surface) to 20 mm depth takes 22 mm / 400 mm/min = 3.30 s; the G0 retract to the
    10 mm retract plane, the 12 mm step to the next hole (15 mm X, 60 mm Y back between sets)
    and the G0 down to the R plane take 0.70 s with the jerk-limited rapid of the default
    machine, so 4.0 s per hole and 2676 x 4.0 s = 10 690 s = 2.97 h without pauses. The
    issue's "about 3.5 h of machining" (12 600 s; the thesis itself gives no duration) leaves
    (12 600 - 10 690) s / 445 pauses = 4.3 s per pause: ``G4 F4`` -> 12 471 s = 3.46 h as
    planned by the interpolator (the former 30 s gave 6.7 h).

    Tool temperature with 4 s pauses (lumped model, time constant R C = 24 s): the first sets
    from a cold tool rise by ~+300 degC through the set as in thesis Fig. 5.5, but after ~10
    sets the run settles at a hot level with only a ~65 K rise through each set and an equal
    drop between sets - 4 s of extra cooling against 24 s of drilling cannot reset the tool. A
    large set pattern at every set (thesis Fig. 5.3) needs pauses of the order of the time
    constant (30 s: +230 K per set, 6.7 h); pass ``gap_between_sets_s=30`` for that reading.

    Parameters
    ----------
    gap_between_sets_s : float, default 4
        ``G4`` pause before each set after the first [s].
    start_hole : int, default 0
        Holes the drill had already drilled (wear of hole k is ``flank_wear_um(start_hole+k)``).
    faults : sequence
        :class:`~cnctwin.sim.faults.ToolBreakage`, :class:`~cnctwin.sim.faults.Chatter`,
        :class:`~cnctwin.sim.faults.HardnessChange` ... (or dicts with ``type``); hole numbers
        count from ``start_hole``.
    dynamometer : bool, default True
        Record the dynamometer.
    initial_tool_temperature_c : float, optional
        Tool-tip temperature at the start [degC]; default ambient (cold tool). With
        ``start_hole`` it continues a run simulated in pieces without a cold restart (pass the
        previous piece's ``truth["final_tool_temperature_c"]``).

    out : str or path-like, optional
        Output folder (recordings, ``truth.json``, sensor files); None keeps everything in memory.
    seed : int, default 0
        Random seed of the noise and of every drawn hidden value.
    overrides : mapping, optional
        Dotted machine/process parameters set on top of ``machine`` (``{"spindle.kt_nm_per_a":
        0.9}``).
    machine : Machine, optional
        Base machine description; default :meth:`Machine.thesis_default`.
    n_holes : int, default 2676
        Holes drilled (thesis: 2676).
    holes_per_set : int, default 6
        Holes per set (one workpiece), then a pause.
    depth_mm : float, default 20.0
        Hole depth [mm].
    speed_rpm : float, default 2400.0
        Spindle speed [rpm].
    feed_mm_per_min : float, default 400.0
        Feed [mm/min].
    cycle : str, default 'CYCLE81'
        Drilling cycle of the program (``CYCLE81``, ``CYCLE83``).
    walk_direction_rad : float, default 0.7
        Direction of the drill's static walk in the X/Y plane [rad].
    fmt : str, default 'parquet'
        Recording format: ``'c4a'`` (Capture4Analysis JSON) or ``'parquet'`` (chunk directory).
    max_file_mb : float, default 500.0
        Split a Capture4Analysis recording into files of at most this size [MB]; None: one file.
    chunk_cycles : int, default 50000
        Cycles simulated and written per chunk (bounds memory).
    progress : callable, optional
        Called with (fraction done 0..1, message) while the scenario runs.

    Returns
    -------
    ScenarioResult
        Recordings (or their files), the hidden truth and the scenario's options.
    """
    cfg = ScenarioConfig.build(overrides, machine=machine)
    o = _prepare(out)
    flist = _faults_from(faults)
    feed = feed_mm_per_min / speed_rpm
    text = _wear_program(n_holes, holes_per_set, gap_between_sets_s, depth_mm=depth_mm,
                         speed_rpm=speed_rpm, feedrate_mm_min=feed_mm_per_min, cycle=cycle)
    prog = parse_program(text)
    gap_blocks = [k for k, b in enumerate(prog.blocks) if b.kind == "dwell"]
    res = ScenarioResult("tool_wear_run", truth={
        **_base_truth("tool_wear_run", seed, overrides, cfg), "n_holes": n_holes,
        "holes_per_set": holes_per_set, "start_hole": start_hole, "depth_mm": depth_mm,
        "speed_rpm": speed_rpm, "feed_mm_per_rev": feed, "feed_mm_per_min": feed_mm_per_min,
        "gap_between_sets_s": gap_between_sets_s, "cycle": cycle,
        "walk_direction_rad": walk_direction_rad, "faults": [fault_to_dict(f) for f in flist]})
    _write_program(o, "tool_wear_run.mpf", text, res.paths)
    daq = (_DynamometerDAQ(cfg.dynamometer, np.random.default_rng([seed, 2]), o, "dynamometer")
           if dynamometer else None)
    tp = _TruthParquet(o / "truth_per_cycle.parquet") if o is not None else None
    pf = _Progress(progress, "wear run")
    hook = DrillingProcess(cfg, material=cfg.materials["aisi1045"], feed_mm_per_rev=feed,
                           speed_rpm=speed_rpm, hole_depth_mm=depth_mm,
                           walk_direction_rad=walk_direction_rad, surface_z_mm=0.0,
                           faults=flist, rng=np.random.default_rng([seed, 1]), truth=tp,
                           daq=daq, daq_off_blocks=gap_blocks, progress=pf,
                           first_hole=start_hole,
                           initial_tool_temperature_c=initial_tool_temperature_c)
    sink, path = _make_sink(o, "tool_wear_run", fmt, max_file_mb)
    sim = _simulate(prog, cfg, seed=seed, hook=hook, sink=sink, chunk_cycles=chunk_cycles)
    if daq is not None:
        daq.close()
    rows = hook.hole_rows()
    th = cfg.tool_thermal
    for r in rows:
        r["set"] = (r["hole"] - start_hole) // holes_per_set
        r["position_in_set"] = (r["hole"] - start_hole) % holes_per_set
        # camera reading delay_s after extraction: the tool cools freely (the same model:
        # one node, or the tip with its holder)
        holder_c = r.get("tool_holder_temperature_extraction_c", th.ambient_temperature_c)
        r["tool_temperature_camera_c"] = free_cooling(
            r["tool_temperature_extraction_c"], holder_c, cfg.camera.delay_s, th)
    cam = None
    if rows:
        cam = thermal_camera_channel([r["extraction_s"] for r in rows],
                                     [r["hole"] for r in rows],
                                     [r["tool_temperature_camera_c"] for r in rows],
                                     camera=cfg.camera, rng=np.random.default_rng([seed, 3]))
    res.truth["holes"] = rows
    res.truth["fault_onsets_s"] = hook.onsets
    res.truth["final_wear_um"] = float(flank_wear_um(start_hole + n_holes - 1, curve=cfg.wear))
    res.truth["initial_tool_temperature_c"] = hook.initial_temperature_c
    res.truth["final_tool_temperature_c"] = hook.temperature_c
    res.truth["dynamometer_sessions"] = daq.sessions if daq is not None else []
    res.truth["n_cycles"] = sim.trajectory["n_cycles"]
    if sim.recording is not None:
        rec = sim.recording
        if daq is not None:
            for k, ch in enumerate(daq.channels):
                rec.external["dynamometer" if k == 0 else f"dynamometer_{k + 1:04d}"] = ch
        if cam is not None:
            rec.external["thermal_camera"] = cam
        res.recordings.append(rec)
        res.per_cycle.append(sim.truth["per_cycle"])
    if o is not None and path is not None:
        res.recording_paths.append(path)
        res.paths += _sink_files(sink, path)
        if daq is not None:
            res.paths += daq.paths
        if cam is not None:
            res.paths.append(write_thermal_camera_csv(cam, o / "thermal_camera.csv"))
        p = o / "holes.csv"
        pd.DataFrame(rows).to_csv(p, index=False)
        res.paths.append(p)
        if tp is not None and tp.close() is not None:
            res.paths.append(tp.path)
    _write_truth(o, res.truth, res.paths)
    return res


def loose_tap(
    out: str | Path | None = None,
    *,
    seed: int = 0,
    overrides: Mapping[str, Any] | None = None,
    machine: Machine | None = None,
    n_holes: int = 4,
    loose_from_hole: int = 2,
    depth_mm: float = 12.0,
    speed_rpm: float = 400.0,
    fmt: str = "c4a",
    max_file_mb: float | None = None,
    chunk_cycles: int = 50_000,
    progress: ProgressFn | None = None,
) -> ScenarioResult:
    """Rigid tapping M8x1.25 in steel; the tap comes loose on extraction (thesis §5.4, Fig 5.10).

    Program :func:`~cnctwin.sim.programs.tapping_program` (CYCLE84): the spindle is in position
    control coupled to Z. From hole ``loose_from_hole`` (0-based) on, a
    :class:`~cnctwin.sim.faults.LooseTool` (override its fields with ``loose_tool.<field>``)
    adds a fluctuating torque (spindle current) and axial force (Z disturbance -> Z ENC_POS)
    while the tap reverses out. Truth per hole: cut and extraction cycle ranges; fault onset.

    Parameters
    ----------
    out : str or path-like, optional
        Output folder (recordings, ``truth.json``, sensor files); None keeps everything in memory.
    seed : int, default 0
        Random seed of the noise and of every drawn hidden value.
    overrides : mapping, optional
        Dotted machine/process parameters set on top of ``machine`` (``{"spindle.kt_nm_per_a":
        0.9}``).
    machine : Machine, optional
        Base machine description; default :meth:`Machine.thesis_default`.
    n_holes : int, default 4
        Tapped holes.
    loose_from_hole : int, default 2
        First hole (0-based) whose tap slips in its holder on extraction.
    depth_mm : float, default 12.0
        Thread depth [mm].
    speed_rpm : float, default 400.0
        Tapping speed [rpm].
    fmt : str, default 'c4a'
        Recording format: ``'c4a'`` (Capture4Analysis JSON) or ``'parquet'`` (chunk directory).
    max_file_mb : float, optional
        Split a Capture4Analysis recording into files of at most this size [MB]; None: one file.
    chunk_cycles : int, default 50000
        Cycles simulated and written per chunk (bounds memory).
    progress : callable, optional
        Called with (fraction done 0..1, message) while the scenario runs.

    Returns
    -------
    ScenarioResult
        Recordings (or their files), the hidden truth and the scenario's options.
    """
    ov = dict(overrides or {})
    lt = {k.split(".", 1)[1]: ov.pop(k) for k in list(ov) if k.startswith("loose_tool.")}
    cfg = ScenarioConfig.build(ov, machine=machine)
    fault = _replace(LooseTool(start_hole=loose_from_hole), lt, "loose_tool")
    o = _prepare(out)
    text = tapping_program(n_holes, pitch_mm=cfg.tap.pitch_mm, depth_mm=depth_mm,
                           speed_rpm=speed_rpm)
    prog = parse_program(text)
    res = ScenarioResult("loose_tap", truth={
        **_base_truth("loose_tap", seed, overrides, cfg), "n_holes": n_holes,
        "depth_mm": depth_mm, "speed_rpm": speed_rpm, "faults": [fault_to_dict(fault)]})
    _write_program(o, "loose_tap.mpf", text, res.paths)
    daq = _DynamometerDAQ(cfg.dynamometer, np.random.default_rng([seed, 2]), o, "dynamometer")
    tp = _TruthParquet(o / "truth_per_cycle.parquet") if o is not None else None
    pf = _Progress(progress, "tapping")
    hook = TappingProcess(cfg, material=cfg.materials["aisi1045"], surface_z_mm=0.0,
                          faults=(fault,), rng=np.random.default_rng([seed, 1]), truth=tp,
                          daq=daq, progress=pf)
    sink, path = _make_sink(o, "loose_tap", fmt, max_file_mb)
    sim = _simulate(prog, cfg, seed=seed, hook=hook, sink=sink, chunk_cycles=chunk_cycles)
    daq.close()
    res.truth["holes"] = hook.hole_rows()
    res.truth["fault_onsets_s"] = hook.onsets
    res.truth["dynamometer_sessions"] = daq.sessions
    _collect(res, sim, sink, path, daq, tp)
    _write_truth(o, res.truth, res.paths)
    return res


def _milling_program(side_mm: float, radius_mm: float, gap_mm: float,
                     air_moves_mm_min: Sequence[float] = (), air_stroke_mm: float = 60.0,
                     **kw: Any) -> str:
    """Square (first corner at the origin) then circle right of it, one program; optional
    air moves of X and Y at the clearance height first (out and back at each feed)."""
    sq = square_path(side_mm, **kw).splitlines()
    sq = [line for line in sq if line.strip() not in ("M30", "M5 M9")]
    if air_moves_mm_min:
        at = next(i for i, line in enumerate(sq) if line.startswith("G0 X"))
        air = ["; air moves clear of the part (approach at feed)"]
        for f in air_moves_mm_min:
            air += [f"G1 X{air_stroke_mm:g} F{f:g}", "X0", f"Y{air_stroke_mm:g}", "Y0"]
        sq = sq[:at + 1] + air + sq[at + 1:]
    center = (side_mm + gap_mm + radius_mm, side_mm / 2.0)
    ci = circle_path(radius_mm, center_xy=center, **kw).splitlines()
    ci = [line for line in ci if not line.startswith(("G90", "T", "S"))]
    return "\n".join(sq + ci) + "\n"


def milling_square_circle(
    out: str | Path | None = None,
    *,
    seed: int = 0,
    overrides: Mapping[str, Any] | None = None,
    machine: Machine | None = None,
    randomize_loop: bool = False,
    side_mm: float = 40.0,
    radius_mm: float = 20.0,
    speed_rpm: float = 6000.0,
    feed_per_tooth_mm: float = 0.167,
    depth_mm: float = 0.5,
    air_moves_mm_min: Sequence[float] = (),
    faults: Sequence[Fault | Mapping[str, Any]] = (),
    fmt: str = "c4a",
    max_file_mb: float | None = None,
    chunk_cycles: int = 50_000,
    progress: ProgressFn | None = None,
) -> ScenarioResult:
    """Milling a square and a circle in Al7050-T7451 (thesis §3.1.2, Figs. 3.2 and 3.3).

    16 mm two-flute carbide end mill (``end_mill.*``), 0.5 mm axial depth, 0.167 mm/tooth
    (F = fz z n = 2004 mm/min at the assumed 6000 rpm), full-slot cut; programs
    :func:`~cnctwin.sim.programs.square_path` (G64) and :func:`~cnctwin.sim.programs.circle_path`
    (G3). The recording has every position-loop signal per axis (``DES_POS``, ``CTRL_POS``,
    ``ENC_POS``, ``CTRL_DIFF``, ``CTRL_DIFF2``, ``CONT_DEV``, ``VEL_FFW``, ``TORQUE_FFW``,
    ``CMD_SPEED``, ``CURRENT``, ``TORQUE``, ``LOAD``, ``POWER``).

    Parameters
    ----------
    out : str or path, optional
        Output directory; ``None`` keeps ``result.recording`` in memory.
    seed : int
        Seed of every random stream (and of the loop draw with ``randomize_loop``).
    overrides : mapping, optional
        Dotted overrides, e.g. ``{"axes.X1.kv_m_min_per_mm": 3.1}``.
    machine : Machine, optional
        Base machine (e.g. one with hidden loop parameters); overrides apply on top.
    randomize_loop : bool, default False
        Draw the X/Y loop parameters with :func:`random_loop_overrides` (``seed``) before
        ``overrides``; the drawn values are in ``truth["loop_overrides"]``.
    side_mm : float, default 40.0
        Side of the square [mm].
    radius_mm : float, default 20.0
        Radius of the circle [mm].
    speed_rpm : float, default 6000.0
        Spindle speed [rpm].
    feed_per_tooth_mm : float, default 0.167
        Feed per tooth [mm].
    depth_mm : float, default 0.5
        Axial depth of cut [mm].
    air_moves_mm_min : sequence of float, default ()
        Feeds of air moves before the square: X and Y out 60 mm and back at each feed at the
        clearance height, spindle on (a CAM program's approach moves; what friction from a
        production recording needs, docs/validation-calibration.md). Default none: the
        thesis program, every X/Y move at constant feed in the cut.
    faults : sequence or mapping, default ()
        Faults to inject (:mod:`cnctwin.sim.faults`), objects or their dicts.
    fmt : str, default 'c4a'
        Recording format: ``'c4a'`` (Capture4Analysis JSON) or ``'parquet'`` (chunk directory).
    max_file_mb : float, optional
        Split a Capture4Analysis recording into files of at most this size [MB]; None: one file.
    chunk_cycles : int, default 50000
        Cycles simulated and written per chunk (bounds memory).
    progress : callable, optional
        Called with (fraction done 0..1, message) while the scenario runs.

    Returns
    -------
    ScenarioResult
        Truth: the paths (corners, circle centre/radius), the feed, the machine (all loop
        parameters) and the per-cycle cutting forces (``per_cycle`` / Parquet).
    """
    drawn = random_loop_overrides(seed) if randomize_loop else {}
    ov = {**drawn, **dict(overrides or {})}
    cfg = ScenarioConfig.build(ov, machine=machine)
    o = _prepare(out)
    flist = _faults_from(faults)
    gap = 30.0
    text = _milling_program(side_mm, radius_mm, gap, air_moves_mm_min=air_moves_mm_min,
                            speed_rpm=speed_rpm,
                            feed_per_tooth_mm=feed_per_tooth_mm,
                            n_flutes=cfg.end_mill.flutes, depth_mm=depth_mm,
                            tool=cfg.end_mill.tool_number)
    prog = parse_program(text)
    feed = feed_per_tooth_mm * cfg.end_mill.flutes * speed_rpm
    res = ScenarioResult("milling_square_circle", truth={
        **_base_truth("milling_square_circle", seed, overrides, cfg),
        "loop_overrides": drawn, "material": "al7050", "speed_rpm": speed_rpm,
        "feed_per_tooth_mm": feed_per_tooth_mm, "feed_mm_min": feed, "depth_mm": depth_mm,
        "air_moves_mm_min": [float(f) for f in air_moves_mm_min],
        "square": {"corners_mm": [[0.0, 0.0], [side_mm, 0.0], [side_mm, side_mm],
                                  [0.0, side_mm]], "direction": "ccw"},
        "circle": {"center_mm": [side_mm + gap + radius_mm, side_mm / 2.0],
                   "radius_mm": radius_mm, "direction": "ccw"},
        "faults": [fault_to_dict(f) for f in flist]})
    _write_program(o, "milling_square_circle.mpf", text, res.paths)
    daq = _DynamometerDAQ(cfg.dynamometer, np.random.default_rng([seed, 2]), o, "dynamometer")
    tp = _TruthParquet(o / "truth_per_cycle.parquet") if o is not None else None
    pf = _Progress(progress, "milling")
    hook = MillingProcess(cfg, material=cfg.materials["al7050"], surface_z_mm=0.0,
                          faults=flist, rng=np.random.default_rng([seed, 1]), truth=tp,
                          daq=daq, progress=pf)
    sink, path = _make_sink(o, "milling_square_circle", fmt, max_file_mb)
    sim = _simulate(prog, cfg, seed=seed, hook=hook, sink=sink, chunk_cycles=chunk_cycles)
    daq.close()
    res.truth["fault_onsets_s"] = hook.onsets
    res.truth["dynamometer_sessions"] = daq.sessions
    _collect(res, sim, sink, path, daq, tp)
    _write_truth(o, res.truth, res.paths)
    return res


def axis_test(
    out: str | Path | None = None,
    *,
    seed: int = 0,
    overrides: Mapping[str, Any] | None = None,
    machine: Machine | None = None,
    randomize_loop: bool = False,
    axes: Sequence[str] = ("X1", "Y1", "Z1"),
    stroke_mm: float = 60.0,
    feeds_mm_min: Sequence[float] = (500.0, 1000.0, 2000.0, 4000.0, 8000.0),
    fmt: str = "c4a",
    max_file_mb: float | None = None,
    chunk_cycles: int = 50_000,
    progress: ProgressFn | None = None,
) -> ScenarioResult:
    """Feed axes back and forth in air at several feeds
    (:func:`~cnctwin.sim.programs.axis_test_program`).

    The calibration program for ``cnctwin calibrate axes``: constant-velocity strokes in both
    directions at every feed (friction, steady following error) with jerk-limited starts and
    stops (jerk filter, speed loop). No cutting, spindle off.

    Parameters
    ----------
    out : str or path, optional
        Output directory; ``None`` keeps ``result.recording`` in memory.
    seed : int
        Seed of every random stream (and of the loop draw with ``randomize_loop``).
    overrides : mapping, optional
        Dotted overrides (``axes.Y1.coulomb_n``).
    machine : Machine, optional
        Base machine; overrides apply on top.
    randomize_loop : bool, default False
        Draw the X/Y loop parameters with :func:`random_loop_overrides` first.
    axes, stroke_mm, feeds_mm_min
        As :func:`~cnctwin.sim.programs.axis_test_program`.
    fmt : str, default 'c4a'
        Recording format: ``'c4a'`` (Capture4Analysis JSON) or ``'parquet'`` (chunk directory).
    max_file_mb : float, optional
        Split a Capture4Analysis recording into files of at most this size [MB]; None: one file.
    chunk_cycles : int, default 50000
        Cycles simulated and written per chunk (bounds memory).
    progress : callable, optional
        Called with (fraction done 0..1, message) while the scenario runs.

    Returns
    -------
    ScenarioResult
        Truth: the machine (all loop and friction parameters), the feeds.
    """
    drawn = random_loop_overrides(seed) if randomize_loop else {}
    cfg = ScenarioConfig.build({**drawn, **dict(overrides or {})}, machine=machine)
    o = _prepare(out)
    text = axis_test_program(axes, stroke_mm=stroke_mm, feeds_mm_min=feeds_mm_min)
    prog = parse_program(text)
    res = ScenarioResult("axis_test", truth={
        **_base_truth("axis_test", seed, overrides, cfg), "loop_overrides": drawn,
        "axes": list(axes), "stroke_mm": stroke_mm, "feeds_mm_min": list(feeds_mm_min)})
    _write_program(o, "axis_test.mpf", text, res.paths)
    sink, path = _make_sink(o, "axis_test", fmt, max_file_mb)
    hook = _NoLoad(surface_z_mm=0.0, faults=(), rng=np.random.default_rng(seed), truth=None,
                   daq=None, progress=_Progress(progress, "axis test"))
    sim = _simulate(prog, cfg, seed=seed, hook=hook, sink=sink, chunk_cycles=chunk_cycles)
    _collect(res, sim, sink, path, None, None)
    _write_truth(o, res.truth, res.paths)
    return res


_DRILL_WORDS = ("CYCLE81", "CYCLE82", "CYCLE83", "G81", "G82", "G83")


def _line_of_offset(text: str, offset: int) -> int:
    """1-based program line of a byte offset (the block events' ``seek_offset``)."""
    return text.encode("utf-8")[: max(offset, 0)].count(b"\n") + 1


def drive_limits_check(rec: Recording, machine: Machine, program_text: str) -> dict[str, Any]:
    """Peak spindle and axis loads of a simulated program against the drives' limits.

    Parameters
    ----------
    rec : Recording
        The simulated recording (CURRENT, TORQUE, POWER per axis; block events).
    machine : Machine
        Its description (current limits, rated torque and current, base speed).
    program_text : str
        The program (to name the line of the block where a limit is exceeded).

    Returns
    -------
    dict
        ``cycle_time_s``, ``spindle`` peaks (``torque_nm``, ``power_w``, ``current_a`` with the
        line where each peaks) and ``limits``, per feed axis the peak current, and
        ``warnings``: one line per exceeded limit naming the program line and block.

    Notes
    -----
    Limits: the current limit (peak), the rated (S1) current and torque, and the S1 power
    ``rated torque x base speed`` of the spindle (a motor spindle's constant-power range
    starts at its base speed); the feed drives' current limit.
    """
    sp = machine.spindle
    name = machine.spindle_name
    blocks = rec.events[rec.events["kind"] == "block"].sort_values("cycle", kind="stable")
    bc = blocks["cycle"].to_numpy(dtype=np.int64)

    def where(idx: int) -> dict[str, Any]:
        cyc = int(rec.cycles[idx])
        k = int(np.searchsorted(bc, cyc, side="right")) - 1
        if k < 0:
            return {"cycle": cyc, "time_s": float(rec.time_s[idx]), "line": None, "block": None}
        row = blocks.iloc[k]
        return {"cycle": cyc, "time_s": float(rec.time_s[idx]),
                "line": _line_of_offset(program_text, int(row["seek_offset"])),
                "block": str(row["gcode"])}

    p_s1 = sp.rated_torque_nm * sp.base_speed_rpm * 2.0 * math.pi / 60.0
    out: dict[str, Any] = {"cycle_time_s": float(rec.n_cycles * machine.cycle_time_s),
                           "spindle": {}, "axes": {}, "warnings": [],
                           "limits": {"spindle_current_limit_a": sp.current_limit_a,
                                      "spindle_rated_current_a": sp.rated_current_a,
                                      "spindle_rated_torque_nm": sp.rated_torque_nm,
                                      "spindle_s1_power_w": p_s1}}
    checks = [("CURRENT", "current_a", sp.current_limit_a, "current limit"),
              ("TORQUE", "torque_nm", sp.rated_torque_nm, "rated torque"),
              ("POWER", "power_w", p_s1, "S1 power")]
    for code, key, limit, what in checks:
        if not rec.has(code, name):
            continue
        v = np.abs(rec.signal(code, name).to_numpy(dtype=np.float64))
        if not np.isfinite(v).any():
            continue
        i = int(np.nanargmax(v))
        out["spindle"][key] = {"peak": float(v[i]), **where(i)}
        if v[i] > limit:
            w = where(i)
            out["warnings"].append(
                f"line {w['line']} ({w['block']}): spindle {key.rsplit('_', 1)[0]} "
                f"{v[i]:.4g} exceeds the {what} {limit:.4g} at t = {w['time_s']:.2f} s")
    for ax in machine.axes:
        if not rec.has("CURRENT", ax.name):
            continue
        v = np.abs(rec.signal("CURRENT", ax.name).to_numpy(dtype=np.float64))
        if not np.isfinite(v).any():
            continue
        i = int(np.nanargmax(v))
        out["axes"][ax.name] = {"current_a": {"peak": float(v[i]), **where(i)},
                                "current_limit_a": ax.current_limit_a}
        if v[i] > ax.current_limit_a:
            w = where(i)
            out["warnings"].append(
                f"line {w['line']} ({w['block']}): {ax.name} current {v[i]:.4g} A exceeds the "
                f"current limit {ax.current_limit_a:.4g} A at t = {w['time_s']:.2f} s")
    return out


def part_program(
    out: str | Path | None = None,
    *,
    program: str | Path,
    seed: int = 0,
    overrides: Mapping[str, Any] | None = None,
    machine: Machine | None = None,
    material: str | None = None,
    surface_z_mm: float = 0.0,
    fmt: str = "c4a",
    max_file_mb: float | None = None,
    chunk_cycles: int = 50_000,
    progress: ProgressFn | None = None,
    start_time: pd.Timestamp | str | None = None,
    first_hole: int = 0,
    faults: Sequence[Fault | Mapping[str, Any]] = (),
) -> ScenarioResult:
    """Any part program of the supported G-code subset on a machine description.

    Parameters
    ----------
    out : str or path, optional
        Output directory; ``None`` keeps ``result.recording`` in memory.
    program : str or path
        The program file (``.mpf``).
    seed : int
        Seed of every random stream.
    overrides : mapping, optional
        Dotted overrides on top of ``machine``.
    machine : Machine, optional
        The machine (e.g. loaded from a machine file); default the thesis machine.
    material : str, optional
        Workpiece material (``aisi1045``, ``grey_cast_iron``, ``al7050``): with it, a
        program with a drilling cycle drills and any other cuts by milling below
        ``surface_z_mm``; without it the program runs in air (no process load).
    surface_z_mm : float, default 0
        Workpiece top surface [mm].
    start_time : Timestamp or str, optional
        UTC time of the first cycle; default the scenarios' common start time.
    first_hole : int, default 0
        Holes the drill has made before this program (its flank wear starts there).
    faults : sequence, default ()
        Faults of a drilling program (:class:`~cnctwin.sim.faults.ToolBreakage`,
        :class:`~cnctwin.sim.faults.HardnessChange`, :class:`~cnctwin.sim.faults.Chatter`,
        :class:`~cnctwin.sim.faults.LooseTool`, or dicts with ``type``: ``--option
        faults='[{"type": "ToolBreakage", "hole": 3}]'``); hole numbers count the program's
        holes from ``first_hole``. In ``truth.json`` under ``faults``.
    fmt : str, default 'c4a'
        Recording format: ``'c4a'`` (Capture4Analysis JSON) or ``'parquet'`` (chunk directory).
    max_file_mb : float, optional
        Split a Capture4Analysis recording into files of at most this size [MB]; None: one file.
    chunk_cycles : int, default 50000
        Cycles simulated and written per chunk (bounds memory).
    progress : callable, optional
        Called with (fraction done 0..1, message) while the scenario runs.

    Returns
    -------
    ScenarioResult
        Truth ``limits``: :func:`drive_limits_check` (cycle time, peaks and the warnings
        naming the program line where a limit is exceeded); of a drilling program ``holes``:
        every entry of the tool into the part at a new X/Y (``hole``, the number the
        ``faults`` use, ``x_mm``, ``y_mm``, ``cut_first_cycle``; milling entries count here).

    Raises
    ------
    GCodeError
        An unsupported word or cycle, naming the line and the word.
    """
    path = Path(program)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read the program: {exc}") from None
    try:
        prog = parse_program(text)
    except GCodeError as exc:
        raise ConfigError(f"{path}: {exc}; the supported subset is listed in "
                          "docs/simulator.md") from None
    cfg = ScenarioConfig.build(overrides, machine=machine)
    flist = _faults_from(faults)
    if flist and material is None:
        raise ConfigError("faults need a cutting load: give --material (a program in air has "
                          "no process to break or wear)")
    o = _prepare(out)
    stem = path.stem
    upper = text.upper()
    hook: _Process
    pf = _Progress(progress, stem)
    rng = np.random.default_rng([seed, 1])
    if material is None:
        kind = "air"
        hook = _NoLoad(surface_z_mm=surface_z_mm, faults=(), rng=rng, truth=None, daq=None,
                       progress=pf)
    else:
        if material not in cfg.materials:
            raise ConfigError(f"unknown material {material!r}; known: {sorted(cfg.materials)}")
        mat = cfg.materials[material]
        if any(w in upper for w in _DRILL_WORDS):
            kind = "drilling"
            speeds = [float(v) for v in re.findall(r"\bS(\d+(?:\.\d*)?)", upper)] or [1.0]
            feeds = [float(v) for v in re.findall(r"\bF(\d*\.?\d+)", upper)] or [0.1]
            hook = DrillingProcess(cfg, material=mat, feed_mm_per_rev=feeds[0],
                                   speed_rpm=max(speeds), hole_depth_mm=20.0,
                                   surface_z_mm=surface_z_mm, faults=flist, rng=rng,
                                   truth=None, daq=None, progress=pf, first_hole=first_hole)
        else:
            if mat.milling is None:
                raise ConfigError(f"material {material!r} has no milling coefficients; the "
                                  "program has no drilling cycle, so it mills: choose al7050")
            if flist:
                raise ConfigError("faults are simulated in drilling programs (a drilling "
                                  "cycle); this program mills")
            kind = "milling"
            hook = MillingProcess(cfg, material=mat, surface_z_mm=surface_z_mm, faults=(),
                                  rng=rng, truth=None, daq=None, progress=pf)
    res = ScenarioResult("part_program", truth={
        **_base_truth("part_program", seed, overrides, cfg), "program": str(path),
        "process": kind, "material": material, "faults": [fault_to_dict(f) for f in flist]})
    _write_program(o, path.name, text, res.paths)
    sink, rpath = _make_sink(o, stem, fmt, max_file_mb)
    try:
        sim = simulate(prog, cfg.machine, seed=seed, start_cycle=START_CYCLE,
                       start_time=START_TIME if start_time is None else start_time,
                       cutting=hook, sink=sink, chunk_cycles=chunk_cycles)
    except GCodeError as exc:  # found while running it (a speed above the machine's limit)
        raise ConfigError(f"{path}: {exc} (the machine's limits: --machine FILE, or the "
                          "thesis machine without one)") from None
    _collect(res, sim, sink, rpath, None, None)
    rec = res.recording
    if kind == "drilling":  # every entry of the tool into the part at a new X/Y, with its cycle
        res.truth["holes"] = [{k: (float(v) if isinstance(v, np.floating) else v)
                               for k, v in row.items()} for row in hook.hole_rows()]
    res.truth["limits"] = drive_limits_check(rec, cfg.machine, text)
    _write_truth(o, res.truth, res.paths)
    return res


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
