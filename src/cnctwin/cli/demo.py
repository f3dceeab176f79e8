"""``cnctwin demo``: simulate the thesis campaign, calibrate, estimate, write the HTML report.

Steps: simulate the air-cut sweep, the warm-up and the drilling validation with the
dynamometer (:mod:`cnctwin.sim.scenarios`), calibrate the spindle twin with the thesis method
and the improved method (:class:`cnctwin.twin.TwinChain`), print the validation table beside
thesis Table 4.1 and write a self-contained HTML report (:class:`cnctwin.report.Report`) with
the analogues of thesis Figures 3.6-3.9 and 4.1-4.5 and a section on the real
Capture4Analysis recording.

Extension hook
--------------
Other topics add report sections by appending a builder to :data:`DEMO_SECTIONS`::

    from cnctwin.cli.demo import DEMO_SECTIONS, DemoContext

    def position_loop_section(ctx: DemoContext) -> None:
        sec = ctx.report.section("Position loop (issue #5)")
        ...                     # ctx.simulate(...), ctx.quick, ctx.out_dir, ctx.progress(...)

    DEMO_SECTIONS.append(position_loop_section)

Builders run in list order after the spindle sections; each gets the :class:`DemoContext`
(campaign recordings, calibrated chains, report, console, options). A builder that raises is
reported in its own section and does not stop the demo.
"""

from __future__ import annotations

import contextlib
import io
import math
import time
import traceback
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from cnctwin.validation.context import DemoContext

if TYPE_CHECKING:
    from matplotlib.figure import Figure
    from rich.console import Console

    from cnctwin.recording import Recording
    from cnctwin.sim.scenarios import ScenarioResult
    from cnctwin.twin import TwinChain

__all__ = ["DEMO_SECTIONS", "THESIS_TABLE_4_1", "DemoContext", "run_demo"]

REAL_C4A = Path("tests/data/real/capture4analysis/"
                "example_data_ff429d74-6482-4d4f-80e1-31419d9bd56c.json")

THESIS_TABLE_4_1 = pd.DataFrame(
    [
        ("Cast iron", 2400.0, 0.3, 4.32, 3.99, 3.94, 1.25),
        ("Cast iron", 3200.0, 0.4, 5.29, 4.83, 4.88, 1.02),
        ("Steel", 2800.0, 0.14, 3.77, 3.37, 3.34, 0.9),
        ("Steel", 3200.0, 0.125, 3.66, 3.18, 3.19, 0.31),
    ],
    columns=["workpiece", "speed_rpm", "feed_mm_per_rev", "current_a", "torque_nm",
             "predicted_torque_nm", "error_pct"],
)
"""Thesis Table 4.1 (measured current, measured and predicted mean cutting torque, error)."""

_MATERIAL_LABEL = {"aisi1045": "Steel", "grey_cast_iron": "Cast iron"}


SectionBuilder = Callable[[DemoContext], None]


# ====================================================================== figures
def _fig(nrows: int = 1, ncols: int = 1, *, w: float = 10.0, h: float = 3.2) -> tuple[Any, Any]:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w, h * nrows), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, ncols, squeeze=False)
    return fig, axes


def _cut_frame(rec: Recording, pad_s: float = 0.3) -> tuple[pd.DataFrame, Any]:
    """HF spindle signals + aligned dynamometer torque around the first cut."""
    from cnctwin.analysis.align import external_on_hf
    from cnctwin.twin import align_dynamometer, find_cuts

    a = align_dynamometer(rec)
    reg = find_cuts(a).iloc[0]
    dyn = external_on_hf(a, "dynamometer", columns=["mz_nm"])["mz_nm"]
    cols = [c for c in ("CURRENT|SP1", "TORQUE|SP1", "POWER|SP1", "LOAD|SP1") if a.has(c)]
    df = a.hf[cols].copy()
    df["dynamometer mz_nm"] = dyn.to_numpy()
    pad = round(pad_s * a.fs_hz)
    lo = max(0, int(np.searchsorted(a.cycles, int(reg["start_cycle"]))) - pad)
    hi = min(len(df), int(np.searchsorted(a.cycles, int(reg["end_cycle"]))) + pad)
    return df.iloc[lo:hi], reg


def fig_cut_raw_lowpass(rec: Recording) -> Figure:
    """Thesis Fig. 3.6: edge spindle signals and dynamometer torque, raw and 10 Hz low-pass."""
    from cnctwin.analysis.filters import lowpass

    df, _ = _cut_frame(rec)
    t = (df.index.to_numpy() - df.index[0]) / 500.0
    fig, axes = _fig(2, 1, h=3.0)
    for k, (title, filt) in enumerate((("a) raw", False), ("b) low-pass 10 Hz", True))):
        ax = axes[k][0]
        for c in df.columns:
            y = df[c].to_numpy(dtype=float)
            y = np.nan_to_num(y, nan=float(np.nanmean(y)))
            if filt:
                y = lowpass(y, 10.0, fs_hz=500.0)
            if c.startswith(("POWER", "LOAD")):
                y = y / max(float(np.nanmax(np.abs(y))), 1e-9) * 5.0
                c = f"{c} (scaled)"
            ax.plot(t, y, lw=0.8, label=c)
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("time [s]")
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7, ncol=3)
    return fig


def fig_cut_correlation(rec: Recording) -> Figure:
    """Thesis Fig. 3.7: correlation heatmaps raw / 100 / 50 / 10 Hz over a cut."""
    from cnctwin.analysis.correlation import correlation_matrix, plot_correlation_heatmaps

    df, _ = _cut_frame(rec, pad_s=0.0)
    df = df.interpolate(limit_direction="both")
    mats = correlation_matrix(df, fs_hz=500.0)
    return plot_correlation_heatmaps(mats)


def fig_field_weakening(stats: pd.DataFrame, fw_rpm: float | None) -> Figure:
    """Thesis Fig. 4.1: mean Iq and smoothed |I| versus speed; field-weakening onset."""
    fig, axes = _fig(1, 1, w=8.0, h=3.6)
    ax = axes[0][0]
    n = stats["speed_rpm"].to_numpy()
    ax.plot(n, stats["current_a"], ".-", ms=3, label="mean q-axis current (HF CURRENT)")
    col = "CURRENT_ABS_SMOOTHED|SP1 (LF) mean"
    if col in stats:
        ax.plot(n, stats[col], ".-", ms=3, label="mean |I| smoothed (LF r0068)")
    if fw_rpm is not None:
        ax.axvline(fw_rpm, color="k", ls="--", lw=1, label=f"field weakening {fw_rpm:.0f} rpm")
    ax.set_ylim(0, max(2.0, float(stats["current_a"].max()) * 1.5))
    ax.set_xlabel("spindle speed [rpm]")
    ax.set_ylabel("current [A]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return fig


def fig_regression(chains: dict[str, TwinChain]) -> Figure:
    """Thesis Fig. 4.2: friction fit on the linear region, thesis and improved."""
    fig, axes = _fig(1, len(chains), w=11.0, h=3.6)
    for k, (name, ch) in enumerate(chains.items()):
        r = ch.results
        st = r.air_cut_stats
        ax = axes[0][k]
        n = st["speed_rpm"].to_numpy()
        ax.plot(n, st["current_a"], "o", ms=3, label="plateau means")
        lo, hi = r.fit_range_rpm
        x = np.linspace(lo, hi, 100)
        f = r.friction.line
        ax.plot(x, r.friction.current_a(x), "r-", lw=1.5,
                label=f"{r.friction.model}: I = {f.slope_a_per_rpm:.3g} n + {f.offset_a:.3f}"
                      f" (R² {f.r2:.3f})")
        ax.axvspan(lo, hi, color="r", alpha=0.07)
        ax.set_xlim(0, min(float(n.max()), 1.6 * hi))
        ax.set_ylim(float(st["current_a"].min()) * 0.9,
                    float(st.loc[st["speed_rpm"] <= 1.6 * hi, "current_a"].max()) * 1.05)
        ax.set_title(f"{name}: fit range {lo:.0f}-{hi:.0f} rpm", fontsize=9)
        ax.set_xlabel("spindle speed [rpm]")
        ax.set_ylabel("mean current [A]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    return fig


def fig_stator(sweep: Recording, stats: pd.DataFrame, poles: int, speed_rpm: float) -> Figure:
    """Thesis Fig. 4.3: stator-frequency band-pass and removal at ~3200 rpm."""
    from cnctwin.analysis.filters import extract_stator_component, remove_stator_component

    k = int(np.argmin(np.abs(stats["speed_rpm"].to_numpy() - speed_rpm)))
    row = stats.iloc[k]
    lo = int(np.searchsorted(sweep.cycles, int(row["start_cycle"])))
    hi = int(np.searchsorted(sweep.cycles, int(row["end_cycle"]), side="right"))
    i = sweep.hf["CURRENT|SP1"].to_numpy(dtype=float)[lo:hi]
    n = float(row["speed_rpm"])
    fig, axes = _fig(2, 1, h=2.8)
    t = np.arange(i.size) / sweep.fs_hz
    try:
        comp = extract_stator_component(i, n, poles=poles, fs_hz=sweep.fs_hz)
        clean = remove_stator_component(i, n, poles=poles, fs_hz=sweep.fs_hz)
    except Exception as exc:  # the folded line can touch 0 Hz / Nyquist
        axes[0][0].text(0.1, 0.5, f"stator line not separable at {n:.0f} rpm: {exc}")
        return fig
    axes[0][0].plot(t, comp, lw=0.8)
    axes[0][0].set_title(f"a) band-passed stator component, {n:.0f} rpm, {poles} poles "
                         f"(Eq. 4.1: {n * poles / 120:.1f} Hz, folded at 500 Hz sampling)",
                         fontsize=9)
    axes[1][0].plot(t, i, lw=0.6, label=f"original (mean {i.mean():.4f} A)")
    axes[1][0].plot(t, clean, lw=0.8, label=f"stator line removed (mean {clean.mean():.4f} A)")
    axes[1][0].set_title("b) original and filtered current", fontsize=9)
    axes[1][0].legend(fontsize=7)
    for ax in (axes[0][0], axes[1][0]):
        ax.set_xlabel("time [s]")
        ax.grid(alpha=0.3)
    return fig


def fig_temperature(runs: list[Recording]) -> Figure:
    """Thesis Fig. 4.4: motor temperature and spindle current during the warm-up."""
    from cnctwin.analysis.segments import lf_on_hf

    fig, axes = _fig(1, 1, w=9.0, h=3.6)
    ax = axes[0][0]
    ax2 = ax.twinx()
    for rec in runs:
        temp = lf_on_hf(rec, "MOTOR_TEMP", "SP1")
        i = rec.hf["CURRENT|SP1"].to_numpy(dtype=float)
        blk = round(5.0 * rec.fs_hz)
        nb = i.size // blk
        t = (np.arange(nb) + 0.5) * blk / rec.fs_hz / 60.0
        n = float(np.nanmedian(rec.hf["CMD_SPEED|SP1"].to_numpy()))
        ib = i[: nb * blk].reshape(nb, blk).mean(axis=1)
        ax.plot(t[2:], ib[2:], lw=1, label=f"current {n:.0f} rpm")
        if temp is not None:
            tb = temp.to_numpy(dtype=float)[: nb * blk].reshape(nb, blk).mean(axis=1)
            ax2.plot(t, tb, ls="--", lw=1, label=f"motor temperature {n:.0f} rpm")
    ax.set_xlabel("time [min]")
    ax.set_ylabel("mean current (5 s blocks) [A]")
    ax2.set_ylabel("motor temperature r0035 [°C]")
    ax.legend(fontsize=7, loc="upper left")
    ax2.legend(fontsize=7, loc="upper right")
    ax.grid(alpha=0.3)
    return fig


def fig_cuts(recs: list[Recording], labels: list[str]) -> Figure:
    """Thesis Fig. 4.5: dynamometer torque and spindle current per cut."""
    from cnctwin.analysis.align import external_on_hf
    from cnctwin.twin import align_dynamometer

    ncols = 3
    nrows = math.ceil(len(recs) / ncols)
    fig, axes = _fig(nrows, ncols, w=12.0, h=2.8)
    for k, (rec, lab) in enumerate(zip(recs, labels, strict=True)):
        ax = axes[k // ncols][k % ncols]
        a = align_dynamometer(rec)
        dyn = external_on_hf(a, "dynamometer", columns=["mz_nm"])["mz_nm"].to_numpy()
        t = np.arange(len(a)) / a.fs_hz
        ax.plot(t, dyn, lw=0.6, label="dynamometer torque [Nm]")
        ax.plot(t, a.hf["CURRENT|SP1"].to_numpy(), lw=0.6, label="spindle current [A]")
        ax.set_ylim(-1, 8)
        ax.set_title(f"{chr(97 + k)}) {lab}", fontsize=9)
        ax.set_xlabel("time [s]")
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    for j in range(len(recs), nrows * ncols):
        axes[j // ncols][j % ncols].set_visible(False)
    return fig


# ====================================================================== the campaign
def _labels(res: ScenarioResult) -> list[str]:
    return [f"{_MATERIAL_LABEL.get(c['material'], c['material'])} {c['speed_rpm']:.0f} rpm "
            f"{c['feed_mm_per_rev']:g} mm/rev" for c in res.truth["cuts"]]


def simulate_campaign(ctx: DemoContext) -> None:
    """Simulate the sweep, warm-up and the cold and warm drilling validations."""
    from cnctwin.sim import scenarios as sc

    q = ctx.quick
    t0 = time.perf_counter()
    ctx.progress("simulating the air-cut sweep" + (" (quick: 40 speeds)" if q else
                                                   " (126 speeds up to 18000 rpm, thesis)"))
    ctx.sweep = (sc.air_cut_sweep(seed=ctx.seed, n_speeds=40, max_speed_rpm=8000.0,
                                  min_speed_rpm=100.0, dwell_s=2.5) if q
                 else sc.air_cut_sweep(seed=ctx.seed))
    ctx.timings["simulate air-cut sweep"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    speeds = (5000.0,) if q else (5000.0, 7000.0)
    minutes = 2.0 if q else 8.0
    ctx.progress(f"simulating the warm-up ({minutes:g} min at "
                 f"{', '.join(f'{s:.0f}' for s in speeds)} rpm)")
    ctx.warm_up = sc.warm_up(seed=ctx.seed, speeds_rpm=speeds, minutes=minutes)
    ctx.timings["simulate warm-up"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    ctx.progress("simulating the drilling validation with dynamometer (cold, calibration)")
    ctx.cold = sc.drilling_validation(seed=ctx.seed)
    ctx.progress(f"simulating the drilling validation after the warm-up (+{ctx.drift_k:g} K)")
    ctx.warm = sc.drilling_validation(
        seed=ctx.seed + 1, overrides={"spindle.ambient_temperature_c": 22.0 + ctx.drift_k})
    ctx.timings["simulate drilling"] = time.perf_counter() - t0


def calibrate_chains(ctx: DemoContext) -> None:
    """Calibrate the thesis and the improved chain and run them on the warm validation."""
    from cnctwin.twin import TwinChain

    assert ctx.sweep and ctx.cold and ctx.warm and ctx.warm_up
    t0 = time.perf_counter()
    for chain in (TwinChain.thesis_method(), TwinChain.improved_method()):
        ctx.progress(f"calibrating {chain!r}")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            chain.calibrate(ctx.sweep.recording, ctx.cold.recordings[0],
                            warm_up=ctx.warm_up.recordings[0])
            chain.run_model_from_measured(ctx.warm.recordings, labels=_labels(ctx.warm))
        ctx.chains[chain.name] = chain
    ctx.timings["calibrate and estimate"] = time.perf_counter() - t0


def _true_means(ctx: DemoContext, v: pd.DataFrame) -> list[float]:
    assert ctx.warm is not None
    labels = _labels(ctx.warm)
    out = []
    for _, row in v.iterrows():
        pc = ctx.warm.per_cycle[labels.index(str(row["recording"]))]
        out.append(float(pc["cutting_torque_nm"].loc[int(row["start_cycle"]):
                                                     int(row["end_cycle"])].mean()))
    return out


def validation_frame(ctx: DemoContext, name: str) -> pd.DataFrame:
    """Validation table of one chain with the simulator's true mean torque."""
    v = ctx.chains[name].results.validation.copy()
    v["true_torque_nm"] = _true_means(ctx, v)
    v["error_vs_true_pct"] = (v["predicted_torque_nm"] / v["true_torque_nm"] - 1.0) * 100.0
    return v


def print_validation(ctx: DemoContext) -> None:
    """Rich table: this run's validation beside thesis Table 4.1."""
    from rich.table import Table

    th = ctx.chains["thesis"].results.validation
    imp = ctx.chains["improved"].results.validation
    tab = Table(title="Validation of the cutting-torque estimate beside thesis Table 4.1 "
                "(simulated cuts after a warm-up drift; each method averages over its own window)",
                title_style="bold")
    for c in ("cut", "Table 4.1: I [A]", "meas [Nm]", "pred [Nm]", "err",
              "thesis method: I [A]", "dyn [Nm]", "pred [Nm]", "err",
              "improved: dyn [Nm]", "pred [Nm]", "err"):
        tab.add_column(c, justify="right" if c != "cut" else "left")
    for k, (_, row) in enumerate(th.iterrows()):
        lab = str(row["recording"])
        ref = THESIS_TABLE_4_1[
            (THESIS_TABLE_4_1["speed_rpm"] == float(lab.split()[-4]))
            & (THESIS_TABLE_4_1["feed_mm_per_rev"] == float(lab.split()[-2]))
            & (THESIS_TABLE_4_1["workpiece"] == " ".join(lab.split()[:-4]))]
        r2 = imp.iloc[k]
        if len(ref):
            t = ref.iloc[0]
            thesis = (f"{t['current_a']:.2f}", f"{t['torque_nm']:.2f}",
                      f"{t['predicted_torque_nm']:.2f}", f"{t['error_pct']:.2f} %")
        else:
            thesis = ("(calibration)", "4.36 / 3.97", "-", "-")
        tab.add_row(lab, *thesis, f"{row['current_a']:.2f}", f"{row['torque_nm']:.2f}",
                    f"{row['predicted_torque_nm']:.2f}", f"{row['error_pct']:.2f} %",
                    f"{r2['torque_nm']:.2f}", f"{r2['predicted_torque_nm']:.2f}",
                    f"{r2['error_pct']:.2f} %")
    ctx.console.print(tab)


# ====================================================================== report sections
def section_campaign(ctx: DemoContext) -> None:
    """Overview and the validation table."""
    sec = ctx.report.section("Campaign and validation (thesis Table 4.1)")
    sec.text(
        "Simulated campaign of the thesis (chapter 4): an air-cut sweep, a warm-up, the five "
        "drilling cuts with a rotary dynamometer cold (the first, steel 2400 rpm 0.16 mm/rev, "
        f"calibrates Kt) and again after a warm-up drift of +{ctx.drift_k:g} K (validated). "
        "The spindle twin is calibrated from the Recordings only, with the thesis method and "
        "the improved method (cnctwin.twin.TwinChain)."
        + (" QUICK MODE: fewer speeds and shorter runs." if ctx.quick else "")
    )
    cols = ["recording", "speed_rpm", "current_a", "temperature_c", "torque_nm",
            "predicted_torque_nm", "error_pct", "true_torque_nm", "error_vs_true_pct"]
    for name in ("thesis", "improved"):
        sec.heading(f"{name} method")
        sec.table(validation_frame(ctx, name)[cols],
                  caption=f"{name}: window means; error_pct vs the dynamometer, "
                          "error_vs_true_pct vs the simulator's true cutting torque")
    sec.heading("Thesis Table 4.1 (published)")
    sec.table(THESIS_TABLE_4_1, caption="Thesis Table 4.1")


def section_comparison(ctx: DemoContext) -> None:
    """Thesis vs improved: identified parameters and errors."""
    assert ctx.sweep is not None
    truth = ctx.sweep.truth["machine"]["spindle"]
    rows = []
    for name, ch in ctx.chains.items():
        m = ch.model
        v = validation_frame(ctx, name)
        rows.append({
            "method": name,
            "Kt [Nm/A]": m.kt_nm_per_a,
            "B [Nm/rpm]": m.b_nm_per_rpm,
            "tau_f [Nm]": m.tau_f_nm,
            "J [kg m2]": m.j_kgm2,
            "Kt err %": 100 * (m.kt_nm_per_a / truth["kt_nm_per_a"] - 1),
            "B err %": 100 * (m.b_nm_per_rpm / truth["viscous_friction_nm_per_rpm"] - 1),
            "tau_f err %": 100 * (m.tau_f_nm / truth["coulomb_friction_nm"] - 1),
            "max cut err vs true %": float(v["error_vs_true_pct"].abs().max()),
        })
    rows.append({"method": "simulator truth", "Kt [Nm/A]": truth["kt_nm_per_a"],
                 "B [Nm/rpm]": truth["viscous_friction_nm_per_rpm"],
                 "tau_f [Nm]": truth["coulomb_friction_nm"],
                 "J [kg m2]": truth["inertia_kg_m2"]})
    sec = ctx.report.section("Thesis method vs improved method")
    sec.text(
        "Same simulated data for both. The thesis method: linear region from the data, "
        "I = a n + b on the plateau means, Kt from the first 0.6 s of the calibration cut, no "
        "temperature or acceleration term. The improved method: Stribeck term and a fit range "
        "kept below the rounded bend, window in full engagement (1 s), the air current "
        "measured at the cutting speed in the same recording, Kt scaled with the motor "
        "temperature, J from the run-ups (see TwinChain.improved_method and "
        "docs/validation-spindle.md for 20 random spindles)."
    )
    sec.table(pd.DataFrame(rows), caption="Identified parameters (truth hidden from the "
                                          "pipeline, read from the simulator afterwards)")


def section_cut_signals(ctx: DemoContext) -> None:
    """Figures 3.6, 3.7 and 4.5."""
    assert ctx.cold is not None and ctx.warm is not None
    sec = ctx.report.section("Edge signals and dynamometer during the cuts (Fig. 3.6, 3.7, 4.5)")
    rec = ctx.cold.recordings[1]
    sec.figure(fig_cut_raw_lowpass(rec), caption="Fig. 3.6 analogue: cast iron 2400 rpm "
               "0.3 mm/rev, a) raw b) 10 Hz low-pass (dynamometer aligned by cross-correlation)")
    sec.figure(fig_cut_correlation(rec), caption="Fig. 3.7 analogue: correlation heatmaps "
               "over the cutting region, raw and low-passed at 100/50/10 Hz")
    sec.figure(fig_cuts(ctx.cold.recordings, _labels(ctx.cold)),
               caption="Fig. 4.5 analogue: dynamometer torque and spindle current per cut")


def section_air_cut(ctx: DemoContext) -> None:
    """Figures 3.8, 3.9, 4.1, 4.2, 4.3."""
    from cnctwin.spindle import plot_air_cut, plot_air_cut_correlation

    assert ctx.sweep is not None
    th = ctx.chains["thesis"].results
    imp = ctx.chains["improved"].results
    st = th.air_cut_stats
    sec = ctx.report.section("Air cut, linear region and friction (Fig. 3.8, 3.9, 4.1-4.3)")
    sec.figure(plot_air_cut(st), caption="Fig. 3.8 analogue: mean, min and max of the edge "
               "signals per air-cut speed")
    sec.figure(plot_air_cut_correlation(st), caption="Fig. 3.9 analogue: correlation of the "
               "per-speed means")
    sec.figure(fig_field_weakening(st, th.field_weakening_rpm), caption="Fig. 4.1 analogue: "
               "current limitation / field weakening (onset from the LF |I| vs Iq divergence)")
    if th.region is not None:
        sec.text(f"Linear region (thesis criteria): {th.region.lo_rpm:.0f}-"
                 f"{th.region.hi_rpm:.0f} rpm, {th.region.poles} poles. Lower limit: "
                 f"{th.region.reason_lo}. Upper limit: {th.region.reason_hi}.")
    sec.figure(fig_regression(ctx.chains), caption="Fig. 4.2 analogue: regression on the "
               "linear region (thesis) and the improved fit range")
    poles = th.region.poles if th.region is not None and th.region.poles else 4
    sec.figure(fig_stator(ctx.sweep.recording, st, poles, 3200.0),
               caption="Fig. 4.3 analogue: stator-frequency band-pass and removal near 3200 rpm")
    if imp.warm_up_coeff_per_k is not None:
        sec.text(f"Warm-up coefficient of the air-cut current: "
                 f"{imp.warm_up_coeff_per_k * 100:.3f} %/K of motor temperature (thesis §4.2).")


def section_temperature(ctx: DemoContext) -> None:
    """Figure 4.4."""
    assert ctx.warm_up is not None
    sec = ctx.report.section("Motor temperature and current (Fig. 4.4)")
    sec.figure(fig_temperature(ctx.warm_up.recordings), caption="Fig. 4.4 analogue: the "
               "current falls while the motor warms (friction and Kt drift)")


def section_real_data(ctx: DemoContext) -> None:
    """The real Capture4Analysis recording: `cnctwin info` and its spindle signals."""
    from cnctwin.cli import main as cli_main
    from cnctwin.iotools import read_recording

    sec = ctx.report.section("Real recording: Capture4Analysis example (SINUMERIK 840D sl)")
    path = REAL_C4A
    if not path.exists():
        path = Path(__file__).resolve().parents[3] / REAL_C4A
    if not path.exists():
        sec.text(f"{REAL_C4A} not found (run the demo from the repository root).", note=True)
        return
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        cli_main(["info", str(path)])
    import html as _html

    sec.text("Output of `cnctwin info` on the real file:")
    sec.html(f"<pre>{_html.escape(buf.getvalue())}</pre>")
    rec = read_recording(path)
    cols = [c for c in ("CMD_SPEED|SP1", "CURRENT|SP1", "TORQUE|SP1", "LOAD|SP1", "POWER|SP1",
                        "ENC_POS|SP1") if rec.has(c)]
    fig, axes = _fig(len(cols), 1, w=10.0, h=1.6)
    t = rec.time_s - rec.time_s[0]
    for k, c in enumerate(cols):
        axes[k][0].plot(t, rec.hf[c].to_numpy(), lw=0.7)
        axes[k][0].set_ylabel(c, fontsize=7)
        axes[k][0].grid(alpha=0.3)
    axes[-1][0].set_xlabel("time [s] (gap of 7.7 s in the counter)")
    sec.figure(fig, caption="Spindle signals of the real recording: a tool change, the "
               "spindle only positions (two moves < 60 rpm)")
    sec.text("The thesis pipeline needs constant-speed air-cut plateaus and a cut with a "
             "dynamometer; this file has neither (no plateau, no cutting region), so the "
             "calibration is not run on it. TORQUE/CURRENT = 1.37 Nm/A here is the drive's "
             "torque factor, not the Kt of Eq. 4.3 (details: docs/real-data-spindle.md).")


SPINDLE_SECTIONS: list[SectionBuilder] = [
    section_campaign,
    section_comparison,
    section_cut_signals,
    section_air_cut,
    section_temperature,
    section_real_data,
]
"""The spindle (issue #4) sections, in report order."""

def section_position_loop(ctx: DemoContext) -> None:
    """Position-loop section (issue #5); imported lazily to keep ``cnctwin --help`` fast."""
    from cnctwin.validation.servo_section import position_loop_section

    position_loop_section(ctx)


def section_use_cases(ctx: DemoContext) -> None:
    """Use-case section (issue #6); imported lazily to keep ``cnctwin --help`` fast."""
    from cnctwin.validation.usecases_section import use_cases_section

    use_cases_section(ctx)


DEMO_SECTIONS: list[SectionBuilder] = [section_position_loop, section_use_cases]
"""Extension hook: builders ``(DemoContext) -> None`` appended by other topics (position loop,
issue #5; use cases, issue #6). They run after :data:`SPINDLE_SECTIONS`."""


# ====================================================================== driver
def run_demo(out_dir: str | Path = "out/demo", *, seed: int = 0, quick: bool = False,
             console: Console | None = None) -> Path:
    """Run the whole demo; return the report path.

    Parameters
    ----------
    out_dir : str or Path
        Output directory.
    seed : int
        Random seed.
    quick : bool
        Fewer speeds and shorter runs (< 1 min).
    console : rich.console.Console, optional
        Terminal output.

    Returns
    -------
    pathlib.Path
        The written ``report.html``.
    """
    from rich.console import Console

    from cnctwin.report import Report

    t_start = time.perf_counter()
    con = console or Console(width=max(Console().width, 150), log_path=False)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rep = Report("cnctwin demo: spindle digital twin of the thesis campaign",
                 subtitle=f"seed {seed}{', quick mode' if quick else ''}")
    ctx = DemoContext(out_dir=out, seed=seed, quick=quick, report=rep, console=con)
    with con.status("[bold]cnctwin demo[/bold]") as status:
        status.update("simulating the campaign")
        simulate_campaign(ctx)
        status.update("calibrating the spindle twin")
        calibrate_chains(ctx)
        print_validation(ctx)
        t0 = time.perf_counter()
        for builder in [*SPINDLE_SECTIONS, *DEMO_SECTIONS]:
            name = getattr(builder, "__name__", repr(builder))
            status.update(f"report: {name}")
            ctx.progress(f"report section {name}")
            try:
                builder(ctx)
            except Exception:  # a broken section must not lose the report
                sec = rep.section(f"Section {name} failed")
                sec.html(f"<pre>{traceback.format_exc()}</pre>")
                con.print(f"[red]section {name} failed[/red] (traceback in the report)")
        ctx.timings["report sections"] = time.perf_counter() - t0
        ctx.timings["total"] = time.perf_counter() - t_start
        tim = rep.section("Run time")
        tim.table(pd.DataFrame({"step": list(ctx.timings),
                                "seconds": list(ctx.timings.values())}))
        path = rep.write(out / "report.html")
    summary = (f"[bold green]done[/bold green] in {ctx.timings['total']:.1f} s; "
               f"report: [bold]{path}[/bold]")
    for name, ch in ctx.chains.items():
        v = ch.results.validation
        summary += (f"\n  {name:9s} Kt {ch.model.kt_nm_per_a:.4f} Nm/A, B "
                    f"{ch.model.b_nm_per_rpm:.3e} Nm/rpm, tau_f {ch.model.tau_f_nm:.4f} Nm; "
                    f"max validation error {v['error_pct'].max():.2f} % (vs dynamometer)")
    summary += ("\n  next: open the report in a browser, or look at a simulated wear run in the "
                "dashboard:\n    cnctwin simulate tool_wear_run --out out/wear --option n_holes=60"
                " && cnctwin web --recording out/wear")
    import importlib.util

    if importlib.util.find_spec("fastapi") is None:  # make demo installs no extras
        from rich.markup import escape

        summary += escape("\n    (the dashboard needs the web extra: pip install -e '.[web]', or "
                          "make test, which installs every extra)")
    con.print(summary)
    return path
