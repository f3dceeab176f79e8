"""The Databus scan reads every number itself (Eisel-Lemire, cnctwin.iotools._databus_scan):
each value must be bit for bit the correctly rounded double that Python's ``float`` (David
Gay's correctly rounded conversion) gives for the same text, also -0.0, halfway cases and the
texts it declines (subnormals, more than 19 significant digits), which orjson reads instead,
in the middle of a message too."""

from __future__ import annotations

import random
import struct
from typing import Any

import numpy as np
import orjson
import pytest

from cnctwin.iotools.databus import DatabusDecoder

TOPIC = "ie/d/j/simatic/v1/hf/dp/r/NCK/hf"
META: dict[str, Any] = {"seq": 1, "hashVersion": 1, "applicationName": "mill", "connections": [
    {"name": "NCK", "type": "sinumerik", "dataPoints": [
        {"name": "hf", "topic": TOPIC, "publishType": "bulk", "dataPointDefinitions": [
            {"name": "A", "id": "1", "dataType": "LReal"},
            {"name": "B", "id": "2", "dataType": "LReal"}]}]}]}


def _message(texts: list[str]) -> bytes:
    """Rows of two values (ids 1 and 2), 2 ms apart, the numbers written as ``texts`` (an
    integer of more than 15 digits sends the whole message to the general decoder, which
    keeps int64 values: not what is tested here)."""
    assert len(texts) % 2 == 0
    parts = []
    for k, t in enumerate(texts):
        ms = (k // 2) * 2
        ts = f"2026-11-28T{ms // 3_600_000 % 24:02d}:{ms // 60_000 % 60:02d}:" \
             f"{ms // 1000 % 60:02d}.{ms % 1000:03d}Z"
        parts.append(f'{{"id":"{1 + k % 2}","qc":3,"ts":"{ts}","val":{t}}}')
    return ('{"seq":1,"vals":[' + ",".join(parts) + "]}").encode()


def _decoded(texts: list[str]) -> np.ndarray:
    got = DatabusDecoder(META).decode_columns(_message(texts), topic=TOPIC)
    assert got is not None
    out = np.empty(len(texts))
    out[0::2] = got.columns["A"]
    out[1::2] = got.columns["B"]
    return out


def _bitwise(texts: list[str]) -> None:
    got = _decoded(texts)
    ref = np.array([float(t) for t in texts])
    bad = np.flatnonzero(got.view(np.uint64) != ref.view(np.uint64))
    assert bad.size == 0, [(texts[i], got[i], ref[i]) for i in bad[:5]]


def _random_decimal(rng: random.Random) -> str:
    nd = rng.randint(1, 19)
    d = str(rng.randint(10 ** (nd - 1), 10 ** nd - 1))
    pos = rng.randint(0, nd)
    s = d if pos == nd else (d[:pos] or "0") + "." + d[pos:]
    if rng.random() < 0.5:  # within the doubles (an overflow is no JSON number to read)
        e = rng.randint(-300, 300 - pos)
        s += rng.choice("eE") + (str(e) if e < 0 else rng.choice(["", "+"]) + str(e))
    elif pos == nd and nd > 15:  # a long integer is int64 territory: the general decoder's
        s += ".0"
    return ("-" if rng.random() < 0.5 else "") + s


@pytest.mark.parametrize("kind", ["any double", "sensor values", "float32 values",
                                  "decimal texts"])
def test_the_scan_reads_numbers_bit_for_bit_as_python(kind: str) -> None:
    rng = random.Random(kind)
    texts: list[str] = []
    while len(texts) < 40_000:
        if kind == "any double":
            v = struct.unpack("<d", struct.pack("<Q", rng.getrandbits(64)))[0]
            t = orjson.dumps(v).decode()  # the shortest text, as a control's encoder writes
            if t == "null":  # NaN and infinity are not JSON
                continue
        elif kind == "sensor values":
            t = orjson.dumps(rng.gauss(0.0, 50.0)).decode()
        elif kind == "float32 values":  # REAL datapoints written as doubles: 17 digits
            t = repr(float(np.float32(rng.gauss(0.0, 50.0))))
        else:
            t = _random_decimal(rng)
        texts.append(t)
    _bitwise(texts)


def test_halfway_cases_signed_zero_and_the_ends_of_the_range() -> None:
    texts = [
        "9007199254740993.0", "9007199254740995.0", "-9007199254740993.0",  # ties: to even
        "0.0", "-0.0", "0", "-0", "0e10", "-0.000e-5",
        "1e23", "8.98846567431158e307", "1.7976931348623157e308",  # the largest double
        "2.2250738585072014e-308", "2.2250738585072011e-308",  # normal / subnormal border
        "5e-324", "4.9406564584124654e-324", "1e-320",  # subnormals: declined, read by orjson
        "1.00000000000000011102230246251565404236316680908203125",  # 54 digits: declined
        "0.1", "0.3", "123456789012345678.0", "1234567890123456789.0",
        "7.3177701707893310e+15", "3.4028235677973366e38", "1E-5", "1e+5",
        "100000000000000000000000.0", "0.000000000000000000000000000001",
    ]
    _bitwise(texts)


def test_a_declined_number_mid_message_keeps_every_value() -> None:
    """The numbers before a declined one come from the scan, it and those after from orjson."""
    rng = random.Random(3)
    texts = [orjson.dumps(rng.gauss(0.0, 5.0)).decode() for _ in range(1000)]
    texts[501] = "4.9e-324"  # subnormal
    texts[700] = "1.2345678901234567890123"  # 23 digits
    _bitwise(texts)


def test_a_numba_without_the_option_gets_the_scan_with_reference_counting(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The scan is compiled without numba's reference counting (``_nrt``, a CPU target
    option); a numba that no longer knows the option ("Unrecognized options") must still
    scan, with the counting: stood in for by an option no numba knows (compiled afresh,
    ~13 s: from numba's cache the options are not checked)."""
    from cnctwin.iotools import _databus_scan as scan

    monkeypatch.setattr(scan, "_NO_REFCOUNT", {"_no_such_option": False})
    monkeypatch.setattr(scan, "_CACHE", False)  # a cached scan is loaded unchecked
    monkeypatch.setattr(scan, "_compiled", None)
    try:
        _bitwise(["1.5", "-0.0", "2.2250738585072011e-308", "123.456"])
        opts = scan._compiled.targetoptions
        assert "_no_such_option" not in opts and "_nrt" not in opts  # the fallback's
    finally:
        monkeypatch.undo()
        scan._compiled = None  # the next scan compiles (or loads) the one without counting
