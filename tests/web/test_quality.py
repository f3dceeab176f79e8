"""Signal-quality accounting (cnctwin.web.quality) on the real recording and on metadata built
with known gaps and clock offsets."""

from __future__ import annotations

import math

import pandas as pd
import pytest

from cnctwin.recording import CounterGap, Recording, RecordingMeta
from cnctwin.web.quality import signal_quality, signal_quality_of


def test_real_recording_gap_and_rate(real_rec: Recording) -> None:
    q = signal_quality_of(real_rec)
    # docs/edge.md "On the real recording": 3818 HF cycles, one gap of 3859 cycles (7.718 s)
    assert real_rec.n_cycles == 3818
    assert q.n_gaps == 1 and q.missing_cycles == 3859
    assert q.missing_s == pytest.approx(7.718, abs=1e-9)
    assert q.longest_gap_s == pytest.approx(7.718, abs=1e-9)
    span = 3818 + 3859  # recorded + missing cycles between the first and the last
    assert q.coverage == pytest.approx(3818 / span, rel=1e-12)
    assert q.effective_rate_hz == pytest.approx(500.0 * 3818 / span, rel=1e-12)
    assert q.nominal_rate_hz == 500.0
    # the reader notes that the file's wall-clock anchors disagree with the counter
    # (recording.cycles_to_time docstring): the scatter is measurable, a few ms at most
    assert q.n_anchors == len(real_rec.meta.time_anchors) >= 2
    assert 0.0 < q.anchor_jitter_ms <= q.anchor_max_dev_ms < 10.0
    # ... except across the gap: the reader's note says the 19 anchors ahead of it are off the
    # median of all anchors by +8.002 s (the gap's wall-clock length is not its 3859 cycles);
    # the step between the two sections' own medians is the same within 2 ms (one cycle)
    assert any("+8.002 s" in i for i in real_rec.meta.issues)
    assert q.clock_step_s == pytest.approx(8.002, abs=0.002)
    assert q.n_issues == len(real_rec.meta.issues) and not q.partial


def test_simulated_recording_is_clean(wear12_rec: Recording) -> None:
    q = signal_quality_of(wear12_rec)
    # the simulator stamps one anchor per second exactly on the counter's clock
    assert q.n_gaps == 0 and q.coverage == 1.0 and q.effective_rate_hz == pytest.approx(500.0)
    assert q.anchor_jitter_ms == 0.0 and q.clock_step_s == 0.0


def test_known_anchor_offsets_and_gap() -> None:
    t0 = pd.Timestamp("2026-01-01", tz="UTC")
    # anchors every 500 cycles (1 s); wall clock late by 0, +3, -3, 0 ms -> std sqrt(4.5) ms
    offsets_ms = [0.0, 3.0, -3.0, 0.0]
    anchors = [(1000 + 500 * k, t0 + pd.Timedelta(seconds=k, milliseconds=o))
               for k, o in enumerate(offsets_ms)]
    meta = RecordingMeta(cycle_time_s=0.002, time_anchors=anchors,
                         gaps=[CounterGap(2600, 2701)], partial=True, issues=["x"])
    q = signal_quality(meta, n_cycles=2401 - 100, first_cycle=1000, last_cycle=3400)
    assert q.missing_cycles == 100 and q.missing_s == pytest.approx(0.2)
    assert q.coverage == pytest.approx(2301 / 2401)
    assert q.anchor_jitter_ms == pytest.approx(math.sqrt(4.5), rel=1e-9)
    assert q.anchor_max_dev_ms == pytest.approx(3.0, rel=1e-9)
    assert q.clock_step_s == 0.0  # every anchor lies before the gap: one anchored section
    assert q.partial and q.n_issues == 1


def test_empty_recording() -> None:
    q = signal_quality(RecordingMeta(), n_cycles=0, first_cycle=None, last_cycle=None)
    assert math.isnan(q.effective_rate_hz) and math.isnan(q.anchor_jitter_ms)
    assert q.n_gaps == 0
