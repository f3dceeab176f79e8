"""Hole-quality recovery on the simulated wear run (docs/hole-quality.md table).

Default machine and drilling model, 6 consecutive holes each at hole 0, 1338 and 2670 of the
thesis wear curve (``tool_wear_run(n_holes=6, start_hole=...)``, seed 0); the analysis gets the
recording, the machine and the drill description only. Prints per indicator the correlation
with the truth over the 18 holes, the median and max relative error, and the median stated
relative standard error where the estimate carries one.

Run: ``.venv/bin/python benchmarks/bench_hole_quality.py``
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from cnctwin.machine.tools import Drill
from cnctwin.sim import Machine
from cnctwin.sim.scenarios import tool_wear_run
from cnctwin.usecases.holes import hole_record
from cnctwin.usecases.quality import hole_quality

PAIRS = [("rotating force", "rotating_force_est_n", "rotating_force_n", "rotating_force_se_n"),
         ("entry force", "entry_force_est_n", "entry_force_peak_n", "entry_force_se_n"),
         ("tool-tip hole position error", "tip_position_error_est_um", "tip_position_error_um",
          "tip_position_error_se_um"),
         ("static walk force", "walk_force_est_n", "walk_force_n", "walk_force_se_n"),
         ("hole oversize", "hole_oversize_est_um", "hole_oversize_um", None)]

if __name__ == "__main__":
    qs, ts = [], []
    for start in (0, 1338, 2670):
        res = tool_wear_run(n_holes=6, start_hole=start, seed=0, dynamometer=False)
        rec = res.recording
        qs.append(hole_quality(rec, hole_record(rec), machine=Machine.thesis_default(),
                               drill=Drill()))
        ts.append(pd.DataFrame(res.truth["holes"]))
    q, t = pd.concat(qs, ignore_index=True), pd.concat(ts, ignore_index=True)
    print("| indicator vs truth | correlation (18 holes) | median / max relative error | "
          "median stated standard error |")
    print("|---|---|---|---|")
    for name, est, true, se in PAIRS:
        e, tr = q[est].to_numpy(), t[true].to_numpy()
        rel = np.abs(e / tr - 1.0)
        s = f"{100 * np.median(q[se].to_numpy() / tr):.1f} %" if se else "-"
        print(f"| {name} | {np.corrcoef(e, tr)[0, 1]:.3f} | {100 * np.median(rel):.1f} % / "
              f"{100 * rel.max():.1f} % | {s} |")
    d = np.angle(np.exp(1j * (q["entry_force_direction_rad"] - t["entry_direction_rad"])))
    print(f"entry direction: max |error| {np.abs(d).max():.3f} rad")
