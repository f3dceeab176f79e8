"""HTML reports of a calibration: the spindle (plateaus, fit and residuals, parameters,
reference cut) and the feed axes (parameters, friction runs, error signals)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from cnctwin.analysis.align import external_on_hf
from cnctwin.analysis.filters import lowpass
from cnctwin.analysis.segments import spindle_speed_rpm
from cnctwin.calibration.axes import AxesCalibration
from cnctwin.calibration.spindle import METHODS, SpindleCalibration
from cnctwin.machine import Machine
from cnctwin.recording import Recording
from cnctwin.report import Report
from cnctwin.servo.identify import AxisFrictionFit
from cnctwin.twin import align_dynamometer

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["axes_calibration_report", "spindle_calibration_report"]


def _fit_figure(cal: SpindleCalibration) -> Figure:
    import matplotlib.pyplot as plt

    res = cal.result
    stats = res.air_cut_stats
    n = stats["speed_rpm"].abs().to_numpy(dtype=np.float64)
    i = stats["current_a"].abs().to_numpy(dtype=np.float64)
    lo, hi = res.fit_range_rpm
    inside = (n >= lo) & (n <= hi)
    fig, (ax, axr) = plt.subplots(2, 1, figsize=(8, 6), sharex=True,
                                  gridspec_kw={"height_ratios": [3, 1.3]})
    ax.plot(n[~inside], i[~inside], "o", ms=3, color="0.6", label="plateaus outside the fit")
    ax.plot(n[inside], i[inside], "o", ms=4, color="C0", label="plateaus fitted")
    grid = np.linspace(max(lo, 1.0), hi, 300)
    ax.plot(grid, res.friction.current_a(grid), "-", color="C3",
            label=f"fit ({res.friction.model})")
    ax.set_ylabel("mean spindle current [A]")
    ax.legend(loc="upper left", fontsize=8)
    ax.grid(alpha=0.3)
    resid = (i - res.friction.current_a(n)) * 1000.0
    axr.axhline(0.0, color="0.5", lw=0.8)
    axr.plot(n[inside], resid[inside], "o", ms=3, color="C0")
    axr.set_ylabel("residual [mA]")
    axr.set_xlabel("spindle speed [rpm]")
    axr.grid(alpha=0.3)
    ax.set_xlim(0, max(float(np.nanmax(n)) if n.size else hi, hi) * 1.02)
    fig.tight_layout()
    return fig


def _reference_figure(cal: SpindleCalibration, reference: Recording, spindle: str,
                      torque_nm: float | None) -> Figure:
    import matplotlib.pyplot as plt

    c = cal.result.calibration
    fs = reference.fs_hz
    cyc = reference.cycles
    a = int(np.searchsorted(cyc, c.region_start_cycle - round(1.0 * fs)))
    b = int(np.searchsorted(cyc, c.region_end_cycle + round(0.3 * fs), side="right"))
    cur = reference.signal(f"CURRENT|{spindle}").to_numpy(dtype=np.float64)
    speed, _ = spindle_speed_rpm(reference, spindle)
    est = cal.model.cutting_torque(np.abs(cur), np.abs(speed), accel_term=True, fs_hz=fs)
    t = (cyc - cyc[a]) / fs
    fig, ax = plt.subplots(figsize=(8, 3.8))
    ax.plot(t[a:b], lowpass(est[a:b], 10.0, fs_hz=fs, order=2), lw=1.0, color="C0",
            label="twin: cutting torque from current (10 Hz)")
    if torque_nm is None and "dynamometer" in reference.external:
        al = align_dynamometer(reference, spindle=spindle)
        dyn = external_on_hf(al, "dynamometer", columns=["mz_nm"])["mz_nm"].to_numpy()
        ok = np.isfinite(dyn[a:b])
        if ok.sum() > 10:
            ax.plot(t[a:b][ok], lowpass(np.abs(dyn[a:b][ok]), 10.0, fs_hz=fs, order=2), lw=1.0,
                    color="C3", label="dynamometer Mz (10 Hz)")
    else:
        ax.axhline(abs(c.torque_nm), color="C3", ls="--", label="given reference torque")
    w0 = (int(np.searchsorted(cyc, c.start_cycle)) - a) / fs
    w1 = (int(np.searchsorted(cyc, c.end_cycle)) - a) / fs
    ax.axvspan(w0, w1, color="C2", alpha=0.15, label="calibration window")
    ax.set_xlabel("time from 1 s before the cut [s]")
    ax.set_ylabel("torque [Nm]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    return fig


def spindle_calibration_report(
    cal: SpindleCalibration,
    reference: Recording | None,
    path: str | Path,
    *,
    spindle: str = "SP1",
    reference_torque_nm: float | None = None,
    machine_path: str = "",
) -> Path:
    """Write the HTML report of a spindle calibration.

    Parameters
    ----------
    cal : SpindleCalibration
        The result of :func:`~cnctwin.calibration.calibrate_spindle`.
    reference : Recording or None
        The reference cut it was calibrated with (dynamometer attached, if any); None when
        Kt came from the motor data.
    path : str or Path
        The HTML file.
    spindle : str
        Spindle axis.
    reference_torque_nm : float, optional
        The given reference torque, if no dynamometer was used [Nm].
    machine_path : str
        The machine file the values were written to (named in the report).

    Returns
    -------
    pathlib.Path
    """
    res = cal.result
    rep = Report("Spindle calibration",
                 subtitle=f"{METHODS[cal.method]}; machine file {machine_path or '-'}")
    sec = rep.section("Parameters")
    rows = []
    for _, r in cal.budget.iterrows():
        lo95 = r["value"] - 1.96 * r["combined"]
        hi95 = r["value"] + 1.96 * r["combined"]
        rows.append({"parameter": r["parameter"], "value": f"{r['value']:.5g}",
                     "standard uncertainty": f"{r['combined']:.2g}",
                     "relative [%]": f"{100 * r['combined'] / abs(r['value']):.2f}",
                     "95 % interval": f"{lo95:.5g} ... {hi95:.5g}", "unit": r["unit"]})
    m = cal.model
    rows.append({"parameter": "j_kgm2", "value": f"{m.j_kgm2:.4g}" if m.j_kgm2 > 0 else "-",
                 "standard uncertainty": "-", "relative [%]": "-", "95 % interval": "-",
                 "unit": "kg m^2"})
    sec.table(pd.DataFrame(rows), caption="Identified spindle parameters (thesis Eq. 4.4: "
              "Kt = 1.04 Nm/A, B = 8.42e-5 Nm/rpm, tau_f = 0.35 Nm on the thesis machine); "
              "95 % interval = value +- 1.96 standard uncertainties")
    tref = m.reference_temperature_c
    sec.text(f"Friction fit over {res.fit_range_rpm[0]:.0f}-{res.fit_range_rpm[1]:.0f} rpm "
             f"({res.friction.line.n_points} plateaus, R^2 = {res.friction.line.r2:.5f}); Kt "
             f"at {abs(res.calibration.speed_rpm):.0f} rpm"
             + (f"; values referred to a motor temperature of {tref:.1f} degC" if tref else "")
             + ".")
    for note in cal.notes:
        sec.text(note, note=True)
    budget = cal.budget.copy()
    sec.table(budget, caption="Uncertainty budget: standard uncertainties per component "
              "[unit of the parameter], combined in quadrature", float_format="{:.3g}")
    sec2 = rep.section("Air-cut plateaus and friction fit")
    sec2.figure(_fit_figure(cal), caption="Mean spindle current per constant-speed plateau "
                "(thesis Fig. 4.1/4.2 analogue) with the fitted friction curve and the residuals "
                "against it; with the self-heating fitted out the curve is the state at the "
                "start of the sweep, and the plateaus held later (warmer) lie a few mA below")
    if res.thermal_friction is not None:
        th = res.thermal_friction
        sec2.text("The air cut held its speeds twice: the bearings' self-heating was fitted "
                  f"out (viscous drift {th.viscous_drift_per_energy:.3g}, Coulomb drift "
                  f"{th.coulomb_drift_per_energy:.3g} per A rpm s of friction energy); the "
                  "friction values refer to the start of the sweep.")
    st = res.air_cut_stats[["speed_rpm", "current_a", "current_std_a", "duration_s"]].copy()
    st.columns = ["speed [rpm]", "mean current [A]", "current std [A]", "duration [s]"]
    sec2.table(st, caption="Plateaus found", float_format="{:.4g}")
    sec2.table(cal.variants, caption="Fit variants behind the model-form uncertainty: a "
               "variant counts ('counted') where the law fits its plateaus as well as the "
               "chosen fit's (its residual variance over the chosen one's, 'residual_ratio', "
               "within the F distribution's 95 % point); the model form is the counted "
               "variants' spread beyond the statistical uncertainty",
               float_format="{:.5g}")
    if not cal.speeds.empty and len(cal.speeds) > 1:
        sp = cal.speeds.copy()
        sp.columns = ["reference", "speed [rpm]", "Kt [Nm/A]", "Kt standard error [Nm/A]",
                      "torque [Nm]", "current [A]"]
        law = cal.flux_law
        sec.table(sp, caption="Kt of each reference cut at its speed; the speed law "
                  + (f"Kt(n) = {law.kt_nm_per_a:.4g} (n_b/n)^{law.exponent:.2f} above "
                     f"n_b = {law.base_speed_rpm:.0f} rpm" if law is not None and
                     law.base_speed_rpm > 0 else "shows no change"), float_format="{:.4g}")
    if reference is None:
        return rep.write(path)
    sec3 = rep.section("Reference cut: predicted vs measured torque")
    sec3.figure(_reference_figure(cal, reference, spindle, reference_torque_nm),
                caption="Reference cut: the twin's cutting torque from the spindle current "
                "and the measured torque (thesis Fig. 4.5 analogue)")
    w = cal.windows[["start_cycle", "end_cycle", "speed_rpm", "current_a", "air_current_a",
                     "torque_nm", "kt_nm_per_a"]].copy()
    w.columns = ["start cycle", "end cycle", "speed [rpm]", "current [A]", "air current [A]",
                 "torque [Nm]", "Kt [Nm/A]"]
    sec3.table(w, caption="Consecutive windows of the reference cut (the first is the "
               "calibration window)", float_format="{:.5g}")
    return rep.write(path)


def _axis_friction_figure(axis: str, fits: list[AxisFrictionFit], position_unit: str
                          ) -> Figure | None:
    """Run means (velocity, effort) of every recording and the fitted friction law."""
    from matplotlib.figure import Figure

    if not fits:
        return None
    fig = Figure(figsize=(7.0, 3.4))
    ax = fig.add_subplot(1, 1, 1)
    vmax = max((max(abs(v) for v in f.run_velocity) for f in fits if f.run_velocity),
               default=0.0)
    for k, f in enumerate(fits):
        if not f.run_velocity:
            continue
        size = 10.0 + 40.0 * np.asarray(f.run_cycles) / max(max(f.run_cycles), 1.0)
        ax.scatter(f.run_velocity, f.run_effort, s=size, alpha=0.7,
                   label=f"recording {k + 1}: run means (size: run length)")
        v = np.linspace(-vmax, vmax, 201)
        ax.plot(v, f.coulomb * np.sign(v) + f.viscous * v + f.offset, lw=1.0,
                label=f"Fc {f.coulomb:.4g} +- {f.se_coulomb:.2g} {f.unit}, "
                      f"b {f.viscous:.3g} +- {f.se_viscous:.2g}")
    ax.set_xlabel(f"velocity [{position_unit}/s]")
    ax.set_ylabel(f"{fits[0].signal} [{fits[0].unit}]")
    ax.set_title(f"{axis}: friction on the constant-velocity air runs")
    ax.axhline(0.0, color="0.7", lw=0.6)
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def axes_calibration_report(
    cal: AxesCalibration,
    recordings: Sequence[Recording],
    path: str | Path,
    *,
    machine: Machine,
    machine_path: str = "",
) -> Path:
    """Write the HTML report of a feed-axis calibration (``cnctwin calibrate axes``).

    Parameters
    ----------
    cal : AxesCalibration
        The result of :func:`~cnctwin.calibration.calibrate_axes`.
    recordings : sequence of Recording
        The recordings it was identified from (for the error-signal figures).
    path : str or Path
        The HTML file.
    machine : Machine
        The machine description (rotary axes, units).
    machine_path : str
        The machine file the values were written to (named in the report).

    Returns
    -------
    pathlib.Path
    """
    from cnctwin.exceptions import CnctwinError
    from cnctwin.machine import parameter_unit
    from cnctwin.servo.figures import plot_error_signals

    rep = Report("Feed-axis calibration",
                 subtitle=f"position loop and friction per axis (thesis ch. 3.1); machine "
                          f"file {machine_path or '-'}")
    rows = []
    for key, r in cal.records.items():
        axis, name = key.split(".")[1], key.split(".")[2]
        rot = machine.axis(axis).rotary if axis in machine.axis_names else False
        u = r.uncertainty
        rows.append({
            "axis": axis, "parameter": name,
            "value": f"{r.value:.5g}" if r.identified else "-",
            "standard uncertainty": f"{u:.2g}" if r.identified and u is not None else "-",
            "95 % interval": (f"{r.value - 1.96 * u:.5g} ... {r.value + 1.96 * u:.5g}"
                              if r.identified and u is not None else "-"),
            "unit": parameter_unit(key, rotary=rot),
            "not identified: why": "" if r.identified else r.reason})
    sec = rep.section("Parameters")
    sec.table(pd.DataFrame(rows), caption="What was written to the machine file (parameter = "
              "its key in [axes.<axis>]); a value not identified keeps the machine's default "
              "and says why")
    for note in cal.notes:
        sec.text(note, note=True)
    for axis, idents in cal.identifications.items():
        s = rep.section(f"Axis {axis}")
        fits = [i.friction.get("TORQUE") or i.friction.get("CURRENT") for i in idents]
        fig = _axis_friction_figure(axis, [f for f in fits if f is not None],
                                    idents[0].position_unit)
        if fig is not None:
            s.figure(fig, caption="Mean effort of each constant-velocity run outside the cuts "
                     "against its velocity, with the fitted law Fc sign(v) + b v (+ offset); "
                     "runs weighted by their length")
        else:
            s.text(f"{axis}: no friction fit (too few constant-velocity air runs; the "
                   "parameter table says why)", note=True)
        for rec in recordings:
            try:
                s.figure(plot_error_signals(rec, axis), caption=f"{axis}: following error, "
                         "controller difference and contour deviation of the first recording "
                         "in which it moves (thesis Figs. 3.2/3.3)")
                break
            except (CnctwinError, KeyError, ValueError):
                continue
    if cal.not_moving:
        rep.section("Axes that did not move").text(
            f"{', '.join(cal.not_moving)}: in none of the recordings; their parameters are "
            "not identified (the machine file says so for each key).")
    return rep.write(path)
