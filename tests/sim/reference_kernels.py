"""Reference kernels: the servo and spindle kernels as they were before the speed work.

Kept unchanged (commit 2390685 of ``servo.py`` and ``spindle.py``) so that

* ``tests/sim/test_kernels_reference.py`` checks that the optimised kernels give the same
  output (bit-identical for the servo, within float rounding for the spindle), and
* ``benchmarks/bench_sim.py`` measures the speed-up against them in the same run.

The position-control setpoint of the spindle (SPOS move to the nearest turn, fine
interpolation over the cycle) is a physics correction of session 2 made after the speed work;
both kernels call the same :func:`cnctwin.sim.spindle._position_setpoint` for it.

Kept in ``tests/`` so that the installed package carries only the kernels it runs (issue 16).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from cnctwin.sim.spindle import _position_setpoint

__all__ = ["servo_kernel_reference", "spindle_kernel_reference"]

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
def servo_kernel_reference(
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
        # unit factors: load units/s -> recorded speed unit
        v_out = 60.0 if not rotary else 1.0 / 6.0  # mm/s -> mm/min ; deg/s -> rpm
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
            # ---- NC: jerk filter
            xd = des[a, k]
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
            xq = round(x * inv_res) * res
            enc = xq
            diff2 = ctrl - enc
            vset0 = kv * diff2 + vel  # load units/s
            dctrl = ctrl - ctrl1
            ctrl1 = ctrl
            # ---- drive: 125 us loops
            fext = force[a, k]
            dsum = 0.0
            for j in range(inner_steps):
                if j > 0:
                    xq_prev = xq
                    xq = round(x * inv_res) * res
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
            lf_speed += a_lf * (vload * v_out - lf_speed)
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



@njit(cache=True)
def _friction_nm_reference(
    w: float, t_rotor: float, pv: NDArray[np.float64]
) -> float:  # pragma: no cover
    """Friction torque [Nm] at speed w [rad/s] and bearing temperature [degC] (signed)."""
    dt_k = t_rotor - pv[8]
    b = pv[6] * max(0.05, 1.0 + pv[9] * dt_k)
    tau_c = pv[7] * max(0.05, 1.0 + pv[10] * dt_k)
    aw = abs(w)
    x = (aw - pv[13]) / pv[14]
    softplus = x + math.log1p(math.exp(-x)) if x > 0.0 else math.log1p(math.exp(x))
    w_eff = aw - (1.0 - pv[43]) * pv[14] * softplus
    sgn = math.tanh(w / pv[15])
    return sgn * (tau_c + pv[11] * math.exp(-aw / pv[12]) + b * w_eff)


@njit(cache=True)
def spindle_kernel_reference(  # pragma: no cover - compiled
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
    for k in range(n):
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
        tau_load = load_nm[k] + pv[41] * noise[k, 2]
        # magnet flux at rotor temperature (Kt drift) - constant within a cycle
        psi_t = psi0 * (1.0 + pv[2] * (tr - pv[3]))
        for i_in in range(inner_steps):
            if m == 1:
                pos_err = pc0 + dpc * i_in - th * 180.0 / math.pi
                w_ref = ff_w + kv * pos_err * math.pi / 180.0
            else:
                w_ref = w_cmd
            # field weakening: id from the voltage ellipse (steady state, Rs neglected)
            we = p * abs(w)
            id_ref = 0.0
            if we > 1.0:
                arg = (umax / we) ** 2 - (lq * i_q) ** 2
                id_ref = min(0.0, (math.sqrt(arg) - psi_t) / ld) if arg > 0.0 else -psi_t / ld
                if id_ref < -0.95 * imax:
                    id_ref = -0.95 * imax
            # speed PI with torque limit from the current circle (anti-windup: clamp)
            kt_drive = 1.5 * p * (psi0 + (ld - lq) * i_d)
            iq_avail = math.sqrt(max(imax * imax - id_ref * id_ref, 0.0))
            t_max = kt_drive * iq_avail
            e = w_ref - w
            t_ref = kp * e + integ
            if t_ref > t_max:
                t_ref = t_max
            elif t_ref < -t_max:
                t_ref = -t_max
            else:
                integ += ki * e * dt
            iq_ref = t_ref / kt_drive
            # current loop (first order)
            i_d += a_i * (id_ref - i_d)
            i_q += a_i * (iq_ref - i_q)
            # saturation lowers the magnet flux contribution at high |iq|
            x = abs(i_q) / pv[4] - 1.0
            sat = 1.0 / (1.0 + pv[5] * x * x) if x > 0.0 else 1.0
            psi_act = psi_t * sat
            te = 1.5 * p * (psi_act + (ld - lq) * i_d) * i_q
            fr = _friction_nm_reference(w, tr, pv)
            w += dt * (te - fr - tau_load) / j
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
        kt_nom = 1.5 * p * psi0 * sq2
        speed_meas = w * rpm + pv[40] * noise[k, 1]
        kt_drive_now = 1.5 * p * (psi0 + (ld - lq) * i_d) * sq2
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
