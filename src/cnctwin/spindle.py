"""Spindle: air-cut analysis, friction fit, Kt calibration and the cutting-torque estimator.

Implements thesis chapter 4 ("Cutting torque estimation with spindle current") on
:class:`~cnctwin.recording.Recording` objects only, so the same calls work on a real recording
and on a simulated one:

1. :func:`~cnctwin.analysis.segments.speed_plateaus` + :func:`air_cut_statistics`: mean, min
   and max of the spindle signals per constant speed of an air-cut sweep (Fig. 3.8, 3.9).
2. :func:`linear_region`: the speed range where the air-cut current is linear in speed; the
   upper limit where the mean current departs from the line (current limitation / field
   weakening, Fig. 4.1), the lower limit where the folded stator frequency becomes the
   dominant line of the current spectrum (Eq. 4.1, Fig. 4.3).
3. :func:`fit_friction`: ``I = a n + b`` on that range (Eq. 4.2; a = B/Kt, b = tau_f/Kt).
4. :func:`calibrate`: ``Kt = tau_c / (I - a n - b)`` from one cut with a dynamometer (Eq. 4.3),
   then ``B = a Kt`` and ``tau_f = b Kt``.
5. :class:`SpindleModel`: ``tau_c = Kt I - B n - tau_f - J dOmega/dt`` (Eq. 3.1 solved for the
   cutting torque; Eq. 4.4 without the inertia term), vectorized and streaming
   (:class:`StreamingTorqueEstimator`), and :func:`validation_table` (Table 4.1).

Typical pipeline::

    plateaus = speed_plateaus(sweep)
    stats = air_cut_statistics(sweep, plateaus)
    region = linear_region_from_recording(sweep, plateaus)
    fit = fit_friction(stats["speed_rpm"], stats["current_a"], region.lo_rpm, region.hi_rpm)
    model = calibrate_from_recording(fit, drilling)           # dynamometer in rec.external
    table = validation_table([measure_cut(r, cutting_regions(r).iloc[0]) for r in cuts], model)

References
----------
.. [1] Thesis "CNC Machine Tool Digital Twin Applications with Advancements of Edge
   Computing", Koç University: Eq. (3.1), (4.1)-(4.4), Table 4.1, Figures 3.6-3.9, 4.1-4.5.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray

from cnctwin._jit import lazy_njit
from cnctwin.analysis.align import align_external, external_on_hf
from cnctwin.analysis.correlation import plot_correlation_heatmaps
from cnctwin.analysis.filters import fold_frequency, lowpass, stator_frequency_hz
from cnctwin.analysis.segments import cutting_regions, speed_plateaus, spindle_speed_rpm
from cnctwin.analysis.spectra import dominant_line
from cnctwin.exceptions import ConfigError, IdentificationError, SignalNotFoundError
from cnctwin.recording import Recording

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from cnctwin.machine import MachineFile

__all__ = [
    "RPM_TO_RAD_S",
    "SPINDLE_MODEL_PARAMETERS",
    "CutMeasurement",
    "FluxLawFit",
    "FrictionFit",
    "LinearRegion",
    "SpeedChangeFlags",
    "SpindleModel",
    "StreamingTorqueEstimator",
    "air_cut_correlation",
    "air_cut_statistics",
    "calibrate",
    "calibrate_from_recording",
    "estimate_poles",
    "field_weakening_onset_rpm",
    "fit_flux_law",
    "fit_friction",
    "identify_inertia",
    "inertia_uncertainty",
    "linear_region",
    "linear_region_from_recording",
    "measure_cut",
    "plateau_segments",
    "plot_air_cut",
    "plot_air_cut_correlation",
    "speed_change_flags",
    "validation_table",
]

RPM_TO_RAD_S = 2.0 * math.pi / 60.0
"""Factor from rpm to rad/s."""

SPINDLE_MODEL_PARAMETERS: dict[str, dict[str, float]] = {
    # Thesis §4.3, Eq. (4.4): Kt from the steel drilling cut at 2400 rpm / 0.16 mm/rev,
    # B and tau_f from the air-cut fit (Eq. 4.2) times Kt, all as printed (rounded).
    "thesis_spinner_840dsl": {"kt_nm_per_a": 1.04, "b_nm_per_rpm": 8.42e-5, "tau_f_nm": 0.35},
}
"""Published spindle parameter sets; use :meth:`SpindleModel.from_parameters`."""

_HF_AIR_CUT: tuple[str, ...] = ("CURRENT", "TORQUE", "POWER", "LOAD")
_LF_AIR_CUT: tuple[str, ...] = (
    "CURRENT_ABS_SMOOTHED", "IQ_ACT", "TORQUE_UTIL", "MOTOR_TEMP", "SPEED_SMOOTHED",
)


# ====================================================================== friction fit (Eq. 4.2)
@dataclass(frozen=True)
class FrictionFit:
    """Straight line ``I = slope * n + offset`` through air-cut mean currents (thesis Eq. 4.2).

    Attributes
    ----------
    slope_a_per_rpm : float
        ``a = B / Kt`` [A/rpm] (thesis: 8.1e-5).
    offset_a : float
        ``b = tau_f / Kt`` [A] (thesis: 0.34).
    r2 : float
        Coefficient of determination (thesis: 0.94).
    norm_residuals : float
        Euclidean norm of the residuals, sqrt(sum r^2) [A] (MATLAB's "norm of residuals";
        thesis: 0.14).
    n_points : int
        Points used.
    slope_std : float
        Standard error of the slope [A/rpm].
    offset_std : float
        Standard error of the offset [A].
    lo_rpm, hi_rpm : float
        Speed range used [rpm].
    """

    slope_a_per_rpm: float
    offset_a: float
    r2: float
    norm_residuals: float
    n_points: int
    slope_std: float
    offset_std: float
    lo_rpm: float
    hi_rpm: float

    def current_a(self, speed_rpm: ArrayLike) -> NDArray[np.float64]:
        """Air-cut current predicted by the line [A]."""
        return np.asarray(
            self.slope_a_per_rpm * np.asarray(speed_rpm, dtype=np.float64) + self.offset_a
        )


def fit_friction(
    speed_rpm: ArrayLike,
    current_a: ArrayLike,
    lo_rpm: float | None = None,
    hi_rpm: float | None = None,
) -> FrictionFit:
    """Least-squares line through air-cut mean currents in a speed range (thesis Eq. 4.2).

    Parameters
    ----------
    speed_rpm : array-like
        Plateau speeds [rpm] (e.g. ``air_cut_statistics(...)["speed_rpm"]``).
    current_a : array-like
        Mean q-axis current at each speed [A] (``["current_a"]``).
    lo_rpm, hi_rpm : float, optional
        Inclusive speed range (the linear region, :func:`linear_region`); default all.

    Returns
    -------
    FrictionFit

    Raises
    ------
    IdentificationError
        Fewer than 3 points in the range, or all at one speed.

    Notes
    -----
    At constant speed and no cut, Eq. (3.1) gives ``Kt I = B Omega + tau_f``, i.e.
    ``I = (B/Kt) n + tau_f/Kt``. The thesis fits 1100-5000 rpm and gets
    ``I = 8.1e-5 n + 0.34`` with R^2 = 0.94 and norm of residuals 0.14 (Eq. 4.2).
    For a spindle turning backwards (M4) pass magnitudes.
    """
    n = np.asarray(speed_rpm, dtype=np.float64).ravel()
    i = np.asarray(current_a, dtype=np.float64).ravel()
    if n.shape != i.shape:
        raise ConfigError(f"speed_rpm has {n.size} values, current_a {i.size}")
    m = np.isfinite(n) & np.isfinite(i)
    if lo_rpm is not None:
        m &= n >= lo_rpm
    if hi_rpm is not None:
        m &= n <= hi_rpm
    x, y = n[m], i[m]
    if x.size < 3 or np.ptp(x) == 0:
        raise IdentificationError(
            f"fit_friction needs at least 3 plateaus at different speeds in "
            f"[{lo_rpm}, {hi_rpm}] rpm, got {x.size}; widen the range or record more speeds"
        )
    xm = x.mean()
    sxx = float(np.sum((x - xm) ** 2))
    slope = float(np.sum((x - xm) * (y - y.mean())) / sxx)
    offset = float(y.mean() - slope * xm)
    res = y - (slope * x + offset)
    ss_res = float(np.sum(res**2))
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    r2 = 1.0 - ss_res / ss_tot if ss_tot > 0 else float("nan")
    dof = x.size - 2
    s2 = ss_res / dof if dof > 0 else float("nan")
    slope_std = math.sqrt(s2 / sxx) if dof > 0 else float("nan")
    offset_std = math.sqrt(s2 * (1.0 / x.size + xm**2 / sxx)) if dof > 0 else float("nan")
    return FrictionFit(
        slope_a_per_rpm=slope,
        offset_a=offset,
        r2=r2,
        norm_residuals=math.sqrt(ss_res),
        n_points=int(x.size),
        slope_std=slope_std,
        offset_std=offset_std,
        lo_rpm=float(x.min()),
        hi_rpm=float(x.max()),
    )


# ====================================================================== air-cut statistics
def air_cut_statistics(
    rec: Recording,
    plateaus: pd.DataFrame | None = None,
    *,
    spindle: str = "SP1",
    hf_signals: Sequence[str] = _HF_AIR_CUT,
    lf_signals: Sequence[str] = _LF_AIR_CUT,
) -> pd.DataFrame:
    """Mean, min, max and std of the spindle signals on each constant-speed plateau.

    Parameters
    ----------
    rec : Recording
        Air-cut sweep recording (no cutting).
    plateaus : pandas.DataFrame, optional
        Output of :func:`~cnctwin.analysis.segments.speed_plateaus`; computed with its
        defaults if omitted.
    spindle : str, default 'SP1'
        Spindle axis name.
    hf_signals : sequence of str
        HF codes summarized (thesis Fig. 3.8 a, b, e, f: current, torque setpoint, power, load).
    lf_signals : sequence of str
        LF drive values summarized where recorded (Fig. 3.8 c, d: smoothed |I|, torque
        utilization; plus Iq, motor temperature, smoothed speed).

    Returns
    -------
    pandas.DataFrame
        One row per plateau, sorted by speed: ``speed_rpm``, ``start_cycle``, ``end_cycle``,
        ``duration_s``, ``n_cycles``, ``current_a`` (mean of ``CURRENT|<spindle>``, or of the
        LF Iq if there is no HF current), ``current_std_a``, and ``"<column> mean|min|max|std"``
        for every signal found. LF statistics use only the LF samples that arrived inside the
        plateau.
    """
    if plateaus is None:
        plateaus = speed_plateaus(rec, spindle=spindle)
    if plateaus.empty:
        raise IdentificationError(
            "no constant-speed plateau found; is this an air-cut sweep? Check speed_plateaus "
            "tolerance_rpm / min_duration_s"
        )
    hf_cols = [f"{c}|{spindle}" for c in hf_signals if rec.has(f"{c}|{spindle}")]
    lf_series: dict[str, pd.Series] = {}
    if not rec.lf.empty:
        exact = rec.lf_wide(method="exact")
        for code in lf_signals:
            # only the cycles where an LF value arrived ('exact'), not the held values
            col = _matching_lf_column(exact.columns, code, spindle)
            if col is not None:
                lf_series[f"{code}|{spindle}"] = exact[col]
    rows: list[dict[str, Any]] = []
    cyc = rec.cycles
    for _, p in plateaus.iterrows():
        lo = np.searchsorted(cyc, int(p["start_cycle"]), side="left")
        hi = np.searchsorted(cyc, int(p["end_cycle"]), side="right")
        row: dict[str, Any] = {
            "speed_rpm": float(p["speed_rpm"]),
            "start_cycle": int(p["start_cycle"]),
            "end_cycle": int(p["end_cycle"]),
            "duration_s": float(p["duration_s"]),
            "n_cycles": int(hi - lo),
        }
        for col in hf_cols:
            v = rec.hf[col].to_numpy(dtype=np.float64)[lo:hi]
            _stats_into(row, col, v)
        for name, s in lf_series.items():
            v = s.to_numpy(dtype=np.float64)[lo:hi]
            _stats_into(row, f"{name} (LF)", v[np.isfinite(v)])
        rows.append(row)
    df = pd.DataFrame(rows).sort_values("speed_rpm", kind="stable").reset_index(drop=True)
    i_col = f"CURRENT|{spindle}"
    if f"{i_col} mean" in df:
        df.insert(1, "current_a", df[f"{i_col} mean"])
        df.insert(2, "current_std_a", df[f"{i_col} std"])
    elif f"IQ_ACT|{spindle} (LF) mean" in df:
        df.insert(1, "current_a", df[f"IQ_ACT|{spindle} (LF) mean"])
        df.insert(2, "current_std_a", df[f"IQ_ACT|{spindle} (LF) std"])
    else:
        raise SignalNotFoundError(
            f"neither HF {i_col!r} nor the LF Iq (IQ_ACT / r0078) is recorded; cannot "
            "summarize the spindle current"
        )
    df.attrs["spindle"] = spindle
    return df


def _matching_lf_column(columns: Iterable[str], code: str, spindle: str) -> str | None:
    from cnctwin.signals import lookup, parse_column

    best: str | None = None
    for c in columns:
        base, ax = parse_column(str(c))
        try:
            spec = lookup(base)
        except SignalNotFoundError:
            continue
        if spec.code == code and (ax is None or ax == spindle):
            if ax == spindle:
                return str(c)
            best = str(c)
    return best


def _stats_into(row: dict[str, Any], name: str, v: NDArray[np.float64]) -> None:
    v = v[np.isfinite(v)]
    if v.size == 0:
        for s in ("mean", "min", "max", "std"):
            row[f"{name} {s}"] = np.nan
        return
    row[f"{name} mean"] = float(v.mean())
    row[f"{name} min"] = float(v.min())
    row[f"{name} max"] = float(v.max())
    row[f"{name} std"] = float(v.std())


def plateau_segments(
    rec: Recording,
    plateaus: pd.DataFrame,
    *,
    spindle: str = "SP1",
    signal: str = "CURRENT",
) -> list[NDArray[np.float64]]:
    """The raw HF samples of one signal on each plateau, in the order of ``plateaus``.

    Parameters
    ----------
    rec : Recording
        The recording.
    plateaus : pandas.DataFrame
        Plateaus (:func:`find_plateaus`).
    spindle : str, default 'SP1'
        Spindle axis name.
    signal : str, default 'CURRENT'
        Signal code (``CURRENT``, ``TORQUE``, ...).

    Returns
    -------
    list of numpy.ndarray
    """
    col = f"{signal}|{spindle}"
    x = rec.signal(col).to_numpy(dtype=np.float64)
    cyc = rec.cycles
    out = []
    for _, p in plateaus.iterrows():
        lo = np.searchsorted(cyc, int(p["start_cycle"]), side="left")
        hi = np.searchsorted(cyc, int(p["end_cycle"]), side="right")
        out.append(x[lo:hi])
    return out


def air_cut_correlation(stats: pd.DataFrame) -> pd.DataFrame:
    """Correlation matrix of the per-speed mean values (thesis Fig. 3.9).

    Parameters
    ----------
    stats : pandas.DataFrame
        Output of :func:`air_cut_statistics`.

    Returns
    -------
    pandas.DataFrame
    """
    cols = ["speed_rpm", *[c for c in stats.columns if c.endswith(" mean")]]
    return stats[cols].corr()


def plot_air_cut_correlation(stats: pd.DataFrame) -> Figure:
    """Heatmap of :func:`air_cut_correlation` (thesis Fig. 3.9).

    Parameters
    ----------
    stats : pandas.DataFrame
        Output of :func:`air_cut_statistics`.

    Returns
    -------
    matplotlib.figure.Figure
    """
    m = air_cut_correlation(stats)
    m.columns = [c.replace(" mean", "") for c in m.columns]
    m.index = [c.replace(" mean", "") for c in m.index]
    return plot_correlation_heatmaps({"air-cut means": m}, titles=["air-cut mean values"])


def plot_air_cut(stats: pd.DataFrame, *, columns: Sequence[str] | None = None) -> Figure:
    """Mean with min-max band of each summarized signal versus speed (thesis Fig. 3.8).

    Parameters
    ----------
    stats : pandas.DataFrame
        Output of :func:`air_cut_statistics`.
    columns : sequence of str, optional
        Signal names (the part before ``" mean"``); default every summarized signal.

    Returns
    -------
    matplotlib.figure.Figure
        Not attached to pyplot (Agg canvas).
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    names = list(columns) if columns is not None else [
        c[: -len(" mean")] for c in stats.columns if c.endswith(" mean")
    ]
    if not names:
        raise ConfigError("stats has no '<signal> mean' columns to plot")
    ncols = min(3, len(names))
    nrows = math.ceil(len(names) / ncols)
    fig = Figure(figsize=(4.2 * ncols, 3.0 * nrows), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, ncols, squeeze=False)
    n = stats["speed_rpm"].to_numpy()
    for k, name in enumerate(names):
        ax = axes[k // ncols][k % ncols]
        ax.fill_between(n, stats[f"{name} min"], stats[f"{name} max"], alpha=0.3,
                        label="min-max")
        ax.plot(n, stats[f"{name} mean"], ".-", lw=1, ms=3, label="mean")
        ax.set_title(f"{chr(97 + k)}) {name}", fontsize=9)
        ax.set_xlabel("spindle speed [rpm]")
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    for j in range(len(names), nrows * ncols):
        axes[j // ncols][j % ncols].set_visible(False)
    return fig


# ====================================================================== linear region (§4.1)
def field_weakening_onset_rpm(stats: pd.DataFrame, *, spindle: str = "SP1",
                              threshold: float = 1.01) -> float | None:
    """Lowest plateau speed where the drive applies field-weakening current [rpm].

    Parameters
    ----------
    stats : pandas.DataFrame
        :func:`~cnctwin.spindle.air_cut_statistics` with the LF means of the smoothed absolute
        current (r0068) and Iq (r0078).
    spindle : str
        Spindle axis.
    threshold : float, default 1.01
        ``|I| / |Iq|`` above which Id is counted as present (on two plateaus in a row).

    Returns
    -------
    float or None
        The speed, or None if the LF currents are not recorded or never diverge.

    Notes
    -----
    Thesis Fig. 3.8c: the smoothed absolute current rises away from Iq once field weakening
    injects negative Id (|I| = sqrt(Id^2 + Iq^2)). Thesis §4.1 searches the linear region only
    below this speed (7000 rpm from the drive parameters); here it is read from the data.
    """
    ci = f"CURRENT_ABS_SMOOTHED|{spindle} (LF) mean"
    cq = f"IQ_ACT|{spindle} (LF) mean"
    if ci not in stats or cq not in stats:
        return None
    order = np.argsort(stats["speed_rpm"].abs().to_numpy(), kind="stable")
    n = stats["speed_rpm"].abs().to_numpy()[order]
    ratio = (stats[ci].abs() / stats[cq].abs().replace(0.0, np.nan)).to_numpy()[order]
    flags = ratio > threshold
    # two plateaus in a row, so one noisy low-current plateau does not count
    both = np.flatnonzero(flags[:-1] & flags[1:])
    return float(n[both[0]]) if both.size else None


@dataclass(frozen=True, eq=False)
class LinearRegion:
    """Speed range where the air-cut current is linear in speed (thesis §4.1).

    Attributes
    ----------
    lo_rpm, hi_rpm : float
        Lowest and highest plateau speed inside the region [rpm].
    reason_lo, reason_hi : str
        Why the region ends there, in words, with the numbers.
    poles : int or None
        Motor pole count used (given or estimated) for the stator line; None without spectra.
    noise_a : float
        Noise of the plateau mean currents used for the departure test [A].
    table : pandas.DataFrame
        Per plateau (sorted by speed): ``speed_rpm``, ``current_a``, ``dominant_hz``,
        ``stator_alias_hz``, ``stator_dominant``, ``in_region``.
    """

    lo_rpm: float
    hi_rpm: float
    reason_lo: str
    reason_hi: str
    poles: int | None
    noise_a: float
    table: pd.DataFrame = field(repr=False)


def estimate_poles(
    speed_rpm: ArrayLike,
    dominant_hz: ArrayLike,
    *,
    fs_hz: float,
    candidates: Sequence[int] = (2, 4, 6, 8, 10, 12, 16),
    tol_hz: float | ArrayLike = 1.0,
) -> int:
    """Pole count that best explains the dominant current lines as folded stator lines.

    Parameters
    ----------
    speed_rpm : array-like
        Plateau speeds [rpm].
    dominant_hz : array-like
        Dominant line of the current spectrum on each plateau [Hz].
    fs_hz : float
        Sample rate of the current [Hz].
    candidates : sequence of int
        Pole counts tried (even).
    tol_hz : float or array-like, default 1.0
        Match tolerance [Hz] (scalar or per plateau).

    Returns
    -------
    int
        The candidate ``p`` for which ``fold(N p / 120)`` matches most plateaus (ties: the
        smaller ``p``).

    Raises
    ------
    IdentificationError
        If the best candidate explains fewer than 3 plateaus or under 30 % of them.
    """
    n = np.asarray(speed_rpm, dtype=np.float64)
    d = np.asarray(dominant_hz, dtype=np.float64)
    tol = np.broadcast_to(np.asarray(tol_hz, dtype=np.float64), n.shape)
    scores = []
    for p in candidates:
        alias = fold_frequency(stator_frequency_hz(n, p), fs_hz)
        scores.append(int(np.sum(np.abs(d - alias) <= tol)))
    best = int(np.argmax(scores))
    if scores[best] < 3 or scores[best] < 0.3 * n.size:
        raise IdentificationError(
            f"no pole count in {list(candidates)} explains the dominant current lines "
            f"(best {candidates[best]} poles matches {scores[best]} of {n.size} plateaus); pass "
            "poles= from the motor datasheet"
        )
    return int(candidates[best])


def _noise_sigma(y: NDArray[np.float64]) -> float:
    """Robust noise of a smooth sequence from its second differences (MAD / sqrt(6))."""
    if y.size < 5:
        return float(np.std(y)) if y.size > 1 else 0.0
    d2 = np.diff(y, 2)
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / math.sqrt(6.0))


class _Line:
    """Incremental least-squares line with prediction intervals."""

    def __init__(self, x: NDArray[np.float64], y: NDArray[np.float64], idx: list[int]) -> None:
        self.x, self.y, self.idx = x, y, list(idx)

    def fit(self) -> tuple[float, float, float, float, int]:
        xs, ys = self.x[self.idx], self.y[self.idx]
        xm = float(xs.mean())
        sxx = float(np.sum((xs - xm) ** 2))
        a = float(np.sum((xs - xm) * (ys - ys.mean())) / sxx) if sxx > 0 else 0.0
        b = float(ys.mean() - a * xm)
        return a, b, xm, sxx, xs.size

    def residual_z(self, j: int, sigma: float) -> float:
        a, b, xm, sxx, m = self.fit()
        se = sigma * math.sqrt(1.0 + 1.0 / m + ((self.x[j] - xm) ** 2 / sxx if sxx > 0 else 0.0))
        return float((self.y[j] - (a * self.x[j] + b)) / se)


def _grow(
    x: NDArray[np.float64],
    y: NDArray[np.float64],
    seed: list[int],
    sigma: float,
    *,
    k_sigma: float,
    n_consecutive: int,
    direction: int,
) -> tuple[list[int], str]:
    line = _Line(x, y, seed)
    edge = max(seed) if direction > 0 else min(seed)
    j = edge + direction
    pending: list[tuple[int, float]] = []
    while 0 <= j < x.size:
        z = line.residual_z(j, sigma)
        if abs(z) <= k_sigma:
            line.idx.append(j)
            pending = []
        else:
            pending.append((j, z))
            if len(pending) >= n_consecutive:
                break
        j += direction
    idx = sorted(line.idx)
    if len(pending) >= n_consecutive:
        lo_x, hi_x = x[idx[0]], x[idx[-1]]
        where = ", ".join(f"{x[p]:.0f} rpm ({z:+.1f} sigma)" for p, z in pending)
        reason = (
            f"the mean current departs from the line fitted on {lo_x:.0f}-{hi_x:.0f} rpm by "
            f"more than {k_sigma:g} sigma (sigma = {sigma:.3g} A) at {where}"
        )
    else:
        reason = f"{'highest' if direction > 0 else 'lowest'} measured speed"
    return idx, reason


def _longest_linear(
    n: NDArray[np.float64],
    cur: NDArray[np.float64],
    sigma: float,
    *,
    k_sigma: float,
    n_consecutive: int,
    min_points: int,
    min_slope_t: float = 5.0,
) -> tuple[list[int], str, str]:
    """The run of points on one rising line with the largest rise (indices into n), with the
    end reasons."""
    best: tuple[float, list[int], str, str] | None = None
    for s in range(0, n.size - min_points + 1):
        seed = list(range(s, s + min_points))
        a, b, *_ = _Line(n, cur, seed).fit()
        res = cur[seed] - (a * n[seed] + b)
        if a <= 0 or np.any(np.abs(res) > k_sigma * sigma):
            continue
        up, r_hi = _grow(n, cur, seed, sigma, k_sigma=k_sigma,
                         n_consecutive=n_consecutive, direction=+1)
        both, r_lo = _grow(n, cur, up, sigma, k_sigma=k_sigma,
                           n_consecutive=n_consecutive, direction=-1)
        a2, _, _, sxx, _ = _Line(n, cur, both).fit()
        # the line must rise significantly (friction grows with speed): a flat or falling
        # stretch (current limitation, field weakening) is not the friction line
        if sxx <= 0 or a2 * math.sqrt(sxx) / sigma < min_slope_t:
            continue
        # the friction line is the run over which the current rises most (from the lower
        # limit to current limitation / field weakening); above field weakening the current
        # is flat or rises slowly over many plateaus, so the longest run is the wrong one
        rise = a2 * float(n[max(both)] - n[min(both)])
        if best is None or rise > best[0]:
            best = (rise, both, r_lo, r_hi)
    if best is None:
        raise IdentificationError(
            "no run of plateaus where the mean current rises linearly with speed; record "
            "more speeds or pass noise_a"
        )
    _, idx, reason_lo, reason_hi = best
    # refine: re-seed on the middle half of the region (away from both curved ends) and
    # grow again, so curvature picked up at one end does not tilt the line at the other
    for _ in range(2):
        lo_k, hi_k = min(idx), max(idx)
        q = (hi_k - lo_k) // 4
        mid = list(range(lo_k + q, hi_k - q + 1))
        if len(mid) < min_points:
            break
        up, reason_hi = _grow(n, cur, mid, sigma, k_sigma=k_sigma,
                              n_consecutive=n_consecutive, direction=+1)
        new, reason_lo = _grow(n, cur, up, sigma, k_sigma=k_sigma,
                               n_consecutive=n_consecutive, direction=-1)
        if new == idx:
            break
        idx = new
    return idx, reason_lo, reason_hi


def linear_region(
    speed_rpm: ArrayLike | pd.DataFrame,
    current_a: ArrayLike | None = None,
    *,
    segments: Sequence[ArrayLike] | None = None,
    fs_hz: float | None = None,
    poles: int | None = None,
    pole_candidates: Sequence[int] = (2, 4, 6, 8, 10, 12, 16),
    k_sigma: float = 3.0,
    n_consecutive: int = 2,
    min_points: int = 5,
    stator_consecutive: int = 3,
    fmin_hz: float = 2.0,
    noise_a: float | None = None,
) -> LinearRegion:
    """Find the linear speed-current region of the spindle from air-cut plateaus (thesis §4.1).

    Parameters
    ----------
    speed_rpm : array-like or pandas.DataFrame
        Plateau speeds [rpm], or the output of :func:`air_cut_statistics` (then
        ``current_a`` is taken from its ``"current_a"`` column).
    current_a : array-like, optional
        Mean q-axis current per plateau [A].
    segments : sequence of array-like, optional
        Raw current samples of each plateau (same order as ``speed_rpm``), e.g. from
        :func:`plateau_segments`. Needed for the spectral lower limit.
    fs_hz : float, optional
        Sample rate of ``segments`` [Hz].
    poles : int, optional
        Motor pole count; estimated from the spectra (:func:`estimate_poles`) if omitted.
    pole_candidates : sequence of int
        Candidates for the estimate.
    k_sigma : float, default 3.0
        A point departs from the line when its prediction residual exceeds ``k_sigma``
        standard errors.
    n_consecutive : int, default 2
        Consecutive departing points that end the region (single outliers are skipped).
    min_points : int, default 5
        Points of the seed fit.
    stator_consecutive : int, default 3
        The lower limit is the lowest speed from which this many consecutive plateaus have
        the folded stator line as their dominant line.
    fmin_hz : float, default 2.0
        Lines below this are ignored when looking for the dominant line [Hz].
    noise_a : float, optional
        Noise of the plateau means [A]; default estimated robustly from the second
        differences of the mean-current sequence.

    Returns
    -------
    LinearRegion

    Notes
    -----
    Linearity: a line is fitted to ``min_points`` consecutive plateaus and grown one plateau
    at a time (up, then down) while the next plateau's mean current lies within ``k_sigma``
    prediction standard errors of the line; ``n_consecutive`` departures end it (upwards:
    current limitation / field weakening bends the curve, thesis Fig. 4.1: 5000 rpm;
    downwards: low-speed friction). Every seed window is tried, the longest rising run wins,
    and it is re-seeded twice on its middle half and grown again. A run counts only if its
    slope is positive by at least 5 standard errors (flat or falling stretches above the
    current limit are not the friction line).

    Lower limit: the dominant line of each plateau's current spectrum is compared with the
    folded stator frequency ``fold(N p / 120, fs)`` (Eq. 4.1, :func:`fold_frequency`),
    tolerance 1.5 frequency bins; the region starts at the lowest speed from which
    ``stator_consecutive`` plateaus in a row are stator-dominated (thesis: 1100 rpm). The
    linearity search then runs on the plateaus from there up, so the region starts at the
    higher of the two limits (a stator line that dominates already in the low-speed friction
    region does not drag the line). Without spectra only the linearity criterion is used.
    """
    if isinstance(speed_rpm, pd.DataFrame):
        stats = speed_rpm
        if current_a is None:
            current_a = stats["current_a"].to_numpy()
        speed_rpm = stats["speed_rpm"].to_numpy()
    if current_a is None:
        raise ConfigError("current_a is required unless speed_rpm is an air_cut_statistics frame")
    n0 = np.abs(np.asarray(speed_rpm, dtype=np.float64))
    i0 = np.abs(np.asarray(current_a, dtype=np.float64))
    if n0.shape != i0.shape:
        raise ConfigError(f"speed_rpm has {n0.size} values, current_a {i0.size}")
    if segments is not None and len(segments) != n0.size:
        raise ConfigError(f"segments has {len(segments)} entries for {n0.size} plateaus")
    order = np.argsort(n0, kind="stable")
    n, cur = n0[order], i0[order]
    if n.size < min_points + n_consecutive:
        raise IdentificationError(
            f"linear_region needs at least {min_points + n_consecutive} plateaus, got {n.size}"
        )
    sigma = float(noise_a) if noise_a is not None else _noise_sigma(cur)
    sigma = max(sigma, 1e-9 * max(float(np.max(np.abs(cur))), 1.0))
    table = pd.DataFrame({"speed_rpm": n, "current_a": cur})
    lo_idx: int | None = None
    reason_lo = ""
    if segments is not None:
        if fs_hz is None:
            raise ConfigError("fs_hz is required with segments")
        segs = [np.asarray(segments[k], dtype=np.float64) for k in order]
        lines = [dominant_line(s, fs_hz=fs_hz, fmin_hz=fmin_hz) for s in segs]
        dom = np.array([ln.freq_hz for ln in lines])
        tol = np.array([1.5 * fs_hz / max(s.size, 1) for s in segs])
        if poles is None:
            poles = estimate_poles(n, dom, fs_hz=fs_hz, candidates=pole_candidates, tol_hz=tol)
        alias = fold_frequency(stator_frequency_hz(n, poles), fs_hz)
        flags = np.abs(dom - alias) <= tol
        table["dominant_hz"] = dom
        table["stator_alias_hz"] = alias
        table["stator_dominant"] = flags
        for k in range(n.size - stator_consecutive + 1):
            if flags[k : k + stator_consecutive].all():
                lo_idx = k
                break
        if lo_idx is None:
            raise IdentificationError(
                f"the folded stator line ({poles} poles) is never the dominant current line on "
                f"{stator_consecutive} consecutive plateaus; check poles= or fmin_hz"
            )
        below = [f"{n[k]:.0f} rpm: {dom[k]:.1f} Hz vs stator {alias[k]:.1f} Hz"
                 for k in range(max(0, lo_idx - 2), lo_idx)]
        reason_lo = (
            f"from {n[lo_idx]:.0f} rpm the folded stator line fold(N*{poles}/120) is the "
            f"dominant line of the current spectrum on {stator_consecutive}+ consecutive "
            f"plateaus ({dom[lo_idx]:.1f} Hz vs {alias[lo_idx]:.1f} Hz)"
            + (f"; below it the dominant line is elsewhere ({'; '.join(below)})" if below else "")
        )
    first = 0 if lo_idx is None else lo_idx
    if n.size - first < min_points:
        raise IdentificationError(
            f"only {n.size - first} plateaus above the lower limit {n[first]:.0f} rpm; "
            f"need {min_points}"
        )
    sub, r_lo_lin, reason_hi = _longest_linear(
        n[first:], cur[first:], sigma, k_sigma=k_sigma, n_consecutive=n_consecutive,
        min_points=min_points,
    )
    idx = [k + first for k in sub]
    if lo_idx is None:
        reason_lo = "without spectra: " + r_lo_lin
    elif min(idx) > lo_idx:
        reason_lo += (
            f"; the mean current is linear in speed only from {n[min(idx)]:.0f} rpm "
            f"(low-speed friction): {r_lo_lin}"
        )
    in_region = np.zeros(n.size, dtype=bool)
    in_region[min(idx) : max(idx) + 1] = True
    table["in_region"] = in_region
    return LinearRegion(
        lo_rpm=float(n[min(idx)]),
        hi_rpm=float(n[max(idx)]),
        reason_lo=reason_lo,
        reason_hi=reason_hi,
        poles=poles,
        noise_a=sigma,
        table=table,
    )


def linear_region_from_recording(
    rec: Recording,
    plateaus: pd.DataFrame | None = None,
    *,
    spindle: str = "SP1",
    poles: int | None = None,
    k_sigma: float = 3.0,
    min_points: int = 5,
) -> LinearRegion:
    """:func:`linear_region` on an air-cut sweep recording (statistics and spectra).

    Parameters
    ----------
    rec : Recording
        The recording.
    plateaus : pandas.DataFrame, optional
        Plateaus (:func:`find_plateaus`); default found in ``rec``.
    spindle : str, default 'SP1'
        Spindle axis name.
    poles : int, optional
        Motor poles (the stator-line filter); default from the machine description.
    k_sigma : float, default 3.0
        Residual threshold in standard deviations for the end of the linear region.
    min_points : int, default 5
        Fewest plateaus in the region.

    Returns
    -------
    LinearRegion
    """
    if plateaus is None:
        plateaus = speed_plateaus(rec, spindle=spindle)
    stats = air_cut_statistics(rec, plateaus, spindle=spindle)
    p_sorted = plateaus.assign(_n=plateaus["speed_rpm"].abs()).sort_values("_n", kind="stable")
    segs = plateau_segments(rec, p_sorted, spindle=spindle)
    return linear_region(
        stats["speed_rpm"].abs().to_numpy(),
        stats["current_a"].to_numpy(),
        segments=segs,
        fs_hz=rec.fs_hz,
        poles=poles,
        k_sigma=k_sigma,
        min_points=min_points,
    )


# ====================================================================== the model (Eq. 3.1/4.4)
def _domega_dt(speed_rpm: NDArray[np.float64], fs_hz: float) -> NDArray[np.float64]:
    """dOmega/dt [rad/s^2]: central differences inside, one-sided at the ends (np.gradient)."""
    w = speed_rpm * RPM_TO_RAD_S
    d = np.empty_like(w)
    if w.size < 2:
        d[:] = 0.0
        return d
    half = 0.5 * fs_hz
    d[1:-1] = (w[2:] - w[:-2]) * half
    d[0] = (w[1] - w[0]) * fs_hz
    d[-1] = (w[-1] - w[-2]) * fs_hz
    return d


@dataclass(frozen=True)
class SpindleModel:
    """Mechanical spindle model of thesis Eq. (3.1): ``Kt I = B n + J dOmega/dt + tau_f + tau_c``.

    Parameters
    ----------
    kt_nm_per_a : float
        Torque constant [Nm/A] (thesis: 1.04).
    b_nm_per_rpm : float
        Viscous friction coefficient per rpm [Nm/rpm] (thesis: 8.42e-5).
    tau_f_nm : float
        Coulomb friction torque [Nm] (thesis: 0.35).
    j_kgm2 : float, default 0.0
        Inertia of rotor + spindle + tool holder [kg m^2] (not given in the thesis).
    kt_temp_coeff_per_k : float, default 0.0
        Relative change of Kt per kelvin of motor temperature [1/K]; NdFeB magnets lose about
        0.09-0.12 %/K (docs/reference/physics-and-performance.md §2), i.e. about -0.001.
    b_temp_coeff_per_k, tau_f_temp_coeff_per_k : float, default 0.0
        Relative change of B and tau_f per kelvin [1/K], if identified.
    reference_temperature_c : float or None, default None
        Motor temperature at which the parameters were identified [degC]; required to use
        ``temperature_c`` in :meth:`cutting_torque` with non-zero coefficients.
    flux_base_speed_rpm : float, default 0.0
        Base speed of the constant-power range [rpm]: above it the torque per reported current
        falls as ``(n_b / |n|)^flux_exponent`` (:meth:`kt_at_speed`, the flux weakening of an
        induction spindle); 0 = Kt does not depend on the speed.
    flux_exponent : float, default 1.0
        Exponent of that law [-] (1 = constant power).
    kt_valid_speed_rpm : tuple of float or None, default None
        Speed range Kt (and the flux law) was calibrated over [rpm]; an estimate outside it is
        an extrapolation (:meth:`kt_extrapolated`).
    stribeck_torque_nm : float, default 0.0
        Low-speed (Stribeck, mixed-lubrication) friction ``tau_s`` on top of the Coulomb
        friction: ``tau_s exp(-|n| / n_s) sign(n)`` [Nm] (the improved calibration fits it
        with B and tau_f, :func:`cnctwin.twin.fit_friction_stribeck`); 0 = none.
    stribeck_speed_rpm : float, default 1.0
        Its decay speed ``n_s`` [rpm].

    Notes
    -----
    Speeds are in rpm as in the thesis; ``B`` per rpm is ``B_SI = B * 60/(2 pi)`` in Nm s/rad
    (8.42e-5 Nm/rpm = 8.04e-4 Nm s/rad). The Coulomb term carries the sign of the speed, so
    the model also holds for reverse rotation (M4); the thesis (all M3) writes it without sign.
    """

    kt_nm_per_a: float
    b_nm_per_rpm: float
    tau_f_nm: float
    j_kgm2: float = 0.0
    kt_temp_coeff_per_k: float = 0.0
    b_temp_coeff_per_k: float = 0.0
    tau_f_temp_coeff_per_k: float = 0.0
    reference_temperature_c: float | None = None
    flux_base_speed_rpm: float = 0.0
    flux_exponent: float = 1.0
    kt_valid_speed_rpm: tuple[float, float] | None = None
    stribeck_torque_nm: float = 0.0
    stribeck_speed_rpm: float = 1.0

    def __post_init__(self) -> None:
        if not (self.stribeck_torque_nm >= 0 and self.stribeck_speed_rpm > 0):
            raise ConfigError("stribeck_torque_nm must be >= 0 and stribeck_speed_rpm > 0; got "
                              f"{self.stribeck_torque_nm}, {self.stribeck_speed_rpm}")

    def stribeck_nm(self, speed_rpm: ArrayLike) -> NDArray[np.float64]:
        """The low-speed friction ``tau_s exp(-|n| / n_s) sign(n)`` [Nm] (0 without it)."""
        n = np.asarray(speed_rpm, dtype=np.float64)
        if not self.stribeck_torque_nm:
            return np.zeros(n.shape)
        return np.asarray(self.stribeck_torque_nm * np.exp(-np.abs(n) / self.stribeck_speed_rpm)
                          * np.sign(n), dtype=np.float64)

    def describe(self) -> str:
        """The parameters in words with units, as pages and reports show them.

        Returns
        -------
        str
            E.g. ``"Kt 1.01 Nm/A, B 8.3e-05 Nm/rpm, tau_f 0.34 Nm, J 0.0045 kg m^2"``, with
            the temperature and field-weakening terms where they are set.

        Examples
        --------
        >>> SpindleModel(kt_nm_per_a=1.01, b_nm_per_rpm=8.3e-5, tau_f_nm=0.34,
        ...              j_kgm2=0.0045).describe()
        'Kt 1.01 Nm/A, B 8.3e-05 Nm/rpm, tau_f 0.34 Nm, J 0.0045 kg m^2'
        """
        parts = [f"Kt {self.kt_nm_per_a:.4g} Nm/A", f"B {self.b_nm_per_rpm:.4g} Nm/rpm",
                 f"tau_f {self.tau_f_nm:.4g} Nm", f"J {self.j_kgm2:.4g} kg m^2"]
        if self.kt_temp_coeff_per_k or self.b_temp_coeff_per_k or self.tau_f_temp_coeff_per_k:
            parts.append(f"temperature coefficients Kt {self.kt_temp_coeff_per_k:.3g}, "
                         f"B {self.b_temp_coeff_per_k:.3g}, tau_f "
                         f"{self.tau_f_temp_coeff_per_k:.3g} 1/K from "
                         f"{self.reference_temperature_c:.4g} °C"
                         if self.reference_temperature_c is not None else
                         f"temperature coefficient Kt {self.kt_temp_coeff_per_k:.3g} 1/K")
        if self.stribeck_torque_nm:
            parts.append(f"Stribeck {self.stribeck_torque_nm:.3g} Nm decaying over "
                         f"{self.stribeck_speed_rpm:.0f} rpm")
        if self.flux_base_speed_rpm > 0:
            parts.append(f"field weakening above {self.flux_base_speed_rpm:.0f} rpm "
                         f"(exponent {self.flux_exponent:.3g})")
        if self.kt_valid_speed_rpm is not None:
            lo, hi = self.kt_valid_speed_rpm
            parts.append(f"calibrated {lo:.0f}-{hi:.0f} rpm")
        return ", ".join(parts)

    def flux_factor(self, speed_rpm: ArrayLike) -> NDArray[np.float64]:
        """``(n_b / |n|)^exponent`` above the base speed, 1 below (and without a law) [-]."""
        n = np.abs(np.asarray(speed_rpm, dtype=np.float64))
        if not self.flux_base_speed_rpm > 0:
            return np.ones_like(n)
        with np.errstate(divide="ignore"):
            f = np.where(n > self.flux_base_speed_rpm,
                         (self.flux_base_speed_rpm / np.maximum(n, 1e-12))
                         ** self.flux_exponent, 1.0)
        return np.asarray(f, dtype=np.float64)

    def kt_at_speed(self, speed_rpm: ArrayLike) -> NDArray[np.float64]:
        """Torque per reported current at a speed: ``Kt (n_b/|n|)^exponent`` above n_b [Nm/A].

        Examples
        --------
        >>> m = SpindleModel(1.0, 8e-5, 0.3, flux_base_speed_rpm=2000.0)
        >>> m.kt_at_speed([1000.0, 4000.0]).tolist()
        [1.0, 0.5]
        """
        return self.kt_nm_per_a * self.flux_factor(speed_rpm)

    def kt_extrapolated(self, speed_rpm: ArrayLike) -> NDArray[np.bool_]:
        """True where a speed lies outside the calibrated range (``kt_valid_speed_rpm``)."""
        n = np.abs(np.asarray(speed_rpm, dtype=np.float64))
        if self.kt_valid_speed_rpm is None:
            return np.zeros(n.shape, dtype=bool)
        lo, hi = self.kt_valid_speed_rpm
        tol = 0.02 * hi
        return np.asarray((n < lo - tol) | (n > hi + tol))

    @classmethod
    def from_parameters(cls, name: str, **overrides: float) -> SpindleModel:
        """A model from :data:`SPINDLE_MODEL_PARAMETERS` (``'thesis_spinner_840dsl'``)."""
        if name not in SPINDLE_MODEL_PARAMETERS:
            raise KeyError(
                f"unknown spindle parameter set {name!r}; valid: "
                f"{', '.join(SPINDLE_MODEL_PARAMETERS)} (cnctwin.spindle.SPINDLE_MODEL_PARAMETERS)"
            )
        kw: dict[str, Any] = {**SPINDLE_MODEL_PARAMETERS[name], **overrides}
        return cls(**kw)

    @classmethod
    def from_machine(cls, machine_file: MachineFile) -> SpindleModel:
        """The spindle twin of a machine file (:mod:`cnctwin.machine.file`).

        Kt, B and tau_f are the file's ``spindle.kt_nm_per_a``,
        ``viscous_friction_nm_per_rpm`` and ``coulomb_friction_nm``, referred to
        ``kt_ref_temperature_c`` with the magnet coefficient ``magnet_temp_coeff_per_k``
        where the file states a calibrated reference temperature; J is used only where it was
        identified (else 0: no acceleration term). Whether the values were calibrated is for
        the caller to check (:meth:`MachineFile.is_identified`). The Stribeck term is used
        where the calibration identified it (``stribeck_torque_nm``, ``stribeck_speed_rpm``).
        """
        s = machine_file.machine.spindle
        calibrated_t = machine_file.is_identified("spindle.kt_ref_temperature_c")
        strib = (machine_file.is_identified("spindle.stribeck_torque_nm")
                 and machine_file.is_identified("spindle.stribeck_speed_rpm"))
        return cls(
            kt_nm_per_a=s.kt_nm_per_a, b_nm_per_rpm=s.viscous_friction_nm_per_rpm,
            tau_f_nm=s.coulomb_friction_nm,
            j_kgm2=s.inertia_kg_m2 if machine_file.is_identified("spindle.inertia_kg_m2")
            else 0.0,
            kt_temp_coeff_per_k=s.magnet_temp_coeff_per_k if calibrated_t else 0.0,
            reference_temperature_c=s.kt_ref_temperature_c if calibrated_t else None,
            flux_base_speed_rpm=s.flux_base_speed_rpm, flux_exponent=s.flux_exponent,
            kt_valid_speed_rpm=rec.valid_range
            if (rec := machine_file.record("spindle.kt_nm_per_a")) is not None else None,
            stribeck_torque_nm=s.stribeck_torque_nm if strib else 0.0,
            stribeck_speed_rpm=s.stribeck_speed_rpm if strib else 1.0)

    def to_dict(self) -> dict[str, float | None]:
        """Parameters as a plain dict (for JSON/TOML)."""
        return asdict(self)

    @property
    def b_nm_s_per_rad(self) -> float:
        """Viscous friction in SI units [Nm s/rad]."""
        return self.b_nm_per_rpm / RPM_TO_RAD_S

    def _params_at(
        self, temperature_c: ArrayLike | None
    ) -> tuple[Any, Any, Any]:
        if temperature_c is None:
            return self.kt_nm_per_a, self.b_nm_per_rpm, self.tau_f_nm
        coeffs = (self.kt_temp_coeff_per_k, self.b_temp_coeff_per_k, self.tau_f_temp_coeff_per_k)
        if not any(coeffs):
            return self.kt_nm_per_a, self.b_nm_per_rpm, self.tau_f_nm
        if self.reference_temperature_c is None:
            raise ConfigError(
                "temperature_c given but the model has no reference_temperature_c; set it to "
                "the motor temperature at identification"
            )
        dt = np.asarray(temperature_c, dtype=np.float64) - self.reference_temperature_c
        return (
            self.kt_nm_per_a * (1.0 + self.kt_temp_coeff_per_k * dt),
            self.b_nm_per_rpm * (1.0 + self.b_temp_coeff_per_k * dt),
            self.tau_f_nm * (1.0 + self.tau_f_temp_coeff_per_k * dt),
        )

    def friction_torque_nm(
        self, speed_rpm: ArrayLike, *, temperature_c: ArrayLike | None = None
    ) -> NDArray[np.float64]:
        """Friction torque ``B n + tau_f sign(n)`` (+ the Stribeck term) [Nm]."""
        n = np.asarray(speed_rpm, dtype=np.float64)
        _, b, tf = self._params_at(temperature_c)
        return np.asarray(b * n + tf * np.sign(n) + self.stribeck_nm(n), dtype=np.float64)

    def cutting_torque(
        self,
        current_a: ArrayLike,
        speed_rpm: ArrayLike,
        *,
        accel_term: bool = True,
        temperature_c: ArrayLike | None = None,
        fs_hz: float = 500.0,
    ) -> NDArray[np.float64]:
        """Cutting torque from spindle current and speed (thesis Eq. 3.1 / 4.4).

        Parameters
        ----------
        current_a : array-like
            Spindle q-axis current [A] (``CURRENT|SP1``).
        speed_rpm : array-like
            Spindle speed [rpm], same shape (``CMD_SPEED|SP1``).
        accel_term : bool, default True
            Subtract ``J dOmega/dt`` (needs a time series; skipped for J = 0 or one sample).
        temperature_c : float or array-like, optional
            Motor temperature [degC] for the temperature compensation of Kt (and B, tau_f).
        fs_hz : float, default 500.0
            Sample rate for the derivative [Hz].

        Returns
        -------
        numpy.ndarray
            ``tau_c = Kt I - B n - tau_f sign(n) - J dOmega/dt`` [Nm], Omega in rad/s (and
            minus the Stribeck term, :meth:`stribeck_nm`, where the model has one).

        Notes
        -----
        ``dOmega/dt`` uses central differences inside and one-sided differences at the ends
        (as :func:`numpy.gradient`); :class:`StreamingTorqueEstimator` reproduces it exactly
        across chunk boundaries.

        Examples
        --------
        >>> m = SpindleModel(1.04, 8.42e-5, 0.35)   # thesis Eq. (4.4)
        >>> round(float(m.cutting_torque(4.32, 2400.0)), 2)   # Table 4.1, cast iron 2400 rpm
        3.94
        """
        i = np.asarray(current_a, dtype=np.float64)
        n = np.asarray(speed_rpm, dtype=np.float64)
        if i.shape != n.shape:
            i, n = np.broadcast_arrays(i, n)
        kt, b, tf = self._params_at(temperature_c)
        if self.flux_base_speed_rpm > 0:
            kt = kt * self.flux_factor(n)
        tau = kt * i - b * n - tf * np.sign(n)
        if self.stribeck_torque_nm:
            tau = tau - self.stribeck_nm(n)
        if accel_term and self.j_kgm2 != 0.0 and n.ndim == 1 and n.size >= 2:
            tau = tau - self.j_kgm2 * _domega_dt(n, fs_hz)
        return np.asarray(tau, dtype=np.float64)

    def predict_current_a(
        self,
        torque_nm: ArrayLike,
        speed_rpm: ArrayLike,
        *,
        temperature_c: ArrayLike | None = None,
    ) -> NDArray[np.float64]:
        """Current needed for a cutting torque at constant speed [A] (Eq. 4.4 solved for I)."""
        n = np.asarray(speed_rpm, dtype=np.float64)
        kt, b, tf = self._params_at(temperature_c)
        if self.flux_base_speed_rpm > 0:
            kt = kt * self.flux_factor(n)
        need = np.asarray(torque_nm, dtype=np.float64) + b * n + tf * np.sign(n)
        if self.stribeck_torque_nm:
            need = need + self.stribeck_nm(n)
        return np.asarray(need / kt)


# ====================================================================== speed law of Kt
@dataclass(frozen=True)
class FluxLawFit:
    """Kt over the speed range: ``Kt(n) = Kt0 (n_b / n)^gamma`` above the base speed n_b.

    Attributes
    ----------
    kt_nm_per_a : float
        Kt below the base speed [Nm/A].
    base_speed_rpm : float
        Base speed n_b [rpm]; 0 when Kt does not change over the calibration speeds.
    exponent : float
        gamma [-]; 1 (constant power) unless three or more speeds fitted it.
    exponent_fitted : bool
        gamma was identified (else it is the stated constant-power value 1).
    base_speed_bound : str
        ``""`` if n_b lies inside the calibration speeds; ``"at most"`` if every speed was
        above it (Kt0 and n_b are then only known as their product, n_b is set to the lowest
        speed); ``"at least"`` if no speed was above it.
    speeds_rpm, kt_values : tuple of float
        The calibration points [rpm], [Nm/A].
    rms_rel : float
        Relative rms residual of the law at the points [-].
    """

    kt_nm_per_a: float
    base_speed_rpm: float
    exponent: float
    exponent_fitted: bool
    base_speed_bound: str
    speeds_rpm: tuple[float, ...]
    kt_values: tuple[float, ...]
    rms_rel: float


def fit_flux_law(speed_rpm: ArrayLike, kt_nm_per_a: ArrayLike, *,
                 rel_tol: float = 0.01) -> FluxLawFit:
    """Fit the speed law of the torque constant to Kt measured at several speeds.

    Parameters
    ----------
    speed_rpm : array-like
        Speeds of the calibration cuts [rpm] (at least 2 distinct).
    kt_nm_per_a : array-like
        Kt measured at each [Nm/A].
    rel_tol : float, default 0.01
        Relative change below which two Kt count as equal (no flux weakening between them).

    Returns
    -------
    FluxLawFit

    Raises
    ------
    IdentificationError
        Fewer than two distinct speeds.

    Notes
    -----
    Above its base speed an induction spindle runs with its flux reduced as 1/n (constant
    power): the torque per torque-producing current falls as ``n_b / n`` (Kt x speed constant,
    as the KIT DMC 60H data show over 2400-4000 rpm). With two speeds the exponent is the
    constant-power 1 and n_b follows from the ratio ``n_b = n2 Kt2 / Kt1`` when the base speed
    lies between them; with three or more speeds the exponent is fitted too (grid 0.5-1.5).
    """
    n = np.abs(np.asarray(speed_rpm, dtype=np.float64)).ravel()
    k = np.asarray(kt_nm_per_a, dtype=np.float64).ravel()
    ok = np.isfinite(n) & np.isfinite(k) & (k > 0)
    n, k = n[ok], k[ok]
    order = np.argsort(n)
    n, k = n[order], k[order]
    distinct = np.unique(np.round(n))
    if distinct.size < 2:
        raise IdentificationError(
            f"the speed law of Kt needs calibration cuts at 2 or more speeds; got "
            f"{', '.join(f'{v:.0f}' for v in distinct) or 'none'} rpm")

    def law(kt0: float, nb: float, g: float) -> NDArray[np.float64]:
        return kt0 * np.where(n > nb, (nb / n) ** g, 1.0)

    def best_for(g: float) -> tuple[float, float, float]:
        cands = np.concatenate([np.linspace(0.5 * n[0], n[-1], 400), n])
        best = (np.inf, 0.0, 0.0)
        for nb in cands:
            shape = np.where(n > nb, (nb / n) ** g, 1.0)
            kt0 = float(np.sum(shape * k) / np.sum(shape * shape))
            r = float(np.sum(((law(kt0, nb, g) - k) / k) ** 2))
            if r < best[0] - 1e-15:
                best = (r, kt0, float(nb))
        return best

    spread = float(np.ptp(k) / np.mean(k))
    if spread <= rel_tol:
        return FluxLawFit(float(np.mean(k)), 0.0, 1.0, False, "at least",
                          tuple(float(v) for v in n), tuple(float(v) for v in k),
                          float(np.sqrt(np.mean((k / np.mean(k) - 1) ** 2))))
    fit_g = distinct.size >= 3
    grid = np.linspace(0.5, 1.5, 101) if fit_g else np.array([1.0])
    r, kt0, nb, g = min((*best_for(float(gg)), float(gg)) for gg in grid)
    bound = ""
    if nb <= n[0] + 1e-9:
        bound = "at most"
        nb = float(n[0])
        kt0 = float(k[0])
    return FluxLawFit(kt0, nb, g, fit_g, bound, tuple(float(v) for v in n),
                      tuple(float(v) for v in k), float(np.sqrt(r / n.size)))


# ====================================================================== calibration (Eq. 4.3)
def calibrate(
    fit: FrictionFit,
    current_a: ArrayLike,
    torque_nm: ArrayLike,
    speed_rpm: ArrayLike,
    *,
    j_kgm2: float = 0.0,
    kt_temp_coeff_per_k: float = 0.0,
    reference_temperature_c: float | None = None,
) -> SpindleModel:
    """Torque constant from one cut with a dynamometer, then B and tau_f (thesis Eq. 4.3).

    Parameters
    ----------
    fit : FrictionFit
        Air-cut line ``I = a n + b`` (:func:`fit_friction`).
    current_a : float or array-like
        Spindle current during the cut [A]; arrays are averaged (thesis: mean over the first
        0.6 s of the cutting region, 4.36 A).
    torque_nm : float or array-like
        Dynamometer cutting torque over the same samples [Nm] (thesis: 3.97 Nm).
    speed_rpm : float or array-like
        Spindle speed [rpm] (thesis: 2400 rpm).
    j_kgm2 : float, default 0.0
        Inertia to store in the model [kg m^2] (:func:`identify_inertia`).
    kt_temp_coeff_per_k : float, default 0.0
        Temperature coefficient of Kt to store [1/K].
    reference_temperature_c : float, optional
        Motor temperature during calibration [degC].

    Returns
    -------
    SpindleModel
        ``Kt = tau_c / (I - a n - b)``, ``B = a Kt``, ``tau_f = b Kt``.

    Raises
    ------
    IdentificationError
        If the current does not exceed the air-cut current (no cut, or wrong window).

    Notes
    -----
    At constant speed Eq. (3.1) gives ``Kt I = B n + tau_f + tau_c``; with ``a = B/Kt`` and
    ``b = tau_f/Kt`` from the air cut, ``Kt = tau_c / (I - a n - b)`` (thesis Eq. 4.3:
    ``3.97 / (4.36 - 8.1e-5 * 2400 - 0.34) = 1.04 Nm/A``). Means are used, so the
    acceleration term averages out over a constant-speed window.

    Examples
    --------
    >>> fit = FrictionFit(8.1e-5, 0.34, 0.94, 0.14, 10, 0.0, 0.0, 1100.0, 5000.0)
    >>> round(calibrate(fit, 4.36, 3.97, 2400.0).kt_nm_per_a, 2)
    1.04
    """
    i = float(np.nanmean(np.asarray(current_a, dtype=np.float64)))
    tau = float(np.nanmean(np.asarray(torque_nm, dtype=np.float64)))
    n = float(np.nanmean(np.asarray(speed_rpm, dtype=np.float64)))
    if not all(np.isfinite([i, tau, n])):
        raise IdentificationError("current, torque or speed has no finite sample in the window")
    i_cut = abs(i) - (fit.slope_a_per_rpm * abs(n) + fit.offset_a)
    if i_cut <= 1e-3 * max(abs(i), 1e-9) or abs(tau) <= 0:
        raise IdentificationError(
            f"the cut current {i:.4g} A does not exceed the air-cut current "
            f"{fit.slope_a_per_rpm * abs(n) + fit.offset_a:.4g} A at {n:.0f} rpm (or the torque "
            f"{tau:.4g} Nm is zero): no cut in the window; check the cutting region and window"
        )
    kt = abs(tau) / i_cut
    return SpindleModel(
        kt_nm_per_a=kt,
        b_nm_per_rpm=fit.slope_a_per_rpm * kt,
        tau_f_nm=fit.offset_a * kt,
        j_kgm2=j_kgm2,
        kt_temp_coeff_per_k=kt_temp_coeff_per_k,
        reference_temperature_c=reference_temperature_c,
    )


@dataclass(frozen=True)
class CutMeasurement:
    """Means over the start of one cutting region (a row of thesis Table 4.1).

    Attributes
    ----------
    workpiece : str
        Material label.
    speed_rpm : float
        Mean spindle speed [rpm].
    feed_mm_per_rev : float
        Feed per revolution [mm/rev] (NaN if unknown).
    current_a : float
        Mean spindle current [A].
    torque_nm : float
        Mean dynamometer cutting torque [Nm] (NaN without dynamometer).
    start_cycle, end_cycle : int
        Window averaged (inclusive cycles).
    """

    workpiece: str
    speed_rpm: float
    feed_mm_per_rev: float
    current_a: float
    torque_nm: float
    start_cycle: int = -1
    end_cycle: int = -1


def measure_cut(
    rec: Recording,
    region: pd.Series | tuple[int, int],
    *,
    window_s: float = 0.6,
    spindle: str = "SP1",
    dynamometer: str | None = "dynamometer",
    torque_column: str = "mz_nm",
    workpiece: str = "",
    feed_mm_per_rev: float = float("nan"),
) -> CutMeasurement:
    """Mean current, torque and speed over the first ``window_s`` of a cutting region.

    Parameters
    ----------
    rec : Recording
        Recording; the dynamometer channel must be aligned (:func:`align_external`).
    region : pandas.Series or (int, int)
        A row of :func:`~cnctwin.analysis.segments.cutting_regions` or (start, end) cycles.
    window_s : float, default 0.6
        Averaging window from the region start (thesis §4.3: first 0.6 s, "in order not to be
        affected by ... increasing tool tip temperature") [s].
    spindle : str, default 'SP1'
        Spindle axis.
    dynamometer : str or None, default 'dynamometer'
        External channel with the cutting torque; None leaves ``torque_nm`` NaN.
    torque_column : str, default 'mz_nm'
        Column of the torque in that channel.
    workpiece : str, optional
        Label.
    feed_mm_per_rev : float, optional
        Feed [mm/rev].

    Returns
    -------
    CutMeasurement
    """
    if isinstance(region, pd.Series):
        start, end = int(region["start_cycle"]), int(region["end_cycle"])
    else:
        start, end = int(region[0]), int(region[1])
    stop = min(end, start + round(window_s * rec.fs_hz) - 1)
    cyc = rec.cycles
    lo = int(np.searchsorted(cyc, start, side="left"))
    hi = int(np.searchsorted(cyc, stop, side="right"))
    if hi <= lo:
        raise IdentificationError(f"no HF cycle between {start} and {stop}")
    current = rec.signal(f"CURRENT|{spindle}").to_numpy(dtype=np.float64)[lo:hi]
    speed, _ = spindle_speed_rpm(rec, spindle)
    torque = float("nan")
    if dynamometer is not None:
        ext = external_on_hf(rec, dynamometer, columns=[torque_column])
        tv = ext[torque_column].to_numpy(dtype=np.float64)[lo:hi]
        if not np.isfinite(tv).any():
            raise IdentificationError(
                f"the dynamometer channel {dynamometer!r} does not cover cycles {start}-{stop} "
                "(after alignment); check its offset_s"
            )
        torque = float(np.nanmean(tv))
    return CutMeasurement(
        workpiece=workpiece,
        speed_rpm=float(np.nanmean(speed[lo:hi])),
        feed_mm_per_rev=float(feed_mm_per_rev),
        current_a=float(np.nanmean(current)),
        torque_nm=torque,
        start_cycle=int(cyc[lo]),
        end_cycle=int(cyc[hi - 1]),
    )


def calibrate_from_recording(
    fit: FrictionFit,
    rec: Recording,
    *,
    dynamometer: str = "dynamometer",
    torque_column: str = "mz_nm",
    window_s: float = 0.6,
    spindle: str = "SP1",
    z_axis: str | None = "Z1",
    regions: pd.DataFrame | None = None,
    region_index: int = 0,
    align: bool = True,
    max_lag_s: float | None = None,
    j_kgm2: float = 0.0,
) -> SpindleModel:
    """:func:`calibrate` on a drilling recording with a dynamometer channel.

    Segments the cuts (:func:`~cnctwin.analysis.segments.cutting_regions`), aligns the
    dynamometer to the spindle current by cross-correlation unless it is already aligned
    (:func:`~cnctwin.analysis.align.align_external`), averages current, torque and speed over
    the first ``window_s`` of cut ``region_index`` (:func:`measure_cut`) and calls
    :func:`calibrate`.

    Parameters
    ----------
    fit : FrictionFit
        Air-cut friction line.
    rec : Recording
        Drilling recording with ``rec.external[dynamometer]``.
    dynamometer, torque_column : str
        Channel and column of the measured cutting torque.
    window_s : float, default 0.6
        Averaging window from the start of the cut [s] (thesis §4.3).
    spindle : str, default 'SP1'
        Spindle axis.
    z_axis : str or None, default 'Z1'
        Feed axis for the segmentation.
    regions : pandas.DataFrame, optional
        Precomputed cutting regions.
    region_index : int, default 0
        Which cut to calibrate on.
    align : bool, default True
        Align the dynamometer first if ``aligned`` is False.
    max_lag_s : float, optional
        Largest clock offset searched [s].
    j_kgm2 : float, default 0.0
        Inertia to store in the model [kg m^2].

    Returns
    -------
    SpindleModel
    """
    if dynamometer not in rec.external:
        raise SignalNotFoundError(
            f"no external channel {dynamometer!r} (the dynamometer) in this recording; it has: "
            f"{', '.join(rec.external) or 'none'}"
        )
    if align and not rec.external[dynamometer].aligned:
        rec = align_external(rec, dynamometer, reference_signal=f"CURRENT|{spindle}",
                             channel_column=torque_column, max_lag_s=max_lag_s)
    if regions is None:
        regions = cutting_regions(rec, spindle=spindle, z_axis=z_axis)
    if len(regions) <= region_index:
        raise IdentificationError(
            f"found {len(regions)} cutting regions, cannot use index {region_index}; check "
            "cutting_regions thresholds"
        )
    cut = measure_cut(rec, regions.iloc[region_index], window_s=window_s, spindle=spindle,
                      dynamometer=dynamometer, torque_column=torque_column)
    return calibrate(fit, cut.current_a, cut.torque_nm, cut.speed_rpm, j_kgm2=j_kgm2)


# ====================================================================== inertia
def _fill(x: NDArray[np.float64]) -> NDArray[np.float64]:
    """Linear interpolation over NaN (ends held)."""
    return np.asarray(pd.Series(x).interpolate(limit_direction="both"), dtype=np.float64)


def _ramp_samples(speed: NDArray[np.float64], tau: NDArray[np.float64], fs: float,
                  lowpass_hz: float | None) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                                     NDArray[np.float64], NDArray[np.bool_]]:
    """Speed [rpm] and torque [Nm] with gaps filled and low-passed, dOmega/dt [rad/s^2], and
    where both were measured (the inertia fits' common preparation).

    The central difference of the speed is the mean of dOmega/dt over the two cycles around
    a sample (a box over +-1 cycle; of an encoder speed, itself a central difference, a
    triangle over +-2 cycles); the torque gets the same average, ``(t[k-1] + 2 t[k] +
    t[k+1]) / 4`` (the box's, and the triangle's, weights on cycle samples), so that both
    sides of ``J dOmega/dt = tau`` see the same window: without it the torque keeps the
    high frequencies of each run-up's start that the difference rounds off, and J came out
    0.3-0.5 % high on 0.1 s run-ups (simulated air cuts)."""
    ok = np.isfinite(speed) & np.isfinite(tau)
    speed = _fill(np.where(ok, speed, np.nan))
    tau = _fill(np.where(ok, tau, np.nan))
    if lowpass_hz is not None and speed.size > 30:
        speed = lowpass(speed, lowpass_hz, fs_hz=fs, order=2)
        tau = lowpass(tau, lowpass_hz, fs_hz=fs, order=2)
    if tau.size > 2:
        tau = np.concatenate([tau[:1], 0.25 * (tau[:-2] + tau[2:]) + 0.5 * tau[1:-1],
                              tau[-1:]])
    return speed, tau, _domega_dt(speed, fs), ok


def identify_inertia(
    rec_or_speed: Recording | ArrayLike,
    torque_nm: ArrayLike | None = None,
    *,
    fs_hz: float | None = None,
    spindle: str = "SP1",
    model: SpindleModel | None = None,
    lowpass_hz: float | None = 20.0,
    min_speed_rpm: float = 10.0,
    min_accel_rad_s2: float = 5.0,
) -> float:
    """Spindle inertia from run-ups and run-downs in air (least squares on Eq. 3.1).

    Parameters
    ----------
    rec_or_speed : Recording or array-like
        A recording with spindle ramps, or the speed samples [rpm].
    torque_nm : array-like, optional
        Motor torque [Nm] when passing arrays. With a Recording it is ``TORQUE|<spindle>``
        (torque setpoint) if recorded, else ``Kt * CURRENT|<spindle>`` from ``model``.
    fs_hz : float, optional
        Sample rate of the arrays [Hz] (a Recording knows its own).
    spindle : str, default 'SP1'
        Spindle axis.
    model : SpindleModel, optional
        Known friction (B, tau_f): then only J is fitted; otherwise J, B and tau_f are fitted
        together and J is returned.
    lowpass_hz : float or None, default 20.0
        Zero-phase low-pass of speed and torque before differentiating [Hz].
    min_speed_rpm : float, default 10.0
        Samples slower than this are left out (the sign of the Coulomb term is undefined).
    min_accel_rad_s2 : float, default 5.0
        The data must contain accelerations above this [rad/s^2]; otherwise the inertia is
        not identifiable.

    Returns
    -------
    float
        J [kg m^2].

    Notes
    -----
    Air cut, Eq. (3.1) with ``tau_c = 0``: ``tau_m = J dOmega/dt + B n + tau_f sign(n)``.
    Solved by linear least squares over all turning samples; the constant-speed samples pin
    the friction, the ramps the inertia.
    """
    if isinstance(rec_or_speed, Recording):
        rec = rec_or_speed
        fs = rec.fs_hz
        speed, _ = spindle_speed_rpm(rec, spindle, prefer_actual=True)
        t_col = f"TORQUE|{spindle}"
        if rec.has(t_col):
            tau = rec.hf[t_col].to_numpy(dtype=np.float64)
        elif model is not None:
            tau = model.kt_nm_per_a * rec.signal(f"CURRENT|{spindle}").to_numpy(np.float64)
        else:
            raise SignalNotFoundError(
                f"{t_col!r} is not recorded; pass model= so the torque is Kt * CURRENT"
            )
    else:
        if torque_nm is None or fs_hz is None:
            raise ConfigError("with arrays, torque_nm and fs_hz are required")
        speed = np.asarray(rec_or_speed, dtype=np.float64)
        tau = np.asarray(torque_nm, dtype=np.float64)
        fs = float(fs_hz)
    if speed.shape != tau.shape:
        raise ConfigError(f"speed has {speed.size} samples, torque {tau.size}")
    speed, tau, acc, ok = _ramp_samples(speed, tau, fs, lowpass_hz)
    m = ok & (np.abs(speed) >= min_speed_rpm)
    if not np.any(np.abs(acc[m]) >= min_accel_rad_s2):
        raise IdentificationError(
            f"no acceleration above {min_accel_rad_s2:g} rad/s^2 while turning: the inertia "
            "needs spindle run-ups or run-downs in the data"
        )
    if model is not None:
        y = tau[m] - model.friction_torque_nm(speed[m])
        a = acc[m]
        return float(np.dot(a, y) / np.dot(a, a))
    x = np.column_stack([acc[m], speed[m], np.sign(speed[m])])
    sol, *_ = np.linalg.lstsq(x, tau[m], rcond=None)
    return float(sol[0])


def inertia_uncertainty(
    rec: Recording,
    model: SpindleModel,
    *,
    spindle: str = "SP1",
    lowpass_hz: float = 20.0,
    min_speed_rpm: float = 300.0,
    min_accel_rad_s2: float = 5.0,
) -> float:
    """Standard uncertainty of the spindle inertia identified from an air cut's speed ramps.

    Parameters
    ----------
    rec : Recording
        The air cut (run-ups and run-downs between its plateaus).
    model : SpindleModel
        The calibrated model (Kt, friction) and its ``j_kgm2``.
    spindle : str, default 'SP1'
        Spindle axis.
    lowpass_hz : float, default 20.0
        Zero-phase low-pass of speed and torque before differentiating [Hz].
    min_speed_rpm : float, default 300.0
        Slower samples are left out (Stribeck zone, as the identification).
    min_accel_rad_s2 : float, default 5.0
        Samples accelerating less are left out [rad/s^2].

    Returns
    -------
    float
        u(J) [kg m^2]; NaN if the air cut has no run-up or no run-down.

    Notes
    -----
    ``tau_m - tau_friction(n) = J dOmega/dt`` fitted on the run-ups alone and on the
    run-downs alone: an error of the friction law (its temperature, its form) adds to the
    accelerating torque on the way up and takes from it on the way down, so the two fits
    differ by twice its effect on J. u(J) combines half their difference, a bound on that
    model error taken as rectangular (divided by sqrt 3, GUM 4.3.7), with the statistical
    standard error of the pooled fit, heteroscedasticity- and autocorrelation-consistent
    (Newey-West [1]_: the samples are low-passed, so neighbours share their noise; the
    AR(1) inflation used before overstated it about 1.7 times, its interval covered 100 of
    100 draws), and the method's dependence on its analysis bandwidth: the change of J when
    the low-pass halves, a bound taken as rectangular as well (J rises with the bandwidth by
    ~0.1 % per octave on simulated air cuts: the sampled current carries within-cycle
    dynamics that the acceleration, a 2-4 cycle difference, averages away). Measured
    coverage of the resulting 95 % interval: docs/validation-calibration.md.

    References
    ----------
    .. [1] W. K. Newey and K. D. West, "A simple, positive semi-definite, heteroskedasticity
       and autocorrelation consistent covariance matrix", Econometrica 55(3), 703-708, 1987.
    """
    speed0, _ = spindle_speed_rpm(rec, spindle, prefer_actual=True)
    tau0 = model.kt_nm_per_a * rec.signal(f"CURRENT|{spindle}").to_numpy(dtype=np.float64)

    def ramps(lp: float | None) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                         NDArray[np.float64], NDArray[np.bool_]]:
        """Speed, dOmega/dt, accelerating torque (friction taken out) and the ramp mask."""
        speed, tau, acc, ok = _ramp_samples(speed0, tau0, rec.fs_hz, lp)
        m = ok & (np.abs(speed) >= min_speed_rpm) & (np.abs(acc) >= min_accel_rad_s2)
        return speed, acc, tau - model.friction_torque_nm(speed), m

    def fit(acc: NDArray[np.float64], y: NDArray[np.float64], sel: NDArray[np.bool_]) -> float:
        return float(np.dot(acc[sel], y[sel]) / np.dot(acc[sel], acc[sel]))

    speed, acc, y, m = ramps(lowpass_hz)
    # accelerating the rotor's speed magnitude (up) or slowing it (down)
    up = m & (acc * np.sign(speed) > 0)
    down = m & (acc * np.sign(speed) < 0)
    if not up.any() or not down.any():
        return float("nan")
    j_up, j_down = fit(acc, y, up), fit(acc, y, down)
    j = model.j_kgm2
    # statistical part: Newey-West (Bartlett kernel) over the low-passed, hence correlated,
    # samples; lag window twice the filter's time scale (fs / f_c), products across the
    # masked gaps vanish (zeros outside the ramps)
    score = np.zeros(y.size)
    score[m] = acc[m] * (y[m] - j * acc[m])
    lags = max(10, round(2.0 * rec.fs_hz / lowpass_hz)) if lowpass_hz else 10
    lags = min(lags, score.size - 1)
    s_hac = float(score @ score) + 2.0 * sum(
        (1.0 - lag / (lags + 1.0)) * float(score[lag:] @ score[:-lag])
        for lag in range(1, lags + 1))
    se = math.sqrt(max(s_hac, 0.0)) / float(np.dot(acc[m], acc[m]))
    # the friction-law error moves the two fits apart symmetrically about the pooled one: the
    # pooled J lies within +-|j_up - j_down| / 2 of the truth from this cause, a bound taken
    # as a rectangular distribution (GUM 4.3.7: u = a / sqrt 3)
    u_law = 0.5 * abs(j_up - j_down) / math.sqrt(3.0)
    # the analysis bandwidth: J grows with it (the sampled current carries what the rotor's
    # 2 ms-averaged acceleration does not, ~0.1 % per octave on simulated air cuts); the
    # change from halving it bounds the method's dependence on it, taken as rectangular like
    # the law's (as one standard uncertainty the interval was 1.2x J's error scatter: rms z
    # 0.85, 198 of 200 covered, docs/validation-calibration.md)
    u_band = 0.0
    if lowpass_hz is not None:
        _, acc2, y2, m2 = ramps(0.5 * lowpass_hz)
        if m2.any():
            u_band = abs(fit(acc2, y2, m2) - fit(acc, y, m)) / math.sqrt(3.0)
    return math.hypot(se, u_law, u_band)


# ====================================================================== speed changes
class SpeedChangeFlags:
    """Which cycles' cutting-torque estimate is no cut: speed changes, settling, standstill.

    While the speed changes, the current mostly accelerates the rotor (``J dOmega/dt``: ~22 Nm
    on a 2400 rpm run-up in 0.17 s, against ~4 Nm of a drilling cut), known only as well as
    J and the measured acceleration, and a drive that steps its speed setpoint once per cycle
    instead of interpolating it samples a current that misses the cycle's mean torque by
    ~2 Nm (the simulated spindle with ``speed_setpoint_interpolation`` off: -1.9 Nm on the
    run-up, +1.9 Nm braking; 0.01 Nm with it on): either far above the calibration's
    uncertainty of a cutting torque.
    A cycle is flagged (code 1) when its speed command differs from the previous or the next
    cycle's by more than ``speed_step_rpm`` and for ``settle_s`` after the last such change;
    code 2 when ``|n| < min_speed_rpm`` (no cut possible); 0 otherwise.

    Parameters
    ----------
    fs_hz : float, default 500
        Sample rate [Hz].
    speed_step_rpm : float, default 1
        Change per cycle that counts as a speed change [rpm] (a ramp of 500 rpm/s moves 1 rpm
        per 2 ms; slower drifts are left to the inertia term).
    settle_s : float, default 0.3
        Time after the last change still flagged (speed loop and current filter) [s].
    min_speed_rpm : float, default 10
        Standstill below this [rpm].
    settled_at_start : bool, default True
        The stream's first samples follow a steady speed (a recording's start); False: what
        came before is not known (a live stream joined at any moment), so they are flagged
        for ``settle_s`` like samples after a change.

    Notes
    -----
    Stateful: consecutive calls of :meth:`update` flag a stream exactly as one call on the
    whole does (:func:`speed_change_flags`).
    """

    CODES: ClassVar[Mapping[int, str]] = {
        0: "cutting torque (steady speed)",
        1: "speed change or settling after it: the current accelerates the rotor, not a cut",
        2: "spindle standing: no cut possible",
    }

    def __init__(self, *, fs_hz: float = 500.0, speed_step_rpm: float = 1.0,
                 settle_s: float = 0.3, min_speed_rpm: float = 10.0,
                 settled_at_start: bool = True) -> None:
        if not (fs_hz > 0 and speed_step_rpm > 0 and settle_s >= 0 and min_speed_rpm >= 0):
            raise ConfigError(f"fs_hz ({fs_hz}) and speed_step_rpm ({speed_step_rpm}) must be "
                              f"> 0, settle_s ({settle_s}) and min_speed_rpm ({min_speed_rpm}) "
                              ">= 0")
        self.speed_step_rpm, self.min_speed_rpm = speed_step_rpm, min_speed_rpm
        self.settle_samples = round(settle_s * fs_hz)
        self._last: float | None = None
        # samples since the last change (none seen; or "just now" when the past is unknown)
        self._since = 1 << 40 if settled_at_start else 0

    def update(self, speed_rpm: ArrayLike, next_rpm: float | None = None) -> NDArray[np.int8]:
        """Flag codes of the next consecutive samples.

        Parameters
        ----------
        speed_rpm : array-like of float
            Speed command of the samples [rpm].
        next_rpm : float, optional
            Command of the sample after them, when known [rpm].

        Returns
        -------
        numpy.ndarray of int8
        """
        nv = np.ascontiguousarray(speed_rpm, dtype=np.float64).reshape(-1)
        flags = np.empty(nv.size, dtype=np.int8)
        if not nv.size:
            return flags
        first = float(nv[0]) if self._last is None else self._last
        after = float(nv[-1]) if next_rpm is None else float(next_rpm)
        self._since = int(_speed_flags(nv, first, after, float(self.speed_step_rpm),
                                       float(self.min_speed_rpm), self.settle_samples,
                                       self._since, flags))
        self._last = float(nv[-1])
        return flags


def _speed_flags_py(nv: NDArray[np.float64], first: float, after: float, tol: float,
                    min_speed: float, settle: int, since: int, out: NDArray[np.int8]) -> int:
    """:meth:`SpeedChangeFlags.update` as one loop (compiled; every edge chunk runs it twice):
    a sample changed when it differs from the one before (``first`` for the first) or after
    (``after`` for the last) by more than ``tol`` or is NaN; flag 1 up to ``settle`` samples
    after a change, 2 below ``min_speed``. Returns the samples since the last change."""
    n = nv.size
    for k in range(n):
        v = nv[k]
        p = nv[k - 1] if k > 0 else first
        q = nv[k + 1] if k < n - 1 else after
        since = since + 1 if abs(v - p) <= tol and abs(q - v) <= tol else 0
        f = 1 if since <= settle else 0
        if not abs(v) >= min_speed:  # NaN too
            f = 2
        out[k] = f
    return since


_speed_flags = lazy_njit(_speed_flags_py)


def speed_change_flags(speed_rpm: ArrayLike, *, fs_hz: float = 500.0,
                       speed_step_rpm: float = 1.0, settle_s: float = 0.3,
                       min_speed_rpm: float = 10.0) -> NDArray[np.int8]:
    """Per sample: 0 cutting torque, 1 speed change / settling, 2 standstill.

    The batch form of :class:`SpeedChangeFlags` (see there for the rule and its reason).

    Parameters
    ----------
    speed_rpm : array-like of float
        Spindle speed command per sample [rpm].
    fs_hz, speed_step_rpm, settle_s, min_speed_rpm
        As in :class:`SpeedChangeFlags`.

    Returns
    -------
    numpy.ndarray of int8
    """
    return SpeedChangeFlags(fs_hz=fs_hz, speed_step_rpm=speed_step_rpm, settle_s=settle_s,
                            min_speed_rpm=min_speed_rpm).update(speed_rpm)


# ====================================================================== streaming estimator
class StreamingTorqueEstimator:
    """Chunk-by-chunk :meth:`SpindleModel.cutting_torque` with identical results.

    With the inertia term, the derivative at sample ``k`` needs sample ``k + 1`` (central
    difference), so the estimator holds the newest sample back: each :meth:`update` returns
    the estimates of all samples received so far except the last; :meth:`flush` returns the
    last one (one-sided difference, as the vectorized path does at the end of an array).
    Concatenating all outputs equals ``model.cutting_torque(all_current, all_speed)``
    exactly, whatever the chunking. Without the inertia term there is no delay.

    Parameters
    ----------
    model : SpindleModel
        Calibrated model.
    fs_hz : float, default 500.0
        Sample rate [Hz].
    accel_term : bool, default True
        Subtract ``J dOmega/dt``.

    Examples
    --------
    >>> import numpy as np
    >>> m = SpindleModel(1.04, 8.42e-5, 0.35, j_kgm2=0.01)
    >>> i = np.linspace(1, 4, 100); n = np.linspace(2000, 2400, 100)
    >>> est = StreamingTorqueEstimator(m)
    >>> out = np.concatenate([est.update(i[k:k + 30], n[k:k + 30]) for k in range(0, 100, 30)]
    ...                      + [est.flush()])
    >>> bool(np.array_equal(out, m.cutting_torque(i, n)))
    True
    """

    def __init__(self, model: SpindleModel, *, fs_hz: float = 500.0, accel_term: bool = True):
        self.model = model
        self.fs_hz = float(fs_hz)
        self.accel_term = accel_term
        self._uses_accel = accel_term and model.j_kgm2 != 0.0
        self._half = 0.5 * self.fs_hz
        self.reset()

    @property
    def delay_samples(self) -> int:
        """Samples held back (1 with the inertia term, else 0)."""
        return 1 if self._uses_accel else 0

    def reset(self) -> None:
        """Forget the stream (start of a new recording)."""
        self._prev_w: float | None = None
        self._pend_i = np.empty(0)
        self._pend_n = np.empty(0)
        self._pend_t: NDArray[np.float64] | None = None
        self.n_samples = 0

    def _torque(self, i: NDArray[np.float64], n: NDArray[np.float64],
                t: NDArray[np.float64] | None, acc: NDArray[np.float64] | None
                ) -> NDArray[np.float64]:
        kt, b, tf = self.model._params_at(t)
        if self.model.flux_base_speed_rpm > 0:
            kt = kt * self.model.flux_factor(n)
        tau = kt * i - b * n - tf * np.sign(n)
        if self.model.stribeck_torque_nm:
            tau = tau - self.model.stribeck_nm(n)
        if acc is not None:
            tau = tau - self.model.j_kgm2 * acc
        return np.asarray(tau, dtype=np.float64)

    def update(
        self,
        current_a: ArrayLike,
        speed_rpm: ArrayLike,
        temperature_c: ArrayLike | None = None,
    ) -> NDArray[np.float64]:
        """Feed the next chunk; return the estimates that are now complete [Nm].

        Parameters
        ----------
        current_a, speed_rpm : array-like
            Next samples (1-D, same length) [A], [rpm].
        temperature_c : float or array-like, optional
            Motor temperature [degC] (scalar for the chunk or one per sample).
        """
        i = np.asarray(current_a, dtype=np.float64).ravel()
        n = np.asarray(speed_rpm, dtype=np.float64).ravel()
        if i.shape != n.shape:
            raise ConfigError(f"chunk has {i.size} currents and {n.size} speeds")
        t: NDArray[np.float64] | None = None
        if temperature_c is not None:
            t = np.broadcast_to(np.asarray(temperature_c, dtype=np.float64), i.shape).copy()
        self.n_samples += i.size
        if not self._uses_accel:
            return self._torque(i, n, t, None)
        if i.size == 0:
            return np.empty(0)
        bi = np.concatenate([self._pend_i, i])
        bn = np.concatenate([self._pend_n, n])
        bt: NDArray[np.float64] | None = None
        if t is not None:
            bt = t if self._pend_t is None or self._pend_i.size == 0 else np.concatenate(
                [self._pend_t, t])
        m = bn.size
        if m < 2:
            self._pend_i, self._pend_n, self._pend_t = bi, bn, bt
            return np.empty(0)
        w = bn * RPM_TO_RAD_S
        acc = np.empty(m - 1)
        if self._prev_w is None:
            acc[0] = (w[1] - w[0]) * self.fs_hz
        else:
            acc[0] = (w[1] - self._prev_w) * self._half
        acc[1:] = (w[2:] - w[:-2]) * self._half
        out = self._torque(bi[:-1], bn[:-1], None if bt is None else bt[:-1], acc)
        self._prev_w = float(w[-2])
        self._pend_i, self._pend_n = bi[-1:], bn[-1:]
        self._pend_t = None if bt is None else bt[-1:]
        return out

    def flush(self) -> NDArray[np.float64]:
        """Return the held-back last sample (end of the stream) and reset."""
        if not self._uses_accel or self._pend_n.size == 0:
            self.reset()
            return np.empty(0)
        w = self._pend_n * RPM_TO_RAD_S
        acc = np.zeros(1) if self._prev_w is None else (w - self._prev_w) * self.fs_hz
        out = self._torque(self._pend_i, self._pend_n, self._pend_t, acc)
        self.reset()
        return out


# ====================================================================== validation (Table 4.1)
def validation_table(
    cuts: Iterable[CutMeasurement | Mapping[str, Any]] | pd.DataFrame,
    model: SpindleModel,
) -> pd.DataFrame:
    """Measured vs predicted mean cutting torque per cut, like thesis Table 4.1.

    Parameters
    ----------
    cuts : iterable of CutMeasurement or mapping, or pandas.DataFrame
        Each with ``workpiece``, ``speed_rpm``, ``feed_mm_per_rev``, ``current_a`` (measured
        mean spindle current [A]) and ``torque_nm`` (measured mean cutting torque [Nm]).
    model : SpindleModel
        Calibrated model; predictions use the constant-speed form (no inertia term, Eq. 4.4).

    Returns
    -------
    pandas.DataFrame
        Columns ``workpiece``, ``speed_rpm``, ``feed_mm_per_rev``, ``current_a``,
        ``torque_nm``, ``predicted_torque_nm``, ``error_nm`` (predicted - measured) and
        ``error_pct`` = |predicted - measured| / |measured| * 100.
    """
    if isinstance(cuts, pd.DataFrame):
        df = cuts.copy()
    else:
        rows = [asdict(c) if isinstance(c, CutMeasurement) else dict(c) for c in cuts]
        df = pd.DataFrame(rows)
    need = ("speed_rpm", "current_a", "torque_nm")
    missing = [c for c in need if c not in df.columns]
    if missing:
        raise ConfigError(f"cuts lack columns {missing}; need {list(need)}")
    if "workpiece" not in df:
        df["workpiece"] = ""
    if "feed_mm_per_rev" not in df:
        df["feed_mm_per_rev"] = np.nan
    pred = model.cutting_torque(df["current_a"].to_numpy(float), df["speed_rpm"].to_numpy(float),
                                accel_term=False)
    meas = df["torque_nm"].to_numpy(float)
    out = df[["workpiece", "speed_rpm", "feed_mm_per_rev", "current_a", "torque_nm"]].copy()
    out["predicted_torque_nm"] = pred
    out["error_nm"] = pred - meas
    with np.errstate(divide="ignore", invalid="ignore"):
        out["error_pct"] = np.abs(pred - meas) / np.abs(meas) * 100.0
    return out.reset_index(drop=True)
