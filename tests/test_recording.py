"""Tests of the Recording container (cnctwin.recording)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from cnctwin import Recording, SignalNotFoundError
from cnctwin.recording import CYCLE_COUNTER_MODULUS, cycles_to_time, find_gaps, unwrap_cycles


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
