"""Feed-axis servo model: NC position loop, SINAMICS speed/current loops and slide mechanics.

One compiled call (:func:`simulate_servo`) runs every feed axis of a machine for a chunk of
position-control cycles (2 ms) and integrates the drive's speed and current loops and the
mechanics at the 125 us controller cycle inside (``inner_steps`` = 16). Structure per axis,
following thesis Fig. 3.1 and SINUMERIK function manuals G2/K3/B2 (physics-and-performance.md
§1.2)::

    DES_POS -> jerk filter (MD32402/MD32410) -> dynamic response adaptation (MD32910)
            -> x_f ----------------------------------------------+--> VEL_FFW = w dx_f/dt
               |                                                  +--> TORQUE_FFW = J d2x_f/dt2
               +-> FFW balancing (MD32620 mode, MD32810/MD32800) -> CTRL_POS
    CMD_SPEED = Kv (CTRL_POS - ENC_POS) + VEL_FFW  ->  drive: PI speed loop (125 us)
            -> torque setpoint (+ TORQUE_FFW, limited) -> current loop (PT1, MD32800-like)
            -> motor + ball screw + slide (inertia, Coulomb/viscous/Stribeck friction,
               external force) -> encoder (quantised) -> ENC_POS

Conventions
-----------
* Positions in mm on linear axes and deg on rotary axes (catalog units).
* ``VEL_FFW`` and ``CMD_SPEED`` per second: mm/s (linear) and deg/s (rotary), the unit
  convention of :mod:`cnctwin.signals` and of the real Capture4Analysis file (VEL_FFW equals
  d(DES_POS)/dt in mm/s, docs/real-data-servo.md §1.1). The LF ``SPEED_SMOOTHED`` (r0063)
  stays in mm/min (rpm), its catalog unit.
* ``TORQUE`` and ``TORQUE_FFW``: force at the slide in N on linear axes (motor torque times
  2 pi / pitch), motor torque in Nm on rotary axes (catalog units).
* ``CURRENT``: torque-generating current Iq in A rms (as :mod:`cnctwin.sim.spindle`).
* External forces act on the slide in the axis' positive direction [N] (rotary: load torque
  [Nm]); a drilling thrust on a tool feeding in -Z is therefore positive.

Signal definitions (what the kernel computes at cycle k)
--------------------------------------------------------
* ``CTRL_POS`` = balanced position setpoint at the comparator: x_f delayed by the FFW
  balancing (mode 1/2: PT1, mode 3/4: dead time, with MD32810 for speed FFW and MD32800 for
  torque FFW; mode 0: x_f).
* ``CTRL_DIFF2`` = ``CTRL_POS - ENC_POS`` exactly (the NC's controller difference).
* ``CTRL_DIFF``: with DSC on, the drive closes the position loop every 125 us with its own fresh
  encoder sample and the setpoint extrapolated over the cycle; ``CTRL_DIFF`` is the mean of that
  drive-side difference over the cycle that starts at k. With DSC off it equals ``CTRL_DIFF2``.
* ``CONT_DEV`` = following error minus the lag the NC expects = ``x_model - ENC_POS``, where
  the NC's model is a PT1 with 1/Kv on x_f without FFW, or a PT1 with the equivalent time
  (MD32810 speed FFW, MD32800 torque FFW) with FFW. Near zero in steady motion; non-zero on
  disturbances (force steps, friction at reversals).
* Following error = ``DES_POS - ENC_POS`` (computed by the reader from the recording).
* Drive values (``CURRENT``, ``TORQUE``, ``LOAD``, ``POWER``) are sampled at the end of the
  cycle that starts at k.

References
----------
.. [1] Siemens, SINUMERIK 840D sl Function Manual K3 (FFW modes MD32620, MD32810, MD32800,
   MD32910), G2 (Kv, equivalent time 1/Kv), B2 (jerk filter MD32402/MD32410).
.. [2] Thesis "CNC Machine Tool Digital Twin Applications with Advancements of Edge
   Computing", Koç University, Fig. 3.1 and §3.1.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from cnctwin.exceptions import ConfigError

if TYPE_CHECKING:
    from cnctwin.sim.machine import FeedAxis

__all__ = [
    "HISTORY_LENGTH",
    "SERVO_HF_CODES",
    "SERVO_LF_CODES",
    "ServoState",
    "ServoTrace",
    "servo_parameters",
    "simulate_servo",
]

HISTORY_LENGTH = 128
"""Ring-buffer length in cycles for moving averages and dead times (256 ms at 2 ms)."""

SERVO_HF_CODES: tuple[str, ...] = (
    "CTRL_POS",
    "ENC_POS",
    "CTRL_DIFF",
    "CTRL_DIFF2",
    "CONT_DEV",
    "VEL_FFW",
    "TORQUE_FFW",
    "CMD_SPEED",
    "CURRENT",
    "TORQUE",
    "LOAD",
    "POWER",
)
"""HF codes the kernel computes (``DES_POS`` is the input)."""

SERVO_LF_CODES: tuple[str, ...] = (
    "SPEED_SMOOTHED",
    "CURRENT_ABS_SMOOTHED",
    "IQ_ACT",
    "TORQUE_UTIL",
    "MOTOR_TEMP",
)
"""LF drive values computed every cycle (sampled by the recorder)."""

_TRUTH_CODES: tuple[str, ...] = ("true_position", "friction_force", "motor_speed_rad_s")

_OUT_CODES = (*SERVO_HF_CODES, *SERVO_LF_CODES, *_TRUTH_CODES)
_N_OUT = len(_OUT_CODES)

# ---------------------------------------------------------------- parameter vector layout
P_KV = 0  # position gain [1/s]
P_FFW_MODE = 1
P_FFW_WEIGHT = 2
P_JERK_TYPE = 3
P_JERK_TIME = 4  # [s]
P_DRA_TIME = 5  # [s]
P_EQ_SPEED = 6  # [s]
P_EQ_CURR = 7  # [s]
P_KP = 8  # speed controller gain [Nm s/rad]
P_TI = 9  # speed controller integral time [s]
P_J = 10  # total inertia at the motor [kg m^2]
P_G = 11  # load units (mm or deg) per motor rad
P_R = 12  # motor torque [Nm] per load force [N] (rotary: per load torque [Nm])
P_FC = 13  # Coulomb friction [N] / [Nm]
P_FV = 14  # viscous friction [N/(mm/s)] / [Nm/(deg/s)]
P_FS = 15  # Stribeck extra breakaway [N] / [Nm]
P_VS = 16  # Stribeck speed [mm/s] / [deg/s]
P_VEPS = 17  # Coulomb smoothing speed [mm/s] / [deg/s]
P_KT = 18  # [Nm/A]
P_IMAX = 19  # [A]
P_TRATED = 20  # [Nm]
P_RES = 21  # encoder resolution [mm] / [deg]
P_DSC = 22
P_RPH = 23  # phase resistance [Ohm]
P_RTH = 24  # thermal resistance [K/W]
P_CTH = 25  # heat capacity [J/K]
P_TAMB = 26  # [degC]
P_LFT = 27  # LF smoothing time [s]
P_ROTARY = 28
P_NOISE = 29  # current noise std [A]
_N_PARAM = 30

# ---------------------------------------------------------------- state vector layout
S_INIT = 0
S_XF1 = 1  # x_f at k-1
S_XF2 = 2  # x_f at k-2
S_J1 = 3  # jerk PT2 stage 1
S_J2 = 4  # jerk PT2 stage 2
S_DRA = 5  # DRA PT1
S_BAL = 6  # balancing PT1
S_MOD = 7  # NC lag model PT1
S_X = 8  # true load position
S_W = 9  # motor speed [rad/s]
S_INT = 10  # PI integral [Nm]
S_TACT = 11  # actual torque [Nm]
S_TSET = 12  # torque setpoint [Nm]
S_XQ = 13  # last quantised encoder value
S_RING = 14  # ring write index (cycles)
S_TEMP = 15  # motor temperature [degC]
S_LF_SPEED = 16
S_LF_IABS = 17
S_LF_IQ = 18
S_LF_UTIL = 19
S_CTRL1 = 20  # CTRL_POS at k-1 (DSC extrapolation)
S_FRIC = 21  # last friction force (truth)
_N_STATE = 22

# ring buffers: 0 jerk MA1 input, 1 jerk MA2 input, 2 DRA dead-time input, 3 balance input
_N_RING = 4


@njit(cache=True, inline="always")
def _ring_delay(ring: NDArray[np.float64], idx: int, delay_cycles: float) -> float:
    """Value ``delay_cycles`` (fractional, linear interpolation) before the newest entry."""
    n = ring.shape[0]
    d0 = int(math.floor(delay_cycles))  # noqa: RUF046 - explicit int for numba
    frac = delay_cycles - d0
    a = ring[(idx - d0) % n]
    if frac == 0.0:
        return a
    b = ring[(idx - d0 - 1) % n]
    return a + frac * (b - a)


@njit(cache=True)
def _servo_kernel(
    des: NDArray[np.float64],
    force: NDArray[np.float64],
    noise: NDArray[np.float64],
    par: NDArray[np.float64],
    st: NDArray[np.float64],
    ring: NDArray[np.float64],
    out: NDArray[np.float64],
    cycle_time_s: float,
    inner_steps: int,
) -> None:
    n_axes, n = des.shape
    tc = cycle_time_s
    h = tc / inner_steps
    nring = ring.shape[2]
    for a in range(n_axes):
        kv = par[a, P_KV]
        mode = int(par[a, P_FFW_MODE])
        w_ffw = par[a, P_FFW_WEIGHT] if mode != 0 else 0.0
        jtype = int(par[a, P_JERK_TYPE])
        jtime = par[a, P_JERK_TIME]
        if jtime <= tc:
            jtype = 0
        dra_t = par[a, P_DRA_TIME]
        t_eq = par[a, P_EQ_SPEED] if mode in (1, 3) else par[a, P_EQ_CURR]
        kp = par[a, P_KP]
        ki_h = kp * h / par[a, P_TI]
        jm = par[a, P_J]
        g = par[a, P_G]
        r = par[a, P_R]
        fc = par[a, P_FC]
        fv = par[a, P_FV]
        fs = par[a, P_FS]
        vs = par[a, P_VS]
        veps = par[a, P_VEPS]
        kt = par[a, P_KT]
        tmax = kt * par[a, P_IMAX]
        trated = par[a, P_TRATED]
        res = par[a, P_RES]
        dsc = par[a, P_DSC] > 0.5
        rph = par[a, P_RPH]
        rth = par[a, P_RTH]
        cth = par[a, P_CTH]
        tamb = par[a, P_TAMB]
        rotary = par[a, P_ROTARY] > 0.5
        inv_res = 1.0 / res
        inv_g = 1.0 / g
        inv_hg = 1.0 / (h * g)
        inv_veps = 1.0 / veps
        inv_vs = 1.0 / vs
        h_over_j = h / jm
        hg = h * g
        # unit factors: load units/s -> recorded speed units. HF VEL_FFW/CMD_SPEED per second
        # (v_out, kept as a factor so the code matches the reference kernel); LF r0063 in
        # mm/min or rpm (v_lf)
        v_out = 1.0
        v_lf = 60.0 if not rotary else 1.0 / 6.0  # mm/s -> mm/min ; deg/s -> rpm
        f_out = 1.0 / r if not rotary else 1.0  # Nm motor -> N at slide ; Nm stays Nm
        # discrete filter coefficients
        cur_t = par[a, P_EQ_CURR]
        a_cur = 1.0 - math.exp(-h / cur_t) if cur_t > 0.0 else 1.0
        # NC filters are backward-Euler PT1s, a = Tc / (T + Tc): ramp lag exactly T
        a_j = tc / (0.5 * jtime + tc) if jtype == 1 else 1.0
        m_ma = max(1, int(round(jtime / tc))) if jtype in (2, 4) else 1  # noqa: RUF046
        a_dra = tc / (dra_t + tc)
        dra_dead = mode in (3, 4)
        dra_cycles = dra_t / tc
        bal_pt1 = mode in (1, 2)
        bal_dead = mode in (3, 4)
        a_bal = tc / (t_eq + tc)
        bal_cycles = t_eq / tc
        t_mod = t_eq if mode != 0 else 1.0 / kv
        a_mod = tc / (t_mod + tc)
        a_lf = 1.0 - math.exp(-tc / par[a, P_LFT])
        use0 = jtype == 2 or jtype == 4
        use1 = jtype == 4
        use2 = dra_t > 0.0 and dra_dead
        use3 = bal_dead
        frozen = False
        fz_xd = 0.0
        fz_f = 0.0
        fz_iq = 0.0
        fz_vl = 0.0
        fz_util = 0.0

        if st[a, S_INIT] == 0.0:
            x0 = des[a, 0] if n > 0 else 0.0
            st[a, S_XF1] = x0
            st[a, S_XF2] = x0
            st[a, S_J1] = x0
            st[a, S_J2] = x0
            st[a, S_DRA] = x0
            st[a, S_BAL] = x0
            st[a, S_MOD] = x0
            st[a, S_X] = x0
            st[a, S_W] = 0.0
            st[a, S_INT] = 0.0
            st[a, S_TACT] = 0.0
            st[a, S_TSET] = 0.0
            st[a, S_XQ] = round(x0 / res) * res  # encoder value of the previous latch
            st[a, S_RING] = 0.0
            st[a, S_TEMP] = tamb
            st[a, S_CTRL1] = x0
            for b in range(_N_RING):
                for i in range(nring):
                    ring[a, b, i] = x0
            st[a, S_INIT] = 1.0

        xf1 = st[a, S_XF1]
        xf2 = st[a, S_XF2]
        j1 = st[a, S_J1]
        j2 = st[a, S_J2]
        dra = st[a, S_DRA]
        bal = st[a, S_BAL]
        mod = st[a, S_MOD]
        x = st[a, S_X]
        w = st[a, S_W]
        integ = st[a, S_INT]
        tact = st[a, S_TACT]
        tset = st[a, S_TSET]
        xq = st[a, S_XQ]
        ridx = int(st[a, S_RING])
        temp = st[a, S_TEMP]
        lf_speed = st[a, S_LF_SPEED]
        lf_iabs = st[a, S_LF_IABS]
        lf_iq = st[a, S_LF_IQ]
        lf_util = st[a, S_LF_UTIL]
        ctrl1 = st[a, S_CTRL1]
        fric = st[a, S_FRIC]

        for k in range(n):
            ridx = (ridx + 1) % nring
            xd = des[a, k]
            fext = force[a, k]
            if frozen:
                if xd == fz_xd and fext == fz_f:
                    # settled: the dynamic state is a bitwise fixed point (see Notes of
                    # simulate_servo); only noise, temperature and LF filters move
                    temp += tc * (rph * fz_iq * fz_iq - (temp - tamb) / rth) / cth
                    lf_speed += a_lf * (fz_vl - lf_speed)
                    lf_iabs += a_lf * (abs(fz_iq) - lf_iabs)
                    lf_iq += a_lf * (fz_iq - lf_iq)
                    lf_util += a_lf * (fz_util - lf_util)
                    for i in range(_N_OUT):
                        out[a, i, k] = out[a, i, k - 1]
                    out[a, 8, k] = fz_iq + noise[a, k]
                    out[a, 12, k] = lf_speed
                    out[a, 13, k] = lf_iabs
                    out[a, 14, k] = lf_iq
                    out[a, 15, k] = lf_util
                    out[a, 16, k] = temp
                    continue
                frozen = False
            b_xf1 = xf1
            b_xf2 = xf2
            b_j1 = j1
            b_j2 = j2
            b_dra = dra
            b_bal = bal
            b_mod = mod
            b_x = x
            b_w = w
            b_integ = integ
            b_tact = tact
            b_tset = tset
            b_xq = xq
            b_ctrl1 = ctrl1
            b_fric = fric
            # ---- NC: jerk filter
            if jtype == 1:
                j1 += a_j * (xd - j1)
                j2 += a_j * (j1 - j2)
                xj = j2
            elif jtype == 2 or jtype == 4:
                ring[a, 0, ridx] = xd
                s = 0.0
                for i in range(m_ma):
                    s += ring[a, 0, (ridx - i) % nring]
                xj = s / m_ma
                if jtype == 4:
                    ring[a, 1, ridx] = xj
                    s = 0.0
                    for i in range(m_ma):
                        s += ring[a, 1, (ridx - i) % nring]
                    xj = s / m_ma
            else:
                xj = xd
            # ---- dynamic response adaptation
            if dra_t > 0.0:
                if dra_dead:
                    ring[a, 2, ridx] = xj
                    xf = _ring_delay(ring[a, 2], ridx, dra_cycles)
                else:
                    dra += a_dra * (xj - dra)
                    xf = dra
            else:
                xf = xj
            # ---- feedforward and balancing
            vel = w_ffw * (xf - xf1) / tc  # load units/s
            if mode == 2 or mode == 4:
                acc = (xf - 2.0 * xf1 + xf2) / (tc * tc)
                tffw = jm * acc / g  # motor Nm
            else:
                tffw = 0.0
            if bal_dead:
                ring[a, 3, ridx] = xf
                ctrl = _ring_delay(ring[a, 3], ridx, bal_cycles)
            elif bal_pt1:
                bal += a_bal * (xf - bal)
                ctrl = bal
            else:
                ctrl = xf
            mod += a_mod * (xf - mod)
            xf2 = xf1
            xf1 = xf
            # ---- position controller (NC): encoder latched at t_k
            xq_prev = xq
            xq = np.rint(x * inv_res) * res  # rint: no float->int->float round trip
            enc = xq
            diff2 = ctrl - enc
            vset0 = kv * diff2 + vel  # load units/s
            dctrl = ctrl - ctrl1
            ctrl1 = ctrl
            # ---- drive: 125 us loops
            dsum = 0.0
            for j in range(inner_steps):
                if j > 0:
                    xq_prev = xq
                    xq = np.rint(x * inv_res) * res
                w_meas = (xq - xq_prev) * inv_hg
                if dsc:
                    dd = ctrl + dctrl * (j / inner_steps) - xq
                    dsum += dd
                    vset = kv * dd + vel
                else:
                    vset = vset0
                e = vset * inv_g - w_meas
                integ += ki_h * e
                tset = kp * e + integ + tffw
                if tset > tmax:
                    integ -= ki_h * e
                    tset = tmax
                elif tset < -tmax:
                    integ -= ki_h * e
                    tset = -tmax
                tact += a_cur * (tset - tact)
                # friction at the slide, load units
                v = w * g
                av = abs(v)
                sg = (1.0 if v > 0.0 else -1.0) if av >= veps else v * inv_veps
                fr = fv * v
                if av < 5.0 * vs:
                    u = v * inv_vs
                    fr += sg * (fc + fs * math.exp(-u * u))
                else:
                    fr += sg * fc
                fric = fr
                w += h_over_j * (tact - (fr - fext) * r)
                x += hg * w
            # ---- recorded values
            iq = tact / kt
            cur = iq + noise[a, k]
            pw = tact * w + rph * iq * iq
            temp += tc * (rph * iq * iq - (temp - tamb) / rth) / cth
            vload = w * g
            lf_speed += a_lf * (vload * v_lf - lf_speed)
            lf_iabs += a_lf * (abs(iq) - lf_iabs)
            lf_iq += a_lf * (iq - lf_iq)
            lf_util += a_lf * (abs(tset) / tmax * 100.0 - lf_util)
            out[a, 0, k] = ctrl
            out[a, 1, k] = enc
            out[a, 2, k] = dsum / inner_steps if dsc else diff2
            out[a, 3, k] = diff2
            out[a, 4, k] = mod - enc
            out[a, 5, k] = vel * v_out
            out[a, 6, k] = tffw * f_out
            out[a, 7, k] = vset0 * v_out
            out[a, 8, k] = cur
            out[a, 9, k] = tset * f_out
            out[a, 10, k] = abs(tset) / trated * 100.0
            out[a, 11, k] = pw
            out[a, 12, k] = lf_speed
            out[a, 13, k] = lf_iabs
            out[a, 14, k] = lf_iq
            out[a, 15, k] = lf_util
            out[a, 16, k] = temp
            out[a, 17, k] = x
            out[a, 18, k] = fric
            out[a, 19, k] = w
            # ---- settled? same inputs as the previous cycle and the state did not move
            if (
                k > 0
                and xd == des[a, k - 1]
                and fext == force[a, k - 1]
                and xf1 == b_xf1 and xf2 == b_xf2 and j1 == b_j1 and j2 == b_j2
                and dra == b_dra and bal == b_bal and mod == b_mod and x == b_x and w == b_w
                and integ == b_integ and tact == b_tact and tset == b_tset and xq == b_xq
                and ctrl1 == b_ctrl1 and fric == b_fric
            ):
                ok = True
                for b in range(_N_RING):
                    if (b == 0 and use0) or (b == 1 and use1) or (b == 2 and use2) or (
                        b == 3 and use3
                    ):
                        v0 = ring[a, b, ridx]
                        for i in range(nring):
                            if ring[a, b, i] != v0:
                                ok = False
                                break
                if ok:
                    frozen = True
                    fz_xd = xd
                    fz_f = fext
                    fz_iq = iq
                    fz_vl = vload * v_lf
                    fz_util = abs(tset) / tmax * 100.0

        st[a, S_XF1] = xf1
        st[a, S_XF2] = xf2
        st[a, S_J1] = j1
        st[a, S_J2] = j2
        st[a, S_DRA] = dra
        st[a, S_BAL] = bal
        st[a, S_MOD] = mod
        st[a, S_X] = x
        st[a, S_W] = w
        st[a, S_INT] = integ
        st[a, S_TACT] = tact
        st[a, S_TSET] = tset
        st[a, S_XQ] = xq
        st[a, S_RING] = float(ridx)
        st[a, S_TEMP] = temp
        st[a, S_LF_SPEED] = lf_speed
        st[a, S_LF_IABS] = lf_iabs
        st[a, S_LF_IQ] = lf_iq
        st[a, S_LF_UTIL] = lf_util
        st[a, S_CTRL1] = ctrl1
        st[a, S_FRIC] = fric


# ---------------------------------------------------------------- Python layer
def servo_parameters(axes: Sequence[FeedAxis]) -> NDArray[np.float64]:
    """Pack feed-axis descriptions into the kernel's parameter matrix.

    Parameters
    ----------
    axes : sequence of FeedAxis
        Axis descriptions (:class:`cnctwin.sim.machine.FeedAxis`).

    Returns
    -------
    numpy.ndarray, shape (n_axes, 30)
        Internal units: gains in 1/s, times in s, inertia at the motor in kg m^2, friction in
        N (Nm) at the slide (table), speeds in mm/s (deg/s).
    """
    p = np.zeros((len(axes), _N_PARAM))
    for i, ax in enumerate(axes):
        g = ax.load_per_motor_rad
        p[i, P_KV] = ax.kv_per_s
        p[i, P_FFW_MODE] = ax.ffw_mode
        p[i, P_FFW_WEIGHT] = ax.ffw_weight
        p[i, P_JERK_TYPE] = ax.jerk_filter_type
        p[i, P_JERK_TIME] = ax.jerk_time_s
        p[i, P_DRA_TIME] = ax.dyn_match_time_s
        p[i, P_EQ_SPEED] = ax.equiv_speedctrl_time_s
        p[i, P_EQ_CURR] = ax.equiv_currctrl_time_s
        p[i, P_KP] = ax.speed_kp_nm_s_per_rad
        p[i, P_TI] = ax.speed_ti_s
        p[i, P_J] = ax.total_inertia_kgm2
        p[i, P_G] = g
        p[i, P_R] = ax.motor_torque_per_load_force
        p[i, P_FC] = ax.coulomb_n
        p[i, P_FV] = ax.viscous_n_per_mm_s
        p[i, P_FS] = ax.stribeck_n
        p[i, P_VS] = ax.stribeck_speed_mm_s
        p[i, P_VEPS] = ax.friction_smoothing_mm_s
        p[i, P_KT] = ax.kt_nm_per_a
        p[i, P_IMAX] = ax.current_limit_a
        p[i, P_TRATED] = ax.rated_torque_nm
        p[i, P_RES] = ax.encoder_resolution
        p[i, P_DSC] = 1.0 if ax.dsc else 0.0
        p[i, P_RPH] = ax.phase_resistance_ohm
        p[i, P_RTH] = ax.thermal_resistance_k_per_w
        p[i, P_CTH] = ax.heat_capacity_j_per_k
        p[i, P_TAMB] = ax.ambient_temperature_c
        p[i, P_LFT] = ax.lf_smoothing_time_s
        p[i, P_ROTARY] = 1.0 if ax.rotary else 0.0
        p[i, P_NOISE] = ax.current_noise_a
    return p


@dataclass
class ServoState:
    """State of the servo kernel between chunks (pass ``trace.state`` to the next call).

    Attributes
    ----------
    values : numpy.ndarray, shape (n_axes, 22)
        Filter, controller, mechanics and thermal states.
    history : numpy.ndarray, shape (n_axes, 4, HISTORY_LENGTH)
        Ring buffers of the moving averages and dead times.
    """

    values: NDArray[np.float64]
    history: NDArray[np.float64]

    @classmethod
    def new(cls, n_axes: int) -> ServoState:
        """A fresh state; the first chunk initialises every filter at its first setpoint."""
        return cls(np.zeros((n_axes, _N_STATE)), np.zeros((n_axes, _N_RING, HISTORY_LENGTH)))

    def copy(self) -> ServoState:
        """An independent copy."""
        return ServoState(self.values.copy(), self.history.copy())


@dataclass
class ServoTrace:
    """Per-cycle output of :func:`simulate_servo`.

    Attributes
    ----------
    axes : tuple of str
        Axis names, the first dimension of every array.
    signals : dict
        HF code (``"ENC_POS"``, ..., see :data:`SERVO_HF_CODES`, plus ``"DES_POS"``) and LF code
        (:data:`SERVO_LF_CODES`) -> array of shape (n_axes, n_cycles), in catalog units.
    truth : dict
        Hidden states, shape (n_axes, n_cycles): ``true_position`` (mm/deg, unquantised),
        ``friction_force`` (N/Nm at the slide/table), ``motor_speed_rad_s``.
    state : ServoState
        State after the last cycle; continue with ``simulate_servo(..., state=trace.state)``.
    """

    axes: tuple[str, ...]
    signals: dict[str, NDArray[np.float64]]
    truth: dict[str, NDArray[np.float64]]
    state: ServoState
    cycle_time_s: float = 0.002
    extra: dict[str, object] = field(default_factory=dict)

    def axis(self, code: str, axis: str) -> NDArray[np.float64]:
        """One signal of one axis (``trace.axis("ENC_POS", "X1")``)."""
        return self.signals[code][self.axes.index(axis)]


def simulate_servo(
    des_pos: ArrayLike,
    axes: Sequence[FeedAxis],
    *,
    force_n: ArrayLike | None = None,
    cycle_time_s: float = 0.002,
    inner_steps: int = 16,
    state: ServoState | None = None,
    rng: np.random.Generator | None = None,
) -> ServoTrace:
    """Run the feed-axis control loops and mechanics for a chunk of position-control cycles.

    Parameters
    ----------
    des_pos : array-like, shape (n_axes, n_cycles)
        Position setpoint after the fine interpolator (``DES_POS``) per axis [mm] or [deg].
    axes : sequence of FeedAxis
        Axis descriptions, in the order of the rows of ``des_pos``.
    force_n : array-like, shape (n_axes, n_cycles), optional
        External force on each slide in its positive direction [N] (rotary axes: load torque
        [Nm]), held over each cycle. Default zero.
    cycle_time_s : float, default 0.002
        Position-control cycle [s].
    inner_steps : int, default 16
        Speed/current-controller steps per cycle (125 us at 2 ms).
    state : ServoState, optional
        State from the previous chunk; ``None`` starts at rest at the first setpoint.
    rng : numpy.random.Generator, optional
        Source of the current measurement noise (``FeedAxis.current_noise_a``); ``None`` gives a
        noise-free run.

    Returns
    -------
    ServoTrace

    Notes
    -----
    Position controller (NC, every cycle k)::

        n_set[k] = Kv (CTRL_POS[k] - ENC_POS[k]) + w (x_f[k] - x_f[k-1]) / T_c

    with Kv [1/s] = 16.667 Kv [(m/min)/mm] (MD10230). Without feedforward the steady following
    error is v / Kv; with speed feedforward the PI speed loop removes the steady speed error, so
    ``CTRL_DIFF2`` tends to zero and ``DES_POS - ENC_POS`` tends to v times the filter delays
    plus the balancing time. Speed loop (drive, every h = T_c / inner_steps)::

        tau_set = Kp e + (Kp / Ti) int e dt + tau_ffw,   |tau_set| <= Kt I_max
        tau     = PT1(tau_set, MD32800)
        J domega/dt = tau - r (F_friction(v) - F_ext),   v = g omega

    with F_friction = b v + sgn(v) (F_c + F_s exp(-(v/v_s)^2)) (sgn linear inside
    +- ``friction_smoothing_mm_s``). The jerk filter moving average over m = round(T/T_c)
    samples delays by (m-1) T_c / 2; type 1 is two PT1 stages of T/2 (low-frequency delay T);
    type 4 is two moving averages. The chunked run is bit-identical to one long run (test_servo.py).

    Settled axes are skipped exactly: when a cycle leaves every dynamic state (filters, loop,
    mechanics, encoder latch) bitwise unchanged, with the same setpoint and force as the cycle
    before and uniform history buffers, the following cycles with the same inputs are that same
    fixed point, so only the current noise, the motor temperature and the LF filters are
    advanced. The output is bit-identical to the full computation
    (``tests/sim/test_kernels_reference.py``); an axis that has never moved (C1/B1 in drilling)
    costs ~1/20 of a moving one. An axis hunting by one encoder increment at standstill (the
    limit cycle of integral action on a quantised encoder) is not a fixed point and keeps being
    simulated.
    """
    des = np.ascontiguousarray(des_pos, dtype=np.float64)
    if des.ndim == 1:
        des = des[None, :]
    n_axes, n = des.shape
    if n_axes != len(axes):
        raise ConfigError(
            f"des_pos has {n_axes} rows but {len(axes)} axes were given; pass one row per axis"
        )
    if inner_steps < 1:
        raise ConfigError(f"inner_steps must be >= 1, not {inner_steps}")
    par = servo_parameters(axes)
    max_delay = max(
        [ax.jerk_time_s * 2 for ax in axes]
        + [ax.dyn_match_time_s + ax.equiv_speedctrl_time_s + ax.equiv_currctrl_time_s
           for ax in axes]
    )
    if max_delay / cycle_time_s > HISTORY_LENGTH - 2:
        raise ConfigError(
            f"filter/dead times up to {max_delay:.3f} s exceed the {HISTORY_LENGTH}-cycle "
            "history; shorten jerk_time_s/dyn_match_time_s"
        )
    if force_n is None:
        force = np.zeros_like(des)
    else:
        force = np.ascontiguousarray(force_n, dtype=np.float64)
        if force.shape != des.shape:
            raise ConfigError(
                f"force_n has shape {force.shape}, des_pos {des.shape}; they must match"
            )
    noise = np.zeros_like(des)
    if rng is not None:
        sd = par[:, P_NOISE]
        if np.any(sd > 0):
            # drawn cycle-major so that chunked runs consume the stream like one long run
            noise = (rng.standard_normal((n, n_axes)) * sd[None, :]).T.copy()
    st = state.copy() if state is not None else ServoState.new(n_axes)
    if st.values.shape != (n_axes, _N_STATE):
        raise ConfigError(
            f"state is for {st.values.shape[0]} axes, des_pos has {n_axes}; pass the state of "
            "the same machine"
        )
    out = np.empty((n_axes, _N_OUT, n))
    _servo_kernel(des, force, noise, par, st.values, st.history, out, cycle_time_s, inner_steps)
    signals: dict[str, NDArray[np.float64]] = {"DES_POS": des}
    for i, code in enumerate(_OUT_CODES):
        if code in _TRUTH_CODES:
            continue
        signals[code] = out[:, i, :]
    truth = {code: out[:, i, :] for i, code in enumerate(_OUT_CODES) if code in _TRUTH_CODES}
    return ServoTrace(
        axes=tuple(ax.name for ax in axes),
        signals=signals,
        truth=truth,
        state=st,
        cycle_time_s=cycle_time_s,
    )
