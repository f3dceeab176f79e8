"""The position-loop section of the demo report (issue #5).

Simulates the thesis' milling experiment (square and circle, Al7050) with hidden, randomly drawn
X/Y loop parameters, identifies each axis from the recording alone, and shows identified against
true values with the thesis Figure 3.2/3.3 analogues. The true values are read only to print the
comparison; :func:`cnctwin.servo.identify_axis` never sees them.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import pandas as pd

from cnctwin.exceptions import IdentificationError
from cnctwin.servo.figures import plot_error_signals, plot_tool_path
from cnctwin.servo.identify import identify_axis
from cnctwin.servo.predict import AxisLoopModel, prediction_residual

if TYPE_CHECKING:
    from cnctwin.validation.context import DemoContext

__all__ = ["position_loop_section"]

# identified parameter -> override key suffix of the hidden truth
_COMPARE: dict[str, str] = {
    "kv_m_min_mm": "kv_m_min_per_mm",
    "jerk_time_s": "jerk_time_s",
}


def position_loop_section(ctx: DemoContext) -> None:
    """Add the position-loop section: identification on simulated milling, Fig. 3.2/3.3.

    Parameters
    ----------
    ctx : DemoContext
        The demo's context (report, recordings, options).
    """
    from cnctwin.sim.scenarios import milling_square_circle

    sec = ctx.report.section(
        "Position loop: identification from a milling recording (Fig. 3.2, 3.3)"
    )
    ctx.progress("simulating the milling experiment with hidden loop parameters")
    res = milling_square_circle(seed=ctx.seed, randomize_loop=True)
    rec = res.recordings[0]
    truth = res.truth.get("loop_overrides", {})
    sec.text(
        "The thesis' milling experiment (Al7050-T7451, 16 mm two-flute end mill, 0.5 mm depth, "
        "0.167 mm/tooth, square and circle path) simulated with X/Y loop parameters drawn at "
        "random and hidden from the analysis. cnctwin.servo.identify_axis sees only the "
        "recording; the true values are shown beside its estimates."
    )
    rows = []
    for axis in ("X1", "Y1"):
        try:
            ident = identify_axis(rec, axis)
        except IdentificationError as exc:
            sec.text(f"{axis}: not identified: {exc}", note=True)
            continue
        for name, key in _COMPARE.items():
            true = truth.get(f"axes.{axis}.{key}")
            est = ident.params.get(name)
            if est is None or true is None:
                continue
            if name == "jerk_time_s":  # the moving-average window is a whole number of cycles
                true = round(true / rec.meta.cycle_time_s) * rec.meta.cycle_time_s
            err = 100.0 * (est.value - true) / true
            rows.append({"axis": axis, "parameter": name, "identified": est.value,
                         "std error": est.stderr, "true (hidden)": true, "error %": err})
        rows.append({"axis": axis, "parameter": "ffw_mode", "identified": ident.ffw_mode,
                     "std error": None,
                     "true (hidden)": {0: "none", 1: "speed", 2: "torque", 3: "speed",
                                       4: "torque"}.get(
                                           int(truth.get(f"axes.{axis}.ffw_mode", -1)), "?"),
                     "error %": None})
        try:
            model = AxisLoopModel.from_identification(ident)
            rms, fe_rms, _ = prediction_residual(model, rec, axis)
        except IdentificationError as exc:
            sec.text(f"{axis}: no ENC_POS prediction: {exc}", note=True)
        else:
            rows.append({"axis": axis, "parameter": "ENC_POS prediction RMS / following-error RMS",
                         "identified": rms / fe_rms, "std error": None,
                         "true (hidden)": "< 0.10 (goal)", "error %": None})
    if rows:
        sec.table(pd.DataFrame(rows),
                  caption="Identified loop parameters against the hidden truth")
    sec.figure(plot_tool_path(rec, ("X1", "Y1")),
               caption="Fig. 3.2a/3.3a analogue: DES_POS, CTRL_POS and ENC_POS on the tool path "
                       "(deviations magnified)")
    for axis in ("X1", "Y1"):
        sec.figure(plot_error_signals(rec, axis),
                   caption=f"Fig. 3.2b/c analogue, {axis}: following error, CTRL_DIFF2, "
                           "CONT_DEV")
