"""Processors of the edge runtime: cutting torque, per-hole events, anomaly detectors.

Each processor wraps an existing analysis instead of re-implementing it:

* :class:`TorqueProcessor`: :class:`cnctwin.spindle.StreamingTorqueEstimator` (identical to
  :meth:`SpindleModel.cutting_torque` on each contiguous run of cycles).
* :class:`HoleProcessor`: :func:`cnctwin.usecases.holes.holes_from_arrays` (the arrays form of
  ``hole_record``) run incrementally on a bounded buffer that starts after the previous hole.
* :class:`AnomalyProcessor`: any detector of :mod:`cnctwin.usecases.anomaly` (learn one / score
  one), taught on the first ``learn_s`` of the stream, then scoring.
* :class:`TwinCompareProcessor`: :func:`cnctwin.compare.compare_recording` on consecutive
  windows of the stream (the machine against its calibrated twin, live).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from cnctwin._jit import lazy_njit
from cnctwin.analysis.segments import runs_of, samples_since
from cnctwin.edge.cut import CutTracker
from cnctwin.edge.pipeline import Chunk, Result
from cnctwin.exceptions import ConfigError
from cnctwin.machine import MachineFile
from cnctwin.recording import CounterGap, Recording, RecordingMeta
from cnctwin.spindle import SpeedChangeFlags, SpindleModel, StreamingTorqueEstimator
from cnctwin.usecases.air_friction import AirFrictionCheck, RapidAir
from cnctwin.usecases.anomaly import Detector, PhysicsResidualDetector
from cnctwin.usecases.hole_load import HoleLoadJudge
from cnctwin.usecases.holes import HOLE_COLUMNS, HoleEvents, holes_from_arrays
from cnctwin.usecases.tool_life import ToolLifeTracker

__all__ = ["TORQUE_FLAGS", "AnomalyProcessor", "HoleProcessor", "TorqueProcessor",
           "TwinCompareProcessor", "prepare_kernels"]

TORQUE_FLAGS: Mapping[int, str] = SpeedChangeFlags.CODES
"""Codes of a ``torque`` result's ``flags`` (present when any cycle is flagged)."""


def _no_held() -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
    """No cycles held back: empty cycle, current and speed arrays."""
    return (np.empty(0, dtype=np.int64), np.empty(0, dtype=np.float64),
            np.empty(0, dtype=np.float64))


class TorqueProcessor:
    """Cutting torque ``tau_c = Kt I - B n - tau_f sign(n) - J dOmega/dt`` per cycle.

    Parameters
    ----------
    model : SpindleModel
        Calibrated spindle model (see :func:`cnctwin.edge.load_spindle_model`).
    spindle : str, default 'SP1'
        Spindle axis: uses ``CURRENT|<spindle>`` [A] and ``CMD_SPEED|<spindle>`` [rpm].
    accel_term : bool, default True
        Subtract ``J dOmega/dt`` (one cycle of delay, see ``StreamingTorqueEstimator``).

    speed_step_rpm : float, default 1
        A change of the speed command by more than this from one cycle to the next is a speed
        change (run-up, braking, a new S word) [rpm].
    settle_s : float, default 0.3
        Time after the last speed change during which the estimate is still flagged (the
        drive's speed loop and current filter settle) [s].
    min_speed_rpm : float, default 10
        Below this the spindle stands: no cut is possible, the estimate is flagged [rpm].

    Notes
    -----
    At a gap the estimator is flushed and restarted, so the derivative is never taken across
    missing cycles; on each contiguous run the result equals the batch
    :meth:`~cnctwin.spindle.SpindleModel.cutting_torque` of that run exactly.
    Each ``torque`` result holds ``first_cycle``, ``n`` and the arrays ``torque_nm``,
    ``speed_rpm``, ``current_a`` for consecutive cycles.

    **No torque without a cut.** While the speed changes the current mostly accelerates the
    rotor and the sampled current does not follow the cycle's mean torque
    (:class:`~cnctwin.spindle.SpeedChangeFlags`): such cycles, and a standing spindle, are no
    cutting-torque estimate. ``torque_nm`` is null there and the result carries ``flags``
    (one code per cycle, :data:`TORQUE_FLAGS`), so no display, MTConnect or OPC UA client
    shows a cut while the spindle only brakes; the same cycles are NaN in ``chunk.derived``
    (not judged by the torque detectors). Equal to
    :func:`~cnctwin.spindle.speed_change_flags` on the whole stream.
    """

    name = "torque"

    @property
    def needs(self) -> tuple[str, ...]:
        """The HF columns read (:func:`cnctwin.edge.pipeline.needed_columns`)."""
        return (self.i_col, self.n_col)

    def __init__(self, model: SpindleModel, *, spindle: str = "SP1",
                 accel_term: bool = True, speed_step_rpm: float = 1.0,
                 settle_s: float = 0.3, min_speed_rpm: float = 10.0) -> None:
        SpeedChangeFlags(speed_step_rpm=speed_step_rpm, settle_s=settle_s,
                         min_speed_rpm=min_speed_rpm)  # checks the options now
        self.speed_step_rpm, self.settle_s = speed_step_rpm, settle_s
        self.min_speed_rpm = min_speed_rpm
        self._flagger: SpeedChangeFlags | None = None
        self.model = model
        self.spindle = spindle
        self.i_col = f"CURRENT|{spindle}"
        self.n_col = f"CMD_SPEED|{spindle}"
        self.column = f"CUT_TORQUE|{spindle}"
        self._fs: float | None = None
        self.accel_term = accel_term
        self._est: StreamingTorqueEstimator | None = None
        self._held = _no_held()  # cycles, current, speed held back (the derivative's lead)
        self.samples = 0

    def _estimator(self, chunk: Chunk) -> StreamingTorqueEstimator:
        if self._est is None:
            self._fs = 1.0 / chunk.cycle_time_s
            self._est = StreamingTorqueEstimator(self.model, fs_hz=self._fs,
                                                 accel_term=self.accel_term)
        return self._est

    def prepare(self) -> None:
        """Compile the speed-change flags (numba) before a live stream's first chunk."""
        _prepare_flags()

    def _flagged(self, tau: NDArray[np.float64], n: NDArray[np.float64]
                 ) -> tuple[NDArray[np.float64], NDArray[np.int8]]:
        """The estimates of consecutive output cycles with their flag codes, NaN where
        flagged (the next cycle's command is known: a cycle's estimate waits for it)."""
        if self._flagger is None:
            self._flagger = SpeedChangeFlags(
                fs_hz=self._fs or 500.0, speed_step_rpm=self.speed_step_rpm,
                settle_s=self.settle_s, min_speed_rpm=self.min_speed_rpm)
        nxt = self._held[2]
        flags = self._flagger.update(n, float(nxt[0]) if nxt.size else None)
        if flags.any():
            tau = np.where(flags == 0, tau, np.nan)
        return tau, flags

    def _result(self, cycles: NDArray[np.int64], tau: NDArray[np.float64],
                flags: NDArray[np.int8], i: NDArray[np.float64], n: NDArray[np.float64]
                ) -> Result:
        """The ``torque`` result (its per-cycle values as lists: a result is plain JSON
        values, for any sink)."""
        c0 = int(cycles[0])
        payload: dict[str, Any] = {
            "spindle": self.spindle, "first_cycle": c0, "n": int(cycles.size),
            "torque_nm": tau.tolist(), "speed_rpm": n.tolist(), "current_a": i.tolist(),
            "units": {"torque_nm": "Nm", "speed_rpm": "rpm", "current_a": "A"}}
        if flags.any():
            payload["flags"] = flags.tolist()
        return Result("torque", c0, payload)

    def process(self, chunk: Chunk) -> list[Result]:
        if self.i_col not in chunk.signals or self.n_col not in chunk.signals:
            raise ConfigError(f"the torque processor needs {self.i_col!r} and {self.n_col!r}; "
                              f"the stream has {sorted(chunk.signals)}")
        est = self._estimator(chunk)
        i = np.asarray(chunk.signals[self.i_col], dtype=np.float64)
        n = np.asarray(chunk.signals[self.n_col], dtype=np.float64)
        tau = est.update(i, n)
        self.samples += tau.size
        hc, hi, hn = self._held
        off = hc.size
        if off:
            cyc = np.concatenate([hc, chunk.cycles])
            ii = np.concatenate([hi, i])
            nn = np.concatenate([hn, n])
        else:
            cyc, ii, nn = chunk.cycles, i, n
        k = tau.size
        self._held = (cyc[k:].copy(), ii[k:].copy(), nn[k:].copy())
        res = None
        if k:
            tau, flags = self._flagged(tau, nn[:k])
            res = self._result(cyc[:k], tau, flags, ii[:k], nn[:k])
        derived = np.full(len(chunk), np.nan)
        # estimates for this chunk's own cycles (the held-back one of the last chunk came out)
        own = tau[off:] if k > off else np.empty(0)
        derived[:own.size] = own
        chunk.derived[self.column] = derived
        if off and k >= off:  # the previous chunk's held-back cycle came out now
            chunk.late[self.column] = (int(hc[-1]), float(tau[off - 1]))
        return [res] if res is not None else []

    def __setstate__(self, state: dict[str, Any]) -> None:
        pending = state.pop("_pending", None)  # a checkpoint of an earlier version
        if pending is not None:
            rows = list(pending)
            state["_held"] = (np.array([r[0] for r in rows], dtype=np.int64),
                              np.array([r[1] for r in rows], dtype=np.float64),
                              np.array([r[2] for r in rows], dtype=np.float64))
        self.__dict__.update(state)

    def _flush(self) -> list[Result]:
        if self._est is None:
            return []
        tau = self._est.flush()
        hc, hi, hn = self._held
        self._held = _no_held()
        self.samples += tau.size
        if not tau.size or not hc.size:
            return []
        tau, flags = self._flagged(tau, hn)
        return [self._result(hc, tau, flags, hi, hn)]

    def gap(self, gap: CounterGap) -> list[Result]:
        out = self._flush()
        self._flagger = None  # each contiguous run is flagged on its own, as it is estimated
        return out

    def finish(self) -> list[Result]:
        return self._flush()


class HoleProcessor:
    """Per-hole record, incremental: ``hole_start`` when a plunge begins, ``hole`` when done.

    The HF columns a hole row needs are kept in a buffer that starts where the previous hole
    ended (the tool back above the surface). Each time the Z axis has moved up since the last
    check, :func:`~cnctwin.usecases.holes.holes_from_arrays` runs on the buffer (its arrays, no
    table is built); a hole is emitted once it is complete: the tool is out of the material
    and the X/Y setpoint has left the hole's position (next hole), or the tool has been out
    for ``settle_s`` (peck drilling: the next peck re-enters at the same X/Y within that
    time), or a later hole follows it. Rows
    equal those of the batch :func:`~cnctwin.usecases.holes.hole_records` on the whole
    recording (the test checks it) because the buffer holds the hole with its approach.

    Parameters
    ----------
    model : SpindleModel
        Spindle model for the torque columns of the row.
    spindle, z_axis, xy_axes : str
        Axis names as in :func:`~cnctwin.usecases.holes.hole_record`.
    window_s : float, default 0.6
        First-window length of each cut [s].
    set_size : int, default 6
        Holes per set.
    settle_s : float, default 1.0
        Time out of the material after which a hole is final [s].
    max_buffer_s : float, default 300
        Longest buffer kept without a hole [s]; older cycles are dropped (counted in
        ``issues``) so memory stays bounded.
    min_speed_mm_s : float, default 0.05
        Z speed above which the axis counts as moving [mm/s].
    live_context : bool, default True
        Also derive the live hole context per cycle (:class:`cnctwin.edge.cut.CutTracker`)
        for the processors after this one: ``chunk.derived`` gets ``HOLE|<z>`` (hole number,
        -1 outside the material), ``CUT_PROGRESS|<z>`` (tip depth / hole depth),
        ``CUT_DEPTH|<z>`` [mm], ``CUT_FEED|<z>`` [mm/min] and ``CUT_SPEED|<spindle>`` [rpm].
        Needs ``CMD_SPEED|<spindle>``; without it no cycle counts as cutting.
    load_judge : HoleLoadJudge or bool, default True
        Judges each completed hole against the taught load of its cut condition (tool,
        cycle, depth, speed, feed; :class:`cnctwin.usecases.hole_load.HoleLoadJudge`, True:
        its defaults): a broken drill, a hole without load, a load rise or drop give an
        ``alarm`` (``detector`` ``HoleLoadJudge``, ``fault``, ``message``). False: none.
    tool_kinds : mapping, optional
        T number -> kind from the tool table (``cnctwin edge run --tools``): a plunge of an
        end mill outside a drilling cycle is not a hole.
    tool_life : ToolLifeTracker, optional
        After each hole a ``tool_life`` result of the hole's tool
        (:class:`cnctwin.usecases.tool_life.ToolLifeTracker`: holes used, flank-wear
        estimate, remaining life with its interval). A partial hole counts as a usage; its
        torque is not used for the wear.
    """

    name = "holes"

    @property
    def needs(self) -> tuple[str, ...]:
        """The HF columns read (:func:`cnctwin.edge.pipeline.needed_columns`)."""
        return tuple(self.columns)

    def __init__(self, model: SpindleModel | None = None, *, spindle: str = "SP1",
                 z_axis: str = "Z1", xy_axes: tuple[str, str] = ("X1", "Y1"),
                 window_s: float = 0.6, set_size: int = 6, settle_s: float = 1.0,
                 max_buffer_s: float = 300.0, min_speed_mm_s: float = 0.05,
                 live_context: bool = True,
                 load_judge: HoleLoadJudge | bool = True,
                 tool_kinds: Mapping[int, str] | None = None,
                 tool_life: ToolLifeTracker | None = None) -> None:
        self.tool_kinds = dict(tool_kinds) if tool_kinds is not None else None
        self.tool_life = tool_life
        self.load_judge: HoleLoadJudge | None = (
            HoleLoadJudge() if load_judge is True else load_judge or None)
        self.model = model
        self.spindle, self.z_axis, self.xy_axes = spindle, z_axis, xy_axes
        self.window_s, self.set_size, self.settle_s = window_s, set_size, settle_s
        self.max_buffer_s = max_buffer_s
        self.min_speed_mm_s = min_speed_mm_s
        axes = (*xy_axes, z_axis)
        self.columns = [f"CURRENT|{spindle}", f"CMD_SPEED|{spindle}",
                        *(f"{c}|{a}" for a in axes for c in ("DES_POS", "ENC_POS")),
                        f"TORQUE|{z_axis}", f"CURRENT|{z_axis}"]
        self.holes = 0
        self.issues: list[str] = []
        self._parts: list[Chunk] = []
        self._n = 0
        self._events: list[HoleEvents] = []
        self._origin_ns: int | None = None
        self._cycle_time_s = 0.002
        self._moved_up = False
        self._rising = False
        self._pending: int | None = None
        self._last_z: float | None = None
        self._in_plunge = False
        self._down_run = 0
        self._up_run = 0
        self.plunges = 0
        self.live_context = live_context
        self.cut: CutTracker | None = None
        self._resumed_after: int | None = None
        self._modal: HoleEvents | None = None

    def _z(self, chunk: Chunk) -> NDArray[np.float64] | None:
        for c in (f"DES_POS|{self.z_axis}", f"ENC_POS|{self.z_axis}"):
            if c in chunk.signals:
                return chunk.signals[c]
        return None

    def process(self, chunk: Chunk) -> list[Result]:
        if self._origin_ns is None:
            self._origin_ns = int(chunk.time_ns[0])
            self._cycle_time_s = chunk.cycle_time_s
        out: list[Result] = []
        z = self._z(chunk)
        if z is None:
            raise ConfigError(f"the hole processor needs DES_POS|{self.z_axis} or "
                              f"ENC_POS|{self.z_axis}; the stream has {sorted(chunk.signals)}")
        sig = chunk.signals
        keep = {c: sig[c] for c in self.columns if c in sig}
        self._parts.append(Chunk(chunk.cycles, chunk.time_ns, keep,
                                 cycle_time_s=chunk.cycle_time_s, machine=chunk.machine))
        self._n += len(chunk)
        events = HoleEvents.from_frame(chunk.events)  # once, for the buffer and the tracker
        if len(events):
            self._events.append(events)
        # live plunge start and "moved up" trigger from the Z setpoint
        step = self.min_speed_mm_s * chunk.cycle_time_s
        has_prev = self._last_z is not None
        zz = z if self._last_z is None else np.concatenate([[self._last_z], z])
        dz = np.diff(zz)
        self._last_z = float(z[-1]) if z.size else self._last_z
        if (dz > step).any():
            self._rising = True
        elif self._rising:  # a retract has finished: a hole may be complete
            self._rising = False
            self._moved_up = True
        if self._pending is not None and (chunk.last_cycle >= self._pending
                                          or self._xy_moved(chunk)):
            self._moved_up = True
        for j in self._plunge_starts(dz, step):
            c = int(chunk.cycles[j if has_prev else j + 1])
            self.plunges += 1
            out.append(Result("hole_start", c, {"holes_done": self.holes, "cycle": c,
                                                 "z_mm": float(zz[j + 1]),
                                                 "units": {"z_mm": "mm"}}))
        if self.live_context:
            self._context(chunk, z, events)
        if self._moved_up:
            self._pending = None
            out += self._evaluate(final=False)
        self._trim()
        return out

    def _plunge_starts(self, dz: NDArray[np.float64], step: float) -> list[int]:
        """Where a plunge starts among the Z steps ``dz``: the 5th sample of a run of samples
        moving down (samples that do not move leave the runs as they are), unless a plunge
        is on; 5 samples moving up end it. A loop over the runs, not the samples."""
        sign = np.where(dz < -step, -1, np.where(dz > step, 1, 0))
        moving = np.flatnonzero(sign)
        out: list[int] = []
        for value, a, end in runs_of(sign[moving]):
            n = end - a
            if value < 0:
                if not self._in_plunge and self._down_run + n >= 5:
                    self._in_plunge = True
                    out.append(int(moving[a + max(5 - self._down_run, 1) - 1]))
                self._down_run += n
                self._up_run = 0
            else:
                if self._up_run + n >= 5:
                    self._in_plunge = False
                self._up_run += n
                self._down_run = 0
        return out

    def _context(self, chunk: Chunk, z: NDArray[np.float64], events: HoleEvents) -> None:
        """Live hole context of the chunk's cycles into ``chunk.derived``."""
        if self.cut is None:
            self.cut = CutTracker(cycle_time_s=chunk.cycle_time_s,
                                  min_speed_mm_s=self.min_speed_mm_s, settle_s=self.settle_s,
                                  first_hole=self.holes)
            if self._modal is not None:
                self.cut.restore_modal(self._modal)
                self._modal = None
        s = chunk.signals
        enc = s.get(f"ENC_POS|{self.z_axis}", z)
        nan = np.full(len(chunk), np.nan)
        speed = s.get(f"CMD_SPEED|{self.spindle}", nan)
        xy = tuple(s[f"DES_POS|{a}"] for a in self.xy_axes if f"DES_POS|{a}" in s)
        ctx = self.cut.update(chunk.cycles, z, enc, speed, xy_des_mm=xy, events=events)
        za = self.z_axis
        chunk.derived[f"HOLE|{za}"] = ctx.hole
        chunk.derived[f"CUT_PROGRESS|{za}"] = ctx.progress
        chunk.derived[f"CUT_DEPTH|{za}"] = ctx.depth_mm
        chunk.derived[f"CUT_FEED|{za}"] = ctx.feed_mm_min
        chunk.derived[f"CUT_SPEED|{self.spindle}"] = ctx.speed_rpm

    def __getstate__(self) -> dict[str, Any]:
        """The state a checkpoint pickles: the buffer as one part of plain arrays (a chunk
        pickles its empty event table, ~0.13 ms each; a hole's worth of 1 s chunks cost
        ~0.5 ms per checkpoint, 0.05 ms so)."""
        state = dict(self.__dict__)
        if self._parts:
            cols, cyc, t = self._buffer()
            last = self._parts[-1]
            state["_parts"] = [(cyc, t, cols, last.cycle_time_s, last.machine)]
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        parts = [p if isinstance(p, Chunk) else  # (a checkpoint of an earlier version)
                 Chunk(p[0], p[1], p[2], cycle_time_s=p[3], machine=p[4])
                 for p in state.get("_parts", [])]
        self.__dict__.update(state)
        self._parts = parts

    def _buffer(self) -> tuple[dict[str, NDArray[np.float64]], NDArray[np.int64],
                               NDArray[np.int64]]:
        """The buffered columns, cycles and times as contiguous arrays."""
        parts = self._parts
        cols = sorted({c for p in parts for c in p.signals})
        cyc = np.concatenate([p.cycles for p in parts])
        t = np.concatenate([p.time_ns for p in parts])
        # (a column a part lacks is NaN there; the NaN block made only then: made as the
        # default of every get(), it was 2/3 of the numpy calls of a hole's evaluation)
        data = {c: np.concatenate([p.signals[c] if c in p.signals
                                   else np.full(len(p), np.nan) for p in parts]
                                  ).astype(np.float64, copy=False)
                for c in cols}
        return data, cyc, t

    def _evaluate(self, *, final: bool) -> list[Result]:
        self._moved_up = False
        if not self._parts:
            return []
        cols, cycles, t_ns = self._buffer()
        speed = cols.get(f"CMD_SPEED|{self.spindle}")
        events = HoleEvents.concat(self._events).until(int(cycles[-1]))
        found = holes_from_arrays(cols, cycles, t_ns, cycle_time_s=self._cycle_time_s,
                                  speed_rpm=speed, events=events, spindle=self.spindle,
                                  z_axis=self.z_axis, xy_axes=self.xy_axes, model=self.model,
                                  window_s=self.window_s, set_size=self.set_size,
                                  first_hole=self.holes, origin_ns=self._origin_ns,
                                  tool_kinds=self.tool_kinds)
        rows = found.rows
        if not rows:
            return []
        last_cycle = int(cycles[-1])
        out: list[Result] = []
        cut_at: int | None = None
        for k, row in enumerate(rows):
            ext_cycle = int(row["end_cycle"]) + round(
                (float(row["extraction_s"]) - float(row["end_s"])) / self._cycle_time_s)
            done = final or k < len(rows) - 1 or (ext_cycle < last_cycle and (
                ((last_cycle - ext_cycle) * self._cycle_time_s >= self.settle_s
                 and not self._reentered(cols, cycles, ext_cycle, row))
                or self._moved_away(cols, cycles, ext_cycle, row)))
            if not done:  # look again when X/Y moves or after settle_s
                self._pending = last_cycle + round(self.settle_s / self._cycle_time_s)
                break
            payload = _row_payload(row)
            msg: dict[str, Any] = {"hole": int(row["hole"]), "row": payload,
                                   "units": HOLE_UNITS}
            resumed = self._resumed_after
            if resumed is not None:
                if int(row["start_cycle"]) <= resumed + 2:
                    msg["partial"] = True
                    msg["partial_reason"] = (
                        f"the runtime restarted at cycle {resumed + 1} without its state "
                        "while this hole was being drilled: its plunge began before the data "
                        "this run has; the row covers only the part after the restart")
                self._resumed_after = None
            out.append(Result("hole", int(row["end_cycle"]), msg))
            if self.load_judge is not None and not msg.get("partial"):
                verdict = self.load_judge.judge(payload)
                if verdict is not None:
                    out.append(Result("alarm", int(row["end_cycle"]), {
                        "detector": "HoleLoadJudge", "fault": verdict.kind,
                        "cycle": int(row["end_cycle"]), "score": verdict.ratio,
                        "reference_nm": verdict.reference_nm, "hole": verdict.hole,
                        "message": verdict.message,
                        "units": {"score": "-", "reference_nm": "Nm"}}))
            if self.tool_life is not None and payload.get("tool") is not None:
                tq = payload.get("torque_mean_nm")
                life = self.tool_life.update(
                    int(payload["tool"]),
                    float("nan") if tq is None or msg.get("partial") else float(tq),
                    float(payload.get("end_s") or float("nan")))
                out.append(Result("tool_life", int(row["end_cycle"]),
                                  {"hole": int(row["hole"]), **life.as_payload()}))
            if self.cut is not None:
                self.cut.hole_done(payload)
            self.holes += 1
            cut_at = ext_cycle
        for note in found.attrs["issues"]:
            # the event count covers the modal history kept before the buffer: not a finding
            if "drilling-cycle calls" not in note and note not in self.issues:
                self.issues.append(note)
        if cut_at is not None and not final:
            self._drop_before(cut_at)
        return out

    def _xy_moved(self, chunk: Chunk) -> bool:
        for axis in self.xy_axes:
            v = chunk.signals.get(f"DES_POS|{axis}")
            if v is not None and v.size and float(np.nanmax(v) - np.nanmin(v)) > 0.01:
                return True
        return False

    def _reentered(self, cols: dict[str, NDArray[np.float64]], cycles: NDArray[np.int64],
                   cycle: int, row: dict[str, Any]) -> bool:
        """The tip went back below the hole's surface after it came out: the next peck of
        the same hole (CYCLE83 re-enters after its retract), so the hole is not complete."""
        z = cols.get(f"ENC_POS|{self.z_axis}", cols.get(f"DES_POS|{self.z_axis}"))
        surface = float(row["surface_z_mm"])
        if z is None or not math.isfinite(surface):
            return False
        after = z[int(np.searchsorted(cycles, cycle)) + 1:]
        return bool(after.size and np.nanmin(after) <= surface)

    def _moved_away(self, cols: dict[str, NDArray[np.float64]], cycles: NDArray[np.int64],
                    cycle: int, row: dict[str, Any]) -> bool:
        """The X/Y setpoint left the hole's position after the tool came out (next hole)."""
        i0 = int(np.searchsorted(cycles, cycle))
        for axis, key in zip(self.xy_axes, ("x_mm", "y_mm"), strict=True):
            ref = float(row[key])
            v = cols.get(f"DES_POS|{axis}")
            if v is not None and math.isfinite(ref):
                v = v[i0:]
                if v.size and np.nanmax(np.abs(v - ref)) > 0.01:
                    return True
        return False

    def _drop_before(self, cycle: int) -> None:
        parts: list[Chunk] = []
        for p in self._parts:
            if p.last_cycle < cycle:
                continue
            if p.first_cycle < cycle:
                s = int(np.searchsorted(p.cycles, cycle))
                p = Chunk(p.cycles[s:], p.time_ns[s:], {c: v[s:] for c, v in p.signals.items()},
                          cycle_time_s=p.cycle_time_s, machine=p.machine)
            parts.append(p)
        self._parts = parts
        self._n = sum(len(p) for p in parts)

    def _trim(self) -> None:
        limit = round(self.max_buffer_s / self._cycle_time_s)
        if self._n > limit and self._parts:
            cut = int(self._parts[-1].cycles[-1]) - limit + 1
            before = self._n
            self._drop_before(cut)
            self.issues.append(f"hole buffer longer than {self.max_buffer_s:g} s without a "
                               f"complete hole: {before - self._n} cycles before {cut} dropped "
                               "from the hole search")
        if len(self._events) > 64:  # one part per chunk with events: merge them
            self._events = [HoleEvents.concat(self._events)]
        if self._events and len(self._events[0]) > 10_000:
            self._events = [self._events[0].take(-5_000), *self._events[1:]]

    def gap(self, gap: CounterGap) -> list[Result]:
        if self.cut is not None:
            self.cut.gap()
        return []  # hole_record works on the cycle base; a gap inside a hole stays visible

    def resumed_without_state(self, after_cycle: int, *, next_hole: int | None = None,
                              events: pd.DataFrame | None = None) -> None:
        """The runtime restarted after ``after_cycle`` without this processor's state.

        A hole whose plunge began at or before the restart is flagged partial (its start is
        not in the data this run sees), never completed from a guess. Holes are numbered on
        from ``next_hole`` (the previous run's last hole + 1), and ``events`` (the NC events
        up to the restart, read again from a replayed file) restore the modal drilling cycle,
        so the holes after the restart get the program's geometry.
        """
        self._resumed_after = int(after_cycle)
        if next_hole is not None:
            self.holes = max(self.holes, int(next_hole))
        if events is not None and not events.empty:
            self._modal = HoleEvents.from_frame(events)
            self._events.append(self._modal)
            self.cut = None  # made with the first chunk, from these events

    def finish(self) -> list[Result]:
        return self._evaluate(final=True)


HOLE_UNITS: dict[str, str] = {
    k: v.rsplit("[", 1)[1].rstrip("]") for k, v in HOLE_COLUMNS.items() if v.endswith("]")
}
"""Units of the hole-row fields (from :data:`cnctwin.usecases.holes.HOLE_COLUMNS`)."""


def _air_samples_py(x: NDArray[np.float64], y: NDArray[np.float64], z: NDArray[np.float64],
                    lx: float, ly: float, lz: float, step: float, still: int, after: int,
                    since_move: int, since_down: int, out: NDArray[np.float64]
                    ) -> tuple[int, int]:
    """:meth:`AnomalyProcessor._air` as one loop (compiled): a sample moves when any
    setpoint steps more than ``step`` from the one before (``lx, ly, lz`` for the first) or
    is NaN, and goes down when Z steps below ``-step``; 1.0 where ``still`` samples passed
    since the last move and ``after`` since the last step down. Returns both counts."""
    for k in range(x.size):
        dx, dy, dz = x[k] - lx, y[k] - ly, z[k] - lz
        still_now = abs(dx) <= step and abs(dy) <= step and abs(dz) <= step
        since_move = since_move + 1 if still_now else 0
        since_down = 0 if dz < -step else since_down + 1
        out[k] = 1.0 if since_move >= still and since_down >= after else 0.0
        lx, ly, lz = x[k], y[k], z[k]
    return since_move, since_down


_air_samples = lazy_njit(_air_samples_py)


def prepare_kernels() -> None:
    """Compile (or load from numba's cache) the loops of the processors' chunk paths: the
    speed-change flags, the anomaly processor's air and rapid-traverse counts, the physics
    detector. A live source calls it before it connects (``cnctwin edge run``); each
    processor's ``prepare`` covers what it uses as well."""
    _prepare_flags()
    _prepare_air()
    PhysicsResidualDetector().prepare()


def _prepare_flags() -> None:
    """Compile the speed-change flags (torque processor, friction check)."""
    SpeedChangeFlags().update(np.zeros(2))


def _prepare_air() -> None:
    """Compile the anomaly processor's air count and the rapid-traverse air's."""
    z = np.zeros(1)
    _air_samples(z, z, z, 0.0, 0.0, 0.0, 1.0, 1, 1, 0, 0, np.empty(1))
    samples_since(np.zeros(1, dtype=np.bool_), before=0)


def _row_payload(row: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in row.items():
        if isinstance(v, pd.Timestamp):
            out[str(k)] = v.isoformat()
        elif v is None or (isinstance(v, float) and math.isnan(v)) or v is pd.NA:
            out[str(k)] = None
        elif isinstance(v, np.generic):
            out[str(k)] = v.item()
        else:
            out[str(k)] = v
    return out


class AnomalyProcessor:
    """Run a :mod:`cnctwin.usecases.anomaly` detector on every cycle, raise alarms.

    Inputs per cycle (the names :func:`cnctwin.usecases.anomaly.signal_stream` uses):
    ``current_a``, ``speed_rpm``, ``predicted_current_a`` (the calibrated twin at zero cutting
    torque), ``z_error_mm`` (DES_POS - ENC_POS of Z), ``torque_nm`` when the torque processor
    ran before, and the hole context when the hole processor ran before (its live
    :class:`~cnctwin.edge.cut.CutTracker`): ``hole`` (-1 outside the material) and ``progress``
    (tip depth / hole depth, NaN outside); without the hole processor ``hole`` is -1 and
    ``progress`` NaN. ``expected_torque_nm`` (the Kienzle torque of the cut,
    :func:`cnctwin.usecases.monitoring.drilling_torque_nm` with the live feed, speed and tip
    depth; NaN while the point enters) is given when the detector asks for it.

    Parameters
    ----------
    detector : Detector, optional
        Default :class:`~cnctwin.usecases.anomaly.PhysicsResidualDetector` (current against
        the twin's prediction).
    model : SpindleModel, optional
        Twin for ``predicted_current_a`` (default the thesis parameter set).
    learn_s : float, default 10
        The first seconds of the stream are learned (teach-in on good data) [s].
    learn_holes : int, optional
        Instead of ``learn_s``: learn until the first cycle of hole ``learn_holes`` (the
        teach-in of :class:`~cnctwin.usecases.monitoring.WearAdaptiveDetector` on the first
        holes); needs the hole processor before this one.
    threshold : float, default 0
        Score above which an alarm is raised.
    refractory_s : float, default 1
        Crossings within this time after an alarm are not new alarms [s].
    material : str, default 'aisi1045'
        Kienzle constants (:data:`cnctwin.usecases.monitoring.KIENZLE_PARAMETERS`) of
        ``expected_torque_nm``.
    diameter_mm, point_angle_deg : float
        Drill geometry of ``expected_torque_nm`` [mm], [deg].
    xy_axes : (str, str), default ('X1', 'Y1')
        Lateral axes for the ``air`` input.
    friction_check : AirFrictionCheck, optional
        Also judge the mean air current against ``model`` itself (not learned: a friction
        that is high from the start shows; :mod:`cnctwin.usecases.air_friction`): an alarm
        with ``detector`` ``AirFrictionCheck``, ``fault`` ``friction_rise``/``friction_drop``.
        ``cnctwin edge run`` turns it on with the calibrated machine file's spindle. Besides
        the ``air`` samples it judges the rapid traverses the NC events show
        (:class:`cnctwin.usecases.air_friction.RapidAir`: ``G0`` outside a machining cycle),
        where production spends most of its air time.
    air_still_s, air_after_plunge_s : float, default 0.3, 1.0
        ``air`` (given when the detector asks for it): 1 where every feed axis has stood
        still for ``air_still_s`` and Z has not gone down for ``air_after_plunge_s`` (a tool
        cuts only while an axis feeds, or dwells at a hole's bottom), 0 else [s].

    Notes
    -----
    The cutting torque of a chunk's last cycle comes with the next chunk (the central
    difference of the inertia term). When the detector uses ``torque_nm`` that cycle is held
    back and scored with the next chunk (``chunk.late``): one cycle (2 ms) of latency, and the
    detector sees exactly the batch torque. At a gap or the end of the stream the held cycle
    is scored with the torque unknown (NaN: not judged by the torque detectors).
    """

    @property
    def needs(self) -> tuple[str, ...]:
        """The HF columns read (:func:`cnctwin.edge.pipeline.needed_columns`)."""
        sp, z = self.spindle, self.z_axis
        return (f"CURRENT|{sp}", f"CMD_SPEED|{sp}", f"DES_POS|{z}", f"ENC_POS|{z}",
                *(f"DES_POS|{a}" for a in self.xy_axes))

    def __init__(self, detector: Detector | None = None, *, model: SpindleModel | None = None,
                 spindle: str = "SP1", z_axis: str = "Z1", learn_s: float = 10.0,
                 learn_holes: int | None = None, threshold: float = 0.0,
                 refractory_s: float = 1.0, material: str = "aisi1045",
                 diameter_mm: float = 8.5, point_angle_deg: float = 140.0,
                 xy_axes: tuple[str, str] = ("X1", "Y1"), air_still_s: float = 0.3,
                 air_after_plunge_s: float = 1.0,
                 friction_check: AirFrictionCheck | None = None) -> None:
        from cnctwin.usecases.monitoring import KIENZLE_PARAMETERS

        self.friction_check = friction_check
        self._rapid = RapidAir()
        self.detector = detector if detector is not None else PhysicsResidualDetector()
        self.name = f"anomaly:{type(self.detector).__name__}"
        self.model = model if model is not None else SpindleModel.from_parameters(
            "thesis_spinner_840dsl")
        self.spindle, self.z_axis = spindle, z_axis
        self.learn_s, self.threshold, self.refractory_s = learn_s, threshold, refractory_s
        if learn_holes is not None and learn_holes < 0:
            raise ConfigError(f"learn_holes must be >= 0, not {learn_holes}")
        self.learn_holes = learn_holes
        if material not in KIENZLE_PARAMETERS:
            raise ConfigError(f"material {material!r} unknown; choose one of "
                              f"{sorted(KIENZLE_PARAMETERS)}")
        if not (diameter_mm > 0 and 0 < point_angle_deg < 180):
            raise ConfigError(f"drill diameter must be > 0 mm and the point angle in (0, 180) "
                              f"deg; got {diameter_mm} mm, {point_angle_deg} deg")
        self.material, self.diameter_mm = material, diameter_mm
        self.point_angle_deg = point_angle_deg
        self.xy_axes = xy_axes
        self.air_still_s, self.air_after_plunge_s = air_still_s, air_after_plunge_s
        self._air_last: tuple[float, ...] | None = None
        self._air_since_move = 0
        self._air_since_down = 0
        self.learned = 0
        self.scored = 0
        self.alarms = 0
        self._start: int | None = None
        self._taught = learn_holes == 0
        self._above = False
        self._last_alarm: int | None = None
        self._held: tuple[int, dict[str, float]] | None = None
        self._ct = 0.002

    def _expected(self, ctx: dict[str, NDArray[np.float64]]) -> NDArray[np.float64]:
        """Kienzle torque of the live cut; NaN outside and while the point enters [Nm]."""
        from cnctwin.usecases.monitoring import KIENZLE_PARAMETERS, drilling_torque_nm

        depth = ctx["depth"]
        with np.errstate(invalid="ignore", divide="ignore"):
            f = ctx["feed"] / np.abs(ctx["speed"])
        ok = np.isfinite(depth) & np.isfinite(f) & (f > 0)
        out = np.full(depth.size, np.nan)
        if ok.any():
            out[ok] = drilling_torque_nm(f[ok], diameter_mm=self.diameter_mm,
                                         point_angle_deg=self.point_angle_deg,
                                         depth_mm=depth[ok],
                                         **KIENZLE_PARAMETERS[self.material])
            cone = self.diameter_mm / 2.0 / math.tan(math.radians(self.point_angle_deg / 2.0))
            out[ok & ~(depth >= cone)] = np.nan  # as expected_torque_stream: full engagement
        return out

    def process(self, chunk: Chunk) -> list[Result]:
        s = chunk.signals
        n_rows = len(chunk)
        i = s.get(f"CURRENT|{self.spindle}")
        n = s.get(f"CMD_SPEED|{self.spindle}")
        if i is None or n is None:
            raise ConfigError(f"the anomaly processor needs CURRENT|{self.spindle} and "
                              f"CMD_SPEED|{self.spindle}")
        des, enc = s.get(f"DES_POS|{self.z_axis}"), s.get(f"ENC_POS|{self.z_axis}")
        zerr = des - enc if des is not None and enc is not None else np.zeros(n_rows)
        pred = self.model.predict_current_a(0.0, n)
        d = chunk.derived
        tq_col = f"CUT_TORQUE|{self.spindle}"
        tq = d.get(tq_col)
        hole = d.get(f"HOLE|{self.z_axis}")
        cols: dict[str, NDArray[np.float64]] = {
            "current_a": i, "speed_rpm": n, "predicted_current_a": pred, "z_error_mm": zerr,
            "progress": d.get(f"CUT_PROGRESS|{self.z_axis}", np.full(n_rows, np.nan)),
            "hole": hole if hole is not None else np.full(n_rows, -1.0)}
        if tq is not None:
            cols["torque_nm"] = tq
        keys = list(self.detector.inputs)
        if "air" in keys or self.friction_check is not None:
            cols["air"] = self._air(chunk)
        needs_holes = "hole" in keys or "progress" in keys or self.learn_holes is not None
        if needs_holes and hole is None:
            raise ConfigError(f"{self.name} needs the live hole context (hole, progress): run "
                              "the hole processor before the anomaly processor (not --no-holes)")
        if "expected_torque_nm" in keys and hole is not None:
            cols["expected_torque_nm"] = self._expected({
                "depth": d[f"CUT_DEPTH|{self.z_axis}"], "feed": d[f"CUT_FEED|{self.z_axis}"],
                "speed": d[f"CUT_SPEED|{self.spindle}"]})
        missing = [k for k in keys if k not in cols]
        if missing:
            raise ConfigError(f"{self.name} needs inputs {missing} the edge stream lacks")
        if self._start is None:
            self._start = chunk.first_cycle
        self._ct = chunk.cycle_time_s
        out: list[Result] = []
        refr = round(self.refractory_s / chunk.cycle_time_s)
        learn_until = self._start + round(self.learn_s / chunk.cycle_time_s)
        if self._held is not None:  # the previous chunk's last cycle, its torque now known
            c0, x0 = self._held
            self._held = None
            late = chunk.late.get(tq_col)
            if late is not None and late[0] == c0:
                x0["torque_nm"] = late[1]
            self._one(c0, x0, learn_until, refr, out)
        m = n_rows
        hold = bool("torque_nm" in keys and tq is not None and n_rows
                    and not np.isfinite(tq[-1]))
        if hold:  # the last cycle waits for its torque (next chunk)
            m = n_rows - 1
            self._held = (chunk.last_cycle, {k: float(cols[k][-1]) for k in keys})
        x = {k: cols[k][:m] for k in keys}
        # learning is a prefix of the stream: the chunk splits into learned and scored cycles
        if self.learn_holes is not None:
            if self._taught:
                n_learn = 0
            else:
                reached = np.flatnonzero(cols["hole"][:m] >= self.learn_holes)
                n_learn = int(reached[0]) if reached.size else m
                self._taught = bool(reached.size)
        else:
            n_learn = int(np.clip(learn_until - chunk.first_cycle, 0, m))
        scores = np.full(n_rows, np.nan)
        if n_learn:
            self.detector.learn_chunk({k: v[:n_learn] for k, v in x.items()})
            self.learned += n_learn
        if m > n_learn:
            sc = self.detector.score_chunk({k: v[n_learn:m] for k, v in x.items()})
            scores[n_learn:m] = sc
            self.scored += m - n_learn
            self._alarms(chunk.cycles[n_learn:m], sc, x, n_learn, refr, out)
        chunk.derived[f"ANOMALY_SCORE|{self.spindle}"] = scores
        if self.friction_check is not None:
            rapid = self._rapid.update(chunk.cycles, chunk.events,
                                       cycle_time_s=chunk.cycle_time_s)
            for f in self.friction_check.update(chunk.cycles, i, pred, n,
                                                np.maximum(cols["air"], rapid),
                                                cycle_time_s=chunk.cycle_time_s):
                self.alarms += 1
                out.append(Result("alarm", f.cycle, {
                    "detector": "AirFrictionCheck",
                    "fault": "friction_rise" if f.residual_a > 0 else "friction_drop",
                    "cycle": f.cycle, "score": f.residual_a / f.tolerance_a, "threshold": 1.0,
                    "current_a": f.predicted_a + f.residual_a, "predicted_current_a":
                    f.predicted_a, "speed_rpm": f.speed_rpm, "message": f.message,
                    "hole": None, "units": {"current_a": "A", "predicted_current_a": "A",
                                            "speed_rpm": "rpm", "score": "-"}}))
        return out

    def prepare(self) -> None:
        """Compile the loops of its chunk path (numba) before a live stream's first chunk;
        the state is not touched."""
        _prepare_air()
        if self.friction_check is not None:
            _prepare_flags()
        self.detector.prepare()

    def _air(self, chunk: Chunk) -> NDArray[np.float64]:
        """1.0 where the tool cannot be cutting: every feed axis (X, Y, Z setpoints) has stood
        still for ``air_still_s`` and Z has not moved down for ``air_after_plunge_s`` (the
        dwell at a hole's bottom); 0.0 else, and everywhere without the setpoints."""
        n_rows = len(chunk)
        axes = [chunk.signals.get(f"DES_POS|{a}") for a in (*self.xy_axes, self.z_axis)]
        if n_rows == 0 or any(v is None for v in axes):
            return np.zeros(n_rows)
        x, y, z = (np.ascontiguousarray(v, dtype=np.float64) for v in axes)
        ct = chunk.cycle_time_s
        last = (float(x[0]), float(y[0]), float(z[0])) if self._air_last is None \
            else self._air_last
        out = np.empty(n_rows)
        self._air_since_move, self._air_since_down = (int(v) for v in _air_samples(
            x, y, z, *last, 0.05 * ct,  # 0.05 mm/s, the hole record's standstill
            round(self.air_still_s / ct), round(self.air_after_plunge_s / ct),
            self._air_since_move, self._air_since_down, out))
        self._air_last = (float(x[-1]), float(y[-1]), float(z[-1]))
        return out

    def _alarms(self, cycles: NDArray[np.int64], sc: NDArray[np.float64],
                x: dict[str, NDArray[np.float64]], offset: int, refr: int,
                out: list[Result]) -> None:
        """Alarm results at the upward threshold crossings of ``sc`` (refractory kept)."""
        above = sc > self.threshold
        was = np.concatenate([[self._above], above[:-1]])
        for j in np.flatnonzero(above & ~was).tolist():
            c = int(cycles[j])
            if self._last_alarm is None or c - self._last_alarm >= refr:
                self._last_alarm = c
                self._alarm(c, float(sc[j]), {k: float(v[offset + j]) for k, v in x.items()},
                            out)
        self._above = bool(above[-1])

    def _alarm(self, c: int, score: float, x: dict[str, float], out: list[Result]) -> None:
        self.alarms += 1
        out.append(Result("alarm", c, {"detector": type(self.detector).__name__,
                                       "cycle": c, "score": score,
                                       "threshold": self.threshold,
                                       "current_a": x.get("current_a"),
                                       "hole": int(x["hole"]) if "hole" in x else None,
                                       "units": {"current_a": "A", "score": "-"}}))

    def _one(self, c: int, x: dict[str, float], learn_until: int, refr: int,
             out: list[Result]) -> float:
        """Learn or score one cycle; an alarm result into ``out``; the score (NaN: learned)."""
        if self.learn_holes is not None:
            if not self._taught and x.get("hole", -1.0) >= self.learn_holes:
                self._taught = True
            learning = not self._taught
        else:
            learning = c < learn_until
        if learning:
            self.detector.learn_one(x)
            self.learned += 1
            return math.nan
        sc = self.detector.score_one(x)
        self.scored += 1
        above = sc > self.threshold
        if above and not self._above and (self._last_alarm is None
                                          or c - self._last_alarm >= refr):
            self._last_alarm = c
            self._alarm(c, float(sc), x, out)
        self._above = bool(above)
        return float(sc)

    def _release(self) -> list[Result]:
        out: list[Result] = []
        if self._held is not None and self._start is not None:
            c0, x0 = self._held
            self._held = None
            x0["torque_nm"] = math.nan
            self._one(c0, x0, self._start + round(self.learn_s / self._ct),
                      round(self.refractory_s / self._ct), out)
        return out

    def gap(self, gap: CounterGap) -> list[Result]:
        out = self._release()
        self._above = False
        self._rapid = RapidAir(settle_s=self._rapid.settle_s)  # the NC state of the gap: unknown
        return out

    def finish(self) -> list[Result]:
        return self._release()


class TwinCompareProcessor:
    """The machine against its calibrated twin, window by window (``twin`` results).

    Buffers the stream and runs :func:`cnctwin.compare.compare_recording` (the same
    comparison as ``cnctwin twin compare``) on each window of ``window_s`` in which an axis of
    the machine file moves; a counter gap ends the window (the twin is restarted from the
    measured position after it, never bridged). Each result carries the window's cycle range
    (``first_cycle``, ``n``) and, per axis, the residual ratio, ``flagged`` and the reasons.

    Parameters
    ----------
    machine_file : MachineFile
        The calibrated machine (``cnctwin calibrate``).
    window_s : float, default 30
        Window length [s].
    parameters : bool, default True
        Also check Kv and friction against the file's (one loop identification per axis and
        window).
    n_bootstrap : int, default 30
        Bootstrap resamples of that check.
    """

    name = "twin"
    needs = None  # compares every axis and the spindle with the twin: every column

    def __init__(self, machine_file: MachineFile, *, window_s: float = 30.0,
                 parameters: bool = True, n_bootstrap: int = 30) -> None:
        if not window_s > 1.0:
            raise ConfigError(f"window_s must be > 1 s, got {window_s}")
        self.machine_file = machine_file
        self.window_s = window_s
        self.parameters = parameters
        self.n_bootstrap = n_bootstrap
        self.windows = 0
        self.issues: list[str] = []
        self._parts: list[Chunk] = []
        self._n = 0
        self._dt = machine_file.machine.cycle_time_s

    def _window(self) -> list[Result]:
        from cnctwin.compare import compare_recording

        parts, self._parts, self._n = self._parts, [], 0
        if not parts:
            return []
        cyc = np.concatenate([q.cycles for q in parts])
        cols = sorted({c for q in parts for c in q.signals})
        data = {c: np.concatenate([q.signals.get(c, np.full(len(q), np.nan)) for q in parts])
                for c in cols}
        hf = pd.DataFrame(data, index=pd.Index(cyc, name="cycle"))
        hf.insert(0, "time", pd.to_datetime(np.concatenate([q.time_ns for q in parts]),
                                            unit="ns", utc=True))
        rec = Recording(hf, meta=RecordingMeta(machine=parts[0].machine,
                                               cycle_time_s=parts[0].cycle_time_s,
                                               source_format="edge"))
        cmp = compare_recording(rec, self.machine_file, parameters=self.parameters,
                                n_bootstrap=self.n_bootstrap)
        if not cmp.axes:
            return []
        self.windows += 1
        doc = cmp.to_dict()
        for a in doc["axes"].values():
            a.pop("spans", None)
        return [Result("twin", int(cyc[0]), {
            "first_cycle": int(cyc[0]), "n": int(cyc.size), "axes": doc["axes"],
            "spindle": doc["spindle"], "flagged": doc["flagged"], "skipped": doc["skipped"]})]

    def process(self, chunk: Chunk) -> list[Result]:
        self._parts.append(chunk)
        self._n += len(chunk)
        self._dt = chunk.cycle_time_s
        if self._n * self._dt >= self.window_s:
            return self._window()
        return []

    def gap(self, gap: CounterGap) -> list[Result]:
        return self._window()

    def finish(self) -> list[Result]:
        return self._window() if self._n * self._dt >= 1.0 else []
