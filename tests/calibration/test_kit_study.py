"""The real KIT DMC 60H excerpts (evaluation only, read from ../shared): what docs/real-data-kit.md
states, asserted (scripts/study_kit.py writes the document)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
KIT = ROOT.parent / "shared" / "data" / "real" / "kit-dmc"
pytestmark = pytest.mark.skipif(not KIT.is_dir(), reason="the KIT excerpts are read from "
                                "../shared/data/real/kit-dmc (evaluation only, not vendored)")


def test_study_numbers(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    sys.path.insert(0, str(ROOT / "scripts"))
    try:
        import study_kit
    finally:
        sys.path.pop(0)
    assert study_kit.main(["--data", str(KIT), "--doc", str(tmp_path / "kit.md")]) == 0
    text = (tmp_path / "kit.md").read_text(encoding="utf-8")
    # the numbers from the files with the csv module and the hand formula (not cnctwin's
    # reader): Kt_eff = mean |F_xy| / (mean |I| - I_air), v_sp in deg/s
    def means(name: str) -> tuple[float, float, float]:
        import csv

        with open(KIT / name, encoding="utf-8") as f:
            rows = list(csv.DictReader(r for r in f if not r.startswith("#")))
        cur = sum(abs(float(r["curr_sp"])) for r in rows) / len(rows)
        fxy = sum(math.hypot(float(r["f_x"]), float(r["f_y"])) for r in rows) / len(rows)
        rpm = sum(float(r["v_sp"]) for r in rows) / len(rows) / 6.0
        return cur, fxy, rpm

    i_air = means("S235JR_Plate_Normal_Aircut_4__off0.csv")[0]
    kt = {}
    for key, name in (("Normal_1", "S235JR_Plate_Normal_1__off760000.csv"),
                      ("Depth_1", "S235JR_Plate_Depth_1__off750000.csv"),
                      ("SF_1", "S235JR_Plate_SF_1__off980000.csv")):
        cur, fxy, rpm = means(name)
        kt[key] = (fxy / (cur - i_air), rpm, cur - i_air, fxy)
    for key, label in (("Depth_1", "cut 3200 rpm, a_p 3 mm (Depth_1)"),
                       ("SF_1", "cut 2400 rpm, a_p 6 mm (SF_1)")):
        k, rpm, di, fxy = kt[key]
        err = 100.0 * (kt["Normal_1"][0] * di / fxy - 1.0)
        table = text.split("## Kt at each speed", 1)[1]
        row = next(ln for ln in table.splitlines() if ln.startswith(f"| {label} |"))
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert float(cells[1]) == pytest.approx(k, abs=6e-5)
        assert float(cells[2]) == pytest.approx(k * rpm, rel=2e-4)
        assert float(cells[3]) == pytest.approx(err, abs=0.06)
    # the findings: the thesis method holds at its own speed, fails one speed step down
    assert abs(100.0 * (kt["Normal_1"][0] * kt["Depth_1"][2] / kt["Depth_1"][3] - 1.0)) < 5.0
    assert 100.0 * (kt["Normal_1"][0] * kt["SF_1"][2] / kt["SF_1"][3] - 1.0) < -15.0
    capsys.readouterr()
