"""Capture4Analysis reader and writer.

Facts about the real file (``tests/data/real/capture4analysis/example_data_ff429d74-...json``,
max-scw/CaptureDataParser, MIT) were counted by hand with ``orjson.loads`` on the raw JSON
(not with the reader): 127 HFData entries holding 3818 rows of 61 values; 78 HFBlockEvent,
49 HFCallEvent, 47 HFTimestamp and 14 LFData entries (70 LF values, 14 per address); first
cycle 5558098, last 5565774; one counter step of 3860 between rows 1493 and 1494 (0-based)
of the sorted counter (5559591 -> 5563451, i.e. 3859 missing cycles); ``CURRENT|6`` in
[-5.371338, 5.197021]; ``LOAD|2`` max 54.071045. The format is described in
``docs/reference/data-formats.md`` section 1.
"""

from __future__ import annotations

import itertools
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import orjson
import pandas as pd
import pytest

from cnctwin.iotools import (
    Capture4AnalysisWriter,
    read_capture4analysis,
    read_recording,
    write_capture4analysis,
)
from cnctwin.recording import CYCLE_COUNTER_MODULUS, EVENT_COLUMNS, CounterGap, Recording


@pytest.fixture(scope="module")
def real(c4a_file: Path) -> Recording:
    return read_capture4analysis(c4a_file)


@pytest.fixture(scope="module")
def raw(c4a_file: Path) -> dict[str, Any]:
    return orjson.loads(c4a_file.read_bytes())


# ---------------------------------------------------------------------------- real file
def test_real_counts(real: Recording) -> None:
    assert real.n_cycles == 3818
    assert len(real.columns) == 60  # 61 with CYCLE, which is the index
    assert real.hf.shape == (3818, 61)  # + time
    assert real.axes == ["C1", "B1", "SP1", "X1", "Y1", "Z1"]  # header order of first use
    assert sorted(real.axes) == sorted(["X1", "Y1", "Z1", "C1", "B1", "SP1"])
    assert int(real.cycles[0]) == 5558098
    assert int(real.cycles[-1]) == 5565774
    assert real.meta.machine == "sinumerik_adapter_840Dsl"
    assert real.meta.cycle_time_s == pytest.approx(0.002)
    assert real.meta.axis_map == {1: "X1", 2: "Y1", 3: "Z1", 4: "C1", 5: "B1", 6: "SP1"}
    assert not real.meta.partial
    assert real.meta.wraps == 0


def test_real_gap(real: Recording) -> None:
    # counter step of 3860 (3859 missing cycles): 1494 rows before it, 2324 after
    assert real.meta.gaps == [CounterGap(5559591, 5563451)]
    assert real.meta.gaps[0].missing == 3859
    step = np.diff(real.cycles)
    assert int(np.flatnonzero(step > 1)[0]) == 1493
    assert int(step.max()) == 3860
    assert any("3859 cycles missing" in i for i in real.meta.issues)


def test_real_events(real: Recording) -> None:
    ev = real.events
    assert list(ev.columns[: len(EVENT_COLUMNS)]) == list(EVENT_COLUMNS)
    assert (ev["kind"] == "block").sum() == 78
    assert (ev["kind"] == "call").sum() == 49
    assert ev["cycle"].is_monotonic_increasing
    first = ev.iloc[0]
    assert (first["cycle"], first["kind"], first["gcode"], first["ipo_gcode"]) == (
        5558103, "block", "M17", "G0")
    calls = ev[ev["kind"] == "call"]
    assert calls.iloc[0]["path"] == "/_CUTTING"
    assert int(calls.iloc[0]["call_stack_level"]) == 2
    # G-code text with brackets and commas is kept verbatim
    assert "S[iAnr2]=rDrzahlWK[iToolNr,iSZpr]" in set(ev["gcode"].dropna())


def test_real_anchors_and_time(real: Recording) -> None:
    assert len(real.meta.time_anchors) == 48  # Initial + 47 HFTimestamp
    t = real.hf["time"]
    assert str(t.dtype) == "datetime64[ns, UTC]"
    # the counter is the clock: exactly 2 ms per cycle
    dt_ns = np.diff(pd.DatetimeIndex(t).as_unit("ns").asi8)
    np.testing.assert_array_equal(dt_ns, np.diff(real.cycles) * 2_000_000)
    # anchors before the gap sit 8.0 s off those after it (real-file finding, see issues)
    assert real.meta.attrs["anchor_spread_ms"] == pytest.approx(8005.0, abs=2.0)
    assert any("time anchors disagree" in i for i in real.meta.issues)


def test_real_lf(real: Recording) -> None:
    lf = real.lf
    assert len(lf) == 70
    assert lf["signal"].nunique() == 5
    assert (lf.groupby("signal").size() == 14).all()
    assert lf["value"].notna().all()  # all 70 strings are numeric
    first = lf[(lf["cycle"] == 5558360) & (lf["signal"] == "/Channel/State/actToolLength2")]
    assert first["text"].iloc[0] == "75.316999999999993"
    assert first["value"].iloc[0] == pytest.approx(75.317, abs=1e-12)
    # LF wall clock is ~1 h 02 min behind the HF clock (docs/reference/data-formats.md 1.2)
    assert real.meta.attrs["lf_wall_clock_offset_s"] == pytest.approx(-3732.2, abs=10.0)
    assert len(real.meta.attrs["lf_wall_clock"]) == 70


def test_real_values(real: Recording, raw: dict[str, Any]) -> None:
    cur = real.signal("CURRENT", "SP1")
    assert cur.min() == pytest.approx(-5.371338, abs=1e-9)
    assert cur.max() == pytest.approx(5.197021, abs=1e-9)
    assert cur.min() >= -5.38 and cur.max() <= 5.20
    assert real.signal("LOAD|Y1").max() == pytest.approx(54.071045, abs=1e-9)
    # spot check against the raw JSON: last row of the file, column LOAD|6
    names = [s["Address"] for s in raw["Header"]["SignalListHFData"]]
    last = raw["Payload"][-2]["HFData"][-1]
    assert last[0] == 5565774
    assert real.hf.loc[5565774, "LOAD|SP1"] == last[names.index("LOAD|6")]


def test_real_header_attrs(real: Recording) -> None:
    a = real.meta.attrs
    assert a["job_description"] == {"TriggersOn": {"activeTool": "6"},
                                     "TriggersOff": {"ncCode": "M6"}}
    assert a["version"] == {"outputFileFormatVersion": "1.0", "RecorderVersion": "3.1.0-36"}
    assert a["initial"] == {"Time": "2023-12-22T14:25:56.836Z", "HFProbeCounter": 5555962}
    assert len(a["signal_list_lf"]) == 5
    assert real.meta.units["CURRENT|SP1"] == "A"


def test_read_recording_dispatches(c4a_file: Path) -> None:
    rec = read_recording(c4a_file)
    assert rec.meta.source_format == "capture4analysis"
    assert rec.n_cycles == 3818


# ---------------------------------------------------------------------------- chains
def test_chain_split_in_three(real: Recording, tmp_path: Path) -> None:
    files = write_capture4analysis(real, tmp_path / "run.json", max_file_mb=0.8)
    assert [f.name for f in files] == ["run.json", "run_2.json", "run_3.json"]
    docs = [orjson.loads(f.read_bytes()) for f in files]
    chain = [d["Footer"]["FilePathChain"] for d in docs]
    assert chain[0]["Previous"] is None and chain[0]["Next"] == "run_2.json"
    assert chain[1]["Previous"] == "run.json" and chain[1]["Next"] == "run_3.json"
    assert chain[2]["Next"] is None and chain[2]["Index"] == 3
    # Siemens behaviour: the last block event of a file opens the next one
    for prev, nxt in itertools.pairwise(docs):
        last = [p["HFBlockEvent"] for p in prev["Payload"] if "HFBlockEvent" in p][-1]
        assert nxt["Payload"][0] == {"HFBlockEvent": last}
    back = read_capture4analysis(files[0])
    assert back.meta.source_files == [str(f) for f in files]
    pd.testing.assert_frame_equal(back.hf, real.hf)
    pd.testing.assert_frame_equal(back.events, real.events)
    pd.testing.assert_frame_equal(back.lf, real.lf)
    assert sum("removed the repeated block event" in i for i in back.meta.issues) == 2
    # without following the chain only the first file is read
    first = read_capture4analysis(files[0], follow_chain=False)
    assert first.n_cycles < real.n_cycles
    assert any("follow_chain=False" in i for i in first.meta.issues)


def test_chain_in_zip(real: Recording, tmp_path: Path) -> None:
    (path,) = write_capture4analysis(real, tmp_path / "run.zip", max_file_mb=0.8, zip=True)
    assert sorted(zipfile.ZipFile(path).namelist()) == ["run.json", "run_2.json", "run_3.json"]
    back = read_recording(path)
    pd.testing.assert_frame_equal(back.hf, real.hf)
    assert len(back.meta.source_files) == 3


def test_chain_missing_next_is_flagged(real: Recording, tmp_path: Path) -> None:
    files = write_capture4analysis(real, tmp_path / "run.json", max_file_mb=0.8)
    files[2].unlink()
    rec = read_capture4analysis(files[0])
    assert rec.meta.partial
    assert any("run_3.json" in i and "incomplete" in i for i in rec.meta.issues)


def test_reordered_header_per_file(real: Recording, tmp_path: Path) -> None:
    """HF signal order may change between files of a run: each file is mapped by Address."""
    files = write_capture4analysis(real, tmp_path / "run.json", max_file_mb=0.8)
    doc = orjson.loads(files[1].read_bytes())
    sig = doc["Header"]["SignalListHFData"]
    perm = [0, *reversed(range(1, len(sig)))]
    doc["Header"]["SignalListHFData"] = [sig[i] for i in perm]
    for p in doc["Payload"]:
        if "HFData" in p:
            p["HFData"] = [[row[i] for i in perm] for row in p["HFData"]]
    files[1].write_bytes(orjson.dumps(doc))
    back = read_capture4analysis(files[0])
    pd.testing.assert_frame_equal(back.hf, real.hf)


# ---------------------------------------------------------------------------- round trips
def _synthetic(n: int = 1000, start: int = 1000, *, seed: int = 1) -> Recording:
    rng = np.random.default_rng(seed)
    cycles = np.arange(start, start + n)
    cycles = np.delete(cycles, np.arange(300, 320))  # a gap of 20 cycles
    sig: dict[str, Any] = {
        f"{code}|{ax}": rng.standard_normal(cycles.size) * 10.0 ** rng.integers(-6, 4)
        for code in ("CURRENT", "ENC_POS") for ax in ("X1", "Z1", "SP1")}
    rec = Recording.from_arrays(cycles, sig, start_time="2024-05-01T10:00:00.123456789Z",
                                machine="sim", axis_map={1: "X1", 3: "Z1", 6: "SP1"})
    rec.events = pd.DataFrame({
        "cycle": pd.Series([start + 5, start + 5, start + 400], dtype="int64"),
        "kind": pd.Series(["block", "call", "block"], dtype="object"),
        "channel": pd.array([1, 1, 1], dtype="Int64"),
        "seek_offset": pd.array([10, 20, 30], dtype="Int64"),
        "gcode": pd.Series(["G1 X[1,2]", None, "M30"], dtype="object"),
        "ipo_gcode": pd.Series(["G1", None, "G0"], dtype="object"),
        "selected_tool": pd.array([3, None, 3], dtype="Int64"),
        "active_tool": pd.array([3, None, 3], dtype="Int64"),
        "path": pd.Series([None, "/_N_SUB", None], dtype="object"),
        "call_stack_level": pd.array([None, 2, None], dtype="Int64"),
    })
    return rec


def test_write_read_round_trip_bit_exact(tmp_path: Path) -> None:
    rec = _synthetic()
    (path,) = write_capture4analysis(rec, tmp_path / "syn.json")
    back = read_capture4analysis(path)
    np.testing.assert_array_equal(back.cycles, rec.cycles)
    a = back.hf[rec.columns].to_numpy()
    b = rec.hf[rec.columns].to_numpy()
    assert a.tobytes() == b.tobytes()  # float64 bit-exact through orjson
    pd.testing.assert_series_equal(back.hf["time"], rec.hf["time"])
    assert back.meta.gaps == rec.meta.gaps == [CounterGap(1299, 1320)]
    assert back.meta.axis_map == {1: "X1", 3: "Z1", 6: "SP1"}
    pd.testing.assert_frame_equal(back.events[list(EVENT_COLUMNS)], rec.events)
    header = orjson.loads(path.read_bytes())["Header"]
    addresses = {s["Address"]: s["Axis"] for s in header["SignalListHFData"]}
    assert addresses["CURRENT|6"] == "SP1" and addresses["ENC_POS|3"] == "Z1"


def test_write_wraps_counter(tmp_path: Path) -> None:
    start = CYCLE_COUNTER_MODULUS - 150
    rec = _synthetic(n=400, start=start)
    (path,) = write_capture4analysis(rec, tmp_path / "wrap.json")
    doc = orjson.loads(path.read_bytes())
    raw = [r[0] for p in doc["Payload"] if "HFData" in p for r in p["HFData"]]
    assert max(raw) < CYCLE_COUNTER_MODULUS and min(raw) == 0
    back = read_capture4analysis(path)
    assert back.meta.wraps == 1
    np.testing.assert_array_equal(back.cycles, rec.cycles)
    np.testing.assert_array_equal(back.events["cycle"], rec.events["cycle"])


def test_writer_streams_chunks(tmp_path: Path) -> None:
    cols = ["CURRENT|X1", "LOAD|SP1"]
    t0 = pd.Timestamp("2024-01-01T00:00:00Z")
    with Capture4AnalysisWriter(tmp_path / "s.json", columns=cols, machine="m",
                                initial=(10, t0), chunk_rows=7) as w:
        for k in range(5):
            c = np.arange(10 + 20 * k, 30 + 20 * k)
            w.write_hf(c, np.column_stack([c * 0.5, c * -1.0]))
            w.write_timestamp(int(c[-1]), t0 + pd.Timedelta(milliseconds=2 * (int(c[-1]) - 10)))
        w.write_block_event(50, gcode="G1 X10", ipo_gcode="G1")
        w.write_lf([{"cycle": 60, "signal": "/Channel/State/actTNumber", "value": "6"}])
        w.write_payload("ExternalData", {"sensor": [1, 2]})
    back = read_capture4analysis(tmp_path / "s.json")
    assert back.n_cycles == 100
    np.testing.assert_array_equal(back.signal("CURRENT|X1").to_numpy(), back.cycles * 0.5)
    assert back.hf["time"].iloc[0] == t0
    assert back.lf["value"].tolist() == [6.0]
    assert back.meta.attrs["payload_other"] == {"ExternalData": [{"sensor": [1, 2]}]}
    assert any("ExternalData" in i for i in back.meta.issues)
    doc = orjson.loads((tmp_path / "s.json").read_bytes())
    assert max(len(p["HFData"]) for p in doc["Payload"] if "HFData" in p) == 7


# ---------------------------------------------------------------------------- repairs
def _doc(rows: list[list[Any]], *, signals: list[dict[str, Any]] | None = None,
         payload_extra: list[dict[str, Any]] | None = None) -> dict[str, Any]:
    signals = signals or [
        {"Name": "CYCLE", "Type": "INTEGER", "Axis": "Cycle", "Address": "CYCLE"},
        {"Name": "Current", "Type": "DOUBLE", "Axis": "", "Address": "CURRENT|6"},
        {"Name": "Load", "Type": "DOUBLE", "Axis": "X1", "Address": "LOAD|1"},
    ]
    return {
        "Footer": {"ErrorMessages": [], "FilePathChain": {"Previous": None, "Actual": "a.json",
                                                          "Next": None, "Index": 1}},
        "Payload": [{"HFData": rows}, *(payload_extra or [])],
        "Header": {"CycleTimeMs": 2, "SignalListHFData": signals,
                   "Initial": {"HFProbeCounter": 100, "Time": "2024-01-01T00:00:00.000Z"},
                   "MachineInfo": {"MachineName": "m"}},
    }


def test_empty_axis_repaired_and_name_ignored(tmp_path: Path) -> None:
    p = tmp_path / "a.json"
    p.write_bytes(orjson.dumps(_doc([[101, 1.5, 2.5], [100, 0.5, 3.5]])))
    rec = read_capture4analysis(p)
    assert rec.columns == ["CURRENT|SP1", "LOAD|X1"]  # Address, not Name ("Current")
    assert any("empty Axis field repaired to 'SP1'" in i for i in rec.meta.issues)
    # arrival order 101, 100 -> sorted by cycle
    np.testing.assert_array_equal(rec.cycles, [100, 101])
    np.testing.assert_array_equal(rec.signal("CURRENT|SP1"), [0.5, 1.5])
    rec2 = read_capture4analysis(p, axis_map={6: "S1"})
    assert rec2.columns == ["CURRENT|S1", "LOAD|X1"]


def test_unknown_axis_number_kept(tmp_path: Path) -> None:
    sig = [{"Name": "CYCLE", "Type": "INTEGER", "Axis": "Cycle", "Address": "CYCLE"},
           {"Name": "x", "Type": "DOUBLE", "Axis": "", "Address": "CURRENT|9"}]
    p = tmp_path / "a.json"
    p.write_bytes(orjson.dumps(_doc([[100, 1.0]], signals=sig)))
    rec = read_capture4analysis(p)
    assert rec.columns == ["CURRENT|9"]
    assert any("axis number 9 not in the axis map" in i for i in rec.meta.issues)


def test_duplicate_cycles_keep_first(tmp_path: Path) -> None:
    p = tmp_path / "a.json"
    p.write_bytes(orjson.dumps(_doc([[100, 1.0, 1.0], [101, 2.0, 2.0], [101, 9.0, 9.0]])))
    rec = read_capture4analysis(p)
    np.testing.assert_array_equal(rec.cycles, [100, 101])
    assert rec.signal("CURRENT|SP1").tolist() == [1.0, 2.0]
    assert any("1 duplicate HF rows" in i and "DIFFERENT" in i for i in rec.meta.issues)


def test_string_values_converted(tmp_path: Path) -> None:
    p = tmp_path / "a.json"
    p.write_bytes(orjson.dumps(_doc([[100, "1.25", 2.0], [101, 3.0, None]])))
    rec = read_capture4analysis(p)
    assert rec.signal("CURRENT|SP1").tolist() == [1.25, 3.0]
    assert np.isnan(rec.signal("LOAD|X1").iloc[1])
    assert any("1 HF values given as strings converted" in i for i in rec.meta.issues)
    assert any("1 HF values were null" in i for i in rec.meta.issues)


def test_lf_only_job(tmp_path: Path) -> None:
    doc = _doc([])
    del doc["Header"]["SignalListHFData"]
    doc["Payload"] = [{"LFData": [{"HFProbeCounter": 120, "timestamp": "2024-01-01T00:00:00Z",
                                   "address": "/Channel/State/progName", "value_type": "String",
                                   "value": "PART1.MPF"}]}]
    p = tmp_path / "lf.json"
    p.write_bytes(orjson.dumps(doc))
    rec = read_capture4analysis(p)
    assert rec.n_cycles == 0
    assert rec.lf["text"].tolist() == ["PART1.MPF"]
    assert np.isnan(rec.lf["value"].iloc[0])
    assert rec.lf["time"].iloc[0] == pd.Timestamp("2024-01-01T00:00:00.040Z")
    assert any("LF-only" in i for i in rec.meta.issues)


def test_lf_aligned_by_counter_not_wall_clock(tmp_path: Path) -> None:
    lf = {"LFData": [{"HFProbeCounter": 101, "timestamp": "2023-12-31T23:00:00Z",
                      "address": "/a", "value_type": "Double", "value": "1.5"}]}
    p = tmp_path / "a.json"
    p.write_bytes(orjson.dumps(_doc([[100, 1.0, 1.0], [101, 2.0, 2.0]], payload_extra=[lf])))
    rec = read_capture4analysis(p)
    assert rec.lf["cycle"].tolist() == [101]
    assert rec.lf["time"].iloc[0] == rec.hf["time"].iloc[1]
    assert rec.meta.attrs["lf_wall_clock_offset_s"] == pytest.approx(-3600.002)
