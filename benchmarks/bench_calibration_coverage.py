"""Coverage of the calibration's stated intervals on hidden machines (issue 29, point 2).

The same campaign as ``tests/calibration/test_roundtrip.py``, through the command line as a
user types it: per draw a machine with hidden spindle and X1/Y1 loop and friction parameters
(``random_spindle_overrides``, ``random_loop_overrides``) is simulated with its own noise
(an air cut up and back down through 200-5000 rpm, one drilling cut with the dynamometer, the
axis test program); ``cnctwin calibrate spindle`` and ``cnctwin calibrate axes`` recover the
parameters from the files. Per parameter: the mean and max error, and the **coverage**, the
share of draws whose hidden value lies inside the stated 95 % interval (value +- 1.96 standard
uncertainties; the goal is 90-98 %); a value identified without an uncertainty counts as "no
interval". Also the thesis method on the same files, for comparison. Writes the table into
docs/validation-calibration.md (the part above its first "## " section after the table).

Usage::

    .venv/bin/python benchmarks/bench_calibration_coverage.py [--draws 100] [--jobs 2]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import platform
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from cnctwin.cli import main
from cnctwin.machine import Machine, load_machine
from cnctwin.sim.scenarios import random_loop_overrides, random_spindle_overrides

_UP = list(range(200, 5001, 200))
SPEEDS_RPM = _UP + _UP[-2::-1]
REF = "drill_1_aisi1045_2400rpm_0p16"
KEYS = ["spindle.kt_nm_per_a", "spindle.viscous_friction_nm_per_rpm",
        "spindle.coulomb_friction_nm", "spindle.inertia_kg_m2",
        "axes.X1.kv_m_min_per_mm", "axes.Y1.kv_m_min_per_mm",
        "axes.X1.jerk_time_s", "axes.Y1.jerk_time_s", "axes.X1.coulomb_n", "axes.Y1.coulomb_n",
        "axes.X1.viscous_n_per_mm_s", "axes.Y1.viscous_n_per_mm_s"]
TOL = {"inertia": 2.0, "spindle": 2.0, "kv_m": 5.0, "jerk": 10.0, "coulomb": 5.0,
       "viscous": 30.0}
"""Accuracy tolerance [%] by the first of these that the key contains."""


def _default(key: str) -> float:
    """The thesis machine's value of a dotted key (what a draw does not hide)."""
    m = Machine.thesis_default()
    parts = key.split(".")
    obj = m.axis(parts[1]) if parts[0] == "axes" else m.spindle
    return float(getattr(obj, parts[-1]))


def _pct(x: float) -> str:
    """An error in per cent: two decimals, or two significant digits below 0.01 %."""
    return f"{x:.2f}" if not 0 < abs(x) < 0.01 else f"{x:.1e}"


def _cli(*args: object) -> None:
    with contextlib.redirect_stdout(io.StringIO()):
        code = main([str(a) for a in args])
    if code != 0:
        raise SystemExit(f"cnctwin {' '.join(map(str, args[:2]))} failed ({code})")


def _seed(seed: int, base: Path) -> dict[str, dict[str, Any]]:
    d = base / f"seed{seed}"
    hidden = {**random_spindle_overrides(seed), **random_loop_overrides(seed)}
    sets = [x for k, v in hidden.items() for x in ("--set", f"{k}={v}")]
    _cli("simulate", "air_cut_sweep", "--out", d / "ac", "--seed", seed, *sets, "--option",
         f"speeds_rpm={SPEEDS_RPM}")
    _cli("simulate", "drilling_validation", "--out", d / "dv", "--seed", seed, *sets,
         "--option", 'cuts=[["aisi1045", 2400, 0.16]]')
    _cli("simulate", "axis_test", "--out", d / "at", "--seed", seed, *sets, "--option",
         'axes=["X1", "Y1"]')
    out: dict[str, dict[str, Any]] = {}
    for method in ("improved", "thesis"):
        m = d / f"{method}.toml"
        _cli("calibrate", "spindle", "--air-cut", d / "ac" / "air_cut_sweep.json",
             "--reference", d / "dv" / f"{REF}.json", "--dynamometer",
             d / "dv" / f"dynamometer_{REF[6:]}.csv", "--machine", m, "--method", method)
        if method == "improved":
            _cli("calibrate", "axes", d / "at" / "axis_test.json", "--machine", m)
        mf = load_machine(m)
        sp = Machine.thesis_default().spindle
        for key in KEYS:
            if method == "thesis" and not key.startswith("spindle"):
                continue
            rec = mf.record(key)
            h = float(hidden[key]) if key in hidden else _default(key)
            h_acc = h
            if key == "spindle.kt_nm_per_a":
                t_ref = mf.value("spindle.kt_ref_temperature_c")
                if method == "thesis" or not mf.is_identified("spindle.kt_ref_temperature_c"):
                    t_ref = 22.0
                h = h_acc = h * (1 + sp.magnet_temp_coeff_per_k * (t_ref - sp.kt_ref_temperature_c))
            if key.endswith("jerk_time_s"):
                h_acc = round(h / 0.002) * 0.002
            ident = rec is not None and rec.identified
            out[f"{method}:{key}"] = {
                "hidden": h, "hidden_eff": h_acc,
                "value": rec.value if ident and rec else float("nan"),
                "u": rec.uncertainty if ident and rec and rec.uncertainty else float("nan"),
                "reason": "" if ident or rec is None else rec.reason}
    return out


def _one(args: tuple[int, str]) -> tuple[int, dict[str, dict[str, Any]]]:
    seed, tmp = args
    return seed, _seed(seed, Path(tmp))


def main_(argv: list[str] | None = None) -> int:
    from concurrent.futures import ProcessPoolExecutor

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=100)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=1, help="draws run side by side")
    ap.add_argument("--doc", type=Path, default=Path("docs/validation-calibration.md"))
    ap.add_argument("--raw", type=Path, help="append each draw's results here (JSON lines) "
                    "as it finishes; with --summarize, the file to summarize")
    ap.add_argument("--summarize", action="store_true",
                    help="no new draws: the table from the draws in --raw")
    a = ap.parse_args(argv)
    t0 = time.time()
    seeds = list(range(a.first_seed, a.first_seed + a.draws))
    res: dict[int, dict[str, dict[str, Any]]] = {}

    def done(seed: int, r: dict[str, dict[str, Any]]) -> None:
        res[seed] = r
        if a.raw is not None:
            with a.raw.open("a", encoding="utf-8") as f:
                f.write(json.dumps({"seed": seed, "results": r}) + "\n")
        print(f"draw {seed} done ({len(res)}/{a.draws})", file=sys.stderr, flush=True)

    if a.summarize:
        if a.raw is None or not a.raw.exists():
            raise SystemExit("--summarize needs --raw FILE with the draws")
        for line in a.raw.read_text(encoding="utf-8").splitlines():
            d = json.loads(line)
            res[int(d["seed"])] = d["results"]
        seeds = sorted(res)
        a.draws = len(seeds)
    else:
        with tempfile.TemporaryDirectory() as tmp:
            if a.jobs > 1:
                with ProcessPoolExecutor(a.jobs) as ex:
                    for seed, r in ex.map(_one, [(s, tmp) for s in seeds]):
                        done(seed, r)
            else:
                for s in seeds:
                    done(s, _seed(s, Path(tmp)))
    wall = time.time() - t0
    rows = []
    first = res[seeds[0]]
    for method in ("improved", "thesis"):
        for key in KEYS:
            k = f"{method}:{key}"
            if k not in first:
                continue
            err = np.array([100 * (r[k]["value"] / r[k]["hidden_eff"] - 1) for r in res.values()])
            z = np.array([(r[k]["value"] - r[k]["hidden"]) / r[k]["u"] for r in res.values()])
            nan = int(np.isnan(err).sum())
            no_u = int(np.sum(np.isfinite(err) & ~np.isfinite(z)))
            inside = int(np.sum(np.abs(z) <= 1.96)) if method == "improved" else None
            tol = next(v for t, v in TOL.items() if t in key)
            zf = z[np.isfinite(z)]
            z_rms = float(np.sqrt(np.mean(zf**2))) if method == "improved" and zf.size else None
            rows.append((method, key, float(np.nanmean(np.abs(err))),
                         float(np.nanmax(np.abs(err))), tol, inside, z_rms, no_u, nan))
    cpu = platform.processor() or platform.machine()
    n = a.draws
    lines = [
        "# Validation: calibrating the twin of a hidden machine (issues 12 and 29)",
        "",
        "Generated by `benchmarks/bench_calibration_coverage.py` (the campaign of "
        "`tests/calibration/test_roundtrip.py`, which asserts it on a small fixed set): "
        f"{n} machines (seeds {seeds[0]}-{seeds[-1]}) with hidden spindle and X1/Y1 loop and "
        "friction parameters drawn from their seed, each simulated with its own noise and "
        "calibrated through the command line only (`cnctwin simulate ... --set`, "
        "`cnctwin calibrate spindle`, `cnctwin calibrate axes`). "
        + (f"Wall time {wall:.0f} s with {a.jobs} job(s) ({cpu})." if not a.summarize else
           "Summarized from the draws' raw results (`--summarize`)."),
        "",
        "Campaign per machine: an air cut up and back down through 200-5000 rpm (3 s per "
        "speed), one drilling cut (AISI 1045, 2400 rpm, 0.16 mm/rev) with the rotary "
        "dynamometer on its own clock, and the axis test program (`cnctwin simulate "
        "axis_test`: X1 and Y1 back and forth over 60 mm at 500-8000 mm/min).",
        "",
        "Coverage = the share of the draws whose hidden value lies inside the stated 95 % "
        "interval (value +- 1.96 standard uncertainties); the goal is 90-98 %. 'rms z': the "
        "root mean square of (value - hidden) / standard uncertainty over the draws with an "
        "interval, 1 for an uncertainty that means what it says (below 1: stated too wide; "
        "a finer measure than the coverage, whose own scatter over 100 draws is ~2 points). "
        "'No interval': identified without a stated uncertainty.",
        "",
        "| method | parameter | mean abs. error [%] | max abs. error [%] | tolerance [%] | "
        "coverage of the 95 % interval | rms z | no interval | not identified |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for method, key, mean, mx, tol, inside, z_rms, no_u, nan in rows:
        ins = "-" if inside is None else f"{100 * inside / n:.0f} % ({inside} of {n})"
        zr = "-" if z_rms is None else f"{z_rms:.2f}"
        lines.append(f"| {method} | `{key}` | {_pct(mean)} | {_pct(mx)} | {tol:g} | {ins} | "
                     f"{zr} | {no_u} | {nan} |")
    lines += [
        "",
        "Notes:",
        "",
        "* Kt is compared at the temperature the machine file states it for "
        "(`spindle.kt_ref_temperature_c`, the motor temperature of the air cut): the hidden Kt "
        "holds at 20 degC and falls by 0.11 %/K (NdFeB). The thesis method states no "
        "temperature; it is compared at 22 degC.",
        "* A moving-average jerk filter spans whole 2 ms cycles; the error is against that "
        "effective length, the interval against the hidden MD32410 itself. A filter of two "
        "cycles is exactly a half-cycle delay (no recording can tell it from the balancing "
        "delay): the calibration writes `identified = false` with that reason; such seeds "
        "count under 'not identified' and as outside the interval.",
        "* The thesis method fits a straight line to a sweep that heats its bearings while it "
        "runs; the improved method fits the self-heating out of the up-and-down air cut "
        "(`cnctwin.twin.fit_friction_thermal`).",
        "* Axis friction: the hidden Coulomb friction is drawn (80-220 N); the viscous "
        "friction is the thesis machine's 0.2 N/(mm/s); the screw ripple (10 N per motor "
        "revolution, docs/simulator.md) is in every draw and not in the friction law. A "
        "friction run is a whole stroke: constant setpoint velocity with the actual speed, "
        "averaged over 50 ms (`cnctwin.servo.identify.STEADY_SMOOTH_CYCLES`), within 1 % of "
        "it. Until this change the test was made sample by sample on the actual speed (the "
        "encoder's position differentiated over two cycles: ~0.1 mm/s of noise, more than "
        "1 % of 500 mm/min), which cut the slow strokes into fragments (~22 runs for 10 "
        "strokes); each fragment's mean kept a part of the screw ripple, the Coulomb error "
        "std was 1.6 N (X1) and 1.3 N (Y1) while the bootstrap over the fragments stated "
        "~1.6 N plus the 1 % floor (Y1: 100 of 100 covered). On whole strokes the error std "
        "is ~0.5 N (25 draws, seeds 3000-3024). The standard error is the bootstrap over the "
        "runs times sqrt(n / (n - p)) (HC1, MacKinnon & White 1985: 10 runs, 3 "
        "coefficients; without it the viscous term covered 88-92 %); no 1 % floor is added "
        "to the friction, whose scatter over whole strokes carries the law's misfit.",
        "* Kv is g a: a from the NC's own relation CMD_SPEED = a (CTRL_POS - ENC_POS) + c "
        "VEL_FFW (exact in the recorded signals), g the steady-state ratio of actual speed to "
        "command over the constant-velocity runs (`cnctwin.servo.identify.steady_speed_gain`, "
        "jackknife over the runs). Until issue 29 g came from the fitted speed-loop model (a "
        "first order + delay fitted to a PI loop with a current loop): Kv errors of 0.03 % "
        "(max 0.08 %) against a stated statistical error of 0.003 %, covered only by the 1 % "
        "floor (`cnctwin.calibration.axes.REL_FLOOR`, coverage 100 %). The floor stays where "
        "a model stands between the data and Kv (no CTRL_POS: a regression absorbs the "
        "setpoint filter; fewer than 3 steady runs: the loop model's gain); those cases are "
        "not in this campaign.",
        "* J: until issue 29 the simulated drive stepped its speed setpoint once per 2 ms "
        "cycle, the sampled run-up current read ~8 % of J alpha low, and J came out 1-6 % low "
        "(mean -2.7 %); its interval covered 100 of 100 draws only because the AR(1) "
        "inflation of its standard error made it ~6 % wide. Now the drive interpolates the "
        "setpoint (docs/simulator.md), J is fitted on the encoder's speed with the torque "
        "averaged like the central difference, and u(J) is Kt's share, the run-up/run-down "
        "difference (friction law), a Newey-West standard error and the change of J when "
        "the analysis low-pass halves (`cnctwin.spindle.inertia_uncertainty`).",
        "* The spindle's friction B and tau_f: until issue 29's last change B covered 99 of "
        "100 draws and tau_f 98, with intervals about 1.7x and 1.4x their errors' scatter "
        "(rms z 0.58 and 0.72 on seeds 3000-3059). Two faults. The thermal friction fit's "
        "covariance was inverted from a normal matrix whose columns span ten decades (the "
        "column of ones against n E ~ 1e8 A rpm^2 s): pinv dropped the small singular "
        "values, tau_f's statistical term came out ~1e-10 Nm and B's at half its value; and "
        "without the derivative by the grid-searched Stribeck decay speed the standard "
        "errors were 0.65 of the estimates' scatter over independent noise "
        "(tests/calibration/test_friction_uncertainty.py; now 1.00 and 1.02). The "
        "model-form term, the spread over the fit variants, then carried the whole width: "
        "it counted the statistical scatter a second time (the variants refit overlapping "
        "sets of the same plateaus) and took in the line fitted up to 100 % of the linear "
        "region, which reaches into the viscous roll-off at the top (its residual variance "
        "2.8x the chosen fit's, median of 60 draws; its B 1.3-2.2 % low). Now the standard "
        "errors come from the whole law's Jacobian with the columns scaled, a variant "
        "counts only if an F test (95 %) finds its residual variance no larger than the "
        "chosen fit's (the 100 % line is out in ~87 % of the draws), and only the counted "
        "variants' spread beyond the statistical term is model form "
        "(`cnctwin.calibration.spindle`). With the statistical term right it explains the "
        "error on its own (60 draws: rms z 0.98 for B, 1.06 for tau_f without any model "
        "form). Kt's and J's intervals are wider by the same correction (Kt's air-current "
        "term at the reference speed, J's share of Kt).",
        "* The second hundred draws (seeds 3100-3199, added in the same round) found three "
        "8-cycle moving averages on axes with `ffw_mode` 2 fitted as 6.5-6.6 cycles + a PT1 "
        "of 1 cycle (errors -17 to -18 %, beyond issue 12's 10 %; z -2.4 to -3.3) and one "
        "of 6 cycles 7 % short (seed 3170). The start grid of the setpoint-chain fit held "
        "fixed delays, so the rounding of the total lag chose which windows were refined "
        "(3.78 cycles: 7 + a PT1 of 1 = 4.0 beat 8, 3.5). Now every grid point carries the "
        "delay that gives it the recording's own lag (`cnctwin.servo.identify."
        "chain_lag_cycles`, tests/servo/test_jerk_lag_grid.py): every identified jerk time "
        "of the 200 draws within 0.001 % of its whole cycles. The plain chain got the "
        "split-delay start as well: a 2-cycle average before a fractional balancing dead "
        "time (seed 3008, X1) had been reported as a 4 ms filter; it is exactly a "
        "half-cycle delay and is refused. The refused filters (19 and 21 of 200, each of "
        "two cycles) count as outside; every stated jerk interval (181 and 179) holds the "
        "hidden value, since the half-cycle quantisation (uniform) dominates u and +-1.96 u "
        "of a uniform covers all of it.",
        "* J: with Kt's corrected uncertainty its interval was 1.2x its error scatter (198 of "
        "200, rms z 0.85). The change of J when the analysis low-pass halves, until then one "
        "standard uncertainty, bounds the method's bandwidth dependence and is now taken as "
        "rectangular (a / sqrt 3), as the run-up/run-down term already was.",
        "* Axis Coulomb friction: until this round X1 covered 90 % with rms z 1.21 (Y1 92 %, "
        "1.14): a bias of -0.79 N over the 200 draws (Y1 -0.80 N; negative in 90 % of them) "
        "under a scatter of 0.61 N (0.56). The cause was the screw ripple: switched off "
        "(`--set axes.X1.ripple_n=0`, 11 draws) the mean error was +0.07 N (Y1 -0.01 N) "
        "against -0.46 N (-0.75 N) with it. A run dropped its first quarter as its transient, "
        "so the forward run of a stroke ended where the backward one began (forward 15-60 "
        "mm, backward 45-0 mm of a 60 mm stroke); a ripple A sin(2 pi x / lead + phase) then "
        "leaves -A lead / (pi L) cos(phase) in the Coulomb term (A 10 N, lead 10 mm, L 45 mm, "
        "phase 0: -0.71 N), with one sign on every draw (the phase is the machine's; "
        "tests/servo/test_friction_strokes.py). Now opposite runs at one feed that cover one "
        "span are cut to the positions both cover (`cnctwin.servo.identify."
        "common_position_runs`): the ripple's mean is the same in both directions and goes "
        "into the offset. They are found without dropping the quarter and lose the 50 ms "
        "smoothing window at each end instead (the quarter dropped and then the common cut "
        "keeps half of each stroke: on 60 draws the bias was +0.13 N / +0.21 N with a scatter "
        "of 0.84 / 0.70 N, against +0.15 / +0.15 N and 0.53 / 0.42 N with the window). On the "
        "200 draws: bias +0.05 N (Y1 +0.00 N), scatter 0.54 N (0.50 N), mean abs. error "
        "0.32 % (0.28 %; 0.61 % and 0.59 % before). The interval is now too wide: 99 % and "
        "100 %, rms z 0.73 and 0.65, above the goal's 98 %: the stated u (median 0.86 N) is "
        "1.6x the scatter. Its cause is open: the bootstrap resamples single runs while the "
        "ripple's mean over a pair's common span is one offset per feed (which the law's "
        "single offset cannot take), but resampling the pairs instead (60 draws, seeds "
        "3000-3059) widened it further (median u 1.21 N against 0.88 N). Moves of a "
        "production job that overlap in part keep their length (a pair is cut only if each "
        "run keeps 70 %).",
        "* Jerk filter: where two moving averages in series fit better than one, the single "
        "average is fitted once more from the window of the same variance, sqrt(w1^2 + w2^2 - "
        "1) (`cnctwin.servo.identify`): its grid starts could all miss the window (on an "
        "Intel host a 9-cycle filter was fitted from windows 1-6 as 8.5 cycles and PT1s and "
        "taken for 8 + 4 cycles in series; tests/servo/test_identify_sim.py, circle, seed "
        "1). In this campaign one draw of 200 changed (X1: max abs. error 5.8e-04 % -> "
        "1.7e-04 %, mean 1.2e-05 -> 6.4e-06 %); the Y1 mean's last digit (2.2e-05 -> "
        "2.3e-05 %) is the host's arithmetic (the rows before were run on an AMD host, these "
        "on an Intel one; every other row is the same).",
        "",
    ]
    text = "\n".join(lines)
    if a.doc.exists():  # keep the hand-written sections after the generated part
        old = a.doc.read_text(encoding="utf-8")
        cut = old.find("\n## ")
        if cut >= 0:
            text += old[cut + 1:]
    a.doc.write_text(text, encoding="utf-8")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main_())
