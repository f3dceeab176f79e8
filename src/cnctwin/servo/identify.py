"""Identification of an axis' cascade position loop from production HF data.

Pure fitting functions first (:func:`fit_setpoint_chain`, :func:`fit_speed_loop`,
:func:`fit_position_controller`, :func:`fit_axis_friction`), then the orchestrator
:func:`identify_axis`, which uses whatever signals a recording has and lists what it could not
identify and why (``AxisIdentification.not_identified``).

Loop structure (thesis Fig. 3.1; docs/reference/physics-and-performance.md §1.2)::

    DES_POS -> jerk filter (MD32402/MD32410) -> delay + PT1 (dynamic response adaptation
    MD32910, feedforward balancing) -> CTRL_POS
    CMD_SPEED = Kv * (CTRL_POS - ENC_POS) + w * VEL_FFW         (MD32200, MD32610/MD32620)
    actual speed = g * PT1_Teq(delay(CMD_SPEED))                (MD32810 equivalent time)
    ENC_POS = integral of the actual speed

Kv is reported in 1/s and in (m/min)/mm (1 (m/min)/mm = 1000/60 1/s = 16.667 1/s, MD10230).
"""

from __future__ import annotations

import itertools
import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import optimize

from cnctwin.exceptions import CnctwinError, IdentificationError
from cnctwin.recording import Recording
from cnctwin.servo._common import (
    AxisData,
    FloatArray,
    axis_data,
    delay,
    derivative,
    detect_velocity_unit,
    informative_segments,
    jerk_filter_average,
    pt1,
    pt2,
    quantum,
    setpoint_chain_segments,
)

__all__ = [
    "CUT_MARGIN_S",
    "JERK_FILTER_TYPES",
    "KV_PER_S_PER_M_MIN_MM",
    "AxisFrictionFit",
    "AxisIdentification",
    "Estimate",
    "PositionControllerFit",
    "SetpointChainFit",
    "SpeedLoopFit",
    "apply_setpoint_chain",
    "common_position_runs",
    "constant_velocity_runs",
    "cut_cycles",
    "fit_axis_friction",
    "fit_position_controller",
    "fit_setpoint_chain",
    "fit_speed_loop",
    "identify_axis",
    "steady_speed_gain",
]

KV_PER_S_PER_M_MIN_MM = 1000.0 / 60.0
"""1 (m/min)/mm in 1/s (MD10230 SCALING_FACTORS_USER_DEF[9] = 16.666667)."""

JERK_FILTER_TYPES: tuple[str, ...] = ("none", "moving_average", "pt2", "double_moving_average")
"""Setpoint-filter models, simplest first (MD32402: 1 = PT2, 2 = MA, 4 = double MA)."""


@dataclass(frozen=True)
class Estimate:
    """One identified parameter.

    Attributes
    ----------
    value : float
        Estimate [unit].
    stderr : float
        Standard error [unit] (method in ``method``); NaN when not available.
    unit : str
        Unit.
    method : str
        How it was obtained.
    """

    value: float
    stderr: float
    unit: str
    method: str


# ---------------------------------------------------------------------------- helpers
def _ess_inflation(resid: FloatArray) -> float:
    """Variance inflation n/n_eff for AR(1)-correlated residuals (>= 1)."""
    r = resid[np.isfinite(resid)]
    if r.size < 10 or float(r @ r) == 0.0:
        return 1.0
    rho = float(r[1:] @ r[:-1]) / float(r @ r)
    rho = min(max(rho, 0.0), 0.999)
    return (1.0 + rho) / (1.0 - rho)


def _hessian_se(cost: Callable[[FloatArray], float], p: FloatArray, n: int, inflation: float,
                steps: FloatArray) -> FloatArray:
    """Standard errors of a least-squares fit from the numerical Hessian of the SSE."""
    k = p.size
    f0 = cost(p)
    h = np.zeros((k, k))
    for i in range(k):
        for j in range(i, k):
            ei = np.zeros(k)
            ej = np.zeros(k)
            ei[i] = steps[i]
            ej[j] = steps[j]
            fpp = cost(p + ei + ej)
            fpm = cost(p + ei - ej)
            fmp = cost(p - ei + ej)
            fmm = cost(p - ei - ej)
            h[i, j] = h[j, i] = (fpp - fpm - fmp + fmm) / (4 * steps[i] * steps[j])
    sigma2 = f0 / max(n - k, 1)
    try:
        cov = np.linalg.inv(h / 2.0) * sigma2 * inflation
        se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    except np.linalg.LinAlgError:
        se = np.full(k, np.nan)
    return se


def _segment_mask(n: int, segs: list[slice], warmup: int) -> np.ndarray:
    m = np.zeros(n, dtype=bool)
    for s in segs:
        m[s.start + warmup : s.stop] = True
    return m


# ---------------------------------------------------------------------------- setpoint chain
@dataclass(frozen=True)
class SetpointChainFit:
    """DES_POS -> CTRL_POS model: jerk filter, then delay, then PT1.

    Attributes
    ----------
    jerk_type : str
        One of :data:`JERK_FILTER_TYPES`.
    jerk_time_s : float
        Jerk-filter time (MA window, PT2 time constant, first MA window) [s].
    jerk_time2_s : float
        Second MA window (double MA only) [s].
    jerk_damping : float
        PT2 damping [-] (PT2 only).
    delay_s : float
        Pure delay after the jerk filter (dynamic response adaptation, dead-time balancing;
        the sum of the two delays of the model) [s].
    pt1_s, pt1b_s : float
        Two first-order lags after the jerk filter (PT1 dynamic response adaptation, PT1
        balancing; ramp lag = time constant) [s], ``pt1_s >= pt1b_s``.
    rms : float
        Residual RMS of CTRL_POS [position unit].
    rms_by_model : dict
        Residual RMS of every model tried.
    stderr : dict
        Standard errors of the parameters above [s] or [-].
    """

    jerk_type: str
    jerk_time_s: float
    jerk_time2_s: float
    jerk_damping: float
    delay_s: float
    pt1_s: float
    pt1b_s: float
    rms: float
    rms_by_model: dict[str, float]
    stderr: dict[str, float]


def _jerk(x: FloatArray, jerk_type: str, p: FloatArray) -> FloatArray:
    if jerk_type == "none":
        return x
    if jerk_type == "moving_average":
        return jerk_filter_average(x, max(p[0], 0.0))
    if jerk_type == "double_moving_average":
        return jerk_filter_average(jerk_filter_average(x, max(p[0], 0.0)), max(p[1], 0.0))
    if jerk_type == "pt2":
        return pt2(x, max(p[0], 0.0), min(max(p[1], 0.05), 5.0))
    raise IdentificationError(f"unknown jerk filter {jerk_type!r}; use one of {JERK_FILTER_TYPES}")


_N_JERK = {"none": 0, "moving_average": 1, "double_moving_average": 2, "pt2": 2}


def apply_setpoint_chain(
    des: FloatArray, *, jerk_type: str, jerk_cycles: tuple[float, ...], delay_cycles: float,
    pt1_cycles: float, pt1b_cycles: float = 0.0, delay2_cycles: float = 0.0,
) -> FloatArray:
    """Jerk filter -> delay -> delay -> PT1 -> PT1 on one contiguous setpoint run (cycles).

    Two interpolated delays in series (dead-time adaptation and dead-time balancing, FFW modes
    3/4) are not one delay of their sum: each linear interpolation smooths a little.

    Parameters
    ----------
    des : numpy.ndarray
        DES_POS samples of one contiguous run [unit].
    jerk_type : str
        Jerk-filter model (:data:`JERK_FILTER_TYPES`).
    jerk_cycles : tuple
        Filter time(s) [cycles] (two for the double moving average, time and damping for PT2).
    delay_cycles : float
        First interpolated delay [cycles].
    pt1_cycles : float
        First PT1 time constant [cycles].
    pt1b_cycles : float, default 0.0
        Second PT1 time constant [cycles].
    delay2_cycles : float, default 0.0
        Second interpolated delay [cycles].

    Returns
    -------
    numpy.ndarray
        The filtered setpoint [unit].
    """
    y = _jerk(des, jerk_type, np.asarray(jerk_cycles, dtype=float))
    y = delay(delay(y, max(delay_cycles, 0.0)), max(delay2_cycles, 0.0))
    return pt1(pt1(y, max(pt1_cycles, 0.0)), max(pt1b_cycles, 0.0))


_RAMP = np.arange(512, dtype=np.float64)
_RAMP_STARTS = np.array([0, _RAMP.size], dtype=np.int64)


_POLISH = {"xatol": 1e-6, "fatol": 0.0, "maxiter": 150, "adaptive": True}
"""Nelder-Mead options of the last step of every setpoint-chain fit (after least squares)."""


def _single_from_double(
    p2: FloatArray, local_fit: Callable[[FloatArray, bool], tuple[FloatArray, float, FloatArray]],
    cost: Callable[[FloatArray], float],
) -> tuple[FloatArray, float, FloatArray]:
    """The single moving average fitted from the double one's parameters ``p2`` (windows
    w1, w2, then delay, PT1s, second delay): its window of the same variance,
    sqrt(w1^2 + w2^2 - 1) samples, held, then freed, then Nelder-Mead; the delay keeps the
    total lag ((w - 1) / 2 per average)."""
    w1, w2 = float(p2[0]), float(p2[1])
    w = float(round(math.sqrt(max(w1 * w1 + w2 * w2 - 1.0, 1.0))))
    x0 = np.concatenate([[w], np.asarray(p2[2:], dtype=float)])
    x0[1] = max(float(p2[2]) + (w1 + w2 - 2.0) / 2.0 - (w - 1.0) / 2.0, 0.0)
    xs, c, jac = local_fit(x0, True)
    xf, cf, jf = local_fit(xs, False)
    if cf < c:
        xs, c, jac = xf, cf, jf
    nm = optimize.minimize(cost, xs, method="Nelder-Mead", options=_POLISH)
    if nm.fun < c:
        xs, c = np.asarray(nm.x, dtype=float), float(nm.fun)
    return xs, c, jac


def chain_lag_cycles(jerk_type: str, params: FloatArray) -> float:
    """Lag of a setpoint chain behind a ramp once settled [cycles] (its DC group delay).

    Parameters
    ----------
    jerk_type : str
        One of :data:`JERK_FILTER_TYPES`.
    params : numpy.ndarray
        The chain's parameters in cycles, as :func:`fit_setpoint_chain` orders them (jerk
        filter, delay, two PT1s, second delay).

    Returns
    -------
    float
        E.g. (w - 1) / 2 for a moving average of w cycles, T for a PT1 of T cycles, plus the
        delays.
    """
    y = setpoint_chain_segments(_RAMP, _RAMP_STARTS, jerk_type,
                                np.asarray(params, dtype=np.float64))
    return float(_RAMP[-1] - y[-1])


def _total_lag_cycles(cost: Callable[[FloatArray], float]) -> float:
    """The pure delay [cycles] that best maps DES_POS on CTRL_POS (``cost`` of the 'none'
    chain, parameters [delay, PT1, PT1, delay2])."""
    coarse = [cost(np.array([float(t), 0.0, 0.0, 0.0])) for t in range(41)]
    k = int(np.argmin(coarse))
    res = optimize.minimize_scalar(lambda t: cost(np.array([t, 0.0, 0.0, 0.0])),
                                   bounds=(max(k - 1.0, 0.0), k + 1.0), method="bounded",
                                   options={"xatol": 1e-4})
    return float(res.x) if float(res.fun) <= coarse[k] else float(k)


def fit_setpoint_chain(
    des: FloatArray, ctrl: FloatArray, segs: list[slice], *, cycle_time_s: float,
    models: tuple[str, ...] = JERK_FILTER_TYPES, rel_tol: float = 0.1,
) -> SetpointChainFit:
    """Fit the setpoint filters between DES_POS and CTRL_POS by least squares.

    Every jerk-filter model is fitted (grid start, then Nelder-Mead) together with a delay and a
    PT1; the simplest model whose residual RMS is within ``1 + rel_tol`` of the best is chosen.

    Parameters
    ----------
    des, ctrl : numpy.ndarray
        DES_POS and CTRL_POS [mm or deg].
    segs : list of slice
        Contiguous runs of the cycle counter.
    cycle_time_s : float
        Cycle time [s].
    models : tuple of str
        Models to try (:data:`JERK_FILTER_TYPES`).
    rel_tol : float, default 0.1
        Relative RMS margin for preferring a simpler model.

    Returns
    -------
    SetpointChainFit

    Notes
    -----
    Moving average over T/cycle samples (fractional allowed); double MA: two in series
    (MD32410, MD32411); PT2: ``1/(T^2 s^2 + 2 D T s + 1)`` (MD32402 types 2, 4, 1; B2
    function manual). After the jerk filter: a delay and two backward-Euler PT1s (dynamic
    response adaptation MD32910 and feedforward balancing MD32810, PT1 in FFW modes 0-2, dead
    time in modes 3/4, K3 function manual).
    Standard errors from the SSE Hessian, inflated for AR(1) residual correlation.
    """
    full_mask = _segment_mask(des.size, segs, 5) & np.isfinite(des) & np.isfinite(ctrl)
    if full_mask.sum() < 50:
        raise IdentificationError(
            "too few samples with DES_POS and CTRL_POS to fit the jerk filter")
    if float(np.ptp(des[full_mask])) == 0.0:
        raise IdentificationError("DES_POS does not move; the setpoint filters cannot be fitted")
    all_segs = segs
    segs, mask = informative_segments(des, all_segs)
    mask &= np.isfinite(des) & np.isfinite(ctrl)
    if mask.sum() < 50:
        segs, mask = all_segs, full_mask

    # the runs the model is evaluated on, one after the other (compiled chain,
    # setpoint_chain_segments: the same numbers as apply_setpoint_chain run by run); a
    # masked sample outside every run of >= 3 cycles has no model
    runs = [s for s in segs if s.stop - s.start >= 3]
    mask &= _segment_mask(des.size, runs, 0)
    run_starts = np.cumsum([0] + [s.stop - s.start for s in runs]).astype(np.int64)
    des_c = np.concatenate([des[s] for s in runs]) if runs else np.empty(0)
    ctrl_m = np.concatenate([ctrl[s][mask[s]] for s in runs]) if runs else np.empty(0)
    mask_c = np.concatenate([mask[s] for s in runs]) if runs else np.empty(0, dtype=bool)

    def resid_of(jt: str) -> Callable[[FloatArray], FloatArray]:
        def resid(p: FloatArray) -> FloatArray:
            return np.asarray(ctrl_m - setpoint_chain_segments(des_c, run_starts, jt, p)[mask_c],
                              dtype=np.float64)

        return resid

    def cost_of(jt: str) -> Callable[[FloatArray], float]:
        rf = resid_of(jt)

        def cost(p: FloatArray) -> float:
            if np.any(p < -1e-9) or (jt == "pt2" and p[1] <= 0.05):
                return 1e30
            r = rf(p)
            return float(r @ r)

        return cost

    fits: dict[str, tuple[FloatArray, float]] = {}
    jacs: dict[str, FloatArray] = {}
    nj_of = _N_JERK
    lag = (des - ctrl)[mask]
    lag_rms = float(np.sqrt(np.mean(lag * lag)))
    early_stop = 1e-7
    q_floor = (quantum(des) + quantum(ctrl)) / math.sqrt(12.0)
    # the setpoint's total lag [cycles], from the best pure delay: every grid point below
    # gets the delay that makes its own lag equal to it, so the grid compares the filters'
    # shapes. On a grid of fixed delays the lag's rounding decided instead (a lag of 3.78
    # cycles: an 8-cycle average, 3.5, lost to 7 cycles + a PT1 of 1, 4.0) and an 8-cycle
    # filter was fitted as 6.5 cycles + a PT1 (calibration campaign, seeds 3120, 3189, 3194)
    d_obs = _total_lag_cycles(cost_of("none"))
    for jt in models:
        cost = cost_of(jt)
        wins = [float(w) for w in range(1, 21)] + [24.0, 28.0, 32.0]
        t1s = [0.0, 1.0, 2.5]
        t2s = [0.0, 1.5]
        if jt == "none":
            shapes = [np.array([0.0, t1, t2]) for t1 in [*t1s, 8.0, 12.0] for t2 in t2s]
        elif jt == "moving_average":
            shapes = [np.array([w, 0.0, t1, t2]) for w in wins for t1 in t1s for t2 in t2s]
        elif jt == "double_moving_average":
            shapes = [np.array([w, w2, 0.0, t1, t2]) for w in wins[:12]
                      for w2 in sorted({max(round(w / 2), 2.0), w})
                      for t1 in t1s for t2 in t2s]
        else:
            shapes = [np.array([t, dmp, 0.0, t1, t2]) for t in np.arange(0.5, 12.5, 1.0)
                      for dmp in (0.7, 1.0) for t1 in t1s for t2 in t2s]
        grid = []
        for g in shapes:
            g = np.append(g, 0.0)  # second delay starts at 0
            g[nj_of[jt]] = max(d_obs - chain_lag_cycles(jt, g), 0.0)
            grid.append(g)
        costs = np.array([cost(g) for g in grid])
        resid_fn = resid_of(jt)
        best_fit: tuple[FloatArray, float] | None = None
        # starts: the best grid points with distinct first parameters (jerk windows), so a
        # wrong window is not refined three times
        starts: list[int] = []
        seen: set[float] = set()
        for i in np.argsort(costs):
            key = float(grid[int(i)][0])
            if key in seen:
                continue
            seen.add(key)
            starts.append(int(i))
            if len(starts) == (6 if jt in ("moving_average", "double_moving_average") else 2):
                break
        inits = []
        for i in starts:
            g0 = grid[int(i)].copy()
            inits.append(g0)
            # same total delay split into two half-cycle interpolations: two fractional
            # delays in series are a 3-tap kernel no single delay reaches (also without a
            # jerk filter: a 2-cycle average, exactly a half-cycle delay, before a fractional
            # balancing dead time must be reached by the plain chain, or it is taken for a
            # filter; campaign seed 3008)
            g1 = g0.copy()
            g1[nj_of[jt]] = max(g0[nj_of[jt]] - 0.5, 0.0)
            g1[-1] = 0.5
            inits.append(g1)
        moving_window = jt in ("moving_average", "double_moving_average")

        def local_fit(
            x_init: FloatArray, freeze_window: bool, jt: str = jt,
            resid_fn: Callable[[FloatArray], FloatArray] = resid_fn,
        ) -> tuple[FloatArray, float, FloatArray]:
            x0 = np.maximum(x_init, 1e-6)
            lb = np.zeros(x0.size)
            ub = np.full(x0.size, np.inf)
            if jt == "pt2":
                lb[1] = 0.06
                x0[1] = max(x0[1], 0.07)
            if freeze_window:
                # MA windows are whole cycles on the NC; the window kink at integers stalls a
                # gradient method, so the window is held first and freed afterwards
                lb[0], ub[0] = x0[0], x0[0] + 1e-9
            with warnings.catch_warnings():
                # scipy casts inf/inf step bounds of the unbounded parameters (harmless)
                warnings.simplefilter("ignore", RuntimeWarning)
                ls = optimize.least_squares(resid_fn, x0, bounds=(lb, ub), method="trf",
                                            diff_step=1e-5, xtol=1e-12, ftol=1e-14,
                                            gtol=1e-14, max_nfev=200)
            return np.asarray(ls.x, dtype=float), float(2.0 * ls.cost), np.asarray(ls.jac)

        for x_init in inits:
            xs, c, jac = local_fit(x_init, moving_window)
            if best_fit is None or c < best_fit[1]:
                best_fit = (xs, c)
                jacs[jt] = jac
        if moving_window and best_fit is not None:
            xs, c, jac = local_fit(best_fit[0], False)
            if c < best_fit[1]:
                best_fit = (xs, c)
                jacs[jt] = jac
        assert best_fit is not None
        res2 = optimize.minimize(cost, best_fit[0], method="Nelder-Mead", options=_POLISH)
        if res2.fun > best_fit[1]:
            res2.x, res2.fun = best_fit[0], best_fit[1]
        fits[jt] = (np.asarray(res2.x, dtype=float), float(res2.fun))
        if jt == "double_moving_average" and "moving_average" in fits \
                and fits[jt][1] < fits["moving_average"][1]:
            # two averages in series look like one of the same variance ((w^2 - 1) / 12
            # each): a start there for the single average, whose own grid starts may all
            # have missed its window (an 18 ms filter, 9 cycles, fitted from windows 1-6 as
            # 8.5 cycles + PT1s, rms 2.6x the double's: then taken for a double average)
            ma = _single_from_double(fits[jt][0], lambda x, f: local_fit(
                x, f, "moving_average", resid_of("moving_average")),
                cost_of("moving_average"))
            if ma[1] < fits["moving_average"][1]:
                fits["moving_average"] = (ma[0], ma[1])
                jacs["moving_average"] = ma[2]
        # a model that explains the setpoint lag to 1e-7 of its size (or to the quantization of
        # the signals) is kept; more complex
        # models are not tried (they could only be chosen if clearly better)
        if math.sqrt(fits[jt][1] / max(int(mask.sum()), 1)) < max(early_stop * lag_rms,
                                                                   2.0 * q_floor):
            break
    n = int(mask.sum())
    rms_by = {jt: math.sqrt(f[1] / n) for jt, f in fits.items()}
    best = min(rms_by.values())
    floor = max(best * (1.0 + rel_tol), 1e-9)
    chosen = next(jt for jt in models if jt in rms_by and rms_by[jt] <= floor)
    p = fits[chosen][0]
    if chosen == "double_moving_average" and min(p[0], p[1]) <= 1.0 + 1e-6:
        # a window of <= 1 cycle is no filter: this is a single moving average
        if "moving_average" in fits and rms_by["moving_average"] <= rms_by[chosen] * (
                1.0 + rel_tol):
            chosen = "moving_average"
            p = fits[chosen][0]
        else:
            chosen = "moving_average"
            p = np.delete(p, 1 if p[1] <= p[0] else 0)
            fits[chosen] = (p, fits["double_moving_average"][1])
            rms_by[chosen] = rms_by["double_moving_average"]
    nj = _N_JERK[chosen]
    # standard errors from the Jacobian at the solution: cov = s^2 (J'J)^-1, inflated for
    # residual autocorrelation
    rf = resid_of(chosen)
    resid = rf(p)
    jac = np.empty((int(mask.sum()), p.size))
    for i in range(p.size):
        h = max(abs(p[i]) * 1e-6, 1e-7)
        e = np.zeros(p.size)
        e[i] = h
        lo = np.maximum(p - e, 0.0)
        jac[:, i] = (rf(p + e) - rf(lo)) / (p[i] + h - lo[i])
    if not np.isfinite(jac).all():
        se = np.full(p.size, np.nan)
    else:
        s2 = fits[chosen][1] / max(n - p.size, 1)
        cov = np.linalg.pinv(jac.T @ jac) * s2 * _ess_inflation(resid)
        se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    dt = cycle_time_s
    names = {"none": [], "moving_average": ["jerk_time_s"], "pt2": ["jerk_time_s", "jerk_damping"],
             "double_moving_average": ["jerk_time_s", "jerk_time2_s"]}[chosen]
    names = [*names, "delay_s", "pt1_s", "pt1b_s", "delay2_s"]
    stderr = {nm: float(se[i]) * (1.0 if nm == "jerk_damping" else dt)
              for i, nm in enumerate(names)}
    jt1 = float(p[0]) * dt if nj >= 1 else 0.0
    jt2 = float(p[1]) * dt if chosen == "double_moving_average" else 0.0
    dmp = float(p[1]) if chosen == "pt2" else float("nan")
    if chosen == "double_moving_average" and jt2 > jt1:  # order is irrelevant; larger first
        jt1, jt2 = jt2, jt1
        se1, se2 = stderr["jerk_time_s"], stderr["jerk_time2_s"]
        stderr["jerk_time_s"], stderr["jerk_time2_s"] = se2, se1
    t_a, t_b = max(float(p[nj + 1]), 0.0) * dt, max(float(p[nj + 2]), 0.0) * dt
    if t_b > t_a:  # the two PT1s commute: larger first
        t_a, t_b = t_b, t_a
        stderr["pt1_s"], stderr["pt1b_s"] = stderr["pt1b_s"], stderr["pt1_s"]
    d_tot = (max(float(p[nj]), 0.0) + max(float(p[nj + 3]), 0.0)) * dt
    stderr["delay_s"] = math.hypot(stderr["delay_s"], stderr.pop("delay2_s"))
    return SetpointChainFit(chosen, jt1, jt2, dmp, d_tot, t_a, t_b, rms_by[chosen], rms_by,
                            stderr)


# ---------------------------------------------------------------------------- speed loop
@dataclass(frozen=True)
class SpeedLoopFit:
    """CMD_SPEED -> actual speed model ``v = g * PT1_T(delay_tau(u))``.

    Attributes
    ----------
    gain : float
        Steady-state ratio actual speed / speed command g [-] (1 when CMD_SPEED is in load
        units and the speed controller has integral action).
    time_s, delay_s : float
        PT1 time constant and pure delay [s]; ``equivalent_time_s = time_s + delay_s``
        is the equivalent time of the speed loop as seen by the position controller
        (MD32810 EQUIV_SPEEDCTRL_TIME). ``delay_s`` includes the hold of the position
        controller output (CMD_SPEED of cycle k acts during cycle k: one cycle); with DSC the
        drive closes the loop itself every speed-controller cycle and the delay can be shorter.
    model_delay_cycles, model_time_cycles : float
        The fitted model parameters as used by the prediction (delay including the hold).
    stderr : dict
        Standard errors of gain, time_s, delay_s.
    rms : float
        Residual RMS [position unit/s].
    """

    gain: float
    time_s: float
    delay_s: float
    stderr: dict[str, float]
    rms: float
    model_delay_cycles: float = 1.0
    model_time_cycles: float = 0.0

    @property
    def equivalent_time_s(self) -> float:
        """Equivalent time constant of the closed speed loop, T + delay [s]."""
        return self.time_s + self.delay_s


def fit_speed_loop(
    cmd_per_s: FloatArray, v_act_backward: FloatArray, segs: list[slice], *, cycle_time_s: float
) -> SpeedLoopFit:
    """Fit first order + delay from the speed command to the actual speed.

    Parameters
    ----------
    cmd_per_s : numpy.ndarray
        Speed command converted to position units per second.
    v_act_backward : numpy.ndarray
        ``(ENC_POS[k] - ENC_POS[k-1]) / dt`` (the mean speed of the last cycle, half a cycle
        late; the fit corrects that half cycle) [unit/s].
    segs : list of slice
        Contiguous runs.
    cycle_time_s : float
        Cycle time [s].

    Returns
    -------
    SpeedLoopFit
    """
    u = np.nan_to_num(cmd_per_s)
    mask = _segment_mask(u.size, segs, 5) & np.isfinite(v_act_backward) & np.isfinite(cmd_per_s)
    if mask.sum() < 50 or float(np.std(v_act_backward[mask])) == 0.0:
        raise IdentificationError("the axis does not move; the speed loop cannot be fitted")
    win, wmask = informative_segments(np.cumsum(u), segs, pad=60, warm=30)
    wmask &= mask
    if wmask.sum() >= 50:
        segs, mask = win, wmask
    y = v_act_backward

    def shaped(p: FloatArray) -> FloatArray:
        out = np.full(u.shape, np.nan)
        for s in segs:
            if s.stop - s.start < 3:
                continue
            # the backward difference is the mean over [k-1, k]: a MA of one cycle
            out[s] = jerk_filter_average(pt1(delay(u[s], max(p[0], 0.0)), max(p[1], 0.0)), 1.0)
        return out

    def cost_g(p: FloatArray) -> tuple[float, float]:
        if np.any(p < -1e-9):
            return 1e30, 1.0
        x = shaped(p)[mask]
        yy = y[mask]
        den = float(x @ x)
        g = float(x @ yy) / den if den > 0 else 1.0
        r = yy - g * x
        return float(r @ r), g

    def cost(p: FloatArray) -> float:
        return cost_g(p)[0]

    grid = [np.array([tau, t]) for tau in (0.0, 0.5, 1.0, 1.5, 2.0, 3.0)
            for t in (0.0, 0.5, 1.0, 2.0, 4.0)]
    start = min(grid, key=cost)
    # converged when the simplex is within 1e-3 cycles (2 us at 2 ms) and the sum of squares
    # changes by < 1e-9 of its start: 100 evaluations instead of scipy's cap of 400 (with
    # fatol 0 it never converged); the parameters move by < 0.002 of their standard error
    res = optimize.minimize(cost, start, method="Nelder-Mead",
                            options={"xatol": 1e-3, "fatol": 1e-9 * cost(start),
                                     "maxiter": 600})
    p = np.maximum(res.x, 0.0)
    sse, g = cost_g(p)
    n = int(mask.sum())
    resid = y[mask] - g * shaped(p)[mask]

    def cost3(q: FloatArray) -> float:
        x = shaped(q[1:])[mask]
        r = y[mask] - q[0] * x
        return float(r @ r)

    q = np.array([g, *p])
    se = _hessian_se(cost3, q, n, _ess_inflation(resid), np.maximum(np.abs(q) * 1e-3, 1e-3))
    dt = cycle_time_s
    return SpeedLoopFit(g, float(p[1]) * dt, float(p[0]) * dt,
                        {"gain": float(se[0]), "time_s": float(se[2]) * dt,
                         "delay_s": float(se[1]) * dt}, math.sqrt(sse / n),
                        model_delay_cycles=float(p[0]), model_time_cycles=float(p[1]))


def steady_speed_gain(
    cmd_per_s: FloatArray, enc: FloatArray, runs: list[slice], *, lag_cycles: float,
    cycle_time_s: float,
) -> tuple[float, float, int]:
    """Steady-state gain from the speed command to the actual speed, from constant-velocity runs.

    Parameters
    ----------
    cmd_per_s : numpy.ndarray
        Speed command converted to position units per second.
    enc : numpy.ndarray
        Actual position ENC_POS [unit].
    runs : list of slice
        Constant-velocity runs of the setpoint (:func:`constant_velocity_runs`); each needs the
        cycle before its start.
    lag_cycles : float
        Equivalent time of the speed loop in cycles, plus the half cycle of the backward
        difference (``SpeedLoopFit.model_delay_cycles + model_time_cycles + 0.5``): the
        command is averaged that much earlier than the travel it causes.
    cycle_time_s : float
        Cycle time [s].

    Returns
    -------
    gain : float
        Travel over the runs divided by the integral of the (delayed) command [-].
    stderr : float
        Jackknife standard error over the runs, times ``t(0.975, n - 1) / 1.96`` so that
        +-1.96 of it is the small-sample 95 % interval [-].
    n_runs : int
        Runs used.

    Raises
    ------
    IdentificationError
        Fewer than 3 usable runs.

    Notes
    -----
    In steady motion a speed loop with integral action makes the actual speed equal its
    setpoint times the drive's normalisation, whatever its dynamics: the ratio needs no loop
    model, unlike the gain of :func:`fit_speed_loop`, whose first order + delay fitted to a PI
    loop with a current loop is biased by a few 1e-4 (simulated axes,
    docs/validation-calibration.md).
    The ratio of sums weights each run by its travel (an end-point error of the position,
    quantisation, noise, the ripple's phase, counts relative to the travel).
    """
    from scipy import stats

    k = np.arange(cmd_per_s.size, dtype=np.float64)
    cmd = np.nan_to_num(cmd_per_s)
    travel, commanded = [], []
    for r in runs:
        if r.start < 1 or r.stop - r.start < 3:
            continue
        d = float(enc[r.stop - 1] - enc[r.start - 1])
        c = float(np.interp(np.arange(r.start, r.stop) - lag_cycles, k, cmd).sum()) \
            * cycle_time_s
        if math.isfinite(d) and math.isfinite(c) and c != 0.0:
            travel.append(abs(d))
            commanded.append(abs(c))
    n = len(travel)
    if n < 3:
        raise IdentificationError(f"the steady speed gain needs >= 3 constant-velocity runs; "
                                  f"found {n}")
    a, b = np.array(travel), np.array(commanded)
    g = float(a.sum() / b.sum())
    jk = (a.sum() - a) / (b.sum() - b)
    se = math.sqrt((n - 1) / n * float(np.sum((jk - jk.mean()) ** 2)))
    return g, se * float(stats.t.ppf(0.975, n - 1)) / 1.96, n


# ---------------------------------------------------------------------------- P controller
@dataclass(frozen=True)
class PositionControllerFit:
    """Least-squares fit of ``cmd = a * diff + c * ffw + offset``.

    Attributes
    ----------
    a, c, offset : float
        Coefficients (``c`` is NaN without a feedforward regressor).
    se_a, se_c : float
        Block-bootstrap standard errors.
    rms : float
        Residual RMS [cmd unit].
    n_used, n_excluded : int
        Samples used; samples dropped as outliers (> 6 MAD, e.g. speed-mode or saturation).
    """

    a: float
    c: float
    offset: float
    se_a: float
    se_c: float
    rms: float
    n_used: int
    n_excluded: int


def fit_position_controller(
    cmd: FloatArray, diff: FloatArray, ffw: FloatArray | None, *, block_cycles: int = 100,
    n_bootstrap: int = 200, seed: int = 0, extra: FloatArray | None = None,
) -> PositionControllerFit:
    """Regress the speed command on the controller difference and the velocity feedforward.

    Parameters
    ----------
    cmd : numpy.ndarray
        Speed command [unit/s].
    diff : numpy.ndarray
        Controller difference (CTRL_DIFF2, or the following error as a proxy) [mm or deg].
    ffw : numpy.ndarray or None
        Velocity feedforward [unit/s]; None for FFW off.
    block_cycles : int, default 100
        Block length of the moving-block bootstrap [cycles].
    n_bootstrap : int, default 200
        Bootstrap resamples.
    seed : int, default 0
        Random seed of the bootstrap.
    extra : numpy.ndarray, optional
        Additional regressor columns (n x m), e.g. setpoint differences that absorb an
        unrecorded setpoint filter.

    Returns
    -------
    PositionControllerFit

    Notes
    -----
    P position controller with speed feedforward (MD32200, MD32620):
    ``n_set = Kv * e + w * v_ffw``. Outliers beyond 6 MAD (speed-controlled spindle, saturation)
    are excluded in two passes and counted.
    """
    cols = [diff] if ffw is None else [diff, ffw]
    if extra is not None:
        cols += [extra[:, j] for j in range(extra.shape[1])]
    a_mat = np.column_stack([*cols, np.ones_like(diff)])
    m = np.isfinite(a_mat).all(axis=1) & np.isfinite(cmd)
    n_total = int(m.sum())
    if n_total < 20:
        raise IdentificationError(
            "fewer than 20 samples with the speed command and controller difference")
    if float(np.std(diff[m])) == 0.0:
        raise IdentificationError("the controller difference is constant; Kv is not identifiable")
    coef = np.zeros(a_mat.shape[1])
    for _ in range(3):
        coef, *_ = np.linalg.lstsq(a_mat[m], cmd[m], rcond=None)
        r = cmd - a_mat @ coef
        mad = float(np.median(np.abs(r[m] - np.median(r[m])))) * 1.4826
        if mad == 0:
            break
        # keep everything within 6 MAD or 1e-3 of the command RMS (a perfect fit has a tiny MAD)
        floor = 1e-3 * float(np.sqrt(np.mean(cmd[m] ** 2)))
        new = m & (np.abs(r) <= max(6 * mad, floor) + 1e-12)
        if new.sum() == m.sum() or new.sum() < 20:
            break
        m = new
    idx = np.flatnonzero(m)
    rng = np.random.default_rng(seed)
    nb = max(1, idx.size // block_cycles)
    boots = []
    for _ in range(n_bootstrap):
        starts = rng.integers(0, max(idx.size - block_cycles, 1), nb)
        sel = idx[(starts[:, None] + np.arange(min(block_cycles, idx.size))[None, :]).ravel()]
        cb, *_ = np.linalg.lstsq(a_mat[sel], cmd[sel], rcond=None)
        boots.append(cb)
    b = np.asarray(boots)
    se = b.std(axis=0, ddof=1) if len(boots) > 1 else np.full(coef.size, np.nan)
    resid = cmd[m] - a_mat[m] @ coef
    return PositionControllerFit(
        float(coef[0]), float(coef[1]) if ffw is not None else float("nan"), float(coef[-1]),
        float(se[0]), float(se[1]) if ffw is not None else float("nan"),
        float(np.sqrt(np.mean(resid**2))), int(m.sum()), n_total - int(m.sum()),
    )


# ---------------------------------------------------------------------------- friction
@dataclass(frozen=True)
class AxisFrictionFit:
    """``tau = Fc sign(v) + b v (+ offset)`` from constant-velocity runs.

    Attributes
    ----------
    coulomb, viscous, offset : float
        Coulomb level [signal unit], viscous slope [signal unit per unit/s], constant
        (weight/gravity) offset [signal unit] (0 if not fitted).
    se_coulomb, se_viscous, se_offset : float
        Standard errors: bootstrap over runs, times ``sqrt(n / (n - p))`` (HC1; MacKinnon &
        White 1985, J. Econometrics 29: the bootstrap's variance is low by (n - p) / n);
        with fewer than :data:`FEW_RUNS_DOF` residual degrees of freedom the noise within
        the runs (their batch means) propagated through the fit instead.
    n_runs : int
        Constant-velocity runs used.
    signal : str
        ``"CURRENT"`` or ``"TORQUE"``.
    unit : str
        Signal unit.
    run_velocity, run_effort, run_cycles : tuple of float
        Per run used: mean velocity [unit/s], mean effort [signal unit], length [cycles].
    """

    coulomb: float
    viscous: float
    offset: float
    se_coulomb: float
    se_viscous: float
    se_offset: float
    n_runs: int
    signal: str
    unit: str
    run_velocity: tuple[float, ...] = ()
    run_effort: tuple[float, ...] = ()
    run_cycles: tuple[float, ...] = ()


def constant_velocity_runs(
    v_per_s: FloatArray, segs: list[slice], *, min_cycles: int = 40, rel_tol: float = 0.02,
    min_speed_frac: float = 0.02, drop_first: float = 0.25,
) -> list[slice]:
    """Runs where the setpoint velocity is constant and non-zero.

    A run keeps cycles whose velocity stays within ``rel_tol`` of the run median and is above
    ``min_speed_frac`` of the largest speed; the first ``drop_first`` of each run (transient)
    is dropped.

    Parameters
    ----------
    v_per_s : numpy.ndarray
        Setpoint velocity [unit/s].
    segs : list
        Contiguous segments to search.
    min_cycles : int, default 40
        Shortest run kept [cycles].
    rel_tol : float, default 0.02
        Allowed deviation from the run median [-].
    min_speed_frac : float, default 0.02
        Smallest speed as a share of the largest [-].
    drop_first : float, default 0.25
        Share of each run dropped at its start [-] (0: velocities already known to have
        settled, e.g. the actual speed checked against the setpoint).

    Returns
    -------
    list of slice
    """
    vmax = float(np.nanmax(np.abs(v_per_s))) if np.isfinite(v_per_s).any() else 0.0
    if vmax == 0.0:
        return []
    global _runs_compiled
    if _runs_compiled is None:
        import numba

        _runs_compiled = numba.njit(cache=True, nogil=True)(_runs_py)
    runs: list[slice] = []
    for s in segs:
        v = np.ascontiguousarray(v_per_s[s], dtype=np.float64)
        found = _runs_compiled(v, float(min_speed_frac * vmax), float(rel_tol),
                               int(min_cycles), float(drop_first))
        runs.extend(slice(s.start + int(a), s.start + int(b)) for a, b in found)
    return runs


def _runs_py(v: FloatArray, v_min: float, rel_tol: float, min_cycles: int, drop_first: float
             ) -> np.ndarray:  # pragma: no cover - compiled by numba; the body is the reference
    """The (start, stop) pairs of :func:`constant_velocity_runs` in one segment: greedy runs
    within ``rel_tol`` of their first value, above ``v_min``, the first ``drop_first`` of
    each dropped."""
    out = np.empty((v.size // max(min_cycles, 1) + 1, 2), dtype=np.int64)
    m = 0
    k = 0
    n = v.size
    while k < n:
        if not np.isfinite(v[k]) or abs(v[k]) < v_min:
            k += 1
            continue
        j = k
        ref = v[k]
        while j < n and np.isfinite(v[j]) and abs(v[j] - ref) <= rel_tol * abs(ref):
            j += 1
        if j - k >= min_cycles:
            out[m, 0] = k + int((j - k) * drop_first)
            out[m, 1] = j
            m += 1
        k = max(j, k + 1)
    return out[:m]


_runs_compiled: Any = None  # numba-compiled _runs_py, made on first use (numba imports slowly)


def _outside(runs: list[slice], cut: np.ndarray, *, min_cycles: int) -> list[slice]:
    """The parts of the runs outside ``cut`` that are at least ``min_cycles`` long."""
    out: list[slice] = []
    for r in runs:
        free = ~cut[r]
        edges = np.flatnonzero(np.diff(np.r_[False, free, False].astype(np.int8)))
        for a, b in zip(edges[::2], edges[1::2], strict=True):
            if b - a >= min_cycles:
                out.append(slice(r.start + int(a), r.start + int(b)))
    return out


def common_position_runs(
    runs: list[slice], position: FloatArray, velocity: FloatArray, *, min_cycles: int = 40,
    speed_tol: float = 0.1, min_share: float = 0.7, edge_cycles: int = 0,
    unpaired_drop_first: float = 0.0,
) -> list[slice]:
    """Runs of opposite directions at one speed, each pair cut to the positions both cover.

    A force that depends on the position only (the screw's ripple, one period per motor
    revolution; pitch or preload variation along the screw) adds the same amount to both
    directions' run means when they cover the same positions at constant speed (uniform
    sampling in position), so it moves the offset of :func:`fit_axis_friction` and cancels
    from its Coulomb term. Runs that keep different positions (the first quarter of each
    stroke dropped as its transient: the forward run ends where the backward one starts)
    leave half the difference of the force's means over the two ranges in the Coulomb term,
    with the same sign on every machine whose screws share a phase.

    Parameters
    ----------
    runs : list of slice
        Constant-velocity runs (:func:`constant_velocity_runs`).
    position : numpy.ndarray
        Actual position [unit].
    velocity : numpy.ndarray
        Actual velocity [unit/s].
    min_cycles : int, default 40
        Shortest part kept: a pair whose common positions give less stays as it was.
    min_share : float, default 0.7
        A pair is cut only if each run keeps at least this share of its cycles [-] (strokes
        back and forth over one span, as a test program makes them); moves of a production
        program that overlap in part keep their length, and the precision of their means,
        rather than trade it for a ripple's bias of ~A lead / (pi L).
    speed_tol : float, default 0.1
        Runs pair when their mean speeds differ by at most this share [-] (one programmed
        feed).
    edge_cycles : int, default 0
        Cycles dropped at both ends of a paired run before the cut (where the speed still
        settles or the braking begins), at most an eighth of it at each end.
    unpaired_drop_first : float, default 0.0
        Share of a run without a partner dropped at its start [-] (its transient, for runs
        found without dropping one: a paired run's start is its partner's end).

    Returns
    -------
    list of slice
        The runs, in their order: paired ones cut to the common positions, the others with
        ``unpaired_drop_first`` dropped.
    """
    shaved = [slice(r.start + e, r.stop - e) for r in runs
              for e in [min(edge_cycles, (r.stop - r.start) // 8)]]
    info = []
    for r in shaved:
        x = position[r]
        v = float(np.nanmean(velocity[r]))
        info.append((v, float(np.nanmin(x)), float(np.nanmax(x))) if np.isfinite(v)
                    and np.isfinite(x).any() else (math.nan, math.nan, math.nan))
    out = list(shaved)
    taken: set[int] = set()
    for i, (vi, lo_i, hi_i) in enumerate(info):
        if i in taken or not vi > 0:
            continue
        best, best_len = -1, 0.0
        for j, (vj, lo_j, hi_j) in enumerate(info):
            if j in taken or not vj < 0 or abs(abs(vj) - vi) > speed_tol * vi:
                continue
            common = min(hi_i, hi_j) - max(lo_i, lo_j)
            if common > best_len:
                best, best_len = j, common
        if best < 0:
            continue
        lo, hi = max(lo_i, info[best][1]), min(hi_i, info[best][2])
        ci, cb = (_within(shaved[k], position, lo, hi) for k in (i, best))
        if ci is not None and cb is not None and all(
                c.stop - c.start >= max(min_cycles, min_share * (r.stop - r.start))
                for c, r in ((ci, shaved[i]), (cb, shaved[best]))):
            out[i], out[best] = ci, cb
            taken |= {i, best}
    for k, r in enumerate(runs):
        if k not in taken:  # as found, with its start dropped
            out[k] = slice(r.start + int((r.stop - r.start) * unpaired_drop_first), r.stop)
    return out


def _within(run: slice, position: FloatArray, lo: float, hi: float) -> slice | None:
    """The part of a monotonic run whose positions lie in [lo, hi] (None: none)."""
    inside = np.flatnonzero((position[run] >= lo) & (position[run] <= hi))
    if not inside.size:
        return None
    return slice(run.start + int(inside[0]), run.start + int(inside[-1]) + 1)


def _identifiable(v: FloatArray, both: bool) -> bool:
    """Runs that determine the friction law: two speeds (:func:`_two_speeds`) and, with the
    offset (both directions), three (direction, speed) groups - fewer leave the lstsq rank
    deficient and its minimum-norm answer is not an estimate."""
    if not _two_speeds(v):
        return False
    if not both:
        return True
    if not ((v > 0).any() and (v < 0).any()):
        return False
    groups = {(bool(x > 0), int(np.floor(np.log(abs(x)) / np.log(1.25)))) for x in v if x != 0}
    return len(groups) >= 3


def _two_speeds(v: FloatArray) -> bool:
    """Run speeds that separate Coulomb from viscous friction: the slowest at most 80 % of
    the fastest (runs at one programmed feed differ by their noise only, and a fit on those is
    ill-conditioned, not informative)."""
    a = np.abs(v)
    return bool(a.size and a.max() > 0 and a.min() <= 0.8 * a.max())


def fit_axis_friction(
    v_per_s: FloatArray, effort: FloatArray, runs: list[slice], *, signal: str, unit: str,
    n_bootstrap: int = 200, seed: int = 0,
) -> AxisFrictionFit:
    """Fit Coulomb + viscous friction of a feed axis to run means of CURRENT or TORQUE.

    The spindle's air-cut line (thesis Eq. 4.2) is :func:`cnctwin.spindle.fit_friction`; this is
    the axis law with both directions and a weight offset.

    Parameters
    ----------
    v_per_s : numpy.ndarray
        Actual velocity [unit/s].
    effort : numpy.ndarray
        CURRENT [A] or TORQUE [N or Nm].
    runs : list of slice
        Constant-velocity runs (:func:`constant_velocity_runs`).
    signal, unit : str
        Name and unit of ``effort`` (for the result).
    n_bootstrap : int, default 200
        Resamples of the bootstrap over runs.
    seed : int, default 0
        Random seed.

    Returns
    -------
    AxisFrictionFit

    Notes
    -----
    ``tau = Fc sign(v) + b v + c``; ``c`` (weight compensation of a vertical axis) is fitted
    only when both directions occur. Run means average out the cutting-free ripple; runs are
    weighted by their length (weighted least squares), because a short run averages the
    noise and a position-periodic force (screw ripple, one period per motor revolution) over
    less travel: its mean keeps up to A lead / (pi L) of a ripple of amplitude A over L.
    """
    vm = np.array([np.nanmean(v_per_s[r]) for r in runs])
    tm = np.array([np.nanmean(effort[r]) for r in runs])
    wm = np.array([float(r.stop - r.start) for r in runs])
    ok = np.isfinite(vm) & np.isfinite(tm)
    vm, tm, wm = vm[ok], tm[ok], np.sqrt(wm[ok])
    both = bool((vm > 0).any() and (vm < 0).any())
    p = 3 if both else 2
    if vm.size < p + 1 or not _identifiable(vm, both):
        raise IdentificationError(
            f"friction needs >= {p + 1} constant-velocity runs at >= 2 speeds; found {vm.size}"
            + (f" at one speed ({np.median(np.abs(vm)):.4g} {unit.split('/')[-1] or 'unit'}/s)"
               if vm.size and not _two_speeds(vm) else ""))

    def design(v: FloatArray) -> FloatArray:
        cols = [np.sign(v), v]
        if both:
            cols.append(np.ones_like(v))
        return np.column_stack(cols)

    coef, *_ = np.linalg.lstsq(design(vm) * wm[:, None], tm * wm, rcond=None)
    rng = np.random.default_rng(seed)
    boots = []
    for _ in range(n_bootstrap):
        sel = rng.integers(0, vm.size, vm.size)
        if not _identifiable(vm[sel], both):
            continue
        cb, *_ = np.linalg.lstsq(design(vm[sel]) * wm[sel, None], tm[sel] * wm[sel],
                                 rcond=None)
        boots.append(cb)
    se = np.asarray(boots).std(axis=0, ddof=1) if len(boots) > 2 else np.full(p, np.nan)
    # the pairs bootstrap estimates the sandwich (HC0) variance, which is low by (n - p) / n
    # for few runs (an axis test gives one run per stroke: 10 for 5 feeds); HC1's factor
    se = se * math.sqrt(vm.size / (vm.size - p))
    if vm.size - p < FEW_RUNS_DOF:
        # few runs (a production job's air moves: 4 runs, 1 residual degree of freedom):
        # the resamples agree by chance (u near zero) or not at all, so the noise of the run
        # means themselves, propagated through the weighted least squares, is the u
        noise = _run_noise_se(effort, [r for r, k in zip(runs, ok, strict=True) if k],
                              design(vm), wm**2)
        se = np.where(np.isfinite(noise), noise, se)
    return AxisFrictionFit(
        float(coef[0]), float(coef[1]), float(coef[2]) if both else 0.0, float(se[0]),
        float(se[1]), float(se[2]) if both else float("nan"), int(vm.size), signal, unit,
        tuple(vm.tolist()), tuple(tm.tolist()), tuple((wm**2).tolist()),
    )


FEW_RUNS_DOF = 3
"""Residual degrees of freedom (runs - parameters) below which a friction fit's u is the
propagated noise of its run means, not the bootstrap over runs: a variance estimated with
1-2 degrees of freedom scatters by more than 80 % of itself. Over 24 draws of a production
job (4 runs, benchmarks/bench_production_friction.py) the bootstrap's smallest u was 0.06 of
the error's scatter and its coverage 83-96 % at 1.96 u; the propagated noise: 96-100 %,
rms z 0.69-0.93."""


def _run_noise_se(effort: FloatArray, runs: list[slice], x: FloatArray, w: FloatArray,
                  blocks: int = 8) -> FloatArray:
    """Standard errors of a weighted least-squares fit of run means that the noise within
    the runs alone leaves: each run mean's variance from its batch means (``blocks`` equal
    parts: their scatter keeps the autocorrelated noise and a ripple longer than a sample,
    which the samples' own variance would understate), propagated as
    ``(X'WX)^-1 X'W diag(var) W X (X'WX)^-1`` (W the runs' weights). NaN for a run too short
    to split.

    References
    ----------
    G. S. Fishman, "Discrete-Event Simulation", Springer 2001, §6.6 (batch means).
    """
    var = np.empty(len(runs))
    for k, r in enumerate(runs):
        y = effort[r]
        y = y[np.isfinite(y)]
        m = y.size // blocks
        if m < 2:
            return np.full(x.shape[1], np.nan)
        bm = y[:m * blocks].reshape(blocks, m).mean(axis=1)
        var[k] = float(bm.var(ddof=1)) / blocks
    xtw = x.T * w
    try:
        inv = np.linalg.inv(xtw @ x)
    except np.linalg.LinAlgError:
        return np.full(x.shape[1], np.nan)
    cov = inv @ (xtw * var) @ xtw.T @ inv
    return np.sqrt(np.clip(np.diag(cov), 0.0, None))


STEADY_SMOOTH_CYCLES = 25
"""Window of the actual speed's centered mean that decides whether a friction run has settled
[cycles] (50 ms at 2 ms): wide enough to average the encoder's differentiated noise, short
against the speed loop's settling after a feed change."""


def _centered_mean(x: FloatArray, segs: list[slice], window: int) -> FloatArray:
    """Centered moving mean of ``x`` over ``window`` cycles within each segment (NaN where the
    window leaves the segment or holds a NaN)."""
    out = np.full(x.shape, np.nan)
    h = window // 2
    for s in segs:
        xs = x[s]
        if xs.size < window:
            continue
        ok = np.isfinite(xs)
        cs = np.concatenate([[0.0], np.cumsum(np.where(ok, xs, 0.0))])
        cn = np.concatenate([[0], np.cumsum(ok)])
        full = (cn[window:] - cn[:-window]) == window
        seg_out = np.full(xs.shape, np.nan)
        seg_out[h : xs.size - (window - 1 - h)] = np.where(
            full, (cs[window:] - cs[:-window]) / window, np.nan)
        out[s] = seg_out
    return out


CUT_MARGIN_S = 0.3
"""Time added before and after every cut when runs are excluded [s]: the current's 5 Hz
smoothing and the engagement's fade-in and out (a milled circle's exit tapers over ~0.2 s)."""


def cut_cycles(recording: Recording, *, spindle: str = "SP1",
               margin_s: float = CUT_MARGIN_S) -> tuple[np.ndarray | None, str]:
    """Where the spindle cuts: its current above its air level, with a margin.

    Parameters
    ----------
    recording : Recording
        The recording.
    spindle : str, default 'SP1'
        Spindle axis name.
    margin_s : float, default :data:`CUT_MARGIN_S`
        Added before and after every cut [s].

    Returns
    -------
    mask : numpy.ndarray of bool or None
        Per HF row, True inside a cut (with the margin); None if the recording cannot tell
        (no spindle current).
    why : str
        Without a mask, the reason; else ``""``.

    Notes
    -----
    :func:`cnctwin.analysis.segments.cutting_regions` with the air level per spindle speed
    from the speed's own samples (its 10th percentile: a milling cut does not move Z down, so
    the drilling rule "air = Z not feeding" does not hold) and no Z condition.
    """
    from cnctwin.analysis.segments import cutting_regions

    col = f"CURRENT|{spindle}"
    if not recording.has(col):
        return None, f"{col} is not recorded, so cuts cannot be told from air moves"
    try:
        reg = cutting_regions(recording, spindle=spindle, require_z_down=False,
                              air_from_z=False)
    except CnctwinError as exc:
        return None, f"the cuts of {spindle} could not be found ({exc})"
    cycles = np.asarray(recording.cycles, dtype=np.int64)
    mask = np.zeros(cycles.size, dtype=bool)
    pad = round(margin_s / recording.meta.cycle_time_s)
    for a, b in zip(reg["start_cycle"], reg["end_cycle"], strict=True):
        lo = int(np.searchsorted(cycles, int(a) - pad, side="left"))
        hi = int(np.searchsorted(cycles, int(b) + pad, side="right"))
        mask[lo:hi] = True
    return mask, ""


# ---------------------------------------------------------------------------- orchestration
@dataclass
class AxisIdentification:
    """What could be identified about one axis' position loop, and what not.

    Attributes
    ----------
    axis : str
        Axis name.
    params : dict
        Parameter name -> :class:`Estimate`. Names: ``kv_1_s``, ``kv_m_min_mm``,
        ``kv_command_1_s`` (Kv in CMD_SPEED units when the speed gain is not 1),
        ``ffw_weight``, ``apparent_ffw_weight``, ``lag_time_s`` (steady following error per
        velocity), ``jerk_time_s``, ``jerk_time2_s``, ``jerk_damping``, ``setpoint_delay_s``,
        ``setpoint_pt1_s``, ``setpoint_pt1b_s``, ``ffw_delay_s``, ``speed_loop_time_s``,
        ``speed_loop_delay_s``, ``speed_loop_equiv_time_s``, ``speed_gain``,
        ``coulomb_<signal>``, ``viscous_<signal>``, ``offset_<signal>``, ``reversal_error``.
    ffw_mode : str
        ``"none"``, ``"speed"``, ``"torque"`` or ``"unknown"``.
    jerk_type : str or None
        Chosen jerk-filter model (:data:`JERK_FILTER_TYPES`), None if not identified.
    not_identified : dict
        Parameter -> reason.
    units : dict
        Velocity unit findings per signal (declared, detected, ratio).
    notes : list of str
        Findings worth reading (unit mismatches, outliers excluded, assumptions).
    setpoint : SetpointChainFit or None
    speed_loop : SpeedLoopFit or None
    controller : PositionControllerFit or None
    cycle_time_s : float
        Cycle time [s].
    position_unit : str
        ``"mm"`` or ``"deg"``.
    friction : dict
        ``"CURRENT"`` / ``"TORQUE"`` -> :class:`AxisFrictionFit` (with its runs).
    kv_exact : bool
        Kv comes from the NC's own relation ``CMD_SPEED = Kv (CTRL_POS - ENC_POS) + c VEL_FFW``
        (controller difference recorded) and the steady-state speed gain
        (:func:`steady_speed_gain`): no loop model between the data and Kv, so its standard
        error is the whole uncertainty. False: a regression approximates the unrecorded
        setpoint filter or the gain comes from the fitted speed-loop model; the calibration
        then allows for model error (``cnctwin.calibration.axes.REL_FLOOR``).
    """

    axis: str
    params: dict[str, Estimate] = field(default_factory=dict)
    ffw_mode: str = "unknown"
    jerk_type: str | None = None
    not_identified: dict[str, str] = field(default_factory=dict)
    units: dict[str, dict[str, Any]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    setpoint: SetpointChainFit | None = None
    speed_loop: SpeedLoopFit | None = None
    controller: PositionControllerFit | None = None
    cycle_time_s: float = 0.002
    position_unit: str = "mm"
    friction: dict[str, AxisFrictionFit] = field(default_factory=dict)
    kv_exact: bool = False

    def value(self, name: str) -> float:
        """Value of a parameter; raises IdentificationError with the reason if missing."""
        if name in self.params:
            return self.params[name].value
        reason = self.not_identified.get(name, "not a parameter of this identification")
        raise IdentificationError(f"{self.axis}: {name} not identified: {reason}")

    def rows(self) -> list[tuple[str, float, float, str, str]]:
        """(parameter, value, stderr, unit, method) rows for tables."""
        return [(k, e.value, e.stderr, e.unit, e.method) for k, e in self.params.items()]


def _velocity_factor(d: AxisData, code: str, ref: FloatArray, ident: AxisIdentification) -> float:
    vu = detect_velocity_unit(d.signals[code], ref, declared=d.units.get(code, ""), kind=d.kind)
    ident.units[code] = {"declared": vu.declared, "detected": vu.detected, "ratio": vu.ratio,
                         "decided_by_data": vu.decided_by_data, "lag_cycles": vu.lag_cycles}
    if vu.decided_by_data and vu.detected != vu.declared:
        ident.notes.append(
            f"{code}|{d.axis} is declared in {vu.declared or '?'} but behaves as {vu.detected} "
            f"(ratio {vu.ratio:.4g} to the reference velocity in unit/s); {vu.detected} is used.")
    return vu.factor


def identify_axis(
    recording: Recording,
    axis: str,
    *,
    jerk_models: tuple[str, ...] = JERK_FILTER_TYPES,
    n_bootstrap: int = 200,
    block_cycles: int = 100,
    seed: int = 0,
    fir_cycles: int = 40,
    spindle: str = "SP1",
    exclude_cuts: bool = True,
    cuts: tuple[np.ndarray | None, str] | None = None,
) -> AxisIdentification:
    """Identify the cascade position loop of one axis from production data.

    Parameters
    ----------
    recording : Recording
        Any recording with at least DES_POS and ENC_POS of the axis.
    axis : str
        Axis name.
    jerk_models : tuple of str
        Jerk-filter models to try (:data:`JERK_FILTER_TYPES`).
    n_bootstrap : int, default 200
        Bootstrap resamples for regression uncertainties.
    block_cycles : int, default 100
        Bootstrap block length [cycles].
    seed : int, default 0
        Random seed (results are reproducible).
    fir_cycles : int, default 40
        Without CTRL_POS: length of the setpoint-difference regressors that absorb the
        unrecorded setpoint filter in the Kv regression [cycles].
    spindle : str, default 'SP1'
        The spindle whose current tells cuts from air moves (``exclude_cuts``).
    exclude_cuts : bool, default True
        Leave the constant-velocity runs during which the spindle cuts out of the friction
        fit (:func:`cut_cycles`): a process force on the axis is not friction.
    cuts : (mask, reason), optional
        This recording's :func:`cut_cycles` result, when the caller already has it (the cuts
        belong to the recording, not to an axis: one computation serves every axis).

    Returns
    -------
    AxisIdentification

    Raises
    ------
    IdentificationError
        If DES_POS or ENC_POS is missing or the axis never moves.

    Notes
    -----
    * Kv: with CTRL_DIFF2 (or CTRL_POS): ``CMD_SPEED = a CTRL_DIFF2 + c VEL_FFW``;
      ``Kv = g a`` with the speed-loop gain ``g`` (actual speed / command), ``w = g c k`` with
      ``k`` = VEL_FFW / setpoint velocity. Without CTRL_POS the following error stands in and
      ``c`` mixes the weight with the setpoint lag, so only an apparent weight is reported.
      Without CMD_SPEED and with FFW off: ``v = Kv e`` on constant-velocity runs.
    * Jerk filter, delay and PT1: :func:`fit_setpoint_chain` on DES_POS -> CTRL_POS.
    * Speed loop: :func:`fit_speed_loop` on CMD_SPEED -> d(ENC_POS)/dt.
    * Friction: :func:`fit_axis_friction` on CURRENT and TORQUE, on the constant-velocity
      runs outside the cuts (``exclude_cuts``); too few such runs -> not identified, with what
      to record.
    """
    d = axis_data(recording, axis)
    for code in ("DES_POS", "ENC_POS"):
        if not d.has(code):
            raise IdentificationError(
                f"{code}|{axis} is not in the recording; identification needs DES_POS and "
                f"ENC_POS (it has: {', '.join(sorted(d.signals)) or 'nothing for this axis'})")
    dt = d.cycle_time_s
    sig = d.signals
    pos_u = d.units.get("DES_POS") or ("mm" if d.kind == "linear" else "deg")
    ident = AxisIdentification(axis=axis, cycle_time_s=dt, position_unit=pos_u)
    P = ident.params
    NI = ident.not_identified
    segs = d.segments
    des, enc = sig["DES_POS"], sig["ENC_POS"]
    v_des = derivative(des, segs, dt, kind="central")
    v_act_b = derivative(enc, segs, dt, kind="backward")
    v_act_c = derivative(enc, segs, dt, kind="central")
    if not np.isfinite(v_des).any() or float(np.nanmax(np.abs(v_des))) == 0.0:
        raise IdentificationError(f"DES_POS|{axis} never moves; nothing to identify")
    has_ctrl = d.has("CTRL_POS")
    ctrl = sig["CTRL_POS"] if has_ctrl else None
    if d.has("CTRL_DIFF2"):
        diff: FloatArray | None = sig["CTRL_DIFF2"]
        diff_name = "CTRL_DIFF2"
    elif ctrl is not None:
        diff = ctrl - enc
        diff_name = "CTRL_POS - ENC_POS"
    else:
        diff = None
        diff_name = ""

    # --- setpoint chain (jerk filter, DRA delay, balancing PT1)
    chain: SetpointChainFit | None = None
    if ctrl is not None:
        try:
            chain = fit_setpoint_chain(des, ctrl, segs, cycle_time_s=dt, models=jerk_models)
        except IdentificationError as exc:
            for nm in ("jerk_time_s", "setpoint_delay_s", "setpoint_pt1_s", "setpoint_pt1b_s"):
                NI[nm] = str(exc)
    else:
        for nm in ("jerk_time_s", "setpoint_delay_s", "setpoint_pt1_s", "setpoint_pt1b_s"):
            NI[nm] = ("CTRL_POS is not recorded: the jerk filter, dynamic response adaptation "
                      "and balancing act between DES_POS and CTRL_POS and cannot be separated "
                      "from the loop lag without it")
    if chain is not None:
        ident.setpoint = chain
        ident.jerk_type = chain.jerk_type
        meth = (f"least squares DES_POS->CTRL_POS, models {'/'.join(chain.rms_by_model)}; "
                f"chosen {chain.jerk_type} (rms {chain.rms:.3g} {pos_u})")
        P["jerk_time_s"] = Estimate(chain.jerk_time_s, chain.stderr.get("jerk_time_s", 0.0), "s",
                                    meth)
        if chain.jerk_type == "double_moving_average":
            P["jerk_time2_s"] = Estimate(chain.jerk_time2_s, chain.stderr["jerk_time2_s"], "s",
                                         meth)
        if chain.jerk_type == "pt2":
            P["jerk_damping"] = Estimate(chain.jerk_damping, chain.stderr["jerk_damping"], "-",
                                         meth)
        P["setpoint_delay_s"] = Estimate(chain.delay_s, chain.stderr["delay_s"], "s", meth)
        P["setpoint_pt1_s"] = Estimate(chain.pt1_s, chain.stderr["pt1_s"], "s", meth)
        P["setpoint_pt1b_s"] = Estimate(chain.pt1b_s, chain.stderr["pt1b_s"], "s", meth)

    # --- velocity units
    f_ffw = 1.0
    has_ffw = d.has("VEL_FFW")
    if has_ffw:
        f_ffw = _velocity_factor(d, "VEL_FFW", v_des, ident)
    has_cmd = d.has("CMD_SPEED")
    f_cmd = 1.0
    if has_cmd:
        f_cmd = _velocity_factor(d, "CMD_SPEED", v_act_c, ident)

    # --- speed loop
    sl: SpeedLoopFit | None = None
    steady_gain: tuple[float, float] | None = None
    if has_cmd:
        try:
            sl = fit_speed_loop(sig["CMD_SPEED"] * f_cmd, v_act_b, segs, cycle_time_s=dt)
        except IdentificationError as exc:
            NI["speed_loop_equiv_time_s"] = str(exc)
    else:
        NI["speed_loop_equiv_time_s"] = "CMD_SPEED is not recorded"
    if sl is not None:
        ident.speed_loop = sl
        meth = "least squares CMD_SPEED -> d(ENC_POS)/dt, first order + delay"
        P["speed_gain"] = Estimate(sl.gain, sl.stderr["gain"], "-", meth)
        P["speed_loop_time_s"] = Estimate(sl.time_s, sl.stderr["time_s"], "s", meth)
        P["speed_loop_delay_s"] = Estimate(sl.delay_s, sl.stderr["delay_s"], "s", meth)
        P["speed_loop_equiv_time_s"] = Estimate(
            sl.equivalent_time_s, math.hypot(sl.stderr["time_s"], sl.stderr["delay_s"]), "s",
            meth + " (T + delay)")
        steady = constant_velocity_runs(v_des, segs)
        try:
            g_ss, se_ss, n_ss = steady_speed_gain(
                sig["CMD_SPEED"] * f_cmd, enc, steady,
                lag_cycles=sl.model_delay_cycles + sl.model_time_cycles + 0.5, cycle_time_s=dt)
        except IdentificationError:
            pass
        else:
            P["speed_gain"] = Estimate(
                g_ss, se_ss, "-",
                f"travel / integral of CMD_SPEED delayed by the loop's equivalent time over "
                f"{n_ss} constant-velocity runs; jackknife SE (t-scaled)")
            steady_gain = (g_ss, se_ss)
        if abs(sl.gain - 1.0) > 0.03:
            ident.notes.append(
                f"CMD_SPEED|{axis} is {1 / sl.gain:.4g} x the actual speed in steady state: its "
                f"scale differs from the load velocity (drive normalisation or gear); Kv and the "
                f"weight are referred to the actual speed.")

    # --- FFW velocity timing and scale k (VEL_FFW vs setpoint velocity)
    k_ffw = 1.0
    if has_ffw:
        ffw_s = sig["VEL_FFW"] * f_ffw
        base = des
        if chain is not None and ctrl is not None:
            base = np.full(des.shape, np.nan)
            for s in segs:
                if s.stop - s.start >= 3:
                    base[s] = _jerk(des[s], chain.jerk_type,
                                    np.array([chain.jerk_time_s / dt,
                                              chain.jerk_time2_s / dt if chain.jerk_type
                                              == "double_moving_average" else chain.jerk_damping]))
        v_base = derivative(base, segs, dt, kind="central")
        vb = np.nan_to_num(v_base)
        m = np.isfinite(v_base) & np.isfinite(ffw_s)

        def ffw_cost(tau: float) -> float:
            x = delay(vb, tau)[m]
            den = float(x @ x)
            if den == 0:
                return 1e30
            return float(np.sum((ffw_s[m] - (x @ ffw_s[m]) / den * x) ** 2))

        taus = np.arange(-2.0, 12.0, 0.5)
        t0 = float(taus[int(np.argmin([ffw_cost(t) for t in taus]))])
        res = optimize.minimize_scalar(ffw_cost, bounds=(t0 - 0.5, t0 + 0.5), method="bounded",
                                       options={"xatol": 1e-4})
        tau_f = float(res.x)
        x = delay(vb, tau_f)[m]
        k_ffw = float(x @ ffw_s[m]) / float(x @ x) if float(x @ x) > 0 else float("nan")
        P["ffw_delay_s"] = Estimate(tau_f * dt, float("nan"), "s",
                                    "lag of VEL_FFW behind d(jerk-filtered DES_POS)/dt")

    # --- Kv and weight
    cmd_is_setpoint = False
    g = sl.gain if sl is not None else 1.0
    se_g = sl.stderr["gain"] if sl is not None else 0.0
    if steady_gain is not None:
        g, se_g = steady_gain
    se_g = se_g if math.isfinite(se_g) else 0.0
    if has_cmd:
        cmd_s = sig["CMD_SPEED"] * f_cmd
        ffw_reg = sig["VEL_FFW"] * f_ffw if has_ffw else None
        if ffw_reg is not None and not np.any(np.abs(np.nan_to_num(ffw_reg)) > 0):
            ffw_reg = None
        use_diff = diff if diff is not None else des - enc
        fir_used = False
        pc: PositionControllerFit | None = None
        try:
            if diff is None:
                # first order: DES - CTRL ~ T v is absorbed by the feedforward regressor
                v_reg = ffw_reg if ffw_reg is not None else v_des
                pc = fit_position_controller(cmd_s, use_diff, v_reg, block_cycles=block_cycles,
                                             n_bootstrap=n_bootstrap, seed=seed)
                if pc.a > 3.0 * max(pc.se_a, 0.0) and pc.a > 0.0:
                    # DES - CTRL is a linear filter of DES: absorb it exactly with setpoint
                    # differences DES[k] - DES[k-j], j = 1..fir_cycles (VEL_FFW is such a
                    # combination too and is left out). Kept only if well conditioned.
                    pf = fit_position_controller(
                        cmd_s, use_diff, None, block_cycles=block_cycles,
                        n_bootstrap=n_bootstrap, seed=seed,
                        extra=_setpoint_differences(des, segs, fir_cycles))
                    if pf.a > 0.0 and pf.se_a < 0.02 * pf.a:
                        pc, fir_used = pf, True
                    else:
                        ident.notes.append(
                            f"Kv|{axis}: the setpoint-difference regression is ill conditioned "
                            f"(a = {pf.a:.4g} +- {pf.se_a:.2g}); the first-order regression on "
                            f"the following error and the feedforward is used, Kv is "
                            f"approximate (the setpoint lag is absorbed only as T*v).")
            else:
                pc = fit_position_controller(cmd_s, use_diff, ffw_reg, block_cycles=block_cycles,
                                             n_bootstrap=n_bootstrap, seed=seed)
        except IdentificationError as exc:
            NI["kv_1_s"] = str(exc)
            pc = None
        if pc is not None:
            cm = np.isfinite(cmd_s) & np.isfinite(use_diff)
            contribution = abs(pc.a) * float(np.std(use_diff[cm])) / max(
                float(np.std(cmd_s[cm])), 1e-300)
            if contribution < 1e-3:
                NI["kv_1_s"] = (
                    f"CMD_SPEED|{axis} carries no position-controller correction (the following "
                    f"error explains {contribution:.1e} of its spread): it is a setpoint velocity "
                    f"(e.g. the servo trace's velocity setpoint at the controller input)")
                NI["ffw_weight"] = NI["kv_1_s"]
                cmd_is_setpoint = True
                pc = None
        if pc is not None and pc.n_excluded > pc.n_used:
            NI["kv_1_s"] = (
                f"the P law CMD_SPEED = Kv*e + c*FFW holds on only {pc.n_used} of "
                f"{pc.n_used + pc.n_excluded} samples of {axis} (spindle in speed control, "
                f"modulo positions or inconsistent units); Kv is not reported")
            NI["ffw_weight"] = NI["kv_1_s"]
            cmd_is_setpoint = True
            pc = None
        if pc is not None and not (pc.a > 3.0 * max(pc.se_a, 0.0) and pc.a > 0.0):
            NI["kv_1_s"] = (
                f"CMD_SPEED|{axis} does not follow a P law on the controller difference "
                f"(coefficient {pc.a:.3g} +- {pc.se_a:.2g} 1/s): it is a setpoint velocity "
                f"(e.g. the servo trace's velocity setpoint at the controller input), a "
                f"speed-controlled spindle, or its units are inconsistent")
            NI["ffw_weight"] = NI["kv_1_s"]
            cmd_is_setpoint = True
            pc = None
        if pc is not None:
            ident.controller = pc
            kv = g * pc.a
            se_kv = abs(kv) * math.hypot(pc.se_a / pc.a if pc.a else 0.0, se_g / g if g else 0.0)
            ident.kv_exact = diff is not None and steady_gain is not None
            if diff is not None or not fir_used:
                diff_name = diff_name or "DES_POS-ENC_POS"
                meth = (f"regression CMD_SPEED = a*({diff_name})"
                        f"{' + c*VEL_FFW' if ffw_reg is not None else ''}; Kv = g*a, "
                        f"g = speed gain; block bootstrap SE")
            else:
                meth = (f"regression CMD_SPEED = a*(DES_POS-ENC_POS) + sum_j h_j*(DES[k]-DES[k-j]),"
                        f" j=1..{fir_cycles} (absorbs the unrecorded setpoint filter); Kv = g*a; "
                        f"block bootstrap SE")
            P["kv_1_s"] = Estimate(kv, se_kv, "1/s", meth)
            if abs(g - 1.0) > 0.03:
                P["kv_command_1_s"] = Estimate(
                    pc.a, pc.se_a, "1/s",
                    "Kv in the units of CMD_SPEED (the NC's MD32200 if CMD_SPEED is a load "
                    "velocity): regression coefficient a before the speed-gain correction")
            P["kv_m_min_mm"] = Estimate(kv / KV_PER_S_PER_M_MIN_MM, se_kv / KV_PER_S_PER_M_MIN_MM,
                                        "(m/min)/mm", meth)
            if pc.n_excluded:
                ident.notes.append(
                    f"{pc.n_excluded} of {pc.n_used + pc.n_excluded} samples left out of the Kv "
                    f"regression as outliers (> 6 MAD: speed-controlled spindle, saturation).")
            if diff is None:
                NI["ffw_weight"] = (
                    "CTRL_POS/CTRL_DIFF2 not recorded: the regression on the following error "
                    "gives w - Kv*T_setpoint, the weight and the setpoint lag cannot be "
                    "separated")
            elif ffw_reg is not None:
                w = g * pc.c * k_ffw
                se_w = abs(w) * math.hypot(pc.se_c / pc.c if pc.c else 0.0,
                                           se_g / g if g else 0.0)
                P["ffw_weight"] = Estimate(w, se_w, "-",
                                           "g*c*k from the CMD_SPEED regression (k = "
                                           "VEL_FFW/setpoint velocity)")
            elif diff is not None and ctrl is not None:
                # no VEL_FFW recorded: use the setpoint velocity as FFW regressor
                v_ctrl = derivative(ctrl, segs, dt, kind="central")
                pc2 = fit_position_controller(cmd_s, diff, v_ctrl, block_cycles=block_cycles,
                                              n_bootstrap=n_bootstrap, seed=seed)
                w = g * pc2.c
                P["ffw_weight"] = Estimate(w, abs(g) * pc2.se_c, "-",
                                           "regression on d(CTRL_POS)/dt (VEL_FFW not recorded)")
                P["kv_1_s"] = Estimate(g * pc2.a, abs(g) * pc2.se_a, "1/s", meth)
                ident.kv_exact = False  # d(CTRL_POS)/dt stands in for the unrecorded VEL_FFW
                P["kv_m_min_mm"] = Estimate(g * pc2.a / KV_PER_S_PER_M_MIN_MM,
                                            abs(g) * pc2.se_a / KV_PER_S_PER_M_MIN_MM,
                                            "(m/min)/mm", meth)
            else:
                NI["ffw_weight"] = "neither VEL_FFW nor CTRL_POS recorded"
    else:
        # FFW must be off for v = Kv e; steady runs of the actual speed
        runs = constant_velocity_runs(v_act_c, segs, rel_tol=0.01)
        if has_ffw and np.any(np.abs(np.nan_to_num(sig["VEL_FFW"])) > 0):
            NI["kv_1_s"] = ("CMD_SPEED is not recorded and velocity feedforward is on: the "
                            "steady following error does not reveal Kv")
        elif len(runs) < 2:
            NI["kv_1_s"] = "CMD_SPEED not recorded and fewer than 2 constant-velocity runs"
        elif diff is None:
            # DES_POS - ENC_POS in steady state is v (1/Kv + setpoint-chain lag): the jerk
            # filter and the dynamic response adaptation add their delay (tests: a 7-16 % low
            # "Kv"); only the position controller's own input separates them
            NI["kv_1_s"] = ("CMD_SPEED and CTRL_POS/CTRL_DIFF2 are not recorded: the steady "
                            "following error against DES_POS includes the setpoint chain "
                            "(jerk filter, dynamic response adaptation), so Kv cannot be told "
                            "from it; record CTRL_POS or CMD_SPEED (lag_time_s gives the total)")
        else:
            e = diff
            em = np.array([np.nanmean(e[r]) for r in runs])
            vm = np.array([np.nanmean(v_act_c[r]) for r in runs])
            kv_i = vm / em
            kv = float(np.sum(vm * em) / np.sum(em * em))
            se = float(np.std(kv_i, ddof=1) / math.sqrt(kv_i.size))
            meth = "steady state v = Kv*e on constant-velocity runs (FFW off assumed)"
            P["kv_1_s"] = Estimate(kv, se, "1/s", meth)
            P["kv_m_min_mm"] = Estimate(kv / KV_PER_S_PER_M_MIN_MM, se / KV_PER_S_PER_M_MIN_MM,
                                        "(m/min)/mm", meth)
            ident.notes.append("Kv from v = Kv*e assumes feedforward off (no VEL_FFW/CMD_SPEED).")
        NI.setdefault("ffw_weight", "CMD_SPEED is not recorded")
    if "kv_1_s" in NI:
        NI.setdefault("kv_m_min_mm", NI["kv_1_s"])
    if cmd_is_setpoint:
        ident.notes[:] = [n for n in ident.notes if not n.startswith(f"Kv|{axis}: the setpoint")]
    if cmd_is_setpoint and sl is not None:
        # CMD -> actual speed is then the whole position loop, not the speed loop
        for nm in ("speed_gain", "speed_loop_time_s", "speed_loop_delay_s",
                   "speed_loop_equiv_time_s"):
            P.pop(nm, None)
        NI["speed_loop_equiv_time_s"] = ("CMD_SPEED is a setpoint velocity here; its response "
                                         "is the whole position loop, not the speed loop")
        ident.speed_loop = None

    # --- steady-state lag: following error per velocity on steady runs (always identifiable)
    v_steady = np.where(np.abs(v_act_c - v_des) <= 0.01 * np.abs(v_des), v_act_c, np.nan)
    runs_ss = constant_velocity_runs(v_steady, segs, rel_tol=0.01)
    if len(runs_ss) >= 1:
        fe_all = des - enc
        fe_src = "DES_POS - ENC_POS"
        if d.has("FOLLOWING_ERROR"):
            fe_all = sig["FOLLOWING_ERROR"]  # recorded per servo cycle: better than held ENC
            fe_src = "recorded FOLLOWING_ERROR"
        lag_i = np.array([np.nanmean(fe_all[r]) / np.nanmean(v_act_c[r]) for r in runs_ss])
        lag = float(np.median(lag_i))
        se_lag = (float(np.std(lag_i, ddof=1) / math.sqrt(lag_i.size)) if lag_i.size > 1
                  else float("nan"))
        P["lag_time_s"] = Estimate(
            lag, se_lag, "s", f"steady {fe_src} / velocity on {lag_i.size} runs "
            f"(= (1-w)/Kv + setpoint lag; 1/Kv with FFW off)")
        if "kv_1_s" in P and "ffw_weight" not in P and has_ffw:
            kv_v = P["kv_1_s"].value
            P["apparent_ffw_weight"] = Estimate(
                1.0 - kv_v * lag, abs(kv_v) * se_lag if se_lag == se_lag else float("nan"), "-",
                "1 - Kv*lag_time: the weight minus Kv times the setpoint lag (jerk filter, "
                "balancing), not separable without CTRL_POS")
    else:
        NI["lag_time_s"] = "no run at steady velocity"

    # --- FFW mode
    tq = sig.get("TORQUE_FFW")
    torque_on = tq is not None and bool(np.nanmax(np.abs(np.nan_to_num(tq))) > 0)
    if torque_on:
        ident.ffw_mode = "torque"
    elif "ffw_weight" in P:
        ident.ffw_mode = "speed" if P["ffw_weight"].value > 0.05 else "none"
    elif has_ffw:
        ident.ffw_mode = ("speed" if np.any(np.abs(np.nan_to_num(sig["VEL_FFW"])) > 0)
                          else "none")
    elif "apparent_ffw_weight" in P:
        ident.ffw_mode = "speed"
    if d.has("TORQUE_FFW") and not torque_on:
        ident.notes.append(f"TORQUE_FFW|{axis} is recorded and zero: torque feedforward is off.")

    # --- friction: runs where the setpoint velocity is constant and the *actual* speed has
    # settled on it (no inertia term left); settled is judged on the actual speed averaged
    # over STEADY_SMOOTH_CYCLES, so the measuring noise of the encoder (differentiated over 2
    # cycles: ~0.1 mm/s, more than 1 % of a slow feed) does not cut a stroke into fragments
    v_settled = _centered_mean(v_act_c, segs, STEADY_SMOOTH_CYCLES)
    v_steady = np.where(np.abs(v_settled - v_des) <= 0.01 * np.abs(v_des), v_des, np.nan)
    runs = constant_velocity_runs(v_steady, segs, rel_tol=0.01, drop_first=0.0)
    in_cut = 0
    if exclude_cuts and runs:
        cut, why = cuts if cuts is not None else cut_cycles(recording, spindle=spindle)
        if cut is None:
            ident.notes.append(f"friction of {axis}: {why}; its constant-velocity runs are "
                               "taken as air moves")
        else:
            kept = _outside(runs, cut, min_cycles=40)
            in_cut = sum(1 for r in runs if cut[r].any())
            if in_cut:
                ident.notes.append(
                    f"friction of {axis}: {in_cut} of {len(runs)} constant-velocity runs lie "
                    f"in cuts ({spindle} current above its air level): their parts in the cut "
                    f"are left out, {len(kept)} runs of at least 40 cycles remain")
            runs = kept
    # a position-periodic force (screw ripple) cancels from the Coulomb term only where the
    # two directions cover the same positions: strokes back and forth over one span are cut
    # to it (the smoothing window off both ends: where the speed still settles or the
    # braking begins); any other run loses its first quarter as its transient
    runs = common_position_runs(runs, enc, v_act_c, min_cycles=40,
                                edge_cycles=STEADY_SMOOTH_CYCLES, unpaired_drop_first=0.25)
    for code in ("CURRENT", "TORQUE"):
        if not d.has(code):
            NI[f"coulomb_{code.lower()}"] = f"{code}|{axis} is not recorded"
            continue
        try:
            ff = fit_axis_friction(v_act_c, sig[code], runs, signal=code,
                                   unit=d.units.get(code, ""), n_bootstrap=n_bootstrap,
                                   seed=seed)
        except IdentificationError as exc:
            NI[f"coulomb_{code.lower()}"] = str(exc) + (
                f" outside the cuts ({in_cut} more lie in cuts); record air moves of {axis} "
                "at two or more feeds in both directions (G1 moves clear of the part, or a "
                "test program such as the one of `cnctwin simulate axis_test`)"
                if in_cut else "")
            continue
        ident.friction[code] = ff
        u = ff.unit
        meth = f"{code} = Fc*sign(v) + b*v{' + c' if ff.se_offset == ff.se_offset else ''} on " \
               f"{ff.n_runs} constant-velocity runs (opposite runs at one feed cut to the " \
               f"positions both cover); bootstrap over runs"
        P[f"coulomb_{code.lower()}"] = Estimate(ff.coulomb, ff.se_coulomb, u, meth)
        P[f"viscous_{code.lower()}"] = Estimate(ff.viscous, ff.se_viscous, f"{u}/({pos_u}/s)",
                                                 meth)
        if ff.se_offset == ff.se_offset:
            P[f"offset_{code.lower()}"] = Estimate(ff.offset, ff.se_offset, u, meth)

    # --- reversal (backlash-like) error from CONT_DEV
    if d.has("CONT_DEV"):
        peaks = _reversal_peaks(v_des, sig["CONT_DEV"], segs, dt)
        if peaks.size >= 1:
            se = float(np.std(peaks, ddof=1) / math.sqrt(peaks.size)) if peaks.size > 1 else (
                float("nan"))
            P["reversal_error"] = Estimate(float(np.mean(peaks)), se, pos_u,
                                           f"mean peak |CONT_DEV| within 100 ms after "
                                           f"{peaks.size} velocity reversals")
        else:
            NI["reversal_error"] = "no velocity reversal in the recording"
    else:
        NI["reversal_error"] = "CONT_DEV is not recorded"
    if "ENC_SOURCE" in d.units:
        ident.notes.append(f"no ENC_POS|{axis}: {d.units['ENC_SOURCE']}|{axis} (the measuring "
                           f"system closer to DES_POS) stands in.")
    q = quantum(enc)
    if q > 0:
        ident.notes.append(f"ENC_POS|{axis} is quantized in steps of {q:.3g} {pos_u}.")
    return ident


def _setpoint_differences(des: FloatArray, segs: list[slice], m: int) -> FloatArray:
    out = np.full((des.size, m), np.nan)
    for s in segs:
        x = des[s]
        for j in range(1, m + 1):
            if x.size > j:
                col = np.full(x.size, np.nan)
                col[j:] = x[j:] - x[:-j]
                out[s.start : s.stop, j - 1] = col
    return out


def _reversal_peaks(
    v: FloatArray, cont_dev: FloatArray, segs: list[slice], dt: float
) -> FloatArray:
    vmax = float(np.nanmax(np.abs(v)))
    thr = 0.05 * vmax
    win = max(round(0.1 / dt), 1)
    peaks = []
    for s in segs:
        vs = np.nan_to_num(v[s])
        sign = np.where(vs > thr, 1, np.where(vs < -thr, -1, 0))
        nz = np.flatnonzero(sign)
        for i, j in itertools.pairwise(nz):
            if sign[i] != sign[j] and j - i < int(0.5 / dt):
                lo = s.start + i
                hi = min(s.start + j + win, s.stop)
                seg = cont_dev[lo:hi]
                if np.isfinite(seg).any():
                    peaks.append(float(np.nanmax(np.abs(seg))))
    return np.asarray(peaks)
