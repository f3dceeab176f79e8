"""The status rides with the chunks while data flows, whatever the phase of the idle ticks
(issue 28, point 1: status and idle work cost little).

A plant ticks each machine every 0.5 s; with 1 s messages and a 1 s status, a tick that
came at the status period took the status just before the next chunk, which then found it
too recent: the phase locked and every status went out in a batch of its own (the plant's
bench: 583 of 750 statuses per 15 s and worker, BENCHMARKS.md). Here a controlled clock
drives one runtime through that phase: while chunks come every period, each status goes out
with a chunk and the statuses stay 0.8-1.2 periods apart; without data the ticks send it
every period.
"""

from __future__ import annotations

import time
import types
from typing import Any

import numpy as np
import pytest

from cnctwin.edge import EdgeRuntime
from cnctwin.edge import runtime as runtime_mod
from cnctwin.edge.pipeline import Chunk


class _BatchSink:
    """Keeps each batch the runtime writes and whether a chunk came with it."""

    name = "batches"
    needs: tuple[str, ...] = ()

    def __init__(self, clock: list[float]) -> None:
        self.clock = clock
        self.batches: list[tuple[float, bool, list[str]]] = []

    def write(self, messages: list[dict[str, Any]], chunk: Any) -> None:
        self.batches.append((self.clock[0], chunk is not None, [m["kind"] for m in messages]))

    def status(self) -> dict[str, Any]:
        return {}

    def close(self) -> None:
        pass


class _Clock(types.ModuleType):
    """The ``time`` module with a controlled ``monotonic``."""

    def __init__(self, clock: list[float]) -> None:
        super().__init__("time")
        self._clock = clock

    def monotonic(self) -> float:
        return self._clock[0]

    def __getattr__(self, name: str) -> Any:
        return getattr(time, name)


class _Source:
    machine = "m1"
    cycle_time_s = 0.002
    live = True


@pytest.mark.parametrize("phase_s", [0.05, 0.3, 0.705, 0.95])
def test_status_rides_with_the_chunks_whatever_the_tick_phase(
        monkeypatch: pytest.MonkeyPatch, phase_s: float) -> None:
    clock = [1000.0]
    monkeypatch.setattr(runtime_mod, "time", _Clock(clock))
    sink = _BatchSink(clock)
    rt = EdgeRuntime(_Source(), [], [sink], machine="m1", status_every_s=1.0,
                     checkpoint_every_s=None)
    period, tick = 1.0, 0.5
    # events: idle ticks every 0.5 s from 1000 on; chunks of 500 cycles every 1 s from
    # 1005 + phase to 1035 + phase; ticks go on to 1045
    events: list[tuple[float, int]] = [(1000.0 + k * tick, 0) for k in range(91)]
    events += [(1005.0 + phase_s + j * period, 1) for j in range(31)]
    events.sort()
    cycle = 0
    for t, kind in events:
        clock[0] = t
        if kind == 1:
            cyc = np.arange(cycle, cycle + 500, dtype=np.int64)
            cycle += 500
            rt.handle(Chunk(cyc, cyc * 2_000_000, {}, cycle_time_s=0.002, machine="m1"))
        else:
            rt.handle(Chunk(np.empty(0, np.int64), np.empty(0, np.int64), {},
                            cycle_time_s=0.002, machine="m1"))
    statuses = [(t, with_chunk) for t, with_chunk, kinds in sink.batches if "status" in kinds]
    streaming = [(t, c) for t, c in statuses if 1007.0 <= t <= 1035.0 + phase_s]
    assert len(streaming) >= 27
    # while data flows every status goes out with a chunk, 0.8-1.2 periods apart
    assert all(c for _, c in streaming), [t for t, c in streaming if not c]
    gaps = np.diff([t for t, _ in streaming])
    assert gaps.min() >= 0.8 * period - 1e-9 and gaps.max() <= 1.2 * period + 1e-9
    # before and after the data: the idle ticks send it every period
    before = [t for t, c in statuses if t < 1005.0]
    after = [t for t, c in statuses if t > 1037.0]
    assert not any(c for t, c in statuses if t < 1005.0 or t > 1037.0)
    np.testing.assert_allclose(np.diff(before), period)
    np.testing.assert_allclose(np.diff(after), period)
