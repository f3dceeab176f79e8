"""Tests of the flattened-CSV (KIT layout) reader.

No real KIT file is vendored, so the fixture is made here from the real Capture4Analysis JSON
(``tests/data/real/capture4analysis``) with stdlib ``json`` + ``csv`` only (not cnctwin's own
writer): ``Header.SignalListHFData`` -> ``_header.csv`` (SignalName as the KIT long name,
Address), ``Payload[*].HFData`` rows -> ``_hfdata.csv``, ``Payload[*].HFBlockEvent`` ->
``_hfblockevent.csv``. Facts of the real file checked by hand (python json): 3818 HF rows of 61
values (CYCLE + 60 signals), first CYCLE 5558098, last 5565774, one counter jump of 3860 ticks
from 5559591 to 5563451 (3859 missing cycles), 78 HFBlockEvents, first at HFProbeCounter
5558103 with GCode "M17"; the HFBlockEvent at HFProbeCounter 5564831 has GCode "D0" followed
by 15 blanks; at HFProbeCounter 5564709 the payload holds three HFCallEvents (Path
"/_SEQUENCE", "/_WP_DIR/_P3", "/_TOOLCHANGE") and then the HFBlockEvent "D0"; 26 counters carry
both kinds, each as calls followed by one block.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cnctwin.exceptions import FormatError
from cnctwin.iotools import (
    parse_capture4analysis,
    read_capture4analysis,
    read_flat_csv,
    write_csv,
)
from cnctwin.recording import CYCLE_COUNTER_MODULUS, EVENT_COLUMNS, Recording

# KIT header.csv long names (docs/reference/data-formats.md 1.3); codes not listed keep the code as
# name
LONG_NAMES = {
    "ENC_POS": "ActualAxisPosition", "DES_POS": "CommandedAxisPosition", "LOAD": "Load",
    "CURRENT": "Current", "POWER": "Power", "TORQUE": "Torque", "CMD_SPEED": "CommandedSpeed",
    "CONT_DEV": "CountourDeviation", "VEL_FFW": "VelocityFeedForward",
    "TORQUE_FFW": "TorqueFeedForward",
}
BLOCK_FIELDS = ["HFProbeCounter", "Channel", "SeekOffset", "SelectedTool", "ActiveTool",
                "GCode", "IpoGC", "ipoReadError", "laBuf"]


def c4a_to_kit(c4a: Path, out: Path, trial: str, *, with_axis: bool = True) -> Path:
    """Convert a Capture4Analysis JSON to the KIT flat CSV layout (stdlib only)."""
    doc = json.loads(c4a.read_text(encoding="utf-8"))
    sig = doc["Header"]["SignalListHFData"]
    stem = out / trial
    with open(f"{stem}_header.csv", "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["SignalName", "Type", "Axis", "Address"])
        for s in sig:
            code = s["Address"].split("|")[0]
            axis = s["Axis"] if with_axis and s["Address"] != "CYCLE" else ""
            w.writerow([LONG_NAMES.get(code, code), s["Type"], axis, s["Address"]])
    with open(f"{stem}_hfdata.csv", "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow([s["Address"] for s in sig])
        for item in doc["Payload"]:
            for row in item.get("HFData", []):
                w.writerow([repr(v) if isinstance(v, float) else v for v in row])
    with open(f"{stem}_hfblockevent.csv", "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(BLOCK_FIELDS)
        for item in doc["Payload"]:
            if "HFBlockEvent" in item:
                ev = item["HFBlockEvent"]
                w.writerow(["" if ev.get(k) is None else ev.get(k) for k in BLOCK_FIELDS])
    return stem


@pytest.fixture(scope="module")
def kit_stem(tmp_path_factory: pytest.TempPathFactory, c4a_file: Path) -> Path:
    return c4a_to_kit(c4a_file, tmp_path_factory.mktemp("kit"), "T01")


@pytest.fixture(scope="module")
def rec(kit_stem: Path) -> Recording:
    return read_flat_csv(Path(f"{kit_stem}_hfdata.csv"))


def test_real_numbers(rec: Recording, c4a_file: Path) -> None:
    assert rec.n_cycles == 3818
    assert len(rec.columns) == 60
    assert rec.cycles[0] == 5558098 and rec.cycles[-1] == 5565774
    assert len(rec.events) == 78
    assert [(g.after_cycle, g.missing) for g in rec.meta.gaps] == [(5559591, 3859)]
    assert rec.meta.axis_map == {1: "X1", 2: "Y1", 3: "Z1", 4: "C1", 5: "B1", 6: "SP1"}
    ev0 = rec.events.iloc[0]
    assert ev0["cycle"] == 5558103 and ev0["gcode"] == "M17" and ev0["ipo_gcode"] == "G0"
    assert ev0["active_tool"] == 6 and ev0["kind"] == "block"
    # values agree with the JSON cell by cell (row 0, LOAD|6 = LOAD|SP1)
    doc = json.loads(c4a_file.read_text(encoding="utf-8"))
    addr = [s["Address"] for s in doc["Header"]["SignalListHFData"]]
    row0 = next(p for p in doc["Payload"] if "HFData" in p)["HFData"][0]
    assert rec.signal("LOAD|SP1").iloc[0] == row0[addr.index("LOAD|6")]
    assert rec.signal("ENC_POS|X1").iloc[0] == row0[addr.index("ENC_POS|1")]
    assert rec.meta.units["LOAD|SP1"] == "%"
    assert any("Unix epoch" in i for i in rec.meta.issues)


@pytest.mark.parametrize("suffix", ["_header.csv", "_hfblockevent.csv", ""])
def test_any_path_of_the_trial(kit_stem: Path, suffix: str) -> None:
    rec = read_flat_csv(Path(f"{kit_stem}{suffix}"))
    assert rec.n_cycles == 3818 and len(rec.events) == 78


def test_missing_header_uses_default_map(tmp_path: Path, c4a_file: Path) -> None:
    stem = c4a_to_kit(c4a_file, tmp_path, "T02")
    Path(f"{stem}_header.csv").unlink()
    rec = read_flat_csv(stem)
    assert "LOAD|SP1" in rec.columns
    assert any("default axis map" in i for i in rec.meta.issues)


def test_empty_axis_field(tmp_path: Path, c4a_file: Path) -> None:
    stem = c4a_to_kit(c4a_file, tmp_path, "T03", with_axis=False)
    rec = read_flat_csv(stem)
    assert "CURRENT|Z1" in rec.columns
    assert any("empty Axis field" in i for i in rec.meta.issues)


def _tiny(tmp_path: Path, rows: list[str]) -> Path:
    p = tmp_path / "S_hfdata.csv"
    p.write_text("CYCLE,LOAD|6,CURRENT|1\n" + "\n".join(rows) + "\n", encoding="utf-8")
    return p


def test_wrong_row_length_and_salvage(tmp_path: Path) -> None:
    p = _tiny(tmp_path, ["10,1.0,2.0", "11,1.5", "12,2.0,3.0"])
    with pytest.raises(FormatError) as ei:
        read_flat_csv(p)
    assert ei.value.position == "line 3" and ei.value.path == str(p)
    rec = read_flat_csv(p, salvage=True)
    assert rec.meta.partial
    assert rec.cycles.tolist() == [10, 12]
    assert any("wrong length" in i and "lines 3" in i for i in rec.meta.issues)


def test_bad_number(tmp_path: Path) -> None:
    p = _tiny(tmp_path, ["10,1.0,2.0", "11,x,2.0"])
    with pytest.raises(FormatError) as ei:
        read_flat_csv(p)
    assert ei.value.position == "line 3" and ei.value.field == "LOAD|6"


def test_empty_cells_are_nan(tmp_path: Path) -> None:
    rec = read_flat_csv(_tiny(tmp_path, ["10,1.0,2.0", "11,,2.0"]))
    assert np.isnan(rec.signal("LOAD|SP1").iloc[1])
    assert any("1 empty cells" in i for i in rec.meta.issues)


def test_no_hfdata(tmp_path: Path) -> None:
    with pytest.raises(FormatError, match=r"_hfdata\.csv"):
        read_flat_csv(tmp_path / "nothing")


def test_no_cycle_column(tmp_path: Path) -> None:
    p = tmp_path / "S_hfdata.csv"
    p.write_text("A,B\n1,2\n", encoding="utf-8")
    with pytest.raises(FormatError, match="no CYCLE"):
        read_flat_csv(p)


# ---------------------------------------------------------------------------- cells and order
def test_gcode_text_kept_verbatim(rec: Recording) -> None:
    """The stdlib-written CSV holds the real G-code "D0" + 15 blanks; the reader keeps them."""
    ev = rec.events.set_index("cycle")
    assert ev.loc[5564831, "gcode"] == "D0" + " " * 15
    assert ev.loc[5558103, "gcode"] == "M17"


def test_number_cells_stripped_text_cells_verbatim(tmp_path: Path) -> None:
    p = _tiny(tmp_path, ["10,1.0,2.0", "12,1.5,2.5"])
    Path(str(p).replace("_hfdata", "_hfblockevent")).write_text(
        "HFProbeCounter,Channel,GCode,IpoGC\n 12 , 1 , G1 X1 ,\n", encoding="utf-8")
    ev = read_flat_csv(p).events
    assert ev["cycle"].tolist() == [12] and ev["channel"].tolist() == [1]
    assert ev["gcode"].tolist() == [" G1 X1 "]
    assert ev["ipo_gcode"].tolist() == [None]


@pytest.fixture(scope="module")
def c4a_real(c4a_file: Path) -> Recording:
    return read_capture4analysis(c4a_file)


def test_event_order_matches_c4a_reader(c4a_real: Recording, tmp_path: Path) -> None:
    """Block and call events at one cycle come out in the C4A reader's order (calls first)."""
    files = write_csv(c4a_real, tmp_path / "T01")
    assert {"hfblockevent", "hfcallevent"} <= set(files)
    back = read_flat_csv(files["hfdata"])
    both = back.events.groupby("cycle")["kind"].agg(lambda k: set(k) == {"block", "call"})
    assert int(both.sum()) == 26
    at = back.events[back.events["cycle"] == 5564709]
    assert at["kind"].tolist() == ["call", "call", "call", "block"]
    assert at["path"].tolist()[:3] == ["/_SEQUENCE", "/_WP_DIR/_P3", "/_TOOLCHANGE"]
    assert at["gcode"].tolist()[3] == "D0"
    # the whole frame, row order and extra columns (ipo_read_error, la_buf) included
    pd.testing.assert_frame_equal(back.events, c4a_real.events)


def test_event_counters_unwrapped_next_to_hf(tmp_path: Path) -> None:
    """Events on both sides of a 2**31 wrap stay on the HF counter (written modulo 2**31)."""
    start = CYCLE_COUNTER_MODULUS - 150
    cycles = np.arange(start, start + 400)
    src = Recording.from_arrays(cycles, {"LOAD|X1": np.zeros(cycles.size)},
                                axis_map={1: "X1"})
    src.events = pd.DataFrame({
        "cycle": pd.Series([start + 5, start + 5, start + 300], dtype="int64"),
        "kind": pd.Series(["call", "block", "block"], dtype="object"),
        "channel": pd.array([1, 1, 1], dtype="Int64"),
        "seek_offset": pd.array([4, 4, 9], dtype="Int64"),
        "gcode": pd.Series([None, "G1 X1", "M30"], dtype="object"),
        "ipo_gcode": pd.Series([None, "G1", "G0"], dtype="object"),
        "selected_tool": pd.array([None, 3, 3], dtype="Int64"),
        "active_tool": pd.array([None, 3, 3], dtype="Int64"),
        "call_stack_level": pd.array([2, None, None], dtype="Int64"),
        "path": pd.Series(["/_N_SUB", None, None], dtype="object"),
    })[list(EVENT_COLUMNS)]
    back = read_flat_csv(write_csv(src, tmp_path / "W")["hfdata"])
    assert back.meta.wraps == 1
    np.testing.assert_array_equal(back.cycles, cycles)
    pd.testing.assert_frame_equal(back.events[list(EVENT_COLUMNS)], src.events)


DUP_ROWS = [[10, 1.0, 2.0], [11, 1.5, 2.5], [11, 9.0, 9.0], [12, 2.0, 3.0], [10, 7.0, 7.0]]
"""Rows at file lines 2..6: cycle 11 repeats at line 4, cycle 10 at line 6 (out of order)."""


def test_duplicate_cycle_keeps_first_and_names_lines(tmp_path: Path) -> None:
    rec = read_flat_csv(_tiny(tmp_path, [",".join(map(str, r)) for r in DUP_ROWS]))
    assert rec.cycles.tolist() == [10, 11, 12]
    # the first row of each cycle in file order: line 2 for 10, line 3 for 11
    np.testing.assert_array_equal(rec.signal("LOAD|SP1").to_numpy(), [1.0, 1.5, 2.0])
    np.testing.assert_array_equal(rec.signal("CURRENT|X1").to_numpy(), [2.0, 2.5, 3.0])
    dup = [i for i in rec.meta.issues if "duplicate CYCLE" in i]
    assert len(dup) == 1
    assert "2 duplicate CYCLE row(s) (DIFFERENT values)" in dup[0]
    assert "cycle 10: line 6 (kept line 2)" in dup[0]
    assert "cycle 11: line 4 (kept line 3)" in dup[0]
    assert any("not in cycle order" in i for i in rec.meta.issues)


def test_duplicate_cycle_same_rule_as_c4a(tmp_path: Path) -> None:
    """The flat CSV and the Capture4Analysis reader keep the same row of a repeated cycle."""
    doc = {
        "Header": {"CycleTimeMs": 2, "SignalListHFData": [
            {"Address": "CYCLE"}, {"Address": "LOAD|6", "Axis": "SP1"},
            {"Address": "CURRENT|1", "Axis": "X1"},
        ]},
        "Payload": [{"HFData": DUP_ROWS}],
    }
    c4a = parse_capture4analysis(json.dumps(doc).encode())
    flat = read_flat_csv(_tiny(tmp_path, [",".join(map(str, r)) for r in DUP_ROWS]))
    assert any("kept the first arrival" in i for i in c4a.meta.issues)
    np.testing.assert_array_equal(flat.cycles, c4a.cycles)
    pd.testing.assert_frame_equal(flat.hf[flat.columns], c4a.hf[flat.columns])
