"""Sources of the edge runtime: replay of a recording file, live Databus over MQTT.

Both yield :class:`~cnctwin.edge.pipeline.Chunk` objects in arrival order with the *raw*
cycle counter; the runtime (:class:`~cnctwin.edge.runtime.EdgeRuntime`) unwraps it, splits
chunks at gaps and sets late rows aside (:class:`~cnctwin.edge.cycles.CycleTracker`).
``counter_modulus`` says whether the counter can wrap (``2**31`` for a raw SINUMERIK CYCLE, 0
for a counter that is already unwrapped, like a Recording's index).
"""

from __future__ import annotations

import threading
import time
import urllib.parse
from collections.abc import Iterator
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from cnctwin.edge.pipeline import Chunk, no_events
from cnctwin.exceptions import ConfigError
from cnctwin.iotools.mqtt import MqttHub, MqttSecurity
from cnctwin.recording import CYCLE_COUNTER_MODULUS, Recording

__all__ = ["DatabusSource", "MqttUrl", "ReplaySource", "parse_mqtt_url", "session_client_id"]


@dataclass(frozen=True)
class MqttUrl:
    """A parsed ``mqtt://[user[:password]@]host[:port][/topic]`` address."""

    host: str
    port: int
    topic: str
    username: str | None = None
    password: str | None = None


def parse_mqtt_url(url: str, *, default_topic: str = "") -> MqttUrl:
    """Split an ``mqtt://`` URL; the path (without the leading ``/``) is the topic.

    Parameters
    ----------
    url : str
        ``mqtt://[user[:password]@]host[:port][/topic]`` (``tcp://`` also accepted; TLS is
        set by the runtime's ``--tls-ca`` option, not by the URL).
    default_topic : str, default ''
        Topic when the URL has no path.

    Returns
    -------
    MqttUrl
        Host, port (default 1883), topic, user name and password (None where absent).

    Raises
    ------
    ConfigError
        For another scheme or a missing host.
    """
    u = urllib.parse.urlparse(url)
    if u.scheme not in ("mqtt", "tcp"):
        raise ConfigError(f"{url!r} is not an mqtt://host:port/topic URL")
    if not u.hostname:
        raise ConfigError(f"{url!r} has no host (mqtt://host:port/topic)")
    topic = urllib.parse.unquote(u.path[1:]) if u.path.startswith("/") else u.path
    return MqttUrl(u.hostname, u.port or 1883, topic or default_topic,
                   urllib.parse.unquote(u.username) if u.username else None,
                   urllib.parse.unquote(u.password) if u.password else None)


def session_client_id(machine: str, metadata_topic: str) -> str:
    """Stable MQTT client id of the runtime for a machine: the key of its persistent session.

    ``cnctwin-edge-<machine>`` (characters outside ``[A-Za-z0-9_-]`` replaced by ``_``, at most
    64 characters); without a machine name, a short hash of the metadata topic.

    Parameters
    ----------
    machine : str
        Machine name.
    metadata_topic : str
        The Databus metadata topic (used when ``machine`` is empty).

    Returns
    -------
    str
        The client id.

    Examples
    --------
    >>> session_client_id("DMU 50/1", "ie/m/j/simatic/v1/s7c1/dp")
    'cnctwin-edge-DMU_50_1'
    >>> session_client_id("", "ie/m/j/simatic/v1/s7c1/dp")
    'cnctwin-edge-tcc0936660f'
    """
    import hashlib
    import re

    if machine:
        slug = re.sub(r"[^A-Za-z0-9_-]", "_", machine)
    else:
        slug = "t" + hashlib.sha1(metadata_topic.encode()).hexdigest()[:10]
    return f"cnctwin-edge-{slug}"[:64]


def _idle_chunk(cycle_time_s: float, machine: str) -> Chunk:
    """An empty chunk: a live source had nothing new in its poll window; the runtime keeps
    its status and sinks going on it (:meth:`~cnctwin.edge.EdgeRuntime.idle`)."""
    return Chunk(np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int64), {},
                 cycle_time_s=cycle_time_s, machine=machine)


def _events_between(events: pd.DataFrame, lo: int, hi: int,
                    cycles: np.ndarray | None = None) -> pd.DataFrame:
    """Events of cycles ``lo..hi`` (``events`` sorted by cycle; ``cycles`` its cycle column).

    Most chunks have none: then the shared empty frame of :class:`Chunk` is returned without
    slicing (a DataFrame slice costs ~100 us, more than the torque of 50 cycles).
    """
    if events.empty:
        return events
    c = events["cycle"].to_numpy(dtype=np.int64) if cycles is None else cycles
    i, j = int(np.searchsorted(c, lo)), int(np.searchsorted(c, hi, side="right"))
    if i == j:
        return no_events()
    return events.iloc[i:j]


class ReplaySource:
    """Replay a recording (any file :func:`cnctwin.read_recording` opens) in chunks of cycles.

    Parameters
    ----------
    recording : Recording or path
        The recording or its file.
    chunk_cycles : int, default 50
        Cycles per chunk (50 cycles = 100 ms at 2 ms).
    speed : float or None, default None
        Pace: ``1`` = real time, ``N`` = N times real time on the cycle clock, ``None`` or
        ``0`` = as fast as possible.
    columns : list of str, optional
        Only these HF columns (default all; :meth:`select_columns` narrows it later).

    Attributes
    ----------
    scheduled_ns : int
        Wall-clock time at which the last chunk was due (for the lag).
    catch_up_cycle : int or None
        Cycles up to this one are replayed as fast as possible, the pace applies after it
        (a resumed run catches up to where the previous one was; set by the runtime).
    """

    counter_modulus = 0
    live = False

    def __init__(self, recording: Recording | str | PathLike[str], *, chunk_cycles: int = 50,
                 speed: float | None = None, columns: list[str] | None = None) -> None:
        if chunk_cycles < 1:
            raise ConfigError(f"chunk_cycles must be >= 1, not {chunk_cycles}")
        if speed is not None and speed < 0:
            raise ConfigError(f"speed must be >= 0 (0 = as fast as possible), not {speed}")
        self.path: str | None = None
        self._lazy = False
        if not isinstance(recording, Recording):
            from cnctwin.iotools import read_recording
            from cnctwin.iotools._detect import reads_columns

            self.path = str(Path(recording).resolve())
            # a columnar file (Parquet): the metadata, events and cycle clock now, the HF
            # columns once the pipeline has said which it needs (select_columns)
            self._lazy = columns is None and reads_columns(recording)
            recording = read_recording(recording, columns=[] if self._lazy else None)
        self.recording = recording
        self.start_after_cycle: int | None = None
        self.catch_up_cycle: int | None = None
        self.chunk_cycles = int(chunk_cycles)
        self.speed = speed or None
        self.machine = recording.meta.machine
        self.cycle_time_s = recording.meta.cycle_time_s
        self.issues: list[str] = list(recording.meta.issues)
        cols = recording.columns if columns is None else [c for c in columns
                                                          if recording.has(c)]
        self._cols = cols
        self.scheduled_ns = 0
        self._interrupted = threading.Event()

    def select_columns(self, columns: list[str] | None) -> None:
        """Replay only these HF columns (None: every column of the recording).

        Called by the runtime before the first chunk with what its processors and sinks
        need (:func:`cnctwin.edge.pipeline.needed_columns`); a columnar file is read now,
        and only those columns of it.
        """
        if self._lazy:
            from cnctwin.iotools import read_recording

            assert self.path is not None
            self.recording = read_recording(self.path, columns=columns)
            self._lazy = False
        rec = self.recording
        self._cols = rec.columns if columns is None else [c for c in columns if rec.has(c)]

    def identity(self) -> dict[str, Any]:
        """What a checkpoint of this replay must match: the file and its cycle range."""
        cyc = self.recording.cycles
        return {"kind": "replay", "path": self.path, "machine": self.machine,
                "n_cycles": int(cyc.size), "first": int(cyc[0]) if cyc.size else None,
                "last": int(cyc[-1]) if cyc.size else None,
                "chunk_cycles": self.chunk_cycles}

    def seek(self, after_cycle: int | None) -> None:
        """Start (the next :meth:`chunks`) at the first cycle after ``after_cycle``."""
        self.start_after_cycle = after_cycle

    def events_until(self, cycle: int) -> pd.DataFrame:
        """The recording's NC events at or before ``cycle`` (what a run that resumes after
        it without its state needs to know: the modal drilling cycle, the tool)."""
        ev = self.recording.events
        if ev.empty:
            return ev
        return ev[ev["cycle"].to_numpy(dtype=np.int64) <= cycle]

    def chunks(self) -> Iterator[Chunk]:
        """Chunks of ``chunk_cycles`` rows (a chunk can contain a recorded gap)."""
        if self._lazy:  # nobody said what is needed: every column
            self.select_columns(None)
        rec = self.recording
        cyc = rec.cycles
        t_ns = rec.hf["time"].to_numpy(dtype="datetime64[ns]").view(np.int64)
        data = {c: rec.hf[c].to_numpy(dtype=np.float64) for c in self._cols}
        ev = rec.events.sort_values("cycle", kind="stable") if not rec.events.empty \
            else rec.events
        ev_cycles = ev["cycle"].to_numpy(dtype=np.int64) if not ev.empty else None
        start_wall = time.perf_counter_ns()
        begin = 0 if self.start_after_cycle is None else int(
            np.searchsorted(cyc, self.start_after_cycle, side="right"))
        first = int(cyc[begin]) if begin < cyc.size else 0
        step_ns = self.cycle_time_s * 1e9
        k = self.chunk_cycles
        for lo in range(begin, cyc.size, k):
            hi = min(lo + k, cyc.size)
            if self.catch_up_cycle is not None and int(cyc[hi - 1]) <= self.catch_up_cycle:
                first = int(cyc[hi - 1]) + 1  # caught up to here: the pace starts after it
                start_wall = time.perf_counter_ns()
                self.scheduled_ns = time.time_ns()
            elif self.speed:
                due = start_wall + int((int(cyc[hi - 1]) + 1 - first) * step_ns / self.speed)
                wait = due - time.perf_counter_ns()
                if wait > 0 and self._interrupted.wait(wait / 1e9):
                    return  # a stop does not wait for the pace (a long recorded pause)
                self.scheduled_ns = time.time_ns() - max(time.perf_counter_ns() - due, 0)
            else:
                self.scheduled_ns = time.time_ns()
            yield Chunk(cyc[lo:hi], t_ns[lo:hi], {c: v[lo:hi] for c, v in data.items()},
                        events=_events_between(ev, int(cyc[lo]), int(cyc[hi - 1]), ev_cycles),
                        cycle_time_s=self.cycle_time_s, machine=self.machine,
                        received_ns=self.scheduled_ns)

    def interrupt(self) -> None:
        """End :meth:`chunks` now, also in the middle of a paced wait (thread-safe;
        :meth:`~cnctwin.edge.EdgeRuntime.stop` calls it)."""
        self._interrupted.set()

    def close(self) -> None:
        """Nothing to release."""


class DatabusSource:
    """Live Industrial Edge Databus values over MQTT, in chunks of arrival time.

    Uses :class:`cnctwin.iotools.mqtt.MqttRecorder` (metadata topic first, then the data
    topics it announces). Each poll window becomes one chunk: one row per cycle in which values
    arrived. If a datapoint is mapped to the column ``CYCLE`` (the SINUMERIK counter), it is the
    cycle base (it can wrap at 2**31); otherwise the cycle is ``floor(ts / cycle_time_s)`` as
    :class:`~cnctwin.iotools.databus.DatabusDecoder` builds it.

    Parameters
    ----------
    host, port : str, int
        Broker.
    metadata_topic : str
        Connector metadata topic (``ie/m/j/simatic/v1/<instance>/dp``).
    name_map : dict, optional
        Datapoint name -> column (``{"Spindle_Current": "CURRENT|SP1"}``).
    window_s : float, default 0.5
        Longest wait for data before an idle tick [s]. A message is processed as soon as it
        arrives (with what arrived with it); without data the runtime is ticked every
        ``window_s`` (status, MQTT acknowledgements, the idle timeout). 0.1 s ticks cost a
        plant of 100 machines a fifth of its CPU with 1 s messages (BENCHMARKS.md).
    idle_timeout_s : float or None, default None
        Stop when no value arrived for this long [s] (None: run until closed).
    cycle_time_s : float, default 0.002
        Cycle time [s].
    username, password : str, optional
        Broker credentials.
    machine : str, optional
        Machine name (default the metadata's ``applicationName``).
    client_id : str, optional
        Stable MQTT client id (:func:`session_client_id`); needed for a persistent session.
    session_expiry_s : int, default 0
        MQTT 5 session expiry [s]: with a ``client_id``, the broker keeps what the control
        publishes while the runtime is down (restart, crash, kill -9) for this long and
        delivers it on reconnect (QoS 1). 0: a clean session, nothing is kept.
    resume_after_cycle : int, optional
        The last cycle already processed (:func:`~cnctwin.edge.runtime.last_emitted_cycle`
        of the results). Rows at or before it, which the broker redelivers after a crash cut
        their acknowledgement off, are skipped and counted (``replayed_rows`` and an issue),
        until the first newer row. Compared modulo the SINUMERIK counter (2**31) when the
        ``CYCLE`` column is mapped.
    ack_batch : int, default 10
        With acknowledgements held until checkpoints (:meth:`hold_acks_until_checkpoint`):
        ask the runtime for a checkpoint once this many messages wait (a broker sends only
        so many unacknowledged QoS 1 messages: mosquitto's default is 20).
    hub : MqttHub, optional
        The connection of a plant worker, shared by its machines (``host``, ``port``, the
        user, ``client_id`` and the session are then the hub's). A plant worker drives such
        sources from one thread (:func:`cnctwin.edge.plant.run_machines`): ``window_s`` 0, so
        :meth:`chunks` never waits.
    batch_s : float, default 0
        With a hub: the machine's messages are processed at most once per ``batch_s`` [s],
        what arrived meanwhile as one chunk (0: each as it arrives). The work per chunk
        (processors, results, outbox, publish) is then paid once per batch: 100 ms messages
        in 0.5 s batches cost 40 % of their CPU one by one (BENCHMARKS.md), for up to
        ``batch_s`` more latency.
    """

    def __init__(self, host: str, port: int = 1883, *, metadata_topic: str,
                 name_map: dict[str, str] | None = None, window_s: float = 0.5,
                 idle_timeout_s: float | None = None, cycle_time_s: float = 0.002,
                 username: str | None = None, password: str | None = None,
                 machine: str = "", ready_timeout_s: float = 30.0,
                 security: MqttSecurity | None = None, client_id: str = "",
                 session_expiry_s: int = 0, resume_after_cycle: int | None = None,
                 ack_batch: int = 10, hub: MqttHub | None = None,
                 batch_s: float = 0.0) -> None:
        from cnctwin.iotools.mqtt import MqttRecorder

        self.recorder = MqttRecorder(host, port, metadata_topic=metadata_topic,
                                     name_map=name_map, cycle_time_s=cycle_time_s,
                                     username=username, password=password, security=security,
                                     client_id=client_id, session_expiry_s=session_expiry_s,
                                     qos=1, columnar=True, manual_ack=True, hub=hub)
        if batch_s < 0 or (batch_s > 0 and hub is None):
            raise ConfigError(f"batch_s = {batch_s}: give 0, or a positive number of seconds "
                              "for a source on a plant worker's hub")
        self.hub = hub
        self.batch_s = float(batch_s)
        self.window_s = window_s
        self.idle_timeout_s = idle_timeout_s
        self.cycle_time_s = cycle_time_s
        self.machine = machine
        self.ready_timeout_s = ready_timeout_s
        self.issues: list[str] = []
        self.counter_modulus = 0
        self.live = True
        self.resume_after_cycle = resume_after_cycle
        self.replayed_rows = 0
        self._hold_acks = False
        self._pending_acks: list[tuple[int, int]] = []
        self.checkpoint_due = False
        self.ack_batch = ack_batch
        self._started = False
        self._closed = False
        self._interrupted = False

    def start(self) -> DatabusSource:
        """Connect, subscribe and wait for the metadata (bounded by ``ready_timeout_s``)."""
        if not self._started:
            from cnctwin.iotools._databus_scan import prepare_scanner

            self.recorder.start()
            prepare_scanner()  # while the metadata comes in
            self.recorder.wait_ready(timeout_s=self.ready_timeout_s)
            self._started = True
        return self

    def chunks(self) -> Iterator[Chunk]:
        """The values as they arrive: one chunk per burst of messages (at most ``window_s``
        of waiting for the first), so a message is processed as soon as it is in; an empty
        chunk after each ``window_s`` without data (the runtime's idle tick)."""
        self.start()
        last_value = time.monotonic()
        while not self._closed and not self._interrupted:
            self.recorder.poll(self.window_s)
            acks = self.recorder.take_acks()
            got = list(self._take())  # also what arrived while waiting for the metadata
            if not got:
                self.recorder.ack(acks)  # nothing made of them (e.g. skipped as replayed)
                if self.idle_timeout_s is not None and \
                        time.monotonic() - last_value > self.idle_timeout_s:
                    return
                yield _idle_chunk(self.cycle_time_s, self.machine)  # runtime ticks
                continue
            last_value = time.monotonic()
            if self._hold_acks:
                # acknowledged when a checkpoint covers them: a crash before it makes the
                # broker deliver them again, and the runtime rebuilds its state from the
                # checkpoint with them (the last chunk of the burst carries the burst's acks)
                yield from got[:-1]
                self._pending_acks += acks
                self.checkpoint_due = len(self._pending_acks) >= self.ack_batch
                yield got[-1]
            else:
                yield from got
                # the generator resumes only after the runtime has written the results of
                # these chunks to every sink: now the broker may forget the messages
                self.recorder.ack(acks)

    def _take(self) -> Iterator[Chunk]:
        """Chunks of what was decoded: the fast path's arrays, then any general-path values
        (in cycle order)."""
        cols, arrived = self.recorder.take_columns()
        msg = self.recorder.dropped_issue()
        if msg:
            self.issues.append(msg)
        out: list[Chunk] = []
        if cols is not None:
            self.issues.extend(cols.issues)
            ch = self._columns_chunk(cols, arrived)
            if ch is not None:
                out.append(ch)
        if self.recorder.decoder.values:
            rec = self.recorder.decoder.recording(clear=True)
            self.issues.extend(rec.meta.issues)
            if rec.n_cycles:
                ch = self._chunk(rec)
                ch.received_ns = arrived or ch.received_ns
                out.append(ch)
        elif self.recorder.decoder.issues:
            self.issues.extend(self.recorder.decoder.issues)
            self.recorder.decoder.issues = []
        out.sort(key=lambda c: c.first_cycle if len(c) else 0)
        yield from out

    def _columns_chunk(self, cols: Any, arrived: int) -> Chunk | None:
        """A chunk of the fast path's arrays (as :meth:`_chunk` builds one from a recording)."""
        step_ns = round(self.cycle_time_s * 1e9)
        t_ns = cols.cycles * step_ns
        sig = {c: v for c, v in cols.columns.items() if c != "CYCLE"}
        raw = cols.columns.get("CYCLE")
        if raw is not None:
            ok = np.isfinite(raw)
            if not ok.all():
                self.issues.append(f"{int((~ok).sum())} rows without a CYCLE value "
                                   "skipped (the counter is the time base)")
                t_ns = t_ns[ok]
                sig = {c: v[ok] for c, v in sig.items()}
            cycles = raw[ok].astype(np.int64)
            self.counter_modulus = CYCLE_COUNTER_MODULUS
        else:
            cycles = cols.cycles
        if self.resume_after_cycle is not None and len(cycles):
            keep = ~self._behind(cycles)
            cycles, t_ns = cycles[keep], t_ns[keep]
            sig = {c: v[keep] for c, v in sig.items()}
        if not len(cycles):
            return None
        if not self.machine:
            self.machine = str((self.recorder.decoder.metadata or {}).get("applicationName",
                                                                          ""))
        return Chunk(cycles, t_ns, sig, cycle_time_s=self.cycle_time_s, machine=self.machine,
                     received_ns=arrived or time.time_ns())

    def hold_acks_until_checkpoint(self, on: bool = True) -> None:
        """Acknowledge messages only when :meth:`checkpointed` says a checkpoint of the
        runtime covers them (the runtime turns this on when it writes checkpoints).

        Only with a persistent session: a clean session's broker delivers nothing again
        after a crash, so holding would only keep the broker's in-flight window full."""
        self._hold_acks = bool(on) and self.recorder._client.session_expiry_s > 0

    def checkpointed(self) -> None:
        """The runtime wrote a checkpoint after the last chunk yielded: acknowledge its
        messages and those before it."""
        acks, self._pending_acks = self._pending_acks, []
        self.checkpoint_due = False
        self.recorder.ack(acks)

    @property
    def redelivers_after_checkpoint(self) -> bool:
        """After a crash the broker delivers again everything after the last checkpoint
        (persistent session, acknowledgements held until checkpoints)."""
        return self._hold_acks  # held only with a persistent session

    def interrupt(self) -> None:
        """End :meth:`chunks` after the current poll window, also when no data arrives
        (thread-safe; :meth:`~cnctwin.edge.EdgeRuntime.stop` calls it on SIGTERM)."""
        self._interrupted = True

    def drain(self) -> Iterator[Chunk]:
        """Disconnect, then yield what was already received (and acknowledged to the broker).

        Called by :meth:`~cnctwin.edge.EdgeRuntime.run` on a stop (SIGTERM, Ctrl-C): messages
        in the receive queue are processed instead of being lost; what the control publishes
        after the disconnect stays with the broker in the persistent session.
        """
        self.recorder.stop()
        while self.recorder.poll(0.0):  # decode everything already in the receive queue
            pass
        yield from self._take()

    def _chunk(self, rec: Recording) -> Chunk:
        if not self.machine:
            self.machine = rec.meta.machine
        hf = rec.hf
        if "CYCLE" in hf.columns:
            raw = hf["CYCLE"].to_numpy(dtype=np.float64)
            ok = np.isfinite(raw)
            if not ok.all():
                self.issues.append(f"{int((~ok).sum())} rows without a CYCLE value "
                                   "skipped (the counter is the time base)")
            hf = hf[ok]
            cycles = raw[ok].astype(np.int64)
            self.counter_modulus = CYCLE_COUNTER_MODULUS
        else:
            cycles = hf.index.to_numpy(dtype=np.int64)
        if self.resume_after_cycle is not None and len(cycles):
            hf, cycles = self._skip_processed(hf, cycles)
        t_ns = hf["time"].to_numpy(dtype="datetime64[ns]").view(np.int64)
        sig = {c: hf[c].to_numpy(dtype=np.float64) for c in hf.columns
               if c not in ("time", "CYCLE")}
        return Chunk(cycles, t_ns, sig, cycle_time_s=self.cycle_time_s,
                     machine=self.machine, received_ns=time.time_ns())

    def _skip_processed(self, hf: pd.DataFrame, cycles: np.ndarray
                        ) -> tuple[pd.DataFrame, np.ndarray]:
        """Drop the rows a previous run already processed (redelivered after a crash)."""
        behind = self._behind(cycles)
        return hf[~behind], cycles[~behind]

    def _behind(self, cycles: np.ndarray) -> np.ndarray:
        """Rows at or before the resume point (counted as replayed; the check ends past it)."""
        last = int(self.resume_after_cycle)  # type: ignore[arg-type]
        if self.counter_modulus:
            m = self.counter_modulus
            behind = ((last - cycles) % m) < m // 2
        else:
            behind = cycles <= last
        k = int(behind.sum())
        if k:
            self.replayed_rows += k
            self.issues.append(f"{k} rows at or before cycle {last} skipped: already processed "
                               "before the restart (redelivered by the broker)")
        if not behind.all():
            self.resume_after_cycle = None  # past the resume point: stop checking
        return behind

    @property
    def dropped(self) -> int:
        """Messages the receive queue dropped because it was full (counted, never silent)."""
        return self.recorder.dropped

    def close(self) -> None:
        """Disconnect."""
        self._closed = True
        self.recorder.stop()


class OpcUaSource:
    """Live values from the control's OPC UA server (:class:`~cnctwin.iotools.opcua_client.
    OpcUaRecorder`), in chunks of the rows that arrived in each poll window.

    One row per source timestamp the server delivers (about 100 ms on SINUMERIK): the
    chunks' ``cycle_time_s`` is the subscription's interval, not the 2 ms position-control
    cycle, and a lost connection is a gap in the cycle counter (``gap_before``).

    Parameters
    ----------
    url : str
        ``opc.tcp://HOST:PORT``.
    nodes : NodeMap
        The node file (:func:`~cnctwin.iotools.opcua_client.read_node_map`).
    options : OpcUaClientOptions, optional
        Security and user.
    interval_s : float, default 0.1
        Publishing interval [s] (the server's interval between values).
    window_s : float, optional
        Longest wait for new rows [s] (default ``5 x interval_s``, at most 0.5 s); rows are
        handed on as soon as they arrive, so a chunk holds what arrived since the last one
        (the adaptive feed's loop latency depends on it).
    idle_timeout_s : float or None
        Stop when no row arrived for this long after the first [s]. Before the first row
        the source waits (the edge connects before the operator starts the program; a loaded
        control can take seconds from the subscription to its first value); interrupt it to
        end a run that never gets data.
    machine : str
        Machine name.
    """

    def __init__(self, url: str, nodes: Any, *, options: Any = None, interval_s: float = 0.1,
                 window_s: float | None = None, idle_timeout_s: float | None = None,
                 machine: str = "") -> None:
        from cnctwin.iotools.opcua_client import OpcUaRecorder

        self.recorder = OpcUaRecorder(url, nodes, options=options, interval_s=interval_s,
                                      machine=machine)
        self.window_s = min(5.0 * interval_s, 0.5) if window_s is None else window_s
        self.idle_timeout_s = idle_timeout_s
        self._tool: str | None = None
        self.machine = machine
        self.live = True
        self.issues: list[str] = []
        self._done = 0
        self._interrupted = False
        self._started = False

    def start(self) -> OpcUaSource:
        """Connect and check every node (raises a ConfigError naming a bad one)."""
        if not self._started:
            self.recorder.start()
            self._started = True
        return self

    def _chunk(self, rows: list[tuple[int, int, dict[str, Any]]]) -> Chunk:
        from cnctwin.recording import CounterGap

        cycles = np.array([r[0] for r in rows], dtype=np.int64)
        t_ns = np.array([r[1] for r in rows], dtype=np.int64)
        cols = self.recorder.nodes.signals
        sig = {c: np.array([_float(r[2].get(c)) for r in rows]) for c in cols}
        prev = self._last_cycle
        gap = CounterGap(prev, int(cycles[0])) if prev is not None and \
            cycles[0] != prev + 1 else None
        self._last_cycle = int(cycles[-1])
        chunk = Chunk(cycles, t_ns, sig, gap_before=gap,
                      cycle_time_s=self.recorder.interval_s, machine=self.machine,
                      received_ns=time.time_ns())
        ev = self._tool_events(rows)
        if ev is not None:
            chunk.events = ev
        return chunk

    def _tool_events(self, rows: list[tuple[int, int, dict[str, Any]]]) -> Any:
        """The active tool (the node file's ``[text] tool``) as NC events where it changes,
        so processors that follow the tool (adaptive feed, holes) see it as from a file."""
        if "tool" not in self.recorder.nodes.text:
            return None
        out = []
        for c, _, vals in rows:
            v = vals.get("tool")
            if v is None or str(v) == self._tool:
                continue
            self._tool = str(v)
            try:
                num = int(float(str(v).strip().lstrip("Tt") or "nan"))
            except ValueError:
                continue  # a tool name, not a T number: not an NC tool event
            out.append({"cycle": c, "kind": "block", "active_tool": num,
                        "selected_tool": num})
        if not out:
            return None
        from cnctwin.recording import EVENT_COLUMNS

        return pd.DataFrame(out, columns=list(EVENT_COLUMNS)).astype({"cycle": "int64"})

    _last_cycle: int | None = None

    def chunks(self) -> Iterator[Chunk]:
        """One chunk per poll window with rows; an empty one after a window without any."""
        self.start()
        last: float | None = None  # time.monotonic() of the last row; None: none yet
        while not self._interrupted:
            self.recorder.new_rows.wait(self.window_s)
            self.recorder.new_rows.clear()
            rows = self.recorder.rows()[self._done:]
            if not rows:
                if self.idle_timeout_s is not None and last is not None and \
                        time.monotonic() - last > self.idle_timeout_s:
                    return
                # the runtime's idle tick: its status and sinks keep going without data
                yield _idle_chunk(self.recorder.interval_s, self.machine)
                continue
            last = time.monotonic()
            self._done += len(rows)
            yield self._chunk(rows)

    def interrupt(self) -> None:
        """End :meth:`chunks` after the current window (thread-safe)."""
        self._interrupted = True

    def drain(self) -> Iterator[Chunk]:
        """Disconnect and yield the rows received so far."""
        self.recorder.stop()
        rows = self.recorder.rows()[self._done:]
        self._done += len(rows)
        if rows:
            yield self._chunk(rows)

    def close(self) -> None:
        """Disconnect."""
        self.recorder.stop()


def _float(v: Any) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return float("nan")
