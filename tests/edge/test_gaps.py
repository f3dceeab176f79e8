"""Gaps, wraps and late data on the CYCLE time base (docs/reference/data-formats.md §1.2: the
counter runs
0..2147483647 and wraps; a real file had a gap of 3860 cycles)."""

from __future__ import annotations

from typing import Any

import numpy as np
from hypothesis import example, given, settings
from hypothesis import strategies as st

from cnctwin.edge import CycleTracker, EdgeRuntime, ReplaySource, TorqueProcessor
from cnctwin.recording import Recording
from cnctwin.spindle import SpindleModel, speed_change_flags

from ._memsink import MemorySink

M = 2**31


def test_tracker_wrap_gap_late() -> None:
    tr = CycleTracker()
    a = tr.update([M - 3, M - 2, M - 1])
    assert a.cycles.tolist() == [M - 3, M - 2, M - 1] and a.runs[0].gap_before is None
    b = tr.update([0, 1, 5, 6, 4, 7])  # wrap, then a jump of 3 missing, then a late row
    assert b.wraps == 1 and tr.wraps == 1
    assert b.cycles.tolist() == [M, M + 1, M + 5, M + 6, M + 7]
    assert b.late == 1 and b.keep.tolist() == [True, True, True, True, False, True]
    assert [(r.start, r.stop) for r in b.runs] == [(0, 2), (2, 5)]
    gap = b.runs[1].gap_before
    assert gap is not None and (gap.after_cycle, gap.before_cycle, gap.missing) == (
        M + 1, M + 5, 3)
    c = tr.update([7, 8])  # 7 repeated across chunks: late, 8 continues
    assert c.late == 1 and c.cycles.tolist() == [M + 8] and c.runs[0].gap_before is None
    assert tr.missing_cycles == 3 and tr.late == 2


@settings(max_examples=200, deadline=None)
@given(steps=st.lists(st.sampled_from([1, 1, 1, 1, 1, 1, 2, 40, 0, -1, -3]), min_size=1,
                      max_size=120),
       cuts=st.lists(st.integers(1, 30), min_size=1, max_size=40),
       start=st.integers(0, 999), modulus=st.sampled_from([0, 1000]))
@example(steps=[1, 1, 1, 1, -3, 4], cuts=[6], start=997, modulus=1000)  # late across a wrap
@example(steps=[1, 1, 1, 1, -3, 4], cuts=[4, 1, 1], start=997, modulus=1000)
def test_tracker_recovers_the_true_cycles(steps: list[int], cuts: list[int], start: int,
                                          modulus: int) -> None:
    """Any mix of runs in a row (most chunks), gaps, repeats and late rows, cut into chunks
    at random and counted modulo 1000 (a wrap every 1000 cycles): the tracker gives back the
    true cycles that are newer than all before them, and counts the rest as late and every
    jump as a gap."""
    true = start + np.cumsum(steps)
    raw = true % modulus if modulus else true
    tr = CycleTracker(modulus=modulus)
    kept: list[int] = []
    k = 0
    for n in cuts * (len(raw) // sum(cuts) + 1):
        if k >= len(raw):
            break
        upd = tr.update(raw[k:k + n])
        kept += upd.cycles.tolist()
        assert sum(r.stop - r.start for r in upd.runs) == upd.cycles.size
        k += n
    newest = np.maximum.accumulate(true)
    newer = np.concatenate([[True], true[1:] > newest[:-1]])
    offset = int(true[0]) - int(raw[0])  # the tracker counts from the first raw value
    assert kept == (true[newer] - offset).tolist()
    assert tr.late == int((~newer).sum())
    jumps = np.diff(true[newer])
    assert len(tr.gaps) == int((jumps > 1).sum())
    assert tr.missing_cycles == int((jumps[jumps > 1] - 1).sum())


def test_runtime_flags_gap_and_never_invents(wear_recording: Recording,
                                             spindle_model: SpindleModel) -> None:
    rec = wear_recording
    # drop 3860 cycles in the middle (the real C4A file's gap) and 1 cycle further on
    c = rec.cycles
    drop = ((c >= c[1000]) & (c < c[1000] + 3860)) | (c == c[5500])
    hf = rec.hf[~drop]
    gapped = Recording(hf.copy(), events=rec.events, meta=rec.meta.copy())
    mem = MemorySink()
    st = EdgeRuntime(ReplaySource(gapped, chunk_cycles=64), [TorqueProcessor(spindle_model)],
                     [mem]).run()
    gaps = [m for m in mem.messages if m["kind"] == "gap"]
    assert [(g["after_cycle"], g["missing_cycles"]) for g in gaps] == [
        (int(c[999]), 3860), (int(c[5499]), 1)]
    assert st["gaps"] == 2 and st["missing_cycles"] == 3861
    tq = [m for m in mem.messages if m["kind"] == "torque"]
    cyc = np.concatenate([np.arange(m["first_cycle"], m["first_cycle"] + m["n"]) for m in tq])
    tau = np.concatenate([np.asarray(m["torque_nm"], dtype=np.float64) for m in tq])
    flags = np.concatenate([m.get("flags", np.zeros(m["n"], dtype=int)) for m in tq])
    assert np.array_equal(cyc, gapped.cycles)  # only received cycles, none invented
    # per contiguous segment the batch estimate (no derivative across a gap)
    i = gapped.hf["CURRENT|SP1"].to_numpy()
    n = gapped.hf["CMD_SPEED|SP1"].to_numpy()
    cuts = np.flatnonzero(np.diff(gapped.cycles) != 1) + 1
    ref = np.concatenate([spindle_model.cutting_torque(ii, nn)
                          for ii, nn in zip(np.split(i, cuts), np.split(n, cuts), strict=True)])
    # speed changes (run-up, braking) are flagged, not a cutting torque (issue 24, point 3):
    # the flags of each contiguous run, as it is estimated
    bflags = np.concatenate([speed_change_flags(nn) for nn in np.split(n, cuts)])
    np.testing.assert_array_equal(flags, bflags)
    assert (flags != 0).any()
    np.testing.assert_array_equal(tau, np.where(bflags == 0, ref, np.nan))
    # each torque message covers consecutive cycles only
    for m in tq:
        assert not any(g["after_cycle"] < m["first_cycle"] + m["n"] - 1
                       and g["before_cycle"] > m["first_cycle"] for g in gaps)


def test_real_capture4analysis_gap(c4a_file: Any, spindle_model: SpindleModel) -> None:
    """The real C4A file (tests/data/PROVENANCE): its counter gap is flagged, not filled."""
    import cnctwin
    from cnctwin.edge import HoleProcessor

    rec = cnctwin.read_recording(c4a_file)
    mem = MemorySink()
    st = EdgeRuntime(ReplaySource(rec, chunk_cycles=50),
                     [TorqueProcessor(spindle_model), HoleProcessor(spindle_model)],
                     [mem]).run()
    gaps = [(m["after_cycle"], m["before_cycle"]) for m in mem.messages if m["kind"] == "gap"]
    assert gaps == [(g.after_cycle, g.before_cycle) for g in rec.meta.gaps] == [
        (5559591, 5563451)]  # docs/reference/data-formats.md §1.2: one gap of 3860 ticks
    assert st["cycles"] == rec.n_cycles == 3818 and st["holes"] == 0
    tq = [m for m in mem.messages if m["kind"] == "torque"]
    tau = np.concatenate([np.asarray(m["torque_nm"], dtype=np.float64) for m in tq])
    i = rec.hf["CURRENT|SP1"].to_numpy()
    n = rec.hf["CMD_SPEED|SP1"].to_numpy()
    cut = int(np.flatnonzero(np.diff(rec.cycles) != 1)[0]) + 1
    ref = np.concatenate([np.where(speed_change_flags(nn) == 0,
                                   spindle_model.cutting_torque(ii, nn), np.nan)
                          for ii, nn in ((i[:cut], n[:cut]), (i[cut:], n[cut:]))])
    np.testing.assert_array_equal(tau, ref)
