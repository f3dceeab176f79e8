"""TwinChain: calibrate the spindle twin from Recordings and estimate the cutting torque.

The orchestrator of thesis chapter 4 in the style of pvlib's ``ModelChain``: a chain is built
from a machine description and a handful of options (model slots take a name or a callable),
:meth:`TwinChain.calibrate` identifies the spindle from an air-cut sweep and one cut with a
dynamometer, and :meth:`TwinChain.run_model_from_measured` estimates the cutting torque of any
recording. Results land in a :class:`TwinChainResult`.

Every analysis reads :class:`~cnctwin.recording.Recording` objects only (HF current and speed,
LF motor temperature / |I| / Iq, the Z position, the dynamometer channel); nothing here reads
simulator internals, so the same calls run on a real campaign.

Presets:

* :meth:`TwinChain.thesis_method`: the thesis as published (region from data, ``I = a n + b`` on
  the plateau means, Kt from the first 0.6 s of the calibration cut, no temperature or
  acceleration term).
* :meth:`TwinChain.improved_method`: the same physics with the error sources of the thesis
  method removed (see its Notes).

Examples
--------
>>> chain = TwinChain.improved_method()
>>> chain.options.temperature_compensation
True
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray

from cnctwin.analysis.align import align_external, external_on_hf
from cnctwin.analysis.filters import lowpass
from cnctwin.analysis.segments import cutting_regions, lf_on_hf, speed_plateaus, spindle_speed_rpm
from cnctwin.exceptions import ConfigError, IdentificationError, SignalNotFoundError
from cnctwin.recording import Recording
from cnctwin.spindle import (
    RPM_TO_RAD_S,
    FrictionFit,
    LinearRegion,
    SpindleModel,
    air_cut_statistics,
    field_weakening_onset_rpm,
    fit_friction,
    identify_inertia,
    linear_region,
    plateau_segments,
)

__all__ = [
    "FRICTION_MODELS",
    "REGION_MODELS",
    "CutEstimate",
    "FrictionCurve",
    "ThermalFrictionFit",
    "TwinChain",
    "TwinChainOptions",
    "TwinChainResult",
    "align_dynamometer",
    "field_weakening_onset_rpm",
    "find_cuts",
    "fit_friction_stribeck",
    "fit_friction_thermal",
    "friction_energy",
    "has_repeated_speeds",
    "ripple_free_means",
    "temperature_coefficient_from_warm_up",
    "thermal_drift_from_warm_up",
]

NDFEB_KT_TEMP_COEFF_PER_K = -0.00105
"""Relative change of Kt per kelvin of magnet temperature [1/K]: the middle of the NdFeB
remanence coefficient range -0.09 ... -0.12 %/K (docs/reference/physics-and-performance.md §2)."""


# ====================================================================== friction models
@dataclass(frozen=True)
class FrictionCurve:
    """Air-cut current versus speed: ``I = a n + b + s exp(-n / n_s)`` [A].

    Attributes
    ----------
    line : FrictionFit
        The straight part (``a = B/Kt`` [A/rpm], ``b = tau_f/Kt`` [A]); for the linear model
        this is the whole curve.
    stribeck_a : float
        Low-speed excess current ``s`` [A] (0 for the linear model).
    stribeck_speed_rpm : float
        Decay speed ``n_s`` [rpm] (NaN for the linear model).
    model : str
        Name of the friction model.
    n_coefficients : int
        Coefficients fitted to the plateau means, the decay speed ``n_s`` and a grid-searched
        drift included (2 for the line); with ``line.n_points`` the residual degrees of
        freedom.
    """

    line: FrictionFit
    stribeck_a: float = 0.0
    stribeck_speed_rpm: float = float("nan")
    model: str = "linear"
    n_coefficients: int = 2

    def residual_dof(self) -> int:
        """Residual degrees of freedom: plateaus used minus coefficients fitted."""
        return self.line.n_points - self.n_coefficients

    def residual_variance_a2(self) -> float:
        """Variance of the plateau means about the curve, per degree of freedom [A^2].

        NaN where the fit has no residual degree of freedom.
        """
        dof = self.residual_dof()
        return self.line.norm_residuals**2 / dof if dof > 0 else float("nan")

    def current_a(self, speed_rpm: ArrayLike) -> NDArray[np.float64]:
        """Air-cut current predicted at ``speed_rpm`` [A]."""
        n = np.abs(np.asarray(speed_rpm, dtype=np.float64))
        out = self.line.current_a(n)
        if self.stribeck_a:
            out = out + self.stribeck_a * np.exp(-n / self.stribeck_speed_rpm)
        return np.asarray(out, dtype=np.float64)


def _fit_linear(speed_rpm: ArrayLike, current_a: ArrayLike, lo_rpm: float,
                hi_rpm: float) -> FrictionCurve:
    return FrictionCurve(fit_friction(speed_rpm, current_a, lo_rpm, hi_rpm))


def fit_friction_stribeck(
    speed_rpm: ArrayLike,
    current_a: ArrayLike,
    lo_rpm: float,
    hi_rpm: float,
    *,
    decay_grid_rpm: Sequence[float] = tuple(np.geomspace(100.0, 2000.0, 40)),
) -> FrictionCurve:
    """Line plus a decaying low-speed (Stribeck) term through air-cut means.

    Parameters
    ----------
    speed_rpm, current_a : array-like
        Plateau speeds [rpm] and mean currents [A].
    lo_rpm, hi_rpm : float
        Speed range used [rpm]; unlike the thesis' linear region it may start far below the
        lower limit, because the curved low-speed part is modelled instead of cut away.
    decay_grid_rpm : sequence of float
        Candidate decay speeds ``n_s`` [rpm]; the one with the least residual wins (the model
        is linear in ``a, b, s`` for a fixed ``n_s``).

    Returns
    -------
    FrictionCurve
        ``line`` holds ``a``, ``b`` with their statistics from the final fit.

    Notes
    -----
    ``Kt I = B n + tau_f + tau_s exp(-n/n_s)`` (Stribeck/mixed lubrication on top of Eq. 3.1).
    The thesis cuts the curved low-speed part away (1100 rpm lower limit); what is left of the
    decaying term just above the limit still tilts a straight line: the slope comes out low and
    the offset high by about ``s exp(-n_lo/n_s)`` (1-3 % of ``tau_f`` on the thesis machine).
    Modelling the term removes that bias and lets the fit use the low speeds, which pin
    ``tau_f`` best.
    """
    n = np.abs(np.asarray(speed_rpm, dtype=np.float64))
    i = np.abs(np.asarray(current_a, dtype=np.float64))
    m = np.isfinite(n) & np.isfinite(i) & (n >= lo_rpm) & (n <= hi_rpm)
    x, y = n[m], i[m]
    if x.size < 6:
        raise IdentificationError(
            f"the Stribeck friction fit needs at least 6 plateaus in [{lo_rpm:.0f}, "
            f"{hi_rpm:.0f}] rpm, got {x.size}"
        )
    best: tuple[float, float, NDArray[np.float64]] | None = None
    for ns in decay_grid_rpm:
        a_mat = np.column_stack([x, np.ones_like(x), np.exp(-x / ns)])
        sol, *_ = np.linalg.lstsq(a_mat, y, rcond=None)
        if sol[2] < 0:
            continue
        rss = float(np.sum((a_mat @ sol - y) ** 2))
        if best is None or rss < best[0]:
            best = (rss, float(ns), sol)
    if best is None:
        return _fit_linear(x, y, lo_rpm, hi_rpm)
    _, ns, sol = best
    # the line through the Stribeck-corrected means (its a, b and residuals are the joint
    # fit's); the standard errors of a, b from the whole law's Jacobian at the optimum (s and
    # the grid-searched n_s included), as in fit_friction_thermal: the line's own carried
    # neither
    decay = np.exp(-x / ns)
    line = fit_friction(x, y - sol[2] * decay)
    jac = np.column_stack([x, np.ones_like(x), decay, sol[2] * x / ns**2 * decay])
    cov = _scaled_covariance(jac, line.norm_residuals**2)
    line = replace(line, slope_std=float(np.sqrt(cov[0, 0])),
                   offset_std=float(np.sqrt(cov[1, 1])))
    return FrictionCurve(line, stribeck_a=float(sol[2]), stribeck_speed_rpm=ns,
                         model="stribeck", n_coefficients=jac.shape[1])


def _scaled_covariance(jac: NDArray[np.float64], rss: float) -> NDArray[np.float64]:
    """s^2 (J'J)^-1 of a least-squares fit, s^2 = rss / (n - p) (NaN without a degree of
    freedom), with J's columns scaled to unit norm first: the air cut's columns span ~10
    decades (1 against n E ~ 1e8 A rpm^2 s), and pinv of the raw normal matrix drops the small
    singular values and with them the offset's variance (it came out ~1e-10 A)."""
    dof = jac.shape[0] - jac.shape[1]
    s2 = rss / dof if dof > 0 else float("nan")
    scale = np.linalg.norm(jac, axis=0)
    scale[scale == 0] = 1.0
    j_s = jac / scale
    return np.asarray(s2 * np.linalg.pinv(j_s.T @ j_s) / np.outer(scale, scale),
                      dtype=np.float64)


@dataclass(frozen=True)
class ThermalFrictionFit:
    """Friction curve referred to the start of the sweep, with the self-heating drift.

    Attributes
    ----------
    curve : FrictionCurve
        The air-cut current at zero dissipated energy (the state the sweep started in).
    viscous_drift_per_energy : float
        Relative change of the viscous term per dissipated energy ``E`` [1/(A rpm s)].
    coulomb_drift_per_energy : float
        Relative change of the Coulomb term per ``E`` [1/(A rpm s)].
    """

    curve: FrictionCurve
    viscous_drift_per_energy: float
    coulomb_drift_per_energy: float


def has_repeated_speeds(speed_rpm: ArrayLike, energy: ArrayLike, *, rel_tol: float = 0.005,
                        min_speeds: int = 3) -> bool:
    """True if at least ``min_speeds`` speeds were held twice at different heating states.

    Parameters
    ----------
    speed_rpm, energy : array-like
        Plateau speeds [rpm] and the friction energy dissipated before each
        (:func:`friction_energy`) [A rpm s].
    rel_tol : float, default 0.005
        Speeds within this relative distance count as the same.
    min_speeds : int, default 3
        How many repeated speeds are needed.

    Returns
    -------
    bool
    """
    n = np.abs(np.asarray(speed_rpm, dtype=np.float64))
    e = np.asarray(energy, dtype=np.float64)
    order = np.argsort(n, kind="stable")
    n, e = n[order], e[order]
    count = 0
    k = 0
    while k < n.size:
        j = k
        while j + 1 < n.size and n[j + 1] - n[k] <= rel_tol * max(n[k], 1.0):
            j += 1
        if j > k and np.ptp(e[k:j + 1]) > 0:
            count += 1
        k = j + 1
    return count >= min_speeds


def fit_friction_thermal(
    speed_rpm: ArrayLike,
    current_a: ArrayLike,
    energy: ArrayLike,
    lo_rpm: float,
    hi_rpm: float,
    *,
    decay_grid_rpm: Sequence[float] = tuple(np.geomspace(100.0, 2000.0, 40)),
    drift: str = "viscous",
) -> ThermalFrictionFit:
    """Friction curve and its self-heating drift from an air cut that revisits its speeds.

    Parameters
    ----------
    speed_rpm, current_a : array-like
        Plateau speeds [rpm] and mean currents [A].
    energy : array-like
        Friction energy dissipated before each plateau (:func:`friction_energy`) [A rpm s].
    lo_rpm, hi_rpm : float
        Speed range used [rpm].
    decay_grid_rpm : sequence of float
        Candidate Stribeck decay speeds [rpm].
    drift : {'viscous', 'both', 'common'}, default 'viscous'
        Which terms drift: only the viscous one (the grease viscosity falls as the bearings
        warm; the load-dependent Coulomb part much less), each with its own coefficient
        (the two trade off against each other on a short sweep), or both by the same
        relative amount. On 20 simulated spindles 'viscous' gave the smallest errors
        (B within 1.5 %, tau_f within 1.3 %; 'both' 2.1 % and 1.4 %, 'common' 1.9 % and 1.5 %).

    Returns
    -------
    ThermalFrictionFit

    Raises
    ------
    IdentificationError
        Fewer than 8 plateaus in the range, or no speed held twice at different energies.

    Notes
    -----
    ``I = a n (1 + g_B E) + b (1 + g_f E) + s exp(-n/n_s)``: the friction heat warms the
    bearings, whose viscous (grease) and Coulomb terms change by different relative amounts
    per kelvin; while the heat stays in the rotor (the first minutes, its time constant to
    the stator being ~10 min) the temperature rise is proportional to the dissipated energy.
    A sweep that goes up and back down holds each speed at two energies, which separates the
    drift from the curve's shape; a one-way sweep cannot (the drift then tilts the line,
    B about 1 % low, see :func:`thermal_drift_from_warm_up`). Linear in ``a, b, s, a g_B,
    b g_f`` for each ``n_s`` of the grid.
    """
    n = np.abs(np.asarray(speed_rpm, dtype=np.float64))
    i = np.abs(np.asarray(current_a, dtype=np.float64))
    e = np.asarray(energy, dtype=np.float64)
    m = np.isfinite(n) & np.isfinite(i) & np.isfinite(e) & (n >= lo_rpm) & (n <= hi_rpm)
    x, y, en = n[m], i[m], e[m]
    if x.size < 8:
        raise IdentificationError(
            f"the thermal friction fit needs at least 8 plateaus in [{lo_rpm:.0f}, "
            f"{hi_rpm:.0f}] rpm, got {x.size}")
    if not has_repeated_speeds(x, en):
        raise IdentificationError(
            "the thermal friction fit needs speeds held twice (a sweep up and back down)")
    best: tuple[float, float, NDArray[np.float64], NDArray[np.float64]] | None = None
    if drift not in ("both", "viscous", "common"):
        raise ConfigError(f"drift must be 'both', 'viscous' or 'common', not {drift!r}")
    g_grid = np.linspace(-2e-7, 2e-8, 111)  # common relative drift per A rpm s
    for ns in decay_grid_rpm:
        decay = np.exp(-x / ns)
        if drift == "common":
            # I = (a n + b)(1 + g E) + s exp(-n/n_s): linear for a fixed g, g on a grid
            for g in g_grid:
                m_g = np.column_stack([x * (1.0 + g * en), 1.0 + g * en, decay])
                s_g, *_ = np.linalg.lstsq(m_g, y, rcond=None)
                r_g = float(np.sum((m_g @ s_g - y) ** 2))
                if s_g[2] >= 0 and (best is None or r_g < best[0]):
                    coef = np.array([s_g[0], s_g[1], s_g[2], s_g[0] * g, s_g[1] * g])
                    best = (r_g, float(ns), coef, m_g)
            continue
        cols = [x, np.ones_like(x), decay, x * en] + ([en] if drift == "both" else [])
        a_mat = np.column_stack(cols)
        sol, *_ = np.linalg.lstsq(a_mat, y, rcond=None)
        if sol[2] < 0:
            continue
        rss = float(np.sum((a_mat @ sol - y) ** 2))
        if best is None or rss < best[0]:
            best = (rss, float(ns), np.concatenate([sol, np.zeros(5 - sol.size)]), a_mat)
    if best is None:
        raise IdentificationError("the thermal friction fit found no non-negative Stribeck term")
    rss, ns, sol, a_mat = best
    # covariance at the optimum of the whole model: the Jacobian holds the linear columns and
    # the derivatives by the grid-searched decay speed (s x / n_s^2 exp(-x/n_s)) and, for
    # 'common', the drift g ((a x + b) E); without them the standard errors came out ~0.65 of
    # the estimates' scatter over independent noise (tests/calibration/
    # test_friction_uncertainty.py)
    extra = [sol[2] * x / ns**2 * np.exp(-x / ns)]
    if drift == "common":
        extra.append((sol[0] * x + sol[1]) * en)
    jac = np.column_stack([a_mat, *extra])
    cov = _scaled_covariance(jac, rss)
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    line = FrictionFit(
        slope_a_per_rpm=float(sol[0]), offset_a=float(sol[1]),
        r2=1.0 - rss / ss_tot if ss_tot > 0 else float("nan"),
        norm_residuals=float(np.sqrt(rss)), n_points=int(x.size),
        slope_std=float(np.sqrt(cov[0, 0])), offset_std=float(np.sqrt(cov[1, 1])),
        lo_rpm=float(x.min()), hi_rpm=float(x.max()))
    curve = FrictionCurve(line, stribeck_a=float(sol[2]), stribeck_speed_rpm=ns,
                          model="stribeck+thermal", n_coefficients=jac.shape[1])
    return ThermalFrictionFit(curve, float(sol[3] / sol[0]), float(sol[4] / sol[1]))


FrictionModel = Callable[[ArrayLike, ArrayLike, float, float], FrictionCurve]
FRICTION_MODELS: dict[str, FrictionModel] = {
    "linear": _fit_linear,
    "stribeck": fit_friction_stribeck,
}
"""Friction model name -> ``f(speed_rpm, current_a, lo_rpm, hi_rpm) -> FrictionCurve``."""


# ====================================================================== region models
RegionModel = Callable[..., LinearRegion]


def _region_auto(stats: pd.DataFrame, segments: Sequence[NDArray[np.float64]], *,
                 fs_hz: float, poles: int | None, fw_rpm: float | None) -> LinearRegion:
    """Thesis §4.1 criteria from data (:func:`~cnctwin.spindle.linear_region`).

    ``fw_rpm`` (the field-weakening onset read from the LF currents) is not needed: the
    region is the linear run with the largest current rise, which lies below it.
    """
    return linear_region(
        stats["speed_rpm"].abs().to_numpy(), stats["current_a"].to_numpy(),
        segments=segments, fs_hz=fs_hz, poles=poles,
    )


REGION_MODELS: dict[str, RegionModel] = {"auto": _region_auto}
"""Region model name -> ``f(stats, segments, *, fs_hz, poles, fw_rpm) -> LinearRegion``."""


def ripple_free_means(
    speed_rpm: ArrayLike,
    segments: Sequence[ArrayLike],
    *,
    poles: int,
    fs_hz: float,
) -> NDArray[np.float64]:
    """Plateau mean currents with the stator-frequency ripple fitted out [A].

    Parameters
    ----------
    speed_rpm : array-like
        Plateau speeds [rpm].
    segments : sequence of array-like
        Raw current samples of each plateau [A] (:func:`~cnctwin.spindle.plateau_segments`).
    poles : int
        Motor pole count (thesis Eq. 4.1).
    fs_hz : float
        Sample rate [Hz].

    Returns
    -------
    numpy.ndarray
        Per plateau the constant of the least-squares fit ``c + s sin(2 pi f t) +
        k cos(2 pi f t)`` at the folded stator frequency ``f = fold(N p / 120, fs)``; NaN
        where ``f`` is below one cycle per plateau (the line folds onto DC and cannot be told
        from the mean).

    Notes
    -----
    The current is sampled once per 2 ms cycle, so the stator ripple (thesis Fig. 4.3) folds
    about 250 Hz. A plain mean over ``T`` seconds keeps up to ``A / (pi f T)`` of a ripple of
    amplitude ``A`` folded to ``f`` (and all of it at ``f`` = 0, e.g. 8 poles at 3750 rpm);
    with ~0.08 A ripple that is several mA, a percent of the friction slope. Fitting the
    sinusoid with the constant removes it (thesis Fig. 4.3b: the stator component does not
    move the average).
    """
    from cnctwin.analysis.filters import fold_frequency, stator_frequency_hz

    n = np.abs(np.asarray(speed_rpm, dtype=np.float64))
    out = np.full(n.size, np.nan)
    for k, seg in enumerate(segments):
        y = np.asarray(seg, dtype=np.float64)
        ok = np.isfinite(y)
        if ok.sum() < 10:
            continue
        t = np.arange(y.size)[ok] / fs_hz
        f = float(fold_frequency(stator_frequency_hz(n[k], poles), fs_hz))
        if f * y.size / fs_hz < 1.0:
            continue
        a = np.column_stack([np.ones(t.size), np.sin(2 * np.pi * f * t),
                             np.cos(2 * np.pi * f * t)])
        sol, *_ = np.linalg.lstsq(a, y[ok], rcond=None)
        out[k] = float(sol[0])
    return out


# ====================================================================== temperature
def temperature_coefficient_from_warm_up(
    rec: Recording, *, spindle: str = "SP1", min_duration_s: float = 60.0
) -> tuple[float, float]:
    """Relative change of the air-cut current per kelvin of motor temperature (thesis §4.2).

    Parameters
    ----------
    rec : Recording
        A long constant-speed air run with the LF motor temperature (r0035), e.g. the warm-up.
    spindle : str
        Spindle axis.
    min_duration_s : float, default 60
        Shortest constant-speed stretch used [s].

    Returns
    -------
    coeff_per_k : float
        ``d ln(I_air) / dT`` [1/K] (negative: the current falls as the motor warms, Fig. 4.4).
    speed_rpm : float
        Speed of the stretch used [rpm].

    Notes
    -----
    The current is averaged over 10 s blocks and regressed on the block-mean motor
    temperature. The coefficient lumps friction and Kt drift and refers to the *winding*
    temperature the drive reports, while the bearings and magnets heat at their own rate; it
    is a compensation for continuous operation, not a physical parameter.
    """
    temp = lf_on_hf(rec, "MOTOR_TEMP", spindle)
    if temp is None:
        raise SignalNotFoundError("the warm-up run has no LF motor temperature (r0035)")
    pl = speed_plateaus(rec, spindle=spindle, min_duration_s=min_duration_s)
    if pl.empty:
        raise IdentificationError("no constant-speed stretch in the warm-up run")
    p = pl.iloc[int(np.argmax(pl["n_cycles"].to_numpy()))]
    lo = int(np.searchsorted(rec.cycles, int(p["start_cycle"])))
    hi = int(np.searchsorted(rec.cycles, int(p["end_cycle"]), side="right"))
    i = rec.signal(f"CURRENT|{spindle}").to_numpy(dtype=np.float64)[lo:hi]
    t = temp.to_numpy(dtype=np.float64)[lo:hi]
    blk = max(1, round(10.0 * rec.fs_hz))
    nb = i.size // blk
    if nb < 4:
        raise IdentificationError("the warm-up stretch is shorter than 40 s")
    ib = np.nanmean(i[: nb * blk].reshape(nb, blk), axis=1)
    tb = np.nanmean(t[: nb * blk].reshape(nb, blk), axis=1)
    if np.ptp(tb) < 0.5:
        raise IdentificationError("the motor temperature rose less than 0.5 K in the warm-up")
    slope, icpt = np.polyfit(tb, ib, 1)
    t_ref = float(tb[0])
    return float(slope / (slope * t_ref + icpt)), float(p["speed_rpm"])


def friction_energy(rec: Recording, *, spindle: str = "SP1") -> NDArray[np.float64]:
    """Cumulative ``|I| |n|`` since the start of the recording [A rpm s].

    Proportional to the friction energy turned into heat in the bearings and rotor at
    constant speed (``P = Kt I omega``); the scale (``Kt 2 pi / 60``) cancels in
    :func:`thermal_drift_from_warm_up`.

    Parameters
    ----------
    rec : Recording
        The recording.
    spindle : str, default 'SP1'
        Spindle axis name.

    Returns
    -------
    numpy.ndarray
        Per HF row [A rpm s].
    """
    cur = np.abs(rec.signal(f"CURRENT|{spindle}").to_numpy(dtype=np.float64))
    speed, _ = spindle_speed_rpm(rec, spindle)
    p = np.nan_to_num(cur) * np.abs(np.nan_to_num(speed))
    return np.asarray(np.cumsum(p) / rec.fs_hz, dtype=np.float64)


def thermal_drift_from_warm_up(
    rec: Recording, *, spindle: str = "SP1", block_s: float = 5.0, skip_s: float = 10.0
) -> float:
    """Relative air-current change per unit of dissipated friction energy, from a warm-up.

    Parameters
    ----------
    rec : Recording
        Warm-up run from a cold start at constant speed (thesis §4.2).
    spindle : str
        Spindle axis.
    block_s : float, default 5
        Averaging block [s].
    skip_s : float, default 10
        Time skipped after the run-up [s].

    Returns
    -------
    float
        ``gamma`` in ``I = I_cold (1 + gamma E)`` [1/(A rpm s)], ``E`` from
        :func:`friction_energy`.

    Notes
    -----
    In the first minutes of a run the bearings and magnets keep most of the friction heat
    (their time constant to the stator is several minutes), so their temperature rise, and
    with it the drop of the friction torque (grease viscosity) and of Kt (magnets), grows with
    the dissipated energy. The winding temperature the drive reports (r0035) hardly moves in
    that time, so it cannot correct the air-cut sweep, which heats the rotor by a kelvin or
    two while it climbs through the linear region and tilts the friction line (slope ~1 %
    low). The energy is measured in both runs, so the warm-up transfers to the sweep.
    """
    e = friction_energy(rec, spindle=spindle)
    pl = speed_plateaus(rec, spindle=spindle, min_duration_s=4 * block_s)
    if pl.empty:
        raise IdentificationError("no constant-speed stretch in the warm-up run")
    p = pl.iloc[int(np.argmax(pl["n_cycles"].to_numpy()))]
    lo = int(np.searchsorted(rec.cycles, int(p["start_cycle"]))) + round(skip_s * rec.fs_hz)
    hi = int(np.searchsorted(rec.cycles, int(p["end_cycle"]), side="right"))
    i = np.abs(rec.signal(f"CURRENT|{spindle}").to_numpy(dtype=np.float64))[lo:hi]
    blk = max(1, round(block_s * rec.fs_hz))
    nb = i.size // blk
    if nb < 4:
        raise IdentificationError("the warm-up is too short for the thermal drift (< 4 blocks)")
    ib = np.nanmean(i[: nb * blk].reshape(nb, blk), axis=1)
    eb = np.nanmean(e[lo:lo + nb * blk].reshape(nb, blk), axis=1)
    slope, icpt = np.polyfit(eb, ib, 1)
    return float(slope / icpt)


# ====================================================================== alignment
def align_dynamometer(
    rec: Recording,
    *,
    dynamometer: str = "dynamometer",
    torque_column: str = "mz_nm",
    spindle: str = "SP1",
    max_lag_s: float | None = None,
) -> Recording:
    """Align the dynamometer clock to the HF clock on the cutting load.

    :func:`cnctwin.analysis.align.align_external` on the spindle current (run-ups blanked,
    lag only: a one-hole recording cannot tell a drift).

    Parameters
    ----------
    rec : Recording
        Recording with the external dynamometer channel.
    dynamometer, torque_column : str
        Channel and torque column.
    spindle : str
        Spindle axis.
    max_lag_s : float, optional
        Largest offset searched [s]; default any offset with at least half overlap.

    Returns
    -------
    Recording
        Copy with the channel's ``offset_s`` set and ``aligned=True``.
    """
    return align_external(rec, dynamometer, reference_signal=f"CURRENT|{spindle}",
                          channel_column=torque_column, max_lag_s=max_lag_s)


def find_cuts(rec: Recording, *, spindle: str = "SP1", z_axis: str | None = "Z1",
              ) -> pd.DataFrame:
    """Cutting regions of a drilling recording: :func:`~cnctwin.analysis.segments.cutting_regions`.

    Parameters
    ----------
    rec : Recording
        Recording with spindle current, speed and (optionally) the Z position.
    spindle, z_axis : str
        Axis names.

    Returns
    -------
    pandas.DataFrame
        As :func:`~cnctwin.analysis.segments.cutting_regions`.
    """
    return cutting_regions(rec, spindle=spindle, z_axis=z_axis)


# ====================================================================== options and results
@dataclass(frozen=True)
class TwinChainOptions:
    """Options of a :class:`TwinChain` (see the constructor for their meaning)."""

    friction_model: str | FrictionModel = "linear"
    region: str | tuple[float, float] | RegionModel = "auto"
    fit_from_rpm: float | None = None
    fit_to_fraction: float = 1.0
    temperature_compensation: bool = False
    acceleration_term: bool = False
    window_s: float = 0.6
    window_start: str = "cut"
    local_air_baseline: bool = False
    kt_temp_coeff_per_k: float = NDFEB_KT_TEMP_COEFF_PER_K
    poles: int | None = None
    ripple_free: bool = False
    thermal_drift: str = "viscous"


@dataclass(frozen=True)
class CutEstimate:
    """One cut of a recording: window means and the estimate (a row of Table 4.1).

    Attributes
    ----------
    start_cycle, end_cycle : int
        Averaging window (inclusive HF cycles).
    region_start_cycle, region_end_cycle : int
        The cutting region it lies in.
    speed_rpm : float
        Mean speed [rpm].
    current_a : float
        Mean spindle current [A].
    air_current_a : float
        Air-cut current subtracted [A] (local baseline or the friction curve).
    temperature_c : float
        Mean LF motor temperature [degC] (NaN if not recorded).
    accel_torque_nm : float
        Mean ``J dOmega/dt`` [Nm] (0 without the acceleration term).
    torque_nm : float
        Mean measured (dynamometer) torque [Nm] (NaN without dynamometer).
    predicted_torque_nm : float
        Mean estimated cutting torque [Nm].
    """

    start_cycle: int
    end_cycle: int
    region_start_cycle: int
    region_end_cycle: int
    speed_rpm: float
    current_a: float
    air_current_a: float
    temperature_c: float
    accel_torque_nm: float
    torque_nm: float
    predicted_torque_nm: float


@dataclass
class TwinChainResult:
    """Everything :class:`TwinChain` identified and estimated.

    Attributes
    ----------
    air_cut_stats : pandas.DataFrame
        Per-plateau statistics of the air cut (:func:`~cnctwin.spindle.air_cut_statistics`).
    field_weakening_rpm : float or None
        Field-weakening onset read from the LF |I| / Iq divergence [rpm].
    region : LinearRegion or None
        Linear speed-current region (thesis §4.1); None for a given range.
    fit_range_rpm : tuple of float
        Speed range of the friction fit [rpm].
    friction : FrictionCurve
        Air-cut current curve; ``friction.line`` is Eq. 4.2 (``a`` [A/rpm], ``b`` [A]).
    spindle_model : SpindleModel
        ``Kt`` [Nm/A], ``B`` [Nm/rpm], ``tau_f`` [Nm], ``J`` [kg m^2], temperature
        coefficients [1/K] and the reference (air-cut) motor temperature [degC].
    calibration : CutEstimate
        The calibration window (``torque_nm`` is the dynamometer torque Kt was fitted to).
    warm_up_coeff_per_k : float or None
        Relative air-cut current change per kelvin of motor temperature from the warm-up
        run [1/K].
    thermal_drift_per_energy : float or None
        Relative air-current change per dissipated friction energy from the warm-up,
        used to refer the air-cut plateaus to the cold start
        (:func:`thermal_drift_from_warm_up`) [1/(A rpm s)].
    validation : pandas.DataFrame
        One row per cut of the recordings passed to :meth:`TwinChain.run_model_from_measured`:
        ``recording`` (index), the :class:`CutEstimate` fields, ``kt_extrapolated`` (the cut's
        speed outside the calibrated range of Kt), ``error_nm`` and ``error_pct``
        (|predicted - measured| / |measured| x 100, where a dynamometer is present).
    cutting_torque : list of pandas.Series
        Estimated cutting torque per HF cycle of each recording [Nm].
    thermal_friction : ThermalFrictionFit or None
        The self-heating drift of the friction terms, where the air cut held its speeds
        twice (:func:`fit_friction_thermal`); the friction curve is then referred to the
        start of the sweep.
    """

    air_cut_stats: pd.DataFrame
    field_weakening_rpm: float | None
    region: LinearRegion | None
    fit_range_rpm: tuple[float, float]
    friction: FrictionCurve
    spindle_model: SpindleModel
    calibration: CutEstimate
    warm_up_coeff_per_k: float | None = None
    thermal_drift_per_energy: float | None = None
    validation: pd.DataFrame = field(default_factory=pd.DataFrame)
    cutting_torque: list[pd.Series] = field(default_factory=list)
    thermal_friction: ThermalFrictionFit | None = None


# ====================================================================== the chain
class TwinChain:
    """Calibrate the spindle twin and estimate the cutting torque (pvlib ModelChain style).

    Parameters
    ----------
    machine : cnctwin.machine.Machine, optional
        Machine description; only names are read (spindle axis, Z axis). No datasheet value
        is used unless passed explicitly (``poles``).
    friction_model : {'linear', 'stribeck'} or callable, default 'linear'
        Air-cut current model (:data:`FRICTION_MODELS`): ``'linear'`` is thesis Eq. 4.2,
        ``'stribeck'`` adds the decaying low-speed term (:func:`fit_friction_stribeck`).
    region : 'auto', (lo_rpm, hi_rpm) or callable, default 'auto'
        Linear region (:data:`REGION_MODELS`): ``'auto'`` applies the thesis §4.1 criteria
        below the field-weakening onset found in the data.
    fit_from_rpm : float, optional
        Start the friction fit here instead of at the region's lower limit [rpm] (for the
        Stribeck model, which needs the curved low-speed part).
    temperature_compensation : bool, default False
        Scale Kt with the LF motor temperature (magnet coefficient ``kt_temp_coeff_per_k``)
        and measure the warm-up coefficient of the air-cut current.
    acceleration_term : bool, default False
        Identify J from the air-cut run-ups and subtract ``J dOmega/dt`` (Eq. 3.1).
    window_s : float, default 0.6
        Averaging window [s] (thesis §4.3: 0.6 s).
    window_start : {'cut', 'engaged'}, default 'cut'
        ``'cut'``: the window starts where the cutting region starts (thesis); ``'engaged'``:
        where the low-passed cut current first reaches 90 % of its median over the region.
    local_air_baseline : bool, default False
        Subtract the air current measured at the same speed in the same recording (before
        and after the cut) instead of the friction curve.
    kt_temp_coeff_per_k : float
        Relative Kt change per kelvin [1/K] used with temperature compensation.
    poles : int, optional
        Motor pole count (datasheet); default estimated from the current spectra.
    ripple_free : bool, default False
        Fit the friction curve to plateau means with the stator ripple fitted out
        (:func:`ripple_free_means`) instead of plain means.
    thermal_drift : {'viscous', 'both', 'common'}, default 'viscous'
        With temperature compensation, no warm-up and an air cut that holds its speeds
        twice: which friction terms drift with the self-heating
        (:func:`fit_friction_thermal`).
    spindle, z_axis : str, optional
        Axis names; default from ``machine`` ('SP1', 'Z1').
    dynamometer, torque_column : str
        External channel and column of the measured cutting torque.
    """

    def __init__(
        self,
        machine: Any | None = None,
        *,
        friction_model: str | FrictionModel = "linear",
        region: str | tuple[float, float] | RegionModel = "auto",
        fit_from_rpm: float | None = None,
        fit_to_fraction: float = 1.0,
        temperature_compensation: bool = False,
        acceleration_term: bool = False,
        window_s: float = 0.6,
        window_start: str = "cut",
        local_air_baseline: bool = False,
        kt_temp_coeff_per_k: float = NDFEB_KT_TEMP_COEFF_PER_K,
        poles: int | None = None,
        ripple_free: bool = False,
        thermal_drift: str = "viscous",
        spindle: str | None = None,
        z_axis: str | None = None,
        dynamometer: str = "dynamometer",
        torque_column: str = "mz_nm",
        name: str = "custom",
    ) -> None:
        if isinstance(friction_model, str) and friction_model not in FRICTION_MODELS:
            raise ConfigError(f"unknown friction_model {friction_model!r}; valid: "
                              f"{', '.join(FRICTION_MODELS)} or a callable")
        if isinstance(region, str) and region not in REGION_MODELS:
            raise ConfigError(f"unknown region {region!r}; valid: {', '.join(REGION_MODELS)}, "
                              "(lo_rpm, hi_rpm) or a callable")
        if window_start not in ("cut", "engaged"):
            raise ConfigError(f"window_start must be 'cut' or 'engaged', not {window_start!r}")
        if not window_s > 0:
            raise ConfigError(f"window_s must be > 0, got {window_s}")
        self.machine = machine
        self.options = TwinChainOptions(
            friction_model=friction_model, region=region, fit_from_rpm=fit_from_rpm,
            fit_to_fraction=fit_to_fraction,
            temperature_compensation=temperature_compensation,
            acceleration_term=acceleration_term, window_s=window_s, window_start=window_start,
            local_air_baseline=local_air_baseline, kt_temp_coeff_per_k=kt_temp_coeff_per_k,
            poles=poles, ripple_free=ripple_free, thermal_drift=thermal_drift,
        )
        self.spindle = spindle or str(getattr(machine, "spindle_name", "SP1"))
        self.z_axis = z_axis if z_axis is not None else "Z1"
        self.dynamometer = dynamometer
        self.torque_column = torque_column
        self.name = name
        self._result: TwinChainResult | None = None

    def __repr__(self) -> str:
        o = self.options
        return (f"TwinChain({self.name}: friction={o.friction_model!r}, region={o.region!r}, "
                f"temperature={o.temperature_compensation}, accel={o.acceleration_term}, "
                f"window={o.window_s:g} s from {o.window_start!r})")

    # ------------------------------------------------------------------ presets
    @classmethod
    def thesis_method(cls, machine: Any | None = None, **kwargs: Any) -> TwinChain:
        """The thesis' method (§4.1-4.3).

        Region from data (thesis §4.1 criteria below the field-weakening onset),
        ``I = a n + b`` on the plateau means (Eq. 4.2), Kt from the mean current and torque of
        the first 0.6 s of the calibration cut (Eq. 4.3), friction from the line; no
        temperature and no acceleration term (Eq. 4.4).
        """
        opts: dict[str, Any] = dict(friction_model="linear", region="auto",
                                    temperature_compensation=False, acceleration_term=False,
                                    window_s=0.6, window_start="cut", local_air_baseline=False,
                                    name="thesis")
        opts.update(kwargs)
        return cls(machine, **opts)

    @classmethod
    def improved_method(cls, machine: Any | None = None, **kwargs: Any) -> TwinChain:
        """The thesis' method with its error sources removed.

        Notes
        -----
        Each change and the error it removes (numbers from ``docs/validation-spindle.md``):

        1. **Friction model with the low-speed term over a wider range**
           (``friction_model='stribeck'``, ``fit_from_rpm=300``). What is left of the Stribeck
           excess just above the thesis' 1100 rpm limit, and the rounded bend below the
           upper limit, tilt the straight line: slope about 1 % low, offset about 1 % high.
           Modelling ``s exp(-n/n_s)`` and fitting from 300 rpm removes the tilt; the upper
           limit stays the data-driven one, below the field-weakening onset.
        2. **Window in full engagement** (``window_start='engaged'``, ``window_s=1.0``). The
           first 0.6 s of a drilling cut contain the drill-point entry, where the torque
           rises and the current follows through the speed loop and the inertia: current
           and torque means are not over the same load. Starting where the cut current has
           reached 90 % of its level and averaging 1 s (not 0.6 s) removes the entry and
           halves the noise; tool heating does not matter for Kt, because current and
           torque see the same load.
        3. **Local air-cut baseline** (``local_air_baseline=True``). The air current at the
           cutting speed is measured in the same recording before/after the cut, so the
           friction at the *current* bearing temperature is subtracted. The thesis subtracts
           the friction line of a cold air cut: after a warm-up the friction has dropped
           (grease viscosity, thesis Fig. 4.4) and the estimate is biased.
        4. **Temperature compensation of Kt** (``temperature_compensation=True``). Kt falls
           with magnet temperature (NdFeB, -0.09 ... -0.12 %/K); a Kt calibrated cold
           over-estimates the torque of a warm machine by ~2 % per 20 K. Kt is scaled with
           the LF motor temperature (r0035) from the calibration temperature, and the
           identified Kt, B, tau_f are referred to the air-cut temperature. The warm-up run
           gives the lumped air-current coefficient (thesis §4.2), used where no local
           baseline exists (continuous cutting).
        6. **Sweep self-heating** (with ``temperature_compensation`` and a warm-up run). The
           up-sweep heats bearings and magnets by 1-2 K while it climbs through the linear
           region; the friction falls and the line tilts (B ~1 % low) while r0035 (winding)
           barely moves. The warm-up gives the current drop per dissipated friction energy
           (:func:`thermal_drift_from_warm_up`); each plateau mean is referred back to the
           cold start with the energy dissipated before it.
        5. **Acceleration term** (``acceleration_term=True``). J is identified from the
           air-cut run-ups (least squares on Eq. 3.1 with the identified friction) and
           ``J dOmega/dt`` is removed from windows where the speed changes.
        """
        opts: dict[str, Any] = dict(friction_model="stribeck", region="auto",
                                    fit_from_rpm=300.0, fit_to_fraction=0.8,
                                    temperature_compensation=True,
                                    acceleration_term=True, window_s=1.0,
                                    window_start="engaged", local_air_baseline=True,
                                    ripple_free=True, name="improved")
        opts.update(kwargs)
        return cls(machine, **opts)

    # ------------------------------------------------------------------ results
    @property
    def results(self) -> TwinChainResult:
        """The result of the last :meth:`calibrate` / :meth:`run_model_from_measured`."""
        if self._result is None:
            raise ConfigError("the chain is not calibrated; call calibrate() first")
        return self._result

    @property
    def model(self) -> SpindleModel:
        """The calibrated spindle model."""
        return self.results.spindle_model

    def with_model(self, model: SpindleModel) -> TwinChain:
        """Use ``model`` (e.g. with the speed law of Kt fitted to cuts at several speeds,
        :func:`cnctwin.spindle.fit_flux_law`) for the estimates from here on; returns ``self``.
        """
        self.results.spindle_model = model
        return self

    # ------------------------------------------------------------------ calibration
    def calibrate(
        self,
        air_cut: Recording | Sequence[Recording],
        calibration_cut: Recording | None,
        *,
        warm_up: Recording | None = None,
        region_index: int = 0,
        reference_torque_nm: float | None = None,
        kt_nm_per_a: float | None = None,
    ) -> TwinChain:
        """Identify the spindle from an air-cut sweep and one cut with a dynamometer.

        Parameters
        ----------
        air_cut : Recording or sequence of Recording
            Air-cut sweep (constant-speed plateaus, thesis §3.2.2); several recordings are
            pooled plateau by plateau (the inertia comes from the first).
        calibration_cut : Recording
            Recording of one cut with the dynamometer channel (thesis: steel, 2400 rpm,
            0.16 mm/rev).
        warm_up : Recording, optional
            Long constant-speed run (thesis §4.2) for the temperature coefficient.
        region_index : int, default 0
            Which cutting region of ``calibration_cut`` to use.
        reference_torque_nm : float, optional
            Mean cutting torque of the calibration window known otherwise (a torque
            measured or computed for that cut) [Nm]; replaces the dynamometer channel.
        kt_nm_per_a : float, optional
            The motor's torque constant from the drive's data (SINAMICS p0316) [Nm/A]: no
            calibration cut is used (``calibration_cut`` may be None) and the friction and J
            are referred to it; the calibration window of the results is empty (NaN).

        Returns
        -------
        TwinChain
            ``self``; results in :attr:`results`.
        """
        o = self.options
        sp = self.spindle
        air_cuts = [air_cut] if isinstance(air_cut, Recording) else list(air_cut)
        if not air_cuts:
            raise ConfigError("calibrate needs at least one air-cut recording")
        gamma = None
        if o.temperature_compensation and warm_up is not None:
            gamma = thermal_drift_from_warm_up(warm_up, spindle=sp)
        parts = [self._air_cut_plateaus(rec, gamma) for rec in air_cuts]
        stats = pd.concat([q[0] for q in parts], ignore_index=True)
        segs = [seg for q in parts for seg in q[1]]
        raw_means = np.concatenate([q[2] for q in parts])
        gamma_factor = np.concatenate([q[3] for q in parts])
        energy = np.concatenate([q[4] for q in parts])
        order = np.argsort(stats["speed_rpm"].abs().to_numpy(), kind="stable")
        stats = stats.iloc[order].reset_index(drop=True)
        segs = [segs[k] for k in order]
        raw_means, gamma_factor, energy = raw_means[order], gamma_factor[order], energy[order]
        fw = field_weakening_onset_rpm(stats, spindle=sp)
        region: LinearRegion | None = None
        fs_air = air_cuts[0].fs_hz
        if isinstance(o.region, tuple):
            lo, hi = float(o.region[0]), float(o.region[1])
        else:
            fn = REGION_MODELS[o.region] if isinstance(o.region, str) else o.region
            region = fn(stats, segs, fs_hz=fs_air, poles=o.poles, fw_rpm=fw)
            lo, hi = region.lo_rpm, region.hi_rpm
        fit_lo = o.fit_from_rpm if o.fit_from_rpm is not None else lo
        hi = fit_lo + o.fit_to_fraction * (hi - fit_lo)
        ffn = FRICTION_MODELS[o.friction_model] if isinstance(o.friction_model, str) \
            else o.friction_model
        means = raw_means
        poles = o.poles if o.poles is not None else (region.poles if region else None)
        if o.ripple_free and poles is not None:
            means = ripple_free_means(stats["speed_rpm"].to_numpy(), segs, poles=poles,
                                      fs_hz=fs_air)
        means = means / gamma_factor
        speeds = stats["speed_rpm"].abs().to_numpy()
        thermal: ThermalFrictionFit | None = None
        if (o.temperature_compensation and gamma is None and o.friction_model == "stribeck"
                and has_repeated_speeds(speeds[(speeds >= fit_lo) & (speeds <= hi)],
                                        energy[(speeds >= fit_lo) & (speeds <= hi)])):
            thermal = fit_friction_thermal(speeds, means, energy, fit_lo, hi,
                                           drift=o.thermal_drift)
            friction = thermal.curve
        else:
            friction = ffn(speeds, means, fit_lo, hi)
        t_ref = self._air_cut_temperature(stats, lo, hi)
        if kt_nm_per_a is not None:
            # Kt from the drive's motor data (p0316), no cut: friction in torque units
            j = 0.0
            if o.acceleration_term:
                j = self._inertia(air_cuts[0], self._model(kt_nm_per_a, friction, 0.0, t_ref))
            nan = float("nan")
            cal = CutEstimate(0, 0, 0, 0, nan, nan, nan, nan, 0.0, nan, nan)
            self._result = TwinChainResult(
                air_cut_stats=stats, field_weakening_rpm=fw, region=region,
                fit_range_rpm=(float(fit_lo), float(hi)), friction=friction,
                spindle_model=self._model(float(kt_nm_per_a), friction, j, t_ref),
                calibration=cal, warm_up_coeff_per_k=None, thermal_drift_per_energy=gamma,
                thermal_friction=thermal)
            return self
        if calibration_cut is None:
            raise IdentificationError("give a calibration cut (with its torque) or the "
                                      "motor's torque constant")
        # Kt from the calibration cut (Eq. 4.3)
        rec = calibration_cut
        if reference_torque_nm is None:
            if self.dynamometer not in rec.external:
                raise IdentificationError(
                    f"the calibration cut has no {self.dynamometer!r} channel; attach the "
                    "dynamometer recording or give the cut's mean torque")
            rec = align_dynamometer(rec, dynamometer=self.dynamometer,
                                    torque_column=self.torque_column, spindle=sp)
        regions = find_cuts(rec, spindle=sp, z_axis=self.z_axis)
        if len(regions) <= region_index:
            raise IdentificationError(
                f"found {len(regions)} cutting regions in the calibration cut, cannot use "
                f"index {region_index}; check cutting_regions thresholds"
            )
        j = 0.0
        kt_ref, cal = self._kt(rec, regions.iloc[region_index], friction, t_ref, j,
                               reference_torque_nm)
        if o.acceleration_term:
            model0 = self._model(kt_ref, friction, 0.0, t_ref)
            j = self._inertia(air_cuts[0], model0)
            kt_ref, cal = self._kt(rec, regions.iloc[region_index], friction, t_ref, j,
                                   reference_torque_nm)
        coeff = None
        if o.temperature_compensation and warm_up is not None:
            coeff, _ = temperature_coefficient_from_warm_up(warm_up, spindle=sp)
        self._result = TwinChainResult(
            air_cut_stats=stats,
            field_weakening_rpm=fw,
            region=region,
            fit_range_rpm=(float(fit_lo), float(hi)),
            friction=friction,
            spindle_model=self._model(kt_ref, friction, j, t_ref),
            calibration=cal,
            warm_up_coeff_per_k=coeff,
            thermal_drift_per_energy=gamma,
            thermal_friction=thermal,
        )
        return self

    def calibration_windows(
        self,
        calibration_cut: Recording,
        *,
        region_index: int = 0,
        reference_torque_nm: float | None = None,
    ) -> pd.DataFrame:
        """Kt from each consecutive averaging window of the calibration cut.

        The first window is the one :meth:`calibrate` used; the following ones continue
        back to back (``window_s`` each) to the end of the cutting region. Their spread shows
        how much Kt depends on where in the cut it is read (drill entry, tool heating, the
        speed loop's response), a component of its uncertainty that one window cannot show.

        Parameters
        ----------
        calibration_cut : Recording
            The recording :meth:`calibrate` was given.
        region_index : int, default 0
            The cutting region.
        reference_torque_nm : float, optional
            As in :meth:`calibrate`.

        Returns
        -------
        pandas.DataFrame
            One row per window: the :class:`CutEstimate` fields and ``kt_nm_per_a`` (referred
            to the model's reference temperature) [Nm/A].
        """
        res = self.results
        rec = calibration_cut
        if reference_torque_nm is None:
            rec = align_dynamometer(rec, dynamometer=self.dynamometer,
                                    torque_column=self.torque_column, spindle=self.spindle)
        regions = find_cuts(rec, spindle=self.spindle, z_axis=self.z_axis)
        region = regions.iloc[region_index]
        m = res.spindle_model
        t_ref = m.reference_temperature_c if m.reference_temperature_c is not None \
            else float("nan")
        rows: list[dict[str, Any]] = []
        start: int | None = None
        while True:
            try:
                w = self._window_means(rec, region, res.friction, m.j_kgm2,
                                       with_torque=reference_torque_nm is None,
                                       start_cycle=start)
            except IdentificationError:
                break
            if reference_torque_nm is not None:
                w["torque_nm"] = float(reference_torque_nm)
            i_cut = abs(w["current_a"]) - w["air_current_a"]
            kt = (abs(w["torque_nm"]) + w["accel_torque_nm"]) / i_cut if i_cut > 0 \
                else float("nan")
            if (self.options.temperature_compensation and np.isfinite(t_ref)
                    and np.isfinite(w["temperature_c"])):
                kt = kt / (1.0 + self.options.kt_temp_coeff_per_k * (w["temperature_c"] - t_ref))
            rows.append({**w, "kt_nm_per_a": kt})
            start = w["end_cycle"] + 1
        return pd.DataFrame(rows)

    def _air_cut_plateaus(
        self, rec: Recording, gamma: float | None
    ) -> tuple[pd.DataFrame, list[NDArray[np.float64]], NDArray[np.float64],
               NDArray[np.float64], NDArray[np.float64]]:
        """Plateau statistics, raw samples, means, thermal factor and energy of one air cut."""
        sp = self.spindle
        plateaus = speed_plateaus(rec, spindle=sp)
        stats = air_cut_statistics(rec, plateaus, spindle=sp)
        p_sorted = plateaus.assign(_n=plateaus["speed_rpm"].abs()).sort_values(
            "_n", kind="stable")
        segs = plateau_segments(rec, p_sorted, spindle=sp)
        means = stats["current_a"].to_numpy(dtype=np.float64)
        e = friction_energy(rec, spindle=sp)
        mid = np.searchsorted(rec.cycles,
                              ((stats["start_cycle"] + stats["end_cycle"]) // 2).to_numpy())
        energy = e[np.clip(mid, 0, e.size - 1)]
        factor = 1.0 + gamma * energy if gamma is not None else np.ones(means.size)
        return stats, list(segs), means, factor, energy

    def _model(self, kt: float, friction: FrictionCurve, j: float,
               t_ref: float) -> SpindleModel:
        o = self.options
        temp = o.temperature_compensation and np.isfinite(t_ref)
        return SpindleModel(
            kt_nm_per_a=kt,
            b_nm_per_rpm=friction.line.slope_a_per_rpm * kt,
            tau_f_nm=friction.line.offset_a * kt,
            j_kgm2=j,
            kt_temp_coeff_per_k=o.kt_temp_coeff_per_k if temp else 0.0,
            reference_temperature_c=t_ref if temp else None,
        )

    def _air_cut_temperature(self, stats: pd.DataFrame, lo: float, hi: float) -> float:
        col = f"MOTOR_TEMP|{self.spindle} (LF) mean"
        if col not in stats:
            return float("nan")
        n = stats["speed_rpm"].abs()
        v = stats.loc[(n >= lo) & (n <= hi), col].to_numpy(dtype=np.float64)
        v = v[np.isfinite(v)]
        return float(v.mean()) if v.size else float("nan")

    def _inertia(self, air_cut: Recording, model: SpindleModel) -> float:
        # the rotor's own speed (encoder) where recorded: the command leads it by the speed
        # loop's lag, which biases J on short run-ups
        speed, _ = spindle_speed_rpm(air_cut, self.spindle, prefer_actual=True)
        cur = air_cut.signal(f"CURRENT|{self.spindle}").to_numpy(dtype=np.float64)
        try:
            j = identify_inertia(speed, model.kt_nm_per_a * cur, fs_hz=air_cut.fs_hz,
                                 model=model, min_speed_rpm=300.0)
        except IdentificationError:
            return 0.0
        return max(float(j), 0.0)

    def _kt(self, rec: Recording, region: pd.Series, friction: FrictionCurve, t_ref: float,
            j: float, torque_nm: float | None = None) -> tuple[float, CutEstimate]:
        w = self._window_means(rec, region, friction, j, with_torque=torque_nm is None)
        if torque_nm is not None:
            w["torque_nm"] = float(torque_nm)
        elif not np.isfinite(w["torque_nm"]):
            t0 = (w["start_cycle"] - int(rec.cycles[0])) / rec.fs_hz
            t1 = (w["end_cycle"] - int(rec.cycles[0])) / rec.fs_hz
            raise IdentificationError(
                f"the {self.dynamometer} channel has no samples in the calibration window "
                f"(cycles {w['start_cycle']}-{w['end_cycle']}, {t0:.1f}-{t1:.1f} s into the "
                "recording): it does not overlap the cut; check that the CSV belongs to this "
                "recording and covers the whole cut")
        i_cut = abs(w["current_a"]) - w["air_current_a"]
        if i_cut <= 1e-3 * max(abs(w["current_a"]), 1e-9) or not abs(w["torque_nm"]) > 0:
            raise IdentificationError(
                f"the calibration window current {w['current_a']:.4g} A does not exceed the "
                f"air current {w['air_current_a']:.4g} A: no cut in the window"
            )
        kt_cal = (abs(w["torque_nm"]) + w["accel_torque_nm"]) / i_cut
        kt_ref = kt_cal
        o = self.options
        if o.temperature_compensation and np.isfinite(t_ref) and np.isfinite(w["temperature_c"]):
            kt_ref = kt_cal / (1.0 + o.kt_temp_coeff_per_k * (w["temperature_c"] - t_ref))
        cal = CutEstimate(**{**w, "predicted_torque_nm": abs(w["torque_nm"])})
        return float(kt_ref), cal

    # ------------------------------------------------------------------ windows
    def _window_means(self, rec: Recording, region: pd.Series, friction: FrictionCurve,
                      j: float, *, with_torque: bool, start_cycle: int | None = None,
                      ) -> dict[str, Any]:
        o = self.options
        sp = self.spindle
        fs = rec.fs_hz
        cyc = rec.cycles
        r0 = int(np.searchsorted(cyc, int(region["start_cycle"])))
        r1 = int(np.searchsorted(cyc, int(region["end_cycle"]), side="right"))
        cur = rec.signal(f"CURRENT|{sp}").to_numpy(dtype=np.float64)
        speed, _ = spindle_speed_rpm(rec, sp)
        start = r0
        if start_cycle is not None:
            start = int(np.searchsorted(cyc, start_cycle))
        elif o.window_start == "engaged":
            seg = np.abs(cur[r0:r1])
            base = float(np.median(np.abs(cur[max(0, r0 - round(0.3 * fs)):r0]))) \
                if r0 > 0 else 0.0
            sm = lowpass(seg, 10.0, fs_hz=fs, order=2) if seg.size > 30 else seg
            lvl = base + 0.9 * (float(np.median(sm)) - base)
            hit = np.flatnonzero(sm >= lvl)
            start = r0 + (int(hit[0]) if hit.size else 0)
        stop = min(r1, start + round(o.window_s * fs))
        if stop - start < max(5, round(0.1 * fs)):
            raise IdentificationError(
                f"the cut at cycles {region['start_cycle']}-{region['end_cycle']} is shorter "
                f"than a usable window; shorten window_s (now {o.window_s} s)"
            )
        n_mean = float(np.nanmean(speed[start:stop]))
        i_mean = float(np.nanmean(cur[start:stop]))
        temp_s = lf_on_hf(rec, "MOTOR_TEMP", sp)
        temp = float(np.nanmean(temp_s.to_numpy(dtype=np.float64)[start:stop])) \
            if temp_s is not None else float("nan")
        acc = 0.0
        if o.acceleration_term and j > 0:
            w = speed * RPM_TO_RAD_S
            acc = j * float(np.nanmean(np.gradient(w)[start:stop] * fs))
        air = float("nan")
        if o.local_air_baseline:
            air = self._local_air(rec, cur, speed, r0, r1, n_mean)
        if not np.isfinite(air):
            air = float(friction.current_a(n_mean))
        torque = float("nan")
        if with_torque and self.dynamometer in rec.external:
            ext = external_on_hf(rec, self.dynamometer, columns=[self.torque_column])
            tv = ext[self.torque_column].to_numpy(dtype=np.float64)[start:stop]
            if np.isfinite(tv).any():
                torque = float(np.nanmean(tv))
        return {
            "start_cycle": int(cyc[start]),
            "end_cycle": int(cyc[stop - 1]),
            "region_start_cycle": int(region["start_cycle"]),
            "region_end_cycle": int(region["end_cycle"]),
            "speed_rpm": n_mean,
            "current_a": i_mean,
            "air_current_a": air,
            "temperature_c": temp,
            "accel_torque_nm": acc,
            "torque_nm": torque,
        }

    def _local_air(self, rec: Recording, cur: NDArray[np.float64], speed: NDArray[np.float64],
                   r0: int, r1: int, n_cut: float) -> float:
        """Mean air current at the cut speed in the same recording, outside any cut."""
        fs = rec.fs_hz
        steady = np.abs(speed - n_cut) <= max(1.0, 1e-3 * abs(n_cut))
        # drop the first 0.5 s of each steady run (speed loop settling after the run-up)
        k = round(0.5 * fs)
        d = np.diff(np.concatenate([[0], steady.astype(np.int8)]))
        for s in np.flatnonzero(d == 1):
            steady[s:s + k] = False
        excl = np.zeros(cur.size, dtype=bool)
        excl[max(0, r0 - round(0.1 * fs)):min(cur.size, r1 + round(0.3 * fs))] = True
        m = steady & ~excl
        if m.sum() < round(0.2 * fs):
            return float("nan")
        return float(np.nanmean(np.abs(cur[m])))

    # ------------------------------------------------------------------ estimation
    def run_model_from_measured(
        self,
        recordings: Recording | Sequence[Recording],
        *,
        labels: Sequence[str] | None = None,
    ) -> TwinChain:
        """Estimate the cutting torque of recordings with the calibrated model.

        Parameters
        ----------
        recordings : Recording or sequence of Recording
            Recordings with spindle current and speed (and a dynamometer, to validate).
        labels : sequence of str, optional
            A label per recording for the ``recording`` column (default its index).

        Returns
        -------
        TwinChain
            ``self``; :attr:`results` ``.validation`` and ``.cutting_torque`` are replaced.
        """
        res = self.results
        recs = [recordings] if isinstance(recordings, Recording) else list(recordings)
        names = list(labels) if labels is not None else [str(k) for k in range(len(recs))]
        if len(names) != len(recs):
            raise ConfigError(f"{len(names)} labels for {len(recs)} recordings")
        rows: list[dict[str, Any]] = []
        series: list[pd.Series] = []
        for name, rec in zip(names, recs, strict=True):
            if self.dynamometer in rec.external and not rec.external[self.dynamometer].aligned:
                rec = align_dynamometer(rec, dynamometer=self.dynamometer,
                                        torque_column=self.torque_column, spindle=self.spindle)
            regions = find_cuts(rec, spindle=self.spindle, z_axis=self.z_axis)
            tau = self._torque_series(rec, regions)
            series.append(tau)
            for _, reg in regions.iterrows():
                w = self._window_means(rec, reg, res.friction, res.spindle_model.j_kgm2,
                                       with_torque=True)
                pred = self._predict(w)
                extra = bool(res.spindle_model.kt_extrapolated(w["speed_rpm"]))
                rows.append({"recording": name, **w, "predicted_torque_nm": pred,
                             "kt_extrapolated": extra})
        df = pd.DataFrame(rows)
        if not df.empty:
            meas = df["torque_nm"].abs()
            df["error_nm"] = df["predicted_torque_nm"] - meas
            with np.errstate(divide="ignore", invalid="ignore"):
                df["error_pct"] = (df["error_nm"].abs() / meas * 100.0)
        res.validation = df
        res.cutting_torque = series
        return self

    def _kt_at(self, temperature_c: float, speed_rpm: float | None = None) -> float:
        m = self.results.spindle_model
        kt = m.kt_nm_per_a
        if speed_rpm is not None and m.flux_base_speed_rpm > 0:
            kt = float(m.kt_at_speed(speed_rpm))
        if m.reference_temperature_c is None or not np.isfinite(temperature_c):
            return kt
        return kt * (1.0 + m.kt_temp_coeff_per_k * (temperature_c - m.reference_temperature_c))

    def _predict(self, w: dict[str, Any]) -> float:
        """Mean cutting torque of a window [Nm]: ``Kt(T, n) (I - I_air) - J dOmega/dt``."""
        kt = self._kt_at(w["temperature_c"], w["speed_rpm"])
        return float(kt * (abs(w["current_a"]) - w["air_current_a"]) - w["accel_torque_nm"])

    def _torque_series(self, rec: Recording, regions: pd.DataFrame) -> pd.Series:
        res = self.results
        sp = self.spindle
        cur = rec.signal(f"CURRENT|{sp}").to_numpy(dtype=np.float64)
        speed, _ = spindle_speed_rpm(rec, sp)
        temp_s = lf_on_hf(rec, "MOTOR_TEMP", sp)
        temp = temp_s.to_numpy(dtype=np.float64) if temp_s is not None else None
        kt = np.full(cur.size, res.spindle_model.kt_nm_per_a)
        if temp is not None and res.spindle_model.reference_temperature_c is not None:
            kt = kt * (1.0 + res.spindle_model.kt_temp_coeff_per_k
                       * (np.nan_to_num(temp, nan=res.spindle_model.reference_temperature_c)
                          - res.spindle_model.reference_temperature_c))
        if res.spindle_model.flux_base_speed_rpm > 0:
            kt = kt * res.spindle_model.flux_factor(speed)
        air = res.friction.current_a(speed)
        tau = kt * (np.abs(cur) - air) * np.sign(np.where(speed == 0, 1.0, speed))
        if self.options.acceleration_term and res.spindle_model.j_kgm2 > 0:
            tau = tau - res.spindle_model.j_kgm2 * np.gradient(speed * RPM_TO_RAD_S) * rec.fs_hz
        return pd.Series(tau, index=rec.hf.index.copy(), name="cutting_torque_nm")
