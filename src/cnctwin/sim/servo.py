"""Feed-axis servo model: NC position loop, SINAMICS speed/current loops and slide mechanics.

One compiled call (:func:`simulate_servo`) runs every feed axis of a machine for a chunk of
position-control cycles (2 ms) and integrates the drive's speed and current loops and the
mechanics at the 125 us controller cycle inside (``inner_steps`` = 16). Structure per axis,
following thesis Fig. 3.1 and SINUMERIK function manuals G2/K3/B2
(docs/reference/physics-and-performance.md
§1.2)::

    DES_POS -> jerk filter (MD32402/MD32410) -> dynamic response adaptation (MD32910)
            -> x_f ----------------------------------------------+--> VEL_FFW = w dx_f/dt
               |                                                  +--> TORQUE_FFW = J d2x_f/dt2
               +-> FFW balancing (MD32620 mode, MD32810/MD32800) -> CTRL_POS
    CMD_SPEED = Kv (CTRL_POS - ENC_POS) + VEL_FFW  ->  drive: PI speed loop (125 us;
            with DSC the position difference every 125 us and VEL_FFW interpolated over the
            cycle, "DSC with spline" S120 p1191, FeedAxis.dsc_spline)
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
  cycle that starts at k. ``TORQUE`` is the torque actual value, Kt x the measured current
  (``CURRENT``, with its noise), as on the real drive (Capture4Analysis X1:
  TORQUE = 1.44 CURRENT, residual below the noise; docs/simulator.md); ``LOAD`` is the
  torque setpoint over the rated torque.
* Measurement: the NC's position measuring system has white noise
  (``FeedAxis.encoder_noise``) before the quantisation; ``ENC_POS``, ``CTRL_DIFF2``,
  ``CONT_DEV`` and the speed setpoint (``CMD_SPEED``) see it; the drive's 125 us speed (and DSC
  position) loop reads the motor encoder, quantised without it. A position-periodic force
  (``FeedAxis.ripple_n``, one period per motor revolution) loads the slide.

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
    "N_KERNEL_OUTPUTS",
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
N_KERNEL_OUTPUTS = _N_OUT
"""Rows per axis of the kernel's output buffer (``simulate_servo(out=...)``)."""

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
P_ENC_NOISE = 30  # NC measuring-system noise std [mm] / [deg]
P_RIPPLE = 31  # position-periodic force amplitude [N] / [Nm]
P_RIPPLE_PHASE = 32  # its phase at position 0 [rad]
P_DSC_SPLINE = 33  # interpolate the speed feedforward over the cycle (S120 p1191)
_N_PARAM = 34

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
S_VEL1 = 22  # speed feedforward at k-1 (DSC spline)
_N_STATE = 23

# ring buffers: 0 jerk MA1 input, 1 jerk MA2 input, 2 DRA dead-time input, 3 balance input
_N_RING = 4


# per-axis drive constants (columns of the kernel's constant matrix)
C_KV = 0
C_INV_G = 1  # 1 / g
C_INV_HG = 2  # 1 / (h g)
C_KI_H = 3  # Kp h / Ti
C_KP = 4
C_TMAX = 5  # Kt I_max [Nm]
C_A_CUR = 6  # current-loop PT1 coefficient
C_G = 7
C_VEPS = 8
C_INV_VEPS = 9
C_FV = 10
C_FC = 11
C_FS = 12
C_VS5 = 13  # 5 v_s: Stribeck term evaluated below this speed
C_INV_VS = 14
C_H_OVER_J = 15
C_R = 16
C_HG = 17  # h g
C_INV_RES = 18
C_RES = 19
C_DSC = 20
C_RIPPLE = 21  # ripple amplitude [N] / [Nm] at the slide
C_RIPPLE_PHASE = 22  # [rad]
C_SPLINE = 23  # 1: speed feedforward interpolated over the cycle
_N_CST = 24

# per-axis values handed from the NC part of a cycle to its drive loops (columns of cin)
I_CTRL = 0
I_DCTRL = 1
I_VEL = 2
I_VSET0 = 3
I_TFFW = 4
I_FEXT = 5
I_XQ = 6  # encoder value latched at the start of the cycle
I_XQP = 7  # encoder value of the previous latch
I_XN = 8  # the NC's measured position (ENC_POS): latched with its measurement noise
I_DVEL = 9  # speed feedforward minus the previous cycle's (DSC spline)
_N_CIN = 10

# drive state per axis while a chunk runs (columns of dst)
D_X = 0
D_W = 1
D_INT = 2
D_TACT = 3
D_TSET = 4
D_FRIC = 5
D_XQ = 6
D_DSUM = 7
_N_DST = 8

_LANES = 3
"""Axes whose 125 us drive loops run side by side in one loop body (see simulate_servo)."""


@njit(cache=True, inline="always")
def _ring_delay(ring: NDArray[np.float64], a: int, b: int, idx: int,
                delay_cycles: float) -> float:
    """Value ``delay_cycles`` (fractional, linear interpolation) before the newest entry."""
    n = ring.shape[2]
    d0 = int(math.floor(delay_cycles))  # noqa: RUF046 - explicit int for numba
    frac = delay_cycles - d0
    i0 = idx - d0
    if i0 < 0:
        i0 += n
    v0 = ring[a, b, i0]
    if frac == 0.0:
        return v0
    i1 = i0 - 1
    if i1 < 0:
        i1 += n
    return v0 + frac * (ring[a, b, i1] - v0)


@njit(cache=True, inline="always")
def _drive_step(
    c: NDArray[np.float64], x: float, w: float, integ: float, tact: float, tset: float,
    xq: float, xq_prev: float, dsum: float, frac: float, ctrl: float, dctrl: float,
    vel: float, vset0: float, tffw: float, fext: float, dvel: float,
) -> tuple[float, float, float, float, float, float, float]:
    """One 125 us step of one axis: speed PI, current PT1, friction, mechanics.

    Returns the new (x, w, integ, tact, tset, dsum, friction).
    """
    w_meas = (xq - xq_prev) * c[C_INV_HG]
    if c[C_DSC] > 0.5:
        dd = ctrl + dctrl * frac - xq
        dsum += dd
        if c[C_SPLINE] > 0.5:  # feedforward from the previous cycle's value to this one's
            vset = c[C_KV] * dd + (vel - dvel * (1.0 - frac))
        else:
            vset = c[C_KV] * dd + vel
    else:
        vset = vset0
    e = vset * c[C_INV_G] - w_meas
    ki_h = c[C_KI_H]
    integ += ki_h * e
    tset = c[C_KP] * e + integ + tffw
    tmax = c[C_TMAX]
    if tset > tmax:
        integ -= ki_h * e
        tset = tmax
    elif tset < -tmax:
        integ -= ki_h * e
        tset = -tmax
    tact += c[C_A_CUR] * (tset - tact)
    # friction at the slide, load units
    v = w * c[C_G]
    av = abs(v)
    sg = (1.0 if v > 0.0 else -1.0) if av >= c[C_VEPS] else v * c[C_INV_VEPS]
    fr = c[C_FV] * v
    if av < c[C_VS5]:
        u = v * c[C_INV_VS]
        fr += sg * (c[C_FC] + c[C_FS] * math.exp(-u * u))
    else:
        fr += sg * c[C_FC]
    if c[C_RIPPLE] != 0.0:  # position-periodic force, one period per motor revolution
        fext -= c[C_RIPPLE] * math.sin(x * c[C_INV_G] + c[C_RIPPLE_PHASE])
    w += c[C_H_OVER_J] * (tact - (fr - fext) * c[C_R])
    x += c[C_HG] * w
    return x, w, integ, tact, tset, dsum, fr


@njit(cache=True)
def _drive_lanes(
    a0: int, a1: int, a2: int, cst: NDArray[np.float64], cin: NDArray[np.float64],
    dst: NDArray[np.float64], fracs: NDArray[np.float64], inner_steps: int,
) -> None:
    """The drive loops of one cycle for axes a0, a1, a2 side by side (lanes may repeat).

    The three axes' steps are independent dependency chains in one loop body, so the CPU
    overlaps them; every lane does exactly the operations of :func:`_drive_step` in order, so
    the result is bit-identical to running the axes one after the other.
    """
    c0 = cst[a0]
    c1 = cst[a1]
    c2 = cst[a2]
    x0, w0, i0, t0, s0, f0 = (dst[a0, D_X], dst[a0, D_W], dst[a0, D_INT], dst[a0, D_TACT],
                              dst[a0, D_TSET], dst[a0, D_FRIC])
    x1, w1, i1, t1, s1, f1 = (dst[a1, D_X], dst[a1, D_W], dst[a1, D_INT], dst[a1, D_TACT],
                              dst[a1, D_TSET], dst[a1, D_FRIC])
    x2, w2, i2, t2, s2, f2 = (dst[a2, D_X], dst[a2, D_W], dst[a2, D_INT], dst[a2, D_TACT],
                              dst[a2, D_TSET], dst[a2, D_FRIC])
    q0, p0 = cin[a0, I_XQ], cin[a0, I_XQP]
    q1, p1 = cin[a1, I_XQ], cin[a1, I_XQP]
    q2, p2 = cin[a2, I_XQ], cin[a2, I_XQP]
    d0 = d1 = d2 = 0.0
    for j in range(inner_steps):
        if j > 0:
            p0 = q0
            q0 = np.rint(x0 * c0[C_INV_RES]) * c0[C_RES]  # rint: no float->int->float trip
            p1 = q1
            q1 = np.rint(x1 * c1[C_INV_RES]) * c1[C_RES]
            p2 = q2
            q2 = np.rint(x2 * c2[C_INV_RES]) * c2[C_RES]
        fr = fracs[j]
        x0, w0, i0, t0, s0, d0, f0 = _drive_step(
            c0, x0, w0, i0, t0, s0, q0, p0, d0, fr, cin[a0, I_CTRL], cin[a0, I_DCTRL],
            cin[a0, I_VEL], cin[a0, I_VSET0], cin[a0, I_TFFW], cin[a0, I_FEXT],
            cin[a0, I_DVEL])
        x1, w1, i1, t1, s1, d1, f1 = _drive_step(
            c1, x1, w1, i1, t1, s1, q1, p1, d1, fr, cin[a1, I_CTRL], cin[a1, I_DCTRL],
            cin[a1, I_VEL], cin[a1, I_VSET0], cin[a1, I_TFFW], cin[a1, I_FEXT],
            cin[a1, I_DVEL])
        x2, w2, i2, t2, s2, d2, f2 = _drive_step(
            c2, x2, w2, i2, t2, s2, q2, p2, d2, fr, cin[a2, I_CTRL], cin[a2, I_DCTRL],
            cin[a2, I_VEL], cin[a2, I_VSET0], cin[a2, I_TFFW], cin[a2, I_FEXT],
            cin[a2, I_DVEL])
    # a repeated lane computed the same values from the same inputs: storing twice is harmless
    for a, x, w, ig, t, s, f, q, d in ((a2, x2, w2, i2, t2, s2, f2, q2, d2),
                                       (a1, x1, w1, i1, t1, s1, f1, q1, d1),
                                       (a0, x0, w0, i0, t0, s0, f0, q0, d0)):
        dst[a, D_X] = x
        dst[a, D_W] = w
        dst[a, D_INT] = ig
        dst[a, D_TACT] = t
        dst[a, D_TSET] = s
        dst[a, D_FRIC] = f
        dst[a, D_XQ] = q
        dst[a, D_DSUM] = d


@njit(cache=True)
def _hold_settled(
    out: NDArray[np.float64], noise: NDArray[np.float64], enc_noise: NDArray[np.float64],
    st: NDArray[np.float64], par: NDArray[np.float64], cst: NDArray[np.float64], a: int,
    k0: int, k1: int, iq: float, v_lf: float, util: float, a_lf: float, tc: float, x: float,
    kt_f: float,
) -> None:
    """Cycles k0..k1-1 of a settled axis (inputs as at cycle k0 - 1, a bitwise fixed point of
    its dynamic state): outputs held, only the measurement noises (current, torque actual, the
    NC's measuring system and what the NC computes from it), motor temperature and LF filters
    move. The same operations per cycle as the full computation, with the state in
    registers."""
    if k1 <= k0:
        return
    for i in range(_N_OUT):
        if i == 8 or i == 9 or 12 <= i <= 16:
            continue
        v = out[a, i, k0 - 1]
        for k in range(k0, k1):
            out[a, i, k] = v
    rph = par[a, P_RPH]
    tamb = par[a, P_TAMB]
    rth = par[a, P_RTH]
    cth = par[a, P_CTH]
    temp = st[a, S_TEMP]
    lf_speed = st[a, S_LF_SPEED]
    lf_iabs = st[a, S_LF_IABS]
    lf_iq = st[a, S_LF_IQ]
    lf_util = st[a, S_LF_UTIL]
    iq_abs = abs(iq)
    noisy_enc = par[a, P_ENC_NOISE] > 0.0
    ctrl = out[a, 0, k0 - 1]
    vel = out[a, 5, k0 - 1]
    mod = st[a, S_MOD]
    kv = par[a, P_KV]
    dsc = cst[a, C_DSC] > 0.5
    inv_res = cst[a, C_INV_RES]
    res = cst[a, C_RES]
    for k in range(k0, k1):
        temp += tc * (rph * iq * iq - (temp - tamb) / rth) / cth
        lf_speed += a_lf * (v_lf - lf_speed)
        lf_iabs += a_lf * (iq_abs - lf_iabs)
        lf_iq += a_lf * (iq - lf_iq)
        lf_util += a_lf * (util - lf_util)
        out[a, 8, k] = iq + noise[a, k]
        out[a, 9, k] = (iq + noise[a, k]) * kt_f
        out[a, 12, k] = lf_speed
        out[a, 13, k] = lf_iabs
        out[a, 14, k] = lf_iq
        out[a, 15, k] = lf_util
        out[a, 16, k] = temp
        if noisy_enc:  # the NC's values from its noisy measuring system (the drive's are held)
            xn = np.rint((x + enc_noise[a, k]) * inv_res) * res
            diff2 = ctrl - xn
            out[a, 1, k] = xn
            if not dsc:
                out[a, 2, k] = diff2
            out[a, 3, k] = diff2
            out[a, 4, k] = mod - xn
            out[a, 7, k] = kv * diff2 + vel
    st[a, S_TEMP] = temp
    st[a, S_LF_SPEED] = lf_speed
    st[a, S_LF_IABS] = lf_iabs
    st[a, S_LF_IQ] = lf_iq
    st[a, S_LF_UTIL] = lf_util


@njit(cache=True)
def _drive_constants(par: NDArray[np.float64], h: float) -> NDArray[np.float64]:
    """Per-axis constants of the 125 us drive loops (columns ``C_*``)."""
    n_axes = par.shape[0]
    cst = np.zeros((n_axes, _N_CST))
    for a in range(n_axes):
        g = par[a, P_G]
        cur_t = par[a, P_EQ_CURR]
        cst[a, C_KV] = par[a, P_KV]
        cst[a, C_INV_G] = 1.0 / g
        cst[a, C_INV_HG] = 1.0 / (h * g)
        cst[a, C_KI_H] = par[a, P_KP] * h / par[a, P_TI]
        cst[a, C_KP] = par[a, P_KP]
        cst[a, C_TMAX] = par[a, P_KT] * par[a, P_IMAX]
        cst[a, C_A_CUR] = 1.0 - math.exp(-h / cur_t) if cur_t > 0.0 else 1.0
        cst[a, C_G] = g
        cst[a, C_VEPS] = par[a, P_VEPS]
        cst[a, C_INV_VEPS] = 1.0 / par[a, P_VEPS]
        cst[a, C_FV] = par[a, P_FV]
        cst[a, C_FC] = par[a, P_FC]
        cst[a, C_FS] = par[a, P_FS]
        cst[a, C_VS5] = 5.0 * par[a, P_VS]
        cst[a, C_INV_VS] = 1.0 / par[a, P_VS]
        cst[a, C_H_OVER_J] = h / par[a, P_J]
        cst[a, C_R] = par[a, P_R]
        cst[a, C_HG] = h * g
        cst[a, C_INV_RES] = 1.0 / par[a, P_RES]
        cst[a, C_RES] = par[a, P_RES]
        cst[a, C_DSC] = 1.0 if par[a, P_DSC] > 0.5 else 0.0
        cst[a, C_RIPPLE] = par[a, P_RIPPLE]
        cst[a, C_RIPPLE_PHASE] = par[a, P_RIPPLE_PHASE]
        cst[a, C_SPLINE] = 1.0 if par[a, P_DSC_SPLINE] > 0.5 else 0.0
    return cst


@njit(cache=True, inline="always")
def _drive_state_from(st: NDArray[np.float64], dst: NDArray[np.float64],
                      a: int) -> None:  # pragma: no cover - compiled
    """Load axis ``a``'s drive state (position, speed, integrator, torques, friction, encoder)
    from its state-vector row into the compact per-step array ``dst``."""
    dst[a, D_X] = st[a, S_X]
    dst[a, D_W] = st[a, S_W]
    dst[a, D_INT] = st[a, S_INT]
    dst[a, D_TACT] = st[a, S_TACT]
    dst[a, D_TSET] = st[a, S_TSET]
    dst[a, D_FRIC] = st[a, S_FRIC]
    dst[a, D_XQ] = st[a, S_XQ]


@njit(cache=True, inline="always")
def _drive_state_to(dst: NDArray[np.float64], target: NDArray[np.float64],
                    a: int) -> None:  # pragma: no cover - compiled
    """Write axis ``a``'s drive state from ``dst`` into row ``a`` of a state-vector array
    (the continuation state, or the start-of-cycle snapshot of the settle check)."""
    target[a, S_X] = dst[a, D_X]
    target[a, S_W] = dst[a, D_W]
    target[a, S_INT] = dst[a, D_INT]
    target[a, S_TACT] = dst[a, D_TACT]
    target[a, S_TSET] = dst[a, D_TSET]
    target[a, S_FRIC] = dst[a, D_FRIC]
    target[a, S_XQ] = dst[a, D_XQ]


@njit(cache=True)
def _servo_kernel(
    des: NDArray[np.float64],
    force: NDArray[np.float64],
    noise: NDArray[np.float64],
    enc_noise: NDArray[np.float64],
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
    cst = _drive_constants(par, h)
    fracs = np.empty(inner_steps)
    for j in range(inner_steps):
        fracs[j] = j / inner_steps
    # NC settings per axis
    mode_a = np.zeros(n_axes, np.int64)
    jtype_a = np.zeros(n_axes, np.int64)
    m_ma_a = np.ones(n_axes, np.int64)
    use = np.zeros((n_axes, _N_RING), np.bool_)
    w_ffw_a = np.zeros(n_axes)
    a_j_a = np.zeros(n_axes)
    a_dra_a = np.zeros(n_axes)
    dra_t_a = np.zeros(n_axes)
    dra_cyc_a = np.zeros(n_axes)
    a_bal_a = np.zeros(n_axes)
    bal_cyc_a = np.zeros(n_axes)
    a_mod_a = np.zeros(n_axes)
    a_lf_a = np.zeros(n_axes)
    v_lf_a = np.zeros(n_axes)
    f_out_a = np.zeros(n_axes)
    kt_f_a = np.zeros(n_axes)
    for a in range(n_axes):
        kv = par[a, P_KV]
        mode = int(par[a, P_FFW_MODE])
        jtype = int(par[a, P_JERK_TYPE])
        jtime = par[a, P_JERK_TIME]
        if jtime <= tc:
            jtype = 0
        dra_t = par[a, P_DRA_TIME]
        t_eq = par[a, P_EQ_SPEED] if mode in (1, 3) else par[a, P_EQ_CURR]
        rotary = par[a, P_ROTARY] > 0.5
        mode_a[a] = mode
        jtype_a[a] = jtype
        w_ffw_a[a] = par[a, P_FFW_WEIGHT] if mode != 0 else 0.0
        # NC filters are backward-Euler PT1s, a = Tc / (T + Tc): ramp lag exactly T
        a_j_a[a] = tc / (0.5 * jtime + tc) if jtype == 1 else 1.0
        if jtype in (2, 4):
            m_ma_a[a] = max(1, int(round(jtime / tc)))  # noqa: RUF046
        dra_t_a[a] = dra_t
        a_dra_a[a] = tc / (dra_t + tc)
        dra_cyc_a[a] = dra_t / tc
        a_bal_a[a] = tc / (t_eq + tc)
        bal_cyc_a[a] = t_eq / tc
        t_mod = t_eq if mode != 0 else 1.0 / kv
        a_mod_a[a] = tc / (t_mod + tc)
        a_lf_a[a] = 1.0 - math.exp(-tc / par[a, P_LFT])
        # unit factors: load units/s -> LF r0063 in mm/min or rpm; Nm motor -> N at slide
        v_lf_a[a] = 60.0 if not rotary else 1.0 / 6.0
        f_out_a[a] = 1.0 / par[a, P_R] if not rotary else 1.0
        # TORQUE is the drive's torque actual value: Kt x the measured current, at the slide
        kt_f_a[a] = par[a, P_KT] * f_out_a[a]
        use[a, 0] = jtype == 2 or jtype == 4
        use[a, 1] = jtype == 4
        use[a, 2] = dra_t > 0.0 and mode in (3, 4)
        use[a, 3] = mode in (3, 4)
        if st[a, S_INIT] == 0.0:
            x0 = des[a, 0] if n > 0 else 0.0
            res = par[a, P_RES]
            for i in (S_XF1, S_XF2, S_J1, S_J2, S_DRA, S_BAL, S_MOD, S_X, S_CTRL1):
                st[a, i] = x0
            st[a, S_W] = 0.0
            st[a, S_INT] = 0.0
            st[a, S_TACT] = 0.0
            st[a, S_TSET] = 0.0
            st[a, S_XQ] = round(x0 / res) * res  # encoder value of the previous latch
            st[a, S_RING] = 0.0
            st[a, S_TEMP] = par[a, P_TAMB]
            for b in range(_N_RING):
                for i in range(nring):
                    ring[a, b, i] = x0
            st[a, S_INIT] = 1.0
    dst = np.zeros((n_axes, _N_DST))
    ridx_a = np.zeros(n_axes, np.int64)
    for a in range(n_axes):
        _drive_state_from(st, dst, a)
        ridx_a[a] = int(st[a, S_RING])
    cin = np.zeros((n_axes, _N_CIN))
    before = np.zeros((n_axes, _N_STATE))  # state at the start of the cycle (settle check)
    same_in = np.zeros(n_axes, np.bool_)
    frozen = np.zeros(n_axes, np.bool_)
    fz_end = np.zeros(n_axes, np.int64)  # first cycle after a settled stretch
    active = np.zeros(n_axes, np.int64)
    for k in range(n):
        # ---- NC part of every axis; settled axes only advance noise, temperature, LF
        na = 0
        for a in range(n_axes):
            if frozen[a]:
                if k < fz_end[a]:
                    continue  # settled cycle, already written by _hold_settled
                frozen[a] = False  # the inputs changed (settled stretches end at a change)
            ridx = ridx_a[a] + 1
            if ridx == nring:
                ridx = 0
            ridx_a[a] = ridx
            xd = des[a, k]
            fext = force[a, k]
            # same inputs as the previous cycle: keep the state at the start of this cycle for
            # the settle check (a moving or loaded axis almost never gets here)
            same_in[a] = k > 0 and xd == des[a, k - 1] and fext == force[a, k - 1]
            if same_in[a]:
                for i in range(_N_STATE):
                    before[a, i] = st[a, i]
                _drive_state_to(dst, before, a)
            xf1 = st[a, S_XF1]
            xf2 = st[a, S_XF2]
            mode = mode_a[a]
            jtype = jtype_a[a]
            # ---- NC: jerk filter
            if jtype == 1:
                a_j = a_j_a[a]
                st[a, S_J1] += a_j * (xd - st[a, S_J1])
                st[a, S_J2] += a_j * (st[a, S_J1] - st[a, S_J2])
                xj = st[a, S_J2]
            elif jtype == 2 or jtype == 4:
                m_ma = m_ma_a[a]
                ring[a, 0, ridx] = xd
                s = 0.0
                for i in range(m_ma):
                    ii = ridx - i
                    if ii < 0:
                        ii += nring
                    s += ring[a, 0, ii]
                xj = s / m_ma
                if jtype == 4:
                    ring[a, 1, ridx] = xj
                    s = 0.0
                    for i in range(m_ma):
                        ii = ridx - i
                        if ii < 0:
                            ii += nring
                        s += ring[a, 1, ii]
                    xj = s / m_ma
            else:
                xj = xd
            # ---- dynamic response adaptation
            if dra_t_a[a] > 0.0:
                if mode == 3 or mode == 4:
                    ring[a, 2, ridx] = xj
                    xf = _ring_delay(ring, a, 2, ridx, dra_cyc_a[a])
                else:
                    st[a, S_DRA] += a_dra_a[a] * (xj - st[a, S_DRA])
                    xf = st[a, S_DRA]
            else:
                xf = xj
            # ---- feedforward and balancing
            vel = w_ffw_a[a] * (xf - xf1) / tc  # load units/s
            if mode == 2 or mode == 4:
                acc = (xf - 2.0 * xf1 + xf2) / (tc * tc)
                tffw = par[a, P_J] * acc / par[a, P_G]  # motor Nm
            else:
                tffw = 0.0
            if mode == 3 or mode == 4:
                ring[a, 3, ridx] = xf
                ctrl = _ring_delay(ring, a, 3, ridx, bal_cyc_a[a])
            elif mode == 1 or mode == 2:
                st[a, S_BAL] += a_bal_a[a] * (xf - st[a, S_BAL])
                ctrl = st[a, S_BAL]
            else:
                ctrl = xf
            st[a, S_MOD] += a_mod_a[a] * (xf - st[a, S_MOD])
            st[a, S_XF2] = xf1
            st[a, S_XF1] = xf
            # ---- position controller (NC): measuring system latched at t_k, with its noise;
            # the drive's speed loop reads the motor encoder (xq) without it
            xq = np.rint(dst[a, D_X] * cst[a, C_INV_RES]) * cst[a, C_RES]
            xn = np.rint((dst[a, D_X] + enc_noise[a, k]) * cst[a, C_INV_RES]) * cst[a, C_RES]
            diff2 = ctrl - xn
            cin[a, I_CTRL] = ctrl
            cin[a, I_DCTRL] = ctrl - st[a, S_CTRL1]
            cin[a, I_VEL] = vel
            cin[a, I_DVEL] = vel - st[a, S_VEL1]
            st[a, S_VEL1] = vel
            cin[a, I_VSET0] = par[a, P_KV] * diff2 + vel  # load units/s
            cin[a, I_TFFW] = tffw
            cin[a, I_FEXT] = fext
            cin[a, I_XQ] = xq
            cin[a, I_XQP] = dst[a, D_XQ]
            cin[a, I_XN] = xn
            st[a, S_CTRL1] = ctrl
            active[na] = a
            na += 1
        # ---- drive: 125 us loops of the moving axes, up to three side by side
        for lo in range(0, na, _LANES):
            a0 = active[lo]
            a1 = active[lo + 1] if lo + 1 < na else a0
            a2 = active[lo + 2] if lo + 2 < na else a0
            _drive_lanes(a0, a1, a2, cst, cin, dst, fracs, inner_steps)
        # ---- recorded values
        for q in range(na):
            a = active[q]
            tact = dst[a, D_TACT]
            w = dst[a, D_W]
            tset = dst[a, D_TSET]
            kt = par[a, P_KT]
            rph = par[a, P_RPH]
            tmax = cst[a, C_TMAX]
            a_lf = a_lf_a[a]
            f_out = f_out_a[a]
            ctrl = cin[a, I_CTRL]
            enc = cin[a, I_XN]
            diff2 = ctrl - enc
            iq = tact / kt
            temp = st[a, S_TEMP]
            temp += tc * (rph * iq * iq - (temp - par[a, P_TAMB]) / par[a, P_RTH]) / par[a, P_CTH]
            st[a, S_TEMP] = temp
            vload = w * par[a, P_G]
            v_lf = vload * v_lf_a[a]
            util = abs(tset) / tmax * 100.0
            st[a, S_LF_SPEED] += a_lf * (v_lf - st[a, S_LF_SPEED])
            st[a, S_LF_IABS] += a_lf * (abs(iq) - st[a, S_LF_IABS])
            st[a, S_LF_IQ] += a_lf * (iq - st[a, S_LF_IQ])
            st[a, S_LF_UTIL] += a_lf * (util - st[a, S_LF_UTIL])
            out[a, 0, k] = ctrl
            out[a, 1, k] = enc
            out[a, 2, k] = dst[a, D_DSUM] / inner_steps if cst[a, C_DSC] > 0.5 else diff2
            out[a, 3, k] = diff2
            out[a, 4, k] = st[a, S_MOD] - enc
            out[a, 5, k] = cin[a, I_VEL]
            out[a, 6, k] = cin[a, I_TFFW] * f_out
            out[a, 7, k] = cin[a, I_VSET0]
            out[a, 8, k] = iq + noise[a, k]
            out[a, 9, k] = (iq + noise[a, k]) * kt_f_a[a]
            out[a, 10, k] = abs(tset) / par[a, P_TRATED] * 100.0
            out[a, 11, k] = tact * w + rph * iq * iq
            out[a, 12, k] = st[a, S_LF_SPEED]
            out[a, 13, k] = st[a, S_LF_IABS]
            out[a, 14, k] = st[a, S_LF_IQ]
            out[a, 15, k] = st[a, S_LF_UTIL]
            out[a, 16, k] = temp
            out[a, 17, k] = dst[a, D_X]
            out[a, 18, k] = dst[a, D_FRIC]
            out[a, 19, k] = w
            # ---- settled? same inputs as the previous cycle and the state did not move
            if not same_in[a]:
                continue
            if (dst[a, D_X] != before[a, S_X] or w != before[a, S_W]
                    or dst[a, D_INT] != before[a, S_INT] or tact != before[a, S_TACT]
                    or tset != before[a, S_TSET] or dst[a, D_FRIC] != before[a, S_FRIC]
                    or dst[a, D_XQ] != before[a, S_XQ]):
                continue
            ok = True
            for i in (S_XF1, S_XF2, S_J1, S_J2, S_DRA, S_BAL, S_MOD, S_CTRL1, S_VEL1):
                if st[a, i] != before[a, i]:
                    ok = False
            for b in range(_N_RING):
                if ok and use[a, b]:
                    v0 = ring[a, b, ridx_a[a]]
                    for i in range(nring):
                        if ring[a, b, i] != v0:
                            ok = False
                            break
            if ok:
                frozen[a] = True
                # the following cycles with the same inputs, written in one tight loop; the
                # cycle loop skips them and resumes at the first cycle whose inputs differ
                k1 = k + 1
                while k1 < n and des[a, k1] == des[a, k] and force[a, k1] == force[a, k]:
                    k1 += 1
                _hold_settled(out, noise, enc_noise, st, par, cst, a, k + 1, k1, iq, v_lf, util,
                              a_lf, tc, dst[a, D_X], kt_f_a[a])
                fz_end[a] = k1
                ridx_a[a] = (ridx_a[a] + (k1 - k - 1)) % nring  # the skipped cycles' advance
    for a in range(n_axes):
        _drive_state_to(dst, st, a)
        st[a, S_RING] = float(ridx_a[a])


# ---------------------------------------------------------------- Python layer
def servo_parameters(axes: Sequence[FeedAxis]) -> NDArray[np.float64]:
    """Pack feed-axis descriptions into the kernel's parameter matrix.

    Parameters
    ----------
    axes : sequence of FeedAxis
        Axis descriptions (:class:`cnctwin.sim.machine.FeedAxis`).

    Returns
    -------
    numpy.ndarray, shape (n_axes, 34)
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
        p[i, P_ENC_NOISE] = ax.encoder_noise
        p[i, P_RIPPLE] = ax.ripple_n
        p[i, P_RIPPLE_PHASE] = ax.ripple_phase_rad
        p[i, P_DSC_SPLINE] = 1.0 if ax.dsc_spline else 0.0
    return p


@dataclass
class ServoState:
    """State of the servo kernel between chunks (pass ``trace.state`` to the next call).

    Attributes
    ----------
    values : numpy.ndarray, shape (n_axes, 23)
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
    out: NDArray[np.float64] | None = None,
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
        Source of the measurement noises: the current (``FeedAxis.current_noise_a``, also in
        the torque actual value ``TORQUE``) and the NC's measuring system
        (``FeedAxis.encoder_noise``); ``None`` gives a noise-free run.
    out : numpy.ndarray, optional
        Buffer for the kernel's outputs, C-contiguous float64 of shape (n_axes, 20, n_cycles);
        the trace's arrays are then views into it (``simulate`` reuses one buffer between
        chunks when its sink does not keep them: no fresh 40 MB per 50 000-cycle chunk).
        Default: a new array.

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
    advanced (in one tight loop over the whole stretch of unchanged inputs). The output is
    bit-identical to the full computation (``tests/sim/test_kernels_reference.py``); an axis
    that has never moved (C1/B1 in drilling) costs ~1/20 of a moving one. An axis hunting by one
    encoder increment at standstill (the limit cycle of integral action on a quantised encoder)
    is not a fixed point and keeps being simulated.

    The kernel runs cycle by cycle over all axes: first the NC part of every axis, then the
    125 us drive loops of the moving axes with up to three axes side by side in one loop body
    (``_drive_lanes``). Each 125 us step is a serial chain of ~20 dependent floating-point
    operations (encoder -> speed error -> PI -> current PT1 -> friction -> mechanics), so one
    axis at a time leaves the CPU waiting on latencies; three independent chains in one body
    overlap. Each lane does the same operations in the same order as one axis alone, so the
    output is bit-identical to the per-axis reference (``tests/sim/test_kernels_reference.py``,
    every FFW mode, jerk filter type, DRA and DSC setting); the drive part runs ~2.2x faster.
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
    enc_noise = np.zeros_like(des)
    if rng is not None:
        sd = par[:, P_NOISE]
        esd = par[:, P_ENC_NOISE]
        if np.any(esd > 0):
            # current and measuring-system noise from one cycle-major block: a chunked run
            # consumes the stream like one long run
            z = rng.standard_normal((n, 2 * n_axes)).T
            np.multiply(z[:n_axes], sd[:, None], out=noise)
            np.multiply(z[n_axes:], esd[:, None], out=enc_noise)
        elif np.any(sd > 0):
            # drawn cycle-major so that chunked runs consume the stream like one long run;
            # scaled straight into the axis-major array (15x faster than (z * sd).T.copy(),
            # the same products)
            np.multiply(rng.standard_normal((n, n_axes)).T, sd[:, None], out=noise)
    st = state.copy() if state is not None else ServoState.new(n_axes)
    if st.values.shape != (n_axes, _N_STATE):
        raise ConfigError(
            f"state is for {st.values.shape[0]} axes, des_pos has {n_axes}; pass the state of "
            "the same machine"
        )
    if out is None:
        out = np.empty((n_axes, _N_OUT, n))
    elif out.shape != (n_axes, _N_OUT, n) or out.dtype != np.float64 or not out.flags.c_contiguous:
        raise ConfigError(f"out must be C-contiguous float64 of shape ({n_axes}, {_N_OUT}, {n}), "
                          f"not {out.dtype} {out.shape}")
    _servo_kernel(des, force, noise, enc_noise, par, st.values, st.history, out, cycle_time_s,
                  inner_steps)
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
