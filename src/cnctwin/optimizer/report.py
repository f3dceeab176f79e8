"""The HTML report of an optimization: the load along the program before and after."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from cnctwin.optimizer.core import OptimizeResult
from cnctwin.report import Report

__all__ = ["optimize_report"]


def _mean(x: np.ndarray, n: int = 50) -> np.ndarray:
    """Centred moving mean over ``n`` samples (NaN as 0)."""
    v = np.nan_to_num(np.asarray(x, dtype=np.float64))
    if v.size < n:
        return v
    return np.convolve(v, np.ones(n) / n, mode="same")


def optimize_report(res: OptimizeResult, path: str | Path, *, program: str = "") -> Path:
    """Write ``report.html`` of an optimization.

    Parameters
    ----------
    res : OptimizeResult
        The result of :func:`~cnctwin.optimizer.optimize_program`.
    path : str or Path
        The HTML file.
    program : str
        The program's file name (title).

    Returns
    -------
    pathlib.Path
    """
    ct = res.cycle_time_s
    saved = (1.0 - ct["optimized"] / ct["programmed"]) * 100.0 if ct.get("programmed") else 0.0
    rep = Report("Feed-rate optimization",
                 subtitle=f"{program}: {ct['programmed']:.1f} s programmed, "
                          f"{ct['optimized']:.1f} s optimized ({saved:.1f} % shorter)")
    lim = res.limits
    mp = lim.margin_parts
    sec = rep.section("Limits and margin")
    sec.text(f"Every predicted load carries a margin of {lim.margin * 100:.1f} %: "
             f"{mp['base'] * 100:.0f} % for what the model leaves out plus {mp['k']:g} x the "
             f"combined relative uncertainty of the material ({mp['material_u'] * 100:.1f} %) "
             f"and of the spindle's torque constant ({mp['kt_u'] * 100:.2f} %). Spindle S1 "
             f"torque {lim.rated_torque_nm:.3g} Nm up to the base speed, S1 power "
             f"{lim.s1_power_w / 1000:.3g} kW above; peak torque {lim.peak_torque_nm:.3g} Nm; "
             f"path feed {lim.path_max_mm_min:.0f} mm/min.")
    if res.violations:
        sec.table(pd.DataFrame(res.violations), caption="Limits the simulated optimized "
                  "program exceeds")
    elif res.runs:
        sec.text("The optimized program, simulated on the machine, exceeds no limit.")
    if res.runs:
        fig, axes = plt.subplots(2, 1, figsize=(10, 6), sharex=False)
        top = 0.0
        for key, style in (("programmed", "C0"), ("optimized", "C1")):
            run = res.runs[key]
            t = run.time_s - run.time_s[0]
            # 0.1 s means: the tooth passing and the 2 ms sampling averaged out
            axes[0].plot(t, _mean(run.cutting_torque_nm), style, lw=0.8,
                         label=f"{key} ({run.cycle_time_s:.1f} s)")
            feed = _mean(run.path_feed_mm_min)
            axes[1].plot(t, feed, style, lw=0.8, label=key)
            cutting = _mean(run.cutting_torque_nm) > 0.05
            if cutting.any():
                top = max(top, float(np.percentile(feed[cutting], 99)))
        if top > 0:  # the cutting feeds, not the rapid moves' peaks, set the scale
            axes[1].set_ylim(0, 1.3 * top)
        axes[0].set_ylabel("cutting torque, 0.1 s mean [Nm]")
        axes[1].set_ylabel("path feed, 0.1 s mean [mm/min]")
        axes[1].set_xlabel("time [s]")
        axes[0].legend(loc="upper right")
        fig.tight_layout()
        rep.section("Load along the program").figure(
            fig, caption="Simulated cutting torque and path feed of both programs on the "
            "machine file's twin")
        plt.close(fig)
    rows = [{"line": ln.line, "block": ln.text, "old F [mm/min]": ln.feed_old_mm_min,
             "new F [mm/min]": ln.feed_new_mm_min, "binds": ln.binding,
             "pieces": len(ln.pieces)} for ln in res.lines]
    if rows:
        rep.section("Per line").table(pd.DataFrame(rows), caption="New feed of each milling "
                                      "line (of its slowest piece) and the limit that sets it")
    return rep.write(path)
