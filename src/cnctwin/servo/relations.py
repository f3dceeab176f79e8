"""Algebraic relations between the position-loop signals of one axis, with residual statistics.

The SINUMERIK HF signals of an axis are not independent (thesis Fig. 3.1, Table 2.1): the
controller difference is ``CTRL_DIFF2 = CTRL_POS - ENC_POS``, the following error is
``DES_POS - ENC_POS``, the contour deviation is the following error minus the lag the NC's own
model expects, and the velocity feedforward is the setpoint velocity. :func:`check_relations`
checks each on any recording and says, per relation, how well it holds and what a large residual
means. Relations whose signals are missing are reported as not checkable, with the reason.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import optimize

from cnctwin.recording import Recording
from cnctwin.servo._common import (
    AxisData,
    FloatArray,
    axis_data,
    best_lag,
    delay,
    derivative,
    detect_velocity_unit,
    pt1,
    quantum,
)

__all__ = ["MEANINGS", "Relation", "RelationReport", "check_relations", "residual_stats"]

MEANINGS: dict[str, str] = {
    "following_error": (
        "Following error e = DES_POS - ENC_POS compared with a recorded following error "
        "(servo trace). A large residual means the trace's following error is taken against "
        "another setpoint (after the jerk filter, i.e. CTRL_POS), against another measuring "
        "system, or the signals are shifted in time."
    ),
    "ctrl_diff2": (
        "CTRL_DIFF2 = CTRL_POS - ENC_POS. A large residual means the signals are sampled in "
        "different cycles (time misalignment), CTRL_DIFF2 contains a compensation (DSC, "
        "backlash or leadscrew compensation acting between the encoders), or the axis mapping "
        "of the file is wrong."
    ),
    "contour_deviation": (
        "CONT_DEV = following error - modelled lag, with the NC's lag model fitted as a delay "
        "plus first-order lag of DES_POS. A large residual means the NC's model has another "
        "structure (jerk filter, feedforward balancing), the axis is not position controlled "
        "(spindle in speed mode: CONT_DEV is 0) or there is a real contour error source the "
        "model does not carry. CONT_DEV itself large means the axis deviates from its own "
        "expected dynamics (friction, backlash, collision, changed Kv)."
    ),
    "vel_ffw": (
        "VEL_FFW = FFW weight x setpoint velocity d(CTRL_POS)/dt (or d(DES_POS)/dt). The fitted "
        "ratio gives the unit (1 for unit/s, 1/60 for unit/min) times the feedforward weight "
        "MD32610; the lag is the feedforward timing. A large residual after scale and lag means "
        "the feedforward is taken from another setpoint (before the jerk filter) or is limited."
    ),
    "speed_command": (
        "CMD_SPEED = Kv x controller difference + c x VEL_FFW (P position controller with "
        "feedforward, MD32200/MD32620). A large residual means the position controller is not "
        "a pure P law here (DSC, saturation at the speed limit, spindle in speed mode) or the "
        "controller difference is not recorded and was approximated."
    ),
}


@dataclass(frozen=True)
class Relation:
    """Result of checking one signal relation on one axis.

    Attributes
    ----------
    name : str
        Relation name (key of :data:`MEANINGS`).
    equation : str
        The relation checked.
    checkable : bool
        False when a needed signal is missing; ``reason`` says which.
    reason : str
        Why it is not checkable (empty when checkable).
    unit : str
        Unit of the residual.
    rms : float
        Residual RMS [unit].
    max_abs : float
        Largest absolute residual [unit].
    tolerance : float
        Tolerance used for ``fraction_within``: the quantization bound of the signals involved
        (sum of their quantization steps times their coefficients) or ``atol``, the larger [unit].
    fraction_within : float
        Share of samples whose residual is within ``tolerance`` [-].
    reference_rms : float
        RMS of the signal the relation predicts, for scale [unit].
    n_samples : int
        Samples compared.
    meaning : str
        What a large residual means.
    details : dict
        Relation-specific findings (fitted lag, scale, detected unit, model parameters).
    """

    name: str
    equation: str
    checkable: bool
    reason: str = ""
    unit: str = ""
    rms: float = float("nan")
    max_abs: float = float("nan")
    tolerance: float = float("nan")
    fraction_within: float = float("nan")
    reference_rms: float = float("nan")
    n_samples: int = 0
    meaning: str = ""
    details: dict[str, Any] = field(default_factory=dict)


@dataclass
class RelationReport:
    """All relations checked on one axis.

    Attributes
    ----------
    axis : str
        Axis name.
    relations : dict
        Relation name -> :class:`Relation`.
    """

    axis: str
    relations: dict[str, Relation]

    def __getitem__(self, name: str) -> Relation:
        return self.relations[name]

    def to_rows(self) -> list[dict[str, Any]]:
        """One dict per relation (for tables and JSON)."""
        return [
            {
                "relation": r.name,
                "checkable": r.checkable,
                "rms": r.rms,
                "max_abs": r.max_abs,
                "tolerance": r.tolerance,
                "fraction_within": r.fraction_within,
                "reference_rms": r.reference_rms,
                "unit": r.unit,
                "reason": r.reason,
            }
            for r in self.relations.values()
        ]


def residual_stats(
    residual: FloatArray, tolerance: float
) -> tuple[float, float, float, int]:
    """RMS, max |r|, fraction within ``tolerance`` and count of the finite residuals.

    Parameters
    ----------
    residual : numpy.ndarray
        Residual samples.
    tolerance : float
        Band counted as within [unit of the residual].

    Returns
    -------
    tuple
        (rms, max |r|, fraction within the tolerance, number of finite samples).
    """
    r = residual[np.isfinite(residual)]
    if r.size == 0:
        return float("nan"), float("nan"), float("nan"), 0
    return (
        float(np.sqrt(np.mean(r * r))),
        float(np.max(np.abs(r))),
        float(np.mean(np.abs(r) <= tolerance * (1 + 1e-9) + 1e-15)),
        int(r.size),
    )


def _missing(d: AxisData, codes: tuple[str, ...]) -> list[str]:
    return [c for c in codes if not d.has(c)]


def _relation(
    name: str, equation: str, residual: FloatArray, reference: FloatArray, tol: float,
    unit: str, details: dict[str, Any],
) -> Relation:
    ref = reference[np.isfinite(reference)]
    ref_rms = float(np.sqrt(np.mean(ref * ref))) if ref.size else 0.0
    tol = max(tol, 1e-9 * ref_rms)  # float round-off floor for unquantized (simulated) data
    rms, mx, frac, n = residual_stats(residual, tol)
    return Relation(
        name, equation, True, "", unit, rms, mx, tol, frac,
        float(np.sqrt(np.mean(ref * ref))) if ref.size else float("nan"), n, MEANINGS[name],
        details,
    )


def _not_checkable(name: str, equation: str, missing: list[str], axis: str) -> Relation:
    cols = ", ".join(f"{c}|{axis}" for c in missing)
    return Relation(name, equation, False, f"not in the recording: {cols}",
                    meaning=MEANINGS[name])


def fit_lag_model(
    target: FloatArray, source: FloatArray, segs: list[slice], *, warmup: int = 20
) -> tuple[float, float, FloatArray]:
    """Fit ``target ~ PT1_T(delay_tau(source))`` per segment; returns (tau, T) [cycles], model.

    Used for the NC's lag model behind CONT_DEV and for balancing delays.
    """

    def model(p: FloatArray) -> FloatArray:
        tau, t1 = max(p[0], 0.0), max(p[1], 0.0)
        out = np.full(source.shape, np.nan)
        for s in segs:
            if s.stop - s.start < 3:
                continue
            out[s] = pt1(delay(source[s], tau), t1)
        return out

    mask = np.zeros(source.shape, dtype=bool)
    for s in segs:
        mask[s.start + warmup : s.stop] = True
    mask &= np.isfinite(target) & np.isfinite(source)

    def cost(p: FloatArray) -> float:
        r = (target - model(p))[mask]
        return float(r @ r)

    grid = [(tau, t1) for tau in (0.0, 1.0, 2.0, 4.0) for t1 in (0.0, 2.0, 5.0, 10.0, 20.0)]
    start = min(grid, key=lambda p: cost(np.array(p)))
    res = optimize.minimize(cost, np.array(start, dtype=float), method="Nelder-Mead",
                            options={"xatol": 1e-3, "fatol": 1e-14, "maxiter": 400})
    p = np.maximum(res.x, 0.0)
    return float(p[0]), float(p[1]), model(p)


def check_relations(rec: Recording, axis: str, *, atol: float = 0.0) -> RelationReport:
    """Check the position-loop signal relations of one axis.

    Parameters
    ----------
    rec : Recording
        Any recording (simulated, Capture4Analysis, servo trace).
    axis : str
        Axis name (``"X1"``).
    atol : float, default 0
        Lower bound of the tolerance of every relation [signal unit]; the tolerance is
        otherwise the quantization bound of the signals involved.

    Returns
    -------
    RelationReport

    Notes
    -----
    Relations (thesis Fig. 3.1 and Table 2.1; Siemens HF signal definitions,
    docs/reference/data-formats.md §1.3):

    * ``following_error``: ``FOLLOWING_ERROR = DES_POS - ENC_POS``
    * ``ctrl_diff2``: ``CTRL_DIFF2 = CTRL_POS - ENC_POS``
    * ``contour_deviation``: ``CONT_DEV = (DES_POS - ENC_POS) - (DES_POS - M(DES_POS))``,
      ``M`` = delay + PT1 fitted by least squares
    * ``vel_ffw``: ``VEL_FFW = r d(CTRL_POS)/dt`` (lag fitted), ``r`` gives unit and weight
    * ``speed_command``: ``CMD_SPEED = a CTRL_DIFF2 + c VEL_FFW`` (least squares)
    """
    d = axis_data(rec, axis)
    dt = d.cycle_time_s
    pos_unit = d.units.get("DES_POS") or ("mm" if d.kind == "linear" else "deg")
    out: dict[str, Relation] = {}
    sig = d.signals
    have_enc = d.has("ENC_POS")
    fe = sig["DES_POS"] - sig["ENC_POS"] if d.has("DES_POS") and have_enc else None

    # 1. following error
    eq = "FOLLOWING_ERROR = DES_POS - ENC_POS"
    miss = _missing(d, ("DES_POS", "ENC_POS", "FOLLOWING_ERROR"))
    if miss:
        rel = _not_checkable("following_error", eq, miss, axis)
        if fe is not None:
            f = fe[np.isfinite(fe)]
            rel.details.update(
                computed_rms=float(np.sqrt(np.mean(f * f))) if f.size else float("nan"),
                computed_max_abs=float(np.max(np.abs(f))) if f.size else float("nan"),
            )
        out["following_error"] = rel
    else:
        assert fe is not None
        rec_fe = sig["FOLLOWING_ERROR"]
        lag, _ = best_lag(rec_fe, fe, max_lag=5)
        tol = max(atol, quantum(rec_fe) + quantum(sig["DES_POS"]) + quantum(sig["ENC_POS"]))
        out["following_error"] = _relation(
            "following_error", eq, rec_fe - fe, rec_fe, tol, pos_unit,
            {"best_lag_cycles": lag, "encoder": d.units.get("ENC_SOURCE", "ENC_POS")},
        )

    # 2. controller difference
    eq = "CTRL_DIFF2 = CTRL_POS - ENC_POS"
    miss = _missing(d, ("CTRL_DIFF2", "CTRL_POS", "ENC_POS"))
    if miss:
        out["ctrl_diff2"] = _not_checkable("ctrl_diff2", eq, miss, axis)
    else:
        pred = sig["CTRL_POS"] - sig["ENC_POS"]
        lag, _ = best_lag(sig["CTRL_DIFF2"], pred, max_lag=3)
        tol = max(atol, sum(quantum(sig[c]) for c in ("CTRL_DIFF2", "CTRL_POS", "ENC_POS")))
        out["ctrl_diff2"] = _relation("ctrl_diff2", eq, sig["CTRL_DIFF2"] - pred,
                                      sig["CTRL_DIFF2"], tol, pos_unit,
                                      {"best_lag_cycles": lag})

    # 3. contour deviation
    eq = "CONT_DEV = (DES_POS - ENC_POS) - (DES_POS - M(DES_POS)),  M = delay + PT1 (fitted)"
    miss = _missing(d, ("CONT_DEV", "DES_POS", "ENC_POS"))
    if miss:
        out["contour_deviation"] = _not_checkable("contour_deviation", eq, miss, axis)
    else:
        assert fe is not None
        target = sig["ENC_POS"] + sig["CONT_DEV"]  # the NC's modelled actual position
        tau, t1, model = fit_lag_model(target, sig["DES_POS"], d.segments)
        resid = sig["CONT_DEV"] - (model - sig["ENC_POS"])
        tol = max(atol, sum(quantum(sig[c]) for c in ("CONT_DEV", "DES_POS", "ENC_POS")))
        fe_f = fe[np.isfinite(fe)]
        cd = sig["CONT_DEV"][np.isfinite(sig["CONT_DEV"])]
        out["contour_deviation"] = _relation(
            "contour_deviation", eq, resid, sig["CONT_DEV"], tol, pos_unit,
            {
                "model_delay_s": tau * dt,
                "model_pt1_s": t1 * dt,
                "cont_dev_rms": float(np.sqrt(np.mean(cd * cd))) if cd.size else float("nan"),
                "following_error_rms": float(np.sqrt(np.mean(fe_f * fe_f))),
            },
        )

    # 4. velocity feedforward
    ref_code = "CTRL_POS" if d.has("CTRL_POS") else "DES_POS"
    eq = f"VEL_FFW = r * d({ref_code})/dt"
    miss = _missing(d, ("VEL_FFW", ref_code))
    if miss:
        out["vel_ffw"] = _not_checkable("vel_ffw", eq, miss, axis)
    else:
        v_ref = derivative(sig[ref_code], d.segments, dt, kind="backward")
        vu = detect_velocity_unit(sig["VEL_FFW"], v_ref, declared=d.units.get("VEL_FFW", ""),
                                  kind=d.kind)
        ffw_s = sig["VEL_FFW"] * vu.factor
        scale = vu.ratio * vu.factor
        pred = delay(np.nan_to_num(v_ref), float(vu.lag_cycles)) * scale
        pred[~np.isfinite(v_ref)] = np.nan
        tol = max(atol * vu.factor, quantum(ffw_s) + quantum(sig[ref_code]) / dt)
        out["vel_ffw"] = _relation(
            "vel_ffw", eq, ffw_s - pred, ffw_s, tol, f"{pos_unit}/s",
            {
                "reference": ref_code,
                "declared_unit": vu.declared,
                "detected_unit": vu.detected,
                "unit_decided_by_data": vu.decided_by_data,
                "ratio_raw": vu.ratio,
                "weight": scale,
                "lag_cycles": vu.lag_cycles,
            },
        )

    # 5. speed command
    diff_code = "CTRL_DIFF2" if d.has("CTRL_DIFF2") else (
        "CTRL_POS-ENC_POS" if d.has("CTRL_POS") and have_enc else "DES_POS-ENC_POS")
    eq = f"CMD_SPEED = a * ({diff_code}) + c * VEL_FFW"
    need = ("CMD_SPEED", "ENC_POS", "DES_POS" if diff_code == "DES_POS-ENC_POS" else "ENC_POS")
    miss = _missing(d, need)
    if miss:
        out["speed_command"] = _not_checkable("speed_command", eq, miss, axis)
    else:
        if diff_code == "CTRL_DIFF2":
            diff = sig["CTRL_DIFF2"]
        elif diff_code == "CTRL_POS-ENC_POS":
            diff = sig["CTRL_POS"] - sig["ENC_POS"]
        else:
            assert fe is not None
            diff = fe
        cols = [diff]
        if d.has("VEL_FFW"):
            cols.append(sig["VEL_FFW"])
        a_mat = np.column_stack([*cols, np.ones_like(diff)])
        y = sig["CMD_SPEED"]
        m = np.isfinite(a_mat).all(axis=1) & np.isfinite(y)
        coef, *_ = np.linalg.lstsq(a_mat[m], y[m], rcond=None)
        pred = a_mat @ coef
        tol = max(atol, quantum(y) + abs(coef[0]) * quantum(diff)
                  + (abs(coef[1]) * quantum(sig["VEL_FFW"]) if d.has("VEL_FFW") else 0.0))
        det = {"a": float(coef[0]), "offset": float(coef[-1]), "difference": diff_code,
               "cmd_unit": d.units.get("CMD_SPEED", "")}
        if d.has("VEL_FFW"):
            det["c"] = float(coef[1])
        out["speed_command"] = _relation("speed_command", eq, y - pred, y, tol,
                                         d.units.get("CMD_SPEED", ""), det)
    return RelationReport(axis, out)
