"""Tests of the Industrial Edge Databus decoder.

Payloads are hand-written to the structure in the Databus payload-format documentation
(industrial-edge/common-databus-payload-format, docs/payload-format/PayloadFormat.md; summary in
docs/reference/data-formats.md section 2): metadata with connections -> dataPoints ->
dataPointDefinitions, bulk ``vals``, timeseries ``records``, deprecated ``single``.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pandas as pd
import pytest

from cnctwin.exceptions import FormatError
from cnctwin.iotools import DatabusDecoder

TOPIC = "ie/d/j/simatic/v1/s7c1/dp/r/PLC_1/default"
TS_TOPIC = "ie/d/j/simatic/v1/s7c1/dp/r/PLC_1/fast"
SINGLE_TOPIC = "ie/d/j/simatic/v1/s7c1/dp/r/PLC_1/temp"


def metadata(ids: tuple[str, str] = ("101", "102"), hv: int = 123) -> dict[str, Any]:
    return {
        "seq": 1, "hashVersion": hv, "applicationName": "S7 Connector",
        "statustopic": "ie/s/j/simatic/v1/s7c1/status",
        "connections": [{"name": "PLC_1", "type": "s7", "dataPoints": [
            {"name": "default", "topic": TOPIC, "publishType": "bulk",
             "dataPointDefinitions": [
                 {"name": "Axis_X_Load", "id": ids[0], "dataType": "LReal"},
                 {"name": "Counter", "id": ids[1], "dataType": "LInt"},
                 {"name": "State", "id": "103", "dataType": "String"}]},
            {"name": "fast", "topic": TS_TOPIC, "publishType": "timeseries",
             "dataPointDefinitions": [{"name": "Spindle_Current", "id": "201",
                                       "dataType": "Real"}]},
            {"name": "temp", "topic": SINGLE_TOPIC, "publishType": "single",
             "dataPointDefinitions": [{"name": "Motor_Temp", "id": "301",
                                       "dataType": "Real"}]},
        ]}],
    }


def bulk(seq: int = 84631) -> bytes:
    return json.dumps({"seq": seq, "vals": [
        {"id": "101", "qc": 3, "ts": "2021-03-10T22:23:04.146Z", "val": 80},
        {"id": "102", "qc": 3, "ts": "2021-03-10T22:23:04.146Z", "val": "9007199254740993"},
        {"id": "101", "qc": 0, "ts": "2021-03-10T22:23:04.156Z", "val": "81.5"},
        {"id": "103", "qc": 2, "ts": "2021-03-10T22:23:04.156Z", "val": "RUN"},
    ]}).encode()


def test_bulk_to_recording() -> None:
    dec = DatabusDecoder(json.dumps(metadata()), name_map={"Axis_X_Load": "LOAD|X1"})
    vals = dec.decode(bulk(), topic=TOPIC)
    assert [v.column for v in vals] == ["LOAD|X1", "Counter", "LOAD|X1", "State"]
    assert vals[0].value == 80.0 and vals[2].value == 81.5 and vals[2].qc == 0
    assert vals[3].value == "RUN"
    rec = dec.recording()
    # 22:23:04.146 and .156 are 5 cycles of 2 ms apart
    assert rec.cycles[1] - rec.cycles[0] == 5
    assert rec.hf["time"].iloc[0] == pd.Timestamp("2021-03-10T22:23:04.146Z")
    assert rec.signal("LOAD|X1").tolist() == [80.0, 81.5]
    assert np.isnan(rec.signal("Counter").iloc[1])  # not held
    assert rec.meta.units["LOAD|X1"] == "%"
    assert rec.lf["text"].tolist() == ["RUN"] and rec.lf["signal"].tolist() == ["State"]
    assert any("quality BAD" in i and "LOAD|X1" in i for i in rec.meta.issues)
    assert any("beyond 2**53" in i for i in rec.meta.issues)
    assert rec.meta.attrs["databus_values"]["qc"].tolist() == [3, 3, 0, 2]
    assert rec.meta.machine == "S7 Connector"


def test_timeseries_and_single() -> None:
    dec = DatabusDecoder(metadata())
    dec.decode({"seq": 5, "records": [
        {"ts": "2021-03-10T22:23:04.000Z", "rseq": 1, "vals": [{"id": "201", "val": 1.5,
                                                               "qc": 3}]},
        {"ts": "2021-03-10T22:23:04.010Z", "rseq": 2, "vals": [{"id": "201", "val": "2.5",
                                                               "qc": 3}]},
    ]}, topic=TS_TOPIC)
    dec.decode({"seq": 7, "val": 42.0, "ts": "2021-03-10T22:23:04.010Z", "qc": 3},
               topic=SINGLE_TOPIC)
    rec = dec.recording()
    assert rec.signal("Spindle_Current").tolist() == [1.5, 2.5]
    assert rec.signal("Motor_Temp").dropna().tolist() == [42.0]


def test_new_metadata_replaces_ids() -> None:
    dec = DatabusDecoder(metadata())
    dec.decode(bulk(), topic=TOPIC)
    dec.update_metadata(metadata(ids=("501", "502"), hv=124))
    with pytest.raises(FormatError) as ei:
        dec.decode(bulk(), topic=TOPIC)
    assert ei.value.field == "id" and ei.value.position == "vals[0]"
    v = dec.decode({"seq": 1, "vals": [{"id": "501", "qc": 3, "ts": "2021-03-10T22:23:05Z",
                                        "val": 1}]}, topic=TOPIC)
    assert v[0].name == "Axis_X_Load"
    assert any("metadata replaced (hashVersion 123 -> 124)" in i for i in dec.issues)


def test_unknown_id_salvage_and_seq_gap() -> None:
    dec = DatabusDecoder(metadata(), salvage=True)
    dec.decode({"seq": 1, "vals": [{"id": "999", "qc": 3, "ts": "2021-03-10T22:23:05Z",
                                    "val": 1}]}, topic=TOPIC)
    dec.decode({"seq": 4, "vals": []}, topic=TOPIC)
    rec = dec.recording(clear=True)
    assert "UNKNOWN_ID_999" in rec.columns
    assert any("unknown id '999'" in i for i in rec.meta.issues)
    assert any("seq jumped from 1 to 4" in i for i in rec.meta.issues)
    assert dec.values == [] and dec.issues == []


def test_errors() -> None:
    dec = DatabusDecoder()
    with pytest.raises(FormatError, match="metadata"):
        dec.decode(bulk(), topic=TOPIC)
    with pytest.raises(FormatError, match="connections"):
        dec.update_metadata({"seq": 1})
    dec.update_metadata(metadata())
    with pytest.raises(FormatError, match="not JSON"):
        dec.decode(b"{", topic=TOPIC)
    with pytest.raises(FormatError) as ei:
        dec.decode({"vals": [{"id": "101", "qc": 3, "ts": "yesterday", "val": 1}]}, topic=TOPIC)
    assert ei.value.field == "ts"
    with pytest.raises(FormatError, match="single"):
        dec.decode({"seq": 1, "val": 1, "ts": "2021-03-10T22:23:05Z"}, topic=TOPIC)
    with pytest.raises(FormatError, match="not a Databus data message"):
        dec.decode({"seq": 1}, topic=TOPIC)
