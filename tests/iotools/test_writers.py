"""Parquet and flattened-CSV writers: round trips through the project's own readers.

The flattened CSV layout (``_hfdata.csv``, ``_header.csv``, ``_hfblockevent.csv``) follows the
KIT CNC milling data set (Ströbel et al. 2025, DOI 10.35097/hvvwn1kfwf7qt48z); it is read back
with :func:`cnctwin.iotools.read_flat_csv`, written independently by another module.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cnctwin.exceptions import FormatError
from cnctwin.iotools import (
    read_capture4analysis,
    read_flat_csv,
    read_parquet,
    read_recording,
    write_csv,
    write_parquet,
)
from cnctwin.recording import EVENT_COLUMNS, ExternalChannel, Recording


@pytest.fixture(scope="module")
def real(c4a_file: Path) -> Recording:
    return read_capture4analysis(c4a_file)


def test_parquet_round_trip(real: Recording, tmp_path: Path) -> None:
    out = write_parquet(real, tmp_path / "run.parquet")
    assert sorted(p.name for p in out.iterdir()) == ["events.parquet", "hf.parquet",
                                                     "lf.parquet"]
    back = read_parquet(out)
    pd.testing.assert_frame_equal(back.hf, real.hf)
    pd.testing.assert_frame_equal(back.events, real.events)
    pd.testing.assert_frame_equal(back.lf, real.lf)
    assert back.meta == real.meta  # dataclass equality: anchors, gaps, issues, attrs, units
    # units are also in the Arrow field metadata
    import pyarrow.parquet as pq

    schema = pq.read_schema(out / "hf.parquet")
    assert schema.field("CURRENT|SP1").metadata[b"unit"] == b"A"
    assert b"cnctwin.meta" in schema.metadata
    # detection: the directory and its hf.parquet
    assert read_recording(out).n_cycles == 3818
    assert read_recording(out / "hf.parquet").n_cycles == 3818


def test_parquet_external_channel(tmp_path: Path) -> None:
    rec = Recording.from_arrays(np.arange(10), {"CURRENT|X1": np.arange(10.0)})
    data = pd.DataFrame({"force_x_n": [1.0, 2.0]}, index=pd.Index([0.0, 0.5], name="time_s"))
    rec.external["dyn"] = ExternalChannel("dyn", data, units={"force_x_n": "N"}, fs_hz=2.0,
                                          offset_s=0.25, aligned=True)
    back = read_parquet(write_parquet(rec, tmp_path / "r"))
    ch = back.external["dyn"]
    pd.testing.assert_frame_equal(ch.data, data)
    assert (ch.units, ch.fs_hz, ch.offset_s, ch.aligned) == ({"force_x_n": "N"}, 2.0, 0.25, True)


def test_parquet_plain_file_and_errors(real: Recording, tmp_path: Path) -> None:
    import pyarrow.parquet as pq

    pq.write_table(real.to_arrow(), tmp_path / "plain.parquet")
    back = read_parquet(tmp_path / "plain.parquet")
    np.testing.assert_array_equal(back.cycles, real.cycles)
    assert any("no cnctwin metadata" in i for i in back.meta.issues)
    (tmp_path / "bad.parquet").write_bytes(b"not parquet")
    with pytest.raises(FormatError, match="not a readable Parquet"):
        read_parquet(tmp_path / "bad.parquet")


def test_csv_kit_layout(real: Recording, tmp_path: Path) -> None:
    files = write_csv(real, tmp_path / "T01")
    assert {k: p.name for k, p in files.items()} == {
        "hfdata": "T01_hfdata.csv", "header": "T01_header.csv",
        "hfblockevent": "T01_hfblockevent.csv", "hfcallevent": "T01_hfcallevent.csv",
        "lfdata": "T01_lfdata.csv"}
    with files["header"].open() as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["SignalName", "Type", "Axis", "Address"]
    assert rows[1] == ["CYCLE", "INTEGER", "Cycle", "CYCLE"]
    assert ["CURRENT|6", "DOUBLE", "SP1", "CURRENT|6"] in rows
    with files["hfblockevent"].open() as fh:
        head = next(csv.reader(fh))
    assert head == ["HFProbeCounter", "Channel", "SeekOffset", "SelectedTool", "ActiveTool",
                    "GCode", "IpoGC", "ipoReadError", "laBuf"]
    first = files["hfdata"].read_text().split("\n", 2)
    assert first[0].startswith("CYCLE,CMD_SPEED|4,")
    assert first[1].startswith("5558098,")


def test_csv_read_back_by_flat_csv_reader(real: Recording, tmp_path: Path) -> None:
    files = write_csv(real, tmp_path / "out" / "T01.csv")
    back = read_flat_csv(files["hfdata"])
    assert list(back.hf.columns) == list(real.hf.columns)
    np.testing.assert_array_equal(back.cycles, real.cycles)
    a = back.hf[real.columns].to_numpy()
    b = real.hf[real.columns].to_numpy()
    assert a.tobytes() == b.tobytes()  # shortest round-trip float text
    pd.testing.assert_series_equal(back.hf["time"], real.hf["time"])
    key = ["cycle", "kind", "seek_offset"]
    ev_a = back.events[list(EVENT_COLUMNS)].sort_values(key).reset_index(drop=True)
    ev_b = real.events[list(EVENT_COLUMNS)].sort_values(key).reset_index(drop=True)
    # the CSV text keeps trailing blanks of G-code ("D0" + 15 blanks in the real file) and the
    # flat-CSV reader keeps text cells verbatim, so the text compares unchanged
    assert any(g != g.strip() for g in ev_b["gcode"].dropna())
    pd.testing.assert_frame_equal(ev_a, ev_b)
    assert read_recording(files["hfdata"]).n_cycles == 3818
