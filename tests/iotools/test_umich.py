"""Tests of the UMich CNC Mill Tool Wear reader on the vendored real CSVs.

Facts checked by hand with awk on ``tests/data/real/umich-cnc-mill`` (independent of pandas):
``awk -F, 'NR>1{n++; if($48=="50.0"||$2=="198.0") inv++} END{print n, inv}'`` gives
experiment_01: 1055 rows, 64 invalid; experiment_02: 1668 / 1383; experiment_05: 462 / 414;
experiment_12: 2276 / 315; experiment_16: 602 / 496. ``uniq -c`` of column 49 of
experiment_05 gives 10 Prep, 72 Layer 1 Up, 380 End. Labels are rows of experiments.csv.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cnctwin.exceptions import FormatError
from cnctwin.iotools import read_umich, read_umich_dataset, read_umich_labels

UMICH = Path(__file__).parents[1] / "data" / "real" / "umich-cnc-mill"


@pytest.mark.parametrize(
    ("exp", "rows", "valid"),
    [(1, 1055, 991), (2, 1668, 285), (5, 462, 48), (12, 2276, 1961), (16, 602, 106)],
)
def test_rows_and_valid(exp: int, rows: int, valid: int) -> None:
    rec = read_umich(UMICH / f"experiment_{exp:02d}.csv")
    assert rec.n_cycles == rows
    assert int(rec.hf["VALID"].sum()) == valid
    assert any(f"{rows - valid} of {rows} rows are not valid" in i for i in rec.meta.issues)


def test_columns_units_and_mapping() -> None:
    rec = read_umich(UMICH / "experiment_01.csv")
    assert rec.meta.cycle_time_s == 0.1 and rec.fs_hz == 10.0
    # 48 data columns in the source (Machining_Process becomes events) + VALID
    assert len(rec.columns) == 47 + 1
    assert rec.axes == ["X1", "Y1", "Z1", "SP1"]
    first = rec.hf.iloc[0]
    # first data row of experiment_01.csv: X1_ActualPosition 198.0, X1_CurrentFeedback 0.18,
    # X1_OutputPower -1.42e-06 kW, S1_CurrentFeedback 0.524, M1_CURRENT_FEEDRATE 50.0
    assert first["ENC_POS|X1"] == 198.0
    assert first["DES_POS|X1"] == 198.0
    assert first["CURRENT|X1"] == pytest.approx(0.18)
    assert first["POWER|X1"] == pytest.approx(-1.42e-06 * 1000)
    assert first["CURRENT|SP1"] == pytest.approx(0.524)
    assert first["FEEDRATE"] == 50.0
    assert first["VALID"] == 0.0
    assert rec.meta.units["POWER|X1"] == "W"
    assert rec.meta.units["VELOCITY_ACT|X1"] == "mm/s"
    assert rec.meta.units["ENC_POS|X1"] == "mm"
    assert rec.meta.attrs["column_map"]["CURRENT|SP1"] == "S1_CurrentFeedback"
    assert any("CURRENT|Z1" in i and "zero in every row" in i for i in rec.meta.issues)


def test_phase_events() -> None:
    rec = read_umich(UMICH / "experiment_05.csv")
    ev = rec.events
    assert ev["gcode"].tolist() == ["Prep", "Layer 1 Up", "End"]
    assert ev["cycle"].tolist() == [0, 10, 82]
    assert set(ev["kind"]) == {"block"}


@pytest.mark.parametrize(
    ("exp", "cond", "feed", "clamp", "finalized", "visual"),
    [
        (1, "unworn", 6.0, 4.0, True, True),
        (4, "unworn", 6.0, 2.5, False, None),
        (6, "worn", 6.0, 4.0, True, False),
        (16, "worn", 20.0, 3.0, False, None),
    ],
)
def test_labels(exp: int, cond: str, feed: float, clamp: float, finalized: bool,
                visual: bool | None) -> None:
    rec = read_umich(UMICH / f"experiment_{exp:02d}.csv")
    lab = rec.meta.attrs["labels"]
    assert rec.meta.attrs["experiment"] == exp
    assert lab["tool_condition"] == cond
    assert lab["feedrate"] == feed and lab["clamp_pressure"] == clamp
    assert lab["machining_finalized"] is finalized
    assert lab["passed_visual_inspection"] is visual
    assert rec.meta.attrs["tool_condition_column"] == cond


def test_dataset() -> None:
    recs = read_umich_dataset(UMICH)
    assert [r.meta.attrs["experiment"] for r in recs] == [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 12,
                                                          14, 15, 16]
    assert sum(r.n_cycles for r in recs) == 16365 - 14 - 15  # wc -l total - headers - labels
    worn = [r.meta.attrs["experiment"] for r in recs
            if r.meta.attrs["labels"]["tool_condition"] == "worn"]
    assert worn == [6, 7, 8, 9, 10, 14, 15, 16]


def _copy_head(tmp_path: Path, n: int) -> list[str]:
    lines = (UMICH / "experiment_01.csv").read_text(encoding="utf-8").splitlines()[: n + 1]
    return lines


def test_wrong_row_length(tmp_path: Path) -> None:
    lines = _copy_head(tmp_path, 5)
    lines[3] = lines[3] + ",1.0"
    p = tmp_path / "experiment_01.csv"
    p.write_text("\n".join(lines) + "\n", encoding="utf-8")
    with pytest.raises(FormatError) as ei:
        read_umich(p)
    assert ei.value.position == "line 4"


def test_bad_number(tmp_path: Path) -> None:
    lines = _copy_head(tmp_path, 5)
    cells = lines[2].split(",")
    cells[1] = "abc"
    lines[2] = ",".join(cells)
    p = tmp_path / "experiment_01.csv"
    p.write_text("\n".join(lines) + "\n", encoding="utf-8")
    with pytest.raises(FormatError) as ei:
        read_umich(p)
    assert ei.value.position == "line 3" and ei.value.field == "X1_ActualPosition"


def test_missing_columns(tmp_path: Path) -> None:
    p = tmp_path / "experiment_99.csv"
    p.write_text("a,b\n1,2\n", encoding="utf-8")
    with pytest.raises(FormatError, match="missing column"):
        read_umich(p)


def test_no_label_row(tmp_path: Path) -> None:
    lines = _copy_head(tmp_path, 3)
    p = tmp_path / "experiment_99.csv"
    p.write_text("\n".join(lines) + "\n", encoding="utf-8")
    rec = read_umich(p, experiments_csv=UMICH / "experiments.csv")
    assert "labels" not in rec.meta.attrs
    assert any("no label row for experiment 99" in i for i in rec.meta.issues)
    assert np.all(rec.hf["VALID"].to_numpy() == 0.0)  # first rows have feedrate 50


# ---------------------------------------------------------------- damaged labels / encoding
def _labels(tmp_path: Path, edit: dict[int, str]) -> Path:
    """experiments.csv with lines replaced (1-based line number -> text)."""
    lines = (UMICH / "experiments.csv").read_text(encoding="utf-8").splitlines()
    for k, text in edit.items():
        lines[k - 1] = text
    p = tmp_path / "experiments.csv"
    p.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return p


def test_labels_short_row(tmp_path: Path) -> None:
    """A row missing fields used to give None labels (or AttributeError on a cut-off row)."""
    p = _labels(tmp_path, {3: "2,wax,20,4.0"})
    with pytest.raises(FormatError, match="row has 4 fields, the header 7") as ei:
        read_umich_labels(p)
    assert ei.value.position == "line 3"


def test_labels_experiment_listed_twice(tmp_path: Path) -> None:
    """A repeated experiment number used to overwrite the earlier row silently."""
    lines = (UMICH / "experiments.csv").read_text(encoding="utf-8").splitlines()
    p = _labels(tmp_path, {4: lines[1]})  # line 4 repeats experiment 1 (line 2)
    with pytest.raises(FormatError, match=r"experiment 1 is listed twice \(lines 2 and 4\)"):
        read_umich_labels(p)


def test_labels_bad_yes_no(tmp_path: Path) -> None:
    """A yes/no cell with other text used to become None (as if empty)."""
    p = _labels(tmp_path, {2: "1,wax,6,4.0,unworn,maybe,yes"})
    with pytest.raises(FormatError, match="machining_finalized 'maybe' is not yes or no") as ei:
        read_umich_labels(p)
    assert ei.value.position == "line 2"
    # empty stays "not given" (the source leaves passed_visual_inspection empty)
    ok = read_umich_labels(_labels(tmp_path, {2: "1,wax,6,4.0,unworn,no,"}))
    assert ok[1]["machining_finalized"] is False and ok[1]["passed_visual_inspection"] is None


def test_not_utf8(tmp_path: Path) -> None:
    """Non-UTF-8 bytes used to escape as UnicodeDecodeError."""
    p = tmp_path / "experiment_01.csv"
    p.write_bytes(b"X1_ActualPosition\n\xff\xfe\n")
    with pytest.raises(FormatError, match="not UTF-8") as ei:
        read_umich(p)
    assert ei.value.path == str(p)
    q = tmp_path / "experiments.csv"
    q.write_bytes(b"No,tool_condition\n1,\xffworn\n")
    with pytest.raises(FormatError, match="not UTF-8"):
        read_umich_labels(q)
