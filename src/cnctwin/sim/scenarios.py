"""Ready-made simulation scenarios of the thesis experiments (one function call each).

Every scenario returns a :class:`ScenarioResult` and, with ``out_dir``, writes

* the recording(s) as Capture4Analysis JSON (:func:`cnctwin.iotools.write_capture4analysis`),
* external sensors as CSV (``dynamometer*.csv``: ``time_s,fx_n,fy_n,fz_n,mz_nm``;
  ``thermal_camera.csv``: ``time_s,hole,temperature_c``),
* ``truth.json``: every TRUE parameter used (machine incl. spindle, materials, tool, wear,
  sensor clocks, fault onsets) and per-scenario ground truth.

Scenarios: :func:`air_cut_sweep`, :func:`warm_up`, :func:`drilling_validation`,
:func:`tool_wear_run`, :func:`loose_tap` (:data:`SCENARIOS`).

Kinematics: these scenarios run the spindle drive (:func:`cnctwin.sim.spindle.simulate_spindle`)
with NC-style ramped commands built here, and a simple Z-axis follower (first-order lag with
speed feedforward residual + axial compliance) for the drilling/tapping feed. They do not yet use
the full feed-axis servo of :func:`cnctwin.sim.machine.simulate` (see docs/simulator.md).

Overrides: ``{"spindle.kt_nm_per_a": 1.1}`` (and every ``Machine.with_overrides`` key),
``"material.<key>.<field>"`` (e.g. ``material.aisi1045.kc1_n_per_mm2``), ``"drill.<field>"``,
``"tap.<field>"``, ``"drilling.<field>"`` (:class:`~cnctwin.sim.cutting.DrillingModel`),
``"wear.<field>"`` (:class:`~cnctwin.sim.tool.WearCurve`), ``"tool_thermal.<field>"``,
``"dynamometer.<field>"``, ``"camera.<field>"``.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray
from scipy.signal import lfilter

from cnctwin.exceptions import ConfigError
from cnctwin.recording import ExternalChannel, Recording
from cnctwin.sim.cutting import (
    MATERIALS,
    DrillingModel,
    Material,
    drill_torque_nm,
    drilling_load,
    tapping_load,
)
from cnctwin.sim.faults import Fault, LooseTool, apply_faults, fault_to_dict, hardness_factor
from cnctwin.sim.machine import Machine
from cnctwin.sim.sensors import (
    Dynamometer,
    ThermalCamera,
    dynamometer_channel,
    thermal_camera_channel,
    write_dynamometer_csv,
    write_thermal_camera_csv,
)
from cnctwin.sim.spindle import SpindleState, SpindleTrace, simulate_spindle
from cnctwin.sim.tool import Drill, Tap, ToolThermal, WearCurve, flank_wear_um, tool_temperature

__all__ = [
    "SCENARIOS",
    "ScenarioConfig",
    "ScenarioResult",
    "air_cut_sweep",
    "drilling_validation",
    "loose_tap",
    "run_scenario",
    "tool_wear_run",
    "warm_up",
]

ProgressFn = Callable[[float, str], None]
_START = pd.Timestamp("2024-05-06T08:00:00Z")


@dataclass
class ScenarioResult:
    """What a scenario produced.

    Attributes
    ----------
    name : str
        Scenario name.
    recordings : list of Recording
        Recordings kept in memory (for streamed scenarios only the last chunk).
    paths : list of Path
        Files written (empty without ``out_dir``).
    truth : dict
        The true parameters and ground truth (also ``truth.json``).
    """

    name: str
    recordings: list[Recording] = field(default_factory=list)
    paths: list[Path] = field(default_factory=list)
    truth: dict[str, Any] = field(default_factory=dict)

    @property
    def recording(self) -> Recording:
        """The (first) recording."""
        if not self.recordings:
            raise ConfigError(f"scenario {self.name!r} kept no recording in memory")
        return self.recordings[0]


@dataclass(frozen=True)
class ScenarioConfig:
    """All true parameters of a scenario run (built from defaults + overrides)."""

    machine: Machine
    materials: dict[str, Material]
    drill: Drill
    tap: Tap
    drilling: DrillingModel
    wear: WearCurve
    tool_thermal: ToolThermal
    dynamometer: Dynamometer
    camera: ThermalCamera

    @classmethod
    def build(cls, overrides: Mapping[str, Any] | None = None) -> ScenarioConfig:
        """Defaults with dotted-key ``overrides`` applied (unknown keys raise ConfigError)."""
        ov = dict(overrides or {})
        machine_keys = {k: v for k, v in ov.items() if k.split(".")[0] not in _OWN_PREFIXES}
        machine = Machine.thesis_default().with_overrides(machine_keys)
        own: dict[str, dict[str, Any]] = {}
        mats: dict[str, dict[str, Any]] = {}
        for key, value in ov.items():
            parts = key.split(".")
            if parts[0] not in _OWN_PREFIXES:
                continue
            if parts[0] == "material":
                if len(parts) != 3 or parts[1] not in MATERIALS:
                    raise ConfigError(
                        f"override {key!r}: use material.<{'|'.join(MATERIALS)}>.<field>"
                    )
                mats.setdefault(parts[1], {})[parts[2]] = value
            elif len(parts) == 2:
                own.setdefault(parts[0], {})[parts[1]] = value
            else:
                raise ConfigError(f"override {key!r}: expected {parts[0]}.<field>")
        materials = {}
        for name, m in MATERIALS.items():
            materials[name] = _replace(m, mats.get(name, {}), f"material.{name}")
        return cls(
            machine=machine,
            materials=materials,
            drill=_replace(Drill(), own.get("drill", {}), "drill"),
            tap=_replace(Tap(), own.get("tap", {}), "tap"),
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
    return dataclasses.replace(obj, **changes) if changes else obj


# ----------------------------------------------------------------------------- building blocks
def _ramp(
    targets_rpm: NDArray[np.float64], start_rpm: float, rate_rpm_per_s: float, cycle_time_s: float
) -> NDArray[np.float64]:
    """Rate-limited speed command (NC spindle acceleration limit)."""
    out = np.empty(targets_rpm.size)
    step = rate_rpm_per_s * cycle_time_s
    v = start_rpm
    for k, tgt in enumerate(targets_rpm):
        v += min(max(tgt - v, -step), step)
        out[k] = v
    return out


def _lf_frame(
    cycles: NDArray[np.int64],
    times: pd.DatetimeIndex,
    trace: SpindleTrace,
    axis: str,
    every: int = 50,
) -> pd.DataFrame:
    """LF drive values (r0063, r0068, r0078, r0081, r0035) every ``every`` cycles (100 ms)."""
    idx = np.arange(0, cycles.size, every)
    parts = []
    for code, arr in (
        ("SPEED_SMOOTHED", trace.speed_smoothed_rpm),
        ("CURRENT_ABS_SMOOTHED", trace.current_abs_smoothed_a),
        ("IQ_ACT", trace.iq_smoothed_a),
        ("TORQUE_UTIL", trace.torque_utilization_pct),
        ("MOTOR_TEMP", trace.motor_temperature_c),
    ):
        v = np.round(arr[idx], 3)
        parts.append(
            pd.DataFrame(
                {
                    "cycle": cycles[idx],
                    "time": times[idx],
                    "signal": f"{code}|{axis}",
                    "value": v,
                    "text": [repr(float(x)) for x in v],
                }
            )
        )
    return pd.concat(parts, ignore_index=True).sort_values(
        ["cycle", "signal"], kind="stable", ignore_index=True
    )


def _recording(
    machine: Machine,
    start_cycle: int,
    trace: SpindleTrace,
    speed_cmd_rpm: NDArray[np.float64],
    extra: Mapping[str, NDArray[np.float64]] | None = None,
) -> Recording:
    """Recording of the spindle HF/LF values (+ extra HF columns) on the cycle base."""
    ax = machine.spindle_name
    n = len(trace)
    cycles = np.arange(start_cycle, start_cycle + n, dtype=np.int64)
    cols: dict[str, Any] = {
        f"CMD_SPEED|{ax}": speed_cmd_rpm,
        f"ENC_POS|{ax}": np.mod(trace.position_deg, 360.0),
        f"CURRENT|{ax}": trace.current_a,
        f"TORQUE|{ax}": trace.torque_setpoint_nm,
        f"LOAD|{ax}": trace.load_pct,
        f"POWER|{ax}": trace.power_w,
    }
    cols.update(extra or {})
    start = _START + pd.Timedelta(seconds=start_cycle * machine.cycle_time_s)
    rec = Recording.from_arrays(
        cycles,
        cols,
        start_time=start,
        cycle_time_s=machine.cycle_time_s,
        machine=machine.name,
        axis_map=dict(machine.axis_map),
        source_format="sim",
    )
    rec.lf = _lf_frame(cycles, pd.DatetimeIndex(rec.hf["time"]), trace, ax)
    return rec


def _write(rec: Recording, path: Path) -> list[Path]:
    from cnctwin.iotools.capture4analysis import write_capture4analysis

    return list(write_capture4analysis(rec, path))


def _write_truth(out: Path | None, truth: dict[str, Any], paths: list[Path]) -> None:
    if out is None:
        return
    p = out / "truth.json"
    p.write_text(json.dumps(truth, indent=2, default=_json_default), encoding="utf-8")
    paths.append(p)


def _json_default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def _prepare(out_dir: str | Path | None) -> Path | None:
    if out_dir is None:
        return None
    p = Path(out_dir)
    p.mkdir(parents=True, exist_ok=True)
    return p


def _z_follow(
    z_des_mm: NDArray[np.float64],
    thrust_n: NDArray[np.float64],
    *,
    lag_s: float,
    stiffness_n_per_mm: float,
    cycle_time_s: float,
    zi: float | None = None,
) -> tuple[NDArray[np.float64], float]:
    """Z ENC_POS: first-order follower of DES_POS plus axial compliance (thrust pushes up)."""
    a = math.exp(-cycle_time_s / lag_s)
    z0 = float(z_des_mm[0]) if zi is None else zi
    y, zf = lfilter([1.0 - a], [1.0, -a], z_des_mm, zi=[a * z0])
    return np.asarray(y + thrust_n / stiffness_n_per_mm), float(zf[0] / a)


# ----------------------------------------------------------------------------- scenarios
def air_cut_sweep(
    out_dir: str | Path | None = None,
    *,
    seed: int = 0,
    overrides: Mapping[str, Any] | None = None,
    n_speeds: int = 126,
    max_speed_rpm: float = 18000.0,
    min_speed_rpm: float = 100.0,
    dwell_s: float = 3.0,
    ramp_rpm_per_s: float = 4000.0,
    progress: ProgressFn | None = None,
) -> ScenarioResult:
    """Air cut at ``n_speeds`` constant spindle speeds up to 18000 rpm (thesis §3.2.2, Fig. 3.8).

    Truth: the speed steps with the cycle range of each steady window (ramp excluded).
    """
    cfg = ScenarioConfig.build(overrides)
    m = cfg.machine
    ct = m.cycle_time_s
    speeds = np.round(np.linspace(min_speed_rpm, max_speed_rpm, n_speeds), 0)
    rng = np.random.default_rng(seed)
    state: SpindleState | None = None
    traces, cmds, windows = [], [], []
    pos = 0
    prev = 0.0
    for i, s in enumerate(speeds):
        t_ramp = abs(s - prev) / ramp_rpm_per_s
        n = round((t_ramp + dwell_s) / ct)
        cmd = _ramp(np.full(n, s), prev, ramp_rpm_per_s, ct)
        tr = simulate_spindle(
            cmd, 0.0, m.spindle, cycle_time_s=ct, inner_steps=m.inner_steps, state=state, rng=rng
        )
        state = tr.state
        settle = round((t_ramp + 0.5) / ct)
        windows.append(
            {"speed_rpm": float(s), "first_cycle": pos + settle, "last_cycle": pos + n - 1}
        )
        traces.append(tr)
        cmds.append(cmd)
        pos += n
        prev = float(s)
        if progress:
            progress((i + 1) / n_speeds, f"{s:.0f} rpm")
    trace = SpindleTrace.concatenate(traces)
    rec = _recording(m, 0, trace, np.concatenate(cmds))
    truth = {
        "scenario": "air_cut_sweep",
        "seed": seed,
        "overrides": dict(overrides or {}),
        **cfg.to_dict(),
        "steps": windows,
    }
    res = ScenarioResult("air_cut_sweep", [rec], [], truth)
    out = _prepare(out_dir)
    if out is not None:
        res.paths += _write(rec, out / "air_cut_sweep.json")
    _write_truth(out, truth, res.paths)
    return res


def warm_up(
    out_dir: str | Path | None = None,
    *,
    seed: int = 0,
    overrides: Mapping[str, Any] | None = None,
    speeds_rpm: tuple[float, ...] = (5000.0, 7000.0),
    duration_s: float = 1500.0,
    ramp_rpm_per_s: float = 4000.0,
    progress: ProgressFn | None = None,
) -> ScenarioResult:
    """Spindle turning ``duration_s`` at each speed from a cold start (thesis §4.2, Fig. 4.4).

    One recording per speed; the motor temperature rises and the current falls.
    """
    cfg = ScenarioConfig.build(overrides)
    m = cfg.machine
    ct = m.cycle_time_s
    res = ScenarioResult(
        "warm_up",
        truth={
            "scenario": "warm_up",
            "seed": seed,
            "overrides": dict(overrides or {}),
            **cfg.to_dict(),
            "runs": [],
        },
    )
    out = _prepare(out_dir)
    for i, s in enumerate(speeds_rpm):
        rng = np.random.default_rng([seed, i])
        n = round(duration_s / ct)
        cmd = _ramp(np.full(n, s), 0.0, ramp_rpm_per_s, ct)
        chunks = []
        state: SpindleState | None = None
        step = 50_000
        for k0 in range(0, n, step):
            tr = simulate_spindle(
                cmd[k0 : k0 + step],
                0.0,
                m.spindle,
                cycle_time_s=ct,
                inner_steps=m.inner_steps,
                state=state,
                rng=rng,
            )
            state = tr.state
            chunks.append(tr)
            if progress:
                progress((i + min(k0 + step, n) / n) / len(speeds_rpm), f"{s:.0f} rpm")
        trace = SpindleTrace.concatenate(chunks)
        rec = _recording(m, 0, trace, cmd)
        res.recordings.append(rec)
        minute = round(60.0 / ct)
        res.truth["runs"].append(
            {
                "speed_rpm": float(s),
                "rotor_temperature_c_per_min": trace.rotor_temperature_c[
                    minute - 1 :: minute
                ].tolist(),
                "stator_temperature_c_per_min": trace.motor_temperature_c[
                    minute - 1 :: minute
                ].tolist(),
                "kt_nm_per_a_per_min": trace.kt_nm_per_a[minute - 1 :: minute].tolist(),
                "friction_nm_per_min": trace.friction_nm[minute - 1 :: minute].tolist(),
            }
        )
        if out is not None:
            res.paths += _write(rec, out / f"warm_up_{int(s)}rpm.json")
    _write_truth(out, res.truth, res.paths)
    return res


@dataclass
class _HoleResult:
    trace: SpindleTrace
    cmd: NDArray[np.float64]
    extra: dict[str, NDArray[np.float64]]
    mz: NDArray[np.float64]
    fz: NDArray[np.float64]
    fx: NDArray[np.float64]
    fy: NDArray[np.float64]
    cut_start: int
    cut_end: int
    tool_temp: NDArray[np.float64]
    onsets: list[float | None]


def _drill_holes(
    cfg: ScenarioConfig,
    *,
    material: Material,
    speed_rpm: float,
    feed_mm_per_rev: float,
    depth_mm: float,
    n_holes: int,
    first_hole: int,
    start_cycle: int,
    state: SpindleState | None,
    tool_temp0: float | None,
    z_state: float | None,
    rng: np.random.Generator,
    gap_s: float,
    faults: tuple[Fault, ...] = (),
    wear_um: NDArray[np.float64] | None = None,
) -> tuple[list[_HoleResult], SpindleState, float, float]:
    """Drill ``n_holes`` blind holes with constant feed (G1 down, G0 out), one chunk per hole."""
    m = cfg.machine
    ct = m.cycle_time_s
    d = cfg.drill
    clearance = 2.0
    feed_mm_s = feed_mm_per_rev * speed_rpm / 60.0
    rapid_mm_s = 20000.0 / 60.0
    results = []
    st = state
    temp = tool_temp0
    zs = z_state
    for j in range(n_holes):
        hole = first_hole + j
        v0 = st.speed_rpm if st is not None else 0.0
        # spin up (4000 rpm/s) and settle 0.5 s before the first approach
        n_spin = round((abs(speed_rpm - v0) / 4000.0 + 0.5) / ct) if j == 0 else 0
        n_app = round(clearance / rapid_mm_s / ct) + 1
        n_cut = round((depth_mm + clearance * 0.5) / feed_mm_s / ct)
        n_dwell = round(0.1 / ct)
        n_ret = round((depth_mm + clearance) / rapid_mm_s / ct) + 1
        n_gap = round(gap_s / ct)
        z = np.concatenate(
            [
                np.full(n_spin, clearance),
                np.linspace(clearance, clearance * 0.5, n_app),
                clearance * 0.5 - feed_mm_s * ct * np.arange(1, n_cut + 1),
                np.full(n_dwell, -depth_mm),
                np.linspace(-depth_mm, clearance, n_ret),
                np.full(n_gap, clearance),
            ]
        )
        z = np.minimum(z, clearance)
        z[n_spin + n_app : n_spin + n_app + n_cut] = np.maximum(
            z[n_spin + n_app : n_spin + n_app + n_cut], -depth_mm
        )
        n = z.size
        v_mm_s = np.gradient(z, ct)
        cmd = _ramp(np.full(n, speed_rpm), st.speed_rpm if st is not None else 0.0, 4000.0, ct)
        feed = np.where(v_mm_s < -1e-9, -v_mm_s * 60.0 / np.maximum(cmd, 1.0), 0.0)
        depth = -z
        wear = float(wear_um[j]) if wear_um is not None else 0.0
        hard = float(hardness_factor(faults, hole))
        angle0 = st.vector[1] if st is not None else 0.0
        angle = angle0 + np.cumsum(cmd) * ct * 2.0 * math.pi / 60.0
        # tool temperature needs the load, the load (slightly) the temperature: use the
        # temperature of the previous sample's power (one pass with cold-tool load first)
        base = drilling_load(
            depth,
            cmd,
            feed,
            drill=d,
            material=material,
            wear_um=wear,
            hardness_factor=hard,
            spindle_angle_rad=angle,
            model=cfg.drilling,
            rng=None,
            dt_s=ct,
        )
        power = base.torque_nm * cmd * 2.0 * math.pi / 60.0
        tt = tool_temperature(power, dt_s=ct, thermal=cfg.tool_thermal, initial_c=temp)
        load = drilling_load(
            depth,
            cmd,
            feed,
            drill=d,
            material=material,
            wear_um=wear,
            hardness_factor=hard,
            spindle_angle_rad=angle,
            tool_temperature_c=tt,
            walk_direction_rad=0.7,
            model=cfg.drilling,
            rng=rng,
            dt_s=ct,
        )
        t_abs = (start_cycle + np.arange(n)) * ct
        cut_idx = np.flatnonzero(load.engagement > 0)
        prog = np.zeros(n)
        if cut_idx.size:
            prog[cut_idx] = np.linspace(0.0, 1.0, cut_idx.size)
        load, onsets = apply_faults(
            faults, load, time_s=t_abs, hole=hole, speed_rpm=cmd, hole_progress=prog, rng=rng
        )
        tr = simulate_spindle(
            cmd,
            load.torque_nm,
            m.spindle,
            cycle_time_s=ct,
            inner_steps=m.inner_steps,
            state=st,
            rng=rng,
        )
        st = tr.state
        temp = float(tt[-1])
        z_enc, zs = _z_follow(
            z, load.thrust_n, lag_s=0.004, stiffness_n_per_mm=5.0e4, cycle_time_s=ct, zi=zs
        )
        x_enc = load.fx_n / 2.0e4
        y_enc = load.fy_n / 2.0e4
        extra = {
            "DES_POS|Z1": z,
            "ENC_POS|Z1": z_enc,
            "DES_POS|X1": np.zeros(n),
            "ENC_POS|X1": x_enc,
            "DES_POS|Y1": np.zeros(n),
            "ENC_POS|Y1": y_enc,
        }
        cs = int(cut_idx[0]) if cut_idx.size else 0
        ce = int(cut_idx[-1]) if cut_idx.size else 0
        results.append(
            _HoleResult(
                tr,
                cmd,
                extra,
                load.torque_nm,
                load.thrust_n,
                load.fx_n,
                load.fy_n,
                start_cycle + cs,
                start_cycle + ce,
                tt,
                onsets,
            )
        )
        start_cycle += n
    assert st is not None
    return results, st, float(temp if temp is not None else 25.0), float(zs or 0.0)


def _assemble(
    cfg: ScenarioConfig, holes: list[_HoleResult], start_cycle: int, rng: np.random.Generator
) -> tuple[Recording, ExternalChannel]:
    m = cfg.machine
    trace = SpindleTrace.concatenate([h.trace for h in holes])
    cmd = np.concatenate([h.cmd for h in holes])
    extra = {k: np.concatenate([h.extra[k] for h in holes]) for k in holes[0].extra}
    rec = _recording(m, start_cycle, trace, cmd, extra)
    t = np.arange(len(trace)) * m.cycle_time_s
    dyn = dynamometer_channel(
        t,
        np.concatenate([h.mz for h in holes]),
        np.concatenate([h.fz for h in holes]),
        fx_n=np.concatenate([h.fx for h in holes]),
        fy_n=np.concatenate([h.fy for h in holes]),
        sensor=cfg.dynamometer,
        rng=rng,
    )
    rec.external["dynamometer"] = dyn
    return rec, dyn


def drilling_validation(
    out_dir: str | Path | None = None,
    *,
    seed: int = 0,
    overrides: Mapping[str, Any] | None = None,
    depth_mm: float = 20.0,
    progress: ProgressFn | None = None,
) -> ScenarioResult:
    """The five thesis drilling cuts with the dynamometer attached (thesis §4.3, Table 4.1).

    Steel 2400/0.16, cast iron 2400/0.3, steel 2800/0.14, cast iron 3200/0.4, steel
    3200/0.125 (rpm / mm/rev), 8.5 mm carbide drill, one recording + dynamometer CSV per cut.
    Truth per cut: the model's mean full-engagement torque, the first full-engagement cycle and
    the dynamometer clock.
    """
    cfg = ScenarioConfig.build(overrides)
    cuts = (
        ("aisi1045", 2400.0, 0.16),
        ("grey_cast_iron", 2400.0, 0.30),
        ("aisi1045", 2800.0, 0.14),
        ("grey_cast_iron", 3200.0, 0.40),
        ("aisi1045", 3200.0, 0.125),
    )
    out = _prepare(out_dir)
    res = ScenarioResult(
        "drilling_validation",
        truth={
            "scenario": "drilling_validation",
            "seed": seed,
            "overrides": dict(overrides or {}),
            **cfg.to_dict(),
            "cuts": [],
        },
    )
    for i, (mat, n, f) in enumerate(cuts):
        rng = np.random.default_rng([seed, i])
        material = cfg.materials[mat]
        holes, _, _, _ = _drill_holes(
            cfg,
            material=material,
            speed_rpm=n,
            feed_mm_per_rev=f,
            depth_mm=depth_mm,
            n_holes=1,
            first_hole=0,
            start_cycle=0,
            state=None,
            tool_temp0=None,
            z_state=None,
            rng=rng,
            gap_s=1.0,
        )
        rec, dyn = _assemble(cfg, holes, 0, rng)
        res.recordings.append(rec)
        ct = cfg.machine.cycle_time_s
        full = holes[0].cut_start + math.ceil(cfg.drill.cone_length_mm / (f * n / 60.0) / ct)
        tag = f"{i + 1}_{mat}_{int(n)}rpm_{f:g}".replace(".", "p")
        res.truth["cuts"].append(
            {
                "material": mat,
                "speed_rpm": n,
                "feed_mm_per_rev": f,
                "model_mean_torque_nm": float(
                    drill_torque_nm(f, n, drill=cfg.drill, material=material, model=cfg.drilling)
                ),
                "full_engagement_first_cycle": full,
                "cut_last_cycle": holes[0].cut_end,
                "recording": f"drill_{tag}.json",
                "dynamometer_csv": f"dynamometer_{tag}.csv",
            }
        )
        if out is not None:
            res.paths += _write(rec, out / f"drill_{tag}.json")
            res.paths.append(write_dynamometer_csv(dyn, out / f"dynamometer_{tag}.csv"))
        if progress:
            progress((i + 1) / len(cuts), f"{mat} {n:.0f} rpm {f} mm/rev")
    _write_truth(out, res.truth, res.paths)
    return res


def tool_wear_run(
    out_dir: str | Path | None = None,
    *,
    seed: int = 0,
    overrides: Mapping[str, Any] | None = None,
    n_holes: int = 2676,
    holes_per_set: int = 6,
    depth_mm: float = 20.0,
    speed_rpm: float = 2400.0,
    feed_mm_per_min: float = 400.0,
    gap_in_set_s: float = 1.5,
    gap_between_sets_s: float = 60.0,
    faults: tuple[Fault, ...] = (),
    progress: ProgressFn | None = None,
) -> ScenarioResult:
    """Tool-wear run: AISI 1045, 20 mm holes, 2400 rpm, 400 mm/min, sets of 6 (thesis §5.1-5.3).

    Streamed: one recording + dynamometer CSV per set (``wear_set_NNNN.json``), a thermal-camera
    CSV (one reading per hole after extraction) and ``holes.csv`` with the true wear, tool
    temperature and model torque per hole. Only the last set is kept in memory.
    """
    cfg = ScenarioConfig.build(overrides)
    m = cfg.machine
    ct = m.cycle_time_s
    material = cfg.materials["aisi1045"]
    feed = feed_mm_per_min / speed_rpm
    out = _prepare(out_dir)
    res = ScenarioResult(
        "tool_wear_run",
        truth={
            "scenario": "tool_wear_run",
            "seed": seed,
            "overrides": dict(overrides or {}),
            **cfg.to_dict(),
            "n_holes": n_holes,
            "holes_per_set": holes_per_set,
            "depth_mm": depth_mm,
            "speed_rpm": speed_rpm,
            "feed_mm_per_rev": feed,
            "faults": [fault_to_dict(f) for f in faults],
            "fault_onsets_s": [None] * len(faults),
        },
    )
    rng = np.random.default_rng(seed)
    state: SpindleState | None = None
    temp: float | None = None
    zs: float | None = None
    cycle = 0
    rows = []
    cam_t, cam_hole, cam_temp = [], [], []
    n_sets = math.ceil(n_holes / holes_per_set)
    for s in range(n_sets):
        first = s * holes_per_set
        k = min(holes_per_set, n_holes - first)
        wear = flank_wear_um(np.arange(first, first + k), curve=cfg.wear)
        if s > 0:
            # cool down between sets: spindle keeps turning, tool cools (exact first order)
            temp = cfg.tool_thermal.ambient_temperature_c + (
                (temp or 25.0) - cfg.tool_thermal.ambient_temperature_c
            ) * math.exp(-gap_between_sets_s / cfg.tool_thermal.time_constant_s)
            cycle += round(gap_between_sets_s / ct)
        holes, state, temp, zs = _drill_holes(
            cfg,
            material=material,
            speed_rpm=speed_rpm,
            feed_mm_per_rev=feed,
            depth_mm=depth_mm,
            n_holes=k,
            first_hole=first,
            start_cycle=cycle,
            state=state,
            tool_temp0=temp,
            z_state=zs,
            rng=rng,
            gap_s=gap_in_set_s,
            faults=faults,
            wear_um=wear,
        )
        rec, dyn = _assemble(cfg, holes, cycle, rng)
        for j, h in enumerate(holes):
            for q, o in enumerate(h.onsets):
                if o is not None and res.truth["fault_onsets_s"][q] is None:
                    res.truth["fault_onsets_s"][q] = o
            rows.append(
                {
                    "hole": first + j,
                    "set": s,
                    "wear_um": float(wear[j]),
                    "cut_first_cycle": h.cut_start,
                    "cut_last_cycle": h.cut_end,
                    "model_torque_nm": float(
                        drill_torque_nm(
                            feed,
                            speed_rpm,
                            drill=cfg.drill,
                            material=material,
                            wear_um=wear[j],
                            model=cfg.drilling,
                        )
                    ),
                    "tool_temperature_after_c": float(h.tool_temp[-1]),
                    "tool_temperature_extraction_c": float(np.max(h.tool_temp)),
                }
            )
            cam_t.append((h.cut_end + 60) * ct)
            cam_hole.append(first + j)
            cam_temp.append(float(np.max(h.tool_temp)))
        cycle += sum(len(h.trace) for h in holes)
        res.recordings = [rec]
        if out is not None:
            res.paths += _write(rec, out / f"wear_set_{s + 1:04d}.json")
            res.paths.append(write_dynamometer_csv(dyn, out / f"dynamometer_set_{s + 1:04d}.csv"))
        if progress:
            progress((s + 1) / n_sets, f"hole {first + k}/{n_holes}")
    cam = thermal_camera_channel(cam_t, cam_hole, cam_temp, camera=cfg.camera, rng=rng)
    res.recordings[-1].external["thermal_camera"] = cam
    res.truth["holes"] = rows
    res.truth["final_wear_um"] = float(flank_wear_um(n_holes - 1, curve=cfg.wear))
    if out is not None:
        res.paths.append(write_thermal_camera_csv(cam, out / "thermal_camera.csv"))
        p = out / "holes.csv"
        pd.DataFrame(rows).to_csv(p, index=False)
        res.paths.append(p)
    _write_truth(out, res.truth, res.paths)
    return res


def loose_tap(
    out_dir: str | Path | None = None,
    *,
    seed: int = 0,
    overrides: Mapping[str, Any] | None = None,
    n_holes: int = 4,
    loose_from_hole: int = 2,
    depth_mm: float = 12.0,
    speed_rpm: float = 400.0,
    progress: ProgressFn | None = None,
) -> ScenarioResult:
    """Rigid tapping M8x1.25 in steel; the tap comes loose on extraction (thesis §5.4, Fig 5.10).

    The spindle is in position control (mode 1) following the tapping position command; Z
    follows synchronously (pitch per revolution). From ``loose_from_hole`` on, a
    :class:`~cnctwin.sim.faults.LooseTool` makes torque, current and Z position fluctuate while
    the tap turns backwards.
    """
    cfg = ScenarioConfig.build(overrides)
    m = cfg.machine
    ct = m.cycle_time_s
    tap = cfg.tap
    material = cfg.materials["aisi1045"]
    fault = LooseTool(start_hole=loose_from_hole)
    rng = np.random.default_rng(seed)
    out = _prepare(out_dir)
    clearance = 3.0
    deg_per_s = speed_rpm * 6.0
    total_deg = (depth_mm + clearance) / tap.pitch_mm * 360.0
    n_move = round(total_deg / deg_per_s / ct)
    acc_n = round(0.08 / ct)
    prof = np.ones(n_move)
    prof[:acc_n] = np.linspace(0, 1, acc_n)
    prof[-acc_n:] = np.linspace(1, 0, acc_n)
    prof_deg = np.cumsum(prof) * total_deg / prof.sum()
    n_wait = round(0.5 / ct)
    st: SpindleState | None = SpindleState.initial(m.spindle)
    pieces: list[SpindleTrace] = []
    cmds, extras_z, extras_zenc, mz, fz = [], [], [], [], []
    onset: float | None = None
    zs: float | None = None
    cycle = 0
    base_deg = 0.0
    for h in range(n_holes):
        pos = (
            np.concatenate(
                [
                    np.full(n_wait, 0.0),
                    prof_deg,
                    np.full(n_wait // 2, total_deg),
                    total_deg - prof_deg,
                    np.full(n_wait, 0.0),
                ]
            )
            + base_deg
        )
        n = pos.size
        z = clearance - (pos - base_deg) / 360.0 * tap.pitch_mm
        speed = np.gradient(pos, ct) / 6.0
        load = tapping_load(-z, speed, tap=tap, material=material)
        t_abs = (cycle + np.arange(n)) * ct
        load, on = apply_faults([fault], load, time_s=t_abs, hole=h, speed_rpm=speed, rng=rng)
        if on[0] is not None and onset is None:
            onset = on[0]
        tr = simulate_spindle(
            speed,
            load.torque_nm,
            m.spindle,
            cycle_time_s=ct,
            inner_steps=m.inner_steps,
            state=st,
            rng=rng,
            position_cmd_deg=pos,
            mode=1,
        )
        st = tr.state
        z_enc, zs = _z_follow(
            z, load.thrust_n, lag_s=0.004, stiffness_n_per_mm=5.0e4, cycle_time_s=ct, zi=zs
        )
        pieces.append(tr)
        cmds.append(speed)
        extras_z.append(z)
        extras_zenc.append(z_enc)
        mz.append(load.torque_nm)
        fz.append(load.thrust_n)
        cycle += n
        base_deg = float(pos[-1])
        if progress:
            progress((h + 1) / n_holes, f"tap {h + 1}/{n_holes}")
    trace = SpindleTrace.concatenate(pieces)
    rec = _recording(
        m,
        0,
        trace,
        np.concatenate(cmds),
        {"DES_POS|Z1": np.concatenate(extras_z), "ENC_POS|Z1": np.concatenate(extras_zenc)},
    )
    t = np.arange(len(trace)) * ct
    dyn = dynamometer_channel(
        t, np.concatenate(mz), np.concatenate(fz), sensor=cfg.dynamometer, rng=rng
    )
    rec.external["dynamometer"] = dyn
    truth = {
        "scenario": "loose_tap",
        "seed": seed,
        "overrides": dict(overrides or {}),
        **cfg.to_dict(),
        "faults": [fault_to_dict(fault)],
        "fault_onsets_s": [onset],
        "n_holes": n_holes,
        "depth_mm": depth_mm,
        "speed_rpm": speed_rpm,
    }
    res = ScenarioResult("loose_tap", [rec], [], truth)
    if out is not None:
        res.paths += _write(rec, out / "loose_tap.json")
        res.paths.append(write_dynamometer_csv(dyn, out / "dynamometer.csv"))
    _write_truth(out, truth, res.paths)
    return res


SCENARIOS: dict[str, Callable[..., ScenarioResult]] = {
    "air_cut_sweep": air_cut_sweep,
    "warm_up": warm_up,
    "drilling_validation": drilling_validation,
    "tool_wear_run": tool_wear_run,
    "loose_tap": loose_tap,
}
"""Scenario name -> function."""


def run_scenario(
    name: str,
    out_dir: str | Path | None = None,
    *,
    seed: int = 0,
    overrides: Mapping[str, Any] | None = None,
    progress: ProgressFn | None = None,
    **options: Any,
) -> ScenarioResult:
    """Run a scenario by name (:data:`SCENARIOS`); ``options`` go to the scenario function."""
    try:
        fn = SCENARIOS[name]
    except KeyError:
        raise ConfigError(f"unknown scenario {name!r}; known: {', '.join(SCENARIOS)}") from None
    return fn(out_dir, seed=seed, overrides=overrides, progress=progress, **options)
