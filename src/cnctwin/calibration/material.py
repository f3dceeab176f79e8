"""The user's workpiece material from their own cuts: milling coefficients without a dynamometer.

``cnctwin calibrate material`` reads recordings of milling cuts, the program that made them,
the tool table and the stock, and fits the linear edge-force coefficients (Altintas,
*Manufacturing Automation*, 2nd ed., ch. 2):

1. **Engagement** of every control cycle: the recorded tool path (``ENC_POS`` of X1/Y1/Z1,
   the active tool from the block events) swept through the stock's Z-map
   (:class:`cnctwin.engagement.ZMap`): entry and exit angle, axial depth; feed per tooth
   from the recorded path speed and spindle speed.
2. **Loads** from the drives, through the calibrated machine: the cutting torque from the
   spindle current (:meth:`cnctwin.spindle.SpindleModel.cutting_torque`: Kt I - B n -
   tau_f - J dOmega/dt), the cutting forces on X, Y and Z from the axis force at the slide
   (``TORQUE``) minus the calibrated friction and the effective mass (slide plus the
   rotor's inertia through the screw) times the acceleration.
3. **Windows** of :data:`WINDOW_CYCLES` cycles with one tool and a steady speed: the mean of
   each load and of each engagement term (the loads are linear in the coefficients, so the
   window means are too; the tooth-passing ripple averages out).
4. **Least squares**: mean torque = Ktc X_c + Kte X_e + d (d: what the friction law leaves
   at this speed; air windows pin it); then, with Ktc and Kte, the force along the feed
   (held by the moving axis; the moving axis' force ripple per motor revolution as a
   nuisance term) gives Krc, Kre, and the axial force (one offset per Z level) Kac, Kae.
   The force across the feed is not used: the axis that holds it stands and vibrates with
   the tooth passing, and its Coulomb friction sticks and slips. Standard errors from the
   residuals, with the relative uncertainty of Kt added in quadrature to Ktc and Kte.

A coefficient whose regressor does not vary enough (no partial immersion, one feed) is
reported as not identified, with the reason, and keeps the base material's value.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cnctwin.engagement import Stock, ZMap, runs_of
from cnctwin.exceptions import IdentificationError
from cnctwin.machine import MachineFile, ToolTable
from cnctwin.recording import Recording
from cnctwin.sim.cutting import Material, MillingCoefficients, arc_integrals
from cnctwin.sim.materials import MILLING_KEYS
from cnctwin.spindle import SpindleModel

__all__ = ["UNITS", "WINDOW_CYCLES", "MaterialCalibration", "calibrate_material",
           "engagement_windows"]

WINDOW_CYCLES = 50
"""Cycles per averaging window (0.1 s at 2 ms: five revolutions at 3000 rpm)."""

UNITS: dict[str, str] = {"ktc_n_per_mm2": "N/mm^2", "krc_n_per_mm2": "N/mm^2",
                         "kac_n_per_mm2": "N/mm^2", "kte_n_per_mm": "N/mm",
                         "kre_n_per_mm": "N/mm", "kae_n_per_mm": "N/mm"}
"""Unit of each milling coefficient."""


@dataclass
class MaterialCalibration:
    """What :func:`calibrate_material` returns.

    Attributes
    ----------
    name : str
        Material name.
    coefficients : MillingCoefficients
        Fitted (or, where not identified, the base material's) coefficients.
    uncertainty : dict
        Coefficient key -> standard uncertainty (same unit); NaN where not identified.
    identified : dict
        Coefficient key -> True when fitted.
    reasons : dict
        Coefficient key -> why it was not identified.
    windows : int
        Cutting windows used.
    residual_torque_nm : float
        RMS residual of the torque fit [Nm].
    offset_torque_nm : float
        Fitted torque offset d (friction left over) [Nm].
    notes : list of str
        What the calibration saw.
    """

    name: str
    coefficients: MillingCoefficients
    uncertainty: dict[str, float]
    identified: dict[str, bool]
    reasons: dict[str, str] = field(default_factory=dict)
    windows: int = 0
    residual_torque_nm: float = math.nan
    offset_torque_nm: float = math.nan
    notes: list[str] = field(default_factory=list)

    @property
    def material(self) -> Material:
        """A :class:`Material` with these coefficients (Kienzle pair from the milling line)."""
        k = self.coefficients
        mc = 0.22
        kc1 = (k.ktc_n_per_mm2 * 0.1 + k.kte_n_per_mm) / 0.1 ** (1.0 - mc)
        return Material(self.name, kc1_n_per_mm2=kc1, mc=mc, milling=k)

    def machine_table(self, *, provenance: dict[str, Any]) -> dict[str, Any]:
        """The ``[materials.NAME]`` table for the machine file."""
        mill: dict[str, Any] = {}
        for key in MILLING_KEYS:
            rec: dict[str, Any] = {"value": float(getattr(self.coefficients, key)),
                                   "unit": UNITS[key]}
            u = self.uncertainty.get(key, math.nan)
            if self.identified.get(key) and math.isfinite(u):
                rec["uncertainty"] = float(u)
                rec["provenance"] = provenance
            else:
                rec["identified"] = False
                rec["reason"] = self.reasons.get(key, "not identified")
            mill[key] = rec
        return {"source": "cnctwin calibrate material", "windows": self.windows,
                "milling": mill}


@dataclass(frozen=True)
class _Windows:
    """Window means: torque, forces in the feed frame, and the engagement regressors."""

    torque: NDArray[np.float64]
    fx: NDArray[np.float64]
    fy: NDArray[np.float64]
    fz: NDArray[np.float64]
    reg: NDArray[np.float64]  # columns: see _REG
    cutting: NDArray[np.bool_]
    ripple: NDArray[np.float64]  # X sin (Fx_f, Fy_f), X cos (..), Y sin (..), Y cos (..)
    z_level: NDArray[np.float64]


_REG = ("G_c_Sn", "G_span", "G_c_S2", "G_Sc", "G_c_Ss", "G_Sn", "R")


def _src(rec: Recording) -> str:
    return ", ".join(rec.meta.source_files) or "recording"


def _tool_per_cycle(rec: Recording) -> NDArray[np.int64]:
    ev = rec.events[rec.events["kind"] == "block"].sort_values("cycle", kind="stable")
    if ev.empty or "active_tool" not in ev:
        raise IdentificationError(f"{_src(rec)}: no block events with the active tool; "
                                  "record with the NC events (Capture4Analysis)")
    bc = ev["cycle"].to_numpy(dtype=np.int64)
    tools = ev["active_tool"].fillna(0).to_numpy(dtype=np.int64)
    k = np.searchsorted(bc, np.asarray(rec.cycles, dtype=np.int64), side="right") - 1
    return np.where(k >= 0, tools[np.maximum(k, 0)], 0)


def _signal(rec: Recording, code: str, axis: str) -> NDArray[np.float64]:
    if not rec.has(code, axis):
        raise IdentificationError(
            f"{_src(rec)}: no {code}|{axis}; the material calibration "
            "needs the spindle current and the axis positions and forces (a "
            "Capture4Analysis recording of the HF signals)")
    return np.asarray(rec.signal(code, axis).to_numpy(dtype=np.float64))


def engagement_windows(rec: Recording, *, mfile: MachineFile, tools: ToolTable,
                       zmap: ZMap, window_cycles: int = WINDOW_CYCLES) -> _Windows:
    """Window means of the loads and the engagement regressors of one recording.

    Parameters
    ----------
    rec : Recording
        A recording of the program (HF signals and block events).
    mfile : MachineFile
        The calibrated machine (spindle law, axis friction and mass).
    tools : ToolTable
        Tool table.
    zmap : ZMap
        The stock (swept and cut by this call: recordings in machining order).
    window_cycles : int
        Cycles per window.

    Returns
    -------
    _Windows
    """
    m = mfile.machine
    dt = m.cycle_time_s
    tool = _tool_per_cycle(rec)
    pos = {a: _signal(rec, "ENC_POS", a) for a in ("X1", "Y1", "Z1")}
    for axn, v in pos.items():
        if not np.isfinite(v).all():
            bad = int(np.count_nonzero(~np.isfinite(v)))
            raise IdentificationError(f"{_src(rec)}: ENC_POS|{axn} has {bad} missing "
                                      "samples; the Z-map needs the whole path")
    speed = _signal(rec, "CMD_SPEED", m.spindle_name)
    n = np.abs(speed)
    cur = _signal(rec, "CURRENT", m.spindle_name)
    model = SpindleModel.from_machine(mfile)
    # the load brakes the rotation: positive for M3 and M4 alike
    torque = model.cutting_torque(cur, speed, fs_hz=1.0 / dt) * np.sign(speed)
    vel = {a: np.gradient(v, dt) for a, v in pos.items()}
    acc = {a: np.gradient(v, dt) for a, v in vel.items()}
    ext = {}
    for axn in ("X1", "Y1", "Z1"):
        ax = m.axis(axn)
        slide = _signal(rec, "TORQUE", axn)
        v = vel[axn]
        fric = ax.friction_n(v)
        # the slide and the motor's rotor, as the slide feels them: J_total / r^2 [kg]
        m_eff = ax.total_inertia_kgm2 / ax.motor_torque_per_load_force**2
        ext[axn] = -(slide - fric - m_eff * acc[axn] / 1000.0)
    e0 = np.full(tool.size, np.nan)
    e1 = np.full(tool.size, np.nan)
    depth = np.zeros(tool.size)
    z_teeth = np.zeros(tool.size)
    radius = np.zeros(tool.size)
    for t, lo, hi in runs_of(tool):
        if t not in tools:
            continue
        spec = tools.get(t)
        eng = zmap.sweep(pos["X1"][lo:hi], pos["Y1"][lo:hi], pos["Z1"][lo:hi],
                         diameter_mm=spec.diameter_mm)
        if spec.kind != "end_mill":
            continue
        e0[lo:hi], e1[lo:hi], depth[lo:hi] = eng.entry_rad, eng.exit_rad, eng.axial_depth_mm
        z_teeth[lo:hi] = spec.flutes
        radius[lo:hi] = spec.diameter_mm / 2.0
    vxy = np.hypot(vel["X1"], vel["Y1"]) * 60.0
    c = np.where((n > 1.0) & (z_teeth > 0), vxy / np.maximum(n, 1.0) / np.maximum(z_teeth, 1),
                 0.0)
    # the feed direction from the set point: the encoders' velocity also carries the axes'
    # vibration under the tooth passing, which correlates with the cutting force (-4 % on
    # Krc when the encoder's direction was used)
    vset = {a: np.gradient(_signal(rec, "DES_POS", a), dt) for a in ("X1", "Y1")}
    th = np.arctan2(vset["Y1"], vset["X1"])
    on = np.isfinite(e0) & (depth > 0.0) & (c > 0.0)
    p0 = np.where(on, e0, 0.0)
    p1 = np.where(on, e1, 0.0)
    a = np.where(on, depth, 0.0)
    g = z_teeth * a / (2.0 * math.pi)
    _, sn, sc, ss, s2 = arc_integrals(p0, p1)
    reg = np.vstack([g * c * sn * radius / 1000.0, g * (p1 - p0) * radius / 1000.0,
                     g * c * s2, g * sc, g * c * ss, g * sn, radius]).T
    ct, st = np.cos(th), np.sin(th)
    fxf = ext["X1"] * ct + ext["Y1"] * st  # machine -> feed frame
    fyf = -ext["X1"] * st + ext["Y1"] * ct
    # force ripple of a moving axis, once per motor revolution (cogging, commutation): the
    # cuts of a calibration program start at the same positions, so it does not average
    # out; its sine and cosine in the feed frame are nuisance regressors
    rip = []
    for axn, cf, cs in (("X1", ct, -st), ("Y1", st, ct)):
        ax = m.axis(axn)
        ph = 2.0 * math.pi * pos[axn] / max(ax.screw_pitch_mm, 1e-9)
        moving = np.abs(vel[axn]) > 0.5
        for f in (np.sin(ph), np.cos(ph)):
            rip.append(np.where(moving, f, 0.0) * cf)  # into Fx_f
            rip.append(np.where(moving, f, 0.0) * cs)  # into Fy_f
    ripple = np.vstack(rip).T
    # windows: one tool, steady speed (within 1 %), all cycles cutting or all in air with an
    # end mill turning; edges of the recording dropped
    w = window_cycles
    nwin = tool.size // w
    rows: list[int] = []
    kind: list[bool] = []
    for i in range(nwin):
        sl = slice(i * w, (i + 1) * w)
        if not (z_teeth[sl] > 0).all() or np.ptp(tool[sl]) != 0:
            continue
        nn = n[sl]
        if nn.mean() < 100.0 or np.ptp(nn) > 0.01 * nn.mean():
            continue
        if on[sl].all():
            rows.append(i)
            kind.append(True)
        elif not on[sl].any() and (np.hypot(vel["X1"][sl], vel["Y1"][sl]) > 0.1).all():
            rows.append(i)
            kind.append(False)
    if not rows:
        empty = np.zeros(0)
        return _Windows(torque=empty, fx=empty, fy=empty, fz=empty,
                        reg=np.zeros((0, len(_REG))), cutting=np.zeros(0, dtype=bool),
                        ripple=np.zeros((0, 8)),
                        z_level=empty)

    def wmean(x: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.array([float(np.mean(x[i * w:(i + 1) * w])) for i in rows])

    regw = np.vstack([wmean(reg[:, j]) for j in range(reg.shape[1])]).T
    ripw = np.vstack([wmean(ripple[:, j]) for j in range(ripple.shape[1])]).T
    return _Windows(torque=wmean(torque), fx=wmean(fxf), fy=wmean(fyf), fz=wmean(ext["Z1"]),
                    reg=regw, cutting=np.array(kind), ripple=ripw,
                    z_level=np.round(wmean(pos["Z1"]), 2))


def _lstsq(a: NDArray[np.float64], y: NDArray[np.float64]
           ) -> tuple[NDArray[Any], NDArray[Any], float]:
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    res = y - a @ coef
    dof = max(y.size - a.shape[1], 1)
    s2 = float(res @ res) / dof
    try:
        cov = s2 * np.linalg.inv(a.T @ a)
        se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    except np.linalg.LinAlgError:
        se = np.full(a.shape[1], np.nan)
    return coef, se, math.sqrt(s2)


def calibrate_material(recordings: Sequence[Recording], *, name: str, mfile: MachineFile,
                       tools: ToolTable, stock: Stock, base: Material | None = None,
                       window_cycles: int = WINDOW_CYCLES) -> MaterialCalibration:
    """Fit the milling coefficients of a material from recordings of cuts.

    Parameters
    ----------
    recordings : sequence of Recording
        The program's recordings, in machining order (each cuts what the earlier left).
    name : str
        Material name (the key in the machine file).
    mfile : MachineFile
        The calibrated machine.
    tools : ToolTable
        Tool table.
    stock : Stock
        The raw part before the first recording.
    base : Material, optional
        Values kept where a coefficient is not identified (default: the library material
        of that name, else aisi1045).
    window_cycles : int, default :data:`WINDOW_CYCLES`
        Cycles per averaging window.

    Returns
    -------
    MaterialCalibration

    Raises
    ------
    IdentificationError
        No cutting window (the recordings do not mill this stock with an end mill of the
        table), or a signal missing.
    """
    from cnctwin.sim.cutting import MATERIALS

    b = base if base is not None else MATERIALS.get(name.lower(), MATERIALS["aisi1045"])
    bk = b.milling if b.milling is not None else MATERIALS["aisi1045"].milling
    assert bk is not None
    zmap = ZMap(stock)
    parts = [engagement_windows(r, mfile=mfile, tools=tools, zmap=zmap,
                                window_cycles=window_cycles) for r in recordings]
    tq = np.concatenate([p.torque for p in parts])
    fx = np.concatenate([p.fx for p in parts])
    fy = np.concatenate([p.fy for p in parts])
    fz = np.concatenate([p.fz for p in parts])
    reg = np.vstack([p.reg for p in parts])
    rip = np.vstack([p.ripple for p in parts])
    cut = np.concatenate([p.cutting for p in parts])
    zlev = np.concatenate([p.z_level + 1e4 * k for k, p in enumerate(parts)])
    if cut.sum() < 4:
        raise IdentificationError(f"{int(cut.sum())} steady cutting windows of "
                            f"{window_cycles * mfile.machine.cycle_time_s:g} s in the recordings:"
                            " the material calibration needs end-mill cuts at a steady spindle "
                            "speed through the given stock (check --stock and --tools)")
    notes: list[str] = []
    ident: dict[str, bool] = {}
    unc: dict[str, float] = {}
    reasons: dict[str, str] = {}
    vals: dict[str, float] = {k: float(getattr(bk, k)) for k in MILLING_KEYS}
    # torque: Ktc, Kte and an offset
    a_t = np.column_stack([reg[:, 0], reg[:, 1], np.ones(tq.size)])
    coef_t, se_t, rms_t = _lstsq(a_t, tq)
    rec_kt = mfile.record("spindle.kt_nm_per_a")
    kt_u = (abs(float(rec_kt.uncertainty) / float(rec_kt.value))
            if rec_kt is not None and rec_kt.uncertainty is not None and rec_kt.value else 0.0)
    for j, key in enumerate(("ktc_n_per_mm2", "kte_n_per_mm")):
        vals[key] = float(coef_t[j])
        unc[key] = float(math.hypot(se_t[j], kt_u * coef_t[j]))
        ident[key] = bool(np.isfinite(se_t[j]) and coef_t[j] > 0)
        if not ident[key]:
            reasons[key] = "the fit gave no positive value with a finite error"
    if np.linalg.matrix_rank(a_t[cut]) < 3 and cut.all():
        notes.append("no air windows: the torque offset and the edge coefficient Kte share "
                     "their information (cut with the spindle turning in air as well)")
    # radial: with Ktc, Kte, from the feed-frame forces
    ktc, kte = vals["ktc_n_per_mm2"], vals["kte_n_per_mm"]
    sel = cut
    y1 = fx[sel] - (-ktc * reg[sel, 2] - kte * reg[sel, 3])
    y2 = fy[sel] - (ktc * reg[sel, 4] + kte * reg[sel, 5])
    # only the force along the feed: it is held by the moving axis, whose friction is the
    # calibrated law. The force across the feed is held by an axis that stands and
    # vibrates with the tooth passing; its Coulomb friction sticks and slips, so its mean
    # current is not the mean cutting force (-3 to -7 % on Krc in the simulator; more with
    # a real axis' stiction); it is not used.
    del y2
    rx = rip[sel][:, 0::2]  # ripple into Fx_f (X sin, X cos, Y sin, Y cos)
    rx = rx[:, np.abs(rx).sum(axis=0) > 1e-6]  # axes that move in the cuts
    a1 = np.column_stack([-reg[sel, 4], -reg[sel, 5], rx])
    coef_r, se_r, _ = _lstsq(a1, y1)
    for j, key in enumerate(("krc_n_per_mm2", "kre_n_per_mm")):
        vals[key] = float(coef_r[j])
        unc[key] = float(se_r[j])
        ident[key] = bool(np.isfinite(se_r[j]) and coef_r[j] > 0)
        if not ident[key]:
            reasons[key] = "the feed-axis forces gave no positive value with a finite error"
    # axial: Fz (+ pushes the tool up) = G (Kac c Sn + Kae span) + an offset per Z level
    # (a standing Z axis holds its force with a position-dependent offset: the motor's force
    # ripple at that angle, the weight balance; one intercept per level absorbs it)
    r_mm = np.maximum(reg[sel, 6], 1e-9)
    levels, lev_idx = np.unique(zlev[sel], return_inverse=True)
    a3 = np.column_stack([reg[sel, 0] * 1000.0 / r_mm, reg[sel, 1] * 1000.0 / r_mm,
                          np.eye(levels.size)[lev_idx]])
    coef_a, se_a, _ = _lstsq(a3, fz[sel])
    for j, key in enumerate(("kac_n_per_mm2", "kae_n_per_mm")):
        vals[key] = float(coef_a[j])
        unc[key] = float(se_a[j])
        ident[key] = bool(np.isfinite(se_a[j]) and coef_a[j] > 0)
        if not ident[key]:
            reasons[key] = ("the Z-axis force gave no positive value with a finite error (the "
                            "axial force needs cuts at several feeds and depths per Z level)")
    for key in MILLING_KEYS:
        if not ident.get(key):
            vals[key] = float(getattr(bk, key))
            unc[key] = math.nan
    notes.append(f"{int(cut.sum())} cutting and {int((~cut).sum())} air windows of "
                 f"{window_cycles} cycles; torque fit residual {rms_t:.3g} Nm RMS, offset "
                 f"{coef_t[2]:+.3g} Nm")
    return MaterialCalibration(name=name, coefficients=MillingCoefficients(**vals),
                               uncertainty=unc, identified=ident, reasons=reasons,
                               windows=int(cut.sum()), residual_torque_nm=rms_t,
                               offset_torque_nm=float(coef_t[2]), notes=notes)
