"""The edge runtime: pull chunks from a source, run the processors, hand results to sinks.

:class:`EdgeRuntime` owns the CYCLE time base (:class:`~cnctwin.edge.cycles.CycleTracker`):
it unwraps the counter, splits chunks at gaps (a ``gap`` message and every processor's
:meth:`gap` hook run first, so nothing spans missing cycles and nothing is interpolated), and
keeps late or repeated rows out of the processing while counting them. It numbers the
messages (``seq``, continued across runs and crashes from ``seq.json`` in the state
directory), writes ``status.json`` there and sends a ``status`` message every
``status_every_s``.
"""

from __future__ import annotations

import bisect
import contextlib
import json
import os
import struct
import threading
import time
import zlib
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
import orjson

from cnctwin.edge._files import sync_dir
from cnctwin.edge.cycles import CycleTracker
from cnctwin.edge.pipeline import (
    Chunk,
    MessageBatch,
    Processor,
    Result,
    Sink,
    Source,
    needed_columns,
)
from cnctwin.edge.sinks import tail_messages
from cnctwin.edge.status_file import StatusFile
from cnctwin.exceptions import ConfigError
from cnctwin.recording import CounterGap

__all__ = ["EdgeRuntime", "last_emitted", "last_emitted_cycle", "read_checkpoint", "read_status"]

STATUS_FILE = "status.json"


@dataclass
class _Counters:
    cycles: int = 0
    chunks: int = 0
    messages: int = 0
    holes: int = 0
    alarms: int = 0
    started_wall: float = field(default_factory=time.monotonic)
    busy_s: float = 0.0
    cpu_s: float = 0.0
    lag_s: float = float("nan")
    age_s: float = float("nan")
    last_cycle: int | None = None
    recent: list[tuple[float, int]] = field(default_factory=list)
    latencies: LatencyWindow = field(default_factory=lambda: LatencyWindow(LATENCY_WINDOW))


LATENCY_WINDOW = 5000
"""Chunks whose arrival-to-publish latency the status summarises (the most recent)."""


class LatencyWindow:
    """The most recent ``size`` latencies, kept sorted as they come: a percentile of the
    window costs a lookup, not a sort (the status asks every second, for every machine).

    Parameters
    ----------
    size : int
        Values kept (the oldest leaves when a new one comes).
    """

    def __init__(self, size: int) -> None:
        if size < 1:
            raise ConfigError(f"a latency window of {size} values: give at least 1")
        self._order: deque[float] = deque(maxlen=size)
        self._sorted: list[float] = []

    def __len__(self) -> int:
        return len(self._order)

    def append(self, value_s: float) -> None:
        """Add a latency [s] (NaN is not kept: it has no place in an order)."""
        if value_s != value_s:
            return
        if len(self._order) == self._order.maxlen:
            old = self._order[0]
            del self._sorted[bisect.bisect_left(self._sorted, old)]
        self._order.append(value_s)
        bisect.insort(self._sorted, value_s)

    def percentile(self, q: float) -> float:
        """The ``q``-th percentile [s], interpolated linearly between the order statistics
        (numpy's default method); NaN when empty."""
        a = self._sorted
        if not a:
            return float("nan")
        pos = (len(a) - 1) * q / 100.0
        lo = int(pos)
        hi = min(lo + 1, len(a) - 1)
        return a[lo] + (a[hi] - a[lo]) * (pos - lo)

    def max(self) -> float:
        """The largest latency [s]; NaN when empty."""
        return self._sorted[-1] if self._sorted else float("nan")


class EdgeRuntime:
    """Source -> processors -> sinks on the CYCLE base.

    Parameters
    ----------
    source : Source
        :class:`~cnctwin.edge.sources.ReplaySource`, :class:`~cnctwin.edge.sources.DatabusSource`
        or anything with ``chunks()``.
    processors : sequence of Processor
        Run in order on every chunk (the torque processor first: others use its values).
    sinks : sequence of Sink
        Receive every message.
    state_dir : str or path-like, optional
        Where ``status.json`` is written (default: no file).
    machine : str, optional
        Machine name in the messages (default the source's).
    status_every_s : float, default 1.0
        Wall-clock period of the status message and file [s]. While data flows the status
        goes out with a chunk's results (one batch for the sinks) once
        ``1 - STATUS_EARLY`` of the period has passed, so its period is then 0.8 to 1.2
        times this (an idle tick takes it over only once ``1 + STATUS_EARLY`` passed);
        without data an idle tick sends it every period.
    checkpoint_every_s : float or None, default 10.0
        Stream time between checkpoints of the processors' state (``checkpoint.a``/``.b`` in
        ``state_dir``: the open hole, the detectors, the estimator's history, the cycle base),
        written atomically after a chunk [s]; a stream faster than real time (a replay at
        full speed) also waits as long of wall time, up to 1 s (10 s of a replay take ~20 ms:
        a checkpoint each would cost a tenth of the pipeline). None: no checkpoints. See
        :meth:`resume`.
    """

    def __init__(self, source: Source, processors: Sequence[Processor], sinks: Sequence[Sink],
                 *, state_dir: str | PathLike[str] | None = None, machine: str = "",
                 status_every_s: float = 1.0,
                 checkpoint_every_s: float | None = 10.0) -> None:
        self.source = source
        self.processors = list(processors)
        self.sinks = list(sinks)
        self.state_dir = Path(state_dir) if state_dir is not None else None
        if self.state_dir is not None:
            self.state_dir.mkdir(parents=True, exist_ok=True)
        self.machine = machine or getattr(source, "machine", "") or "machine"
        self.status_every_s = status_every_s
        self.tracker: CycleTracker | None = None
        self.c = _Counters()
        self.state = "starting"
        self._seq = 0
        self._seq_reserved = 0
        if self.state_dir is not None:
            self._seq = self._seq_reserved = _read_seq(self.state_dir)
        self._overload_reported: dict[str, int] = {}
        self._last_status = -1e9
        self._last_data = -1e9  # time.monotonic() of the last chunk with cycles
        self._stop = threading.Event()
        self.final_status: dict[str, Any] | None = None
        self.checkpoint_every_s = checkpoint_every_s
        self._ckpt_cycle: int | None = None
        self._ckpt_wall = 0.0
        self._ckpt_file: CheckpointFile | None = None  # opened with the first checkpoint
        self._suppress: dict[str, int] = {}
        self.resumed: dict[str, Any] | None = None
        self._status_file = StatusFile(self.state_dir / STATUS_FILE) \
            if self.state_dir is not None else None

    # ------------------------------------------------------------------ messages
    def _reserve(self, n: int) -> None:
        """Persist a seq bound above the next ``n`` numbers before they are used.

        The state directory keeps the bound (``seq.json``, written atomically); a runtime that
        is killed restarts numbering from it, so a ``(machine, seq)`` pair is never given to
        two different messages, across restarts and crashes (numbers may be skipped).
        """
        if self.state_dir is None or self._seq + n <= self._seq_reserved:
            return
        self._seq_reserved = self._seq + n + SEQ_BLOCK
        _write_seq(self.state_dir, self._seq_reserved)

    def _messages(self, results: list[Result], chunk: Chunk | None) -> list[dict[str, Any]]:
        if self._suppress:
            results = self._not_yet_emitted(results)
        self._reserve(len(results))
        out = []
        for r, plain in zip(results, self._plain_messages(results, chunk), strict=True):
            out.append({"seq": self._seq, **plain})
            self._seq += 1
            if r.kind == "hole":
                self.c.holes += 1
            elif r.kind == "alarm":
                self.c.alarms += 1
        self.c.messages += len(out)
        return out

    def _emit(self, results: list[Result], chunk: Chunk | None, *,
              status: bool = False) -> None:
        """Number ``results`` and hand them to every sink, in one batch.

        With ``status``, the status (and any overload alarms) follows them in the same batch
        (counted with them): one JSON-lines write, one outbox transaction and the publishes of
        a chunk carry it, where a batch of its own cost as much again (BENCHMARKS.md, "where
        a machine-second goes"); ``status.json`` is written after the sinks have the batch.
        """
        replays = self._suppress and any(getattr(s, "replays", False) for s in self.sinks)
        msgs = MessageBatch(self._messages(results, chunk))  # JSON encoded once for all sinks
        repeats: MessageBatch | None = None
        if replays:
            # a resumed run repeats cycles: sinks that write by id (the store) get the
            # repeated results too (no seq: nothing is published twice)
            repeats = MessageBatch(self._plain_messages(results, chunk))
        st: dict[str, Any] | None = None
        if status:
            self._last_status = time.monotonic()
            alarms = self._overload_alarms(self.overload())
            msgs += self._messages(alarms, None)  # numbered first: counted in the status
            st = self.status()
            report = Result("status", self.c.last_cycle or 0,
                            {k: v for k, v in st.items() if k != "machine"})
            msgs += self._messages([report], None)
            if repeats is not None:
                repeats += self._plain_messages([*alarms, report], None)
        for s in self.sinks:
            s.write(repeats if repeats is not None and getattr(s, "replays", False) else msgs,
                    chunk)
        if st is not None:
            self._status_written(st)

    def _plain_messages(self, results: list[Result], chunk: Chunk | None
                        ) -> list[dict[str, Any]]:
        out = []
        for r in results:
            msg: dict[str, Any] = {"kind": r.kind, "machine": self.machine, "cycle": r.cycle}
            if chunk is not None and len(chunk):
                msg["time"] = _iso(int(chunk.time_ns[0]) + round(
                    (r.cycle - chunk.first_cycle) * chunk.cycle_time_s * 1e9))
            msg.update(r.payload)
            out.append(msg)
        return out

    # ------------------------------------------------------------------ one chunk
    def process(self, chunk: Chunk) -> None:
        """Run one source chunk through the pipeline (split at gaps, late rows counted)."""
        t0, c0 = time.perf_counter(), time.thread_time()
        self._last_data = time.monotonic()
        if self.tracker is None:
            self.tracker = CycleTracker(modulus=int(getattr(self.source, "counter_modulus", 0)))
        else:
            self.tracker.modulus = int(getattr(self.source, "counter_modulus",
                                               self.tracker.modulus))
        upd = self.tracker.update(chunk.cycles)
        keep = upd.keep
        if upd.late:
            sel = np.flatnonzero(keep)
        for run in upd.runs:
            if upd.late:
                rows = sel[run.start:run.stop]
                sub = Chunk(upd.cycles[run.start:run.stop], chunk.time_ns[rows],
                            {c: v[rows] for c, v in chunk.signals.items()},
                            events=chunk.events, cycle_time_s=chunk.cycle_time_s,
                            machine=chunk.machine, received_ns=chunk.received_ns)
            elif len(upd.runs) == 1 and upd.cycles.size == len(chunk):
                sub = chunk
                sub.cycles = upd.cycles
            else:
                sl = slice(run.start, run.stop)
                cyc = upd.cycles[sl]
                ev = chunk.events
                if not ev.empty:
                    ec = ev["cycle"].to_numpy(dtype=np.int64)
                    ev = ev[(ec >= cyc[0]) & (ec <= cyc[-1])]
                sub = Chunk(cyc, chunk.time_ns[sl], {c: v[sl] for c, v in chunk.signals.items()},
                            events=ev, cycle_time_s=chunk.cycle_time_s, machine=chunk.machine,
                            received_ns=chunk.received_ns)
            results: list[Result] = []
            if run.gap_before is not None:
                results += self._gap(run.gap_before)
            for p in self.processors:
                results += p.process(sub)
            self.c.cycles += len(sub)
            self.c.last_cycle = sub.last_cycle
            if getattr(self.source, "live", False):  # device clock vs edge clock
                self.c.age_s = (time.time_ns() - int(sub.time_ns[-1])) / 1e9
            last = run is upd.runs[-1]
            if last:
                self.c.chunks += 1
            # a status that is due goes out with the chunk's last results
            self._emit(results, sub, status=last and self._status_after(1.0 - self.STATUS_EARLY))
        if not upd.runs:  # only late or repeated rows (counted by the tracker)
            self.c.chunks += 1
            self._maybe_status()
        if chunk.received_ns:
            # arrival of the data (a live source: its first message) -> results handed to
            # every sink (the MQTT sink publishes in write()); the checkpoint comes after
            self.c.lag_s = (time.time_ns() - chunk.received_ns) / 1e9
            self.c.latencies.append(self.c.lag_s)
        self._maybe_checkpoint(chunk.cycle_time_s)
        self.c.busy_s += time.perf_counter() - t0
        self.c.cpu_s += time.thread_time() - c0

    def _gap(self, gap: CounterGap) -> list[Result]:
        out = [Result("gap", gap.before_cycle, {
            "after_cycle": gap.after_cycle, "before_cycle": gap.before_cycle,
            "missing_cycles": gap.missing,
            "missing_s": gap.missing * getattr(self.source, "cycle_time_s", 0.002)})]
        for p in self.processors:
            out += p.gap(gap)
        return out

    # ------------------------------------------------------------------ restart
    def _maybe_checkpoint(self, cycle_time_s: float) -> None:
        last = self.c.last_cycle
        if self.state_dir is None or self.checkpoint_every_s is None or last is None:
            return
        due = bool(getattr(self.source, "checkpoint_due", False))
        now = time.monotonic()
        if not due and self._ckpt_cycle is not None and (
                (last - self._ckpt_cycle) * cycle_time_s < self.checkpoint_every_s
                or now - self._ckpt_wall < min(self.checkpoint_every_s, 1.0)):
            return  # (the first chunk is checkpointed at once: a crash after it resumes)
        self._ckpt_cycle = last
        self._ckpt_wall = now
        for s in self.sinks:  # what the checkpoint covers is written before it
            flush = getattr(s, "checkpoint", None)
            if flush is not None:
                flush()
        if self._ckpt_file is None:
            self._ckpt_file = CheckpointFile(self.state_dir)
        self._ckpt_file.write({
            "version": CHECKPOINT_VERSION, "source": source_identity(self.source),
            "cycle": last, "tracker": self.tracker, "processors": self.processors,
            "holes": self.c.holes, "alarms": self.c.alarms})
        done = getattr(self.source, "checkpointed", None)
        if done is not None:  # a live source acknowledges what the checkpoint covers
            done()

    def _hold_acks(self) -> None:
        """With checkpoints, a live source acknowledges messages only when one covers them."""
        hold = getattr(self.source, "hold_acks_until_checkpoint", None)
        if hold is not None and self.state_dir is not None and \
                self.checkpoint_every_s is not None:
            hold(True)

    def resume(self) -> dict[str, Any]:
        """Continue a run that ended without finishing (a crash, ``kill -9``, a power loss).

        Call before :meth:`run`. When ``status.json`` in the state directory says the last
        run did not finish and ``results.jsonl`` holds its results:

        * with a checkpoint of the same source that the source can go back to (a replayed
          file seeks to the checkpoint's cycle; a live source whose broker delivers again
          what followed the checkpoint, or whose checkpoint is as new as the results), the
          processors' state is restored from it (open hole,
          detectors, estimator) and processing repeats the cycles after it: the results
          equal an uninterrupted run's;
        * otherwise processing continues after the last emitted cycle with fresh
          processors, and a hole that was open at the crash is flagged ``partial`` (its
          start is not in the data the new run sees); detectors learn again.

        Either way a result the previous run already emitted (same kind, cycle at or before
        its last one) is not emitted again, so the ``(machine, seq)`` key never names a
        repeat and every cycle's torque appears once. A previous run that finished cleanly
        is not resumed (a new run of the same file starts over, with a new ``run`` message).

        Returns
        -------
        dict
            ``resumed`` (bool), ``from_checkpoint`` (bool), ``after_cycle``, ``last_emitted``
            (kind -> cycle); also in the ``run`` message.
        """
        info: dict[str, Any] = {"resumed": False, "from_checkpoint": False,
                                "after_cycle": None, "last_emitted": {}}
        self.resumed = info
        if self.state_dir is None:
            return info
        try:
            prev = read_status(self.state_dir)
        except (FileNotFoundError, ValueError):
            prev = {}
        last = last_emitted(self.state_dir / "results.jsonl")
        if prev.get("state") in (None, "finished") or "torque" not in last:
            return info
        info.update(resumed=True, last_emitted=last)
        self._suppress = {k: v for k, v in last.items() if k not in ("status", "run")}
        seek = getattr(self.source, "seek", None)
        ck = read_checkpoint(self.state_dir)
        self._hold_acks()
        redelivers = bool(getattr(self.source, "redelivers_after_checkpoint", False))
        if ck is not None and ck.get("source") == source_identity(self.source) and (
                seek is not None or redelivers or int(ck["cycle"]) >= last["torque"]):
            self.processors = list(ck["processors"])
            self.tracker = ck["tracker"]
            self.c.holes, self.c.alarms = int(ck["holes"]), int(ck["alarms"])
            self._ckpt_cycle = int(ck["cycle"])
            info.update(from_checkpoint=True, after_cycle=int(ck["cycle"]))
            if redelivers:  # the broker repeats what followed the checkpoint: process it
                setattr(self.source, "resume_after_cycle", int(ck["cycle"]))  # noqa: B010
        else:
            after = int(last["torque"])
            info["after_cycle"] = after
            # what the lost state knew: the hole numbers used, the NC events before the
            # restart (modal drilling cycle, tool) where the source can read them again
            numbered = last_hole_number(self.state_dir / "results.jsonl")
            events_until = getattr(self.source, "events_until", None)
            events = events_until(after) if events_until is not None else None
            info["next_hole"] = None if numbered is None else numbered + 1
            for p in self.processors:
                hook = getattr(p, "resumed_without_state", None)
                if hook is not None:
                    hook(after, next_hole=info["next_hole"], events=events)
        if hasattr(self.source, "catch_up_cycle"):  # as fast as possible to where it was
            self.source.catch_up_cycle = int(last["torque"])
        if seek is not None:
            seek(info["after_cycle"])
        for s in self.sinks:  # a sink that writes blocks continues the one left open
            cont = getattr(s, "resume", None)
            if cont is not None:
                cont(int(info["after_cycle"]), results=self.state_dir / "results.jsonl")
        return info

    def _not_yet_emitted(self, results: list[Result]) -> list[Result]:
        """Drop what the previous run already emitted (a resume repeats those cycles)."""
        out = []
        for r in results:
            bound = self._suppress.get(r.kind)
            if bound is None:
                out.append(r)
                continue
            if r.kind == "torque":
                n = int(r.payload["n"])
                first = int(r.payload["first_cycle"])
                skip = min(max(bound - first + 1, 0), n)
                if skip == n:
                    continue
                if skip:
                    pl = dict(r.payload)
                    for key in ("torque_nm", "speed_rpm", "current_a"):
                        pl[key] = pl[key][skip:]
                    pl["first_cycle"], pl["n"] = first + skip, n - skip
                    r = Result("torque", first + skip, pl)
                out.append(r)
            elif r.cycle > bound:
                out.append(r)
        return out

    # ------------------------------------------------------------------ overload
    def overload(self) -> dict[str, int]:
        """What was lost or refused under load, counted since the start (never silent).

        ``input_dropped``: messages the live source's full receive queue dropped;
        ``forward_dropped``: results the store-and-forward queue of the MQTT sink discarded
        (oldest first) because the broker was away longer than its bound. (Late or repeated
        rows are counted apart, ``late_rows`` of the status.)
        """
        fwd = 0
        for s in self.sinks:
            queue = getattr(s, "queue", None)
            fwd += int(getattr(queue, "dropped", 0) or 0)
        return {"input_dropped": int(getattr(self.source, "dropped", 0) or 0),
                "forward_dropped": fwd}

    def _overload_alarms(self, counts: dict[str, int]) -> list[Result]:
        """An ``alarm`` message for every overload counter that grew since the last one."""
        out = []
        what = {"input_dropped": "input messages dropped (the receive queue was full)",
                "forward_dropped": "results discarded by the forward queue (broker away "
                                   "longer than the queue holds)"}
        for key, total in counts.items():
            delta = total - self._overload_reported.get(key, 0)
            if delta > 0:
                out.append(Result("alarm", self.c.last_cycle or 0, {
                    "detector": "runtime-overload", "overload": key, "count": delta,
                    "total": total, "message": f"{delta} {what[key]}; {total} in all"}))
                self._overload_reported[key] = total
        return out

    # ------------------------------------------------------------------ status
    def status(self) -> dict[str, Any]:
        """The runtime status (what ``status.json`` and the ``status`` message hold)."""
        c = self.c
        wall = max(time.monotonic() - c.started_wall, 1e-9)
        now = time.monotonic()
        c.recent = [(t, n) for t, n in c.recent if now - t <= 5.0] + [(now, c.cycles)]
        t_a, n_a = c.recent[0]
        recent_rate = (c.cycles - n_a) / (now - t_a) if now - t_a > 0.2 else float("nan")
        ct = float(getattr(self.source, "cycle_time_s", 0.002))
        tr = self.tracker
        issues: list[str] = list(getattr(self.source, "issues", []))[-10:]
        for p in self.processors:
            issues += list(getattr(p, "issues", []))[-5:]
        gaps = tr.gaps if tr is not None else []
        return {
            "machine": self.machine, "state": self.state, "updated": _iso(time.time_ns()),
            "cycles": c.cycles, "chunks": c.chunks, "messages": c.messages,
            "last_cycle": c.last_cycle,
            "cycles_per_s": c.cycles / wall, "cycles_per_s_recent": recent_rate,
            "cycles_per_busy_s": c.cycles / c.busy_s if c.busy_s > 0 else float("nan"),
            "cpu_s": round(c.cpu_s, 6),
            "cycles_per_cpu_s": c.cycles / c.cpu_s if c.cpu_s > 0 else float("nan"),
            "machine_rate_cycles_per_s": 1.0 / ct,
            "lag_s": c.lag_s, "data_age_s": c.age_s,
            "latency_ms": _latency_ms(c.latencies),
            "holes": c.holes, "alarms": c.alarms,
            "gaps": len(gaps), "missing_cycles": tr.missing_cycles if tr else 0,
            "last_gaps": [[g.after_cycle, g.before_cycle] for g in gaps[-5:]],
            "wraps": tr.wraps if tr else 0, "late_rows": tr.late if tr else 0,
            "sinks": {s.name: s.status() for s in self.sinks},
            "overload": self.overload(),
            "issues": issues,
        }

    def _status_after(self, share: float) -> bool:
        """``share`` of ``status_every_s`` has passed since the last status."""
        return time.monotonic() - self._last_status >= self.status_every_s * share

    @property
    def status_due(self) -> bool:
        """An idle tick owes the status: ``status_every_s`` passed since the last, or, while
        data flows (a chunk within the last ``status_every_s``, whose successor carries the
        status from ``1 - STATUS_EARLY`` of the period on), the early share more.

        Without that margin a tick that came at the period took the status just before the
        next chunk, which then found it too recent, and the phase locked: every status in a
        batch of its own (the plant's bench: 583 of 750 statuses per 15 s and worker)."""
        streaming = time.monotonic() - self._last_data < self.status_every_s
        return self._status_after(1.0 + self.STATUS_EARLY if streaming else 1.0)

    STATUS_EARLY = 0.2
    """A chunk carries the status once this share of ``status_every_s`` is left: chunks
    that come about as often as the status would otherwise miss it by a few ms in turn and
    leave it to an idle tick, in a batch of its own."""

    def _maybe_status(self, *, force: bool = False) -> None:
        if force or self.status_due:
            self._emit([], None, status=True)

    def _status_written(self, st: dict[str, Any]) -> None:
        """``status.json`` and the ``on_status`` callback, after the status was emitted."""
        if self._status_file is not None:
            # strict JSON: orjson writes a value not known yet (NaN) as null (RFC 8259 has no
            # NaN), as the results are encoded
            self._status_file.write(orjson.dumps(st, option=orjson.OPT_INDENT_2
                                                 | orjson.OPT_SERIALIZE_NUMPY, default=str))
        if self._on_status is not None:
            self._on_status(st)

    _on_status: Callable[[dict[str, Any]], None] | None = None

    def idle(self) -> None:
        """Nothing arrived: keep the status current (every ``status_every_s``) and let the
        sinks send what they hold (the MQTT sink's queue, e.g. the ``run`` message)."""
        self._maybe_status()
        for s in self.sinks:
            pump = getattr(s, "pump", None)
            if pump is not None:
                pump()

    # ------------------------------------------------------------------ loop
    def stop(self) -> None:
        """Ask :meth:`run` to finish after the current chunk (thread-safe).

        A live source is interrupted too, so an idle stream (no data arriving) stops as well.
        """
        self._stop.set()
        interrupt = getattr(self.source, "interrupt", None)
        if interrupt is not None:
            interrupt()

    def run(self, *, max_cycles: int | None = None,
            on_status: Callable[[dict[str, Any]], None] | None = None,
            close: bool = True) -> dict[str, Any]:
        """Process the source until it ends, :meth:`stop` is called or ``max_cycles``.

        Parameters
        ----------
        max_cycles : int, optional
            Stop after this many cycles.
        on_status : callable, optional
            Called with each status dict (e.g. a live display).
        close : bool, default True
            Finish the processors and close the sinks and the source at the end.

        Returns
        -------
        dict
            The final status.

        See Also
        --------
        begin, handle, end : the same run driven from outside, a chunk at a time (a plant
            worker drives all its live machines so, from one thread).
        """
        chunks = self.begin(on_status=on_status)
        try:
            for chunk in chunks:
                self.handle(chunk)
                if self._stop.is_set() or (max_cycles is not None
                                           and self.c.cycles >= max_cycles):
                    break
        finally:
            self.end(close=close)
        return self.final_status if self.final_status is not None else self.status()

    def begin(self, *, on_status: Callable[[dict[str, Any]], None] | None = None
              ) -> Iterator[Chunk]:
        """Start a run driven from outside: the ``run`` message, then the source's chunks.

        Returns
        -------
        iterator of Chunk
            The source's :meth:`chunks`; give each to :meth:`handle`, then call :meth:`end`.
        """
        self._on_status = on_status
        self.state = "running"
        src = self.source
        select = getattr(src, "select_columns", None)
        if select is not None:  # a replay reads only what the pipeline uses
            select(needed_columns([*self.processors, *self.sinks]))
        if getattr(src, "live", False):
            # the processors' compiled loops (numba: ~2 s without its cache) now, not in the
            # first message's latency
            for p in self.processors:
                prepare = getattr(p, "prepare", None)
                if prepare is not None:
                    prepare()
        self._hold_acks()
        self._emit([Result("run", -1, {
            "started": _iso(time.time_ns()), "source": type(src).__name__,
            "live": bool(getattr(src, "live", False)),
            "resume_after_cycle": getattr(src, "resume_after_cycle", None),
            "resumed": self.resumed})], None)
        return iter(self.source.chunks())

    def handle(self, chunk: Chunk) -> None:
        """One chunk of :meth:`begin`'s iterator: processed, or an idle tick when empty."""
        if len(chunk):
            self.process(chunk)
        else:  # a live source with nothing new: status and sinks keep going
            self.idle()

    @property
    def stopping(self) -> bool:
        """:meth:`stop` was called."""
        return self._stop.is_set()

    def end(self, *, close: bool = True) -> dict[str, Any]:
        """End a run: after a stop, a live source's drain is processed; then :meth:`finish`
        (when ``close``). Returns the final status."""
        try:
            if self._stop.is_set():
                # a live source disconnects first, then hands over what it already received
                # (and acknowledged): processed, not lost
                drain = getattr(self.source, "drain", None)
                if drain is not None:
                    for chunk in drain():
                        if len(chunk):
                            self.process(chunk)
        finally:
            if close:
                self.finish()
            else:  # its slots stay for a resume; the files close
                self._close_checkpoint()
        return self.final_status if self.final_status is not None else self.status()

    def finish(self) -> None:
        """Flush the processors (held-back samples, open holes), final status, close sinks."""
        results: list[Result] = []
        for p in self.processors:
            results += p.finish()
        self._emit(results, None)
        done = getattr(self.source, "checkpointed", None)
        if done is not None:  # everything is written: nothing to repeat
            done()
        self.state = "finished"
        self._maybe_status(force=True)
        self.final_status = self.status()
        for s in self.sinks:
            s.close()
        self.source.close()
        if self.state_dir is not None:  # a clean end: the next run continues without a gap
            _write_seq(self.state_dir, self._seq)
            self._close_checkpoint()
            remove_checkpoint(self.state_dir)

    def _close_checkpoint(self) -> None:
        """Close the checkpoint's slot files (a later checkpoint opens them again)."""
        if self._ckpt_file is not None:
            self._ckpt_file.close()
            self._ckpt_file = None


CHECKPOINT_FILE = "checkpoint.pkl"  # the single-file form before session 26 (read, removed)
CHECKPOINT_VERSION = 3  # 2: NC events as arrays; 3: the torque processor flags speed changes


def source_identity(source: Any) -> dict[str, Any]:
    """What a checkpoint must match to be restored for ``source`` (its ``identity()``, or
    the class and machine name)."""
    ident = getattr(source, "identity", None)
    if ident is not None:
        return dict(ident())
    return {"kind": type(source).__name__, "machine": getattr(source, "machine", "")}


CHECKPOINT_SLOTS = ("checkpoint.a", "checkpoint.b")
_CK_MAGIC = b"CNCTCK01"
_CK_HEAD = struct.Struct("<8sQQI")  # magic, sequence number, payload length, CRC-32 of it


class CheckpointFile:
    """The checkpoint of one state directory: two slot files written in turn, in place.

    Each write overwrites the slot that does not hold the newest valid checkpoint (a header
    with a sequence number, the length and the CRC-32 of the pickle, then the pickle) and
    ``fdatasync``s it; :func:`read_checkpoint` takes the valid slot with the higher number.
    A write cut off at any point (a crash, a power loss in the middle of the flush) leaves
    the other slot, the previous checkpoint, intact. Against a new file, a sync and a
    rename per checkpoint (the form before session 26, ``checkpoint.pkl``) it costs half the
    CPU (89-107 against 174-177 us for a 60 kB pickle, the CRC included, on a 2-vCPU VM),
    for every machine every second in a live plant (BENCHMARKS.md, session 26).

    Parameters
    ----------
    state_dir : path-like
        The runtime's state directory.
    """

    def __init__(self, state_dir: str | PathLike[str]) -> None:
        self.dir = Path(state_dir)
        self._fds: list[int | None] = [None, None]
        seqs = [_slot(self.dir / n)[0] for n in CHECKPOINT_SLOTS]
        self._seq = max(seqs)  # -1: no valid slot
        # the slot to write next: not the one holding the newest valid checkpoint
        self._next = 0 if self._seq < 0 else 1 - seqs.index(self._seq)

    def write(self, doc: dict[str, Any]) -> None:
        """Pickle ``doc`` into the older slot and flush it to the disk."""
        import pickle

        payload = pickle.dumps(doc, protocol=pickle.HIGHEST_PROTOCOL)
        k = self._next
        fd = self._fds[k]
        if fd is None:
            path = self.dir / CHECKPOINT_SLOTS[k]
            new = not path.exists()
            fd = self._fds[k] = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
            if new:  # the new name itself must survive a power loss
                sync_dir(self.dir)
        self._seq = max(self._seq, 0) + 1
        head = _CK_HEAD.pack(_CK_MAGIC, self._seq, len(payload), zlib.crc32(payload))
        os.pwrite(fd, head + payload, 0)
        os.ftruncate(fd, _CK_HEAD.size + len(payload))
        _datasync(fd)
        self._next = 1 - k

    def close(self) -> None:
        """Close the slot files (they stay)."""
        for k, fd in enumerate(self._fds):
            if fd is not None:
                os.close(fd)
                self._fds[k] = None


_datasync = getattr(os, "fdatasync", os.fsync)  # (macOS has no fdatasync)


def _slot(path: Path, *, load: bool = False) -> tuple[int, bytes | None]:
    """(sequence number, pickle if ``load``) of a valid slot file, else (-1, None)."""
    try:
        with path.open("rb") as fh:
            head = fh.read(_CK_HEAD.size)
            if len(head) < _CK_HEAD.size:
                return -1, None
            magic, seq, n, crc = _CK_HEAD.unpack(head)
            if magic != _CK_MAGIC:
                return -1, None
            payload = fh.read(n)
    except OSError:
        return -1, None
    if len(payload) != n or zlib.crc32(payload) != crc:
        return -1, None  # cut off, or a torn flush: the other slot holds the previous one
    return int(seq), payload if load else None


def remove_checkpoint(state_dir: str | PathLike[str]) -> None:
    """Delete the checkpoint files of ``state_dir`` (both slots, and the older
    ``checkpoint.pkl``)."""
    d = Path(state_dir)
    for name in (*CHECKPOINT_SLOTS, CHECKPOINT_FILE):
        (d / name).unlink(missing_ok=True)


def write_checkpoint(state_dir: Path, doc: dict[str, Any]) -> None:
    """Write ``doc`` as the newest checkpoint of ``state_dir`` (:class:`CheckpointFile`; a
    runtime keeps one open rather than calling this per checkpoint)."""
    f = CheckpointFile(state_dir)
    try:
        f.write(doc)
    finally:
        f.close()


def read_checkpoint(state_dir: Path) -> dict[str, Any] | None:
    """The newest checkpoint in ``state_dir``, or None (none, another version, unreadable).

    The files are the runtime's own, written into its state directory; like any pickle they
    must not come from elsewhere.

    Parameters
    ----------
    state_dir : path-like
        The runtime's state directory.

    Returns
    -------
    dict or None
    """
    import pickle

    d = Path(state_dir)
    best = max((_slot(d / n, load=True) for n in CHECKPOINT_SLOTS), key=lambda x: x[0])
    try:
        if best[1] is not None:
            doc = pickle.loads(best[1])
        elif (d / CHECKPOINT_FILE).exists():  # written before session 26
            with (d / CHECKPOINT_FILE).open("rb") as fh:
                doc = pickle.load(fh)
        else:
            return None
    except Exception:  # a foreign or older file: resume without state, never fail
        return None
    if not isinstance(doc, dict) or doc.get("version") != CHECKPOINT_VERSION:
        return None
    return doc


SEQ_FILE = "seq.json"
SEQ_BLOCK = 1000
"""Message numbers reserved on disk ahead of use (at most this many are skipped by a crash)."""


def _read_seq(state_dir: Path) -> int:
    p = state_dir / SEQ_FILE
    if not p.exists():
        return 0
    try:
        return int(json.loads(p.read_text(encoding="utf-8"))["next_seq"])
    except (ValueError, KeyError, TypeError, OSError) as exc:
        raise ConfigError(f"{p}: unreadable message counter ({exc}); the next seq cannot be "
                          "known: restore the file or give a new --out directory") from None


def _write_seq(state_dir: Path, next_seq: int) -> None:
    p = state_dir / SEQ_FILE
    tmp = p.with_suffix(".tmp")
    with tmp.open("w", encoding="utf-8") as fh:
        json.dump({"next_seq": int(next_seq)}, fh)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, p)


def _latency_ms(lat: LatencyWindow) -> dict[str, Any]:
    """p50/p99/max [ms] of the recent chunks' arrival-to-publish latency (None before any)."""
    if not len(lat):
        return {"p50": None, "p99": None, "max": None, "chunks": 0}
    return {"p50": round(lat.percentile(50) * 1e3, 3), "p99": round(lat.percentile(99) * 1e3, 3),
            "max": round(lat.max() * 1e3, 3), "chunks": len(lat)}


def _iso(t_ns: int) -> str:
    sec, ns = divmod(int(t_ns), 1_000_000_000)
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(sec)) + f".{ns // 1000:06d}Z"


def read_status(state_dir: str | PathLike[str]) -> dict[str, Any]:
    """The last ``status.json`` written by a runtime into ``state_dir``.

    Parameters
    ----------
    state_dir : str or path-like
        The runtime's state directory (``--out``).

    Returns
    -------
    dict
        The status document (counters, latency, state, last results).

    Raises
    ------
    FileNotFoundError
        If no runtime has written a status there.
    """
    p = Path(state_dir) / STATUS_FILE
    if not p.exists():
        raise FileNotFoundError(f"no {STATUS_FILE} in {state_dir}: start `cnctwin edge run "
                                f"--out {state_dir}` first")
    doc: dict[str, Any] = json.loads(p.read_text(encoding="utf-8"))
    return doc


def last_emitted(results: str | PathLike[str], *, tail_bytes: int = 1 << 20
                 ) -> dict[str, int]:
    """The last cycle of each result kind in ``results`` (a JSON lines file) and its newest
    rotated file; a torque message counts to its last cycle (``first_cycle + n - 1``).

    Read from the end (``tail_bytes`` of each file); a line a crash cut short is skipped.
    Empty for a first run.

    Parameters
    ----------
    results : str or path-like
        The runtime's ``results.jsonl``.
    tail_bytes : int, default 1048576
        How much of the end of the file is read [bytes].

    Returns
    -------
    dict
        Message kind -> last cycle emitted (empty on a first run).
    """
    out: dict[str, int] = {}
    for msgs in tail_messages(results, tail_bytes=tail_bytes):
        for m in msgs:
            try:
                kind = str(m["kind"])
                c = int(m["first_cycle"]) + int(m["n"]) - 1 if kind == "torque" \
                    else int(m["cycle"])
            except (KeyError, TypeError, ValueError):
                continue
            out[kind] = max(out.get(kind, c), c)
        if "torque" in out:
            break
    return out


def last_hole_number(results: str | PathLike[str], *, tail_bytes: int = 1 << 20
                     ) -> int | None:
    """The highest hole number a runtime emitted into ``results`` (its newest rotated file
    too, when the current one has none), or None.

    Parameters
    ----------
    results : str or path-like
        The runtime's ``results.jsonl``.
    tail_bytes : int, default 1048576
        How much of the end of each file is read [bytes].

    Returns
    -------
    int or None
        The hole number, or None when no hole was emitted.
    """
    for msgs in tail_messages(results, tail_bytes=tail_bytes):
        numbers = []
        for m in msgs:
            with contextlib.suppress(KeyError, TypeError, ValueError):
                if m.get("kind") == "hole":
                    numbers.append(int(m["hole"]))
        if numbers:
            return max(numbers)
    return None


def last_emitted_cycle(results: str | PathLike[str], *, tail_bytes: int = 1 << 20
                       ) -> int | None:
    """The last cycle a runtime wrote a torque value for into ``results`` (a JSON lines file).

    Read from the end of the file (its last ``tail_bytes``; a line a crash cut short is
    skipped); when the file holds no torque message yet, the newest rotated file
    (``results.<time>.jsonl``) is read. None when there is none: a first run.

    The results file is what the runtime really emitted, so after a crash (``kill -9``) this
    is the resume point of a live source: the broker redelivers messages whose
    acknowledgement the crash cut off, and their cycles are skipped, not emitted twice.

    Parameters
    ----------
    results : str or path-like
        The runtime's ``results.jsonl``.
    tail_bytes : int, default 1048576
        How much of the end of the file is read [bytes].

    Returns
    -------
    int or None
        The cycle, or None on a first run.
    """
    return last_emitted(results, tail_bytes=tail_bytes).get("torque")
