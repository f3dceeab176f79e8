"""Damaged and odd Capture4Analysis input: clear errors by default, flagged partial data with
``salvage=True`` (project rule: nothing accepted is silently dropped)."""

from __future__ import annotations

import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import orjson
import pytest

from cnctwin.exceptions import FormatError, TruncatedFileError
from cnctwin.iotools import _detect, read_capture4analysis, read_recording


def _doc(rows: list[Any], **extra: Any) -> dict[str, Any]:
    doc: dict[str, Any] = {
        "Header": {
            "CycleTimeMs": 2,
            "Initial": {"HFProbeCounter": 100, "Time": "2024-01-01T00:00:00.000Z"},
            "SignalListHFData": [
                {"Name": "CYCLE", "Type": "INTEGER", "Axis": "Cycle", "Address": "CYCLE"},
                {"Name": "CURRENT|6", "Type": "DOUBLE", "Axis": "SP1", "Address": "CURRENT|6"},
                {"Name": "LOAD|6", "Type": "DOUBLE", "Axis": "SP1", "Address": "LOAD|6"},
            ],
        },
        "Payload": [{"HFData": rows}],
        "Footer": {"ErrorMessages": [], "FilePathChain": {"Previous": None, "Next": None}},
    }
    doc.update(extra)
    return doc


def _write(tmp_path: Path, doc: dict[str, Any] | bytes, name: str = "a.json") -> Path:
    p = tmp_path / name
    p.write_bytes(doc if isinstance(doc, bytes) else orjson.dumps(doc))
    return p


# ---------------------------------------------------------------------------- truncation
def test_truncated_real_file(c4a_file: Path, tmp_path: Path) -> None:
    data = c4a_file.read_bytes()
    p = _write(tmp_path, data[:1_000_000], "cut.json")
    with pytest.raises(TruncatedFileError) as info:
        read_capture4analysis(p)
    assert info.value.path == str(p)
    assert info.value.position is not None and "byte 1000000" in info.value.position
    assert "salvage=True" in str(info.value)

    rec = read_capture4analysis(p, salvage=True)
    assert rec.meta.partial
    # complete payload entries before the cut are kept; rows after it are lost
    assert 0 < rec.n_cycles < 3818
    full = read_capture4analysis(c4a_file)
    np.testing.assert_array_equal(
        rec.hf[rec.columns].to_numpy(), full.hf.loc[rec.cycles, rec.columns].to_numpy())
    assert int(rec.cycles[0]) == 5558098
    assert any("truncated at byte 1000000" in i and "complete payload entries" in i
               for i in rec.meta.issues)


def test_truncated_inside_header(c4a_file: Path, tmp_path: Path) -> None:
    p = _write(tmp_path, c4a_file.read_bytes()[:3000], "cut.json")
    for salvage in (False, True):
        with pytest.raises(TruncatedFileError, match="Header"):
            read_capture4analysis(p, salvage=salvage)


# ---------------------------------------------------------------------------- structure
def test_missing_header(tmp_path: Path) -> None:
    doc = _doc([[100, 1.0, 2.0]])
    del doc["Header"]
    with pytest.raises(FormatError, match="no complete Header") as info:
        read_capture4analysis(_write(tmp_path, doc))
    assert info.value.position == "Header"


def test_hf_data_without_signal_list(tmp_path: Path) -> None:
    doc = _doc([[100, 1.0, 2.0]])
    del doc["Header"]["SignalListHFData"]
    with pytest.raises(FormatError, match="no SignalListHFData") as info:
        read_capture4analysis(_write(tmp_path, doc))
    assert info.value.position == "Payload[0].HFData"


def test_missing_cycle_column(tmp_path: Path) -> None:
    doc = _doc([[1.0, 2.0]])
    doc["Header"]["SignalListHFData"].pop(0)
    with pytest.raises(FormatError, match="no CYCLE entry"):
        read_capture4analysis(_write(tmp_path, doc))


def test_missing_address(tmp_path: Path) -> None:
    doc = _doc([[100, 1.0, 2.0]])
    del doc["Header"]["SignalListHFData"][1]["Address"]
    p = _write(tmp_path, doc)
    with pytest.raises(FormatError) as info:
        read_capture4analysis(p)
    assert info.value.field == "Address"
    assert info.value.position == "Header.SignalListHFData[1]"
    rec = read_capture4analysis(p, salvage=True)
    assert "CURRENT|SP1" in rec.columns and rec.meta.partial


def test_not_an_object(tmp_path: Path) -> None:
    with pytest.raises(FormatError, match="not a JSON object"):
        read_capture4analysis(_write(tmp_path, b"[1, 2, 3]"))


def test_syntax_error_in_payload_entry(tmp_path: Path) -> None:
    good = orjson.dumps(_doc([[100, 1.0, 2.0]]))
    # a second payload entry with a broken number
    bad = good.replace(b'"Payload":[', b'"Payload":[{"HFData":[[101,1.0.0,2.0]]},')
    p = _write(tmp_path, bad)
    with pytest.raises(FormatError) as info:
        read_capture4analysis(p)
    assert info.value.position is not None
    assert info.value.position.startswith("Payload[0], byte ")
    rec = read_capture4analysis(p, salvage=True)
    assert rec.cycles.tolist() == [100]
    assert rec.meta.partial and any("entry dropped" in i for i in rec.meta.issues)


# ---------------------------------------------------------------------------- values
def test_wrong_type_non_numeric_string(tmp_path: Path) -> None:
    p = _write(tmp_path, _doc([[100, 1.0, 2.0], [101, "abc", 2.0]]))
    with pytest.raises(FormatError) as info:
        read_capture4analysis(p)
    assert info.value.position == "Payload[0].HFData[1][1]"
    assert info.value.field == "CURRENT|SP1"
    rec = read_capture4analysis(p, salvage=True)
    assert rec.meta.partial
    assert np.isnan(rec.signal("CURRENT|SP1").iloc[1])
    assert rec.signal("LOAD|SP1").tolist() == [2.0, 2.0]


def test_boolean_is_wrong_type(tmp_path: Path) -> None:
    with pytest.raises(FormatError, match="where a number is required"):
        read_capture4analysis(_write(tmp_path, _doc([[100, True, 2.0]])))


def test_non_integer_cycle(tmp_path: Path) -> None:
    with pytest.raises(FormatError, match="not an integer") as info:
        read_capture4analysis(_write(tmp_path, _doc([[100.5, 1.0, 2.0]])))
    assert info.value.field == "CYCLE"


def test_row_of_wrong_length(tmp_path: Path) -> None:
    p = _write(tmp_path, _doc([[100, 1.0, 2.0], [101, 1.0], [102, 3.0, 4.0]]))
    with pytest.raises(FormatError, match="2 values, SignalListHFData declares 3") as info:
        read_capture4analysis(p)
    assert info.value.position == "Payload[0].HFData[1]"
    rec = read_capture4analysis(p, salvage=True)
    assert rec.cycles.tolist() == [100, 102]
    assert rec.meta.partial and any("row dropped" in i for i in rec.meta.issues)


def test_unknown_payload_key_kept(tmp_path: Path) -> None:
    doc = _doc([[100, 1.0, 2.0]])
    doc["Payload"].append({"ExternalData": {"id": "ET200", "values": [1, 2]}})
    rec = read_capture4analysis(_write(tmp_path, doc))
    assert not rec.meta.partial
    assert rec.meta.attrs["payload_other"]["ExternalData"] == [
        {"id": "ET200", "values": [1, 2]}]
    assert any("'ExternalData' (1 entries) not interpreted" in i for i in rec.meta.issues)


def test_footer_error_messages_reported(tmp_path: Path) -> None:
    doc = _doc([[100, 1.0, 2.0]])
    doc["Footer"]["ErrorMessages"] = ["buffer overflow"]
    rec = read_capture4analysis(_write(tmp_path, doc))
    assert any("buffer overflow" in i for i in rec.meta.issues)


@pytest.mark.parametrize("footer", [["a", "b"], "done"])
def test_footer_not_an_object(tmp_path: Path, footer: Any) -> None:
    """A Footer that is not an object used to escape as AttributeError ('list'.get)."""
    p = _write(tmp_path, _doc([[100, 1.0, 2.0]], Footer=footer))
    with pytest.raises(FormatError, match="Footer is a") as info:
        read_capture4analysis(p)
    assert info.value.path == str(p) and info.value.position == "Footer"
    rec = read_capture4analysis(p, salvage=True)
    assert rec.meta.partial and rec.n_cycles == 1
    assert any("Footer is a" in i for i in rec.meta.issues)


@pytest.mark.parametrize(("payload", "kind"), [({"HFData": [[100, 1.0, 2.0]]}, "an object"),
                                               (None, "null")])
def test_payload_not_an_array(tmp_path: Path, payload: Any, kind: str) -> None:
    """A Payload that is not an array used to give an empty recording without any issue."""
    p = _write(tmp_path, _doc([], Payload=payload))
    with pytest.raises(FormatError, match=f"Payload is {kind}, not an array") as info:
        read_capture4analysis(p)
    assert info.value.position == "Payload"
    rec = read_capture4analysis(p, salvage=True)
    assert rec.meta.partial and rec.n_cycles == 0
    assert any(f"Payload is {kind}" in i for i in rec.meta.issues)


def test_event_integer_field_not_an_integer(tmp_path: Path) -> None:
    """A non-integer Channel used to become <NA> silently."""
    doc = _doc([[100, 1.0, 2.0]])
    doc["Payload"].append({"HFBlockEvent": {"HFProbeCounter": 100, "Channel": "one",
                                            "GCode": "G1 X1"}})
    p = _write(tmp_path, doc)
    with pytest.raises(FormatError, match=r"HFBlockEvent\.Channel 'one' is not an integer") as info:
        read_capture4analysis(p)
    assert info.value.position == "Payload[1].HFBlockEvent" and info.value.field == "Channel"
    rec = read_capture4analysis(p, salvage=True)
    assert rec.meta.partial
    # the event is kept with its G-code; only the bad field is missing
    assert rec.events["gcode"].tolist() == ["G1 X1"]
    assert rec.events["channel"].isna().all()
    assert any("Channel 'one' is not an integer; kept as missing" in i for i in rec.meta.issues)


def test_one_bad_time_anchor_keeps_the_others(tmp_path: Path) -> None:
    """One unparsable HFTimestamp used to discard every anchor (times from the epoch)."""
    doc = _doc([[100, 1.0, 2.0], [101, 1.0, 2.0], [102, 1.0, 2.0]])
    doc["Payload"].append({"HFTimestamp": {"HFProbeCounter": 102, "Time": "yesterday"}})
    rec = read_capture4analysis(_write(tmp_path, doc))
    # Initial (cycle 100 at 2024-01-01T00:00:00Z) still times the rows: 2 ms per cycle
    assert str(rec.hf["time"].iloc[2]) == "2024-01-01 00:00:00.004000+00:00"
    assert [c for c, _ in rec.meta.time_anchors] == [100]
    assert any("1 of 2 time anchors" in i and "'yesterday' at cycle 102" in i
               for i in rec.meta.issues)


def test_unusable_initial_and_job_description_reported(tmp_path: Path) -> None:
    """A non-object Initial and a non-list JobDescription used to vanish without an issue."""
    doc = _doc([[100, 1.0, 2.0]])
    doc["Header"]["Initial"] = ["2024-01-01"]
    doc["Header"]["JobDescription"] = "drill 4 holes"
    rec = read_capture4analysis(_write(tmp_path, doc))
    assert any("Header.Initial" in i and "not used as a time anchor" in i
               for i in rec.meta.issues)
    assert rec.meta.attrs["job_description"] == {"item0": "drill 4 holes"}
    assert any("JobDescription is not a list" in i for i in rec.meta.issues)


# ---------------------------------------------------------------------------- zip
def test_broken_zip(c4a_file: Path, tmp_path: Path) -> None:
    good = tmp_path / "good.zip"
    with zipfile.ZipFile(good, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.write(c4a_file, "run.json")
    data = good.read_bytes()
    bad = _write(tmp_path, data[: len(data) // 2], "bad.zip")
    with pytest.raises(TruncatedFileError, match="broken zip") as info:
        read_capture4analysis(bad)
    assert info.value.path == str(bad)
    rec = read_capture4analysis(bad, salvage=True)
    assert rec.meta.partial
    assert 0 < rec.n_cycles < 3818
    assert any("broken zip archive" in i for i in rec.meta.issues)
    garbage = _write(tmp_path, b"PK\x03\x04 not really a zip", "junk.zip")
    with pytest.raises(TruncatedFileError):
        read_capture4analysis(garbage, salvage=True)


def test_zip_without_json(tmp_path: Path) -> None:
    p = tmp_path / "empty.zip"
    with zipfile.ZipFile(p, "w") as zf:
        zf.writestr("readme.txt", "nothing")
    with pytest.raises(FormatError, match=r"no \.json"):
        read_capture4analysis(p)


# ---------------------------------------------------------------------------- detection
def test_unknown_format_lists_supported(tmp_path: Path) -> None:
    p = _write(tmp_path, b"hello", "x.bin")
    with pytest.raises(FormatError, match=r"supported: .*Capture4Analysis"):
        read_recording(p)
    with pytest.raises(FormatError, match="file not found"):
        read_recording(tmp_path / "missing.json")


def test_missing_reader_module(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(_detect.SUPPORTED_FORMATS, "edge_dataobject",
                        ("cnctwin.iotools._no_such_reader", "read_x", "Edge dataobject"))
    p = _write(tmp_path, b'{"header": {"key": "dataobject"}, "body": {"datapoint": []}}')
    with pytest.raises(FormatError, match="reader is not available"):
        read_recording(p)


# ---------------------------------------------------------------------------- other readers
@pytest.mark.parametrize("reader", ["read_thermal_camera_csv", "read_dynamometer_csv",
                                    "read_edge_dataobject"])
def test_not_utf8_is_a_format_error(tmp_path: Path, reader: str) -> None:
    """Non-UTF-8 bytes used to escape as UnicodeDecodeError; now the file and byte are named."""
    import cnctwin.iotools as iot

    p = tmp_path / "junk.csv"
    p.write_bytes(b"time_s,value\n0,\xff\n")
    with pytest.raises(FormatError, match="not UTF-8 text") as info:
        getattr(iot, reader)(p)
    assert info.value.path == str(p) and info.value.position == "byte 15"


def test_edge_dataobject_array_of_non_objects(tmp_path: Path) -> None:
    """A JSON array of numbers used to escape as TypeError from json.loads."""
    from cnctwin.iotools import read_edge_dataobject

    p = _write(tmp_path, b"[1, 2, 3]", "msgs.json")
    with pytest.raises(FormatError, match="message is a int, not a JSON object") as info:
        read_edge_dataobject(p)
    assert info.value.path is not None and info.value.path.startswith(str(p))


def test_trace_syntax_error_is_not_truncation(tmp_path: Path) -> None:
    """Broken XML syntax used to be reported as a truncated file."""
    from cnctwin.iotools import read_sinumerik_trace

    p = _write(tmp_path, b"<traceSession><a></b></traceSession>", "t.xml")
    with pytest.raises(FormatError, match="XML error: mismatched tag") as info:
        read_sinumerik_trace(p)
    assert not isinstance(info.value, TruncatedFileError)
    assert info.value.position == "line 1, column 19"
    cut = _write(tmp_path, b"<traceSession><a>", "cut.xml")
    with pytest.raises(TruncatedFileError):
        read_sinumerik_trace(cut)
