"""Study: the spindle torque sensor across speeds on the real KIT DMC 60H excerpts (issue 13).

Reads the evaluation-only excerpts from ``../shared/data/real/kit-dmc`` (never copied into the
repository) with :func:`cnctwin.iotools.read_recording` (the KIT merged-CSV reader), and writes
``docs/real-data-kit.md``:

* per excerpt: speed, spindle current, the force resultant |F_xy| of the dynamometer (unit not
  stated in the data set) and the authors' simulated spindle force;
* the torque reference: slot milling (a_e = D = 10 mm, phi 180 deg) of the same plate with the
  same feed per revolution; the mean cutting torque is taken proportional to the mean force
  resultant in the table plane (M = F_t r with F_t a fixed share of |F_xy| for the same tool,
  immersion and chip; r = 5 mm). The unknown force unit and that share cancel in every ratio,
  so errors are relative and need no scale;
* the effective torque constant Kt_eff = |F_xy| / (I_cut - I_air) at each speed, the thesis
  method (one Kt from the 3200 rpm cut) against the speed law
  (:func:`cnctwin.spindle.fit_flux_law`).

Usage::

    .venv/bin/python scripts/study_kit.py [--data ../shared/data/real/kit-dmc]
        [--doc docs/real-data-kit.md]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from cnctwin.iotools import read_recording
from cnctwin.spindle import fit_flux_law


def _stats(path: Path) -> dict[str, float]:
    r = read_recording(path)
    n = r.signal("SPEED_ACT", "SP1").to_numpy(dtype=np.float64)
    i = np.abs(r.signal("CURRENT", "SP1").to_numpy(dtype=np.float64))
    d = r.external["dynamometer"].data
    f = np.hypot(d["fx"].to_numpy(), d["fy"].to_numpy())
    sim = r.external.get("simulation")
    fsp = float(sim.data["f_sp_sim"].mean()) if sim is not None and "f_sp_sim" in sim.data \
        else float("nan")
    return {"speed_rpm": float(n.mean()), "current_a": float(i.mean()),
            "current_se": float(i.std(ddof=1) / np.sqrt(i.size)), "f_xy": float(f.mean()),
            "f_xy_se": float(f.std(ddof=1) / np.sqrt(f.size)), "f_sp_sim_n": fsp,
            "rows": float(r.n_cycles)}


def _kt_law(law: object, speed_rpm: float) -> float:
    """Kt of the fitted flux law at a speed: constant below the base speed, (n_b / n)^p above."""
    kt = float(law.kt_nm_per_a)  # type: ignore[attr-defined]
    nb = float(law.base_speed_rpm)  # type: ignore[attr-defined]
    p = float(getattr(law, "exponent", 1.0))
    return kt * (nb / speed_rpm) ** p if speed_rpm > nb > 0 else kt


def _holdout_section(folder: Path, law: object, kt_thesis: float,
                     air: dict[float, float]) -> list[str]:
    """The calibrated law and the thesis method on cuts not used to calibrate."""
    lines = [
        "## Cuts not among the excerpts: the check of the calibrated law",
        "",
        f"Cuts of the same machine and plate series from `{folder.name}/` (each file's header "
        "names its source file, commit and character offset; evaluation-only data, kept out "
        "of the repository). Neither the law nor the thesis Kt saw them. The air current at "
        "the cut's speed is that of the nearest air-cut excerpt.",
        "",
        "| cut | speed [rpm] | I - I_air [A] | F_xy measured | law: Kt(n) x (I - I_air), "
        "error [%] | thesis: one Kt (3200 rpm), error [%] |",
        "|---|---|---|---|---|---|",
    ]
    for f in sorted(folder.glob("*.csv")):
        s = _stats(f)
        n = s["speed_rpm"]
        i_air = air[min(air, key=lambda v: abs(v - n))]
        di = s["current_a"] - i_air
        law_err = 100.0 * (_kt_law(law, n) * di / s["f_xy"] - 1.0)
        thesis_err = 100.0 * (kt_thesis * di / s["f_xy"] - 1.0)
        lines.append(f"| {f.stem} | {n:.0f} | {di:.3f} | {s['f_xy']:.3f} +- "
                     f"{s['f_xy_se']:.3f} | {law_err:+.1f} | {thesis_err:+.1f} |")
    lines += ["", "Where each hold-out excerpt comes from (anyone with the source can repeat "
              "it):", ""]
    for f in sorted(folder.glob("*.csv")):
        head = f.read_text(encoding="utf-8").splitlines()[0].lstrip("# ").strip()
        lines.append(f"* {f.stem}: {head}")
    lines += [
        "",
        "The law's error carries the force reference's own scatter (the standard error of "
        "the mean resultant over 0.44 s is 0.3-0.6 %) and the assumption that the share of "
        "the tangential force in |F_xy| is the same in every cut (same tool, immersion and "
        "chip; a slot turning direction changes how the force splits between X and Y, not "
        "the resultant).",
        "",
    ]
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path,
                    default=Path(__file__).resolve().parents[2] / "shared" / "data" / "real"
                    / "kit-dmc")
    ap.add_argument("--doc", type=Path, default=Path("docs/real-data-kit.md"))
    ap.add_argument("--holdout", type=Path, metavar="DIR",
                    help="more excerpts in the same layout, not used to calibrate: cuts the "
                    "calibrated law is checked on (evaluation only: keep them outside the "
                    "repository)")
    a = ap.parse_args(argv)
    if not a.data.is_dir():
        raise SystemExit(f"{a.data}: the KIT excerpts are not there (evaluation-only data, "
                         "read from ../shared/data/real/kit-dmc)")
    files = {
        "cut 3200 rpm, a_p 6 mm (Normal_1)": "S235JR_Plate_Normal_1__off760000.csv",
        "cut 3200 rpm, a_p 3 mm (Depth_1)": "S235JR_Plate_Depth_1__off750000.csv",
        "cut 2400 rpm, a_p 6 mm (SF_1)": "S235JR_Plate_SF_1__off980000.csv",
        "air 3200 rpm (Normal_Aircut_4)": "S235JR_Plate_Normal_Aircut_4__off0.csv",
        "air 4000 rpm (SF_Aircut_4)": "S235JR_Plate_SF_Aircut_4__off0.csv",
    }
    st = {k: _stats(a.data / v) for k, v in files.items()}
    air = {3200.0: st["air 3200 rpm (Normal_Aircut_4)"]["current_a"],
           4000.0: st["air 4000 rpm (SF_Aircut_4)"]["current_a"]}
    # no air cut at 2400 rpm in the excerpts: the air current is flat between 3200 and 4000
    # (0.642 / 0.639 A); 2400 rpm takes the 3200 rpm value, +-0.01 A stated
    air_at = {2400.0: air[3200.0], 3200.0: air[3200.0]}
    cuts = [k for k in st if k.startswith("cut")]
    # cutting current above the air current at the cut's speed
    di = {k: st[k]["current_a"] - air_at[round(st[k]["speed_rpm"] / 100) * 100.0]
          for k in cuts}
    kt_eff = {k: st[k]["f_xy"] / di[k] for k in cuts}
    cal = "cut 3200 rpm, a_p 6 mm (Normal_1)"
    thesis = {k: 100.0 * (kt_eff[cal] * di[k] / st[k]["f_xy"] - 1.0) for k in cuts}
    law = fit_flux_law([st[k]["speed_rpm"] for k in (cal, "cut 2400 rpm, a_p 6 mm (SF_1)")],
                       [kt_eff[cal], kt_eff["cut 2400 rpm, a_p 6 mm (SF_1)"]])
    kt_n = {k: kt_eff[k] * st[k]["speed_rpm"] for k in cuts}
    mean_ktn = float(np.mean([kt_n[cal], kt_n["cut 2400 rpm, a_p 6 mm (SF_1)"]]))
    gamma = float(np.log(kt_eff["cut 2400 rpm, a_p 6 mm (SF_1)"] / kt_eff[cal])
                  / np.log(3200.0 / 2400.0))
    lines = [
        "# The spindle torque sensor across speeds: the real KIT DMC 60H excerpts (issue 13)",
        "",
        "Generated by `scripts/study_kit.py` from the excerpts in "
        "`../shared/data/real/kit-dmc/` (KIT wbk, DMG MORI DMC 60H with SINUMERIK and "
        "Industrial Edge; slot milling of S235JR plates, 10 mm tool, a_e 10 mm; edge signals "
        "filtered and resampled to 50 Hz by the authors and merged with a dynamometer). The "
        "data are licensed for evaluation only: they are read from `../shared`, never copied "
        "into this repository; the reader is `cnctwin.iotools.kit_merged` "
        "(`cnctwin info FILE` reads them).",
        "",
        "## What each excerpt holds (22-23 rows = 0.44 s)",
        "",
        "| excerpt | speed [rpm] | spindle current [A] | force resultant F_xy [unit unknown] "
        "| simulated spindle force [N] |",
        "|---|---|---|---|---|",
    ]
    for k, s in st.items():
        lines.append(f"| {k} | {s['speed_rpm']:.0f} | {s['current_a']:.3f} +- "
                     f"{s['current_se']:.3f} | {s['f_xy']:.3f} +- {s['f_xy_se']:.3f} | "
                     + (f"{s['f_sp_sim_n']:.0f}" if np.isfinite(s["f_sp_sim_n"]) else "-")
                     + " |")
    lines += [
        "",
        "## The torque reference and its assumptions",
        "",
        "* The dynamometer forces carry no unit in the data set (about 1/200 of the authors' "
        "simulated force in N): they are kept as unknown and used only in ratios.",
        "* Slot milling with the same tool, immersion and feed per revolution: the mean "
        "cutting torque is proportional to the mean force resultant in the table plane, "
        "M = k |F_xy| r, with the same k at every speed (same chip: the authors' simulated "
        "spindle force is 744 N at both 2400 and 3200 rpm for a_p 6 mm). k, r and the force "
        "unit cancel in every relative error below.",
        "* Air current: 0.642 A at 3200 rpm and 0.639 A at 4000 rpm (flat); the excerpts "
        "hold no air cut at 2400 rpm, so 0.642 A is used there (an error of 0.01 A moves the "
        "2400 rpm Kt by 0.5 %).",
        "",
        "## Kt at each speed, the thesis method and the speed law",
        "",
        "| cut | Kt_eff = F_xy / (I - I_air) [unit/A] | Kt_eff x speed | thesis method "
        "(Kt from 3200 rpm, a_p 6), error of the torque [%] |",
        "|---|---|---|---|",
    ]
    for k in cuts:
        lines.append(f"| {k} | {kt_eff[k]:.4f} | {kt_n[k]:.0f} | {thesis[k]:+.1f} |")
    lines += [
        "",
        f"* Same speed, other depth (3200 rpm, a_p 3 mm): the thesis method holds "
        f"({thesis['cut 3200 rpm, a_p 3 mm (Depth_1)']:+.1f} %).",
        f"* One speed step down (2400 rpm, same chip): it misses by "
        f"{thesis['cut 2400 rpm, a_p 6 mm (SF_1)']:+.1f} %: the cutting current at the same "
        "chip grows with speed.",
        f"* Kt_eff x speed is {kt_n[cal]:.0f} at 3200 rpm and "
        f"{kt_n['cut 2400 rpm, a_p 6 mm (SF_1)']:.0f} at 2400 rpm: constant within "
        f"{100 * abs(kt_n[cal] - mean_ktn) / mean_ktn:.1f} % of their mean, the constant-power "
        f"range of an induction spindle above its base speed; the exponent between the two "
        f"speeds is {gamma:.2f} (1 = constant power).",
        f"* `fit_flux_law` on the two cuts (exponent 1 stated, two speeds cannot fit it): Kt "
        f"{law.kt_nm_per_a:.4f} unit/A below a base speed of {law.base_speed_rpm:.0f} rpm "
        f"({law.base_speed_bound or 'inside the calibration speeds'}), n_b/n above. Calibrated "
        "on both, the model reproduces both by construction; the check is on other cuts "
        "(below, with `--holdout`).",
        "",
    ]
    lines += _holdout_section(a.holdout, law, kt_eff[cal], air) if a.holdout else [
        "## What this study cannot show",
        "",
        "The acceptance of issue 13 asks for cuts of the same machine at other speeds, not "
        "among the excerpts, predicted within 5 %: run with `--holdout DIR` on such cuts.",
        "",
    ]
    lines += [
        "## What to record",
        "",
        "To calibrate such a spindle a user records: an air cut up and back down through the "
        "speed range (its current bends where the flux weakening starts); reference cuts with "
        "a known torque (dynamometer, or a torque from the cutting-force model) at **two or "
        "more speeds**, one below and one above the expected base speed, better three to fit "
        "the exponent; the motor data sheet's rated (base) speed as a cross-check. "
        "`cnctwin calibrate spindle --reference cut_2400.json cut_3200.json --dynamometer "
        "d_2400.csv d_3200.csv ...` writes Kt, the base speed and the valid speed range; "
        "estimates outside that range are flagged (`kt_extrapolated`).",
        "",
    ]
    a.doc.write_text("\n".join(lines), encoding="utf-8")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
