"""Calibrate the spindle of one's own machine: friction, torque constant, inertia, with uncertainty.

:func:`calibrate_spindle` runs the :class:`~cnctwin.twin.TwinChain` (thesis chapters 3.2 and 4:
air-cut plateaus -> friction line, one reference cut -> Kt; the improved method by default) on
the user's recordings, checks first that they can support each parameter, and states every
value with a standard uncertainty and its provenance, ready for the machine file
(:mod:`cnctwin.machine.file`).

Uncertainty budget (standard uncertainties, combined in quadrature; GUM, JCGM 100:2008 §5):

* statistical: the friction regression's standard errors (thesis Eq. 4.2; for the improved
  method at the optimum of the whole law, its decay speed and drift included) and the spread of
  Kt over the consecutive averaging windows of the reference cut (standard error of their mean);
* model form: the standard deviation of B, tau_f and Kt over fit variants the method could as
  well have used (upper end of the fit range at 60 / 80 / 100 % of the linear region, lower end
  moved up, the self-heating drift on the viscous term only / on both terms / common), which
  shows the curvature the straight line does not model (bearing self-heating during the
  sweep, Stribeck residue). A variant counts only where the law fits its plateaus as well as
  the chosen fit's (the ratio of residual variances within the F distribution's 95 % point,
  a lack-of-fit test): a range that reaches into the viscous roll-off at the top of the
  linear region is not one the method could as well have used (its slope 1.3-2.2 % low on
  simulated spindles). The variants fit overlapping sets of the same plateaus, so their
  spread holds the statistical scatter too: only what exceeds the statistical term (in
  quadrature) counts as model form (docs/validation-calibration.md);
* reference: the torque reference's own relative uncertainty, as the user states it (a
  dynamometer's calibration certificate; 0 if not given, and the report says it is not
  included).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from cnctwin.exceptions import IdentificationError
from cnctwin.machine import ParameterRecord, Provenance
from cnctwin.recording import Recording
from cnctwin.spindle import FluxLawFit, SpindleModel, fit_flux_law, inertia_uncertainty
from cnctwin.twin import FrictionCurve, TwinChain, TwinChainResult

__all__ = [
    "METHODS",
    "SpindleCalibration",
    "calibrate_spindle",
    "check_air_cut_plateaus",
]

METHODS: dict[str, str] = {
    "improved": "improved method (Stribeck friction from 300 rpm, engaged 1 s window, local "
                "air baseline, temperature referral, J from run-ups; docs/validation-spindle.md)",
    "thesis": "thesis method (I = a n + b over the linear region, Eq. 4.2; Kt from the first "
              "0.6 s of the reference cut, Eq. 4.3)",
}
"""Method name -> what it does (for the provenance and the report)."""

_MIN_PLATEAUS = {"improved": 6, "thesis": 3}
LACK_OF_FIT_LEVEL = 0.95
"""Level of the F test that admits a fit variant into the model-form spread."""
_RANGE_RPM = (500.0, 7000.0)


@dataclass
class SpindleCalibration:
    """The calibrated spindle and how far to trust it.

    Attributes
    ----------
    method : str
        ``"improved"`` or ``"thesis"``.
    model : SpindleModel
        Kt [Nm/A], B [Nm/rpm], tau_f [Nm], J [kg m^2] at ``model.reference_temperature_c``.
    uncertainty : dict
        Parameter (``kt_nm_per_a``, ``b_nm_per_rpm``, ``tau_f_nm``) -> standard uncertainty
        [its unit] (J is identified without one).
    budget : pandas.DataFrame
        Per parameter the components (``statistical``, ``model_form``, ``reference``) and
        ``combined`` standard uncertainty [unit of the parameter], ``value``, ``unit``.
    records : dict
        Machine-file key (``spindle.kt_nm_per_a`` ...) -> :class:`ParameterRecord`.
    result : TwinChainResult
        Everything the chain identified (plateau statistics, fit, calibration window).
    windows : pandas.DataFrame
        The reference cut's consecutive windows and the Kt of each
        (:meth:`~cnctwin.twin.TwinChain.calibration_windows`).
    variants : pandas.DataFrame
        The fit variants behind the model-form uncertainty: per variant Kt, B, tau_f, its
        fit range, ``residual_ratio`` and ``counted`` (whether the lack-of-fit test admits
        it to the spread; :data:`LACK_OF_FIT_LEVEL`).
    reference_torque_source : str
        ``"dynamometer"`` or ``"given"``.
    notes : list of str
        What a user should know (what was not identified and why, what is not included).
    speeds : pandas.DataFrame
        Kt of each reference cut at its speed (``speed_rpm``, ``kt_nm_per_a``, ``kt_se``,
        ``torque_nm``, ``current_a``).
    flux_law : FluxLawFit or None
        The speed law of Kt, where the references span speeds.
    """

    method: str
    model: SpindleModel
    uncertainty: dict[str, float]
    budget: pd.DataFrame
    records: dict[str, ParameterRecord]
    result: TwinChainResult
    windows: pd.DataFrame
    variants: pd.DataFrame
    reference_torque_source: str
    notes: list[str] = field(default_factory=list)
    speeds: pd.DataFrame = field(default_factory=pd.DataFrame)
    flux_law: FluxLawFit | None = None


def check_air_cut_plateaus(
    stats: pd.DataFrame,
    *,
    method: str = "improved",
    lo_rpm: float = _RANGE_RPM[0],
    hi_rpm: float = _RANGE_RPM[1],
    source: str = "the air cuts",
) -> None:
    """Refuse air cuts that cannot support the friction fit, saying what to record next.

    Parameters
    ----------
    stats : pandas.DataFrame
        Plateau statistics (``speed_rpm``; :func:`~cnctwin.spindle.air_cut_statistics`).
    method : {'improved', 'thesis'}
        The improved fit has three coefficients and a decay speed (>= 6 plateaus); the thesis
        line two (>= 3).
    lo_rpm, hi_rpm : float
        Speed range the plateaus must lie in [rpm] (the linear region of a motor spindle
        lies inside it; thesis §4.1: 1100-5000 rpm).
    source : str
        Named in the message.

    Raises
    ------
    IdentificationError
        "need at least N constant-speed plateaus between lo and hi rpm; found k at ...".
    """
    need = _MIN_PLATEAUS[method]
    n = stats["speed_rpm"].abs().to_numpy(dtype=np.float64) if len(stats) else np.array([])
    inside = np.sort(n[(n >= lo_rpm) & (n <= hi_rpm)])
    if inside.size >= need:
        return
    found = "none" if inside.size == 0 else (
        f"{inside.size} at " + ", ".join(f"{v:.0f}" for v in inside[:8]) + " rpm")
    raise IdentificationError(
        f"{source}: need at least {need} constant-speed plateaus between {lo_rpm:.0f} and "
        f"{hi_rpm:.0f} rpm for the {method} friction fit; found {found}. Record an air cut "
        f"(no contact) with the spindle held at {need} or more speeds spread over that range, "
        "3 s or more each (e.g. S500 M3 / G4 F3 / S1000 M3 / G4 F3 ...)")


def _chain(method: str, **kw: Any) -> TwinChain:
    if method == "improved":
        return TwinChain.improved_method(**kw)
    if method == "thesis":
        return TwinChain.thesis_method(**kw)
    raise IdentificationError(f"unknown method {method!r}; choose one of {sorted(METHODS)}")


def _variant_options(method: str) -> list[dict[str, Any]]:
    if method == "improved":
        return [{"fit_to_fraction": 0.6}, {"fit_to_fraction": 1.0}, {"fit_from_rpm": 600.0},
                {"thermal_drift": "both"}, {"thermal_drift": "common"}]
    return [{"fit_to_fraction": 0.6}, {"fit_to_fraction": 0.8}]


def calibrate_spindle(
    air_cuts: Sequence[Recording],
    reference: Recording | Sequence[Recording] | None,
    *,
    method: str = "improved",
    reference_torque_nm: float | Sequence[float] | None = None,
    reference_uncertainty_pct: float = 0.0,
    kt_nm_per_a: float | None = None,
    kt_tolerance_pct: float = 5.0,
    warm_up: Recording | None = None,
    spindle: str = "SP1",
    recording_names: Sequence[str] = (),
) -> SpindleCalibration:
    """Identify Kt, B, tau_f (and J) of a motor spindle from air cuts and one reference cut.

    Parameters
    ----------
    air_cuts : sequence of Recording
        Air-cut recordings with constant-speed plateaus (thesis §3.2.2).
    reference : Recording or sequence of Recording
        Cuts whose torque is known: with the dynamometer attached as external channel
        ``"dynamometer"`` (column ``mz_nm``), or with ``reference_torque_nm``. Cuts at two or
        more speeds give the speed law of Kt (:func:`cnctwin.spindle.fit_flux_law`: the
        constant-power range of an induction spindle); the first gives friction and J.
    method : {'improved', 'thesis'}, default 'improved'
        :meth:`TwinChain.improved_method` or :meth:`TwinChain.thesis_method`.
    reference_torque_nm : float or sequence of float, optional
        Mean cutting torque of each reference cut [Nm], instead of a dynamometer.
    reference_uncertainty_pct : float, default 0
        Relative standard uncertainty of the torque reference [%] (calibration certificate).
    kt_nm_per_a : float, optional
        Without a reference cut: the motor's torque constant from the drive's data (SINAMICS
        p0316, the motor data sheet) [Nm/A]. Friction and J are referred to it.
    kt_tolerance_pct : float, default 5
        Its tolerance as the data sheet states it (+- %, taken as a uniform distribution:
        standard uncertainty tolerance / sqrt(3)); every cutting torque inherits it.
    warm_up : Recording, optional
        A long constant-speed run for the temperature referral (improved method).
    spindle : str, default 'SP1'
        Spindle axis name.
    recording_names : sequence of str
        Names of the air cuts, then the reference (and the warm-up), for messages and the
        provenance (default: ``meta.source_files``).

    Returns
    -------
    SpindleCalibration

    Raises
    ------
    IdentificationError
        Too few plateaus (what to record next), no cut in the reference, no torque reference.
    SignalNotFoundError
        A recording lacks the spindle current or speed.
    """
    if method not in METHODS:
        raise IdentificationError(f"unknown method {method!r}; choose one of {sorted(METHODS)}")
    from cnctwin.analysis.segments import speed_plateaus
    from cnctwin.spindle import air_cut_statistics

    parts = []
    for r in air_cuts:
        pl = speed_plateaus(r, spindle=spindle)
        if not pl.empty:
            parts.append(air_cut_statistics(r, pl, spindle=spindle))
    stats = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame({"speed_rpm": []})
    n_air = len(air_cuts)
    air_names = list(recording_names)[:n_air]
    check_air_cut_plateaus(stats, method=method, source="the air cut" + (
        f"s {', '.join(air_names)}" if len(air_names) > 1 else
        (f" {air_names[0]}" if air_names else "s")))
    if kt_nm_per_a is not None:
        return _calibrate_with_motor_kt(air_cuts, method=method, kt_nm_per_a=kt_nm_per_a,
                                        kt_tolerance_pct=kt_tolerance_pct, warm_up=warm_up,
                                        spindle=spindle, recording_names=recording_names)
    refs = ([] if reference is None else [reference] if isinstance(reference, Recording)
            else list(reference))
    if not refs:
        raise IdentificationError("calibrate_spindle needs a reference cut with a known "
                                  "torque, or the motor's torque constant (kt_nm_per_a)")
    if reference_torque_nm is None or isinstance(reference_torque_nm, int | float):
        torques: list[float | None] = [reference_torque_nm] * len(refs)
    else:
        torques = [float(t) for t in reference_torque_nm]
        if len(torques) != len(refs):
            raise IdentificationError(f"{len(torques)} reference torques for {len(refs)} "
                                      "reference cuts; give one per cut")
    reference = refs[0]
    cal_kw: dict[str, Any] = {"warm_up": warm_up, "reference_torque_nm": torques[0]}
    base_opts: dict[str, Any] = {}
    for _ in range(3):
        chain = _chain(method, spindle=spindle, **base_opts)
        chain.calibrate(air_cuts, reference, **cal_kw)
        # above a base speed inside the air cut the air current bends up (the torque per
        # current falls): the friction line must stay below it
        nb = _base_speed_hint(chain, refs, torques)
        lo_fit, hi_fit = chain.results.fit_range_rpm
        if nb is None or nb >= hi_fit:
            break
        region = chain.results.region
        base_opts = {"region": (region.lo_rpm if region is not None else lo_fit, nb)}
    res = chain.results
    model = res.spindle_model
    if model.b_nm_per_rpm < 0 or model.tau_f_nm < 0:
        lo_fit, hi_fit = res.fit_range_rpm
        raise IdentificationError(
            f"the friction line through the air cut over {lo_fit:.0f}-{hi_fit:.0f} rpm gives "
            f"B = {model.b_nm_per_rpm:.3g} Nm/rpm and tau_f = {model.tau_f_nm:.3g} Nm: a "
            "negative friction, so the air current bends inside that range (above a base "
            "speed the torque per current falls); give reference cuts at two or more speeds "
            "(one below and one above the bend) so the base speed is found and the fit stays "
            "below it")
    windows = chain.calibration_windows(reference, reference_torque_nm=torques[0])
    full = windows[(windows["end_cycle"] - windows["start_cycle"] + 1)
                   >= 0.5 * chain.options.window_s * reference.fs_hz]
    # --- variants (model form)
    rows = [{"variant": "chosen", "kt_nm_per_a": model.kt_nm_per_a,
             "b_nm_per_rpm": model.b_nm_per_rpm, "tau_f_nm": model.tau_f_nm,
             "fit_lo_rpm": res.fit_range_rpm[0], "fit_hi_rpm": res.fit_range_rpm[1]}]
    curves = []
    for opts in _variant_options(method):
        try:
            v = _chain(method, spindle=spindle, **{**base_opts, **opts}).calibrate(
                air_cuts, reference, **cal_kw)
        except IdentificationError:
            continue
        vm = v.results.spindle_model
        curves.append(v.results.friction)
        rows.append({"variant": ", ".join(f"{k}={val}" for k, val in opts.items()),
                     "kt_nm_per_a": vm.kt_nm_per_a, "b_nm_per_rpm": vm.b_nm_per_rpm,
                     "tau_f_nm": vm.tau_f_nm, "fit_lo_rpm": v.results.fit_range_rpm[0],
                     "fit_hi_rpm": v.results.fit_range_rpm[1]})
    variants = _lack_of_fit(pd.DataFrame(rows), [res.friction, *curves])

    kt = model.kt_nm_per_a
    k_w = full["kt_nm_per_a"].to_numpy(dtype=np.float64)
    k_w = k_w[np.isfinite(k_w)]
    u_kt_win = float(np.std(k_w, ddof=1) / math.sqrt(k_w.size)) if k_w.size > 1 else 0.0
    cal = res.calibration
    i_cut = abs(cal.current_a) - cal.air_current_a
    line = res.friction.line
    u_air = math.hypot(line.offset_std, line.slope_std * abs(cal.speed_rpm)) \
        if np.isfinite(line.offset_std) else 0.0
    u_kt_stat = math.hypot(u_kt_win, kt * u_air / i_cut if i_cut > 0 else 0.0)
    u_kt_ref = kt * reference_uncertainty_pct / 100.0
    u_kt_model = _model_form(variants, "kt_nm_per_a", u_kt_stat)
    u_kt = math.sqrt(u_kt_stat**2 + u_kt_model**2 + u_kt_ref**2)
    rel_kt = u_kt / kt
    b, tf = model.b_nm_per_rpm, model.tau_f_nm
    u_b_stat = kt * line.slope_std if np.isfinite(line.slope_std) else 0.0
    u_tf_stat = kt * line.offset_std if np.isfinite(line.offset_std) else 0.0
    budget_rows, unc = _budget(
        (("kt_nm_per_a", kt, u_kt_stat, u_kt_model, "Nm/A"),
         ("b_nm_per_rpm", b, u_b_stat, _model_form(variants, "b_nm_per_rpm", u_b_stat),
          "Nm/rpm"),
         ("tau_f_nm", tf, u_tf_stat, _model_form(variants, "tau_f_nm", u_tf_stat), "Nm")),
        rel_kt=rel_kt, u_kt_ref=u_kt_ref)
    notes: list[str] = []
    if reference_uncertainty_pct == 0.0:
        notes.append("the torque reference's own uncertainty is not included; give "
                     "--torque-uncertainty-pct from the dynamometer's calibration certificate")
    if warm_up is None and method == "improved" and res.thermal_friction is None:
        notes.append("the air cut did not hold its speeds twice and no warm-up was given: the "
                     "bearings' self-heating during the sweep is not referred out (it tilts B "
                     "by about 1-2 %); record the sweep up and back down through the linear "
                     "region")
    budget = pd.DataFrame(budget_rows)
    names = list(recording_names) or [
        f for r in (*air_cuts, *refs) for f in r.meta.source_files[:1]]
    prov = Provenance.now(f"cnctwin calibrate spindle --method {method}", names)
    fit_range = (float(res.fit_range_rpm[0]), float(res.fit_range_rpm[1]))
    n_cal = abs(cal.speed_rpm)
    t_ref = model.reference_temperature_c
    records: dict[str, ParameterRecord] = {
        "spindle.kt_nm_per_a": ParameterRecord(
            kt, unc["kt_nm_per_a"], prov, valid_range=(n_cal, n_cal),
            valid_quantity="speed_rpm"),
        "spindle.viscous_friction_nm_per_rpm": ParameterRecord(
            b, unc["b_nm_per_rpm"], prov, valid_range=fit_range, valid_quantity="speed_rpm"),
        "spindle.coulomb_friction_nm": ParameterRecord(
            tf, unc["tau_f_nm"], prov, valid_range=fit_range, valid_quantity="speed_rpm"),
    }
    fr = res.friction
    if fr.stribeck_a > 0 and np.isfinite(fr.stribeck_speed_rpm):
        records["spindle.stribeck_torque_nm"] = ParameterRecord(fr.stribeck_a * kt, None, prov)
        records["spindle.stribeck_speed_rpm"] = ParameterRecord(fr.stribeck_speed_rpm, None, prov)
    if model.j_kgm2 > 0:
        # u(J): run-ups against run-downs (the friction law's error) and the fit's own
        # scatter, plus Kt's relative uncertainty (J comes from Kt x the current)
        u_fit = inertia_uncertainty(air_cuts[0], model, spindle=spindle)
        u_j = math.hypot(u_fit, model.j_kgm2 * unc["kt_nm_per_a"] / kt) \
            if math.isfinite(u_fit) else None
        records["spindle.inertia_kg_m2"] = ParameterRecord(model.j_kgm2, u_j, prov)
    else:
        records["spindle.inertia_kg_m2"] = ParameterRecord(
            0.015, identified=False,
            reason="not identified: the air cuts' run-ups did not give J (the thesis method "
                   "does not identify it); record run-ups between plateaus with the improved "
                   "method")
        notes.append("inertia J not identified (default kept)")
    if t_ref is not None and np.isfinite(t_ref):
        for key in ("spindle.kt_ref_temperature_c", "spindle.friction_ref_temperature_c"):
            records[key] = ParameterRecord(float(t_ref), None, prov)
    speeds = _speed_table(chain, refs, torques)
    model, law = _speed_law(model, speeds, unc, records, prov, notes)
    if law is not None:
        chain.with_model(model)
        budget.loc[budget["parameter"] == "kt_nm_per_a", "value"] = model.kt_nm_per_a
        for name in ("b_nm_per_rpm", "tau_f_nm"):
            budget.loc[budget["parameter"] == name, "value"] = getattr(model, name)
        for name in ("kt_nm_per_a", "b_nm_per_rpm", "tau_f_nm"):
            budget.loc[budget["parameter"] == name, "combined"] = unc[name]
    return SpindleCalibration(
        method=method, model=model, uncertainty=unc, budget=budget, records=records,
        result=res, windows=windows, variants=variants,
        reference_torque_source="given" if torques[0] is not None else "dynamometer",
        notes=notes, speeds=speeds, flux_law=law)


def _calibrate_with_motor_kt(
    air_cuts: Sequence[Recording], *, method: str, kt_nm_per_a: float,
    kt_tolerance_pct: float, warm_up: Recording | None, spindle: str,
    recording_names: Sequence[str],
) -> SpindleCalibration:
    """Friction and J from the air cuts with Kt from the motor data; no reference cut."""
    import dataclasses

    if not kt_nm_per_a > 0 or not kt_tolerance_pct >= 0:
        raise IdentificationError(f"the motor's torque constant must be > 0 Nm/A and its "
                                  f"tolerance >= 0 %, not {kt_nm_per_a} / {kt_tolerance_pct}")
    kw: dict[str, Any] = {"warm_up": warm_up, "kt_nm_per_a": kt_nm_per_a}
    chain = _chain(method, spindle=spindle).calibrate(air_cuts, None, **kw)
    res = chain.results
    model = res.spindle_model
    if model.b_nm_per_rpm < 0 or model.tau_f_nm < 0:
        raise IdentificationError(
            f"the friction line through the air cut gives B = {model.b_nm_per_rpm:.3g} Nm/rpm "
            f"and tau_f = {model.tau_f_nm:.3g} Nm: a negative friction; record the air cut "
            "up and back down below the motor's rated speed")
    rows = [{"variant": "chosen", "b_nm_per_rpm": model.b_nm_per_rpm,
             "tau_f_nm": model.tau_f_nm}]
    curves = [res.friction]
    for opts in _variant_options(method):
        try:
            vr = _chain(method, spindle=spindle, **opts).calibrate(air_cuts, None, **kw).results
        except IdentificationError:
            continue
        vm = vr.spindle_model
        curves.append(vr.friction)
        rows.append({"variant": ", ".join(f"{k}={v}" for k, v in opts.items()),
                     "b_nm_per_rpm": vm.b_nm_per_rpm, "tau_f_nm": vm.tau_f_nm})
    variants = _lack_of_fit(pd.DataFrame(rows), curves)
    rel_kt = kt_tolerance_pct / 100.0 / math.sqrt(3.0)
    line = res.friction.line
    unc = {"kt_nm_per_a": kt_nm_per_a * rel_kt}
    budget_rows = [{"parameter": "kt_nm_per_a", "value": kt_nm_per_a, "unit": "Nm/A",
                    "statistical": 0.0, "model_form": 0.0, "reference": unc["kt_nm_per_a"],
                    "combined": unc["kt_nm_per_a"]}]
    for name, value, se, unit in (("b_nm_per_rpm", model.b_nm_per_rpm, line.slope_std,
                                   "Nm/rpm"),
                                  ("tau_f_nm", model.tau_f_nm, line.offset_std, "Nm")):
        stat = kt_nm_per_a * se if np.isfinite(se) else 0.0
        mf = _model_form(variants, name, stat)
        ref = abs(value) * rel_kt
        unc[name] = math.sqrt(stat**2 + mf**2 + ref**2)
        budget_rows.append({"parameter": name, "value": value, "unit": unit,
                            "statistical": stat, "model_form": mf, "reference": ref,
                            "combined": unc[name]})
    names = list(recording_names) or [f for r in air_cuts for f in r.meta.source_files[:1]]
    prov = Provenance.now(f"cnctwin calibrate spindle --method {method} --kt-nm-per-a "
                          f"{kt_nm_per_a:g} (motor data, +-{kt_tolerance_pct:g} %)", names)
    fit_range = (float(res.fit_range_rpm[0]), float(res.fit_range_rpm[1]))
    records: dict[str, ParameterRecord] = {
        "spindle.kt_nm_per_a": ParameterRecord(kt_nm_per_a, unc["kt_nm_per_a"], prov),
        "spindle.viscous_friction_nm_per_rpm": ParameterRecord(
            model.b_nm_per_rpm, unc["b_nm_per_rpm"], prov, valid_range=fit_range,
            valid_quantity="speed_rpm"),
        "spindle.coulomb_friction_nm": ParameterRecord(
            model.tau_f_nm, unc["tau_f_nm"], prov, valid_range=fit_range,
            valid_quantity="speed_rpm"),
        "spindle.flux_base_speed_rpm": ParameterRecord(
            0.0, identified=False,
            reason="Kt from the motor data holds below the motor's rated speed; how it falls "
                   "above (constant power) needs reference cuts at two or more speeds"),
    }
    if model.j_kgm2 > 0:
        records["spindle.inertia_kg_m2"] = ParameterRecord(model.j_kgm2, None, prov)
    t_ref = model.reference_temperature_c
    if t_ref is not None and np.isfinite(t_ref):
        for key in ("spindle.kt_ref_temperature_c", "spindle.friction_ref_temperature_c"):
            records[key] = ParameterRecord(float(t_ref), None, prov)
    notes = [f"Kt {kt_nm_per_a:g} Nm/A from the motor data, +-{kt_tolerance_pct:g} %: every "
             f"cutting torque the twin estimates carries that tolerance (standard "
             f"uncertainty {100 * rel_kt:.1f} %), besides the friction's; one reference cut "
             "with a dynamometer brings Kt to about 0.1-0.2 % (docs/validation-calibration.md)"]
    empty = pd.DataFrame(columns=["start_cycle", "end_cycle", "speed_rpm", "current_a",
                                  "air_current_a", "torque_nm", "kt_nm_per_a"])
    return SpindleCalibration(
        method=method, model=dataclasses.replace(model), uncertainty=unc,
        budget=pd.DataFrame(budget_rows), records=records, result=res, windows=empty,
        variants=variants, reference_torque_source="motor data", notes=notes)


def _lack_of_fit(variants: pd.DataFrame, curves: Sequence[FrictionCurve], *,
                 level: float = LACK_OF_FIT_LEVEL) -> pd.DataFrame:
    """Mark the fit variants whose friction law fits its plateaus as well as the chosen one's.

    Parameters
    ----------
    variants : pandas.DataFrame
        One row per fit, the chosen one first.
    curves : sequence of FrictionCurve
        The friction curve of each row, in the same order.
    level : float
        Level of the F test.

    Returns
    -------
    pandas.DataFrame
        ``variants`` with ``residual_ratio`` (the variant's residual variance per degree of
        freedom over the chosen fit's) and ``counted`` (the ratio within the F distribution's
        ``level`` point for the two fits' residual degrees of freedom; the chosen fit always
        counts), a copy.
    """
    from scipy.stats import f as f_dist

    chosen = curves[0]
    s2_c = chosen.residual_variance_a2()
    ratio, counted = [], []
    for k, c in enumerate(curves):
        r = c.residual_variance_a2() / s2_c if s2_c > 0 else float("nan")
        ok = k == 0 or not np.isfinite(r) or r <= float(
            f_dist.ppf(level, c.residual_dof(), chosen.residual_dof()))
        ratio.append(r)
        counted.append(bool(ok))
    return variants.assign(residual_ratio=ratio, counted=counted)


def _model_form(variants: pd.DataFrame, col: str, u_stat: float) -> float:
    """Model-form standard uncertainty of ``col``: the counted variants' spread beyond u_stat.

    The variants fit overlapping sets of the same plateaus, so their standard deviation holds
    the noise the statistical term already carries; only what exceeds it in quadrature is
    taken as the law's misfit, so that the noise is not counted twice. With the statistical
    term right (tests/calibration/test_friction_uncertainty.py) the whole spread counted had
    made B's interval 1.4x its error's scatter on 60 simulated spindles.
    """
    x = variants.loc[variants["counted"], col].to_numpy(dtype=np.float64)
    spread = float(np.std(x, ddof=1)) if x.size > 1 else 0.0
    return math.sqrt(max(spread**2 - u_stat**2, 0.0))


def _base_speed_hint(chain: TwinChain, refs: list[Recording],
                     torques: list[float | None]) -> float | None:
    """The base speed the references show (None: one speed, or no flux weakening seen)."""
    if len(refs) < 2:
        return None
    sp = _speed_table(chain, refs, torques)
    n = sp["speed_rpm"].to_numpy(dtype=np.float64)
    if float(np.ptp(n)) <= 0.05 * float(n.max()):
        return None
    law = fit_flux_law(n, sp["kt_nm_per_a"].to_numpy(dtype=np.float64))
    return law.base_speed_rpm if law.base_speed_rpm > 0 else None


def _speed_table(chain: TwinChain, refs: list[Recording],
                 torques: list[float | None]) -> pd.DataFrame:
    """Kt of each reference cut at its speed (mean of its full windows) [Nm/A]."""
    rows = []
    for k, (rec, tq) in enumerate(zip(refs, torques, strict=True)):
        w = chain.calibration_windows(rec, reference_torque_nm=tq)
        full = w[(w["end_cycle"] - w["start_cycle"] + 1)
                 >= 0.5 * chain.options.window_s * rec.fs_hz]
        kt = full["kt_nm_per_a"].to_numpy(dtype=np.float64)
        kt = kt[np.isfinite(kt)]
        if kt.size == 0:
            raise IdentificationError(f"reference cut {k + 1}: no full averaging window in "
                                      "its cut (the cut is shorter than the window)")
        rows.append({"reference": k + 1, "speed_rpm": float(np.mean(np.abs(full["speed_rpm"]))),
                     "kt_nm_per_a": float(np.mean(kt)),
                     "kt_se": float(np.std(kt, ddof=1) / math.sqrt(kt.size))
                     if kt.size > 1 else 0.0,
                     "torque_nm": float(np.mean(np.abs(full["torque_nm"]))),
                     "current_a": float(np.mean(np.abs(full["current_a"])))})
    return pd.DataFrame(rows)


def _budget(rows: Sequence[tuple[str, float, float, float, str]], *, rel_kt: float,
            u_kt_ref: float) -> tuple[list[dict[str, Any]], dict[str, float]]:
    """The uncertainty budget of Kt, B and tau_f: statistical, model form, reference.

    B and tau_f are the air-cut line's slope and offset in amperes times Kt, so Kt's whole
    relative uncertainty (its reference included) carries over to them; Kt's own reference
    term is the torque reference's uncertainty.
    """
    out = []
    unc: dict[str, float] = {}
    for name, value, stat, model_form, unit in rows:
        ref = abs(value) * rel_kt if name != "kt_nm_per_a" else u_kt_ref
        comb = math.sqrt(stat**2 + model_form**2 + ref**2)
        unc[name] = comb
        out.append({"parameter": name, "value": value, "unit": unit, "statistical": stat,
                    "model_form": model_form, "reference": ref, "combined": comb})
    return out, unc


def _speed_law(model: SpindleModel, speeds: pd.DataFrame, unc: dict[str, float],
               records: dict[str, ParameterRecord], prov: Provenance, notes: list[str],
               ) -> tuple[SpindleModel, FluxLawFit | None]:
    """Fit the speed law of Kt where the references span speeds; record it (or why not)."""
    import dataclasses

    n = speeds["speed_rpm"].to_numpy(dtype=np.float64)
    lo, hi = float(n.min()), float(n.max())
    kt_rec = records["spindle.kt_nm_per_a"]
    if hi - lo <= 0.05 * hi:
        records["spindle.kt_nm_per_a"] = dataclasses.replace(kt_rec, valid_range=(lo, hi))
        records["spindle.flux_base_speed_rpm"] = ParameterRecord(
            0.0, identified=False,
            reason=f"Kt was calibrated at one speed ({hi:.0f} rpm): how it changes with speed "
                   "is not known and estimates at other speeds are extrapolations (flagged); "
                   f"add reference cuts at other speeds (e.g. {0.75 * hi:.0f} and "
                   f"{1.25 * hi:.0f} rpm)")
        notes.append(f"Kt holds at {hi:.0f} rpm only; reference cuts at two or more speeds "
                     "give its speed law")
        return dataclasses.replace(model, kt_valid_speed_rpm=(lo, hi)), None
    k = speeds["kt_nm_per_a"].to_numpy(dtype=np.float64)
    law = fit_flux_law(n, k)
    scale = law.kt_nm_per_a / model.kt_nm_per_a
    new = dataclasses.replace(
        model, kt_nm_per_a=law.kt_nm_per_a, b_nm_per_rpm=model.b_nm_per_rpm * scale,
        tau_f_nm=model.tau_f_nm * scale, j_kgm2=model.j_kgm2 * scale,
        flux_base_speed_rpm=law.base_speed_rpm, flux_exponent=law.exponent,
        kt_valid_speed_rpm=(lo, hi))
    rel_kt = unc["kt_nm_per_a"] / model.kt_nm_per_a
    u_rel = math.hypot(rel_kt, law.rms_rel)
    unc["kt_nm_per_a"] = law.kt_nm_per_a * u_rel
    for key in ("b_nm_per_rpm", "tau_f_nm"):
        unc[key] = unc[key] * scale
    records["spindle.kt_nm_per_a"] = dataclasses.replace(
        kt_rec, value=law.kt_nm_per_a, uncertainty=unc["kt_nm_per_a"], valid_range=(lo, hi))
    for key, attr in (("spindle.viscous_friction_nm_per_rpm", "b_nm_per_rpm"),
                      ("spindle.coulomb_friction_nm", "tau_f_nm")):
        r = records[key]
        records[key] = dataclasses.replace(r, value=getattr(new, attr),
                                           uncertainty=unc["b_nm_per_rpm" if "visc" in key
                                                           else "tau_f_nm"])
    for key in ("spindle.stribeck_torque_nm", "spindle.inertia_kg_m2"):
        r0 = records.get(key)
        if r0 is not None and r0.identified:
            records[key] = dataclasses.replace(
                r0, value=r0.value * scale,
                uncertainty=r0.uncertainty * scale if r0.uncertainty is not None else None)
    if law.base_speed_bound == "at least":
        records["spindle.flux_base_speed_rpm"] = ParameterRecord(
            0.0, identified=False,
            reason=f"Kt is constant over {lo:.0f}-{hi:.0f} rpm: no flux weakening there; the "
                   f"base speed lies above {hi:.0f} rpm and estimates above it are "
                   "extrapolations")
    else:
        # standard uncertainty of n_b: refit with each Kt moved by its standard uncertainty
        u_i = np.hypot(speeds["kt_se"].to_numpy(dtype=np.float64), k * rel_kt)
        d = []
        for i in range(k.size):
            kp, km = k.copy(), k.copy()
            kp[i] += u_i[i]
            km[i] -= u_i[i]
            d.append(0.5 * (fit_flux_law(n, kp).base_speed_rpm
                            - fit_flux_law(n, km).base_speed_rpm))
        u_nb = float(np.sqrt(np.sum(np.square(d))))
        records["spindle.flux_base_speed_rpm"] = ParameterRecord(
            law.base_speed_rpm, u_nb, prov, valid_range=(lo, hi), valid_quantity="speed_rpm")
        if law.base_speed_bound == "at most":
            notes.append(f"every reference cut ran above the base speed: Kt x speed is "
                         f"constant over {lo:.0f}-{hi:.0f} rpm; the base speed is at most "
                         f"{lo:.0f} rpm and Kt below {lo:.0f} rpm is an extrapolation")
    if law.exponent_fitted:
        records["spindle.flux_exponent"] = ParameterRecord(law.exponent, None, prov,
                                                           valid_range=(lo, hi),
                                                           valid_quantity="speed_rpm")
    elif law.base_speed_bound != "at least":
        records["spindle.flux_exponent"] = ParameterRecord(
            1.0, identified=False,
            reason="constant power assumed (flux as 1/n above the base speed); reference cuts "
                   "at three or more speeds fit the exponent")
    return new, law
