"""Spindle drive model: PMSM motor spindle with speed/current control, friction and heating.

Layers (pvlib style):

* :class:`SpindleMotor`: the description (every parameter with unit, default and source).
* :func:`simulate_spindle`: integrates the drive at the 125 us controller cycle and returns one
  sample per 2 ms position-control cycle (what the edge device records) as a
  :class:`SpindleTrace`; ``trace.state`` continues a simulation chunk by chunk.

Current convention: every current the drive reports (``CURRENT``, r0068, r0078) is in
**A rms**, as in the SINAMICS parameter list. Internally the dq model uses the
amplitude-invariant Park transform (peak values), so with ``p`` pole pairs

    Te = 1.5 p (psi_pm + (Ld - Lq) id) iq          (id, iq peak)
    Kt = Te / Iq_rms = 1.5 * sqrt(2) * p * psi_pm   (at id = 0)

and ``SpindleMotor.flux_linkage_vs`` is derived from ``kt_nm_per_a`` with that relation.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from cnctwin.exceptions import ConfigError
from cnctwin.machine.description import SpindleMotor

__all__ = ["SpindleMotor", "SpindleState", "SpindleTrace", "simulate_spindle"]


# ----------------------------------------------------------------------------- state and trace
_N_STATE = 18
# state vector layout (float64):
_S_OMEGA, _S_THETA, _S_INTEG, _S_ID, _S_IQ, _S_TSTATOR, _S_TROTOR = 0, 1, 2, 3, 4, 5, 6
_S_LF_SPEED, _S_LF_IABS, _S_LF_IQ, _S_LF_UTIL, _S_PREV_POSCMD, _S_HAVE_POSCMD, _S_CYCLE = (
    7,
    8,
    9,
    10,
    11,
    12,
    13,
)
# position control: offset of the setpoint from the programmed angle [deg] and its rate
# [deg/s] while the SPOS move to the nearest whole turn runs
_S_POS_OFFSET, _S_POS_OFFSET_RATE = 14, 15


@dataclass(frozen=True)
class SpindleState:
    """Continuation state of :func:`simulate_spindle` (pass ``trace.state`` to the next chunk).

    Attributes
    ----------
    vector : numpy.ndarray
        Internal state: speed [rad/s], angle [rad], speed-PI integrator [Nm], id, iq [A peak],
        stator and rotor temperature [degC], the four LF smoothing filters, the previous
        position setpoint [deg] and its validity flag, the number of cycles simulated, and
        the offset of the position setpoint from the programmed angle and its rate (the SPOS
        move when position control takes over).
    """

    vector: NDArray[np.float64]

    @classmethod
    def initial(
        cls,
        motor: SpindleMotor,
        *,
        speed_rpm: float = 0.0,
        stator_temperature_c: float | None = None,
        rotor_temperature_c: float | None = None,
    ) -> SpindleState:
        """A spindle at rest (or turning at ``speed_rpm``) in thermal equilibrium.

        Parameters
        ----------
        motor : SpindleMotor
            The motor.
        speed_rpm : float, default 0
            Initial speed [rpm].
        stator_temperature_c, rotor_temperature_c : float, optional
            Initial temperatures [degC]; default ``motor.ambient_temperature_c``.
        """
        v = np.zeros(_N_STATE)
        v[_S_OMEGA] = speed_rpm * _RPM_TO_RAD_S
        ta = motor.ambient_temperature_c
        v[_S_TSTATOR] = ta if stator_temperature_c is None else stator_temperature_c
        v[_S_TROTOR] = ta if rotor_temperature_c is None else rotor_temperature_c
        v[_S_LF_SPEED] = speed_rpm
        return cls(v)

    @property
    def speed_rpm(self) -> float:
        """Actual speed [rpm]."""
        return float(self.vector[_S_OMEGA] / _RPM_TO_RAD_S)

    @property
    def stator_temperature_c(self) -> float:
        """Winding temperature (r0035) [degC]."""
        return float(self.vector[_S_TSTATOR])

    @property
    def rotor_temperature_c(self) -> float:
        """Rotor / bearing temperature [degC]."""
        return float(self.vector[_S_TROTOR])

    @property
    def cycles(self) -> int:
        """Cycles simulated so far."""
        return int(self.vector[_S_CYCLE])


_TRACE_FIELDS: tuple[str, ...] = (
    "speed_rpm",
    "position_deg",
    "current_a",
    "id_a",
    "current_abs_a",
    "torque_setpoint_nm",
    "torque_nm",
    "load_pct",
    "power_w",
    "friction_nm",
    "speed_smoothed_rpm",
    "current_abs_smoothed_a",
    "iq_smoothed_a",
    "torque_utilization_pct",
    "motor_temperature_c",
    "rotor_temperature_c",
    "kt_nm_per_a",
    "voltage_v",
)


@dataclass(frozen=True)
class SpindleTrace:
    """Spindle drive values, one per 2 ms position-control cycle.

    Attributes
    ----------
    speed_rpm : numpy.ndarray
        Actual speed (measured, with noise) [rpm].
    position_deg : numpy.ndarray
        Spindle angle, unwrapped (ENC_POS of the spindle before modulo 360) [deg].
    current_a : numpy.ndarray
        Actual torque-generating current Iq incl. stator-frequency ripple and measurement
        noise, sampled (not averaged) at the end of each cycle: HF ``CURRENT`` [A rms].
    id_a : numpy.ndarray
        Actual field-generating current Id (negative in field weakening) [A rms].
    current_abs_a : numpy.ndarray
        sqrt(Id^2 + Iq^2) [A rms].
    torque_setpoint_nm : numpy.ndarray
        Speed-controller output, HF ``TORQUE`` [Nm].
    torque_nm : numpy.ndarray
        True electromagnetic torque [Nm] (truth; not recorded by the drive).
    load_pct : numpy.ndarray
        |torque setpoint| / rated torque, HF ``LOAD`` [%].
    power_w : numpy.ndarray
        Drive power = (torque factor x actual Iq) x speed, HF ``POWER`` [W].
    friction_nm : numpy.ndarray
        True friction torque (Coulomb + Stribeck + viscous) [Nm] (truth).
    speed_smoothed_rpm, current_abs_smoothed_a, iq_smoothed_a : numpy.ndarray
        100 ms PT1-smoothed speed (r0063) [rpm], |I| (r0068) [A rms] and Iq (r0078) [A rms].
    torque_utilization_pct : numpy.ndarray
        Smoothed torque setpoint / available torque (r0081) [%].
    motor_temperature_c : numpy.ndarray
        Winding temperature (r0035) [degC].
    rotor_temperature_c : numpy.ndarray
        Rotor / bearing temperature [degC] (truth).
    kt_nm_per_a : numpy.ndarray
        True torque constant incl. magnet temperature and saturation [Nm/A rms] (truth).
    voltage_v : numpy.ndarray
        Phase-voltage amplitude demanded [V] (truth).
    state : SpindleState
        State after the last cycle, to continue the simulation.
    """

    speed_rpm: NDArray[np.float64]
    position_deg: NDArray[np.float64]
    current_a: NDArray[np.float64]
    id_a: NDArray[np.float64]
    current_abs_a: NDArray[np.float64]
    torque_setpoint_nm: NDArray[np.float64]
    torque_nm: NDArray[np.float64]
    load_pct: NDArray[np.float64]
    power_w: NDArray[np.float64]
    friction_nm: NDArray[np.float64]
    speed_smoothed_rpm: NDArray[np.float64]
    current_abs_smoothed_a: NDArray[np.float64]
    iq_smoothed_a: NDArray[np.float64]
    torque_utilization_pct: NDArray[np.float64]
    motor_temperature_c: NDArray[np.float64]
    rotor_temperature_c: NDArray[np.float64]
    kt_nm_per_a: NDArray[np.float64]
    voltage_v: NDArray[np.float64]
    state: SpindleState

    def __len__(self) -> int:
        return int(self.speed_rpm.size)

    @staticmethod
    def concatenate(traces: Sequence[SpindleTrace]) -> SpindleTrace:
        """Join consecutive chunks (state of the last one)."""
        if not traces:
            raise ConfigError("SpindleTrace.concatenate needs at least one trace")
        arrays = {f: np.concatenate([getattr(t, f) for t in traces]) for f in _TRACE_FIELDS}
        return SpindleTrace(**arrays, state=traces[-1].state)


_RPM_TO_RAD_S = 2.0 * math.pi / 60.0
_SQRT2 = math.sqrt(2.0)

# parameter vector layout for the compiled kernel
_P_NAMES: tuple[str, ...] = (
    "p",
    "psi",
    "alpha",
    "kt_ref_t",
    "sat_knee_peak",
    "sat_c",
    "b_rad",
    "tau_c",
    "fric_ref_t",
    "b_tc",
    "tau_tc",
    "strib_tau",
    "strib_w",
    "roll_w0",
    "roll_ww",
    "eps_w",
    "rs",
    "ld",
    "lq",
    "umax",
    "imax_peak",
    "rated_torque",
    "j",
    "tc_i",
    "kp",
    "ti",
    "kv",
    "t_amb",
    "r_sa",
    "r_rs",
    "c_s",
    "c_r",
    "pfe0",
    "f_base",
    "cu_tc",
    "rip_a",
    "rip_hi",
    "rip_w0",
    "w_max",
    "noise_i",
    "noise_w",
    "noise_t",
    "tau_lf",
    "roll_r",
    "spos_v",
    "spos_a",
    "flux_wb",
    "flux_exp",
    "sp_interp",
)
assert len(_P_NAMES) == 49


def _param_vector(motor: SpindleMotor) -> NDArray[np.float64]:
    """Pack the motor into the kernel's parameter vector (SI units, peak currents)."""
    if motor.pole_count < 2 or motor.pole_count % 2:
        raise ConfigError(
            f"SpindleMotor.pole_count must be an even number >= 2, got {motor.pole_count}"
        )
    for name in (
        "inertia_kg_m2",
        "kt_nm_per_a",
        "current_limit_a",
        "dc_link_v",
        "d_inductance_h",
        "q_inductance_h",
        "current_loop_time_constant_s",
        "speed_ctrl_ti_s",
        "spos_speed_rpm",
        "spos_accel_rev_s2",
        "lf_smoothing_time_s",
        "stator_heat_capacity_j_per_k",
        "rotor_heat_capacity_j_per_k",
        "stator_to_ambient_k_per_w",
        "rotor_to_stator_k_per_w",
    ):
        if not getattr(motor, name) > 0:
            raise ConfigError(f"SpindleMotor.{name} must be > 0, got {getattr(motor, name)}")
    p = motor.pole_pairs
    v = {
        "p": float(p),
        "psi": motor.flux_linkage_vs,
        "alpha": motor.magnet_temp_coeff_per_k,
        "kt_ref_t": motor.kt_ref_temperature_c,
        "sat_knee_peak": motor.kt_saturation_knee_a * _SQRT2,
        "sat_c": motor.kt_saturation_coeff,
        "b_rad": motor.viscous_friction_nm_per_rpm / _RPM_TO_RAD_S,
        "tau_c": motor.coulomb_friction_nm,
        "fric_ref_t": motor.friction_ref_temperature_c,
        "b_tc": motor.viscous_friction_temp_coeff_per_k,
        "tau_tc": motor.coulomb_friction_temp_coeff_per_k,
        "strib_tau": motor.stribeck_torque_nm,
        "strib_w": max(motor.stribeck_speed_rpm, 1e-6) * _RPM_TO_RAD_S,
        "roll_w0": motor.viscous_rolloff_speed_rpm * _RPM_TO_RAD_S,
        "roll_ww": max(motor.viscous_rolloff_width_rpm, 1e-6) * _RPM_TO_RAD_S,
        "eps_w": max(motor.friction_smoothing_rpm, 1e-6) * _RPM_TO_RAD_S,
        "rs": motor.stator_resistance_ohm,
        "ld": motor.d_inductance_h,
        "lq": motor.q_inductance_h,
        "umax": motor.max_phase_voltage_v,
        "imax_peak": motor.current_limit_a * _SQRT2,
        "rated_torque": motor.rated_torque_nm,
        "j": motor.inertia_kg_m2,
        "tc_i": motor.current_loop_time_constant_s,
        "kp": motor.speed_ctrl_kp_nm_s_per_rad,
        "ti": motor.speed_ctrl_ti_s,
        "kv": motor.position_ctrl_kv_per_s,
        "t_amb": motor.ambient_temperature_c,
        "r_sa": motor.stator_to_ambient_k_per_w,
        "r_rs": motor.rotor_to_stator_k_per_w,
        "c_s": motor.stator_heat_capacity_j_per_k,
        "c_r": motor.rotor_heat_capacity_j_per_k,
        "pfe0": motor.iron_loss_w_at_base,
        "f_base": max(motor.stator_frequency_hz(motor.base_speed_rpm), 1e-6),
        "cu_tc": motor.copper_temp_coeff_per_k,
        "rip_a": motor.ripple_amplitude_a,
        "rip_hi": motor.ripple_high_speed_a,
        "rip_w0": motor.ripple_growth_speed_rpm * _RPM_TO_RAD_S,
        "w_max": motor.max_speed_rpm * _RPM_TO_RAD_S,
        "noise_i": motor.current_noise_a,
        "noise_w": motor.speed_noise_rpm,
        "noise_t": motor.torque_noise_nm,
        "tau_lf": motor.lf_smoothing_time_s,
        "flux_wb": motor.flux_base_speed_rpm * _RPM_TO_RAD_S,
        "flux_exp": motor.flux_exponent,
        "sp_interp": 1.0 if motor.speed_setpoint_interpolation else 0.0,
        "roll_r": motor.viscous_rolloff_ratio,
        "spos_v": motor.spos_speed_rpm * 6.0,
        "spos_a": motor.spos_accel_rev_s2 * 360.0,
    }
    return np.array([v[n] for n in _P_NAMES], dtype=np.float64)


@njit(cache=True)
def _friction_nm(w: float, t_rotor: float, pv: NDArray[np.float64]) -> float:  # pragma: no cover
    """Friction torque [Nm] at speed w [rad/s] and bearing temperature [degC] (signed)."""
    dt_k = t_rotor - pv[8]
    b = pv[6] * max(0.05, 1.0 + pv[9] * dt_k)
    tau_c = pv[7] * max(0.05, 1.0 + pv[10] * dt_k)
    aw = abs(w)
    x = (aw - pv[13]) / pv[14]
    softplus = x + math.log1p(math.exp(-x)) if x > 0.0 else math.log1p(math.exp(x))
    w_eff = aw - (1.0 - pv[43]) * pv[14] * softplus
    r = w / pv[15]
    # tanh(r) rounds to exactly +-1.0 for |r| > 19.1; skip the call there (same bits)
    sgn = math.tanh(r) if abs(r) < 20.0 else (1.0 if r > 0.0 else -1.0)
    return sgn * (tau_c + pv[11] * math.exp(-aw / pv[12]) + b * w_eff)


_TAYLOR_STEP_RAD_S = 0.02
"""Largest speed change [rad/s] over which :func:`_kernel` extrapolates the friction torque
from its last exact evaluation (quadratic Taylor model); beyond it the friction is evaluated
exactly again. Error bound max|g3| d^3 / 6 < 3e-12 Nm for the default motor, g3 the third
derivative (see :func:`_friction_taylor`)."""


@njit(cache=True)
def _friction_taylor(
    w: float, t_rotor: float, pv: NDArray[np.float64]
) -> tuple[float, float, float]:  # pragma: no cover
    """Friction torque at ``w`` [Nm] and its first two derivatives in w (away from w = 0).

    Valid where the sign term is exactly +-1 (``|w| >= 20 eps``, see :func:`_friction_nm`);
    the value is computed with the same operations as :func:`_friction_nm` (same bits).
    With g(|w|) = tau_c + tau_s exp(-|w|/w_s) + B w_eff(|w|) and f = sgn(w) g(|w|)::

        g1 = -tau_s/w_s exp(-|w|/w_s) + B (1 - (1 - r) sigmoid(x))
        g2 =  tau_s/w_s^2 exp(-|w|/w_s) - B (1 - r) sigmoid(x) (1 - sigmoid(x)) / W

    with x = (|w| - w_k) / W; df/dw = g1, d2f/dw2 = sgn g2. The third derivative is bounded
    by tau_s / w_s^3 + 0.0962 B (1 - r) / W^2 (2.1e-6 Nm s^3/rad^3 for the default motor).
    """
    dt_k = t_rotor - pv[8]
    b = pv[6] * max(0.05, 1.0 + pv[9] * dt_k)
    tau_c = pv[7] * max(0.05, 1.0 + pv[10] * dt_k)
    aw = abs(w)
    x = (aw - pv[13]) / pv[14]
    if x > 0.0:
        ex = math.exp(-x)
        softplus = x + math.log1p(ex)
        sig = 1.0 / (1.0 + ex)
    else:
        ex = math.exp(x)
        softplus = math.log1p(ex)
        sig = ex / (1.0 + ex)
    w_eff = aw - (1.0 - pv[43]) * pv[14] * softplus
    sgn = 1.0 if w > 0.0 else -1.0
    st = pv[11] * math.exp(-aw / pv[12])
    g0 = tau_c + st + b * w_eff
    g1 = -st / pv[12] + b * (1.0 - (1.0 - pv[43]) * sig)
    g2 = st / (pv[12] * pv[12]) - b * (1.0 - pv[43]) * sig * (1.0 - sig) / pv[14]
    return sgn * g0, g1, sgn * g2


@njit(cache=True)
def _position_setpoint(
    state: NDArray[np.float64], cmd_deg: float, th_deg: float, cycle_time_s: float,
    spos_v: float, spos_a: float,
) -> tuple[float, float]:  # pragma: no cover - compiled
    """Position setpoint at the start and the end of a cycle in position control [deg].

    When position control takes over (SPOS, rigid tapping) the NC takes the actual angle as
    the setpoint and moves it to the programmed angle modulo 360 (the nearest turn) with a
    trapezoidal profile (``spos_v`` [deg/s], ``spos_a`` [deg/s^2]; MD35300/MD35210): the
    setpoint is ``cmd + offset`` with the offset running to a whole number of turns. The drive
    interpolates the setpoint linearly over the cycle (fine interpolation), so the position
    loop sees no 500 Hz staircase.
    """
    if state[_S_HAVE_POSCMD] > 0.5:
        start = state[_S_PREV_POSCMD]
    else:
        state[_S_POS_OFFSET] = th_deg - cmd_deg
        state[_S_POS_OFFSET_RATE] = 0.0
        start = th_deg
    # the offset runs monotonically to its nearest whole turn, so that turn is the target
    target = 360.0 * round(state[_S_POS_OFFSET] / 360.0)
    rem = target - state[_S_POS_OFFSET]
    if rem != 0.0 or state[_S_POS_OFFSET_RATE] != 0.0:
        dv = spos_a * cycle_time_s
        want = math.copysign(min(spos_v, math.sqrt(2.0 * spos_a * abs(rem))), rem)
        v = state[_S_POS_OFFSET_RATE]
        v = min(v + dv, want) if want > v else max(v - dv, want)
        step = v * cycle_time_s
        if abs(rem) <= abs(step) or (abs(rem) < 0.5 * dv * cycle_time_s and abs(v) <= dv):
            state[_S_POS_OFFSET] = target
            state[_S_POS_OFFSET_RATE] = 0.0
        else:
            state[_S_POS_OFFSET] += step
            state[_S_POS_OFFSET_RATE] = v
    end = cmd_deg + state[_S_POS_OFFSET]
    state[_S_PREV_POSCMD] = end
    state[_S_HAVE_POSCMD] = 1.0
    return start, end


@njit(cache=True)
def _kernel(  # pragma: no cover - compiled
    speed_cmd_rpm: NDArray[np.float64],
    load_nm: NDArray[np.float64],
    pos_cmd_deg: NDArray[np.float64],
    mode: NDArray[np.int64],
    noise: NDArray[np.float64],
    pv: NDArray[np.float64],
    state: NDArray[np.float64],
    cycle_time_s: float,
    inner_steps: int,
    out: NDArray[np.float64],
) -> None:
    n = speed_cmd_rpm.size
    dt = cycle_time_s / inner_steps
    p = pv[0]
    psi0 = pv[1]
    ld = pv[17]
    lq = pv[18]
    umax = pv[19]
    imax = pv[20]
    j = pv[22]
    a_i = 1.0 - math.exp(-dt / pv[23])
    kp = pv[24]
    ki = kp / pv[25]
    kv = pv[26]
    b_lf = 1.0 - math.exp(-cycle_time_s / pv[42])
    rpm = 60.0 / (2.0 * math.pi)
    sq2 = math.sqrt(2.0)
    psi_sq_margin = 1.0 + 1e-9
    psi_sq_far = 1.0 + 1e-8  # > psi_sq_margin: the product test never skips a needed id_ref
    umax2 = umax * umax
    inv_kt0 = 1.0 / (1.5 * p * psi0)
    w = state[0]
    th = state[1]
    integ = state[2]
    i_d = state[3]
    i_q = state[4]
    ts = state[5]
    tr = state[6]
    t_ref = 0.0
    te = 0.0
    fr = 0.0
    u = 0.0
    psi_act = psi0
    dt_over_j = dt / j
    # friction: exact evaluation at an anchor speed w0, quadratic Taylor model while
    # |w - w0| <= _TAYLOR_STEP_RAD_S and w stays where sgn(w) is exactly +-1; the anchor is
    # renewed every cycle (the rotor temperature moves the coefficients)
    w_taylor_min = 25.0 * pv[15] + _TAYLOR_STEP_RAD_S
    for k in range(n):
        anchored = False
        w0 = 0.0
        f0 = 0.0
        f1 = 0.0
        f2h = 0.0
        m = mode[k]
        ff_w = 0.0
        pc0 = 0.0
        dpc = 0.0
        if m == 1:
            pc0, pc1 = _position_setpoint(state, pos_cmd_deg[k], th * 180.0 / math.pi,
                                          cycle_time_s, pv[44], pv[45])
            dpc = (pc1 - pc0) / inner_steps
            ff_w = (pc1 - pc0) / cycle_time_s * math.pi / 180.0
        else:
            state[12] = 0.0
        w_cmd = speed_cmd_rpm[k] / rpm
        # the drive interpolates the speed setpoint linearly over the cycle (isochronous
        # setpoint, S120 setpoint channel): from the previous cycle's command to this one
        w_prev = state[16] if state[17] > 0.0 and pv[48] > 0.0 else w_cmd
        if m == 1:
            state[17] = 0.0
        else:
            state[16] = w_cmd
            state[17] = 1.0
        tau_load = load_nm[k] + pv[41] * noise[k, 2]
        # magnet flux at rotor temperature (Kt drift) - constant within a cycle
        psi_t = psi0 * (1.0 + pv[2] * (tr - pv[3]))
        # flux law of the constant-power range (induction spindle): (w_b / |w|)^exp above w_b,
        # known to the drive (its torque constant follows); off (factor exactly 1) at w_b = 0
        flux_f = 1.0
        if pv[46] > 0.0 and abs(w) > pv[46]:
            flux_f = (pv[46] / abs(w)) ** pv[47]
            psi_t = psi_t * flux_f
        for i_in in range(inner_steps):
            if m == 1:
                pos_err = pc0 + dpc * i_in - th * 180.0 / math.pi
                w_ref = ff_w + kv * pos_err * math.pi / 180.0
            else:
                w_ref = w_prev + (w_cmd - w_prev) * ((i_in + 1) / inner_steps)
            # field weakening: id from the voltage ellipse (steady state, Rs neglected)
            we = p * abs(w)
            id_ref = 0.0
            lq_iq = lq * i_q
            # well below the voltage limit, umax^2 > we^2 (psi_t^2 (1 + 1e-8) + (lq iq)^2),
            # id_ref is 0: decided with products, no division on the speed loop's path
            if we > 1.0 and umax2 <= we * we * (psi_sq_far * psi_t * psi_t + lq_iq * lq_iq):
                arg = (umax / we) ** 2 - lq_iq * lq_iq
                # below the voltage limit (sqrt(arg) > psi_t with margin) id_ref is 0.0:
                # skip the sqrt there (same bits)
                if arg <= psi_sq_margin * psi_t * psi_t:
                    id_ref = (min(0.0, (math.sqrt(arg) - psi_t) / ld) if arg > 0.0
                              else -psi_t / ld)
                if id_ref < -0.95 * imax:
                    id_ref = -0.95 * imax
            # speed PI with torque limit from the current circle (anti-windup: clamp)
            kt_drive = 1.5 * p * (psi0 * flux_f + (ld - lq) * i_d)
            # sqrt(fl(imax^2)) == imax exactly, so id_ref == 0 needs no sqrt (same bits)
            iq_avail = (imax if id_ref == 0.0
                        else math.sqrt(max(imax * imax - id_ref * id_ref, 0.0)))
            t_max = kt_drive * iq_avail
            e = w_ref - w
            t_ref = kp * e + integ
            if t_ref > t_max:
                t_ref = t_max
            elif t_ref < -t_max:
                t_ref = -t_max
            else:
                integ += ki * e * dt
            # i_d is exactly 0 below base speed: the constant 1 / kt then (no division)
            iq_ref = (t_ref * inv_kt0 if i_d == 0.0 and flux_f == 1.0
                      else t_ref / kt_drive)
            # current loop (first order)
            i_d += a_i * (id_ref - i_d)
            i_q += a_i * (iq_ref - i_q)
            # saturation lowers the magnet flux contribution at high |iq|
            sat = 1.0
            if abs(i_q) > pv[4]:  # else x <= 0: no saturation (division skipped, same bits)
                x = abs(i_q) / pv[4] - 1.0
                sat = 1.0 / (1.0 + pv[5] * x * x) if x > 0.0 else 1.0
            psi_act = psi_t * sat
            te = 1.5 * p * (psi_act + (ld - lq) * i_d) * i_q
            dw = w - w0
            if anchored and abs(dw) <= _TAYLOR_STEP_RAD_S:
                fr = f0 + dw * (f1 + f2h * dw)
            elif abs(w) >= w_taylor_min:
                f0, f1, f2 = _friction_taylor(w, tr, pv)
                f2h = 0.5 * f2
                w0 = w
                anchored = True
                fr = f0
            else:
                fr = _friction_nm(w, tr, pv)
                anchored = False
            w += dt_over_j * (te - fr - tau_load)
            th += dt * w
        # voltage demand (truth)
        we = p * w
        vd = pv[16] * i_d - we * lq * i_q
        vq = pv[16] * i_q + we * (ld * i_d + psi_act)
        u = math.sqrt(vd * vd + vq * vq)
        # thermal network: stator (copper + iron) <- rotor (friction) -> ambient
        rs_t = pv[16] * (1.0 + pv[34] * (ts - 20.0))
        p_cu = 1.5 * rs_t * (i_d * i_d + i_q * i_q)
        f_el = abs(we) / (2.0 * math.pi)
        p_fe = pv[32] * (f_el / pv[33]) ** 1.6
        p_fr = abs(fr * w)
        q_rs = (tr - ts) / pv[29]
        ts += cycle_time_s * (p_cu + p_fe + q_rs - (ts - pv[27]) / pv[28]) / pv[30]
        tr += cycle_time_s * (p_fr - q_rs) / pv[31]
        # measured values
        aw = abs(w)
        rip = pv[35]
        if aw > pv[37]:
            rip += pv[36] * ((aw - pv[37]) / max(pv[38] - pv[37], 1e-9)) ** 2
        iq_rms = i_q / sq2
        id_rms = i_d / sq2
        cur = iq_rms + rip * math.sin(p * th) + pv[39] * noise[k, 0]
        iabs = math.sqrt(iq_rms * iq_rms + id_rms * id_rms)
        kt_nom = 1.5 * p * psi0 * flux_f * sq2
        speed_meas = w * rpm + pv[40] * noise[k, 1]
        kt_drive_now = 1.5 * p * (psi0 * flux_f + (ld - lq) * i_d) * sq2
        t_avail = kt_drive_now * math.sqrt(max(imax * imax - i_d * i_d, 0.0)) / sq2
        util = 100.0 * abs(t_ref) / max(t_avail, 1e-9)
        state[7] += b_lf * (w * rpm - state[7])
        state[8] += b_lf * (iabs - state[8])
        state[9] += b_lf * (iq_rms - state[9])
        state[10] += b_lf * (util - state[10])
        out[k, 0] = speed_meas
        out[k, 1] = th * 180.0 / math.pi
        out[k, 2] = cur
        out[k, 3] = id_rms
        out[k, 4] = iabs
        out[k, 5] = t_ref
        out[k, 6] = te
        out[k, 7] = 100.0 * abs(t_ref) / pv[21]
        out[k, 8] = kt_nom * cur * w
        out[k, 9] = fr
        out[k, 10] = state[7]
        out[k, 11] = state[8]
        out[k, 12] = state[9]
        out[k, 13] = state[10]
        out[k, 14] = ts
        out[k, 15] = tr
        out[k, 16] = 1.5 * p * (psi_act + (ld - lq) * i_d) * sq2
        out[k, 17] = u
    state[0] = w
    state[1] = th
    state[2] = integ
    state[3] = i_d
    state[4] = i_q
    state[5] = ts
    state[6] = tr
    state[13] += n


def simulate_spindle(
    speed_cmd_rpm: ArrayLike,
    load_torque_nm: ArrayLike,
    motor: SpindleMotor,
    *,
    cycle_time_s: float = 0.002,
    inner_steps: int = 16,
    state: SpindleState | None = None,
    rng: np.random.Generator | None = None,
    position_cmd_deg: ArrayLike | None = None,
    mode: ArrayLike | None = None,
    out: NDArray[np.float64] | None = None,
) -> SpindleTrace:
    """Simulate the spindle drive, one output sample per position-control cycle.

    Parameters
    ----------
    speed_cmd_rpm : array-like of float
        Speed command per cycle (signed, already ramped by the NC) [rpm].
    load_torque_nm : array-like of float or float
        Process load torque per cycle, signed: positive brakes positive rotation (M3) [Nm].
    motor : SpindleMotor
        Motor and drive parameters.
    cycle_time_s : float, default 0.002
        Position-control cycle [s]; one output sample per cycle.
    inner_steps : int, default 16
        Controller steps per cycle (16 x 125 us = 2 ms on S120 booksize).
    state : SpindleState, optional
        Continue from ``trace.state`` of the previous chunk; default a cold spindle at rest.
    rng : numpy.random.Generator, optional
        Noise source; default ``numpy.random.default_rng(0)``.
    position_cmd_deg : array-like of float, optional
        Spindle position command per cycle (rigid tapping, mode 1) [deg].
    mode : array-like of int, optional
        0 = speed control, 1 = position control (follows ``position_cmd_deg``) per cycle;
        default all 0.
    out : numpy.ndarray, optional
        Buffer for the trace, C-contiguous float64 of shape (18, n_cycles), one row per trace
        field; the trace's arrays are then views into it (``simulate`` reuses one buffer
        between chunks when its sink does not keep them). Default: a new array.

    Returns
    -------
    SpindleTrace

    Notes
    -----
    Per 125 us step: speed PI (torque setpoint clamped to the current circle, anti-windup by
    clamping), field weakening id from the voltage ellipse
    (w_e Lq iq)^2 + (w_e (Ld id + psi))^2 = U_max^2, first-order current loop, torque
    Te = 1.5 p (psi(T) + (Ld - Lq) id) iq and the mechanics
    J dw/dt = Te - tau_fric(w, T) - tau_load (thesis Eq. 3.1). The friction is
    tau_f + tau_s exp(-|w|/w_s) + B w_eff with w_eff rolling off above ``viscous_rolloff_speed``.
    Per 2 ms cycle: two-node thermal network, LF PT1 smoothing, and the measured values. The
    stator-frequency ripple (a phase-current offset seen in dq) is sampled at the end of the
    cycle, so above 250 Hz it folds about the 250 Hz Nyquist frequency.
    Noise is drawn as one (n, 3) block per call, so chunked simulation equals one-shot
    simulation for the same generator.
    """
    cmd = np.ascontiguousarray(np.atleast_1d(np.asarray(speed_cmd_rpm, dtype=np.float64)))
    n = cmd.size
    load = np.ascontiguousarray(np.broadcast_to(np.asarray(load_torque_nm, dtype=np.float64), (n,)))
    if mode is None:
        mode_arr = np.zeros(n, dtype=np.int64)
    else:
        mode_arr = np.ascontiguousarray(np.broadcast_to(np.asarray(mode, dtype=np.int64), (n,)))
    if position_cmd_deg is None:
        if np.any(mode_arr == 1):
            raise ConfigError("simulate_spindle: mode 1 (position control) needs position_cmd_deg")
        pos = np.zeros(n)
    else:
        pos = np.ascontiguousarray(np.broadcast_to(np.asarray(position_cmd_deg, float), (n,)))
    if inner_steps < 1 or cycle_time_s <= 0:
        raise ConfigError("simulate_spindle: inner_steps must be >= 1 and cycle_time_s > 0")
    st = (state if state is not None else SpindleState.initial(motor)).vector.copy()
    gen = rng if rng is not None else np.random.default_rng(0)
    noise = gen.standard_normal((n, 3))
    nf = len(_TRACE_FIELDS)
    if out is None:
        out = np.empty((nf, n))
    elif out.shape != (nf, n) or out.dtype != np.float64 or not out.flags.c_contiguous:
        raise ConfigError(f"simulate_spindle: out must be C-contiguous float64 of shape "
                          f"({nf}, {n}), not {out.dtype} {out.shape}")
    # the kernel writes out[k, field] into the transposed view: each field is one contiguous
    # row, handed out without a copy
    _kernel(
        cmd,
        load,
        pos,
        mode_arr,
        noise,
        _param_vector(motor),
        st,
        float(cycle_time_s),
        int(inner_steps),
        out.T,
    )
    arrays = {f: out[i] for i, f in enumerate(_TRACE_FIELDS)}
    return SpindleTrace(**arrays, state=SpindleState(st))
