"""Processors of the edge runtime: cutting torque, per-hole events, anomaly detectors.

Each processor wraps an existing analysis instead of re-implementing it:

* :class:`TorqueProcessor`: :class:`cnctwin.spindle.StreamingTorqueEstimator` (identical to
  :meth:`SpindleModel.cutting_torque` on each contiguous run of cycles).
* :class:`HoleProcessor`: :func:`cnctwin.usecases.holes.hole_record` run incrementally on a
  bounded buffer that starts after the previous hole.
* :class:`AnomalyProcessor`: any detector of :mod:`cnctwin.usecases.anomaly` (learn one / score
  one), taught on the first ``learn_s`` of the stream, then scoring.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from cnctwin.edge.pipeline import Chunk, Result
from cnctwin.exceptions import ConfigError
from cnctwin.recording import CounterGap, Recording, RecordingMeta, empty_events
from cnctwin.spindle import SpindleModel, StreamingTorqueEstimator
from cnctwin.usecases.anomaly import Detector, PhysicsResidualDetector
from cnctwin.usecases.holes import HOLE_COLUMNS

__all__ = ["AnomalyProcessor", "HoleProcessor", "TorqueProcessor"]


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

    Notes
    -----
    At a gap the estimator is flushed and restarted, so the derivative is never taken across
    missing cycles; on each contiguous run the result equals the batch
    :meth:`~cnctwin.spindle.SpindleModel.cutting_torque` of that run exactly.
    Each ``torque`` result holds ``first_cycle``, ``n`` and the arrays ``torque_nm``,
    ``speed_rpm``, ``current_a`` for consecutive cycles.
    """

    name = "torque"

    def __init__(self, model: SpindleModel, *, spindle: str = "SP1",
                 accel_term: bool = True) -> None:
        self.model = model
        self.spindle = spindle
        self.i_col = f"CURRENT|{spindle}"
        self.n_col = f"CMD_SPEED|{spindle}"
        self.column = f"CUT_TORQUE|{spindle}"
        self._fs: float | None = None
        self.accel_term = accel_term
        self._est: StreamingTorqueEstimator | None = None
        self._pending: deque[tuple[int, float, float]] = deque()  # (cycle, i, n) held back
        self.samples = 0

    def _estimator(self, chunk: Chunk) -> StreamingTorqueEstimator:
        if self._est is None:
            self._fs = 1.0 / chunk.cycle_time_s
            self._est = StreamingTorqueEstimator(self.model, fs_hz=self._fs,
                                                 accel_term=self.accel_term)
        return self._est

    def _result(self, cycles: list[int], tau: NDArray[np.float64], i: list[float],
                n: list[float]) -> Result:
        return Result("torque", cycles[0], {
            "spindle": self.spindle, "first_cycle": cycles[0], "n": len(cycles),
            "torque_nm": tau.tolist(), "speed_rpm": n, "current_a": i,
            "units": {"torque_nm": "Nm", "speed_rpm": "rpm", "current_a": "A"}})

    def process(self, chunk: Chunk) -> list[Result]:
        if self.i_col not in chunk.signals or self.n_col not in chunk.signals:
            raise ConfigError(f"the torque processor needs {self.i_col!r} and {self.n_col!r}; "
                              f"the stream has {sorted(chunk.signals)}")
        est = self._estimator(chunk)
        i = chunk.signals[self.i_col]
        n = chunk.signals[self.n_col]
        tau = est.update(i, n)
        self.samples += tau.size
        held = list(self._pending)
        cyc = [c for c, _, _ in held] + chunk.cycles.tolist()
        ii = [a for _, a, _ in held] + i.tolist()
        nn = [b for _, _, b in held] + n.tolist()
        k = tau.size
        self._pending = deque(zip(cyc[k:], ii[k:], nn[k:], strict=True))
        derived = np.full(len(chunk), np.nan)
        # estimates for this chunk's own cycles (the held-back one of the last chunk came out)
        off = len(held)
        own = tau[off:] if k > off else np.empty(0)
        derived[:own.size] = own
        chunk.derived[self.column] = derived
        return [self._result(cyc[:k], tau, ii[:k], nn[:k])] if k else []

    def _flush(self) -> list[Result]:
        if self._est is None:
            return []
        tau = self._est.flush()
        held = list(self._pending)
        self._pending.clear()
        self.samples += tau.size
        if not tau.size or not held:
            return []
        return [self._result([c for c, _, _ in held], tau, [a for _, a, _ in held],
                             [b for _, _, b in held])]

    def gap(self, gap: CounterGap) -> list[Result]:
        return self._flush()

    def finish(self) -> list[Result]:
        return self._flush()


class HoleProcessor:
    """Per-hole record, incremental: ``hole_start`` when a plunge begins, ``hole`` when done.

    The HF columns a hole row needs are kept in a buffer that starts where the previous hole
    ended (the tool back above the surface). Each time the Z axis has moved up since the last
    check, :func:`~cnctwin.usecases.holes.hole_record` runs on the buffer; a hole is emitted
    once it is complete: the tool is out of the material and the X/Y setpoint has left the
    hole's position (next hole), or the tool has been out for ``settle_s`` (peck drilling: the
    next peck re-enters at the same X/Y within that time), or a later hole follows it. Rows
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
    """

    name = "holes"

    def __init__(self, model: SpindleModel | None = None, *, spindle: str = "SP1",
                 z_axis: str = "Z1", xy_axes: tuple[str, str] = ("X1", "Y1"),
                 window_s: float = 0.6, set_size: int = 6, settle_s: float = 1.0,
                 max_buffer_s: float = 300.0, min_speed_mm_s: float = 0.05) -> None:
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
        self._events: pd.DataFrame = empty_events()
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
        keep = {c: v for c, v in chunk.signals.items() if c in self.columns}
        self._parts.append(Chunk(chunk.cycles, chunk.time_ns, keep,
                                 cycle_time_s=chunk.cycle_time_s, machine=chunk.machine))
        self._n += len(chunk)
        if not chunk.events.empty:
            self._events = pd.concat([self._events, chunk.events], ignore_index=True) \
                if not self._events.empty else chunk.events.copy()
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
        down = dz < -step
        up = dz > step
        for j in np.flatnonzero(down | up).tolist() if dz.size else []:
            if down[j]:
                self._down_run += 1
                self._up_run = 0
                if not self._in_plunge and self._down_run >= 5:
                    self._in_plunge = True
                    c = int(chunk.cycles[j if has_prev else j + 1])
                    self.plunges += 1
                    out.append(Result("hole_start", c, {"holes_done": self.holes, "cycle": c,
                                                         "z_mm": float(zz[j + 1]),
                                                         "units": {"z_mm": "mm"}}))
            else:
                self._up_run += 1
                self._down_run = 0
                if self._up_run >= 5:
                    self._in_plunge = False
        if self._moved_up:
            self._pending = None
            out += self._evaluate(final=False)
        self._trim()
        return out

    def _buffer(self) -> Recording:
        cols = sorted({c for p in self._parts for c in p.signals})
        cyc = np.concatenate([p.cycles for p in self._parts])
        t = np.concatenate([p.time_ns for p in self._parts])
        data = {c: np.concatenate([p.signals.get(c, np.full(len(p), np.nan))
                                   for p in self._parts]) for c in cols}
        hf = pd.DataFrame(data, index=pd.Index(cyc, name="cycle"))
        hf.insert(0, "time", pd.to_datetime(t, unit="ns", utc=True))
        meta = RecordingMeta(machine=self._parts[0].machine, cycle_time_s=self._cycle_time_s,
                             source_format="edge")
        ev = self._events[self._events["cycle"] <= int(cyc[-1])] if not self._events.empty \
            else self._events
        return Recording(hf, events=ev, meta=meta)

    def _evaluate(self, *, final: bool) -> list[Result]:
        from cnctwin.usecases.holes import hole_record

        self._moved_up = False
        if not self._parts:
            return []
        rec = self._buffer()
        origin = pd.Timestamp(int(self._origin_ns or 0), unit="ns", tz="UTC")
        rows = hole_record(rec, spindle=self.spindle, z_axis=self.z_axis,
                           xy_axes=self.xy_axes, model=self.model, window_s=self.window_s,
                           set_size=self.set_size, first_hole=self.holes,
                           time_origin=origin, store=False)
        if rows.empty:
            return []
        last_cycle = int(rec.cycles[-1])
        out: list[Result] = []
        cut_at: int | None = None
        for k in range(len(rows)):
            row = rows.iloc[k]
            ext_cycle = int(row["end_cycle"]) + round(
                (float(row["extraction_s"]) - float(row["end_s"])) / self._cycle_time_s)
            done = final or k < len(rows) - 1 or (ext_cycle < last_cycle and (
                (last_cycle - ext_cycle) * self._cycle_time_s >= self.settle_s
                or self._moved_away(rec, ext_cycle, row)))
            if not done:  # look again when X/Y moves or after settle_s
                self._pending = last_cycle + round(self.settle_s / self._cycle_time_s)
                break
            out.append(Result("hole", int(row["end_cycle"]),
                              {"hole": int(row["hole"]), "row": _row_payload(row),
                               "units": HOLE_UNITS}))
            self.holes += 1
            cut_at = ext_cycle
        for msg in rows.attrs.get("issues", []):
            # the event count covers the modal history kept before the buffer: not a finding
            if "drilling-cycle calls" not in msg and msg not in self.issues:
                self.issues.append(msg)
        if cut_at is not None and not final:
            self._drop_before(cut_at)
        return out

    def _xy_moved(self, chunk: Chunk) -> bool:
        for axis in self.xy_axes:
            v = chunk.signals.get(f"DES_POS|{axis}")
            if v is not None and v.size and float(np.nanmax(v) - np.nanmin(v)) > 0.01:
                return True
        return False

    def _moved_away(self, rec: Recording, cycle: int, row: pd.Series) -> bool:
        """The X/Y setpoint left the hole's position after the tool came out (next hole)."""
        i0 = int(np.searchsorted(rec.cycles, cycle))
        for axis, key in zip(self.xy_axes, ("x_mm", "y_mm"), strict=True):
            col = f"DES_POS|{axis}"
            ref = float(row[key])
            if rec.has(col) and math.isfinite(ref):
                v = rec.hf[col].to_numpy(dtype=np.float64)[i0:]
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
        if len(self._events) > 10_000:
            self._events = self._events.iloc[-5_000:]

    def gap(self, gap: CounterGap) -> list[Result]:
        return []  # hole_record works on the cycle base; a gap inside a hole stays visible

    def finish(self) -> list[Result]:
        return self._evaluate(final=True)


HOLE_UNITS: dict[str, str] = {
    k: v.rsplit("[", 1)[1].rstrip("]") for k, v in HOLE_COLUMNS.items() if v.endswith("]")
}
"""Units of the hole-row fields (from :data:`cnctwin.usecases.holes.HOLE_COLUMNS`)."""


def _row_payload(row: pd.Series) -> dict[str, Any]:
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
    torque), ``z_error_mm`` (DES_POS - ENC_POS of Z), ``progress`` (NaN) and ``hole`` (-1),
    plus ``torque_nm`` when the torque processor ran before.

    Parameters
    ----------
    detector : Detector, optional
        Default :class:`~cnctwin.usecases.anomaly.PhysicsResidualDetector` (current against
        the twin's prediction).
    model : SpindleModel, optional
        Twin for ``predicted_current_a`` (default the thesis parameter set).
    learn_s : float, default 10
        The first seconds of the stream are learned (teach-in on good data) [s].
    threshold : float, default 0
        Score above which an alarm is raised.
    refractory_s : float, default 1
        Crossings within this time after an alarm are not new alarms [s].
    """

    def __init__(self, detector: Detector | None = None, *, model: SpindleModel | None = None,
                 spindle: str = "SP1", z_axis: str = "Z1", learn_s: float = 10.0,
                 threshold: float = 0.0, refractory_s: float = 1.0) -> None:
        self.detector = detector if detector is not None else PhysicsResidualDetector()
        self.name = f"anomaly:{type(self.detector).__name__}"
        self.model = model if model is not None else SpindleModel.from_parameters(
            "thesis_spinner_840dsl")
        self.spindle, self.z_axis = spindle, z_axis
        self.learn_s, self.threshold, self.refractory_s = learn_s, threshold, refractory_s
        self.learned = 0
        self.scored = 0
        self.alarms = 0
        self._start: int | None = None
        self._above = False
        self._last_alarm: int | None = None

    def process(self, chunk: Chunk) -> list[Result]:
        s = chunk.signals
        i = s.get(f"CURRENT|{self.spindle}")
        n = s.get(f"CMD_SPEED|{self.spindle}")
        if i is None or n is None:
            raise ConfigError(f"the anomaly processor needs CURRENT|{self.spindle} and "
                              f"CMD_SPEED|{self.spindle}")
        des, enc = s.get(f"DES_POS|{self.z_axis}"), s.get(f"ENC_POS|{self.z_axis}")
        zerr = des - enc if des is not None and enc is not None else np.zeros(len(chunk))
        pred = self.model.predict_current_a(0.0, n)
        tq = chunk.derived.get(f"CUT_TORQUE|{self.spindle}")
        cols: dict[str, NDArray[np.float64]] = {
            "current_a": i, "speed_rpm": n, "predicted_current_a": pred, "z_error_mm": zerr,
            "progress": np.full(len(chunk), np.nan), "hole": np.full(len(chunk), -1.0)}
        if tq is not None:
            cols["torque_nm"] = tq
        missing = [k for k in self.detector.inputs if k not in cols]
        if missing:
            raise ConfigError(f"{self.name} needs inputs {missing} the edge stream lacks")
        if self._start is None:
            self._start = chunk.first_cycle
        learn_until = self._start + round(self.learn_s / chunk.cycle_time_s)
        keys = list(self.detector.inputs)
        arrs = [cols[k].tolist() for k in keys]
        cyc = chunk.cycles.tolist()
        scores = np.full(len(chunk), np.nan)
        out: list[Result] = []
        refr = round(self.refractory_s / chunk.cycle_time_s)
        for j, c in enumerate(cyc):
            x = {k: a[j] for k, a in zip(keys, arrs, strict=True)}
            if c < learn_until:
                self.detector.learn_one(x)
                self.learned += 1
                continue
            sc = self.detector.score_one(x)
            self.scored += 1
            scores[j] = sc
            above = sc > self.threshold
            if above and not self._above and (self._last_alarm is None
                                              or c - self._last_alarm >= refr):
                self._last_alarm = c
                self.alarms += 1
                out.append(Result("alarm", c, {"detector": type(self.detector).__name__,
                                               "cycle": c, "score": float(sc),
                                               "threshold": self.threshold,
                                               "current_a": x.get("current_a"),
                                               "units": {"current_a": "A", "score": "-"}}))
            self._above = bool(above)
        chunk.derived[f"ANOMALY_SCORE|{self.spindle}"] = scores
        return out

    def gap(self, gap: CounterGap) -> list[Result]:
        self._above = False
        return []

    def finish(self) -> list[Result]:
        return []
