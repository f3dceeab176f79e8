"""Calibrate the feed axes of one's own machine: position loop and friction per axis.

:func:`calibrate_axes` runs :func:`cnctwin.servo.identify_axis` (thesis chapter 3.1) on the
user's production recordings and maps what it identified onto the machine file's keys:

============================  ===============================================  =============
machine file key              identification                                   NC datum
============================  ===============================================  =============
``kv_m_min_per_mm``           ``kv_m_min_mm``                                  MD32200
``ffw_weight``                ``ffw_weight`` (needs CTRL_POS and VEL_FFW)      MD32610
``jerk_filter_type``          chosen setpoint-filter model                     MD32402
``jerk_time_s``               ``jerk_time_s`` (moving average / PT2)           MD32410
``ffw_mode``                  speed/torque FFW, dead-time or PT1 balancing     MD32620
``equiv_speedctrl_time_s``    balancing time DES_POS -> CTRL_POS (speed FFW)   MD32810
``equiv_currctrl_time_s``     balancing time (torque FFW)                      MD32800
``coulomb_n``                 ``coulomb_torque`` or ``coulomb_current`` x Kt   -
``viscous_n_per_mm_s``        ``viscous_torque`` or ``viscous_current`` x Kt   -
============================  ===============================================  =============

Friction is identified at the motor (current or torque) and referred to the slide with the
axis' torque constant and screw lead (``kt_nm_per_a``, ``screw_pitch_mm``, ``gear_ratio`` of
the machine description, which the user states; they are not identifiable from these
signals). Several recordings are pooled per parameter by the inverse-variance weighted mean;
the stated standard uncertainty adds a relative floor (:data:`REL_FLOOR`) in quadrature where a
model stands between the data and the parameter (the loop parameters; not the friction, whose
bootstrap over whole constant-velocity strokes carries the friction law's misfit, nor Kv
where it is model-free).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from cnctwin.exceptions import IdentificationError
from cnctwin.machine import FeedAxis, Machine, ParameterRecord, Provenance
from cnctwin.recording import Recording
from cnctwin.servo import AxisIdentification, identify_axis, moving_axes
from cnctwin.servo.identify import cut_cycles

__all__ = [
    "CALIBRATED_KEYS",
    "JERK_FILTER_MD32402",
    "REL_FLOOR",
    "AxesCalibration",
    "calibrate_axes",
]

JERK_FILTER_MD32402: dict[str, int] = {"none": 0, "pt2": 1, "moving_average": 2,
                                       "double_moving_average": 4}
"""Setpoint-filter model -> MD32402 AX_JERK_MODE."""

_DIRECT = {
    "kv_m_min_per_mm": "kv_m_min_mm",
    "ffw_weight": "ffw_weight",
    "jerk_time_s": "jerk_time_s",
}

CALIBRATED_KEYS: tuple[str, ...] = (
    "kv_m_min_per_mm", "ffw_weight", "jerk_filter_type", "jerk_time_s", "ffw_mode",
    "equiv_speedctrl_time_s", "coulomb_n", "viscous_n_per_mm_s")
"""The keys :func:`calibrate_axes` writes per axis (``axes.<name>.<key>``)."""

REL_FLOOR = 0.01
"""Relative standard-uncertainty floor of an identified loop parameter: what the loop model
(one PT1 + dead time for the speed loop, linearly interpolated fractional delays) does not
describe on a real drive; the same floor :class:`~cnctwin.servo.predict.DriftMonitor` uses.
Not added to Kv where it comes from the NC's own relation and the steady-state speed gain
(:attr:`cnctwin.servo.AxisIdentification.kv_exact`): no loop model stands between the data
and Kv there, and the coverage of its interval without the floor is measured
(docs/validation-calibration.md). Not added to the friction either: its bootstrap runs over
whole constant-velocity strokes at several feeds, whose scatter carries the friction law's
misfit (coverage measured there too)."""

_BOUNDS = {"ffw_weight": (0.0, 1.0), "jerk_time_s": (0.0, 0.1),
           "equiv_speedctrl_time_s": (0.0, 0.05), "equiv_currctrl_time_s": (1e-5, 0.01),
           "kv_m_min_per_mm": (0.05, 20.0)}


@dataclass
class AxesCalibration:
    """What the axis calibration identified.

    Attributes
    ----------
    records : dict
        Machine-file key (``axes.X1.kv_m_min_per_mm``) -> :class:`ParameterRecord`; keys the
        identification refused carry ``identified=False`` and the reason.
    identifications : dict
        Axis -> one :class:`~cnctwin.servo.AxisIdentification` per recording.
    notes : list of str
        Findings worth reading (unit mismatches, assumptions).
    not_moving : list of str
        The machine's feed axes that move in no recording (their keys are in ``records``,
        not identified, with the reason).
    """

    records: dict[str, ParameterRecord] = field(default_factory=dict)
    identifications: dict[str, list[AxisIdentification]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    not_moving: list[str] = field(default_factory=list)


def _pool(values: list[tuple[float, float]]) -> tuple[float, float]:
    """Inverse-variance weighted mean and its standard uncertainty (spread-inflated)."""
    v = np.array([x for x, _ in values])
    s = np.array([u if (u == u and u > 0) else np.nan for _, u in values])
    if v.size == 1:
        return float(v[0]), float(s[0]) if s[0] == s[0] else float("nan")
    if np.all(np.isfinite(s)):
        w = 1.0 / s**2
        mean = float(np.sum(w * v) / np.sum(w))
        u = 1.0 / math.sqrt(float(np.sum(w)))
    else:
        mean, u = float(np.mean(v)), float("nan")
    spread = float(np.std(v, ddof=1) / math.sqrt(v.size))
    return mean, float(np.nanmax([u, spread]))


def calibrate_axes(
    recordings: Sequence[Recording],
    *,
    machine: Machine | None = None,
    axes: Sequence[str] | None = None,
    recording_names: Sequence[str] = (),
    n_bootstrap: int = 200,
) -> AxesCalibration:
    """Identify the position loop and friction of feed axes from production recordings.

    Parameters
    ----------
    recordings : sequence of Recording
        Recordings with at least DES_POS and ENC_POS of the axes (CTRL_POS, CMD_SPEED,
        VEL_FFW, CURRENT, TORQUE make more identifiable).
    machine : Machine, optional
        The machine description (torque constant and lead for the friction at the slide);
        default the thesis machine.
    axes : sequence of str, optional
        Axes to calibrate; default every axis that moves in some recording.
    recording_names : sequence of str
        Names for messages and the provenance.
    n_bootstrap : int, default 200
        Bootstrap resamples of the regressions.

    Returns
    -------
    AxesCalibration

    Raises
    ------
    IdentificationError
        An axis asked for is in no recording, or no axis moves in any recording.
    """
    m = machine or Machine.thesis_default()
    names = list(recording_names) or [
        (r.meta.source_files[0] if r.meta.source_files else f"recording {k}")
        for k, r in enumerate(recordings)]
    per_rec = [[a for a in moving_axes(r) if a != m.spindle_name] for r in recordings]
    wanted = list(axes) if axes else sorted({a for lst in per_rec for a in lst})
    unknown = [a for a in wanted if a not in m.axis_names]
    if unknown:
        raise IdentificationError(
            f"axis {', '.join(unknown)} is not in the machine description (axes: "
            f"{', '.join(m.axis_names)}); add a table [axes.{unknown[0]}] to the machine file "
            "(with rotary = true for a rotary axis) or choose the axes with --axis")
    if not wanted:
        raise IdentificationError(
            f"no feed axis moves in {', '.join(names)} (DES_POS and ENC_POS with travel); "
            "record a production job or a test program that moves the axes")
    out = AxesCalibration()
    cuts = [cut_cycles(r, spindle=m.spindle_name) if mov else (None, "")
            for r, mov in zip(recordings, per_rec, strict=True)]
    for ax in wanted:
        idents: list[AxisIdentification] = []
        used: list[str] = []
        reasons: list[str] = []
        for name, rec, mov, cut in zip(names, recordings, per_rec, cuts, strict=True):
            if ax not in mov:
                continue
            try:
                idents.append(identify_axis(rec, ax, n_bootstrap=n_bootstrap,
                                            spindle=m.spindle_name, cuts=cut))
                used.append(name)
            except IdentificationError as exc:
                reasons.append(f"{name}: {exc}")
        if not idents:
            if axes:
                raise IdentificationError(
                    f"axis {ax} does not move in any of {', '.join(names)}"
                    + (f" ({'; '.join(reasons)})" if reasons else "")
                    + "; name a recorded axis with --axis or record one where it moves")
            continue
        out.identifications[ax] = idents
        for i in idents:
            out.notes += [f"{ax}: {n}" for n in i.notes]
        prov = Provenance.now("cnctwin calibrate axes (cnctwin.servo.identify_axis)", used)
        base = m.axis(ax) if ax in m.axis_names else None
        for key, param in _DIRECT.items():
            est = [(i.params[param].value, i.params[param].stderr) for i in idents
                   if param in i.params]
            full = f"axes.{ax}.{key}"
            if est:
                v, u = _pool(est)
                if key != "kv_m_min_per_mm" or not all(i.kv_exact for i in idents):
                    u = math.hypot(u if u == u else 0.0, REL_FLOOR * abs(v))
                lo, hi = _BOUNDS.get(key, (-math.inf, math.inf))
                if not lo <= v <= hi:
                    edge = min(max(v, lo), hi)
                    if u == u and abs(v - edge) <= 3.0 * u:
                        out.notes.append(f"{ax}: {key} = {v:.5g} +- {u:.2g} lies beyond its "
                                         f"physical bound {edge:g} within 3 standard "
                                         f"uncertainties; {edge:g} is written")
                        v = edge
                    else:
                        out.records[full] = ParameterRecord(
                            float(getattr(base, key)) if base is not None else edge,
                            identified=False,
                            reason=f"identified {v:.5g}, outside {lo:g} ... {hi:g}: the "
                                   "recording does not fit the loop model")
                        continue
                out.records[full] = ParameterRecord(v, u if u == u else None, prov)
            else:
                why = "; ".join(sorted({i.not_identified.get(param, f"{param} not identified")
                                        for i in idents}))
                default = getattr(base, key) if base is not None else float("nan")
                if default == default:
                    out.records[full] = ParameterRecord(float(default), identified=False,
                                                        reason=why)
        jtypes = [i.jerk_type for i in idents if i.jerk_type]
        pt2_pair = _pt2_pair(idents)
        pt2: bool | None = None  # None: no PT2 pair; True: accepted; False: ambiguous
        if pt2_pair is not None and base is not None:
            pt2 = _pt2_jerk(out, ax, idents, pt2_pair, prov)
        elif jtypes:
            jt = max(set(jtypes), key=jtypes.count)
            out.records[f"axes.{ax}.jerk_filter_type"] = ParameterRecord(
                float(JERK_FILTER_MD32402[jt]), None, prov)
            rec_j = out.records.get(f"axes.{ax}.jerk_time_s")
            dt = idents[0].cycle_time_s
            inactive = jt == "none" or (
                jt in ("moving_average", "double_moving_average") and rec_j is not None
                and rec_j.identified and rec_j.value <= 1.5 * dt)
            if inactive and base is not None:
                out.records[f"axes.{ax}.jerk_filter_type"] = ParameterRecord(0.0, None, prov)
                out.records[f"axes.{ax}.jerk_time_s"] = ParameterRecord(
                    float(base.jerk_time_s), identified=False,
                    reason="no jerk filter seen between DES_POS and CTRL_POS (MD32402 = 0 is "
                           "written); a moving average over 2 cycles is a linearly "
                           "interpolated half-cycle delay and cannot be told from one: it is "
                           "then part of the balancing time")
            elif jt in ("moving_average", "double_moving_average") and rec_j is not None \
                    and rec_j.identified and rec_j.uncertainty is not None:
                # a moving average spans whole cycles: every MD32410 within half a cycle of
                # the identified length gives the same filter (uniform, dt / sqrt(12))
                out.records[f"axes.{ax}.jerk_time_s"] = dataclasses.replace(
                    rec_j, uncertainty=math.hypot(rec_j.uncertainty, dt / math.sqrt(12.0)))
        if pt2 is False and base is not None:
            for key in ("equiv_speedctrl_time_s", "ffw_mode"):
                out.records[f"axes.{ax}.{key}"] = ParameterRecord(
                    float(getattr(base, key)), identified=False,
                    reason="a PT2 jerk filter beside PT1 balancing: three PT1 stages the "
                           "identification's two cannot separate; read MD32620/MD32810 from "
                           "the NC")
        else:
            _balancing(out, ax, idents, prov, pt2_pair=bool(pt2))
        _friction(out, ax, idents, base, prov)
    if not axes:
        # the machine's other feed axes: not identified, and why (not an empty section)
        for ax in m.axis_names:
            if ax in wanted or ax == m.spindle_name:
                continue
            why = (f"{ax} does not move in {', '.join(names)}: nothing to identify; record "
                   f"a program that moves it (e.g. the axis test program) and calibrate again")
            base_ax = m.axis(ax)
            out.not_moving.append(ax)
            for key in CALIBRATED_KEYS:
                out.records[f"axes.{ax}.{key}"] = ParameterRecord(
                    float(getattr(base_ax, key)), identified=False, reason=why)
    return out


def _pt2_pair(idents: list[AxisIdentification]) -> tuple[float, float] | None:
    """The two equal setpoint PT1s of a PT2 jerk filter (MD32402 = 1), if the fit shows them.

    The NC's second-order jerk filter is two PT1 stages of MD32410 / 2 each (low-frequency
    delay MD32410). The identification's setpoint chain has two PT1 slots after the jerk
    filter (for the dynamic response adaptation and the PT1 balancing); a PT2 jerk filter with
    dead-time balancing fills both with the same time constant, where the jerk model 'none'
    explains the data exactly. Returns (T1 + T2, its standard error) [s].
    """
    vals = []
    for i in idents:
        a = i.params.get("setpoint_pt1_s")
        b = i.params.get("setpoint_pt1b_s")
        if i.jerk_type not in ("none", "pt2") or a is None or b is None:
            continue
        dt = i.cycle_time_s
        if min(a.value, b.value) > 0.25 * dt and abs(a.value - b.value) <= 0.15 * max(
                a.value, b.value):
            se = math.hypot(a.stderr if a.stderr == a.stderr else 0.0,
                            b.stderr if b.stderr == b.stderr else 0.0)
            vals.append((a.value + b.value, se))
    return _pool(vals) if vals else None


def _pt2_jerk(out: AxesCalibration, ax: str, idents: list[AxisIdentification],
              pair: tuple[float, float], prov: Provenance) -> bool:
    """Record MD32402 = 1 and MD32410 from a PT2 pair; False (refused, with the reason) where
    PT1 balancing makes it ambiguous."""
    modes = [i.ffw_mode for i in idents]
    delays = [i.params["setpoint_delay_s"].value for i in idents if "setpoint_delay_s" in i.params]
    dt = idents[0].cycle_time_s
    if delays and max(delays) < 0.25 * dt and "none" not in modes:
        out.records[f"axes.{ax}.jerk_time_s"] = ParameterRecord(
            0.008, identified=False,
            reason="two equal setpoint PT1s and no dead time: a PT2 jerk filter (MD32402 = 1) "
                   "beside PT1 feedforward balancing (MD32620 = 1/2) cannot be told apart with "
                   "two PT1 stages; read MD32402/MD32410 from the NC")
        return False
    v, u = pair
    out.records[f"axes.{ax}.jerk_filter_type"] = ParameterRecord(1.0, None, prov)
    out.records[f"axes.{ax}.jerk_time_s"] = ParameterRecord(
        v, math.hypot(u if u == u else 0.0, REL_FLOOR * v), prov)
    return True


def _balancing(out: AxesCalibration, ax: str, idents: list[AxisIdentification],
               prov: Provenance, *, pt2_pair: bool = False) -> None:
    """FFW mode MD32620 and the balancing time MD32810 (speed FFW) or MD32800 (torque FFW).

    With feedforward the NC delays the setpoint by the balancing time (dead time: modes 3/4)
    or filters it (PT1: modes 1/2) so that it meets the actual position; the identification
    sees it between DES_POS and CTRL_POS as ``setpoint_delay_s`` / ``setpoint_pt1_s``
    (with the dynamic response adaptation MD32910, which it cannot tell apart: both are
    written to the balancing time).
    """
    modes = [i.ffw_mode for i in idents if i.ffw_mode in ("none", "speed", "torque")]
    if not modes:
        return
    mode = max(set(modes), key=modes.count)
    if mode == "none":
        out.records[f"axes.{ax}.ffw_mode"] = ParameterRecord(0.0, None, prov)
        return
    delay = [(i.params["setpoint_delay_s"].value, i.params["setpoint_delay_s"].stderr)
             for i in idents if "setpoint_delay_s" in i.params]
    pt1 = [(i.params["setpoint_pt1_s"].value, i.params["setpoint_pt1_s"].stderr)
           for i in idents if "setpoint_pt1_s" in i.params]
    if not delay:
        return
    d_v, d_u = _pool(delay)
    p_v, p_u = _pool(pt1) if pt1 else (0.0, 0.0)
    dead = d_v >= p_v or pt2_pair  # the PT1 pair is the jerk filter, not the balancing
    code = {("speed", True): 3, ("speed", False): 1, ("torque", True): 4,
            ("torque", False): 2}[(mode, dead)]
    out.records[f"axes.{ax}.ffw_mode"] = ParameterRecord(float(code), None, prov)
    v, u = (d_v, d_u) if dead else (p_v, p_u)
    key = "equiv_speedctrl_time_s" if mode == "speed" else "equiv_currctrl_time_s"
    lo, hi = _BOUNDS.get(key, (0.0, math.inf))
    v = min(max(v, lo), hi)
    out.records[f"axes.{ax}.{key}"] = ParameterRecord(
        v, math.hypot(u if u == u else 0.0, REL_FLOOR * v, 0.05 * idents[0].cycle_time_s),
        prov)


def _friction(out: AxesCalibration, ax: str, idents: list[AxisIdentification],
              base: FeedAxis | None, prov: Provenance) -> None:
    """Friction at the slide from the motor-side fit (torque preferred, else current x Kt)."""
    if base is None:
        return
    per_force = base.motor_torque_per_load_force
    load_unit = "Nm" if base.rotary else "N"

    def scale(unit: str) -> float | None:
        """Factor from the fitted effort's unit to load force (torque on rotary axes)."""
        u = unit.split("/")[0].strip()
        if u == load_unit:
            return 1.0
        if u == "Nm":
            return 1.0 / per_force
        if u == "A":
            return base.kt_nm_per_a / per_force
        return None

    for key, stem in (("coulomb_n", "coulomb"), ("viscous_n_per_mm_s", "viscous")):
        full = f"axes.{ax}.{key}"
        for code in ("torque", "current"):
            est = []
            for i in idents:
                e = i.params.get(f"{stem}_{code}")
                f = scale(e.unit) if e is not None else None
                if e is not None and f is not None:
                    est.append((e.value * f, e.stderr * f))
            if est:
                # no REL_FLOOR: the bootstrap over whole strokes (one run per stroke since
                # issue 29) carries the friction law's misfit as the runs' scatter
                v, u = _pool(est)
                if v < 0.0:
                    out.records[full] = ParameterRecord(
                        float(getattr(base, key)), identified=False,
                        reason=f"the fit on {code.upper()} gives {v:.4g} {load_unit}"
                               f"{'' if stem == 'coulomb' else '/(unit/s)'}, a negative "
                               "friction: a weight or a process force on the axis, or a "
                               "current sign opposite to the motion; record the axis test "
                               "program in air")
                else:
                    out.records[full] = ParameterRecord(v, u if u == u else None, prov)
                break
        else:
            why = "; ".join(sorted({i.not_identified.get(f"coulomb_{c}", "")
                                    for i in idents for c in ("torque", "current")} - {""}))
            out.records[full] = ParameterRecord(
                float(getattr(base, key)), identified=False,
                reason=why or "no constant-velocity runs with CURRENT or TORQUE")
