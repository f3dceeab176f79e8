"""The live ``hole_start`` of the hole processor: the 5th sample of a run moving down starts a
plunge (unless one is on), 5 samples moving up end it, samples standing still leave the runs
as they are. The processor walks the runs of a chunk, not its samples; checked here against
the rule applied sample by sample (written out below), on random Z moves cut into random
chunks, and on a drilling run end to end."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from cnctwin.edge import HoleProcessor, ReplaySource
from cnctwin.sim.scenarios import tool_wear_run


def _by_sample(dz_chunks: list[np.ndarray], step: float) -> list[tuple[int, int]]:
    """The rule sample by sample: (chunk, index of the step) of each plunge start."""
    in_plunge, down_run, up_run = False, 0, 0
    out = []
    for k, dz in enumerate(dz_chunks):
        for j, d in enumerate(dz.tolist()):
            if d < -step:
                down_run += 1
                up_run = 0
                if not in_plunge and down_run >= 5:
                    in_plunge = True
                    out.append((k, j))
            elif d > step:
                up_run += 1
                down_run = 0
                if up_run >= 5:
                    in_plunge = False
    return out


_RUNS = st.lists(st.tuples(st.sampled_from([-1.0, 0.0, 1.0, -0.5, 0.1]), st.integers(1, 8)),
                max_size=60)  # runs of a move (0.1: below the step, standing) 1-8 samples long


@settings(max_examples=400, deadline=None)
@given(_RUNS, st.lists(st.integers(1, 40), min_size=1, max_size=20))
def test_runs_give_the_plunge_starts_of_the_sample_by_sample_rule(
        runs: list[tuple[float, int]], cuts: list[int]) -> None:
    step = 0.2
    moves = [m for m, n in runs for _ in range(n)]
    dz = np.array(moves)
    chunks, k = [], 0
    for n in cuts * (1 + len(moves) // max(sum(cuts), 1)):
        if k >= dz.size:
            break
        chunks.append(dz[k:k + n])
        k += n
    p = HoleProcessor(live_context=False)
    got = [(i, j) for i, c in enumerate(chunks) for j in p._plunge_starts(c, step)]
    assert got == _by_sample(chunks, step)


def test_a_drilling_run_starts_each_hole_once() -> None:
    """12 simulated CYCLE81 holes: 12 plunge starts, each before its hole's cut."""
    rec = tool_wear_run(n_holes=12, holes_per_set=6, dynamometer=False, seed=4).recording
    p = HoleProcessor()
    starts, holes = [], []
    for chunk in ReplaySource(rec, chunk_cycles=137).chunks():
        for r in p.process(chunk):
            (starts if r.kind == "hole_start" else holes).append(r)
    holes += [r for r in p.finish() if r.kind == "hole"]
    assert len(starts) == 12 == p.plunges
    rows = [h.payload["row"] for h in holes if h.kind == "hole"]
    assert len(rows) == 12
    for s, row in zip(starts, rows, strict=True):
        assert s.cycle <= int(row["start_cycle"])


def test_the_live_cut_context_does_not_depend_on_the_chunks() -> None:
    """The live hole context (``HOLE``, ``CUT_PROGRESS``, ``CUT_DEPTH``, ``CUT_FEED``,
    ``CUT_SPEED``: feed and speed latched from each cut's first 25 new-material cycles, then
    held) is a function of the stream, not of how it is cut into chunks: 500-, 137- and
    7-cycle chunks give the same arrays, bit for bit (the latch cycles are written at once
    per chunk since session 26); each of the 6 holes has its context, depth within 0..20 mm,
    progress within 0..1.05 (the encoder passes the 20 mm depth by a few um)."""
    rec = tool_wear_run(n_holes=6, holes_per_set=6, dynamometer=False, seed=2).recording
    got = []
    for size in (500, 137, 7):
        p = HoleProcessor(live_context=True)
        parts: dict[str, list[np.ndarray]] = {}
        for chunk in ReplaySource(rec, chunk_cycles=size).chunks():
            p.process(chunk)
            for k, v in chunk.derived.items():
                parts.setdefault(k, []).append(v)
        got.append({k: np.concatenate(v) for k, v in parts.items()})
    assert set(got[0]) == {"HOLE|Z1", "CUT_PROGRESS|Z1", "CUT_DEPTH|Z1", "CUT_FEED|Z1",
                           "CUT_SPEED|SP1"}
    for other in got[1:]:
        for k, v in got[0].items():
            np.testing.assert_array_equal(other[k], v, err_msg=k)
    ctx = got[0]
    assert sorted(set(ctx["HOLE|Z1"][ctx["HOLE|Z1"] >= 0].astype(int))) == list(range(6))
    cut = np.isfinite(ctx["CUT_DEPTH|Z1"])
    assert cut.any()
    assert ctx["CUT_DEPTH|Z1"][cut].min() >= 0.0 and ctx["CUT_DEPTH|Z1"][cut].max() <= 20.05
    assert ctx["CUT_PROGRESS|Z1"][cut].max() <= 1.05
