"""Shared helpers of :mod:`cnctwin.servo`: signal access, gaps, units, quantization, filters.

Everything here works on a :class:`~cnctwin.recording.Recording` only (never on simulator
internals), so the analyses run unchanged on real files.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import signal as sps

from cnctwin.recording import Recording
from cnctwin.signals import axis_kind

__all__ = [
    "AxisData",
    "VelocityUnit",
    "axis_data",
    "best_lag",
    "delay",
    "derivative",
    "detect_velocity_unit",
    "jerk_filter_average",
    "moving_axes",
    "pt1",
    "pt2",
    "quantum",
    "segments",
]

FloatArray = NDArray[np.float64]

# factors from a declared velocity unit to position units per second
_UNIT_TO_PER_S: dict[str, float] = {
    "mm/s": 1.0,
    "mm/min": 1.0 / 60.0,
    "m/min": 1000.0 / 60.0,
    "deg/s": 1.0,
    "deg/min": 1.0 / 60.0,
    "rpm": 6.0,
    "1/min": 6.0,
}


def informative_segments(
    x: FloatArray, segs: list[slice], *, pad: int = 120, warm: int = 60,
    max_samples: int = 3000,
) -> tuple[list[slice], NDArray[np.bool_]]:
    """Windows around the changes of the velocity of ``x`` (where filters reveal themselves).

    Constant-velocity stretches carry no information on filter shapes, only cost time. Each
    window starts ``warm + pad`` cycles before a change so the filters have settled; the
    returned mask excludes the first ``warm`` cycles of each window. When the windows hold more
    than ``max_samples`` cycles, an evenly spread subset of them is kept (0 keeps all).

    Returns
    -------
    windows : list of slice
        Sub-runs of ``segs``.
    mask : numpy.ndarray of bool
        Samples to use in a cost function.
    """
    n = x.size
    keep = np.zeros(n, dtype=bool)
    for s in segs:
        xs = x[s]
        if xs.size < 4:
            continue
        acc = np.abs(np.diff(xs, 2))
        thr = 1e-6 * max(float(np.max(acc)), 1e-300)
        idx = np.flatnonzero(acc > thr) + 1
        if idx.size == 0:
            continue
        local = np.zeros(xs.size, dtype=bool)
        lo = np.clip(idx - pad - warm, 0, xs.size)
        hi = np.clip(idx + pad, 0, xs.size)
        diff = np.zeros(xs.size + 1, dtype=np.int64)
        np.add.at(diff, lo, 1)
        np.add.at(diff, hi, -1)
        local = np.cumsum(diff[:-1]) > 0
        keep[s] = local
    windows = [slice(w.start, w.stop) for w in segments_of_mask(keep)]
    total = sum(w.stop - w.start for w in windows)
    if max_samples and total > max_samples and len(windows) > 1:
        # parameters are constant: a spread-out subset of the windows is enough
        step = total / max_samples
        keep_idx = sorted({min(int(i * step), len(windows) - 1)
                           for i in range(int(len(windows) / step) + 1)})
        windows = [windows[i] for i in keep_idx]
    mask = np.zeros(n, dtype=bool)
    for w in windows:
        mask[w.start + warm : w.stop] = True
    return windows, mask


def segments_of_mask(mask: NDArray[np.bool_]) -> list[slice]:
    """Runs of True in a boolean mask."""
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    starts = np.flatnonzero(d == 1)
    stops = np.flatnonzero(d == -1)
    return [slice(int(a), int(b)) for a, b in zip(starts, stops, strict=True)]


def segments(cycles: NDArray[np.int64]) -> list[slice]:
    """Contiguous runs of the cycle counter (no gap inside a run).

    Parameters
    ----------
    cycles : numpy.ndarray of int64
        Unwrapped, sorted cycle counter.

    Returns
    -------
    list of slice
        One slice per run, in order.
    """
    c = np.asarray(cycles, dtype=np.int64)
    if c.size == 0:
        return []
    cut = np.flatnonzero(np.diff(c) != 1) + 1
    bounds = [0, *cut.tolist(), int(c.size)]
    return [slice(bounds[i], bounds[i + 1]) for i in range(len(bounds) - 1)]


def quantum(x: FloatArray) -> float:
    """Estimated quantization step of a recorded signal (0 for unquantized data).

    The smallest difference between distinct values that is not float round-off; the 1st
    percentile of the positive gaps is used so a single round-off pair does not decide.

    Parameters
    ----------
    x : numpy.ndarray
        Samples.

    Returns
    -------
    float
        Step in the unit of ``x``.
    """
    v = np.unique(x[np.isfinite(x)])
    if v.size < 3:
        return 0.0
    d = np.diff(v)
    scale = max(1.0, float(np.max(np.abs(v))))
    d = d[d > 1e-12 * scale]
    if d.size == 0:
        return 0.0
    q = float(np.percentile(d, 1.0))
    if q <= 1e-9 * scale:
        return 0.0
    # a grid only if (nearly) all gaps are integer multiples of q
    ratio = d / q
    on_grid = np.abs(ratio - np.round(ratio)) < 0.05 + 1e-6 * ratio
    return q if float(np.mean(on_grid)) >= 0.9 else 0.0


def derivative(
    x: FloatArray, segs: list[slice], dt_s: float, *, kind: str = "central"
) -> FloatArray:
    """Derivative per contiguous segment; NaN where a neighbour is missing [unit/s].

    ``kind='backward'`` gives ``(x[k]-x[k-1])/dt`` (the mean velocity of cycle k-1..k, i.e.
    half a cycle late); ``'central'`` gives ``(x[k+1]-x[k-1])/(2 dt)``.
    """
    out = np.full(x.shape, np.nan)
    for s in segs:
        xs = x[s]
        if xs.size < 3:
            continue
        if kind == "backward":
            out[s][1:] = np.diff(xs) / dt_s
        else:
            seg_out = np.full(xs.shape, np.nan)
            seg_out[1:-1] = (xs[2:] - xs[:-2]) / (2.0 * dt_s)
            out[s] = seg_out
    return out


@dataclass
class AxisData:
    """The HF signals of one axis as float arrays on the recording's cycle grid.

    Attributes
    ----------
    axis : str
        Axis name.
    cycle_time_s : float
        Position-control cycle [s].
    segments : list of slice
        Contiguous runs of the counter (filters and derivatives restart at each gap).
    signals : dict
        Catalog code -> samples (positions in mm or deg, velocities as recorded).
    units : dict
        Catalog code -> unit as declared in ``rec.meta.units``.
    kind : {'linear', 'rotary', 'spindle'}
        Axis kind from the name.
    """

    axis: str
    cycle_time_s: float
    segments: list[slice]
    signals: dict[str, FloatArray]
    units: dict[str, str]
    kind: str

    def has(self, code: str) -> bool:
        """Whether the signal is present and not all NaN."""
        x = self.signals.get(code)
        return x is not None and bool(np.isfinite(x).any())

    def __len__(self) -> int:
        return len(next(iter(self.signals.values()))) if self.signals else 0


def axis_data(rec: Recording, axis: str) -> AxisData:
    """Collect the HF signals of ``axis`` (and derived ``CTRL_DIFF2`` when possible).

    Parameters
    ----------
    rec : Recording
        Any recording.
    axis : str
        Axis name (``"X1"``).

    Returns
    -------
    AxisData
    """
    sigs: dict[str, FloatArray] = {}
    units: dict[str, str] = {}
    for col in rec.columns:
        if "|" not in col:
            continue
        code, ax = col.split("|", 1)
        if ax != axis:
            continue
        sigs[code] = rec.hf[col].to_numpy(dtype=np.float64)
        units[code] = rec.meta.units.get(col, "")
    if "ENC_POS" not in sigs:
        # no active-encoder position: take the measuring system the setpoint refers to (the
        # one closer to DES_POS), e.g. measPos2 for a trace of the 2nd-encoder setpoint
        alts = [c for c in ("ENC1_POS", "ENC2_POS") if c in sigs]
        if alts:
            if "DES_POS" in sigs and len(alts) > 1:
                alts.sort(key=lambda c: float(np.nanmean((sigs["DES_POS"] - sigs[c]) ** 2)))
            sigs["ENC_POS"] = sigs[alts[0]]
            units["ENC_POS"] = units[alts[0]]
            units["ENC_SOURCE"] = alts[0]
    kind = axis_kind(axis)
    if kind == "linear" and units.get("DES_POS") == "deg":
        kind = "rotary"  # the reader knew better than the name (servo trace 'AX7')
    return AxisData(
        axis=axis,
        cycle_time_s=rec.meta.cycle_time_s,
        segments=segments(rec.cycles),
        signals=sigs,
        units=units,
        kind=kind,
    )


@dataclass(frozen=True)
class VelocityUnit:
    """How a recorded velocity signal converts to position units per second.

    Attributes
    ----------
    declared : str
        Unit declared by the recording (``rec.meta.units``).
    factor : float
        Multiply the recorded value by this to get position units per second.
    detected : str
        Unit that the data support (``"mm/s"``, ``"mm/min"``, ...); equals ``declared`` when
        the data do not decide.
    ratio : float
        Least-squares ratio recorded / reference velocity (reference in unit/s).
    lag_cycles : int
        Lag of the recorded signal behind the reference [cycles].
    decided_by_data : bool
        Whether ``detected`` came from the data.
    """

    declared: str
    factor: float
    detected: str
    ratio: float
    lag_cycles: int
    decided_by_data: bool


def best_lag(x: FloatArray, ref: FloatArray, *, max_lag: int = 10) -> tuple[int, float]:
    """Integer lag (x behind ref) maximising the least-squares fit ``x[k] ~ r ref[k-lag]``.

    Returns
    -------
    lag : int
        Cycles; positive when ``x`` lags ``ref``.
    ratio : float
        Least-squares ratio at that lag.
    """
    best = (0, 0.0, math.inf)
    n = x.size
    for lag in range(-max_lag, max_lag + 1):
        if lag >= 0:
            a, b = x[lag:], ref[: n - lag]
        else:
            a, b = x[: n + lag], ref[-lag:]
        m = np.isfinite(a) & np.isfinite(b)
        if m.sum() < 10:
            continue
        aa, bb = a[m], b[m]
        den = float(bb @ bb)
        if den <= 0:
            continue
        r = float(aa @ bb) / den
        sse = float(np.sum((aa - r * bb) ** 2))
        if sse < best[2]:
            best = (lag, r, sse)
    return best[0], best[1]


def _unit_family(axis_kind_: str) -> tuple[str, str, str]:
    if axis_kind_ == "linear":
        return ("mm/s", "mm/min", "m/min")
    return ("deg/s", "deg/min", "rpm")


def detect_velocity_unit(
    recorded: FloatArray, reference_per_s: FloatArray, *, declared: str, kind: str
) -> VelocityUnit:
    """Find the unit of a recorded velocity from a reference velocity in unit/s.

    The candidate units of the axis kind are tried (mm/s, mm/min, m/min; deg/s, deg/min, rpm);
    the one whose converted ratio to the reference is closest to 1 (in log) is taken when that
    ratio lies in [0.3, 1.5] (a feedforward weight below 0.3 or a reference that does not move
    leaves the declared unit).

    Parameters
    ----------
    recorded : numpy.ndarray
        The recorded velocity (VEL_FFW, CMD_SPEED) in its own unit.
    reference_per_s : numpy.ndarray
        Reference velocity in position units per second (d(DES_POS)/dt).
    declared : str
        Declared unit.
    kind : str
        Axis kind.
    """
    lag, ratio = best_lag(recorded, reference_per_s)
    declared_factor = _UNIT_TO_PER_S.get(declared, 1.0)
    best_unit, best_dist = declared, math.inf
    if ratio != 0 and np.isfinite(ratio):
        for u in _unit_family(kind):
            conv = ratio * _UNIT_TO_PER_S[u]
            if conv <= 0:
                continue
            dist = abs(math.log(conv))
            if dist < best_dist:
                best_unit, best_dist = u, dist
    conv_best = ratio * _UNIT_TO_PER_S.get(best_unit, 1.0)
    decided = bool(0.3 <= conv_best <= 1.5)
    unit_ = best_unit if decided else declared
    factor = _UNIT_TO_PER_S.get(unit_, declared_factor)
    return VelocityUnit(declared, factor, unit_, ratio, lag, decided)


# ---------------------------------------------------------------------------- filters
def jerk_filter_average(x: FloatArray, window: float) -> FloatArray:
    """The control's jerk filter of type 2 (MD32402 = 2): a causal mean over ``window``
    samples, fractional windows allowed.

    A model of the drive's setpoint filter, not a trend smoother (that is
    :func:`cnctwin.usecases.wear.moving_average`, NaN-aware and centered).

    ``y[k] = (sum_{j=0}^{m-1} x[k-j] + f x[k-m]) / W`` with ``m = floor(W)``, ``f = W - m``:
    the mean of the last ``W`` samples for integer ``W`` (MD32402 type 2 with
    MD32410 = W cycles), continuous in ``W`` in between. Group delay about ``(W - 1) / 2``
    cycles. The signal is taken constant before its first sample.

    Parameters
    ----------
    x : numpy.ndarray
        Samples.
    window : float
        Window length [cycles]; at or below 1 returns ``x``.
    """
    if window <= 1.0 + 1e-9:
        return x.copy()
    m = math.floor(window)
    f = window - m
    pad = m + 2
    xp = np.concatenate([np.full(pad, x[0]), x])
    cs = np.concatenate([[0.0], np.cumsum(xp)])
    k = np.arange(pad, xp.size)
    s = cs[k + 1] - cs[k + 1 - m] + f * xp[k - m]
    return np.asarray(s / window, dtype=np.float64)


def delay(x: FloatArray, cycles: float) -> FloatArray:
    """Delay by a real number of cycles with linear interpolation (constant before start)."""
    if abs(cycles) < 1e-9:
        return x.copy()
    n = x.size
    t = np.arange(n, dtype=np.float64) - cycles
    return np.interp(t, np.arange(n, dtype=np.float64), x, left=x[0], right=x[-1])


def pt1(x: FloatArray, time_cycles: float) -> FloatArray:
    """First-order lag, backward Euler: ``y[k] = y[k-1] + (x[k] - y[k-1]) / (T + 1)``.

    The steady ramp lag is exactly ``T`` cycles (the NC's PT1 filters are of this kind, so ``T``
    is the equivalent time); starts in steady state at ``x[0]``.

    Parameters
    ----------
    x : numpy.ndarray
        Samples.
    time_cycles : float
        Time constant T [cycles].
    """
    if time_cycles < 1e-9:
        return x.copy()
    p = time_cycles / (time_cycles + 1.0)
    y, _ = sps.lfilter([1.0 - p], [1.0, -p], x, zi=[p * x[0]])
    return np.asarray(y, dtype=np.float64)


def pt2(x: FloatArray, time_cycles: float, damping: float) -> FloatArray:
    """Second-order low-pass ``1/(T^2 s^2 + 2 D T s + 1)``, bilinear discretization.

    Parameters
    ----------
    x : numpy.ndarray
        Samples.
    time_cycles : float
        Time constant T [cycles].
    damping : float
        Damping D [-].
    """
    if time_cycles < 1e-3:
        return x.copy()
    # bilinear transform s = 2 (z - 1) / (z + 1) written out (scipy.signal.bilinear is slow)
    k2 = (2.0 * time_cycles) ** 2
    dk = 4.0 * damping * time_cycles
    a0 = k2 + dk + 1.0
    b = np.array([1.0, 2.0, 1.0]) / a0
    a = np.array([1.0, (2.0 - 2.0 * k2) / a0, (k2 - dk + 1.0) / a0])
    z1 = (b[2] - a[2]) * x[0]
    zi = np.array([(b[1] - a[1]) * x[0] + z1, z1])
    y, _ = sps.lfilter(b, a, x, zi=zi)
    return np.asarray(y, dtype=np.float64)


def moving_axes(rec: Recording, *, min_travel: float = 0.05) -> list[str]:
    """Axes whose DES_POS and actual position are recorded and whose setpoint moves.

    The actual position is ``ENC_POS`` or, in a servo trace, ``ENC1_POS`` / ``ENC2_POS``.

    Parameters
    ----------
    rec : Recording
        A recording (trace or edge recording).
    min_travel : float, default 0.05
        Smallest setpoint travel that counts as moving [mm or deg].

    Returns
    -------
    list of str
        Axis names, in the recording's column order.
    """
    out = []
    for ax in rec.axes:
        has_enc = any(rec.has(code, ax) for code in ("ENC_POS", "ENC1_POS", "ENC2_POS"))
        if not (rec.has("DES_POS", ax) and has_enc):
            continue
        v = rec.signal("DES_POS", ax).to_numpy(dtype=np.float64)
        v = v[np.isfinite(v)]
        if v.size and float(np.ptp(v)) >= min_travel:
            out.append(ax)
    return out


# ------------------------------------------------------------- setpoint chain, compiled
JERK_CODES: dict[str, int] = {"none": 0, "moving_average": 1, "double_moving_average": 2,
                              "pt2": 3}
"""Jerk-filter model -> its code in :func:`setpoint_chain_segments`."""


def _ma_py(x: FloatArray, window: float, out: FloatArray) -> None:  # pragma: no cover
    """:func:`jerk_filter_average` into ``out`` (the same operations in the same order)."""
    n = x.size
    if window <= 1.0 + 1e-9:
        out[:] = x
        return
    m = math.floor(window)
    f = window - m
    pad = m + 2
    cs = np.empty(n + pad + 1)
    cs[0] = 0.0
    acc = 0.0
    for i in range(n + pad):
        acc += x[0] if i < pad else x[i - pad]
        cs[i + 1] = acc
    for i in range(n):
        k = pad + i
        xm = x[0] if k - m < pad else x[k - m - pad]
        out[i] = (cs[k + 1] - cs[k + 1 - m] + f * xm) / window


def _delay_py(x: FloatArray, cycles: float, out: FloatArray) -> None:  # pragma: no cover
    """:func:`delay` into ``out`` (numpy.interp's formula: slope (t - j) + x[j])."""
    n = x.size
    if abs(cycles) < 1e-9:
        out[:] = x
        return
    for k in range(n):
        t = float(k) - cycles
        if t < 0.0:
            out[k] = x[0]
        elif t >= n - 1:
            out[k] = x[n - 1]
        else:
            j = math.floor(t)
            if t == float(j):
                out[k] = x[j]
            else:
                out[k] = (x[j + 1] - x[j]) * (t - j) + x[j]


def _pt1_py(x: FloatArray, time_cycles: float, out: FloatArray) -> None:  # pragma: no cover
    """:func:`pt1` into ``out`` (scipy.signal.lfilter's transposed direct form II)."""
    n = x.size
    if time_cycles < 1e-9:
        out[:] = x
        return
    p = time_cycles / (time_cycles + 1.0)
    b0 = 1.0 - p
    z = p * x[0]
    for k in range(n):
        y = z + b0 * x[k]
        out[k] = y
        z = x[k] * 0.0 - y * -p


def _pt2_py(x: FloatArray, time_cycles: float, damping: float,
            out: FloatArray) -> None:  # pragma: no cover
    """:func:`pt2` into ``out`` (scipy.signal.lfilter's transposed direct form II)."""
    n = x.size
    if time_cycles < 1e-3:
        out[:] = x
        return
    k2 = (2.0 * time_cycles) ** 2
    dk = 4.0 * damping * time_cycles
    a0 = k2 + dk + 1.0
    b0, b1, b2 = 1.0 / a0, 2.0 / a0, 1.0 / a0
    a1, a2 = (2.0 - 2.0 * k2) / a0, (k2 - dk + 1.0) / a0
    z1 = (b2 - a2) * x[0]
    z0 = (b1 - a1) * x[0] + z1
    for k in range(n):
        y = z0 + b0 * x[k]
        out[k] = y
        z0 = z1 + x[k] * b1 - y * a1
        z1 = x[k] * b2 - y * a2


def _chain_py(des: FloatArray, starts: NDArray[np.int64], jerk_code: int, p: FloatArray,
              out: FloatArray) -> None:  # pragma: no cover - compiled by numba
    """:func:`cnctwin.servo.identify.apply_setpoint_chain` on each run
    ``des[starts[i]:starts[i+1]]`` into ``out``."""
    nj = 0 if jerk_code == 0 else 1 if jerk_code == 1 else 2
    for i in range(starts.size - 1):
        a, b = starts[i], starts[i + 1]
        x = des[a:b]
        u = np.empty(b - a)
        w = np.empty(b - a)
        if jerk_code == 0:
            u[:] = x
        elif jerk_code == 1:
            _ma(x, max(p[0], 0.0), u)
        elif jerk_code == 2:
            _ma(x, max(p[0], 0.0), w)
            _ma(w, max(p[1], 0.0), u)
        else:
            _pt2(x, max(p[0], 0.0), min(max(p[1], 0.05), 5.0), u)
        _delay(u, max(p[nj], 0.0), w)
        _delay(w, max(p[nj + 3], 0.0), u)
        _pt1(u, max(p[nj + 1], 0.0), w)
        _pt1(w, max(p[nj + 2], 0.0), out[a:b])


_ma: Any = _ma_py
_delay: Any = _delay_py
_pt1: Any = _pt1_py
_pt2: Any = _pt2_py
_chain_compiled: Any = None  # made on first use (numba imports slowly)


def setpoint_chain_segments(des: FloatArray, starts: NDArray[np.int64], jerk_type: str,
                            params: FloatArray) -> FloatArray:
    """The setpoint chain of :func:`cnctwin.servo.identify.apply_setpoint_chain` on
    consecutive runs of one array, compiled (numba): the same operations in the same order as
    the NumPy/SciPy filters, so the same numbers (tests/servo/test_setpoint_kernel.py).

    Parameters
    ----------
    des : numpy.ndarray
        The runs' DES_POS samples, one after the other [unit].
    starts : numpy.ndarray of int64
        Start index of each run and, last, ``des.size``; each run is filtered on its own
        (the filters start settled at its first sample).
    jerk_type : str
        Jerk-filter model (:data:`JERK_CODES`).
    params : numpy.ndarray
        Jerk filter parameter(s) [cycles] (none, one, or two; PT2: time and damping), then
        the first delay, the two PT1 times and the second delay [cycles].

    Returns
    -------
    numpy.ndarray
        The filtered setpoint [unit].
    """
    global _chain_compiled, _ma, _delay, _pt1, _pt2
    if _chain_compiled is None:
        import numba

        opts: dict[str, Any] = {"cache": True, "nogil": True}
        _ma = numba.njit(**opts)(_ma_py)
        _delay = numba.njit(**opts)(_delay_py)
        _pt1 = numba.njit(**opts)(_pt1_py)
        _pt2 = numba.njit(**opts)(_pt2_py)
        _chain_compiled = numba.njit(**opts)(_chain_py)
    out = np.empty(des.size)
    _chain_compiled(np.ascontiguousarray(des, dtype=np.float64),
                    np.ascontiguousarray(starts, dtype=np.int64), JERK_CODES[jerk_type],
                    np.ascontiguousarray(params, dtype=np.float64), out)
    return out
