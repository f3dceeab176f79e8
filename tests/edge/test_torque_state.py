"""The torque processor's state across a checkpoint, also one written by the version before
the held-back cycles became arrays (a deque of (cycle, current, speed) tuples): the
estimates after the restore equal those of the processor that was never stopped."""

from __future__ import annotations

import pickle
from collections import deque

import numpy as np

from cnctwin.edge import TorqueProcessor
from cnctwin.edge.pipeline import Chunk
from cnctwin.spindle import SpindleModel


def _chunks(n: int, size: int) -> list[Chunk]:
    rng = np.random.default_rng(7)
    out = []
    for k in range(n):
        cyc = np.arange(k * size, (k + 1) * size, dtype=np.int64)
        speed = np.where(cyc < 700, 1200.0, 2400.0)  # a speed change: flagged cycles
        out.append(Chunk(cyc, cyc * 2_000_000,
                         {"CURRENT|SP1": rng.normal(5.0, 0.1, size), "CMD_SPEED|SP1": speed},
                         cycle_time_s=0.002, machine="m"))
    return out


def _payloads(p: TorqueProcessor, chunks: list[Chunk]) -> list[dict]:
    return [r.payload for c in chunks for r in p.process(c)] + [r.payload for r in p.finish()]


def test_a_checkpoint_of_the_deque_version_restores_the_same_estimates() -> None:
    model = SpindleModel(1.04, 8.42e-5, 0.35, j_kgm2=0.0045)
    chunks = _chunks(6, 250)
    ref = TorqueProcessor(model)
    for c in chunks[:3]:
        ref.process(c)
    state = pickle.loads(pickle.dumps(ref)).__dict__.copy()
    hc, hi, hn = state.pop("_held")
    assert hc.size >= 1  # the derivative holds the last cycle back
    state["_pending"] = deque(zip(hc.tolist(), hi.tolist(), hn.tolist(), strict=True))
    old = TorqueProcessor.__new__(TorqueProcessor)
    old.__setstate__(state)
    new = pickle.loads(pickle.dumps(ref))
    want = _payloads(ref, chunks[3:])
    for p in (old, new):
        got = _payloads(p, chunks[3:])
        assert [g["first_cycle"] for g in got] == [w["first_cycle"] for w in want]
        for g, w in zip(got, want, strict=True):
            np.testing.assert_array_equal(g["torque_nm"], w["torque_nm"])
            assert g["speed_rpm"] == w["speed_rpm"] and g["current_a"] == w["current_a"]
            assert isinstance(g["torque_nm"], list)  # plain JSON values for any sink
