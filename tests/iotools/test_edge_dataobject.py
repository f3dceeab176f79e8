"""Tests of the SINUMERIK Edge ``dataobject`` reader and assembler.

The messages are hand-written to the structure documented by Siemens (time-behaviour page of
the Manage MyMachines /Edge developer documentation; reproduced in
docs/reference/data-formats.md section 1.6): CYCLE [6, 8, 9, 10] with period_ms 2 and
timestamp 2094-01-01T07:18:06.354 gives t = .354, .358, .360, .362 s (t(i) = t(i-1) +
(CYCLE(i) - CYCLE(i-1)) * 2 ms).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pandas as pd
import pytest

from cnctwin.exceptions import FormatError
from cnctwin.iotools import EdgeDataobjectAssembler, read_edge_dataobject
from cnctwin.recording import CYCLE_COUNTER_MODULUS


def msg(cycles: list[int], enc: list[Any], *, ts: str = "2094-01-01T07:18:06.354000",
        extra: list[dict[str, Any]] | None = None) -> dict[str, Any]:
    return {
        "header": {"message_type": "dataobject", "key": "dataobject",
                   "source_id": "sinumerik_adapter_840Dsl"},
        "body": {"datapoint": [
            {"address": "CYCLE", "timestamp": ts, "quality_mode": "hf", "period_ms": 2,
             "content": [{"value": cycles}]},
            {"address": "ENC1_POS|1", "timestamp": ts, "quality_mode": "hf", "period_ms": 2,
             "content": [{"value": enc}]},
            *(extra or []),
        ]},
    }


def test_documented_example() -> None:
    rec = read_edge_dataobject(json.dumps(msg([6, 8, 9, 10], [20.0, 30.0, 40.0, 50.0]))
                               .encode())
    assert rec.cycles.tolist() == [6, 8, 9, 10]
    assert rec.signal("ENC1_POS|X1").tolist() == [20.0, 30.0, 40.0, 50.0]
    t0 = pd.Timestamp("2094-01-01T07:18:06.354Z")
    ms = [(t - t0).total_seconds() * 1e3 for t in rec.hf["time"]]
    assert ms == pytest.approx([0.0, 4.0, 6.0, 8.0])
    assert rec.meta.machine == "sinumerik_adapter_840Dsl"
    assert rec.meta.cycle_time_s == 0.002
    assert [(g.after_cycle, g.missing) for g in rec.meta.gaps] == [(6, 1)]
    assert any("taken as UTC" in i for i in rec.meta.issues)
    assert rec.meta.units["ENC1_POS|X1"] == "mm"


def test_file_jsonl_and_assembler(tmp_path: Path) -> None:
    p = tmp_path / "stream.jsonl"
    p.write_text(json.dumps(msg([1, 2], [1.0, 2.0])) + "\n" +
                 json.dumps(msg([3, 4], [3.0, 4.0], ts="2094-01-01T07:18:06.358")) + "\n",
                 encoding="utf-8")
    rec = read_edge_dataobject(p)
    assert rec.cycles.tolist() == [1, 2, 3, 4]
    assert rec.meta.attrs["messages"] == 2
    assert rec.hf["time"].iloc[2] == pd.Timestamp("2094-01-01T07:18:06.358Z")


def test_assembler_duplicates_and_columns() -> None:
    asm = EdgeDataobjectAssembler()
    chunk = asm.feed(msg([1, 2], [1.0, 2.0]))
    assert chunk.n_cycles == 2
    asm.feed(msg([2, 3], [2.5, 3.0], extra=[{"address": "LOAD|6", "period_ms": 2,
                                             "content": [{"value": [10, 11]}]}]))
    rec = asm.recording(clear=True)
    assert rec.cycles.tolist() == [1, 2, 3]
    # cycle 2 arrived twice: the first arrival is kept (as the Capture4Analysis and flat-CSV
    # readers do), the repeat is flagged with its values differing
    assert rec.signal("ENC1_POS|X1").tolist() == [1.0, 2.0, 3.0]
    assert rec.signal("LOAD|SP1").iloc[0] != rec.signal("LOAD|SP1").iloc[0]  # NaN
    dup = [i for i in rec.meta.issues if "arrived twice" in i]
    assert len(dup) == 1 and "1 duplicate" in dup[0] and "DIFFERENT" in dup[0]
    assert "kept the first" in dup[0]
    assert len(asm) == 0


def test_duplicate_cycle_consistent_with_the_other_readers(tmp_path: Path) -> None:
    # the same cycles repeated by an out-of-order message: first arrival kept, like
    # read_flat_csv ("kept the first of each cycle") and Capture4Analysis ("first arrival")
    p = tmp_path / "stream.jsonl"
    p.write_text("\n".join(json.dumps(m) for m in (
        msg([3, 4], [3.0, 4.0], ts="2094-01-01T07:18:06.358"),
        msg([1, 2], [1.0, 2.0]),
        msg([4, 5], [4.0, 5.0], ts="2094-01-01T07:18:06.360"),
    )) + "\n", encoding="utf-8")
    rec = read_edge_dataobject(p)
    assert rec.cycles.tolist() == [1, 2, 3, 4, 5]
    assert rec.signal("ENC1_POS|X1").tolist() == [1.0, 2.0, 3.0, 4.0, 5.0]
    dup = [i for i in rec.meta.issues if "duplicate" in i]
    assert len(dup) == 1 and "identical" in dup[0] and "e.g. 4" in dup[0]
    assert any("out of cycle order" in i for i in rec.meta.issues)


def test_wrap_between_messages() -> None:
    top = CYCLE_COUNTER_MODULUS - 1
    asm = EdgeDataobjectAssembler()
    asm.feed(msg([top - 1, top], [1.0, 2.0]))
    asm.feed(msg([0, 1], [3.0, 4.0]))
    rec = asm.recording()
    assert rec.cycles.tolist() == [top - 1, top, top + 1, top + 2]


def test_errors() -> None:
    with pytest.raises(FormatError, match="expected 'dataobject'"):
        read_edge_dataobject(json.dumps({"header": {"message_type": "x"}}).encode())
    bad = msg([1, 2], [1.0])
    with pytest.raises(FormatError) as ei:
        read_edge_dataobject(json.dumps(bad).encode())
    assert ei.value.position == "body.datapoint[1]" and ei.value.field == "ENC1_POS|1"
    with pytest.raises(FormatError) as ei:
        read_edge_dataobject(json.dumps(msg([1, 2], [1.0, "x"])).encode())
    assert ei.value.field == "ENC1_POS|1"
    no_cycle = msg([1], [1.0])
    no_cycle["body"]["datapoint"].pop(0)
    with pytest.raises(FormatError, match="no CYCLE"):
        read_edge_dataobject(json.dumps(no_cycle).encode())
    with pytest.raises(FormatError, match="not JSON"):
        read_edge_dataobject(b'{"header": ')


def test_salvage_length_mismatch() -> None:
    asm = EdgeDataobjectAssembler(salvage=True)
    asm.feed(msg([1, 2, 3], [1.0]))
    rec = asm.recording()
    assert rec.meta.partial
    assert rec.signal("ENC1_POS|X1").tolist()[0] == 1.0
    assert rec.signal("ENC1_POS|X1").isna().sum() == 2
