"""The pipeline model of the edge runtime: Source -> Processors -> Sinks on the CYCLE base.

* A **source** yields :class:`Chunk` objects: ``k`` consecutive position-control cycles (the
  unwrapped CYCLE counter, contiguous inside a chunk; a jump starts a new chunk and is carried
  in ``gap_before``), their UTC times, the HF signals and the NC events of those cycles.
* A **processor** turns a chunk into :class:`Result` objects (cutting torque, hole start/end,
  alarms) and may leave per-cycle derived values in ``chunk.derived`` for later processors and
  for the store.
* A **sink** delivers results (MQTT with store-and-forward, the store, a JSON lines file).

Every result carries the cycle it refers to and its values with units in the names, so that
a consumer downstream can order and deduplicate them (``seq`` is set by the runtime).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np
import orjson
import pandas as pd
from numpy.typing import NDArray

from cnctwin.recording import CounterGap, Recording, RecordingMeta, empty_events

__all__ = ["RESULT_KINDS", "Chunk", "MessageBatch", "Processor", "Result", "Sink", "Source",
           "dumps", "needed_columns", "no_events"]

_NO_EVENTS = empty_events()  # shared and never modified: building one costs ~3 ms


def no_events() -> pd.DataFrame:
    """The shared empty event table of chunks without NC events (read it, never modify it).

    Returns
    -------
    pandas.DataFrame
    """
    return _NO_EVENTS


RESULT_KINDS: dict[str, str] = {
    "torque": "cutting torque of a contiguous run of cycles (arrays, one value per cycle)",
    "hole_start": "a plunge of the drilling axis began (first downward Z motion)",
    "hole": "a hole is complete: its row of cnctwin.usecases.holes.hole_record",
    "alarm": "an anomaly score crossed its threshold upward, or a hole judged against its cut "
             "condition (HoleLoadJudge: breakage, no load, load rise or drop)",
    "tool_life": "after a hole, its tool's life: holes used, flank-wear estimate, remaining "
                 "holes and time with a 90 % interval (cnctwin.usecases.tool_life)",
    "twin": "a window of the stream against the calibrated twin (cnctwin.compare): residual "
            "ratio and departures per axis",
    "gap": "the CYCLE counter jumped: cycles missing (never invented)",
    "override": "adaptive feed: the feed override requested for the active tool (tool, "
                "override_pct, target, measured; cnctwin.edge.adaptive)",
    "status": "runtime status (rates, lag, counts, queue, gaps)",
    "run": "a run of the runtime began (first message of every run; consumers and the live "
           "page start a new view, so two runs into one state directory are never mixed)",
}
"""Kinds of :class:`Result` the runtime produces."""


@dataclass
class Chunk:
    """``k`` consecutive cycles of the HF stream.

    Attributes
    ----------
    cycles : numpy.ndarray of int64
        Unwrapped cycle counter, consecutive (``cycles[i+1] == cycles[i] + 1``).
    time_ns : numpy.ndarray of int64
        UTC time of each cycle [ns since the Unix epoch].
    signals : dict of str to numpy.ndarray
        ``CODE|AXIS`` -> float64 values per cycle.
    events : pandas.DataFrame
        NC events of these cycles (:data:`cnctwin.recording.EVENT_COLUMNS`).
    gap_before : CounterGap or None
        Missing cycles in front of this chunk.
    cycle_time_s : float
        Position-control cycle time [s].
    machine : str
        Machine name.
    received_ns : int
        Wall-clock time the chunk became available [ns since the epoch] (for the lag).
    derived : dict of str to numpy.ndarray
        Per-cycle values computed by processors (same length as ``cycles``; NaN where a value
        is not yet known, e.g. the held-back last sample of the torque estimator).
    late : dict of str to (int, float)
        Derived values of a cycle of the *previous* chunk that became known only with this
        one: column -> (cycle, value) (the torque estimator's held-back sample), so that a
        later processor holding that cycle back can complete it.
    """

    cycles: NDArray[np.int64]
    time_ns: NDArray[np.int64]
    signals: dict[str, NDArray[np.float64]]
    events: pd.DataFrame = field(default_factory=no_events)
    gap_before: CounterGap | None = None
    cycle_time_s: float = 0.002
    machine: str = ""
    received_ns: int = 0
    derived: dict[str, NDArray[np.float64]] = field(default_factory=dict)
    late: dict[str, tuple[int, float]] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.cycles.size)

    @property
    def first_cycle(self) -> int:
        """First cycle of the chunk."""
        return int(self.cycles[0])

    @property
    def last_cycle(self) -> int:
        """Last cycle of the chunk."""
        return int(self.cycles[-1])

    def to_recording(self, columns: list[str] | None = None) -> Recording:
        """The chunk as a :class:`~cnctwin.recording.Recording` (optionally some columns)."""
        cols = list(self.signals) if columns is None else [c for c in columns
                                                           if c in self.signals]
        hf = pd.DataFrame({c: self.signals[c] for c in cols},
                          index=pd.Index(self.cycles, name="cycle"))
        hf.insert(0, "time", pd.to_datetime(self.time_ns, unit="ns", utc=True))
        meta = RecordingMeta(machine=self.machine, cycle_time_s=self.cycle_time_s,
                             source_format="edge")
        return Recording(hf, events=self.events, meta=meta)


@dataclass(frozen=True)
class Result:
    """One output of the runtime.

    Attributes
    ----------
    kind : str
        One of :data:`RESULT_KINDS`.
    cycle : int
        Cycle the result refers to (first cycle for arrays, the end for a hole).
    payload : dict
        JSON-serialisable values, units in the key names (``torque_nm``) and in ``units``.
    """

    kind: str
    cycle: int
    payload: dict[str, Any]


def dumps(message: dict[str, Any]) -> bytes:
    """One message as compact JSON bytes (orjson; NaN becomes null).

    Parameters
    ----------
    message : dict
        A result message.

    Returns
    -------
    bytes
        Its JSON (orjson; NaN written as null).
    """
    return orjson.dumps(message, option=orjson.OPT_SERIALIZE_NUMPY)


class MessageBatch(list[dict[str, Any]]):
    """The messages of one emission, handed to every sink; :meth:`encoded` gives their JSON,
    encoded once however many sinks ask for it (the MQTT and JSON lines sinks both do)."""

    _encoded: list[bytes] | None = None

    def encoded(self) -> list[bytes]:
        """:func:`dumps` of each message (computed on the first call)."""
        if self._encoded is None:
            self._encoded = [dumps(m) for m in self]
        return self._encoded


def encoded(messages: list[dict[str, Any]]) -> list[bytes]:
    """The JSON of ``messages``: shared when they come as a :class:`MessageBatch`."""
    if isinstance(messages, MessageBatch):
        return messages.encoded()
    return [dumps(m) for m in messages]


@runtime_checkable
class Source(Protocol):
    """Yields chunks; ``issues`` lists what it had to skip or repair (counted, not silent)."""

    machine: str
    cycle_time_s: float
    issues: list[str]

    def chunks(self) -> Iterator[Chunk]:
        """Chunks in arrival order (raw counter values; the runtime unwraps and checks)."""
        ...

    def close(self) -> None:
        """Release connections/files."""
        ...


@runtime_checkable
class Processor(Protocol):
    """Turns chunks into results."""

    name: str

    def process(self, chunk: Chunk) -> list[Result]:
        """Results for this chunk (may fill ``chunk.derived``)."""
        ...

    def gap(self, gap: CounterGap) -> list[Result]:
        """The stream jumped: finish what spans it (no interpolation across it)."""
        ...

    def finish(self) -> list[Result]:
        """End of the stream: emit what is still held back."""
        ...


@runtime_checkable
class Sink(Protocol):
    """Delivers results."""

    name: str

    def write(self, messages: list[dict[str, Any]], chunk: Chunk | None) -> None:
        """Deliver ``messages`` (and, for the store, the chunk's derived values)."""
        ...

    def status(self) -> dict[str, Any]:
        """Counters for the status message (queue depth, drops, connection)."""
        ...

    def close(self) -> None:
        """Flush and release."""
        ...


def needed_columns(parts: Iterable[Any]) -> list[str] | None:
    """The HF columns a pipeline's processors and sinks read from the chunks.

    Each declares ``needs``: a tuple of ``CODE|AXIS`` names (empty: results only, e.g. the
    JSON-lines and MQTT sinks) or None (every column: the store, MTConnect's axis samples,
    the twin compare). A part without the attribute counts as None, so a user's own
    processor gets every column.

    Parameters
    ----------
    parts : iterable
        Processors and sinks.

    Returns
    -------
    list of str or None
        The union in sorted order, or None when some part needs every column.
    """
    cols: set[str] = set()
    for p in parts:
        need = getattr(p, "needs", None)
        if need is None:
            return None
        cols.update(need)
    return sorted(cols)
