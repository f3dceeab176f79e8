"""Run the calibrated twin beside the machine: where does the machine depart from its twin?

:func:`compare_recording` drives the twin described by a machine file
(:mod:`cnctwin.machine.file`) with a recording's own setpoints and compares with what the
machine measured, per feed axis and for the spindle:

* **following error**: :class:`~cnctwin.servo.predict.AxisLoopModel` built from the machine
  file's loop data (Kv MD32200, FFW weight MD32610, jerk filter MD32402/32410, balancing
  MD32810/32800, dynamic response adaptation MD32910) is driven by ``DES_POS`` and predicts
  ``ENC_POS``; ``residual_ratio = rms(FE_meas - FE_pred) / rms(FE_meas)`` (thesis Figs. 3.2 and
  3.3 show the measured signals this overlays);
* **axis current**: the motor current the twin needs for the measured motion,
  ``I = (J_tot alpha + r (F_c sign v + b v)) / Kt`` with ``r`` the lead per radian; and the
  friction the recording shows on its constant-velocity runs against the machine file's
  (:func:`cnctwin.servo.identify_axis`), in units of their combined uncertainty;
* **spindle current** outside the cuts: ``I = (B n + tau_f + tau_s e^{-n/n_s} + J dOmega/dt)
  / Kt`` (thesis Eq. 3.1 without cutting torque).

An axis is ``flagged`` where the machine departs from its twin beyond what the calibration's
uncertainty allows: the residual ratio above its limit, or a friction or gain that moved by
more than ``k_sigma`` combined standard uncertainties (with a relative floor for what the
loop model does not describe).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cnctwin.analysis.filters import lowpass
from cnctwin.exceptions import IdentificationError, SignalNotFoundError
from cnctwin.machine import KV_UNIT_PER_S, FeedAxis, MachineFile
from cnctwin.recording import Recording
from cnctwin.servo import AxisIdentification, identify_axis, moving_axes
from cnctwin.servo._common import axis_data, derivative
from cnctwin.servo.identify import cut_cycles
from cnctwin.servo.predict import AxisLoopModel

__all__ = [
    "CURRENT_BAND_HZ",
    "AxisComparison",
    "MachineComparison",
    "SpindleComparison",
    "compare_recording",
    "loop_model_from_axis",
]

_JERK_TYPES = {0: "none", 1: "pt2", 2: "moving_average", 4: "double_moving_average"}

CURRENT_BAND_HZ = 50.0
"""Band of the axis-current comparison [Hz]: the motion's accelerations (jerk-limited, tens of
ms) lie below it; above it the measured current is the sensor's white noise."""


def loop_model_from_axis(axis: FeedAxis, *, cycle_time_s: float = 0.002) -> AxisLoopModel:
    """The position-loop twin of a machine-file axis.

    Parameters
    ----------
    axis : FeedAxis
        The axis' NC data.
    cycle_time_s : float, default 0.002
        Position-control cycle [s].

    Returns
    -------
    AxisLoopModel

    Notes
    -----
    DES_POS passes the jerk filter (MD32402/32410; active above one cycle; type 1 is two PT1
    stages of MD32410 / 2), the dynamic
    response adaptation (MD32910, a dead time) and the feedforward balancing: a dead time of
    MD32810 (speed FFW, mode 3) or MD32800 (torque FFW, mode 4), a PT1 of that time in modes 1
    and 2 (SINUMERIK 840D sl function manual K3/G2, "feedforward control"). The closed speed
    loop of the drive (DSC, 125 us) acts as one cycle's output hold plus a small lag that
    grows with the mechanical time ``J / Kp``: ``T_c + 0.06 J / Kp``, fitted to the loop
    identification on the simulated S120 drive (2.02-2.17 ms over Kp = 1.0-2.1 Nm s/rad).
    """
    dt = cycle_time_s
    jt = axis.jerk_time_s if axis.jerk_time_s > dt else 0.0
    jerk = _JERK_TYPES.get(axis.jerk_filter_type, "moving_average") if jt > 0 else "none"
    mode = axis.ffw_mode
    bal = axis.equiv_speedctrl_time_s if mode in (1, 3) else (
        axis.equiv_currctrl_time_s if mode in (2, 4) else 0.0)
    delay = axis.dyn_match_time_s + (bal if mode in (3, 4) else 0.0)
    pt1 = bal if mode in (1, 2) else 0.0
    pt1b = 0.0
    damping = 1.0
    if jerk == "pt2":
        # MD32402 = 1: two PT1 stages of MD32410 / 2 (low-frequency delay MD32410)
        if pt1 == 0.0:
            jerk, pt1, pt1b = "none", 0.5 * jt, 0.5 * jt
        else:
            jt = 0.5 * jt  # PT2 of T/2, damping 1, beside the PT1 balancing
    return AxisLoopModel(
        kv_1_s=axis.kv_m_min_per_mm * KV_UNIT_PER_S,
        ffw_weight=axis.ffw_weight if mode != 0 else 0.0,
        jerk_type=jerk, jerk_time_s=jt, jerk_time2_s=jt, jerk_damping=damping,
        setpoint_delay_s=delay, setpoint_pt1_s=pt1, setpoint_pt1b_s=pt1b, ffw_delay_s=0.5 * dt,
        speed_delay_cycles=1.0 + 0.06 * axis.total_inertia_kgm2
        / max(axis.speed_kp_nm_s_per_rad, 1e-9) / dt,
        speed_time_cycles=0.0,
        cycle_time_s=dt)


@dataclass
class AxisComparison:
    """One feed axis: twin against machine.

    Attributes
    ----------
    axis : str
    residual_ratio : float
        rms(FE_meas - FE_pred) / rms(FE_meas) over the moving cycles [-].
    current_residual_ratio : float or None
        rms(I_meas - I_pred) / rms(I_meas) over the moving cycles outside the cuts, both below
        :data:`CURRENT_BAND_HZ`, I_pred from the twin's predicted motion [-] (None without
        CURRENT or with too few such cycles).
    flagged : bool
        The machine departs from its twin beyond the calibrated uncertainty.
    reasons : list of str
        Why it is flagged (each with the numbers).
    parameters : dict
        Parameter -> ``{"twin", "machine", "z"}``: the machine file's value, the value this
        recording shows and their distance in combined standard uncertainties.
    spans : list of dict
        Stretches where the following-error residual exceeds its limit (cycles and seconds).
    series : dict
        Per-cycle arrays for the figures (``time_s``, ``fe_meas``, ``fe_pred``, ``i_meas``,
        ``i_pred``).
    """

    axis: str
    residual_ratio: float
    current_residual_ratio: float | None
    flagged: bool
    reasons: list[str] = field(default_factory=list)
    parameters: dict[str, dict[str, float]] = field(default_factory=dict)
    spans: list[dict[str, float]] = field(default_factory=list)
    series: dict[str, np.ndarray] = field(default_factory=dict, repr=False)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able summary (without the series)."""
        return {"residual_ratio": self.residual_ratio,
                "current_residual_ratio": self.current_residual_ratio,
                "flagged": self.flagged, "reasons": self.reasons,
                "parameters": self.parameters, "spans": self.spans}


@dataclass
class SpindleComparison:
    """The spindle outside the cuts: twin current against measured.

    Attributes
    ----------
    residual_ratio : float
        rms(I_meas - I_pred) / rms(I_meas) over the steady turning cycles outside cuts [-].
    mean_error_pct : float
        Mean relative current error on those cycles [%].
    flagged : bool
    reasons : list of str
    """

    residual_ratio: float
    mean_error_pct: float
    flagged: bool
    reasons: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able summary."""
        return {"residual_ratio": self.residual_ratio, "mean_error_pct": self.mean_error_pct,
                "flagged": self.flagged, "reasons": self.reasons}


@dataclass
class MachineComparison:
    """:func:`compare_recording` result.

    Attributes
    ----------
    axes : dict
        Axis -> :class:`AxisComparison`.
    spindle : SpindleComparison or None
    skipped : dict
        Axis -> why it was not compared.
    limits : dict
        The thresholds used.
    """

    axes: dict[str, AxisComparison]
    spindle: SpindleComparison | None
    skipped: dict[str, str]
    limits: dict[str, float]

    def to_dict(self) -> dict[str, Any]:
        """The ``compare.json`` document."""
        return {"axes": {k: v.to_dict() for k, v in self.axes.items()},
                "spindle": self.spindle.to_dict() if self.spindle is not None else None,
                "skipped": self.skipped, "limits": self.limits,
                "flagged": sorted([k for k, v in self.axes.items() if v.flagged]
                                  + (["spindle"] if self.spindle and self.spindle.flagged
                                     else []))}


def _unc(mf: MachineFile, key: str) -> float:
    rec = mf.record(key)
    return float(rec.uncertainty) if rec is not None and rec.uncertainty is not None else 0.0


def _spans(bad: np.ndarray, t: np.ndarray, cycles: np.ndarray, resid: np.ndarray,
           min_len: int) -> list[dict[str, float]]:
    m = np.concatenate([[False], bad, [False]]).astype(np.int8)
    d = np.diff(m)
    out = []
    for a, b in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=True):
        if b - a < min_len:
            continue
        r = resid[a:b]
        out.append({"start_cycle": int(cycles[a]), "end_cycle": int(cycles[b - 1]),
                    "start_s": float(t[a]), "end_s": float(t[b - 1]),
                    "rms_residual": float(np.sqrt(np.nanmean(r * r)))})
    return out


def _compare_axis(rec: Recording, mf: MachineFile, name: str, *, residual_limit: float,
                  k_sigma: float, rel_floor: float, n_bootstrap: int,
                  cuts: tuple[np.ndarray | None, str], parameters: bool = True
                  ) -> AxisComparison:
    ax = mf.machine.axis(name)
    dt = mf.machine.cycle_time_s
    d = axis_data(rec, name)
    des, enc = d.signals["DES_POS"], d.signals["ENC_POS"]
    model = loop_model_from_axis(ax, cycle_time_s=dt)
    pred = np.full(des.shape, np.nan)
    for s in d.segments:
        ok = np.flatnonzero(np.isfinite(enc[s]) & np.isfinite(des[s]))
        if ok.size == 0:
            continue
        a = s.start + int(ok[0])
        # a run of finite setpoints from the first finite actual position on
        bad = np.flatnonzero(~np.isfinite(des[a:s.stop]))
        b = a + int(bad[0]) if bad.size else s.stop
        if b - a < 3:
            continue
        pred[a:b] = model.predict(des[a:b], enc_start=float(enc[a])).enc_pos
    fe_meas = des - enc
    fe_pred = des - pred
    v = derivative(des, d.segments, dt, kind="central")
    moving = np.isfinite(v) & (np.abs(v) > 1e-6) & np.isfinite(fe_pred)
    if moving.sum() < 10:
        raise IdentificationError(f"{name} does not move in the recording")
    res = fe_meas - fe_pred
    rms_fe = float(np.sqrt(np.mean(fe_meas[moving] ** 2)))
    ratio = float(np.sqrt(np.mean(res[moving] ** 2)) / rms_fe) if rms_fe > 0 else float("nan")
    reasons: list[str] = []
    if not ratio <= residual_limit:
        unknown = [k for k in ("kv_m_min_per_mm", "ffw_weight", "jerk_time_s",
                               "equiv_speedctrl_time_s")
                   if not mf.is_identified(f"axes.{name}.{k}")]
        reasons.append(f"following-error residual ratio {ratio:.3f} > {residual_limit:g}"
                       + (f" (not identified in the machine file, defaults used: "
                          f"{', '.join(unknown)})" if unknown else ""))
    # spans: 0.2 s rolling rms of the residual beyond the limit share of the measured FE
    w = max(1, round(0.2 / dt))
    kern = np.ones(w) / w
    r2 = np.convolve(np.where(moving, res, 0.0) ** 2, kern, mode="same")
    f2 = np.convolve(np.where(moving, fe_meas, 0.0) ** 2, kern, mode="same")
    floor = (10.0 * ax.encoder_resolution) ** 2
    bad = moving & (r2 > residual_limit**2 * np.maximum(f2, floor))
    t = rec.time_s
    spans = _spans(bad, t, rec.cycles, res, min_len=w)
    # currents from the measured motion
    i_pred = None
    cur_ratio: float | None = None
    i_meas = d.signals.get("CURRENT")
    if i_meas is not None:
        # the twin's current for the twin's motion: the predicted position differentiated
        # (the measured ENC_POS twice differentiated turns 0.15 um of measuring noise into
        # amps of acceleration current), compared where the tool does not cut (the process
        # force is not in the axis model) and below CURRENT_BAND_HZ on both sides (the
        # current's white measuring noise above is not the twin's to explain)
        v_pred = derivative(pred, d.segments, dt, kind="central")
        acc = derivative(v_pred, d.segments, dt, kind="central")
        r = ax.load_per_motor_rad  # mm (deg) per motor rad
        alpha = acc / r
        force = ax.coulomb_n * np.tanh(v_pred / ax.friction_smoothing_mm_s) \
            + ax.viscous_n_per_mm_s * v_pred
        i_pred = (ax.total_inertia_kgm2 * alpha + ax.motor_torque_per_load_force * force) \
            / ax.kt_nm_per_a
        cut = cuts[0]
        ok = moving & np.isfinite(i_pred) & np.isfinite(i_meas)
        if cut is not None:
            ok &= ~cut
        if ok.sum() > 30:
            fs = 1.0 / dt
            band = min(CURRENT_BAND_HZ, 0.4 * fs)
            i_m = lowpass(np.where(np.isfinite(i_meas), i_meas, 0.0), band, fs_hz=fs, order=2)
            i_p = lowpass(np.where(np.isfinite(i_pred), i_pred, 0.0), band, fs_hz=fs, order=2)
            rms_i = float(np.sqrt(np.mean(i_m[ok] ** 2)))
            if rms_i > 0:
                cur_ratio = float(np.sqrt(np.mean((i_m[ok] - i_p[ok]) ** 2)) / rms_i)
    # parameters the recording shows against the twin's
    params: dict[str, dict[str, float]] = {}
    ident: AxisIdentification | None = None
    if parameters:
        try:
            ident = identify_axis(rec, name, n_bootstrap=n_bootstrap,
                                  spindle=mf.machine.spindle_name, cuts=cuts)
        except IdentificationError:
            ident = None
    if ident is not None:
        per_force = ax.motor_torque_per_load_force
        checks = [("kv_m_min_per_mm", "kv_m_min_mm", 1.0)]
        for stem, key in (("coulomb", "coulomb_n"), ("viscous", "viscous_n_per_mm_s")):
            for code in ("torque", "current"):
                e = ident.params.get(f"{stem}_{code}")
                if e is None:
                    continue
                unit = e.unit.split("/")[0].strip()
                f = 1.0 if unit == ("Nm" if ax.rotary else "N") else (
                    1.0 / per_force if unit == "Nm" else ax.kt_nm_per_a / per_force)
                checks.append((key, f"{stem}_{code}", f))
                break
        for key, pname, f in checks:
            e = ident.params.get(pname)
            if e is None:
                continue
            twin = float(getattr(ax, key))
            meas = e.value * f
            se = e.stderr * f if e.stderr == e.stderr else 0.0
            u = math.sqrt(_unc(mf, f"axes.{name}.{key}") ** 2 + se**2
                          + (rel_floor * abs(twin)) ** 2)
            z = abs(meas - twin) / u if u > 0 else float("inf")
            params[key] = {"twin": twin, "machine": meas, "z": z}
            if z > k_sigma:
                reasons.append(f"{key}: machine {meas:.5g}, twin {twin:.5g} "
                               f"({z:.1f} combined standard uncertainties)")
    series = {"time_s": t, "fe_meas": fe_meas, "fe_pred": fe_pred}
    if i_meas is not None and i_pred is not None:
        series.update(i_meas=i_meas, i_pred=i_pred)
    return AxisComparison(name, ratio, cur_ratio, bool(reasons), reasons, params, spans,
                          series)


def _compare_spindle(rec: Recording, mf: MachineFile, *, rel_limit: float
                     ) -> SpindleComparison | None:
    from cnctwin.analysis.segments import speed_plateaus, spindle_speed_rpm

    sp = mf.machine.spindle_name
    if not rec.has("CURRENT", sp):
        return None
    try:
        plateaus = speed_plateaus(rec, spindle=sp)
    except SignalNotFoundError:  # no spindle speed: nothing to compare
        return None
    if plateaus.empty:
        return None
    s = mf.machine.spindle
    speed, _ = spindle_speed_rpm(rec, sp)
    cur = np.abs(rec.signal(f"CURRENT|{sp}").to_numpy(dtype=np.float64))
    keep = np.zeros(cur.size, dtype=bool)
    cyc = rec.cycles
    for _, p in plateaus.iterrows():
        a = int(np.searchsorted(cyc, int(p["start_cycle"])))
        b = int(np.searchsorted(cyc, int(p["end_cycle"]), side="right"))
        keep[a:b] = abs(p["speed_rpm"]) > 50.0
    # no feed motion, no cut: drop every cycle where a feed axis moves (and 0.5 s after)
    hold = round(0.5 * rec.fs_hz)
    for name in mf.machine.axis_names:
        if not rec.has("DES_POS", name):
            continue
        x = rec.signal("DES_POS", name).to_numpy(dtype=np.float64)
        mv = np.zeros(x.size, dtype=bool)
        mv[1:] = np.abs(np.diff(x)) > 1e-9
        if mv.any():
            keep &= ~(np.convolve(mv.astype(np.float64), np.ones(hold + 1))[: x.size] > 0)
    rec_b = mf.record("spindle.viscous_friction_nm_per_rpm")
    if rec_b is not None and rec_b.valid_range is not None:
        lo, hi = rec_b.valid_range
        inside = (np.abs(speed) >= lo) & (np.abs(speed) <= hi)
        if keep.any() and not (keep & inside).any():
            return SpindleComparison(float("nan"), float("nan"), False, [
                f"spindle speeds {np.nanmin(np.abs(speed[keep])):.0f}-"
                f"{np.nanmax(np.abs(speed[keep])):.0f} rpm lie outside the calibrated friction "
                f"range {lo:.0f}-{hi:.0f} rpm: not compared (no extrapolation)"])
        keep &= inside
    if keep.sum() < 10:
        return SpindleComparison(float("nan"), float("nan"), False, [
            "no steady turning without feed motion in the calibrated speed range: the "
            "spindle's air current was not compared"])
    n = np.abs(speed)
    tau = (s.viscous_friction_nm_per_rpm * n + s.coulomb_friction_nm
           + s.stribeck_torque_nm * np.exp(-n / s.stribeck_speed_rpm))
    i_pred = tau / s.kt_nm_per_a
    err = cur[keep] - i_pred[keep]
    ratio = float(np.sqrt(np.mean(err**2)) / np.sqrt(np.mean(cur[keep] ** 2)))
    mean_pct = float(100.0 * np.mean(err) / np.mean(cur[keep]))
    reasons = []
    if abs(mean_pct) > 100.0 * rel_limit:
        reasons.append(f"air current {mean_pct:+.1f} % from the twin's friction "
                       f"(limit {100.0 * rel_limit:g} %)")
    return SpindleComparison(ratio, mean_pct, bool(reasons), reasons)


def compare_recording(
    rec: Recording,
    machine_file: MachineFile,
    *,
    axes: Sequence[str] | None = None,
    residual_limit: float = 0.2,
    k_sigma: float = 3.0,
    rel_floor: float = 0.05,
    spindle_limit: float = 0.05,
    n_bootstrap: int = 100,
    parameters: bool = True,
) -> MachineComparison:
    """Compare a recording with the twin of the machine file.

    Parameters
    ----------
    rec : Recording
        A recording of the machine (DES_POS and ENC_POS per axis; CURRENT for the currents).
    machine_file : MachineFile
        The calibrated machine.
    axes : sequence of str, optional
        Axes to compare; default every axis of the machine that moves in the recording.
    residual_limit : float, default 0.2
        Largest following-error residual ratio of a twin that holds.
    k_sigma : float, default 3
        Departure threshold in combined standard uncertainties.
    rel_floor : float, default 0.05
        Relative uncertainty floor of a parameter (what the loop model and one recording do
        not resolve: a friction that differs by direction, the Stribeck zone).
    spindle_limit : float, default 0.05
        Largest mean relative departure of the spindle's air current.
    n_bootstrap : int, default 100
        Bootstrap resamples of the parameter check.
    parameters : bool, default True
        Also identify Kv and friction on the recording and compare them with the file's
        (the costly part: one loop identification per axis).

    Returns
    -------
    MachineComparison
    """
    m = machine_file.machine
    moving = [a for a in moving_axes(rec) if a != m.spindle_name]
    wanted = list(axes) if axes else [a for a in moving if a in m.axis_names]
    out: dict[str, AxisComparison] = {}
    skipped: dict[str, str] = {}
    for a in moving:
        if a not in m.axis_names:
            skipped[a] = "not in the machine file"
    cuts = cut_cycles(rec, spindle=m.spindle_name)  # the recording's, for every axis
    for a in wanted:
        if a not in m.axis_names:
            skipped[a] = "not in the machine file"
            continue
        if a not in moving:
            skipped[a] = "does not move in the recording"
            continue
        try:
            out[a] = _compare_axis(rec, machine_file, a, residual_limit=residual_limit,
                                   k_sigma=k_sigma, rel_floor=rel_floor,
                                   n_bootstrap=n_bootstrap, cuts=cuts, parameters=parameters)
        except IdentificationError as exc:
            skipped[a] = str(exc)
    spindle = _compare_spindle(rec, machine_file, rel_limit=spindle_limit)
    return MachineComparison(out, spindle, skipped, {
        "residual_limit": residual_limit, "k_sigma": k_sigma, "rel_floor": rel_floor,
        "spindle_limit": spindle_limit})
