"""Hole quality from servo positions: deviation paths, position error, straightness, flags.

Thesis chapter 5.3: while Z drills, the X and Y setpoints are constant, so any difference
between the desired (``DES_POS``) and the encoder (``ENC_POS``) positions of X and Y during the
cut shows the tool being pushed sideways (friction, walking drill, anomalies) and hints at a hole
that is off position or not straight. Figures 5.6-5.9 show these paths per hole in 3D and in the
X-Z, Y-Z and X-Y planes with the top of the hole at (0, 0, 0); :func:`deviation_paths` gives the
data and :mod:`cnctwin.usecases.figures` draws them.

Indicators (per hole, over the cut from the surface to the bottom):

* position error: ``|mean(ENC_xy - DES_xy)|``, the mean lateral offset from the programmed
  position [mm];
* straightness: ``max_k |d_xy(k) - mean(d_xy)|`` with ``d = ENC - DES``, the largest lateral
  excursion along the depth once the mean offset is removed [mm];
* out-of-tolerance flags against a tolerance [mm].

These are servo-side indicators: the encoder measures the axis, not the tool tip, so bending of
the drill itself is not seen. They flag holes to inspect; they do not replace a CMM.

Dynamic indicators (:func:`hole_runout`): the speed-loop integral rejects slow lateral forces,
so the static walk is invisible in ``ENC - DES``, but two lateral forces are fast enough to pass
the axis' dynamic compliance (:func:`feed_axis_dynamic_stiffness`):

* the force rotating with the spindle (unequal lip heights, grows with wear): a 1x spindle
  frequency component of the X/Y deviation (40 Hz at 2400 rpm), measured by a lock-in fit
  over the full-engagement part of the cut -> ``runout_um``;
* the chisel-edge skid at entry (~0.2 s while the point enters): a bump of the X/Y deviation
  whose direction is the skid direction -> ``entry_deviation_um``, ``entry_direction_rad``.

With the axis description (``machine``) the amplitudes become forces (amplitude x dynamic
stiffness); with the drill (``drill``) tool-tip estimates follow: hole position error
F_entry / k_tip, orbit radius runout + F_rot / (g k_tip), oversize twice that
(:class:`cnctwin.machine.tools.Drill`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray

from cnctwin.exceptions import ConfigError, SignalNotFoundError
from cnctwin.recording import Recording

if TYPE_CHECKING:
    from cnctwin.machine import FeedAxis, Machine
    from cnctwin.machine.tools import Drill

__all__ = [
    "AxisStiffness",
    "deviation_paths",
    "feed_axis_dynamic_stiffness",
    "hole_quality",
    "hole_runout",
]


def _hole_rows(rec: Recording, holes: pd.DataFrame) -> pd.DataFrame:
    need = {"hole", "cut_start_cycle", "cut_end_cycle"}
    if not need <= set(holes.columns):
        raise ConfigError(f"hole table needs columns {sorted(need)}; run hole_record first")
    c0, c1 = int(rec.cycles[0]), int(rec.cycles[-1])
    inside = (holes["cut_start_cycle"] >= c0) & (holes["cut_end_cycle"] <= c1)
    return holes[inside]


def _axes_present(rec: Recording, axes: tuple[str, str, str]) -> None:
    for ax in axes:
        for code in ("DES_POS", "ENC_POS"):
            if not rec.has(code, ax):
                raise SignalNotFoundError(
                    f"hole quality needs {code}|{ax}; the recording has: {', '.join(rec.columns)}"
                )


def deviation_paths(
    rec: Recording,
    holes: pd.DataFrame,
    *,
    axes: tuple[str, str, str] = ("X1", "Y1", "Z1"),
) -> pd.DataFrame:
    """Desired and encoder positions of every hole, with the top of the hole at (0, 0, 0).

    Parameters
    ----------
    rec : Recording
        Recording with ``DES_POS`` and ``ENC_POS`` of the three axes.
    holes : pandas.DataFrame
        Hole record of this recording (:func:`~cnctwin.usecases.holes.hole_record`).
    axes : (str, str, str), default ('X1', 'Y1', 'Z1')
        Lateral X, lateral Y and drilling axis.

    Returns
    -------
    pandas.DataFrame
        Long form, one row per cycle of each cut: ``hole``, ``cycle``, ``t_s`` (from the cut
        start) [s], ``des_x_mm``, ``des_y_mm``, ``des_z_mm``, ``enc_x_mm``, ``enc_y_mm``,
        ``enc_z_mm`` [mm], all relative to the top of the hole: the programmed X/Y at the cut
        start and the surface Z (``surface_z_mm`` of the hole record).
    """
    _axes_present(rec, axes)
    rows = _hole_rows(rec, holes)
    cyc = rec.cycles
    parts = []
    for _, h in rows.iterrows():
        lo = int(np.searchsorted(cyc, int(h["cut_start_cycle"])))
        hi = int(np.searchsorted(cyc, int(h["cut_end_cycle"]), side="right"))
        sl = slice(lo, hi)
        top = [float(rec.hf[f"DES_POS|{axes[0]}"].iloc[lo]),
               float(rec.hf[f"DES_POS|{axes[1]}"].iloc[lo]),
               float(h["surface_z_mm"]) if "surface_z_mm" in h and math.isfinite(
                   float(h["surface_z_mm"])) else float(rec.hf[f"DES_POS|{axes[2]}"].iloc[lo])]
        d = {"hole": int(h["hole"]), "cycle": cyc[sl],
             "t_s": (cyc[sl] - cyc[lo]) * rec.meta.cycle_time_s}
        for k, (ax, tag) in enumerate(zip(axes, ("x", "y", "z"), strict=True)):
            d[f"des_{tag}_mm"] = rec.hf[f"DES_POS|{ax}"].to_numpy(dtype=np.float64)[sl] - top[k]
            d[f"enc_{tag}_mm"] = rec.hf[f"ENC_POS|{ax}"].to_numpy(dtype=np.float64)[sl] - top[k]
        parts.append(pd.DataFrame(d))
    cols = ["hole", "cycle", "t_s", "des_x_mm", "des_y_mm", "des_z_mm", "enc_x_mm", "enc_y_mm",
            "enc_z_mm"]
    if not parts:
        return pd.DataFrame(columns=cols)
    return pd.concat(parts, ignore_index=True)[cols]


def hole_quality(
    rec: Recording,
    holes: pd.DataFrame,
    *,
    tolerance_mm: float = 0.01,
    straightness_tolerance_mm: float | None = None,
    nominal_depth_mm: float | None = None,
    depth_tolerance_mm: float = 0.1,
    machine: Machine | None = None,
    drill: Drill | None = None,
    tip_tolerance_mm: float = 0.05,
    oversize_tolerance_mm: float = 0.02,
    axes: tuple[str, str, str] = ("X1", "Y1", "Z1"),
) -> pd.DataFrame:
    """Position error, straightness and out-of-tolerance flags per hole.

    Parameters
    ----------
    rec : Recording
        Recording with ``DES_POS``/``ENC_POS`` of the three axes.
    holes : pandas.DataFrame
        Hole record of this recording.
    tolerance_mm : float, default 0.01
        Position tolerance (radius) [mm].
    straightness_tolerance_mm : float, optional
        Straightness tolerance [mm]; default ``tolerance_mm``.
    nominal_depth_mm : float, optional
        Programmed depth; with it ``depth_error_mm`` and ``depth_oot`` are filled [mm].
    depth_tolerance_mm : float, default 0.1
        Depth tolerance [mm].
    machine, drill : optional
        Axis and tool descriptions for the force and tool-tip estimates of
        :func:`hole_runout` (columns added when the hole record has ``speed_rpm``).
    tip_tolerance_mm : float, default 0.05
        Tolerance of the estimated tool-tip position error (hole position) [mm]. [E] +-0.05
        mm is a usual positional tolerance of drilled holes without a pilot
    oversize_tolerance_mm : float, default 0.02
        Tolerance of the estimated hole oversize [mm]. [E]
    axes : (str, str, str)
        Lateral X, lateral Y and drilling axis.

    Returns
    -------
    pandas.DataFrame
        Per hole: ``hole``, ``position_error_x_mm``, ``position_error_y_mm``,
        ``position_error_mm``, ``straightness_mm``, ``depth_error_mm``, the columns of
        :func:`hole_runout`, ``position_oot``, ``straightness_oot``, ``depth_oot``,
        ``tip_position_oot``, ``oversize_oot`` (False without estimates), ``out_of_tolerance``
        (any flag).

    Notes
    -----
    With ``d = ENC - DES`` of X and Y over the cut: position error ``|mean(d)|``, straightness
    ``max |d - mean(d)|`` (both Euclidean in the XY plane).
    """
    if tolerance_mm <= 0:
        raise ConfigError(f"tolerance_mm must be > 0, not {tolerance_mm}")
    st_tol = tolerance_mm if straightness_tolerance_mm is None else straightness_tolerance_mm
    paths = deviation_paths(rec, holes, axes=axes)
    rows = []
    for hole, p in paths.groupby("hole", sort=True):
        dx = (p["enc_x_mm"] - p["des_x_mm"]).to_numpy()
        dy = (p["enc_y_mm"] - p["des_y_mm"]).to_numpy()
        mx, my = float(np.nanmean(dx)), float(np.nanmean(dy))
        straight = float(np.nanmax(np.hypot(dx - mx, dy - my))) if dx.size else math.nan
        rows.append({"hole": int(str(hole)), "position_error_x_mm": mx, "position_error_y_mm": my,
                     "position_error_mm": math.hypot(mx, my), "straightness_mm": straight})
    q = pd.DataFrame(rows, columns=["hole", "position_error_x_mm", "position_error_y_mm",
                                    "position_error_mm", "straightness_mm"])
    depth = holes.set_index("hole")["depth_mm"] if "depth_mm" in holes.columns else None
    if nominal_depth_mm is not None and depth is not None:
        q["depth_error_mm"] = q["hole"].map(depth).astype(float) - nominal_depth_mm
    else:
        q["depth_error_mm"] = math.nan
    if "speed_rpm" in holes.columns and len(q):
        ro = hole_runout(rec, holes, machine=machine, drill=drill, axes=axes)
        q = q.merge(ro, on="hole", how="left")
    q["position_oot"] = q["position_error_mm"] > tolerance_mm
    q["straightness_oot"] = q["straightness_mm"] > st_tol
    q["depth_oot"] = q["depth_error_mm"].abs() > depth_tolerance_mm
    q["tip_position_oot"] = (q["tip_position_error_est_um"] > 1000.0 * tip_tolerance_mm
                             if "tip_position_error_est_um" in q else False)
    q["oversize_oot"] = (q["hole_oversize_est_um"] > 1000.0 * oversize_tolerance_mm
                         if "hole_oversize_est_um" in q else False)
    q["out_of_tolerance"] = (q["position_oot"] | q["straightness_oot"] | q["depth_oot"]
                             | q["tip_position_oot"] | q["oversize_oot"])
    q.attrs.update({"tolerance_mm": tolerance_mm, "straightness_tolerance_mm": st_tol,
                    "nominal_depth_mm": nominal_depth_mm,
                    "depth_tolerance_mm": depth_tolerance_mm,
                    "tip_tolerance_mm": tip_tolerance_mm,
                    "oversize_tolerance_mm": oversize_tolerance_mm})
    return q


@dataclass(frozen=True)
class AxisStiffness:
    """Result of :func:`feed_axis_dynamic_stiffness`.

    Attributes
    ----------
    frequency_hz : numpy.ndarray
        Frequencies [Hz].
    stiffness_n_per_um : numpy.ndarray
        |F / x| at the slide [N/um].
    phase_rad : numpy.ndarray
        Phase of F / x [rad].
    """

    frequency_hz: NDArray[np.float64]
    stiffness_n_per_um: NDArray[np.float64]
    phase_rad: NDArray[np.float64]


def feed_axis_dynamic_stiffness(
    axis: FeedAxis, frequency_hz: ArrayLike, *, standstill: bool = True
) -> AxisStiffness:
    """Dynamic stiffness of a position-controlled ball-screw axis against a force at the slide.

    Parameters
    ----------
    axis : cnctwin.machine.FeedAxis
        Axis description (inertia, pitch, speed-controller gains, Kv, friction).
    frequency_hz : array-like
        Frequencies [Hz].
    standstill : bool, default True
        Linearise the Coulomb + Stribeck friction of a standing slide as the damper
        (F_c + F_s) / v_eps of its smoothing band (``friction_smoothing_mm_s``).

    Returns
    -------
    AxisStiffness

    Notes
    -----
    With rho = pitch / 2 pi [m/rad], motor angle theta = x / rho, a P position loop (Kv, closed
    in the drive with DSC), a PI speed loop (Kp, Ti) and a PT1 current loop (T_i):

        F / x = [J s^2 + Kp (1 + 1/(Ti s)) (s + Kv) / (1 + T_i s)] / rho^2 + c s

    (J at the motor, c the viscous + linearised friction at the slide). The integral makes the
    axis infinitely stiff at 0 Hz; around the speed-loop corner it is softest. Default X axis:
    J = 2.5e-3 kg m^2, Kp = 1.5 Nm s/rad, Ti = 8 ms, Kv = 41.7 1/s, rho = 1.59 mm/rad:
    133 N/um at 40 Hz without friction, 390 N/um with the standstill friction band
    (v_eps = 0.2 mm/s), so a 20-60 N rotating force moves the slide 0.05-0.15 um; with the
    former 0.02 mm/s band it was 2760 N/um (7-20 nm). Structure after Altintas et al.,
    Machine tool feed drives, CIRP Annals 60 (2011) 779-796 (disturbance response of
    ball-screw drives).
    """
    f = np.atleast_1d(np.asarray(frequency_hz, dtype=np.float64))
    s = 2j * np.pi * np.maximum(f, 1e-9)
    rho = axis.screw_pitch_mm / 1000.0 / (2.0 * math.pi)
    ctrl = (axis.speed_kp_nm_s_per_rad * (1.0 + 1.0 / (axis.speed_ti_s * s)) * (s + axis.kv_per_s)
            / (1.0 + axis.equiv_currctrl_time_s * s))
    c_mm = axis.viscous_n_per_mm_s
    if standstill:
        c_mm += (axis.coulomb_n + axis.stribeck_n) / axis.friction_smoothing_mm_s
    k = (axis.total_inertia_kgm2 * s * s + ctrl) / rho**2 + c_mm * 1000.0 * s
    return AxisStiffness(f, np.abs(k) / 1e6, np.angle(k))


def _axis_response_um_per_n(axis: FeedAxis, force: NDArray[np.float64], dt_s: float,
                            *, standstill: bool = True) -> NDArray[np.float64]:
    """Slide displacement [um] of the position-controlled axis under a force history [N].

    Linear model of :func:`feed_axis_dynamic_stiffness` as H(s) = x / F, simulated with a
    zero-order hold on the force (scipy.signal.lsim).
    """
    from scipy.signal import lsim

    rho = axis.screw_pitch_mm / 1000.0 / (2.0 * math.pi)
    c_mm = axis.viscous_n_per_mm_s
    if standstill:
        c_mm += (axis.coulomb_n + axis.stribeck_n) / axis.friction_smoothing_mm_s
    c_rot = c_mm * 1000.0 * rho**2  # at the motor [Nm s/rad]
    j, kp, ti = axis.total_inertia_kgm2, axis.speed_kp_nm_s_per_rad, axis.speed_ti_s
    tc, kv = axis.equiv_currctrl_time_s, axis.kv_per_s
    num = [rho**2 * ti * tc * 1e6, rho**2 * ti * 1e6, 0.0]
    den = np.polyadd(np.polymul([j, c_rot, 0.0], [ti * tc, ti, 0.0]),
                     kp * np.array([ti, ti * kv + 1.0, kv]))
    t = np.arange(force.size) * dt_s
    _, y, _ = lsim((num, den), force, t, interp=False)
    return np.asarray(y, dtype=np.float64)


def _alias_hz(f: float, fs: float) -> float:
    return abs(((f + fs / 2.0) % fs) - fs / 2.0)


def _lstsq_cov(a: NDArray[np.float64], d: NDArray[np.float64]
               ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Least-squares coefficients of ``a x = d`` and their white-noise covariance
    s^2 (A'A)^-1 (s^2 the residual variance; NaN without degrees of freedom)."""
    coef, *_ = np.linalg.lstsq(a, d, rcond=None)
    dof = d.size - a.shape[1]
    s2 = float(np.sum((d - a @ coef) ** 2)) / dof if dof > 0 else math.nan
    return np.asarray(coef, dtype=np.float64), np.asarray(s2 * np.linalg.pinv(a.T @ a),
                                                          dtype=np.float64)


def _lockin(t: NDArray[np.float64], d: NDArray[np.float64], f_hz: float
            ) -> tuple[float, float]:
    """Amplitude of the f_hz sinusoid in d(t) (least squares with offset and trend) and its
    standard error from the residual (white-noise covariance s^2 (A'A)^-1, propagated to
    sqrt(a^2 + b^2) to first order)."""
    w = 2.0 * math.pi * f_hz
    a = np.column_stack([np.ones_like(t), t - t.mean(), np.cos(w * t), np.sin(w * t)])
    coef, cov_all = _lstsq_cov(a, d)
    amp = float(math.hypot(coef[2], coef[3]))
    if t.size <= a.shape[1] or amp == 0.0:
        return amp, math.nan
    cov = cov_all[2:, 2:]
    g = np.array([coef[2], coef[3]]) / amp
    return amp, float(math.sqrt(max(float(g @ cov @ g), 0.0)))


def hole_runout(
    rec: Recording,
    holes: pd.DataFrame,
    *,
    point_length_mm: float = 4.25 / math.tan(math.radians(70.0)),
    machine: Machine | None = None,
    drill: Drill | None = None,
    axes: tuple[str, str, str] = ("X1", "Y1", "Z1"),
) -> pd.DataFrame:
    """Spindle-frequency run-out and entry deviation of X/Y per hole (dynamic indicators).

    Parameters
    ----------
    rec : Recording
        Recording with ``DES_POS``/``ENC_POS`` of the three axes.
    holes : pandas.DataFrame
        Hole record (needs ``speed_rpm``).
    point_length_mm : float
        Axial length of the drill point (D/2)/tan(sigma/2) [mm]; default 8.5 mm, 140 deg.
    machine : cnctwin.machine.Machine, optional
        Axis description: adds force estimates (amplitude x :func:`feed_axis_dynamic_stiffness`).
    drill : cnctwin.machine.tools.Drill, optional
        With ``machine``: tool-tip estimates from the drill's tip stiffness and run-out.
    axes : (str, str, str)
        Lateral X, lateral Y and drilling axis.

    Returns
    -------
    pandas.DataFrame
        Per hole: ``hole``, ``spindle_hz``, ``alias_hz`` (frequency seen at the recording rate),
        ``runout_x_um``, ``runout_y_um``, ``runout_um`` (mean of the two: slide orbit radius),
        their standard errors ``runout_x_se_um``, ``runout_y_se_um``, ``runout_se_um`` (from
        the lock-in residual: the encoders' measuring noise),
        ``entry_deviation_x_um``, ``entry_deviation_y_um``, ``entry_deviation_um``,
        ``entry_direction_rad`` (largest excursion of the revolution-averaged deviation);
        with ``machine``: ``rotating_force_est_n`` (and ``rotating_force_se_n``),
        ``entry_force_est_x_n``/``_y_n``,
        ``entry_force_est_n``, ``entry_force_direction_rad``, ``walk_force_est_x_n``/``_y_n``,
        (standard errors ``entry_force_se_n``, ``walk_force_se_n``,
        ``tip_position_error_se_um``),
        ``walk_force_est_n``; with ``drill`` too: ``tip_position_error_est_um``,
        ``tip_straightness_est_um``, ``tip_orbit_radius_est_um``, ``hole_oversize_est_um``.

    Notes
    -----
    Run-out: lock-in fit a cos(wt) + b sin(wt) + offset + trend of ``ENC - DES`` of X and of Y
    over the cut deeper than two point lengths (full engagement), w = 2 pi x alias of n/60 at the
    recording rate; amplitude sqrt(a^2 + b^2). Entry: ``ENC - DES`` minus its mean over the
    0.1 s before the tip reaches the surface, averaged over one spindle revolution, from the
    surface to three point lengths deep; the largest excursion (vector) gives amplitude and
    direction. Forces (with ``machine``): least-squares fit of the entry window with the axis'
    responses to the walk (rising with the thrust) and to the chisel-edge bump (``_entry_fit``);
    rotating force = run-out amplitude x |K(n/60)|. On the simulated wear run these recover the
    hidden forces to a few per cent (rotating, entry) and ~25 % (walk): docs/hole-quality.md.
    """
    paths = deviation_paths(rec, holes, axes=axes)
    if "speed_rpm" not in holes.columns:
        raise ConfigError("hole_runout needs the hole record's speed_rpm column")
    fs = rec.fs_hz
    speed = holes.set_index("hole")["speed_rpm"]
    cyc = rec.cycles
    dx_all = (rec.hf[f"ENC_POS|{axes[0]}"] - rec.hf[f"DES_POS|{axes[0]}"]).to_numpy(np.float64)
    dy_all = (rec.hf[f"ENC_POS|{axes[1]}"] - rec.hf[f"DES_POS|{axes[1]}"]).to_numpy(np.float64)
    rows = []
    for hole, p in paths.groupby("hole", sort=True):
        h = int(str(hole))
        f_sp = abs(float(speed.get(h, math.nan))) / 60.0
        fa = _alias_hz(f_sp, fs) if math.isfinite(f_sp) else math.nan
        z = p["des_z_mm"].to_numpy()
        t = p["t_s"].to_numpy()
        dx = (p["enc_x_mm"] - p["des_x_mm"]).to_numpy() * 1000.0
        dy = (p["enc_y_mm"] - p["des_y_mm"]).to_numpy() * 1000.0
        full = z < -2.0 * point_length_mm
        row: dict[str, float] = {"hole": h, "spindle_hz": f_sp, "alias_hz": fa}
        span = float(np.ptp(t[full])) if full.sum() > 2 else 0.0
        ok = math.isfinite(fa) and fa > 2.0 / max(span, 1e-9)
        if ok and full.sum() >= 20:
            row["runout_x_um"], row["runout_x_se_um"] = _lockin(t[full], dx[full], fa)
            row["runout_y_um"], row["runout_y_se_um"] = _lockin(t[full], dy[full], fa)
        else:
            row["runout_x_um"] = row["runout_y_um"] = math.nan
            row["runout_x_se_um"] = row["runout_y_se_um"] = math.nan
        row["runout_um"] = 0.5 * (row["runout_x_um"] + row["runout_y_um"])
        row["runout_se_um"] = 0.5 * math.hypot(row["runout_x_se_um"], row["runout_y_se_um"])
        # entry: baseline before contact from the full recording, then the bump
        c0 = int(p["cycle"].iloc[0])
        i0 = int(np.searchsorted(cyc, c0))
        nb = max(round(0.1 * fs), 1)
        bx = float(np.mean(dx_all[max(i0 - nb, 0):i0 + 1])) * 1000.0
        by = float(np.mean(dy_all[max(i0 - nb, 0):i0 + 1])) * 1000.0
        ent = (z <= 0.0) & (z >= -3.0 * point_length_mm)
        ex, ey = dx[ent] - bx, dy[ent] - by
        nrev = max(round(fs / fa), 1) if math.isfinite(fa) and fa > 0 else 1
        if ex.size >= nrev:
            kern = np.ones(nrev) / nrev
            ex = np.convolve(ex, kern, mode="valid")
            ey = np.convolve(ey, kern, mode="valid")
        if ex.size:
            k = int(np.argmax(np.hypot(ex, ey)))
            row["entry_deviation_x_um"], row["entry_deviation_y_um"] = float(ex[k]), float(ey[k])
        else:
            row["entry_deviation_x_um"] = row["entry_deviation_y_um"] = math.nan
        row["entry_deviation_um"] = math.hypot(row["entry_deviation_x_um"],
                                               row["entry_deviation_y_um"])
        row["entry_direction_rad"] = math.atan2(row["entry_deviation_y_um"],
                                                row["entry_deviation_x_um"])
        if machine is not None and ent.sum() > 10:
            fit = _entry_fit(machine.axis(axes[0]), machine.axis(axes[1]),
                             t[ent], -z[ent], dx[ent] - bx, dy[ent] - by,
                             point_length_mm=point_length_mm, alias_hz=fa, dt_s=1.0 / fs)
            row.update(fit)
        if machine is not None:
            ax_x, ax_y = machine.axis(axes[0]), machine.axis(axes[1])
            kx = float(feed_axis_dynamic_stiffness(ax_x, f_sp).stiffness_n_per_um[0])
            ky = float(feed_axis_dynamic_stiffness(ax_y, f_sp).stiffness_n_per_um[0])
            row["rotating_force_est_n"] = 0.5 * (row["runout_x_um"] * kx
                                                 + row["runout_y_um"] * ky)
            row["rotating_force_se_n"] = 0.5 * math.hypot(row["runout_x_se_um"] * kx,
                                                          row["runout_y_se_um"] * ky)
            if drill is not None:
                kt = drill.tip_stiffness_n_per_um
                row["tip_position_error_est_um"] = row["entry_force_est_n"] / kt
                row["tip_position_error_se_um"] = row.get("entry_force_se_n", math.nan) / kt
                row["tip_straightness_est_um"] = row["walk_force_est_n"] / (
                    drill.guided_stiffness_gain * kt)
                orbit = drill.radial_runout_um + row["rotating_force_est_n"] / (
                    drill.guided_stiffness_gain * kt)
                row["tip_orbit_radius_est_um"] = orbit
                row["hole_oversize_est_um"] = 2.0 * orbit
        rows.append(row)
    return pd.DataFrame(rows)


def _entry_fit(ax_x: FeedAxis, ax_y: FeedAxis, t: NDArray[np.float64],
               depth_mm: NDArray[np.float64], dx_um: NDArray[np.float64],
               dy_um: NDArray[np.float64], *, point_length_mm: float, alias_hz: float,
               dt_s: float) -> dict[str, float]:
    """Entry and walk forces from the entry window by fitting the axis' force responses.

    Force shapes over the depth u = clip(depth / L_point, 0, 1): the walk rises with the
    thrust (u), the chisel-edge skid is a bump 4 u (1 - u); each goes through the axis model
    (:func:`_axis_response_um_per_n`); regressors per axis: offset, the two responses and
    u cos / u sin at the spindle alias frequency (the rotating force rising with the thrust).
    Standard errors from the residual (white-noise covariance s^2 (A'A)^-1; the entry force's
    propagated to its magnitude to first order): ``entry_force_se_n``, ``walk_force_se_n``.
    """
    u = np.clip(depth_mm / point_length_mm, 0.0, 1.0)
    shapes = (u, 4.0 * u * (1.0 - u))
    w = 2.0 * math.pi * alias_hz if math.isfinite(alias_hz) else 0.0
    out: dict[str, float] = {}
    var: dict[str, float] = {}
    for tag, ax, d in (("x", ax_x, dx_um), ("y", ax_y, dy_um)):
        resp = [_axis_response_um_per_n(ax, g, dt_s) for g in shapes]
        cols = [np.ones_like(t), *resp]
        if w > 0:
            cols += [u * np.cos(w * t), u * np.sin(w * t)]
        a = np.column_stack(cols)
        coef, cov = _lstsq_cov(a, d)
        out[f"walk_force_est_{tag}_n"] = float(coef[1])
        out[f"entry_force_est_{tag}_n"] = float(coef[2])
        var[f"walk_{tag}"], var[f"entry_{tag}"] = float(cov[1, 1]), float(cov[2, 2])
    out["walk_force_est_n"] = math.hypot(out["walk_force_est_x_n"], out["walk_force_est_y_n"])
    out["entry_force_est_n"] = math.hypot(out["entry_force_est_x_n"],
                                          out["entry_force_est_y_n"])
    for kind in ("walk", "entry"):
        fx, fy = out[f"{kind}_force_est_x_n"], out[f"{kind}_force_est_y_n"]
        f = math.hypot(fx, fy)
        out[f"{kind}_force_se_n"] = math.sqrt(
            (fx * fx * var[f"{kind}_x"] + fy * fy * var[f"{kind}_y"]) / (f * f)) \
            if f > 0 else math.nan
    out["entry_force_direction_rad"] = math.atan2(out["entry_force_est_y_n"],
                                                  out["entry_force_est_x_n"])
    return out
