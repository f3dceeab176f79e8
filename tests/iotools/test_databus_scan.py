"""The numba pass over Databus ``bulk`` messages (issue 28, point 1: decoding at the cost of a
plant's pipelines).

The truth is the general decoder (``DatabusDecoder.decode`` + ``recording``: one Python object
per value, ``json`` from the standard library) and the typed ``msgspec`` path the scanner sits
in front of: on every message in the regular HF layout, written in the ways a JSON encoder may
write it (whitespace, key order, ``qc`` left out, ``seq`` quoted, null or absent, integers and
floats of any size, 1-9 fraction digits of the timestamp, with or without ``Z``), the scanner
accepts and gives the same cycles, values, issues and seq bookkeeping; anything outside its
subset it declines (and the message is still decoded, by the other paths).
"""

from __future__ import annotations

import json
import time
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cnctwin.iotools._databus_scan import id_table, scan_bulk
from cnctwin.iotools.databus import DatabusDecoder

TOPIC = "ie/d/j/simatic/v1/hf/dp/r/NCK/hf"
IDS = ["1", "7", "12", "103"]
META: dict[str, Any] = {"seq": 1, "hashVersion": 1, "applicationName": "mill", "connections": [
    {"name": "NCK", "type": "sinumerik", "dataPoints": [
        {"name": "hf", "topic": TOPIC, "publishType": "bulk", "dataPointDefinitions": [
            {"name": f"S{i}", "id": i, "dataType": "LReal"} for i in IDS]}]}]}


def _without_scan(d: DatabusDecoder) -> DatabusDecoder:
    d._lut = None  # the typed msgspec path alone
    return d


def _same(a: Any, b: Any) -> None:
    assert a is not None and b is not None
    assert a.cycles.tolist() == b.cycles.tolist()
    assert list(a.columns) == list(b.columns)
    for c in a.columns:
        np.testing.assert_array_equal(a.columns[c], b.columns[c])
    assert a.n_values == b.n_values
    assert a.issues == b.issues


@st.composite
def _message(draw: st.DrawFn) -> tuple[bytes, bool]:
    """A regular HF message in one of the ways an encoder may write it; True if every value
    lies within the scanner's subset (so it must accept)."""
    ids = draw(st.lists(st.sampled_from(IDS), min_size=1, max_size=4, unique=True))
    n_rows = draw(st.integers(1, 8))
    frac = draw(st.integers(0, 9))
    zulu = draw(st.booleans())
    t_ns = draw(st.integers(-2 * 10**18, 2 * 10**18)) // 2_000_000 * 2_000_000
    order = draw(st.permutations(["id", "qc", "ts", "val"]))
    with_qc = draw(st.booleans())
    sep = draw(st.sampled_from([(",", ":"), (", ", ": "), (",\n ", " : ")]))
    within = True
    vals = []
    step = max(2_000_000, 10**(9 - frac))  # rows of distinct cycles at the written precision
    t_ns = t_ns // step * step
    for r in range(n_rows):
        t = np.datetime64(t_ns + r * step, "ns")
        text = np.datetime_as_string(t, unit="s") + (
            "." + str(t.astype(np.int64) % 10**9).zfill(9)[:frac] if frac else "")
        ts = text + ("Z" if zulu else "")
        for i in ids:
            v = draw(st.one_of(st.floats(allow_nan=False, allow_infinity=False),
                               st.integers(-10**15 + 1, 10**15 - 1),
                               st.integers(-2**62, 2**62)))
            if isinstance(v, int) and abs(v) >= 10**15:
                within = False  # a long integer: the general path decides (2**53)
            item = {"id": i, "qc": draw(st.sampled_from([0, 1, 2, 3])), "ts": ts, "val": v}
            if not with_qc:
                del item["qc"]
            vals.append({k: item[k] for k in order if k in item})
    seq = draw(st.sampled_from([5, "5", None, "absent"]))
    doc: dict[str, Any] = {"vals": vals} if seq == "absent" else {"seq": seq, "vals": vals}
    if draw(st.booleans()):
        doc = dict(reversed(doc.items()))
    return json.dumps(doc, separators=sep).encode(), within


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_message())
def test_the_scanner_accepts_every_regular_message_and_equals_the_other_paths(
        case: tuple[bytes, bool]) -> None:
    payload, within = case
    d = DatabusDecoder(META)
    scanned = scan_bulk(payload, d._lut)  # type: ignore[arg-type]
    if within:
        assert scanned is not None, payload[:300]
    fast = d.decode_columns(payload, topic=TOPIC)
    typed = _without_scan(DatabusDecoder(META)).decode_columns(payload, topic=TOPIC)
    if typed is None:  # e.g. rows sharing a cycle, which only the general path keeps
        assert fast is None
        return
    _same(fast, typed)
    general = DatabusDecoder(META)
    general.decode(payload, topic=TOPIC)
    rec = general.recording()
    assert rec.hf.index.to_numpy().tolist() == fast.cycles.tolist()
    for c, v in fast.columns.items():
        np.testing.assert_array_equal(v, rec.hf[c].to_numpy())


@pytest.mark.parametrize("payload", [
    b'{"seq":1,"vals":[{"id":"1","ts":"2026-11-28T01:02:03.004Z","val":"1.5"}]}',  # quoted
    b'{"seq":1,"vals":[{"id":"1","ts":"2026-11-28T01:02:03.004Z","val":12345678901234567}]}',
    b'{"seq":1,"vals":[{"id":"1","ts":"2026-11-28T01:02:03.004+01:00","val":1}]}',  # offset
    b'{"seq":1,"vals":[{"id":"9","ts":"2026-11-28T01:02:03.004Z","val":1}]}',  # unknown id
    b'{"seq":1,"vals":[{"id":"01","ts":"2026-11-28T01:02:03.004Z","val":1}]}',  # not plain
    b'{"seq":1,"vals":[{"id":"1","ts":"2026-02-30T01:02:03.004Z","val":1}]}',  # no such day
    b'{"seq":1,"vals":[{"id":"1","ts":"2026-11-28T01:02:03.004Z","val":1,"x":2}]}',  # a key
    b'{"seq":1,"vals":[{"id":"1","ts":"2026-11-28T01:02:03.004Z","val":1e400}]}',  # inf
    b'{"seq":1,"vals":[{"\\u0069d":"1","ts":"2026-11-28T01:02:03.004Z","val":1}]}',  # escape
    b'{"seq":1,"vals":[{"id":"1","ts":"2026-11-28T01:02:03.004Z","val":1}]} x',  # trailing
    b'{"seq":1,"vals":[{"id":"1","ts":"2026-11-28T01:02:03.004Z","val":1}]',  # truncated
    b'{"seq":1,"vals":[{"id":"1","ts":"2026-11-28T01:02:03.004Z","val":1},'
    b'{"id":"1","ts":"2026-11-28T01:02:03.004Z","val":2}]}',  # one column twice in a row
    b'{"seq":1,"vals":[{"id":"1","ts":"2026-11-28T01:02:03.004Z","val":1},'
    b'{"id":"7","ts":"2026-11-28T01:02:03.004Z","val":2},'
    b'{"id":"1","ts":"2026-11-28T01:02:03.006Z","val":3}]}',  # a row ends early
    b'{"seq":1,"vals":[]}',
])
def test_the_scanner_declines_what_lies_outside_its_subset(payload: bytes) -> None:
    d = DatabusDecoder(META)
    assert scan_bulk(payload, d._lut) is None  # type: ignore[arg-type]


def test_a_non_decimal_id_turns_the_scanner_off_and_decoding_still_works() -> None:
    meta = json.loads(json.dumps(META))
    meta["connections"][0]["dataPoints"][0]["dataPointDefinitions"][0]["id"] = "a1"
    d = DatabusDecoder(meta)
    assert d._lut is None
    assert id_table({"0101": 0}) is None and id_table({str(1 << 21): 0}) is None
    msg = {"seq": 3, "vals": [{"id": "a1", "qc": 3, "ts": "2026-11-28T01:02:03.004Z",
                               "val": 2.5}]}
    got = d.decode_columns(json.dumps(msg).encode(), topic=TOPIC)
    assert got is not None and got.columns["S1"].tolist() == [2.5]


def test_hand_checked_message() -> None:
    """Two rows of two datapoints: 2026-11-28T01:02:03.004Z is 1 795 827 723.004 s after
    the epoch (date -d 2026-11-28T01:02:03Z +%s: 1795827723), cycle 897 913 861 502 at 2 ms;
    the qualities BAD and UNCERTAIN counted per column; seq followed across messages."""
    d = DatabusDecoder(META)
    msg = (b'{"seq":"41","vals":[{"id":"7","qc":0,"ts":"2026-11-28T01:02:03.004Z","val":1.25},'
           b'{"id":"1","ts":"2026-11-28T01:02:03.004Z","val":-3},'
           b'{"id":"7","qc":1,"ts":"2026-11-28T01:02:03.006Z","val":2.5e-3},'
           b'{"id":"1","qc":3,"ts":"2026-11-28T01:02:03.006Z","val":0}]}')
    assert scan_bulk(msg, d._lut) is not None  # type: ignore[arg-type]
    got = d.decode_columns(msg, topic=TOPIC)
    assert got is not None
    assert got.cycles.tolist() == [897_913_861_502, 897_913_861_503]
    assert got.columns == {"S7": pytest.approx([1.25, 0.0025]), "S1": pytest.approx([-3, 0])}
    assert got.issues == ["1 values with quality BAD (qc=0) kept: {'S7': 1}",
                          "1 values with quality UNCERTAIN (qc=1) kept: {'S7': 1}"]
    d.decode_columns(msg.replace(b'"41"', b"43"), topic=TOPIC)
    assert d.issues[-1] == f"{TOPIC}: seq jumped from 41 to 43"
    assert time.gmtime(1795827723)[:6] == (2026, 11, 28, 1, 2, 3)


def test_rows_written_otherwise_than_the_first_are_parsed_in_full() -> None:
    """From the second row on, the scanner reads a value object as a byte copy of the first
    row's at its place (but timestamp and number); a row written otherwise (other key order,
    whitespace, timestamp precision, a qc given) is parsed in full, with the same result as
    the typed path."""
    rows = [
        b'{"id":"1","qc":3,"ts":"2026-11-28T01:02:03.004Z","val":1.5},'
        b'{"id":"7","qc":3,"ts":"2026-11-28T01:02:03.004Z","val":2}',
        b'{"id":"1","qc":3,"ts":"2026-11-28T01:02:03.006Z","val":-1e-3},'
        b'{"id":"7","qc":3,"ts":"2026-11-28T01:02:03.006Z","val":20.25}',
        b'{"qc":3, "id":"1","val":3,"ts":"2026-11-28T01:02:03.008Z"},'
        b'{ "id" : "7", "ts":"2026-11-28T01:02:03.008Z","val":4}',
        b'{"id":"1","qc":1,"ts":"2026-11-28T01:02:03.01Z","val":5},'
        b'{"id":"7","qc":3,"ts":"2026-11-28T01:02:03.01Z","val":6}',
        b'{"id":"1","qc":3,"ts":"2026-11-28T01:02:03.012Z","val":7.0},'
        b'{"id":"7","qc":3,"ts":"2026-11-28T01:02:03.012Z","val":8}',
    ]
    msg = b'{"seq":9,"vals":[' + b",".join(rows) + b"]}"
    d = DatabusDecoder(META)
    assert scan_bulk(msg, d._lut) is not None  # type: ignore[arg-type]
    fast = d.decode_columns(msg, topic=TOPIC)
    typed = _without_scan(DatabusDecoder(META)).decode_columns(msg, topic=TOPIC)
    _same(fast, typed)
    assert fast is not None and fast.columns["S1"].tolist() == [1.5, -1e-3, 3, 5, 7]
    assert fast.columns["S7"].tolist() == [2, 20.25, 4, 6, 8]
    assert fast.issues == ["1 values with quality UNCERTAIN (qc=1) kept: {'S1': 1}"]
    # a later row whose id differs from the first row's at that place: not the layout
    bad = msg.replace(b'{"id":"7","qc":3,"ts":"2026-11-28T01:02:03.012Z"',
                      b'{"id":"12","qc":3,"ts":"2026-11-28T01:02:03.012Z"')
    assert scan_bulk(bad, d._lut) is None  # type: ignore[arg-type]


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 6), st.integers(1, 4), st.booleans()), min_size=2,
                max_size=5))
def test_merging_messages_equals_a_table_of_their_values(
        parts: list[tuple[int, int, bool]]) -> None:
    """Several messages' columns merged (the live source takes what arrived since its last
    chunk): one row per cycle, a later message's value replacing an earlier one of the same
    cycle and column, NaN where no message had a value; consecutive messages of the same
    datapoints (a live connector's) take a shortcut that must give the same."""
    from cnctwin.iotools.databus import DatabusColumns, merge_columns

    batches, rows = [], []
    start = 0
    for k, (gap, n, other) in enumerate(parts):
        start = start + gap - 3  # may overlap the previous message
        cyc = np.arange(start, start + n, dtype=np.int64)
        start += n
        names = ["A", "B"] if not other else ["B"]
        cols = {c: np.arange(n, dtype=np.float64) + 10 * k + (c == "B") for c in names}
        if np.unique(cyc).size == cyc.size:
            batches.append(DatabusColumns(cyc, cols, n * len(names), []))
            rows += [(int(cc), c, float(cols[c][j])) for j, cc in enumerate(cyc) for c in names]
    if len(batches) < 2:
        return
    got = merge_columns(batches)
    want: dict[int, dict[str, float]] = {}
    for cc, c, v in rows:  # in message order: the last wins
        want.setdefault(cc, {})[c] = v
    assert got.cycles.tolist() == sorted(want)
    for c in got.columns:
        exp = [want[cc].get(c, np.nan) for cc in sorted(want)]
        np.testing.assert_array_equal(got.columns[c], exp)
    assert set(got.columns) == {c for r in want.values() for c in r}


@settings(max_examples=300, deadline=None)
@given(data=st.binary(min_size=1, max_size=80).map(lambda b: bytes(x % 3 for x in b)),
       seed=st.integers(0, 2**32 - 1))
def test_the_compiled_byte_compare_equals_slices(data: bytes, seed: int) -> None:
    """The template compare of the scan reads 8 bytes per load (one unaligned load, the last
    word overlapping): equal to comparing the slices, at every offset and length the buffer
    holds, up to its last byte (bytes of three values, so equal runs are common)."""
    import random

    from cnctwin.iotools import _databus_scan as scan

    scan._scanner()  # compiled: the helpers are numba functions from here on
    buf = np.frombuffer(data, dtype=np.uint8)
    rng = random.Random(seed)
    n = buf.size
    for _ in range(50):
        m = rng.randint(0, n)
        a, b = rng.randint(0, n - m), rng.randint(0, n - m)
        assert scan._same_bytes(buf, a, b, m) == (data[a:a + m] == data[b:b + m]), (a, b, m)
