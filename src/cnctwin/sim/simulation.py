"""The simulator's orchestrator: part program -> what the edge device records.

:func:`simulate` runs, chunk by chunk: the interpolator (``DES_POS``, spindle commands, NC
events), an optional cutting-process hook (:class:`CuttingInput` -> :class:`CuttingOutput`), the
spindle drive (:func:`cnctwin.sim.spindle.simulate_spindle`), the feed axes
(:func:`cnctwin.sim.servo.simulate_servo`) and hands a :class:`~cnctwin.sim.recorder.RecordedChunk`
to a sink (in memory by default; Parquet or Capture4Analysis for long runs).

Process-model coupling (documented approximation): the cutting hook sees the *expected* actual
positions (``DES_POS`` delayed by the axis' filter + loop equivalent time, the NC's own lag
model) and the *commanded* spindle speed, not the simulated actual values of the same chunk. The
difference is the contour deviation (um) and the spindle speed drop under load (< 1 %), both
negligible for the load, and it keeps every physical block one compiled pass per chunk.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import pandas as pd
import pyarrow as pa
from numpy.typing import NDArray

from cnctwin.exceptions import ConfigError
from cnctwin.recording import EVENT_COLUMNS, LF_COLUMNS, Recording, RecordingMeta
from cnctwin.sim.machine import Machine
from cnctwin.sim.recorder import MemorySink, RecordedChunk, RecordingSink
from cnctwin.sim.servo import N_KERNEL_OUTPUTS, ServoState, simulate_servo
from cnctwin.sim.spindle import _TRACE_FIELDS, SpindleState, simulate_spindle

__all__ = [
    "RECORDED_CODES",
    "CuttingInput",
    "CuttingOutput",
    "SimulationResult",
    "TrajectoryLike",
    "simulate",
]

RECORDED_CODES: tuple[str, ...] = (
    "DES_POS",
    "ENC_POS",
    "CTRL_POS",
    "CTRL_DIFF",
    "CTRL_DIFF2",
    "CONT_DEV",
    "VEL_FFW",
    "TORQUE_FFW",
    "CMD_SPEED",
    "CURRENT",
    "TORQUE",
    "LOAD",
    "POWER",
)
"""HF codes recorded per axis (thesis Table 2.1 plus CTRL_DIFF), columns ``CODE|AXIS``."""

LF_PERIOD_S = 0.1
"""LF drive values are sampled every 100 ms (thesis §3.2.1: 100 ms smoothing)."""


class TrajectoryLike(Protocol):
    """What the interpolator yields (``cnctwin.sim.interpolator.Trajectory``)."""

    des_pos: dict[str, NDArray[np.float64]]
    spindle_speed_cmd_rpm: NDArray[np.float64]
    spindle_mode: NDArray[Any]
    spindle_pos_cmd_deg: NDArray[np.float64]
    block_index: NDArray[Any]
    tool: NDArray[Any]
    events: pd.DataFrame
    holes: pd.DataFrame
    cycle_time_s: float


@dataclass(frozen=True)
class CuttingInput:
    """What the cutting hook gets for one chunk (every array has one value per cycle).

    Attributes
    ----------
    cycle : numpy.ndarray of int64
        Real cycle numbers (``start_cycle`` + offset).
    offset : numpy.ndarray of int64
        0-based cycle index since the program start.
    time_s : numpy.ndarray
        Seconds since the program start [s].
    des_pos : dict
        Axis -> position setpoint ``DES_POS`` [mm] / [deg].
    position : dict
        Axis -> expected actual position (``DES_POS`` delayed by the axis' lag model) [mm]/[deg].
    spindle_speed_rpm : numpy.ndarray
        Commanded spindle speed [rpm].
    spindle_pos_deg : numpy.ndarray
        Commanded spindle angle [deg].
    spindle_mode : numpy.ndarray
        0 speed control, 1 position control (rigid tapping).
    tool : numpy.ndarray
        Active tool number.
    block_index : numpy.ndarray
        Index of the executing block in the program.
    cycle_time_s : float
        Position-control cycle [s].
    duration_s : float
        Machine time of the whole program as the interpolator planned it [s] (NaN when the
        trajectory was given without it); for progress reports.
    """

    cycle: NDArray[np.int64]
    offset: NDArray[np.int64]
    time_s: NDArray[np.float64]
    des_pos: dict[str, NDArray[np.float64]]
    position: dict[str, NDArray[np.float64]]
    spindle_speed_rpm: NDArray[np.float64]
    spindle_pos_deg: NDArray[np.float64]
    spindle_mode: NDArray[Any]
    tool: NDArray[Any]
    block_index: NDArray[Any]
    cycle_time_s: float
    duration_s: float = math.nan

    def __len__(self) -> int:
        return int(self.cycle.size)


@dataclass
class CuttingOutput:
    """What the cutting hook returns for one chunk.

    Attributes
    ----------
    spindle_torque_nm : numpy.ndarray
        Load torque on the spindle, positive brakes M3 rotation [Nm].
    force_n : dict
        Axis -> external force on the axis in its positive direction [N] (rotary: [Nm]);
        axes not given get zero. A drilling thrust pushing the tool up is ``{"Z1": +F}``.
    truth : dict
        Extra per-cycle hidden values to keep (``"wear_um"``, ``"cutting_torque_nm"``, ...).
    """

    spindle_torque_nm: NDArray[np.float64]
    force_n: dict[str, NDArray[np.float64]] = field(default_factory=dict)
    truth: dict[str, NDArray[np.float64]] = field(default_factory=dict)


CuttingHook = Callable[[CuttingInput], CuttingOutput]


@dataclass
class SimulationResult:
    """Result of :func:`simulate`.

    Attributes
    ----------
    recording : Recording or None
        What the edge device records; ``None`` when streamed to a sink.
    truth : dict
        Everything used and hidden: ``machine`` (dict), ``seed``, ``start_cycle``,
        ``start_time``, ``dropped_cycles``, ``n_dropped``, ``holes`` (DataFrame),
        ``per_cycle`` (DataFrame indexed by cycle: cutting loads, true positions, friction,
        spindle truth, hook truth; only kept in memory mode).
    trajectory : dict
        Summary: ``n_cycles``, ``duration_s``, ``n_holes``, ``n_events``.

    Notes
    -----
    ``truth["holes"]`` is the interpolator's hole table with its ``*cycle`` columns shifted to
    real cycle numbers (``start_cycle`` added), like the recording's events.
    """

    recording: Recording | None
    truth: dict[str, Any]
    trajectory: dict[str, Any]


# ----------------------------------------------------------------------------- chunk sources
@dataclass
class _Chunk:
    offset: int
    traj: Any


def _slice_trajectory(traj: Any, lo: int, hi: int) -> Any:
    """A view of cycles lo..hi of a whole trajectory (event cycles stay program offsets)."""
    ev = traj.events
    ev = ev[(ev["cycle"] >= lo) & (ev["cycle"] < hi)]
    return _SimpleTrajectory(
        des_pos={k: np.asarray(v)[lo:hi] for k, v in traj.des_pos.items()},
        spindle_speed_cmd_rpm=np.asarray(traj.spindle_speed_cmd_rpm)[lo:hi],
        spindle_mode=np.asarray(traj.spindle_mode)[lo:hi],
        spindle_pos_cmd_deg=np.asarray(traj.spindle_pos_cmd_deg)[lo:hi],
        block_index=np.asarray(traj.block_index)[lo:hi],
        tool=np.asarray(traj.tool)[lo:hi],
        events=ev,
        holes=traj.holes if lo == 0 else traj.holes.iloc[0:0],
        cycle_time_s=traj.cycle_time_s,
    )


@dataclass
class _SimpleTrajectory:
    des_pos: dict[str, NDArray[np.float64]]
    spindle_speed_cmd_rpm: NDArray[np.float64]
    spindle_mode: NDArray[Any]
    spindle_pos_cmd_deg: NDArray[np.float64]
    block_index: NDArray[Any]
    tool: NDArray[Any]
    events: pd.DataFrame
    holes: pd.DataFrame
    cycle_time_s: float


def _n_cycles(traj: Any) -> int:
    return int(np.asarray(traj.spindle_speed_cmd_rpm).size)


def _chunks_from(program: Any, machine: Machine, chunk_cycles: int) -> Iterator[_Chunk]:
    """Chunks with their 0-based offsets; event cycles are offsets from the program start."""
    if hasattr(program, "des_pos"):  # one whole trajectory
        n = _n_cycles(program)
        for lo in range(0, max(n, 1), chunk_cycles):
            yield _Chunk(lo, _slice_trajectory(program, lo, min(n, lo + chunk_cycles)))
        return
    if isinstance(program, list | tuple | Iterator):  # already chunked trajectories (an
        # iterator: produced while the simulation runs, e.g. a feed override in a closed loop)
        off = 0
        for t in program:
            yield _Chunk(off, t)
            off += _n_cycles(t)
        return
    from cnctwin.sim import interpolator  # engineer A's module
    from cnctwin.sim.gcode import parse_program

    prog = parse_program(program) if isinstance(program, str) else program
    limits = {ax.name: _axis_limits(interpolator, ax) for ax in machine.axes}
    spindle = _spindle_limits(interpolator, machine)
    off = 0
    for t in interpolator.interpolate_chunks(
        prog, limits=limits, spindle=spindle, cycle_time_s=machine.cycle_time_s,
        axes=machine.axis_names, chunk_cycles=chunk_cycles,
        tool_change_s=machine.tool_change_s,
    ):
        yield _Chunk(off, t)
        off += _n_cycles(t)


def _axis_limits(mod: Any, ax: Any) -> Any:
    return mod.AxisLimits(max_velocity_mm_min=ax.max_velocity_mm_min,
                          max_accel_mm_s2=ax.max_accel_mm_s2, max_jerk_mm_s3=ax.max_jerk_mm_s3)


def _spindle_limits(mod: Any, machine: Machine) -> Any:
    """Speed ramp from half the peak torque on the spindle inertia [rpm/s]."""
    sp = machine.spindle
    accel_rpm_s = sp.current_limit_a * sp.kt_nm_per_a * 0.5 / sp.inertia_kg_m2 * 60 / (2 * np.pi)
    return mod.SpindleLimits(max_speed_rpm=sp.max_speed_rpm, accel_rpm_s=float(accel_rpm_s))


# ----------------------------------------------------------------------------- simulate
def simulate(
    program: Any,
    machine: Machine | None = None,
    *,
    seed: int = 0,
    start_cycle: int = 5_000_000,
    start_time: str | pd.Timestamp = "2026-01-01T08:00:00Z",
    cutting: CuttingHook | None = None,
    dropped_cycles: float = 0.0,
    sink: RecordingSink | None = None,
    chunk_cycles: int = 50_000,
    progress: bool = False,
) -> SimulationResult:
    """Simulate a part program on the machine and record what the edge device records.

    Parameters
    ----------
    program : str, Program, Trajectory or list of Trajectory
        Part-program text, a parsed :class:`~cnctwin.sim.gcode.Program`, or an already
        interpolated trajectory (one, or its chunks in order).
    machine : Machine, optional
        Machine description; default :meth:`Machine.thesis_default`.
    seed : int, default 0
        Seed of every random stream (feed-axis current and measuring-system noise, spindle
        noise, dropped cycles). Same seed -> identical output; two seeds -> independent noise
        (the machine's own properties, e.g. each screw's ripple phase, stay the machine's).
    start_cycle : int, default 5_000_000
        CYCLE counter value of the first cycle.
    start_time : str or Timestamp, default '2026-01-01T08:00:00Z'
        UTC time of the first cycle.
    cutting : callable, optional
        ``cutting(CuttingInput) -> CuttingOutput`` giving spindle load torque and axis forces;
        default no process load (air cut).
    dropped_cycles : float, default 0
        Fraction of cycles randomly missing from the recording (counter gaps, as in real
        files) [-]; they are simulated but not recorded and show up in ``meta.gaps``.
    sink : RecordingSink, optional
        Where chunks go; default an in-memory sink whose Recording is returned.
    chunk_cycles : int, default 50_000
        Cycles per chunk (100 s at 2 ms); bounds memory when streaming.
    progress : bool, default False
        Print one progress line per chunk to stderr.

    Returns
    -------
    SimulationResult
    """
    machine = machine if machine is not None else Machine.thesis_default()
    if not 0.0 <= dropped_cycles < 1.0:
        raise ConfigError(f"dropped_cycles must be a fraction in [0, 1), not {dropped_cycles}")
    if chunk_cycles < 1:
        raise ConfigError(f"chunk_cycles must be >= 1, not {chunk_cycles}")
    t0 = pd.Timestamp(start_time)
    t0 = t0.tz_localize("UTC") if t0.tzinfo is None else t0.tz_convert("UTC")
    tc = machine.cycle_time_s
    streams = np.random.SeedSequence(seed).spawn(3)
    rng_servo, rng_spindle, rng_drop = (np.random.default_rng(s) for s in streams)

    feed = machine.axis_names
    sp_name = machine.spindle_name
    all_axes = (*feed, sp_name)
    columns = [f"{code}|{ax}" for ax in all_axes for code in RECORDED_CODES]
    meta = RecordingMeta(
        machine=machine.name, cycle_time_s=tc, axis_map=dict(machine.axis_map),
        source_format="sim", time_anchors=[(start_cycle, t0)],
        attrs={"simulator": "cnctwin.sim", "seed": seed},
    )
    in_memory = sink is None
    out_sink: RecordingSink = MemorySink() if sink is None else sink
    out_sink.open(columns, meta)
    # a sink that is done with a chunk's arrays when write() returns (keeps_chunks False):
    # the drive outputs go into two buffers reused chunk after chunk
    reuse = not in_memory and not getattr(out_sink, "keeps_chunks", True)
    servo_buf = np.empty(0)
    spindle_buf = np.empty(0)

    lags = {ax.name: _expected_lag_s(ax, tc) for ax in machine.axes}
    lf_period = max(1, round(LF_PERIOD_S / tc))
    servo_state: ServoState | None = None
    spindle_state: SpindleState | None = None
    tail: dict[str, NDArray[np.float64]] = {}
    last_pos = {ax: 0.0 for ax in feed}
    truth_frames: list[pd.DataFrame] = []
    holes: list[pd.DataFrame] = []
    n_total = 0
    n_dropped = 0
    n_events = 0
    for chunk in _chunks_from(program, machine, chunk_cycles):
        traj = chunk.traj
        n = _n_cycles(traj)
        if n == 0:
            continue
        off = np.arange(chunk.offset, chunk.offset + n, dtype=np.int64)
        cyc = start_cycle + off
        des = np.empty((len(feed), n))
        for i, ax in enumerate(feed):
            v = traj.des_pos.get(ax)
            des[i] = last_pos[ax] if v is None else np.asarray(v, dtype=np.float64)
            last_pos[ax] = float(des[i, -1])
        speed_cmd = np.asarray(traj.spindle_speed_cmd_rpm, dtype=np.float64)
        sp_mode = np.asarray(traj.spindle_mode, dtype=np.int64)
        sp_pos_cmd = np.asarray(traj.spindle_pos_cmd_deg, dtype=np.float64)

        # ---- process load
        if cutting is not None:
            pos = {}
            for i, ax in enumerate(feed):
                hist = np.concatenate([tail.get(ax, np.full(256, des[i, 0])), des[i]])
                k = np.arange(hist.size - n, hist.size, dtype=np.float64) - lags[ax] / tc
                pos[ax] = np.interp(k, np.arange(hist.size, dtype=np.float64), hist)
                tail[ax] = hist[-256:]
            cin = CuttingInput(
                cycle=cyc, offset=off, time_s=off.astype(np.float64) * tc,
                des_pos={ax: des[i] for i, ax in enumerate(feed)}, position=pos,
                spindle_speed_rpm=speed_cmd, spindle_pos_deg=sp_pos_cmd, spindle_mode=sp_mode,
                tool=np.asarray(traj.tool), block_index=np.asarray(traj.block_index),
                cycle_time_s=tc, duration_s=float(getattr(traj, "duration_s", math.nan)),
            )
            cout = cutting(cin)
            load = np.broadcast_to(np.asarray(cout.spindle_torque_nm, dtype=np.float64), (n,))
            force = np.zeros_like(des)
            for ax, f in cout.force_n.items():
                if ax not in feed:
                    raise ConfigError(f"cutting hook returned a force for {ax!r}; feed axes are "
                                      f"{', '.join(feed)}")
                force[feed.index(ax)] = f
            hook_truth = cout.truth
        else:
            load = np.zeros(n)
            force = np.zeros_like(des)
            hook_truth = {}

        # ---- drives
        sp_out = sv_out = None
        if reuse:
            if servo_buf.size < len(feed) * N_KERNEL_OUTPUTS * n:
                servo_buf = np.empty(len(feed) * N_KERNEL_OUTPUTS * n)
                spindle_buf = np.empty(len(_TRACE_FIELDS) * n)
            sv_out = servo_buf[:len(feed) * N_KERNEL_OUTPUTS * n].reshape(
                len(feed), N_KERNEL_OUTPUTS, n)
            sp_out = spindle_buf[:len(_TRACE_FIELDS) * n].reshape(len(_TRACE_FIELDS), n)
        sp = simulate_spindle(
            speed_cmd, load, machine.spindle, cycle_time_s=tc, inner_steps=machine.inner_steps,
            state=spindle_state, rng=rng_spindle, position_cmd_deg=sp_pos_cmd, mode=sp_mode,
            out=sp_out,
        )
        spindle_state = sp.state
        sv = simulate_servo(des, machine.axes, force_n=force, cycle_time_s=tc,
                            inner_steps=machine.inner_steps, state=servo_state, rng=rng_servo,
                            out=sv_out)
        servo_state = sv.state

        # ---- HF columns
        hf: dict[str, NDArray[np.float64]] = {}
        for i, ax in enumerate(feed):
            for code in RECORDED_CODES:
                hf[f"{code}|{ax}"] = sv.signals[code][i]
        hf.update(_spindle_columns(sp_name, sp, speed_cmd, sp_mode, sp_pos_cmd))

        # ---- LF values every 100 ms (on the cycle counter)
        lf = _lf_frame(cyc, lf_period, feed, sv.signals, sp_name, sp, meta)

        # ---- events, real cycles
        ev = traj.events.copy() if len(traj.events) else pd.DataFrame(columns=EVENT_COLUMNS)
        if len(ev):
            ev["cycle"] = ev["cycle"].astype(np.int64) + start_cycle
        n_events += len(ev)

        # ---- dropped cycles
        keep = np.ones(n, dtype=bool)
        if dropped_cycles > 0:
            keep = rng_drop.random(n) >= dropped_cycles
        n_dropped += int(n - keep.sum())
        if not keep.all():
            hf = {k: v[keep] for k, v in hf.items()}
        out_sink.write(RecordedChunk(cycles=cyc[keep], hf=hf, lf=lf, events=ev))

        # ---- truth
        if in_memory:
            tr: dict[str, NDArray[np.float64]] = {"spindle_load_torque_nm": load.copy()}
            for i, ax in enumerate(feed):
                tr[f"force_n|{ax}"] = force[i]
                tr[f"true_position|{ax}"] = sv.truth["true_position"][i]
                tr[f"friction|{ax}"] = sv.truth["friction_force"][i]
            tr["spindle_torque_nm"] = sp.torque_nm
            tr["spindle_friction_nm"] = sp.friction_nm
            tr["spindle_kt_nm_per_a"] = sp.kt_nm_per_a
            tr["spindle_rotor_temperature_c"] = sp.rotor_temperature_c
            for key, val in hook_truth.items():
                tr[key] = np.broadcast_to(np.asarray(val, dtype=np.float64), (n,))
            truth_frames.append(pd.DataFrame(tr, index=pd.Index(cyc, name="cycle")))
        if len(traj.holes):
            holes.append(traj.holes)
        n_total += n
        if progress:
            print(f"simulate: {n_total} cycles ({n_total * tc:.1f} s machine time)",
                  file=sys.stderr)

    meta.attrs["n_dropped_cycles"] = n_dropped
    recording = out_sink.close(meta)
    holes_df = pd.concat(holes, ignore_index=True) if holes else pd.DataFrame()
    for col in holes_df.columns:  # hole cycle offsets -> real cycle numbers
        if str(col).endswith("cycle"):
            holes_df[col] = holes_df[col].astype(np.int64) + start_cycle
    truth: dict[str, Any] = {
        "machine": machine.to_dict(),
        "seed": seed,
        "start_cycle": start_cycle,
        "start_time": t0,
        "dropped_cycles": dropped_cycles,
        "n_dropped": n_dropped,
        "holes": holes_df,
        "per_cycle": pd.concat(truth_frames) if truth_frames else pd.DataFrame(),
    }
    summary = {"n_cycles": n_total, "duration_s": n_total * tc, "n_holes": len(holes_df),
               "n_events": n_events}
    return SimulationResult(recording=recording if in_memory else None, truth=truth,
                            trajectory=summary)


def _expected_lag_s(ax: Any, tc: float) -> float:
    """Low-frequency lag of ENC_POS behind DES_POS: jerk filter + DRA + loop equivalent time."""
    t = ax.jerk_time_s if ax.jerk_time_s > tc else 0.0
    if ax.jerk_filter_type == 1:
        j = t
    elif ax.jerk_filter_type in (2, 4):
        m = max(1, round(t / tc))
        j = (m - 1) * tc / 2 * (2 if ax.jerk_filter_type == 4 else 1)
    else:
        j = 0.0
    return float(j + ax.dyn_match_time_s + ax.position_equivalent_time_s)


def _spindle_columns(
    name: str, sp: Any, speed_cmd: NDArray[np.float64], mode: NDArray[np.int64],
    pos_cmd: NDArray[np.float64],
) -> dict[str, NDArray[np.float64]]:
    """Spindle HF columns. Speed mode: no position loop (CTRL_DIFF/CONT_DEV/VEL_FFW zero)."""
    enc = np.mod(sp.position_deg, 360.0)
    pos_mode = mode == 1
    zeros = np.zeros_like(speed_cmd)
    if pos_mode.any():
        des = np.where(pos_mode, np.mod(pos_cmd, 360.0), enc)
        diff = np.where(pos_mode, (des - enc + 180.0) % 360.0 - 180.0, 0.0)
        vel_ffw = np.where(pos_mode, speed_cmd, 0.0)
    else:  # speed control throughout: the same values without the selects
        des, diff, vel_ffw = enc, zeros, zeros
    return {
        f"DES_POS|{name}": des,
        f"ENC_POS|{name}": enc,
        f"CTRL_POS|{name}": des,
        f"CTRL_DIFF|{name}": diff,
        f"CTRL_DIFF2|{name}": diff,
        f"CONT_DEV|{name}": zeros,
        f"VEL_FFW|{name}": vel_ffw,
        f"TORQUE_FFW|{name}": zeros,
        f"CMD_SPEED|{name}": speed_cmd.copy(),
        f"CURRENT|{name}": sp.current_a,
        f"TORQUE|{name}": sp.torque_setpoint_nm,
        f"LOAD|{name}": sp.load_pct,
        f"POWER|{name}": sp.power_w,
    }


def _lf_frame(
    cyc: NDArray[np.int64], period: int, feed: tuple[str, ...],
    sig: dict[str, NDArray[np.float64]], sp_name: str, sp: Any, meta: RecordingMeta,
) -> pd.DataFrame:
    from cnctwin.recording import cycles_to_time

    idx = np.flatnonzero(cyc % period == 0)
    if idx.size == 0:
        return pd.DataFrame(columns=LF_COLUMNS)
    names: list[str] = []
    rows: list[NDArray[np.float64]] = []
    for i, ax in enumerate(feed):
        for code in ("SPEED_SMOOTHED", "CURRENT_ABS_SMOOTHED", "IQ_ACT", "TORQUE_UTIL",
                     "MOTOR_TEMP"):
            names.append(f"{code}|{ax}")
            rows.append(sig[code][i, idx])
    names += [f"{code}|{sp_name}" for code in ("SPEED_SMOOTHED", "CURRENT_ABS_SMOOTHED",
                                                 "IQ_ACT", "TORQUE_UTIL", "MOTOR_TEMP")]
    rows += [sp.speed_smoothed_rpm[idx], sp.current_abs_smoothed_a[idx],
             sp.iq_smoothed_a[idx], sp.torque_utilization_pct[idx], sp.motor_temperature_c[idx]]
    # rows sorted by (cycle, signal) directly: cycle-major, signal names in sorted order
    order = sorted(range(len(names)), key=names.__getitem__)
    values = np.stack([rows[j] for j in order], axis=1).ravel()
    cycles = np.repeat(cyc[idx], len(names))
    # the signal column as an Arrow take from the sorted names (pandas' str dtype is Arrow
    # backed): 6x faster than converting a numpy unicode array, same frame
    sorted_names = pa.array([names[j] for j in order], type=pa.large_string())
    take = np.tile(np.arange(len(names), dtype=np.int32), idx.size)
    signals = sorted_names.take(pa.array(take)).to_pandas()
    # one time per sampled cycle, repeated per signal (cycles_to_time is elementwise)
    times = cycles_to_time(cyc[idx], meta.time_anchors,
                           cycle_time_s=meta.cycle_time_s).repeat(len(names))
    return pd.DataFrame({
        "cycle": cycles, "time": times, "signal": signals, "value": values,
        "text": pd.Series(np.full(cycles.size, None, dtype=object), dtype="object"),
    })


def iter_chunks(program: Any, machine: Machine, chunk_cycles: int) -> Iterable[Any]:
    """The trajectory chunks :func:`simulate` would run (for inspection and tests)."""
    return (c.traj for c in _chunks_from(program, machine, chunk_cycles))
