"""Tool wear from drive signals: trends, set patterns, a calibrated wear estimator, remaining life.

Thesis chapter 5.1: as the flank wear grows, the cutting torque and so the spindle current grow
(Figure 5.2); per-hole means with a moving average of 15 holes show the trend (Figure 5.3), with a
rise at the last holes of every set of 6 caused by the tool heating up (section 5.2). This module
turns per-hole values into a wear estimate in micrometres and a remaining-life forecast, and
validates wear models with leave-one-group-out cross-validation.

References
----------
.. [1] Thesis, Koç University, chapter 5.1, Figures 5.2 and 5.3.
.. [2] Subramanian, K., Cook, N. H., "Sensing of drill wear and prediction of drill life",
   J. Eng. Ind. 99(2):295-301, 1977: drilling torque grows linearly with average flank wear,
   M = 0.125 HB d^2 f + 0.289 HB d^2 r + 0.0487 HB d^2 w.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray

from cnctwin.exceptions import ConfigError, IdentificationError

__all__ = [
    "LifeForecast",
    "LogoResult",
    "SetPattern",
    "WearEstimator",
    "forecast_remaining_life",
    "leave_one_group_out",
    "moving_average",
    "relative_increase",
    "ridge_fit",
    "set_pattern",
]


def moving_average(
    values: ArrayLike, *, window: int = 15, centered: bool = True
) -> NDArray[np.float64]:
    """Moving average that ignores NaN and shrinks the window at the ends.

    Parameters
    ----------
    values : array-like
        Per-hole values (e.g. mean spindle current of each hole) [any unit].
    window : int, default 15
        Window length in holes (thesis Figure 5.3 uses 15).
    centered : bool, default True
        Centered window (offline trend, as MATLAB ``movmean``); ``False`` gives the trailing
        window an online tracker can compute.

    Returns
    -------
    numpy.ndarray
        Same length as ``values``.
    """
    if window < 1:
        raise ConfigError(f"window must be >= 1, not {window}")
    x = np.asarray(values, dtype=np.float64)
    ok = np.isfinite(x)
    csum = np.concatenate([[0.0], np.cumsum(np.where(ok, x, 0.0))])
    ccount = np.concatenate([[0], np.cumsum(ok)])
    idx = np.arange(x.size)
    if centered:
        lo = np.clip(idx - (window - 1) // 2, 0, x.size)
        hi = np.clip(idx + window // 2 + 1, 0, x.size)
    else:
        lo = np.clip(idx - window + 1, 0, x.size)
        hi = idx + 1
    count = ccount[hi] - ccount[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        out = (csum[hi] - csum[lo]) / count
    return np.where(count > 0, out, np.nan)


@dataclass(frozen=True)
class SetPattern:
    """Pattern of a per-hole value within sets of consecutive holes.

    Attributes
    ----------
    position_mean : numpy.ndarray
        Mean, over all sets, of the value divided by its set mean, per position in the set
        (1.0 = the set average) [-].
    position_std : numpy.ndarray
        Standard deviation of that ratio per position [-].
    n_sets : int
        Number of complete sets used.
    rise_last_vs_first : float
        ``position_mean[-1] / position_mean[0] - 1``: how much the last hole of a set exceeds
        the first (the tool-heating effect of thesis section 5.2) [-].
    """

    position_mean: NDArray[np.float64]
    position_std: NDArray[np.float64]
    n_sets: int
    rise_last_vs_first: float


def set_pattern(values: ArrayLike, *, set_size: int = 6) -> SetPattern:
    """Within-set pattern of per-hole values (thesis chapter 5.1: sets of 6 holes).

    Parameters
    ----------
    values : array-like
        Per-hole values in drilling order; incomplete trailing sets are ignored.
    set_size : int, default 6
        Holes per set.

    Returns
    -------
    SetPattern
        Per position in the set the mean and spread of value / set mean, and the rise from
        the first to the last hole.
    """
    x = np.asarray(values, dtype=np.float64)
    n_sets = x.size // set_size
    if n_sets < 1:
        raise IdentificationError(
            f"need at least one complete set of {set_size} holes, got {x.size} holes"
        )
    sets = x[: n_sets * set_size].reshape(n_sets, set_size)
    ratio = sets / np.nanmean(sets, axis=1, keepdims=True)
    mean = np.nanmean(ratio, axis=0)
    std = np.nanstd(ratio, axis=0)
    return SetPattern(mean, std, n_sets, float(mean[-1] / mean[0] - 1.0))


def relative_increase(
    values: ArrayLike, *, baseline: int = 30, set_size: int | None = 6
) -> NDArray[np.float64]:
    """Relative increase of a per-hole value over its new-tool baseline.

    With ``set_size`` the values are first replaced by their set means, which removes the
    within-set heating pattern (a temperature correction that needs no thermometer).

    Parameters
    ----------
    values : array-like
        Per-hole values (torque [Nm] or current [A]).
    baseline : int, default 30
        Number of first holes whose mean is the new-tool reference.
    set_size : int or None, default 6
        Holes per set; ``None`` keeps the raw per-hole values.

    Returns
    -------
    numpy.ndarray
        ``value / baseline_mean - 1`` per hole [-].
    """
    x = np.asarray(values, dtype=np.float64)
    if set_size:
        n_full = x.size // set_size * set_size
        sets = x[:n_full].reshape(-1, set_size)
        smooth = np.repeat(np.nanmean(sets, axis=1), set_size)
        tail = x[n_full:]
        x = np.concatenate([smooth, np.full(tail.size, np.nanmean(tail)) if tail.size else tail])
    if baseline < 1 or baseline > x.size:
        raise ConfigError(f"baseline must be between 1 and {x.size} holes, not {baseline}")
    ref = float(np.nanmean(x[:baseline]))
    if not np.isfinite(ref) or ref == 0.0:
        raise IdentificationError("the baseline holes have no finite, non-zero mean")
    return x / ref - 1.0


@dataclass
class WearEstimator:
    """Map the relative torque increase to flank wear, calibrated on a few measured points.

    The model follows Subramanian & Cook [2]: torque grows linearly with average flank wear,
    so ``Vb = Vb0 + k * increase`` where ``increase`` is :func:`relative_increase` of the
    (temperature-corrected) per-hole torque.

    Attributes
    ----------
    slope_um : float
        Wear per unit relative increase [µm].
    offset_um : float
        Wear at zero increase (the initial wear of the new tool) [µm].
    slope_std_um : float
        Standard error of the slope [µm].
    n_points : int
        Calibration points used.
    resid_std_um : float
        Standard deviation of the measured points about the fit [µm].
    cov_um2 : tuple of float
        Covariance of (slope, offset): (var slope, cov, var offset) [µm²]; offset terms 0
        when the offset is not fitted.
    """

    slope_um: float = float("nan")
    offset_um: float = 0.0
    slope_std_um: float = float("nan")
    n_points: int = 0
    resid_std_um: float = float("nan")
    cov_um2: tuple[float, float, float] = (float("nan"), 0.0, 0.0)

    def fit(
        self, increase: ArrayLike, wear_um: ArrayLike, *, fit_offset: bool = False
    ) -> WearEstimator:
        """Calibrate on measured wear points (microscope readings).

        Parameters
        ----------
        increase : array-like
            Relative torque increase at the measured holes [-].
        wear_um : array-like
            Measured flank wear at those holes [µm].
        fit_offset : bool, default False
            Fit the initial wear too (needs at least 3 points); otherwise it is 0 µm.

        Returns
        -------
        WearEstimator
            ``self``, calibrated.
        """
        x = np.asarray(increase, dtype=np.float64)
        y = np.asarray(wear_um, dtype=np.float64)
        ok = np.isfinite(x) & np.isfinite(y)
        x, y = x[ok], y[ok]
        need = 3 if fit_offset else 2
        if x.size < need:
            raise IdentificationError(
                f"need at least {need} measured wear points with finite values, got {x.size}"
            )
        a = np.column_stack([x, np.ones_like(x)]) if fit_offset else x[:, None]
        coef, *_ = np.linalg.lstsq(a, y, rcond=None)
        resid = y - a @ coef
        dof = max(x.size - a.shape[1], 1)
        cov = np.linalg.pinv(a.T @ a) * float(resid @ resid) / dof
        self.slope_um = float(coef[0])
        self.offset_um = float(coef[1]) if fit_offset else 0.0
        self.slope_std_um = float(np.sqrt(cov[0, 0]))
        self.n_points = int(x.size)
        self.resid_std_um = float(np.sqrt(float(resid @ resid) / dof))
        self.cov_um2 = ((float(cov[0, 0]), float(cov[0, 1]), float(cov[1, 1])) if fit_offset
                        else (float(cov[0, 0]), 0.0, 0.0))
        return self

    def predict_std(self, increase: ArrayLike) -> NDArray[np.float64]:
        """Standard uncertainty of a wear prediction [µm]: the fit's parameters and the
        scatter of the measured points about it (a prediction, not a mean, interval)."""
        if not np.isfinite(self.slope_um):
            raise IdentificationError("WearEstimator is not calibrated; call fit() first")
        x = np.asarray(increase, dtype=np.float64)
        vs, c, vo = self.cov_um2
        return np.sqrt(x * x * vs + 2.0 * x * c + vo + self.resid_std_um**2)

    def predict(self, increase: ArrayLike) -> NDArray[np.float64]:
        """Flank wear for a relative torque increase [µm]."""
        if not np.isfinite(self.slope_um):
            raise IdentificationError("WearEstimator is not calibrated; call fit() first")
        return self.offset_um + self.slope_um * np.asarray(increase, dtype=np.float64)


@dataclass(frozen=True)
class LifeForecast:
    """Remaining-life forecast to a wear limit.

    Attributes
    ----------
    index_at_limit : float
        Hole (or segment) index at which the wear is forecast to reach the limit; ``inf`` if the
        fitted trend never reaches it.
    remaining : float
        ``index_at_limit - last index`` [holes].
    remaining_low, remaining_high : float
        A 90 % interval from residual bootstrap [holes].
    model : str
        Trend model used.
    """

    index_at_limit: float
    remaining: float
    remaining_low: float
    remaining_high: float
    model: str


def _crossings(coef: ArrayLike, start: float, limit: float,
               horizon: float) -> NDArray[np.float64]:
    """First index at or after ``start`` (within ``horizon``) where each polynomial (rows of
    ``coef``, highest power first) reaches ``limit``; ``inf`` where it does not. Closed form
    up to degree 2 (the roots), a 4001-point grid above."""
    c = np.atleast_2d(np.asarray(coef, dtype=np.float64))
    out = np.full(c.shape[0], np.inf)
    p0 = c @ (float(start) ** np.arange(c.shape[1] - 1, -1, -1))  # each polynomial at start
    above = p0 >= limit
    out[above] = start
    end = start + horizon
    if c.shape[1] > 3:
        grid = np.linspace(start, end, 4001)
        for i in np.flatnonzero(~above):
            hit = np.flatnonzero(np.polyval(c[i], grid) >= limit)
            out[i] = grid[hit[0]] if hit.size else np.inf
        return out
    pad = np.zeros((c.shape[0], 3))
    pad[:, 3 - c.shape[1]:] = c
    a, b, cc = pad[:, 0], pad[:, 1], pad[:, 2] - limit
    roots = np.full((c.shape[0], 2), np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        lin = np.abs(a) <= 1e-300
        roots[lin, 0] = -cc[lin] / b[lin]
        disc = b * b - 4.0 * a * cc
        ok = ~lin & (disc >= 0)
        sq = np.sqrt(np.where(ok, disc, 0.0))
        roots[ok, 0] = (-b[ok] - sq[ok]) / (2.0 * a[ok])
        roots[ok, 1] = (-b[ok] + sq[ok]) / (2.0 * a[ok])
    valid = np.isfinite(roots) & (roots > start) & (roots <= end)
    first = np.where(valid, roots, np.inf).min(axis=1)
    out[~above] = first[~above]
    return out


def forecast_remaining_life(
    index: ArrayLike,
    wear_um: ArrayLike,
    *,
    limit_um: float,
    window: int | None = None,
    degree: int = 2,
    n_boot: int = 200,
    seed: int = 0,
) -> LifeForecast:
    """Forecast when the wear reaches ``limit_um`` by extrapolating a polynomial trend.

    Parameters
    ----------
    index : array-like
        Hole or segment index of each wear value.
    wear_um : array-like
        Estimated or measured flank wear [µm].
    limit_um : float
        Wear limit [µm] (e.g. 300 µm for carbide drills in steel; ISO 3685 uses 300 µm
        average flank wear as a tool-life criterion for turning).
    window : int, optional
        Fit only the last ``window`` points (the recent trend); default all.
    degree : int, default 2
        Polynomial degree (2 captures the accelerating wear phase).
    n_boot : int, default 200
        Residual-bootstrap draws for the interval.
    seed : int, default 0
        Seed of the bootstrap.

    Returns
    -------
    LifeForecast
        Index at which the trend reaches ``limit_um`` (``inf`` if it never does), the remaining
        holes and their 90 % bootstrap interval.
    """
    x = np.asarray(index, dtype=np.float64)
    y = np.asarray(wear_um, dtype=np.float64)
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    if window is not None:
        x, y = x[-window:], y[-window:]
    if x.size <= degree + 1:
        raise IdentificationError(
            f"need more than {degree + 1} wear values to fit a degree-{degree} trend"
        )
    last = float(x[-1])
    if y[-1] >= limit_um:
        return LifeForecast(last, 0.0, 0.0, 0.0, f"poly{degree}")
    # the fit in an index relative to the last point (conditioning), crossings back in index
    v = np.vander(x - last, degree + 1)
    coef = np.linalg.lstsq(v, y, rcond=None)[0]
    horizon = 10.0 * max(float(x[-1] - x[0]), 1.0)
    at = float(_crossings(coef, 0.0, limit_um, horizon)[0]) + last
    rng = np.random.default_rng(seed)
    fitted = v @ coef
    resid = y - fitted
    # all draws at once: resampled residuals on the fit, one least-squares solve
    yb = fitted[:, None] + resid[rng.integers(0, resid.size, size=(resid.size, n_boot))]
    coef_b = np.linalg.lstsq(v, yb, rcond=None)[0].T
    b = np.sort(_crossings(coef_b, 0.0, limit_um, horizon))  # inf sorts last
    # order statistics, not np.percentile: draws that never reach the limit are +inf
    lo = float(b[int(np.floor(0.05 * (b.size - 1)))])
    hi = float(b[int(np.ceil(0.95 * (b.size - 1)))])
    return LifeForecast(at, at - last, lo, hi, f"poly{degree}")


def ridge_fit(
    x: NDArray[np.float64], y: NDArray[np.float64], *, alpha: float
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], float]:
    """Ridge regression on standardized features.

    Returns ``(mean, scale, weights, intercept)``; predict with
    ``((x - mean) / scale) @ weights + intercept``.

    Parameters
    ----------
    x : numpy.ndarray
        ``(n, p)`` features.
    y : numpy.ndarray
        ``n`` targets.
    alpha : float
        Ridge penalty.

    Returns
    -------
    tuple
        (mean, scale, weights, intercept).
    """
    mean = x.mean(axis=0)
    scale = x.std(axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    xs = (x - mean) / scale
    intercept = float(y.mean())
    w = np.linalg.solve(xs.T @ xs + alpha * np.eye(x.shape[1]), xs.T @ (y - intercept))
    return mean, scale, w, intercept


@dataclass(frozen=True)
class LogoResult:
    """Leave-one-group-out validation of a wear model.

    Attributes
    ----------
    per_group : pandas.DataFrame
        Per held-out group: ``group``, ``n``, ``mae_um``, ``rmse_um`` of the model, and the same
        for the baselines (``baseline_mean_mae_um``: predict the training mean;
        ``baseline_usage_mae_um``: wear linear in the usage counter, i.e. a tool-life counter).
    mae_um, baseline_mean_mae_um, baseline_usage_mae_um : float
        Means over the groups [µm].
    features : list of str
        Features used.
    """

    per_group: pd.DataFrame
    mae_um: float
    baseline_mean_mae_um: float
    baseline_usage_mae_um: float
    features: list[str]


def leave_one_group_out(
    data: pd.DataFrame,
    *,
    features: Sequence[str],
    target: str = "Vb",
    group: str = "tool",
    usage: str = "segment",
    alpha: float = 100.0,
) -> LogoResult:
    """Leave-one-group-out error of a ridge wear model against two plain baselines.

    Parameters
    ----------
    data : pandas.DataFrame
        One row per segment or hole with feature columns, the wear ``target`` [µm], the
        ``group`` id (tool or experiment) and a ``usage`` counter (order within the group).
    features : sequence of str
        Feature columns.
    target, group, usage : str
        Column names.
    alpha : float, default 100
        Ridge penalty on standardized features.

    Returns
    -------
    LogoResult
        Per held-out group the errors of the ridge model and of the two baselines, and their
        means [µm].
    """
    missing = [c for c in (*features, target, group, usage) if c not in data.columns]
    if missing:
        raise ConfigError(f"columns not in the data: {missing}")
    x_all = data[list(features)].to_numpy(dtype=np.float64)
    y_all = data[target].to_numpy(dtype=np.float64)
    u_all = data[usage].to_numpy(dtype=np.float64)
    g_all = data[group].to_numpy()
    rows = []
    for g in pd.unique(g_all):
        test = g_all == g
        train = ~test
        mean, scale, w, b0 = ridge_fit(x_all[train], y_all[train], alpha=alpha)
        pred = ((x_all[test] - mean) / scale) @ w + b0
        err = pred - y_all[test]
        base = np.full(test.sum(), y_all[train].mean()) - y_all[test]
        c = np.polyfit(u_all[train], y_all[train], 1)
        use = np.polyval(c, u_all[test]) - y_all[test]
        rows.append(
            {
                "group": g,
                "n": int(test.sum()),
                "mae_um": float(np.abs(err).mean()),
                "rmse_um": float(np.sqrt((err**2).mean())),
                "baseline_mean_mae_um": float(np.abs(base).mean()),
                "baseline_usage_mae_um": float(np.abs(use).mean()),
            }
        )
    per = pd.DataFrame(rows)
    return LogoResult(
        per,
        float(per["mae_um"].mean()),
        float(per["baseline_mean_mae_um"].mean()),
        float(per["baseline_usage_mae_um"].mean()),
        list(features),
    )
