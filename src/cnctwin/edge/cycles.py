"""The CYCLE time base of a live stream: unwrap, gaps, wraps and late data.

A stream of raw CYCLE counter values arrives chunk by chunk. :class:`CycleTracker` turns each
chunk into contiguous runs on the unwrapped counter (int64, counting on past the 31-bit wrap),
records every jump forward as a gap (the cycles in between are missing: nothing is invented),
and separates values at or before the newest cycle already processed (late or repeated data)
so that the runtime can count and flag them instead of processing them out of order.

Notes
-----
Wrap rule as :func:`cnctwin.recording.unwrap_cycles`: a backward step larger than half the
modulus (2**31, Siemens FAQ: CYCLE runs 0..2147483647) is a wrap-around; a smaller backward
step is late data.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cnctwin.recording import CYCLE_COUNTER_MODULUS, CounterGap

__all__ = ["CycleRun", "CycleTracker", "TrackerUpdate"]


@dataclass(frozen=True)
class CycleRun:
    """Row positions ``start .. stop-1`` of a chunk that form one contiguous run of cycles.

    Attributes
    ----------
    start, stop : int
        Row slice in the chunk (after late rows were removed, see ``TrackerUpdate.keep``).
    first_cycle : int
        Unwrapped cycle of the first row.
    gap_before : CounterGap or None
        The jump in front of this run (missing cycles), if any.
    """

    start: int
    stop: int
    first_cycle: int
    gap_before: CounterGap | None


@dataclass(frozen=True)
class TrackerUpdate:
    """Result of :meth:`CycleTracker.update` for one chunk.

    Attributes
    ----------
    cycles : numpy.ndarray of int64
        Unwrapped cycles of the kept rows, increasing.
    keep : numpy.ndarray of bool
        Which input rows were kept (False: late or repeated).
    runs : list of CycleRun
        Contiguous runs of the kept rows.
    late : int
        Rows dropped from processing because their cycle was not newer than the last one
        processed (counted, never silently).
    wraps : int
        Counter wrap-arounds found in this chunk.
    """

    cycles: NDArray[np.int64]
    keep: NDArray[np.bool_]
    runs: list[CycleRun]
    late: int
    wraps: int


@dataclass
class CycleTracker:
    """Unwrap a raw CYCLE counter across chunks and find gaps, wraps and late rows.

    Parameters
    ----------
    modulus : int, default 2**31
        Counter period (0 for an already unwrapped counter, e.g. a Recording's index).

    Attributes
    ----------
    last_cycle : int or None
        Newest unwrapped cycle processed.
    gaps : list of CounterGap
        Every jump seen (most recent last).
    missing_cycles : int
        Total cycles missing in the gaps.
    wraps, late : int
        Totals over the stream.
    """

    modulus: int = CYCLE_COUNTER_MODULUS
    last_cycle: int | None = None
    gaps: list[CounterGap] = field(default_factory=list)
    missing_cycles: int = 0
    wraps: int = 0
    late: int = 0
    _offset: int = 0
    _last_raw: int | None = None

    def update(self, raw_cycles: ArrayLike) -> TrackerUpdate:
        """Place the next chunk's raw counter values on the unwrapped base.

        Parameters
        ----------
        raw_cycles : array-like of int
            Raw counter values in arrival order.

        Returns
        -------
        TrackerUpdate
        """
        raw = np.asarray(raw_cycles, dtype=np.int64).ravel()
        n = raw.size
        last_raw = self._last_raw
        if n and self.last_cycle is not None \
                and int(raw[0]) + self._offset == self.last_cycle + 1 \
                and (not self.modulus or (last_raw is not None
                                          and int(raw[0]) == last_raw + 1)) \
                and int(raw[-1]) - int(raw[0]) == n - 1 \
                and (n == 1 or not (raw[1:] - raw[:-1] != 1).any()):
            # the usual chunk: the next cycles in a row, no wrap, gap or late row (the
            # general path below gives the same, with ~15 array operations more)
            cyc = raw + self._offset
            self.last_cycle = int(cyc[-1])
            if self.modulus:
                self._last_raw = int(raw[-1])
            return TrackerUpdate(cyc, np.ones(n, dtype=bool), [CycleRun(0, n, int(cyc[0]),
                                                                        None)], 0, 0)
        unwrapped = np.empty(n, dtype=np.int64)
        wraps = 0
        half = self.modulus // 2
        offset = self._offset
        if self.modulus:
            # vectorized unwrap, each step (from the previous raw value) to the nearest:
            # below -half the counter wrapped; above +half a late row from before the wrap
            # came after it (back across the wrap, undone by the next step)
            prev = np.empty(n, dtype=np.int64)
            if n:
                prev[0] = raw[0] if last_raw is None else last_raw
                prev[1:] = raw[:-1]
            step = raw - prev
            wrap_at = (step < -half).astype(np.int64) - (step > half)
            wraps = int(wrap_at.sum())
            unwrapped = raw + (offset + np.cumsum(wrap_at) * self.modulus)
            if n:
                self._offset = offset + wraps * self.modulus
                self._last_raw = int(raw[-1])
        else:
            unwrapped = raw.copy()
        # late rows: not newer than the running maximum (including the previous chunks)
        start = self.last_cycle if self.last_cycle is not None else np.iinfo(np.int64).min
        runmax = np.maximum.accumulate(np.concatenate([[start], unwrapped]))[:-1] if n else \
            np.empty(0, dtype=np.int64)
        keep = unwrapped > runmax
        late = int(n - keep.sum())
        cyc = unwrapped[keep]
        runs: list[CycleRun] = []
        if cyc.size:
            breaks = np.flatnonzero(np.diff(cyc) != 1) + 1
            starts = np.concatenate([[0], breaks])
            stops = np.concatenate([breaks, [cyc.size]])
            for s, e in zip(starts.tolist(), stops.tolist(), strict=True):
                before = self.last_cycle if s == 0 else int(cyc[s - 1])
                gap = None
                if before is not None and int(cyc[s]) != before + 1:
                    gap = CounterGap(int(before), int(cyc[s]))
                    self.gaps.append(gap)
                    self.missing_cycles += gap.missing
                runs.append(CycleRun(int(s), int(e), int(cyc[s]), gap))
            self.last_cycle = int(cyc[-1])
        self.wraps += wraps
        self.late += late
        return TrackerUpdate(cyc, keep, runs, late, wraps)
