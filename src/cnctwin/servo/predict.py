"""The identified loop as a twin: predict ENC_POS and the error signals from DES_POS; drift.

:class:`AxisLoopModel` simulates the identified structure (thesis Fig. 3.1)::

    DES_POS -> jerk filter -> delay -> PT1 -> CTRL_POS
    u = Kv (CTRL_POS - ENC_POS) + w v_ffw         v_ffw = delay(d(jerk-filtered DES)/dt)
    v = g-free speed loop: PT1_T(delay_tau(u)) (tau includes the one-cycle output hold)
    ENC_POS[k] = ENC_POS[k-1] + dt * mean speed over cycle k-1..k

:class:`DriftMonitor` keeps per-axis identifications over recordings and flags parameters that
move beyond their combined uncertainty.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from cnctwin.exceptions import IdentificationError
from cnctwin.recording import Recording
from cnctwin.servo._common import FloatArray, axis_data, delay, derivative
from cnctwin.servo.identify import AxisIdentification, _jerk, apply_setpoint_chain

__all__ = [
    "AxisLoopModel",
    "DriftAlarm",
    "DriftMonitor",
    "Prediction",
    "prediction_residual",
]


@dataclass(frozen=True)
class Prediction:
    """Signals predicted by :meth:`AxisLoopModel.predict` (one value per cycle).

    Attributes
    ----------
    ctrl_pos : numpy.ndarray
        Controller input position [mm or deg].
    enc_pos : numpy.ndarray
        Actual position [mm or deg].
    following_error : numpy.ndarray
        DES_POS - ENC_POS [mm or deg].
    ctrl_diff2 : numpy.ndarray
        CTRL_POS - ENC_POS [mm or deg].
    speed_command : numpy.ndarray
        Velocity command Kv e + w v_ffw, referred to the actual speed [unit/s].
    vel_ffw : numpy.ndarray
        Velocity feedforward w v_ffw [unit/s].
    """

    ctrl_pos: FloatArray
    enc_pos: FloatArray
    following_error: FloatArray
    ctrl_diff2: FloatArray
    speed_command: FloatArray
    vel_ffw: FloatArray


@dataclass(frozen=True)
class AxisLoopModel:
    """The identified position loop of one axis.

    Parameters
    ----------
    kv_1_s : float
        Position-loop gain [1/s].
    ffw_weight : float
        Speed-feedforward weight [-] (0 = off).
    jerk_type : str
        Jerk-filter model (``cnctwin.servo.JERK_FILTER_TYPES``).
    jerk_time_s, jerk_time2_s, jerk_damping : float
        Jerk-filter parameters [s], [s], [-].
    setpoint_delay_s, setpoint_pt1_s, setpoint_pt1b_s : float
        Delay and two PT1s after the jerk filter (dynamic response adaptation, balancing) [s].
    ffw_delay_s : float
        Delay of the feedforward behind d(jerk-filtered DES_POS)/dt [s].
    speed_delay_cycles, speed_time_cycles : float
        Speed-loop model (delay incl. the output hold; PT1) [cycles].
    cycle_time_s : float, default 0.002
        Position-control cycle [s].
    """

    kv_1_s: float
    ffw_weight: float = 0.0
    jerk_type: str = "none"
    jerk_time_s: float = 0.0
    jerk_time2_s: float = 0.0
    jerk_damping: float = 1.0
    setpoint_delay_s: float = 0.0
    setpoint_pt1_s: float = 0.0
    setpoint_pt1b_s: float = 0.0
    ffw_delay_s: float = 0.0
    speed_delay_cycles: float = 1.0
    speed_time_cycles: float = 0.0
    cycle_time_s: float = 0.002

    @classmethod
    def from_identification(cls, ident: AxisIdentification) -> AxisLoopModel:
        """Build the model from :func:`~cnctwin.servo.identify_axis` output.

        Raises
        ------
        IdentificationError
            If Kv or the speed loop was not identified (the reason is in the message).
        """
        if "kv_1_s" not in ident.params:
            raise IdentificationError(
                f"{ident.axis}: no loop model without Kv: {ident.not_identified.get('kv_1_s')}")
        dt = ident.cycle_time_s
        sp = ident.setpoint
        sl = ident.speed_loop
        w = ident.params["ffw_weight"].value if "ffw_weight" in ident.params else 0.0
        kw: dict[str, Any] = {}
        if sp is not None:
            kw.update(jerk_type=sp.jerk_type, jerk_time_s=sp.jerk_time_s,
                      jerk_time2_s=sp.jerk_time2_s,
                      jerk_damping=sp.jerk_damping if sp.jerk_damping == sp.jerk_damping else 1.0,
                      setpoint_delay_s=sp.delay_s, setpoint_pt1_s=sp.pt1_s,
                      setpoint_pt1b_s=sp.pt1b_s)
        elif "apparent_ffw_weight" in ident.params:
            # no CTRL_POS: assume w = 1 (MD32610 default) and put the lag into a pure delay
            wa = ident.params["apparent_ffw_weight"].value
            kv = ident.params["kv_1_s"].value
            w = 1.0
            kw.update(setpoint_delay_s=max((1.0 - wa) / kv, 0.0),
                      ffw_delay_s=max((1.0 - wa) / kv, 0.0))
        if sl is not None:
            kw.update(speed_delay_cycles=sl.model_delay_cycles,
                      speed_time_cycles=sl.model_time_cycles)
        if "ffw_delay_s" in ident.params:
            kw["ffw_delay_s"] = ident.params["ffw_delay_s"].value
        return cls(kv_1_s=ident.params["kv_1_s"].value, ffw_weight=w, cycle_time_s=dt, **kw)

    def _jerk_params(self) -> FloatArray:
        dt = self.cycle_time_s
        second = (self.jerk_time2_s / dt if self.jerk_type == "double_moving_average"
                  else self.jerk_damping)
        return np.array([self.jerk_time_s / dt, second])

    def predict(self, des_pos_mm: ArrayLike, *, enc_start: float | None = None) -> Prediction:
        """Predict the loop signals from a contiguous DES_POS sequence.

        Parameters
        ----------
        des_pos_mm : array-like
            Position setpoint per cycle [mm or deg]; one contiguous run (no counter gaps).
        enc_start : float, optional
            Initial actual position; default ``des_pos_mm[0]`` (axis at rest).

        Returns
        -------
        Prediction

        Notes
        -----
        Discrete loop per cycle ``k``: ``u[k] = Kv (ctrl[k] - enc[k]) + w vff[k]``;
        ``z = PT1(delay(u))``; ``enc[k+1] = enc[k] + dt (z[k] + z[k+1]) / 2``, with the same
        filter discretizations used in identification (linear interpolation for fractional
        delays, ``z[k] = a z[k-1] + (1-a) x[k]``, ``a = T/(T+1)``).
        """
        des = np.asarray(des_pos_mm, dtype=np.float64)
        n = des.size
        dt = self.cycle_time_s
        ctrl = apply_setpoint_chain(
            des, jerk_type=self.jerk_type, jerk_cycles=tuple(self._jerk_params()),
            delay_cycles=self.setpoint_delay_s / dt, pt1_cycles=self.setpoint_pt1_s / dt,
            pt1b_cycles=self.setpoint_pt1b_s / dt)
        jf = _jerk(des, self.jerk_type, self._jerk_params())
        v_jf = derivative(jf, [slice(0, n)], dt, kind="central")
        v_jf[0] = 0.0
        if n > 1:
            v_jf[-1] = v_jf[-2]
        vff = self.ffw_weight * delay(v_jf, self.ffw_delay_s / dt)
        tau = max(self.speed_delay_cycles, 0.0)
        t_sp = self.speed_time_cycles
        a = t_sp / (t_sp + 1.0) if t_sp > 1e-9 else 0.0  # backward-Euler pole (as pt1())
        enc = np.empty(n)
        u = np.zeros(n)
        z = np.zeros(n)
        enc[0] = des[0] if enc_start is None else float(enc_start)
        kv = self.kv_1_s
        i_tau = math.floor(tau)
        frac = tau - i_tau
        half = 0.5 * dt
        for k in range(n):
            u[k] = kv * (ctrl[k] - enc[k]) + vff[k]
            if k + 1 >= n:
                break
            # delayed input at k+1: u at time k+1-tau, linear interpolation (0 before start)
            j = k + 1 - i_tau
            if i_tau >= 1:
                u_hi = u[j] if j >= 0 else 0.0
                u_lo = u[j - 1] if j - 1 >= 0 else 0.0
                ud = (1.0 - frac) * u_hi + frac * u_lo
                z[k + 1] = a * z[k] + (1.0 - a) * ud
            else:
                # tau < 1: u[k+1] depends on enc[k+1]; the step is linear, solve it
                alpha = 1.0 - frac  # weight of u[k+1]
                beta = (1.0 - a) * alpha
                base = a * z[k] + (1.0 - a) * frac * u[k]
                rhs = base + beta * (kv * (ctrl[k + 1] - enc[k] - half * z[k]) + vff[k + 1])
                z[k + 1] = rhs / (1.0 + beta * kv * half)
            enc[k + 1] = enc[k] + half * (z[k] + z[k + 1])
        return Prediction(ctrl, enc, des - enc, ctrl - enc, u, vff)


def prediction_residual(
    model: AxisLoopModel, rec: Recording, axis: str
) -> tuple[float, float, FloatArray]:
    """Drive the model with the recorded DES_POS and compare with the recorded ENC_POS.

    Each contiguous run is predicted from its own start (actual position taken from the
    recording at the run start).

    Parameters
    ----------
    model : AxisLoopModel
        The identified loop (:meth:`AxisLoopModel.from_identification`).
    rec : Recording
        A recording with ``DES_POS|<axis>`` and ``ENC_POS|<axis>``.
    axis : str
        Axis name.

    Returns
    -------
    rms : float
        RMS of ENC_POS - predicted ENC_POS [mm or deg].
    following_error_rms : float
        RMS of the recorded following error, for scale [mm or deg].
    residual : numpy.ndarray
        Per-cycle residual (NaN where not predicted).
    """
    d = axis_data(rec, axis)
    if not (d.has("DES_POS") and d.has("ENC_POS")):
        raise IdentificationError(f"prediction needs DES_POS|{axis} and ENC_POS|{axis}")
    des, enc = d.signals["DES_POS"], d.signals["ENC_POS"]
    res = np.full(des.shape, np.nan)
    for s in d.segments:
        if s.stop - s.start < 3:
            continue
        p = model.predict(des[s], enc_start=float(enc[s.start]))
        res[s] = enc[s] - p.enc_pos
    fe = des - enc
    r = res[np.isfinite(res)]
    return (float(np.sqrt(np.mean(r * r))), float(np.sqrt(np.nanmean(fe * fe))), res)


@dataclass(frozen=True)
class DriftAlarm:
    """A parameter that moved beyond ``k_sigma`` combined standard errors.

    Attributes
    ----------
    axis, parameter : str
    previous, current : float
        Values of the previous and the current recording [unit].
    change : float
        current - previous [unit].
    combined_se : float
        sqrt(se_prev^2 + se_cur^2 + floor^2) [unit].
    z : float
        |change| / combined_se [-].
    previous_label, current_label : str
        Labels of the two recordings.
    """

    axis: str
    parameter: str
    previous: float
    current: float
    change: float
    combined_se: float
    z: float
    previous_label: str
    current_label: str


@dataclass
class DriftMonitor:
    """Keeps per-axis identified parameters over recordings; flags significant moves.

    Parameters
    ----------
    k_sigma : float, default 3
        Alarm threshold in combined standard errors.
    rel_floor : float, default 0.01
        Relative uncertainty floor added in quadrature (identification on noise-free data has
        near-zero standard errors; real parameters are not constant to better than this).
    parameters : tuple of str
        Parameters watched (gain, friction, reversal error by default).

    Examples
    --------
    >>> from cnctwin.servo.identify import AxisIdentification, Estimate
    >>> mon = DriftMonitor()
    >>> a = AxisIdentification("X1", params={"kv_1_s": Estimate(40.0, 0.2, "1/s", "")})
    >>> b = AxisIdentification("X1", params={"kv_1_s": Estimate(35.0, 0.2, "1/s", "")})
    >>> mon.update(a, label="mon"), len(mon.update(b, label="tue"))
    ([], 1)
    """

    k_sigma: float = 3.0
    rel_floor: float = 0.01
    parameters: tuple[str, ...] = (
        "kv_1_s", "ffw_weight", "apparent_ffw_weight", "coulomb_current", "viscous_current",
        "coulomb_torque", "viscous_torque", "reversal_error", "speed_loop_equiv_time_s",
        "jerk_time_s",
    )
    history: dict[str, list[tuple[str, AxisIdentification]]] = field(default_factory=dict)

    def update(self, ident: AxisIdentification, *, label: str = "") -> list[DriftAlarm]:
        """Add one identification; return alarms against the previous one of the same axis."""
        hist = self.history.setdefault(ident.axis, [])
        alarms: list[DriftAlarm] = []
        if hist:
            prev_label, prev = hist[-1]
            for name in self.parameters:
                if name not in prev.params or name not in ident.params:
                    continue
                p0, p1 = prev.params[name], ident.params[name]
                se0 = p0.stderr if np.isfinite(p0.stderr) else 0.0
                se1 = p1.stderr if np.isfinite(p1.stderr) else 0.0
                floor = self.rel_floor * max(abs(p0.value), abs(p1.value))
                comb = math.sqrt(se0**2 + se1**2 + floor**2)
                change = p1.value - p0.value
                z = abs(change) / comb if comb > 0 else (math.inf if change else 0.0)
                if z > self.k_sigma:
                    alarms.append(DriftAlarm(ident.axis, name, p0.value, p1.value, change, comb,
                                             z, prev_label, label))
        hist.append((label or str(len(hist)), ident))
        return alarms

    def series(self, axis: str, parameter: str) -> list[tuple[str, float, float]]:
        """(label, value, stderr) of one parameter over the recordings of an axis."""
        return [(lab, i.params[parameter].value, i.params[parameter].stderr)
                for lab, i in self.history.get(axis, []) if parameter in i.params]
