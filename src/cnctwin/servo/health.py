"""Machine condition from production data: an axis' loop and mechanics tracked over time.

No test program: ordinary production recordings are cut into windows, each window is
identified with the existing estimators (:func:`~cnctwin.servo.identify.identify_axis` for Kv,
the speed loop and the reversal error; :func:`fit_friction_per_direction` for Coulomb and
viscous friction per direction; the :class:`~cnctwin.servo.predict.AxisLoopModel` of a
reference window for the prediction residual), and every parameter is compared with a baseline
by tests that use the identification's standard errors.

Layers (pvlib-like):

* pure functions: :func:`split_windows`, :func:`fit_friction_per_direction`,
  :func:`residual_ratio`, :func:`baseline_parameter` (random-effects mean),
  :func:`z_score`;
* description/result dataclasses: :class:`HealthWindow`, :class:`BaselineParameter`,
  :class:`ParameterTest`, :class:`HealthAlarm`, :class:`HealthResult`;
* orchestration: :func:`identify_window`, :class:`LoopHealthMonitor` (online, one window at a
  time, as on the edge) and :func:`track_loop_health` (recordings in, result out).

Windows in which a parameter cannot be identified (no motion, one speed per direction, no
reversal, ...) carry the reason in ``HealthWindow.not_identified`` and are skipped by the tests of
that parameter; nothing is filled in.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd

from cnctwin.exceptions import ConfigError, IdentificationError
from cnctwin.recording import Recording
from cnctwin.servo._common import FloatArray, axis_data, derivative
from cnctwin.servo.identify import (
    JERK_FILTER_TYPES,
    AxisIdentification,
    Estimate,
    _ess_inflation,
    constant_velocity_runs,
    identify_axis,
)
from cnctwin.servo.predict import AxisLoopModel, prediction_residual

__all__ = [
    "DEFAULT_MAX_REL_STDERR",
    "DEFAULT_REL_FLOORS",
    "HEALTH_PARAMETERS",
    "BaselineParameter",
    "DirectionalFriction",
    "HealthAlarm",
    "HealthResult",
    "HealthWindow",
    "LoopHealthMonitor",
    "ParameterTest",
    "baseline_parameter",
    "fit_friction_per_direction",
    "identify_window",
    "residual_ratio",
    "split_windows",
    "track_loop_health",
    "z_score",
]

HEALTH_PARAMETERS: tuple[str, ...] = (
    "kv_1_s", "speed_loop_equiv_time_s", "coulomb_pos", "coulomb_neg", "viscous_pos",
    "viscous_neg", "reversal_error", "residual_ratio",
)
"""Parameters tested by default (names of :attr:`HealthWindow.params`)."""

DEFAULT_REL_FLOORS: Mapping[str, float] = {
    "kv_1_s": 0.01, "speed_loop_equiv_time_s": 0.03, "coulomb_pos": 0.02, "coulomb_neg": 0.02,
    "viscous_pos": 0.05, "viscous_neg": 0.05, "reversal_error": 0.05, "residual_ratio": 0.05,
}
"""Relative uncertainty floors [-] added in quadrature to every test: a machine's parameters are
not constant to better than this between production windows (temperature, lubrication), and
identification on near noise-free data reports standard errors far below it [E]."""

DEFAULT_MAX_REL_STDERR: Mapping[str, float] = {
    "kv_1_s": 0.1, "speed_loop_equiv_time_s": 0.5, "coulomb_pos": 0.5, "coulomb_neg": 0.5,
}
"""Largest relative standard error [-] for a window estimate to be used: beyond it the window
did not excite the parameter (e.g. a P law fitted on a setpoint velocity, Kv 0.19 +- 0.03 1/s on
the servo trace's braking test) [E]."""

_POSITION_SIGNALS = ("DES_POS", "ENC_POS", "ENC1_POS", "ENC2_POS", "CTRL_POS", "CTRL_DIFF2",
                     "CONT_DEV", "VEL_FFW", "TORQUE_FFW", "CMD_SPEED", "CURRENT", "TORQUE",
                     "FOLLOWING_ERROR")


# ---------------------------------------------------------------------------- pure functions
def split_windows(recording: Recording, *, window_s: float) -> list[Recording]:
    """Cut a recording into consecutive windows of about ``window_s`` seconds.

    Parameters
    ----------
    recording : Recording
        Any recording.
    window_s : float
        Target window length [s]; the recording is split into ``max(1, round(T / window_s))``
        windows of equal duration ``T / n`` (no remainder is dropped).

    Returns
    -------
    list of Recording
        Windows in time order (each a :meth:`Recording.select` of a cycle range).
    """
    if not window_s > 0:
        raise ConfigError(f"window_s must be > 0 s, got {window_s}")
    n_cyc = recording.n_cycles
    if n_cyc == 0:
        return []
    t = recording.time_s
    dur = float(t[-1] - t[0]) + recording.meta.cycle_time_s
    n = max(1, round(dur / window_s))
    # half a cycle below each edge: float times on the cycle grid do not fall on either side
    edges = t[0] + dur * np.arange(n + 1) / n - 0.5 * recording.meta.cycle_time_s
    cyc = recording.cycles
    out = []
    for i in range(n):
        idx = np.flatnonzero((t >= edges[i]) & ((t < edges[i + 1]) if i < n - 1 else True))
        if idx.size:
            out.append(recording.select(cycles=(int(cyc[idx[0]]), int(cyc[idx[-1]]))))
    return out


@dataclass(frozen=True)
class DirectionalFriction:
    """Coulomb and viscous friction per direction of travel.

    Attributes
    ----------
    params : dict
        ``coulomb_pos``, ``viscous_pos``, ``coulomb_neg``, ``viscous_neg`` ->
        :class:`~cnctwin.servo.identify.Estimate` (those that could be identified).
        Coulomb levels are magnitudes [signal unit]; viscous slopes [signal unit per unit/s].
    not_identified : dict
        Parameter -> reason.
    n_runs_pos, n_runs_neg : int
        Constant-velocity runs used per direction.
    signal, unit : str
        Effort signal (``CURRENT`` or ``TORQUE``) and its unit.
    """

    params: dict[str, Estimate]
    not_identified: dict[str, str]
    n_runs_pos: int
    n_runs_neg: int
    signal: str
    unit: str


def _run_stats(effort: FloatArray, runs: list[slice]) -> tuple[FloatArray, FloatArray]:
    """Mean and standard error (AR(1)-inflated) of the effort over each run."""
    means, ses = [], []
    for r in runs:
        x = effort[r]
        x = x[np.isfinite(x)]
        if x.size < 5:
            means.append(np.nan)
            ses.append(np.nan)
            continue
        m = float(np.mean(x))
        means.append(m)
        ses.append(float(np.std(x, ddof=1)) / math.sqrt(x.size) * math.sqrt(_ess_inflation(x - m)))
    return np.asarray(means), np.asarray(ses)


def fit_friction_per_direction(
    v_per_s: FloatArray, effort: FloatArray, runs: list[slice], *, signal: str, unit: str,
    position_unit: str = "mm", min_speed_ratio: float = 1.2,
) -> DirectionalFriction:
    """Fit ``effort = +-Fc + b v`` separately for positive and negative velocity.

    Parameters
    ----------
    v_per_s : numpy.ndarray
        Actual velocity [unit/s].
    effort : numpy.ndarray
        CURRENT [A] or TORQUE [N, Nm].
    runs : list of slice
        Constant-velocity runs (:func:`~cnctwin.servo.identify.constant_velocity_runs`).
    signal, unit : str
        Name and unit of ``effort``.
    position_unit : str, default 'mm'
        Position unit (for the unit of the viscous slope).
    min_speed_ratio : float, default 1.2
        The fastest and slowest run of a direction must differ by this factor, else Coulomb and
        viscous cannot be separated in that direction and are reported as not identified.

    Returns
    -------
    DirectionalFriction

    Notes
    -----
    Positive direction ``tau = Fc+ + b+ v``, negative ``tau = -Fc- + b- v`` (Coulomb + viscous
    per direction, the quantities of the AMM universal axis test, docs/reference/peers.md §1.1). A
    weight
    offset of a vertical axis adds to ``Fc+`` and subtracts from ``Fc-``. Weighted least
    squares on run means with their within-run standard errors (AR(1)-inflated);
    the covariance is scaled by the reduced chi-square when it exceeds 1 (scatter of the runs
    beyond their noise, e.g. a Stribeck or temperature effect).
    """
    means, ses = _run_stats(effort, runs)
    vm = np.array([np.nanmean(v_per_s[r]) for r in runs]) if runs else np.array([])
    ok = np.isfinite(vm) & np.isfinite(means) & np.isfinite(ses)
    vm, means, ses = vm[ok], means[ok], ses[ok]
    params: dict[str, Estimate] = {}
    ni: dict[str, str] = {}
    counts = {}
    for tag, sgn in (("pos", 1.0), ("neg", -1.0)):
        sel = (vm * sgn) > 0
        counts[tag] = int(sel.sum())
        v, y, s = vm[sel], means[sel], ses[sel]
        speeds = np.abs(v)
        if v.size == 0:
            reason = f"no constant-velocity run in the {'+' if sgn > 0 else '-'} direction"
        elif speeds.max() < min_speed_ratio * speeds.min():
            reason = (f"{v.size} constant-velocity run(s) in the {'+' if sgn > 0 else '-'} "
                      f"direction, all near {np.median(speeds):.4g} {position_unit}/s: Coulomb "
                      f"and viscous friction need two speeds (ratio >= {min_speed_ratio})")
        else:
            reason = ""
        if reason:
            ni[f"coulomb_{tag}"] = ni[f"viscous_{tag}"] = reason
            continue
        floor = 1e-9 * max(float(np.max(np.abs(y))), 1e-300)
        w = 1.0 / np.maximum(s, floor) ** 2
        x = np.column_stack([np.full(v.size, sgn), v])
        xtw = x.T * w
        cov = np.linalg.inv(xtw @ x)
        coef = cov @ (xtw @ y)
        dof = v.size - 2
        if dof > 0:
            chi2 = float(np.sum(w * (y - x @ coef) ** 2)) / dof
            cov = cov * max(chi2, 1.0)
        se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        meth = (f"WLS of {signal} run means on {v.size} constant-velocity runs "
                f"({'+' if sgn > 0 else '-'} direction, {speeds.min():.4g}-{speeds.max():.4g} "
                f"{position_unit}/s)")
        params[f"coulomb_{tag}"] = Estimate(float(coef[0]), float(se[0]), unit, meth)
        params[f"viscous_{tag}"] = Estimate(float(coef[1]), float(se[1]),
                                            f"{unit}/({position_unit}/s)", meth)
    return DirectionalFriction(params, ni, counts["pos"], counts["neg"], signal, unit)


def residual_ratio(
    model: AxisLoopModel, recording: Recording, axis: str, *, block_s: float = 1.0
) -> Estimate:
    """RMS of the loop model's ENC_POS prediction error relative to the following error.

    Parameters
    ----------
    model : AxisLoopModel
        Reference loop model.
    recording : Recording
        Window with DES_POS and ENC_POS of ``axis``.
    axis : str
        Axis name.
    block_s : float, default 1.0
        Block length of the jackknife [s].

    Returns
    -------
    Estimate
        ``rms(ENC_POS - predicted) / rms(DES_POS - ENC_POS)`` [-] with a delete-one-block
        jackknife standard error.

    Notes
    -----
    :func:`~cnctwin.servo.predict.prediction_residual` drives the model with the recorded
    DES_POS; a loop that changed (Kv, speed loop, friction) no longer matches the prediction
    and the ratio grows. Jackknife over blocks (Efron & Stein 1981) keeps the error
    autocorrelation inside each block.
    """
    with warnings.catch_warnings():
        # a window without a predictable run gives an empty mean (checked below)
        warnings.simplefilter("ignore", RuntimeWarning)
        _, _, res = prediction_residual(model, recording, axis)
    d = axis_data(recording, axis)
    fe = d.signals["DES_POS"] - d.signals["ENC_POS"]
    ok = np.isfinite(res) & np.isfinite(fe)
    if ok.sum() < 10:
        raise IdentificationError(f"too few predicted samples of {axis} for the residual ratio")
    r2, f2 = res[ok] ** 2, fe[ok] ** 2
    if float(f2.sum()) == 0.0:
        raise IdentificationError(f"{axis} has no following error in the window (no motion)")
    ratio = math.sqrt(float(r2.sum()) / float(f2.sum()))
    blk = max(round(block_s / d.cycle_time_s), 10)
    nb = r2.size // blk
    se = float("nan")
    if nb >= 3:
        rb = np.add.reduceat(r2[: nb * blk], np.arange(0, nb * blk, blk))
        fb = np.add.reduceat(f2[: nb * blk], np.arange(0, nb * blk, blk))
        rest_r, rest_f = float(r2[nb * blk:].sum()), float(f2[nb * blk:].sum())
        tot_r, tot_f = float(rb.sum()) + rest_r, float(fb.sum()) + rest_f
        loo = np.sqrt(np.clip((tot_r - rb) / np.maximum(tot_f - fb, 1e-300), 0.0, None))
        se = float(math.sqrt((nb - 1) / nb * float(np.sum((loo - loo.mean()) ** 2))))
    return Estimate(ratio, se, "-", "rms(ENC_POS - AxisLoopModel prediction) / rms(DES_POS - "
                                    "ENC_POS), reference model; block jackknife SE")


@dataclass(frozen=True)
class BaselineParameter:
    """Baseline of one parameter (random-effects mean of the baseline windows).

    Attributes
    ----------
    name, unit : str
        Parameter and unit.
    mean : float
        Baseline value [unit].
    stderr_mean : float
        Standard error of the baseline value [unit].
    tau : float
        Between-window standard deviation beyond the windows' own standard errors [unit]
        (0 for a reference identification or a single window).
    rel_floor : float
        Relative floor used in the tests [-].
    n_windows : int
        Windows (or reference identifications) behind the baseline.
    source : str
        ``"windows 0-4"`` or ``"reference"``.
    """

    name: str
    unit: str
    mean: float
    stderr_mean: float
    tau: float
    rel_floor: float
    n_windows: int
    source: str

    @property
    def band(self) -> float:
        """Standard deviation expected for a new window without its own SE [unit]."""
        return math.sqrt(self.tau**2 + self.stderr_mean**2 + (self.rel_floor * self.mean) ** 2)


def baseline_parameter(
    estimates: Sequence[Estimate], *, name: str, rel_floor: float = 0.0, source: str = ""
) -> BaselineParameter:
    """Random-effects mean of a parameter over baseline windows.

    Parameters
    ----------
    estimates : sequence of Estimate
        The parameter in each baseline window (value and standard error).
    name : str
        Parameter name.
    rel_floor : float, default 0
        Relative floor for the tests [-] (stored, not used in the mean).
    source : str
        Description of where the baseline comes from.

    Returns
    -------
    BaselineParameter

    Notes
    -----
    DerSimonian-Laird estimator (DerSimonian & Laird, Controlled Clinical Trials 7 (1986)
    177-188, doi:10.1016/0197-2456(86)90046-2): fixed-effect weights ``w = 1/s^2``,
    ``Q = sum w (x - x_fe)^2``, ``tau^2 = max(0, (Q - (k-1)) / (sum w - sum w^2 / sum w))``,
    then ``mean = sum w* x / sum w*`` with ``w* = 1/(s^2 + tau^2)`` and SE ``(sum w*)^-1/2``.
    Windows without a finite SE make it the plain mean with the sample standard deviation as
    ``tau``.
    """
    x = np.array([e.value for e in estimates], dtype=float)
    s = np.array([e.stderr for e in estimates], dtype=float)
    ok = np.isfinite(x)
    x, s = x[ok], s[ok]
    k = x.size
    if k == 0:
        raise IdentificationError(f"no baseline value of {name}")
    unit = estimates[0].unit
    if k == 1:
        se0 = float(s[0]) if math.isfinite(float(s[0])) else 0.0
        return BaselineParameter(name, unit, float(x[0]), se0, 0.0, rel_floor, 1, source)
    if not np.all(np.isfinite(s)) or np.any(s <= 0):
        sd = float(np.std(x, ddof=1))
        return BaselineParameter(name, unit, float(np.mean(x)), sd / math.sqrt(k), sd,
                                 rel_floor, k, source)
    w = 1.0 / s**2
    x_fe = float(np.sum(w * x) / np.sum(w))
    q = float(np.sum(w * (x - x_fe) ** 2))
    c = float(np.sum(w) - np.sum(w**2) / np.sum(w))
    tau2 = max(0.0, (q - (k - 1)) / c) if c > 0 else 0.0
    ws = 1.0 / (s**2 + tau2)
    mean = float(np.sum(ws * x) / np.sum(ws))
    return BaselineParameter(name, unit, mean, float(1.0 / math.sqrt(np.sum(ws))),
                             math.sqrt(tau2), rel_floor, k, source)


def z_score(estimate: Estimate, baseline: BaselineParameter) -> tuple[float, float]:
    """Standardised distance of a window's estimate from the baseline.

    Parameters
    ----------
    estimate : Estimate
        A window's estimate with its standard error.
    baseline : BaselineParameter
        The baseline of the parameter.

    Returns
    -------
    z : float
        ``(x - mean) / sigma`` [-].
    sigma : float
        ``sqrt(s^2 + stderr_mean^2 + tau^2 + (rel_floor * mean)^2)`` [unit].

    Notes
    -----
    Under no change, ``x - mean`` has the variance of the window's estimate (its SE), of the
    baseline mean, and of the between-window variation (``tau``, floored by ``rel_floor``).
    """
    se = estimate.stderr if math.isfinite(estimate.stderr) else 0.0
    sigma = math.sqrt(se**2 + baseline.band**2)
    if sigma == 0.0:
        return (0.0 if estimate.value == baseline.mean else math.inf), 0.0
    return (estimate.value - baseline.mean) / sigma, sigma


def _p_two_sided(z: float) -> float:
    return math.erfc(abs(z) / math.sqrt(2.0)) if math.isfinite(z) else 0.0


# ---------------------------------------------------------------------------- results
@dataclass(frozen=True)
class HealthWindow:
    """What one window tells about the axis.

    Attributes
    ----------
    index : int
        Window number in the sequence (0-based).
    label : str
        ``"<source>#<k>"`` (source file or label, window within it).
    source : str
        Recording label.
    start_time : pandas.Timestamp or None
        UTC time of the first cycle.
    duration_s : float
        Window length [s].
    n_cycles : int
        Cycles in the window.
    params : dict
        Parameter -> :class:`~cnctwin.servo.identify.Estimate`: ``kv_1_s``,
        ``speed_loop_equiv_time_s``, ``speed_loop_bandwidth_hz`` (= 1/(2 pi T_eq), derived),
        ``coulomb_pos/neg``, ``viscous_pos/neg`` (effort signal in ``effort_signal``),
        ``reversal_error``, ``residual_ratio``.
    not_identified : dict
        Parameter -> reason (not enough excitation, signal missing, ...).
    effort_signal : str
        ``CURRENT`` or ``TORQUE`` (friction), ``""`` if neither.
    identification : AxisIdentification or None
        The window's full identification (None when the axis did not move).
    """

    index: int
    label: str
    source: str
    start_time: pd.Timestamp | None
    duration_s: float
    n_cycles: int
    params: dict[str, Estimate]
    not_identified: dict[str, str]
    effort_signal: str = ""
    identification: AxisIdentification | None = field(default=None, repr=False)

    @property
    def excited(self) -> bool:
        """Whether anything was identified in the window."""
        return bool(self.params)


@dataclass(frozen=True)
class ParameterTest:
    """Test of one parameter in one window against the baseline.

    Attributes
    ----------
    window_index : int
    parameter : str
    value, stderr : float
        Window estimate and its SE [unit].
    baseline : float
        Baseline value [unit].
    sigma : float
        Standard deviation of ``value - baseline`` under no change [unit].
    z : float
        ``(value - baseline) / sigma`` [-].
    p_value : float
        Two-sided normal p-value of ``z``.
    cusum_pos, cusum_neg : float
        Two-sided CUSUM of ``z`` after this window (0 in the baseline) [-].
    in_baseline : bool
        The window belongs to the baseline period (not tested).
    """

    window_index: int
    parameter: str
    value: float
    stderr: float
    baseline: float
    sigma: float
    z: float
    p_value: float
    cusum_pos: float
    cusum_neg: float
    in_baseline: bool


@dataclass(frozen=True)
class HealthAlarm:
    """A parameter that drifted from its baseline.

    Attributes
    ----------
    axis, parameter, unit : str
    test : str
        ``"z"`` (one window beyond ``z_alarm``) or ``"cusum"`` (sustained shift beyond
        ``cusum_h``).
    window_index : int
        Window at which the alarm fired.
    onset_index : int
        Estimated first changed window (the window itself for ``z``; for ``cusum`` the window
        after the CUSUM last left zero).
    window_label, onset_label : str
    baseline : float
        Baseline value [unit].
    value : float
        Window value (``z``) or mean over onset..alarm windows (``cusum``) [unit].
    change, relative_change : float
        ``value - baseline`` [unit] and ``change / |baseline|`` [-].
    z : float
        Window z (``z``) or Stouffer's ``sum z / sqrt(m)`` over the m windows since the onset
        (``cusum``) [-].
    p_value : float
        Two-sided normal p-value of ``z``.
    confidence : float
        ``1 - p_value``.
    """

    axis: str
    parameter: str
    unit: str
    test: str
    window_index: int
    onset_index: int
    window_label: str
    onset_label: str
    baseline: float
    value: float
    change: float
    relative_change: float
    z: float
    p_value: float
    confidence: float

    def describe(self) -> str:
        """One line for reports."""
        return (f"{self.axis} {self.parameter}: {self.baseline:.5g} -> {self.value:.5g} "
                f"{self.unit} ({100 * self.relative_change:+.1f} %), z = {self.z:+.1f}, "
                f"p = {self.p_value:.1e}, {self.test} test, from window {self.onset_index} "
                f"({self.onset_label}), alarm at window {self.window_index}")


@dataclass
class HealthResult:
    """Loop health of one axis over a sequence of windows.

    Attributes
    ----------
    axis : str
    windows : list of HealthWindow
    baseline : dict
        Parameter -> :class:`BaselineParameter` (parameters without a baseline are absent and
        listed in ``no_baseline``).
    tests : dict
        Parameter -> list of :class:`ParameterTest` (windows where it was identified).
    alarms : list of HealthAlarm
    no_baseline : dict
        Parameter -> reason.
    settings : dict
        Test settings (z_alarm, cusum_k, cusum_h, baseline_windows, window_s, rel_floors).
    notes : list of str
        Findings worth reading (reference model, rejected models).
    """

    axis: str
    windows: list[HealthWindow] = field(default_factory=list)
    baseline: dict[str, BaselineParameter] = field(default_factory=dict)
    tests: dict[str, list[ParameterTest]] = field(default_factory=dict)
    alarms: list[HealthAlarm] = field(default_factory=list)
    no_baseline: dict[str, str] = field(default_factory=dict)
    settings: dict[str, object] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def series(self, parameter: str) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(window index, value, stderr) of one parameter (identified windows only)."""
        rows = [(w.index, w.params[parameter].value, w.params[parameter].stderr)
                for w in self.windows if parameter in w.params]
        if not rows:
            return np.array([]), np.array([]), np.array([])
        a = np.asarray(rows, dtype=float)
        return a[:, 0], a[:, 1], a[:, 2]

    def alarms_for(self, parameter: str) -> list[HealthAlarm]:
        """Alarms of one parameter."""
        return [a for a in self.alarms if a.parameter == parameter]


# ---------------------------------------------------------------------------- orchestration
def identify_window(
    recording: Recording, axis: str, *, index: int = 0, source: str = "", label: str = "",
    model: AxisLoopModel | None = None, setpoint_chain: bool = True, effort_signal: str = "auto",
    jerk_models: tuple[str, ...] = JERK_FILTER_TYPES, min_travel: float = 0.5,
    max_rel_stderr: Mapping[str, float] | None = None, n_bootstrap: int = 50, seed: int = 0,
) -> HealthWindow:
    """Identify the health parameters of one axis in one window.

    Parameters
    ----------
    recording : Recording
        The window.
    axis : str
        Axis name.
    index : int
        Window number in the sequence.
    source, label : str
        Recording label and window label.
    model : AxisLoopModel, optional
        Reference model for ``residual_ratio``; without it the residual is not computed.
    setpoint_chain : bool, default True
        Fit the jerk filter/setpoint chain (DES_POS -> CTRL_POS, ~95 % of the identification
        time). NC machine data, not machine condition: only the window that builds the
        reference model needs it.
    effort_signal : {'auto', 'CURRENT', 'TORQUE'}
        Friction signal; ``auto`` prefers CURRENT (the drive's measured current), then TORQUE.
    jerk_models : tuple of str
        Jerk-filter models tried by the setpoint-chain fit
        (:data:`~cnctwin.servo.identify.JERK_FILTER_TYPES`; restrict it when MD32402 is known:
        the PT2 and double-MA fits take most of the time).
    min_travel : float, default 0.5
        Least peak-to-peak travel of DES_POS for the window to count as excited [mm or deg];
        below it every parameter is reported as not identified (a creeping or parked axis
        gives a Kv regression on quantization noise).
    max_rel_stderr : mapping, optional
        Largest relative standard error per parameter (:data:`DEFAULT_MAX_REL_STDERR`); a
        less certain estimate is reported as not identified with its value and SE.
    n_bootstrap : int, default 50
        Bootstrap resamples of the regressions.
    seed : int, default 0
        Random seed.

    Returns
    -------
    HealthWindow
    """
    if effort_signal not in ("auto", "CURRENT", "TORQUE"):
        raise ConfigError(f"effort_signal must be 'auto', 'CURRENT' or 'TORQUE', got "
                          f"{effort_signal!r}")
    keep = [s for s in _POSITION_SIGNALS if setpoint_chain or s != "CTRL_POS"]
    rec = recording.select(axes=[axis], signals=keep)
    start = rec.hf["time"].iloc[0] if rec.n_cycles else None
    dur = rec.n_cycles * rec.meta.cycle_time_s
    params: dict[str, Estimate] = {}
    ni: dict[str, str] = {}
    base = {"index": index, "label": label or f"{source}#{index}", "source": source,
            "start_time": start, "duration_s": dur, "n_cycles": rec.n_cycles}
    des_col = f"DES_POS|{axis}"
    des_w = (rec.hf[des_col].to_numpy(dtype=np.float64) if des_col in rec.hf.columns
             else np.array([np.nan]))
    travel = float(np.nanmax(des_w) - np.nanmin(des_w)) if np.isfinite(des_w).any() else 0.0
    try:
        if travel < min_travel:
            unit = rec.meta.units.get(des_col, "")
            raise IdentificationError(
                f"not enough excitation: DES_POS|{axis} travels {travel:.3g} {unit} in the "
                f"window (< min_travel {min_travel:g})" if des_col in rec.hf.columns
                else f"DES_POS|{axis} is not recorded")
        ident = identify_axis(rec, axis, n_bootstrap=n_bootstrap, seed=seed,
                              jerk_models=jerk_models)
    except IdentificationError as exc:
        reason = f"not identified in this window: {exc}"
        return HealthWindow(**base, params={},  # type: ignore[arg-type]
                            not_identified={p: reason for p in HEALTH_PARAMETERS})
    limits = {**DEFAULT_MAX_REL_STDERR, **dict(max_rel_stderr or {})}
    for name in ("kv_1_s", "speed_loop_equiv_time_s", "reversal_error"):
        if name in ident.params:
            params[name] = ident.params[name]
        else:
            ni[name] = ident.not_identified.get(name, "not identified")
    if "speed_loop_equiv_time_s" in params:
        te = params["speed_loop_equiv_time_s"]
        if te.value > 0:
            bw = 1.0 / (2.0 * math.pi * te.value)
            params["speed_loop_bandwidth_hz"] = Estimate(
                bw, bw * te.stderr / te.value, "Hz", "1/(2 pi T_eq) of the speed-loop "
                                                     "equivalent time")
    # friction per direction on runs where the actual speed is steady
    d = axis_data(rec, axis)
    dt = d.cycle_time_s
    segs = d.segments
    des, enc = d.signals["DES_POS"], d.signals["ENC_POS"]
    v_des = derivative(des, segs, dt, kind="central")
    v_act = derivative(enc, segs, dt, kind="central")
    choices = ("CURRENT", "TORQUE") if effort_signal == "auto" else (effort_signal,)
    code = next((c for c in choices if d.has(c)), "")
    pos_u = ident.position_unit
    if not code:
        for nm in ("coulomb_pos", "coulomb_neg", "viscous_pos", "viscous_neg"):
            ni[nm] = f"{' or '.join(choices)}|{axis} is not recorded"
    else:
        with np.errstate(invalid="ignore"):
            v_steady = np.where(np.abs(v_act - v_des) <= 0.01 * np.abs(v_des), v_act, np.nan)
        runs = constant_velocity_runs(v_steady, segs, rel_tol=0.01)
        fr = fit_friction_per_direction(v_act, d.signals[code], runs, signal=code,
                                        unit=d.units.get(code, ""), position_unit=pos_u)
        params.update(fr.params)
        ni.update(fr.not_identified)
    for name, lim in limits.items():
        e = params.get(name)
        if e is None:
            continue
        rel = e.stderr / abs(e.value) if e.value else math.inf
        if math.isfinite(e.stderr) and rel > lim:
            del params[name]
            ni[name] = (f"too uncertain in this window: {e.value:.4g} +- {e.stderr:.2g} {e.unit} "
                        f"(relative SE {rel:.2g} > {lim:g}); not enough excitation or the "
                        f"model does not hold")
            if name == "speed_loop_equiv_time_s":
                params.pop("speed_loop_bandwidth_hz", None)
    if model is not None:
        try:
            params["residual_ratio"] = residual_ratio(model, rec, axis)
        except IdentificationError as exc:
            ni["residual_ratio"] = str(exc)
    else:
        ni["residual_ratio"] = "no reference loop model (Kv not identified in a reference window)"
    return HealthWindow(**base, params=params, not_identified=ni,  # type: ignore[arg-type]
                        effort_signal=code, identification=ident)


@dataclass
class LoopHealthMonitor:
    """Online loop-health monitor of one axis: feed windows one at a time.

    The first ``baseline_windows`` windows form the baseline (or a given reference); every
    later window is tested per parameter with a z test and a two-sided CUSUM of the z values.

    Parameters
    ----------
    axis : str
        Axis name.
    baseline_windows : int, default 5
        Windows in the baseline period.
    min_baseline : int, default 2
        Identified windows a parameter needs in the baseline period to be tested.
    parameters : tuple of str
        Parameters tested (:data:`HEALTH_PARAMETERS`).
    z_alarm : float, default 5
        Single-window alarm threshold on ``|z|``.
    cusum_k, cusum_h : float, default 0.5, 8
        CUSUM reference value and decision interval [z units].
    rel_floors : mapping, optional
        Relative floors per parameter (:data:`DEFAULT_REL_FLOORS`).
    reference : sequence of HealthWindow, optional
        Windows of an earlier period used as the baseline instead of the first windows.
    model : AxisLoopModel, optional
        Reference loop model, kept here for the caller (:func:`track_loop_health` sets it from
        the first window that yields a model fitting its own window).

    Notes
    -----
    z test: alarm when ``|z| > z_alarm`` (normal two-sided p = 5.7e-7 at 5; the estimated
    between-window spread makes the real tail heavier, hence the high threshold).
    CUSUM (Page 1954, Biometrika 41:100-115, doi:10.1093/biomet/41.1-2.100):
    ``S+ = max(0, S+ + z - k)``, ``S- = max(0, S- - z - k)``, alarm when either exceeds ``h``;
    with k = 0.5, h = 8 the in-control average run length is ~9500 windows per parameter
    (Siegmund's approximation), detection of a 2-sigma shift takes ~6 windows.
    After an alarm the parameter is latched (no repeated alarm) until a window is back within
    ``|z| < 2``; then both sums restart at 0.
    """

    axis: str
    baseline_windows: int = 5
    min_baseline: int = 2
    parameters: tuple[str, ...] = HEALTH_PARAMETERS
    z_alarm: float = 5.0
    cusum_k: float = 0.5
    cusum_h: float = 8.0
    rel_floors: Mapping[str, float] | None = None
    reference: Sequence[HealthWindow] | None = None
    model: AxisLoopModel | None = None
    result: HealthResult = field(init=False)
    _state: dict[str, dict[str, float]] = field(init=False, default_factory=dict)

    def __post_init__(self) -> None:
        self.result = HealthResult(axis=self.axis, settings={
            "z_alarm": self.z_alarm, "cusum_k": self.cusum_k, "cusum_h": self.cusum_h,
            "baseline_windows": self.baseline_windows, "min_baseline": self.min_baseline,
            "rel_floors": dict(self.floors)})
        if self.reference is not None:
            self._make_baseline(list(self.reference), "reference")

    @property
    def floors(self) -> dict[str, float]:
        """Relative floors in use."""
        return {**DEFAULT_REL_FLOORS, **dict(self.rel_floors or {})}

    @property
    def baseline_ready(self) -> bool:
        """Whether the baseline has been formed."""
        return bool(self.result.baseline) or bool(self.result.no_baseline)

    def _make_baseline(self, windows: list[HealthWindow], source: str) -> None:
        floors = self.floors
        if windows and source != "reference":
            source = f"windows {windows[0].index}-{windows[-1].index}"
        for p in self.parameters:
            ests = [w.params[p] for w in windows if p in w.params]
            if len(ests) < min(self.min_baseline, max(len(windows), 1)) or not ests:
                reasons = sorted({w.not_identified.get(p, "") for w in windows} - {""})
                self.result.no_baseline[p] = (
                    f"identified in {len(ests)} of {len(windows)} baseline windows (needs "
                    f"{self.min_baseline})" + (f"; e.g. {reasons[0]}" if reasons else ""))
                continue
            self.result.baseline[p] = baseline_parameter(ests, name=p,
                                                         rel_floor=floors.get(p, 0.0),
                                                         source=source)
            self._state[p] = {"pos": 0.0, "neg": 0.0, "latched": 0.0, "onset_pos": -1.0,
                              "onset_neg": -1.0}
        # baseline windows get their (untested) z for the figures and the table
        for w in windows:
            if source == "reference":
                break
            for p, b in self.result.baseline.items():
                if p in w.params:
                    z, sig = z_score(w.params[p], b)
                    self.result.tests.setdefault(p, []).append(ParameterTest(
                        w.index, p, w.params[p].value, w.params[p].stderr, b.mean, sig, z,
                        _p_two_sided(z), 0.0, 0.0, True))

    def update(self, window: HealthWindow) -> list[HealthAlarm]:
        """Add one window; returns the alarms it raised."""
        res = self.result
        res.windows.append(window)
        if not self.baseline_ready:
            if len(res.windows) >= self.baseline_windows:
                self._make_baseline(list(res.windows), "windows")
            return []
        new: list[HealthAlarm] = []
        by_index = {w.index: w for w in res.windows}
        for p, b in res.baseline.items():
            if p not in window.params:
                continue
            est = window.params[p]
            z, sig = z_score(est, b)
            st = self._state[p]
            if st["pos"] == 0.0:
                st["onset_pos"] = float(window.index)
            if st["neg"] == 0.0:
                st["onset_neg"] = float(window.index)
            zc = z if math.isfinite(z) else math.copysign(1e6, z)
            st["pos"] = max(0.0, st["pos"] + zc - self.cusum_k)
            st["neg"] = max(0.0, st["neg"] - zc - self.cusum_k)
            res.tests.setdefault(p, []).append(ParameterTest(
                window.index, p, est.value, est.stderr, b.mean, sig, z, _p_two_sided(z),
                st["pos"], st["neg"], False))
            if st["latched"]:
                if abs(z) < 2.0:
                    st.update(pos=0.0, neg=0.0, latched=0.0)
                continue
            alarm: HealthAlarm | None = None
            if abs(z) > self.z_alarm:
                alarm = self._alarm(p, b, "z", window, window, est.value, z)
            elif max(st["pos"], st["neg"]) > self.cusum_h:
                onset = int(st["onset_pos"] if st["pos"] >= st["neg"] else st["onset_neg"])
                tests = [t for t in res.tests[p] if not t.in_baseline
                         and onset <= t.window_index <= window.index]
                zs = np.array([t.z for t in tests])
                z_comb = float(zs.sum() / math.sqrt(zs.size))
                value = float(np.mean([t.value for t in tests]))
                alarm = self._alarm(p, b, "cusum", window, by_index.get(onset, window), value,
                                    z_comb)
            if alarm is not None:
                st["latched"] = 1.0
                new.append(alarm)
        res.alarms.extend(new)
        return new

    def _alarm(self, p: str, b: BaselineParameter, test: str, window: HealthWindow,
               onset: HealthWindow, value: float, z: float) -> HealthAlarm:
        pv = _p_two_sided(z)
        change = value - b.mean
        rel = change / abs(b.mean) if b.mean else math.copysign(math.inf, change)
        return HealthAlarm(self.axis, p, b.unit, test, window.index, onset.index, window.label,
                           onset.label, b.mean, value, change, rel, z, pv, 1.0 - pv)

    def finish(self) -> HealthResult:
        """The result so far (forms the baseline from fewer windows if the sequence was short)."""
        if not self.baseline_ready and self.result.windows:
            self._make_baseline(list(self.result.windows), "windows")
        return self.result


def track_loop_health(
    recordings: Iterable[Recording | str | Path],
    axis: str,
    *,
    window_s: float = 60.0,
    labels: Sequence[str] | None = None,
    baseline_windows: int = 5,
    reference: Sequence[HealthWindow] | None = None,
    parameters: tuple[str, ...] = HEALTH_PARAMETERS,
    z_alarm: float = 5.0,
    cusum_k: float = 0.5,
    cusum_h: float = 8.0,
    rel_floors: Mapping[str, float] | None = None,
    effort_signal: str = "auto",
    jerk_models: tuple[str, ...] = JERK_FILTER_TYPES,
    min_travel: float = 0.5,
    max_reference_residual: float = 0.5,
    n_bootstrap: int = 50,
    seed: int = 0,
) -> HealthResult:
    """Loop health of one axis over a sequence of production recordings.

    Parameters
    ----------
    recordings : iterable of Recording or path
        Recordings in time order (paths are read with :func:`cnctwin.iotools.read_recording`
        one at a time).
    axis : str
        Axis name.
    window_s : float, default 60
        Window length [s] (:func:`split_windows`; windows never span two recordings).
    labels : sequence of str, optional
        One label per recording (default the file name or ``rec<i>``).
    baseline_windows : int, default 5
        Windows in the baseline period (ignored with ``reference``).
    reference : sequence of HealthWindow, optional
        Baseline windows of an earlier period (e.g. ``earlier_result.windows[:5]``).
    parameters, z_alarm, cusum_k, cusum_h, rel_floors
        Tests (:class:`LoopHealthMonitor`).
    effort_signal : {'auto', 'CURRENT', 'TORQUE'}
        Friction signal.
    jerk_models : tuple of str
        Jerk-filter models of the reference window's setpoint-chain fit
        (:func:`identify_window`).
    min_travel : float, default 0.5
        Least DES_POS travel of an excited window [mm or deg] (:func:`identify_window`).
    max_reference_residual : float, default 0.5
        The first window whose loop model predicts its own window with a residual ratio below
        this becomes the reference model of ``residual_ratio``; a model that does not fit
        where it was identified is no reference (listed in ``notes``).
    n_bootstrap : int, default 50
        Bootstrap resamples per window.
    seed : int, default 0
        Random seed.

    Returns
    -------
    HealthResult

    Examples
    --------
    >>> from cnctwin.sim import Machine, simulate
    >>> prog = "G90 G0 X0\\nG1 X60 F3000\\nX0\\nG1 X60 F6000\\nX0\\nM30\\n"
    >>> recs = [simulate(prog, Machine.thesis_default(), seed=s).recording for s in range(3)]
    >>> res = track_loop_health(recs, "X1", baseline_windows=2)
    >>> [w.index for w in res.windows], res.alarms
    ([0, 1, 2], [])
    """
    mon = LoopHealthMonitor(axis, baseline_windows=baseline_windows, parameters=parameters,
                            z_alarm=z_alarm, cusum_k=cusum_k, cusum_h=cusum_h,
                            rel_floors=rel_floors, reference=reference)
    res = mon.result
    res.settings.update(window_s=window_s, min_travel=min_travel,
                        max_reference_residual=max_reference_residual)
    model_reason = "no reference loop model yet (Kv not identified in an earlier window)"
    if reference is not None:
        for w in reference:
            if w.identification is not None and "kv_1_s" in w.identification.params:
                mon.model = AxisLoopModel.from_identification(w.identification)
                res.notes.append(f"reference loop model from {w.label}")
                break
    index = 0
    for i, item in enumerate(recordings):
        if isinstance(item, Recording):
            rec = item
            src = labels[i] if labels is not None else f"rec{i}"
        else:
            from cnctwin.iotools import read_recording

            rec = read_recording(item)
            src = labels[i] if labels is not None else Path(item).name
        for k, win in enumerate(split_windows(rec, window_s=window_s)):
            need_model = mon.model is None
            w = identify_window(win, axis, index=index, source=src, label=f"{src}#{k}",
                                model=mon.model, setpoint_chain=need_model,
                                effort_signal=effort_signal, jerk_models=jerk_models,
                                min_travel=min_travel, n_bootstrap=n_bootstrap, seed=seed)
            if need_model:
                model_reason, w = _adopt_model(mon, w, win, axis, max_reference_residual,
                                               model_reason)
            mon.update(w)
            index += 1
    if mon.model is None and model_reason not in res.notes:
        res.notes.append(f"residual_ratio not tracked: {model_reason}")
    return mon.finish()


def _adopt_model(mon: LoopHealthMonitor, w: HealthWindow, win: Recording, axis: str,
                 max_ratio: float, reason: str) -> tuple[str, HealthWindow]:
    """Make the window's loop model the reference if it predicts its own window."""
    ni = dict(w.not_identified)
    if w.identification is None or "kv_1_s" not in w.identification.params:
        ni["residual_ratio"] = reason
        return reason, replace(w, not_identified=ni)
    try:
        model = AxisLoopModel.from_identification(w.identification)
        rr = residual_ratio(model, win, axis)
    except IdentificationError as exc:
        reason = f"no reference loop model: {exc}"
        ni["residual_ratio"] = reason
        return reason, replace(w, not_identified=ni)
    if not rr.value < max_ratio:
        reason = (f"the loop model identified in {w.label} does not predict its own window "
                  f"(residual ratio {rr.value:.3g} >= {max_ratio:g}; e.g. an unidentified FFW "
                  f"weight or setpoint filter), so it is not used as the reference")
        mon.result.notes.append(reason)
        ni["residual_ratio"] = reason
        return reason, replace(w, not_identified=ni)
    mon.model = model
    mon.result.notes.append(f"reference loop model from {w.label} (in-sample residual ratio "
                            f"{rr.value:.3g})")
    ni.pop("residual_ratio", None)
    return "", replace(w, params={**w.params, "residual_ratio": rr}, not_identified=ni)
