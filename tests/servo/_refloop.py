"""UNIT-TEST STAND-IN ONLY: a small reference position loop to generate synthetic recordings.

This is *not* the project simulator (``cnctwin.sim``); it exists so the servo analyses can be
unit-tested before and independently of it, on data with known parameters. It is written
independently of ``cnctwin.servo`` (discrete sample-window moving average, sub-stepped speed
loop) so the analysis code is never compared with itself. The real proof on the simulator is in
``tests/servo/test_identify_sim.py``.

Structure (thesis Fig. 3.1): DES -> moving average of ``jerk_n`` samples -> integer delay
``dra_cycles`` -> PT1 balancing ``bal_t_s`` -> CTRL; CMD = Kv (CTRL - ENC) + w * v_ffw with
v_ffw = d(jerk-filtered DES)/dt; speed loop = dead time ``speed_delay_s`` + PT1 ``speed_t_s``
integrated with 16 sub-steps per cycle; ENC = integral of speed. Current from inertia and
Coulomb + viscous friction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from cnctwin.recording import Recording


@dataclass
class RefLoop:
    kv_1_s: float = 40.0
    ffw_weight: float = 1.0
    jerk_n: int = 8
    dra_cycles: int = 1
    bal_t_s: float = 0.0
    speed_t_s: float = 0.002
    speed_delay_s: float = 0.001
    coulomb_a: float = 0.8
    viscous_a_per_mm_s: float = 0.01
    inertia_a_per_mm_s2: float = 0.0005
    cycle_s: float = 0.002
    ffw_unit_per_min: bool = True  # write VEL_FFW / CMD_SPEED in mm/min (catalog convention)
    enc_quantum_mm: float = 0.0


def trapezoid_moves(
    targets: list[float], speeds: list[float], *, accel: float = 2000.0, dwell_s: float = 0.2,
    cycle_s: float = 0.002, start: float = 0.0,
) -> NDArray[np.float64]:
    """Point-to-point moves with trapezoidal velocity (mm, mm/s, mm/s^2), sampled per cycle."""
    pos = [start] * int(dwell_s / cycle_s)
    x = start
    for tgt, v in zip(targets, speeds, strict=True):
        dist = tgt - x
        sgn = np.sign(dist)
        d = abs(dist)
        vpk = min(v, np.sqrt(d * accel))
        ta = vpk / accel
        tc = (d - vpk * ta) / vpk if vpk > 0 else 0.0
        t_tot = 2 * ta + tc
        t = np.arange(1, int(np.ceil(t_tot / cycle_s)) + 1) * cycle_s
        t = np.minimum(t, t_tot)
        s = np.where(
            t < ta, 0.5 * accel * t**2,
            np.where(t < ta + tc, 0.5 * accel * ta**2 + vpk * (t - ta),
                     d - 0.5 * accel * np.maximum(t_tot - t, 0) ** 2))
        pos.extend((x + sgn * s).tolist())
        x = tgt
        pos.extend([x] * int(dwell_s / cycle_s))
    return np.asarray(pos)


def run(loop: RefLoop, des: NDArray[np.float64], *, axis: str = "X1",
        with_ctrl: bool = True) -> Recording:
    n = des.size
    dt = loop.cycle_s
    # jerk filter: mean of the last jerk_n samples
    pad = np.concatenate([np.full(loop.jerk_n, des[0]), des])
    cs = np.cumsum(pad)
    jf = (cs[loop.jerk_n:] - cs[:-loop.jerk_n]) / loop.jerk_n if loop.jerk_n > 1 else des.copy()
    jf = jf[-n:]
    dl = np.concatenate([np.full(loop.dra_cycles, jf[0]), jf])[:n]
    ctrl = dl.copy()
    if loop.bal_t_s > 0:
        a = np.exp(-dt / loop.bal_t_s)
        for k in range(1, n):
            ctrl[k] = a * ctrl[k - 1] + (1 - a) * dl[k]
    v_ffw = np.gradient(jf, dt) * loop.ffw_weight
    sub = 16
    h = dt / sub
    dsteps = round(loop.speed_delay_s / h)
    hist = [0.0] * (dsteps + 1)
    enc = np.empty(n)
    cmd = np.empty(n)
    vel_end = np.empty(n)
    x = des[0]
    v = 0.0
    acc = np.zeros(n)
    for k in range(n):
        xq = np.round(x / loop.enc_quantum_mm) * loop.enc_quantum_mm if loop.enc_quantum_mm else x
        enc[k] = xq
        u = loop.kv_1_s * (ctrl[k] - xq) + v_ffw[k]
        cmd[k] = u
        v0 = v
        for _ in range(sub):
            hist.append(u)
            ud = hist.pop(0)
            if loop.speed_t_s > 0:
                v += (ud - v) * (1 - np.exp(-h / loop.speed_t_s))
            else:
                v = ud
            x += v * h
        vel_end[k] = v
        acc[k] = (v - v0) / dt
    cur = (loop.inertia_a_per_mm_s2 * acc + loop.coulomb_a * np.sign(np.round(vel_end, 6))
           + loop.viscous_a_per_mm_s * vel_end)
    f = 60.0 if loop.ffw_unit_per_min else 1.0
    sig = {
        f"DES_POS|{axis}": des,
        f"ENC_POS|{axis}": enc,
        f"VEL_FFW|{axis}": v_ffw * f,
        f"CMD_SPEED|{axis}": cmd * f,
        f"CURRENT|{axis}": cur,
        f"TORQUE_FFW|{axis}": np.zeros(n),
    }
    if with_ctrl:
        sig[f"CTRL_POS|{axis}"] = ctrl
        sig[f"CTRL_DIFF2|{axis}"] = ctrl - enc
    rec = Recording.from_arrays(np.arange(n) + 1000, sig, cycle_time_s=dt,
                                source_format="unit-test reference loop")
    if not loop.ffw_unit_per_min:
        rec.meta.units[f"VEL_FFW|{axis}"] = "mm/min"  # deliberately wrong declaration
        rec.meta.units[f"CMD_SPEED|{axis}"] = "mm/min"
    return rec


def standard_des(cycle_s: float = 0.002) -> NDArray[np.float64]:
    """Back-and-forth moves at several speeds in both directions (mm)."""
    return trapezoid_moves(
        [40.0, 0.0, 60.0, 10.0, 50.0, -20.0, 30.0],
        [100.0, 150.0, 250.0, 60.0, 200.0, 120.0, 80.0], cycle_s=cycle_s)
