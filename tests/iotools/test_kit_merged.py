"""The KIT merged milling CSV (DMG DMC 60H, edge signals + dynamometer at 50 Hz; issue 13)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cnctwin.exceptions import FormatError
from cnctwin.iotools import read_recording
from cnctwin.iotools.kit_merged import read_kit_merged

# evaluation-only data (PROVENANCE.md: read from ../shared, never copied into the repository)
KIT = Path(__file__).resolve().parents[3] / "shared" / "data" / "real" / "kit-dmc"
needs_kit = pytest.mark.skipif(not KIT.is_dir(), reason="the KIT excerpts are read from "
                               "../shared/data/real/kit-dmc (evaluation only, not vendored)")

LAYOUT = ("Unnamed: 0,time,pos_x,pos_sp,cmd_pos_x,cmd_v_sp,cont_dev_x,v_x,a_x,v_sp,a_sp,"
          "time_diff,f_x,f_y,f_z,a_p,a_e,phi,curr_x,curr_sp,f_sp_sim,materialremoved_sim,extra\n")


def _write(tmp_path: Path, rows: list[str]) -> Path:
    p = tmp_path / "DMC_test.csv"
    p.write_text("# a comment line\n" + LAYOUT + "".join(rows), encoding="utf-8")
    return p


def test_layout_maps_every_column(tmp_path: Path) -> None:
    rows = [f"{i},{0.02 * i:.2f},1.5,720.0,1.4,19200.0,0.01,8.0,0.1,19199.0,2.0,0.02,"
            f"-0.6,-3.8,-0.85,6,10,180,0.3,-3.17,744.0,560.0,7\n" for i in (10, 11, 13)]
    rec = read_recording(_write(tmp_path, rows))
    assert rec.meta.source_format == "kit_merged"
    assert rec.meta.cycle_time_s == 0.02
    assert rec.cycles.tolist() == [10, 11, 13]
    assert len(rec.meta.gaps) == 1  # row 12 missing: a counter gap, not invented
    assert rec.signal("CMD_SPEED", "SP1").tolist() == pytest.approx([3200.0] * 3)  # deg/s / 6
    assert rec.signal("SPEED_ACT", "SP1").iloc[0] == pytest.approx(19199.0 / 6)
    assert rec.meta.units["SPEED_ACT|SP1"] == "rpm"
    assert rec.signal("CURRENT", "SP1").iloc[0] == pytest.approx(-3.17)
    assert rec.signal("ENC_POS", "X1").iloc[0] == 1.5
    dyn = rec.external["dynamometer"]
    assert list(dyn.data.columns) == ["fx", "fy", "fz"]
    assert set(dyn.units.values()) == {"unknown"} and dyn.aligned
    assert rec.external["process"].data["a_e_mm"].iloc[0] == 10.0
    assert rec.external["simulation"].units == {"f_sp_sim": "N",
                                                "materialremoved_sim": "unknown"}
    assert "extra" in rec.columns and any("extra" in i for i in rec.meta.issues)


def test_bad_cell_names_row_and_column(tmp_path: Path) -> None:
    rows = ["1,0.02,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1\n",
            "2,0.04,1,1,1,abc,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1\n"]
    with pytest.raises(FormatError, match="not a number") as err:
        read_kit_merged(_write(tmp_path, rows))
    assert err.value.field == "cmd_v_sp"


@needs_kit
def test_the_real_excerpts_read() -> None:
    for f in sorted(KIT.glob("S235JR_*.csv")):
        rec = read_recording(f)
        n = rec.signal("SPEED_ACT", "SP1").to_numpy()
        assert np.isfinite(n).all()
        assert {round(float(np.median(n)) / 100) * 100} <= {2400, 3200, 4000}, f.name
    sample = read_recording(KIT / "kit_layout_sample.csv")
    assert sample.n_cycles == 2 and "CONT_DEV|Y1" in sample.columns
