"""Tests of the Recording container (cnctwin.recording)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from cnctwin import ConfigError, Recording, SignalNotFoundError
from cnctwin.recording import (
    CYCLE_COUNTER_MODULUS,
    RecordingMeta,
    cycles_to_time,
    find_gaps,
    unwrap_cycles,
)


def test_unwrap_counts_wraps_and_keeps_monotonic() -> None:
    raw = np.array([CYCLE_COUNTER_MODULUS - 2, CYCLE_COUNTER_MODULUS - 1, 0, 1])
    c, wraps = unwrap_cycles(raw)
    assert wraps == 1
    np.testing.assert_array_equal(np.diff(c), [1, 1, 1])


def test_gaps_are_reported() -> None:
    gaps = find_gaps(np.array([1, 2, 3, 3863, 3864]))
    assert len(gaps) == 1
    assert gaps[0].missing == 3859


def test_time_from_anchors_uses_counter_as_clock() -> None:
    # Real file: 78 ticks between HFTimestamps 156 ms apart (docs/reference/data-formats.md 1.2).
    t0 = pd.Timestamp("2023-12-22T14:26:01.312Z")
    times = cycles_to_time([5558199, 5558277], [(5558199, t0)], cycle_time_s=0.002)
    assert (times[1] - times[0]) == pd.Timedelta(milliseconds=156)
    assert times.tz is not None


def test_select_and_conversions() -> None:
    cycles = np.arange(1000, 1100)
    rec = Recording.from_arrays(
        cycles,
        {"CURRENT|SP1": np.linspace(0, 1, 100), "ENC_POS|Z1": np.zeros(100)},
        start_time="2024-01-01T00:00:00",
    )
    assert rec.axes == ["SP1", "Z1"]
    assert rec.meta.units["CURRENT|SP1"] == "A"
    assert rec.meta.units["ENC_POS|Z1"] == "mm"
    sub = rec.select(signals=["CURRENT"], cycles=(1010, 1019))
    assert sub.columns == ["CURRENT|SP1"]
    assert sub.n_cycles == 10
    table = rec.to_arrow()
    assert table.column_names[:2] == ["cycle", "time"]
    assert table.schema.field("CURRENT|SP1").metadata == {b"unit": b"A"}
    with pytest.raises(SignalNotFoundError, match="CURRENT\\|SP1"):
        rec.signal("TORQUE", "SP1")


def test_sections_between_gaps_use_their_own_anchors_when_monotonic() -> None:
    t0 = pd.Timestamp("2024-01-01T00:00:00Z")
    cycles = np.array([0, 1, 2, 1000, 1001])
    gaps = find_gaps(cycles)
    # the gap lasted 10 s of wall time although only 997 cycles (1.994 s) are missing
    anchors = [(0, t0), (1000, t0 + pd.Timedelta(seconds=12))]
    times = cycles_to_time(cycles, anchors, cycle_time_s=0.002, gaps=gaps)
    assert times[3] == t0 + pd.Timedelta(seconds=12)
    assert times[2] == t0 + pd.Timedelta(milliseconds=4)
    # anchors that would make time run backwards: the counter stays the clock
    back = [(0, t0), (1000, t0 - pd.Timedelta(seconds=1))]
    times = cycles_to_time(cycles, back, cycle_time_s=0.002, gaps=gaps)
    assert times.is_monotonic_increasing


# ---------------------------------------------------------------------------- one JSON encoding
def test_meta_json_round_trip_and_older_forms() -> None:
    """One encoding of RecordingMeta (issue 16, point 6): what it writes it reads back, and the
    stores' earlier form (anchor times as integer ns since the epoch) still reads."""
    import json

    from cnctwin.recording import CounterGap, meta_from_json, meta_to_dict, meta_to_json

    t0 = pd.Timestamp("2026-11-26 10:00:00.123456789", tz="UTC")
    meta = RecordingMeta(
        machine="DMC 60H", cycle_time_s=0.002, axis_map={1: "X1", 5: "SP1"},
        units={"CURRENT|SP1": "A"}, source_files=["a.json"], source_format="capture4analysis",
        time_anchors=[(0, t0), (500, t0 + pd.Timedelta(seconds=1))],
        gaps=[CounterGap(10, 14)], wraps=1, issues=["x"], partial=True,
        attrs={"n": np.int64(3), "v": np.arange(2.0), "t": t0},
    )
    back = meta_from_json(meta_to_json(meta))
    assert back.time_anchors == meta.time_anchors  # nanoseconds and time zone kept
    assert back.gaps == meta.gaps and back.axis_map == meta.axis_map
    assert back.attrs == {"n": 3, "v": [0.0, 1.0], "t": t0.isoformat()}
    older = meta_to_dict(meta) | {"time_anchors": [[0, int(t0.value)]]}
    assert meta_from_json(json.dumps(older)).time_anchors == [(0, t0)]


def test_meta_json_bad_form_names_the_key() -> None:
    from cnctwin.recording import meta_from_json

    with pytest.raises(ConfigError, match="'gaps'"):
        meta_from_json('{"gaps": [[1]]}')
    with pytest.raises(ConfigError, match="not valid JSON"):
        meta_from_json("{")


def test_one_encoding_of_recording_meta() -> None:
    """No module but ``cnctwin.recording`` writes or parses the metadata's JSON itself."""
    from pathlib import Path

    import cnctwin

    root = Path(cnctwin.__file__).parent
    own = [p.relative_to(root).as_posix() for p in root.rglob("*.py")
           if p.name != "recording.py"
           and any(s in p.read_text(encoding="utf-8")
                   for s in ("def meta_to_json", "def meta_from_json", "def _jsonable",
                             '"time_anchors": ['))]
    assert own == []
