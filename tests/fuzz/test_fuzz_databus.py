"""Fuzzed Databus messages and metadata (issue 14, point 6).

Every input ends either in accepted values (losses in ``decoder.issues``) or in a project
exception (:class:`cnctwin.exceptions.CnctwinError`) whose message names the topic; never a
raw ValueError/KeyError/TypeError/AttributeError/IndexError from inside the parser. Seeds:
the documented message structure (docs/reference/data-formats.md §2), mutated by hypothesis:
truncation,
byte flips, removed brackets, NaN/Inf/huge numbers, wrong JSON types, non-UTF-8 bytes, empty
and very large messages. The example budget is bounded for CI (``max_examples``).
"""

from __future__ import annotations

import json
import time
from typing import Any

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cnctwin.exceptions import CnctwinError
from cnctwin.iotools.databus import DatabusDecoder

TOPIC = "ie/d/j/simatic/v1/s7c1/dp/r/PLC_1/default"
META_TOPIC = "ie/m/j/simatic/v1/s7c1/dp"
META: dict[str, Any] = {"seq": 1, "hashVersion": 123, "applicationName": "S7 Connector",
                        "connections": [{"name": "PLC_1", "type": "s7", "dataPoints": [
                            {"name": "default", "topic": TOPIC, "publishType": "bulk",
                             "dataPointDefinitions": [
                                 {"name": "Load", "id": "101", "dataType": "LReal"},
                                 {"name": "Counter", "id": "102", "dataType": "LInt"},
                                 {"name": "State", "id": "103", "dataType": "String"}]}]}]}
DATA: dict[str, Any] = {"seq": 7, "vals": [
    {"id": "101", "qc": 3, "ts": "2021-03-10T22:23:04.146Z", "val": 80.5},
    {"id": "102", "qc": 3, "ts": "2021-03-10T22:23:04.146Z", "val": "9007199254740993"},
    {"id": "103", "qc": 2, "ts": "2021-03-10T22:23:04.156Z", "val": "RUN"}]}
SETTINGS = settings(max_examples=300, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow])

json_leaf = st.one_of(st.none(), st.booleans(), st.integers(-2**70, 2**70),
                      st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=20))
json_any = st.recursive(json_leaf, lambda kids: st.one_of(
    st.lists(kids, max_size=4), st.dictionaries(st.text(max_size=8), kids, max_size=4)),
    max_leaves=12)


def _mutations(doc: dict[str, Any]) -> st.SearchStrategy[bytes]:
    raw = json.dumps(doc).encode()

    def truncate(k: int) -> bytes:
        return raw[:k]

    def flip(pos_byte: tuple[int, int]) -> bytes:
        pos, b = pos_byte
        pos %= len(raw)
        return raw[:pos] + bytes([b]) + raw[pos + 1:]

    def drop_bracket(k: int) -> bytes:
        idx = [i for i, c in enumerate(raw) if c in b"[]{}"]
        i = idx[k % len(idx)]
        return raw[:i] + raw[i + 1:]

    return st.one_of(
        st.integers(0, len(raw)).map(truncate),
        st.tuples(st.integers(0, 10**6), st.integers(0, 255)).map(flip),
        st.integers(0, 10**6).map(drop_bracket),
        st.binary(max_size=64),  # arbitrary bytes, non-UTF-8 included
        st.just(b""),
        st.just(raw[:-1] + b"," + b" " * 200_000 + b"}"),  # a very large message
    )


def _swap_values(doc: dict[str, Any], path: list[Any], value: Any) -> dict[str, Any]:
    """``doc`` with the node at ``path`` (keys/indices, clipped to what exists) replaced."""
    out = json.loads(json.dumps(doc))
    node = out
    for i, key in enumerate(path):
        if isinstance(node, dict) and node:
            k = sorted(node)[key % len(node)] if isinstance(key, int) else key
            if i == len(path) - 1 or not isinstance(node[k], dict | list):
                node[k] = value
                return out
            node = node[k]
        elif isinstance(node, list) and node:
            j = key % len(node) if isinstance(key, int) else 0
            if i == len(path) - 1 or not isinstance(node[j], dict | list):
                node[j] = value
                return out
            node = node[j]
        else:
            break
    return out


def _check(exc: BaseException, topic: str) -> None:
    assert isinstance(exc, CnctwinError), f"{type(exc).__name__}: {exc}"
    assert topic in str(exc), f"the error does not name the topic: {exc}"


@SETTINGS
@given(_mutations(DATA))
def test_data_bytes(payload: bytes) -> None:
    dec = DatabusDecoder(META)
    try:
        dec.decode(payload, topic=TOPIC)
    except Exception as exc:
        _check(exc, TOPIC)


@SETTINGS
@given(st.lists(st.integers(0, 50), min_size=1, max_size=4), json_any)
def test_data_wrong_types(path: list[int], value: Any) -> None:
    dec = DatabusDecoder(META)
    try:
        dec.decode(json.dumps(_swap_values(DATA, path, value)).encode(), topic=TOPIC)
    except Exception as exc:
        _check(exc, TOPIC)


@SETTINGS
@given(_mutations(META))
def test_metadata_bytes(payload: bytes) -> None:
    dec = DatabusDecoder()
    try:
        dec.update_metadata(payload, topic=META_TOPIC)
    except Exception as exc:
        _check(exc, META_TOPIC)


@SETTINGS
@given(st.lists(st.integers(0, 50), min_size=1, max_size=6), json_any)
def test_metadata_wrong_types(path: list[int], value: Any) -> None:
    dec = DatabusDecoder()
    try:
        dec.update_metadata(json.dumps(_swap_values(META, path, value)).encode(),
                            topic=META_TOPIC)
    except Exception as exc:
        _check(exc, META_TOPIC)


NUM_DATA: dict[str, Any] = {"seq": 8, "vals": [
    {"id": "101", "qc": 3, "ts": "2021-03-10T22:23:04.146Z", "val": 80.5},
    {"id": "102", "qc": 3, "ts": "2021-03-10T22:23:04.146Z", "val": 12},
    {"id": "101", "qc": 1, "ts": "2021-03-10T22:23:04.148Z", "val": -3.25},
    {"id": "102", "qc": 0, "ts": "2021-03-10T22:23:04.150Z", "val": 7}]}


def _general(payload: bytes) -> dict[str, Any] | None:
    d = DatabusDecoder(META)
    try:
        d.decode(payload, topic=TOPIC)
    except CnctwinError:
        return None
    rec = d.recording()
    if rec.lf is not None and len(rec.lf):
        return None
    return {"cycles": rec.hf.index.to_numpy().tolist(),
            "cols": {c: rec.hf[c].to_numpy().tolist() for c in rec.hf.columns if c != "time"}}


@SETTINGS
@given(_mutations(NUM_DATA))
def test_fast_bulk_path_never_raises_and_equals_the_general_path(payload: bytes) -> None:
    """The live source's fast path (``decode_columns``) on mutated messages: it declines
    (None: the general path then names the problem) or returns exactly the values the general
    path's recording holds; it never raises."""
    _fast_equals_general(payload)


def _fast_equals_general(payload: bytes) -> bool:
    """Assert the fast path declines or equals the general path; True when it decoded."""
    fast = DatabusDecoder(META).decode_columns(payload, topic=TOPIC)
    if fast is None:
        return False
    want = _general(payload)
    assert want is not None, payload[:200]
    assert fast.cycles.tolist() == want["cycles"]
    assert set(fast.columns) == set(want["cols"])
    for c, v in fast.columns.items():
        assert v.tolist() == want["cols"][c] or all(
            (a == b) or (a != a and b != b) for a, b in zip(v.tolist(), want["cols"][c],
                                                            strict=True)), c
    return True


def test_fast_bulk_path_on_the_documented_message() -> None:
    """The documented bulk message of numbers: decoded by the fast path, the qualities BAD and
    UNCERTAIN counted as the general path counts them, the seq followed."""
    d = DatabusDecoder(META)
    got = d.decode_columns(json.dumps(NUM_DATA).encode(), topic=TOPIC)
    assert got is not None and got.n_values == 4
    assert got.cycles.size == 3  # 146, 148, 150 ms at 2 ms
    assert got.columns["Load"].tolist()[:2] == [80.5, -3.25]
    assert got.columns["Counter"][0] == 12.0 and got.columns["Counter"][2] == 7.0
    assert any("quality BAD" in i for i in got.issues)
    assert any("quality UNCERTAIN" in i for i in got.issues)
    # a text value or a 64-bit integer as a string: declined, the general path handles it
    assert d.decode_columns(json.dumps(DATA).encode(), topic=TOPIC) is None
    d.decode_columns(json.dumps({**NUM_DATA, "seq": 10}).encode(), topic=TOPIC)
    assert "seq jumped from 8 to 10" in d.issues[-1]


@st.composite
def _regular_bulk(draw: st.DrawFn) -> bytes:
    """A bulk message in the layout of an HF connector: the same ids in the same order for
    each timestamp in turn (the layout the fast path reshapes instead of scattering), with
    timestamps that may share a cycle or go backwards, numbers of either JSON kind, any
    quality, then possibly one mutation."""
    ids = draw(st.lists(st.sampled_from(["101", "102"]), min_size=1, max_size=2, unique=True))
    n_rows = draw(st.integers(1, 6))
    start_ms = 1615414984146
    steps = draw(st.lists(st.sampled_from([1, 2, 2, 2, 4, 0, -2]), min_size=n_rows,
                          max_size=n_rows))
    vals: list[dict[str, Any]] = []
    t = start_ms
    for r in range(n_rows):
        t += steps[r] if r else 0
        sec, ms = divmod(t, 1000)
        ts = time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(sec)) + f".{ms:03d}Z"
        for i in ids:
            v = draw(st.one_of(st.integers(-2**60, 2**60), st.floats(allow_nan=False,
                                                                      allow_infinity=False)))
            vals.append({"id": i, "qc": draw(st.sampled_from([0, 1, 2, 3])), "ts": ts,
                         "val": v})
    payload = json.dumps({"seq": 8, "vals": vals}).encode()
    if draw(st.booleans()):
        return payload
    return draw(_mutations(json.loads(payload)))


@SETTINGS
@given(_regular_bulk())
def test_fast_bulk_path_regular_layout_equals_the_general_path(payload: bytes) -> None:
    """The fast path's reshape of a regular message (one row per timestamp) gives the values
    the general path's recording holds, or declines; shared cycles and backward times go
    to the scatter with the last value winning, as in the general path."""
    _fast_equals_general(payload)
