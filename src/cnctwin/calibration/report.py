"""HTML report of a spindle calibration: plateaus, fit and residuals, parameters, reference cut."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from cnctwin.analysis.align import external_on_hf
from cnctwin.analysis.filters import lowpass
from cnctwin.analysis.segments import spindle_speed_rpm
from cnctwin.calibration.spindle import METHODS, SpindleCalibration
from cnctwin.recording import Recording
from cnctwin.report import Report
from cnctwin.twin import align_dynamometer

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["spindle_calibration_report"]


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
    sec2.table(cal.variants, caption="Fit variants behind the model-form uncertainty",
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
