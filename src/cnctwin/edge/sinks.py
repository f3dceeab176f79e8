"""Sinks of the edge runtime: MQTT with store-and-forward, the store, a JSON lines file.

Messages are dicts built by the runtime (``seq``, ``kind``, ``machine``, ``cycle``,
``time``, then the result's values with units in the key names); see docs/edge.md.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import os
import random
import threading
import time
from collections.abc import Iterator
from os import PathLike
from pathlib import Path
from typing import IO, Any

import numpy as np
import pandas as pd

from cnctwin.edge.forward import ForwardQueue
from cnctwin.edge.forward_log import ForwardLog
from cnctwin.edge.pipeline import Chunk, dumps, encoded
from cnctwin.exceptions import ConfigError
from cnctwin.iotools._mqtt_read import receiving_client
from cnctwin.iotools.mqtt import MqttSecurity, connect_error, refusal
from cnctwin.recording import Recording, RecordingMeta, find_gaps

__all__ = ["JsonLinesSink", "MqttSink", "StoreSink", "dumps", "reconnect_delay_s",
           "tail_messages"]


def reconnect_delay_s(failures: int, *, base_s: float, max_s: float) -> float:
    """Wait before the next connection attempt after ``failures`` failed ones in a row [s].

    Exponential backoff: ``base_s * 2**(failures - 1)``, at most ``max_s`` (``base_s`` after
    a connection that was up and got lost, ``failures = 0``).

    Parameters
    ----------
    failures : int
        Consecutive failed attempts so far.
    base_s : float
        Delay after the first failure [s].
    max_s : float
        Largest delay [s].

    Returns
    -------
    float
        ``min(base_s 2^(failures-1), max_s)`` [s] (``base_s`` for ``failures <= 1``).

    Examples
    --------
    >>> [reconnect_delay_s(k, base_s=2.0, max_s=60.0) for k in range(7)]
    [2.0, 2.0, 4.0, 8.0, 16.0, 32.0, 60.0]
    """
    return float(min(base_s * 2.0 ** max(failures - 1, 0), max_s))


def tail_lines(path: str | PathLike[str], *, tail_bytes: int) -> list[bytes]:
    """The complete lines in the last ``tail_bytes`` of a file (a JSON lines results file).

    A line the window starts inside is left out; so is nothing else (a last line a crash cut
    short is returned, the caller's parser refuses it).

    Parameters
    ----------
    path : str or path-like
        The file.
    tail_bytes : int
        How much of its end is read [bytes].

    Returns
    -------
    list of bytes
        Lines in file order; empty for a missing file.
    """
    try:
        with Path(path).open("rb") as fh:
            size = fh.seek(0, os.SEEK_END)
            start = max(size - tail_bytes, 0)
            fh.seek(start)
            lines = fh.read().split(b"\n")
    except FileNotFoundError:
        return []
    return lines[1:] if start > 0 else lines


def rotated_files(path: str | PathLike[str]) -> list[Path]:
    """The files :class:`JsonLinesSink` rotated ``path`` into, oldest first.

    ``<stem>.<UTC time of the rotation>.jsonl``: the time stamp sorts by name.
    """
    p = Path(path)
    return sorted(p.parent.glob(f"{p.stem}.*{p.suffix}"))




def tail_messages(results: str | PathLike[str], *, tail_bytes: int
                  ) -> Iterator[list[dict[str, Any]]]:
    """The messages in the tail of a results file, then of each file it was rotated into,
    newest first (:func:`tail_lines`; a line a crash cut short, or not a JSON object, is
    skipped).

    Parameters
    ----------
    results : str or path-like
        The runtime's ``results.jsonl``.
    tail_bytes : int
        How much of the end of each file is read [bytes].

    Yields
    ------
    list of dict
        The messages of one file, in file order.
    """
    p = Path(results)
    for f in [p, *reversed(rotated_files(p))]:
        msgs = []
        for line in tail_lines(f, tail_bytes=tail_bytes):
            try:
                m = json.loads(line)
            except json.JSONDecodeError:
                continue
            if isinstance(m, dict):
                msgs.append(m)
        yield msgs


class JsonLinesSink:
    """Append every message as one JSON line to ``path``, rotated by size, with retention.

    Parameters
    ----------
    path : str or path-like
        The file (appended to; created with its directory).
    kinds : set of str, optional
        Only these message kinds (default all).
    rotate_bytes : int, optional
        When the file reaches this size [bytes] it is renamed to
        ``<stem>.<UTC time of the rotation>.jsonl`` and a new one is started (default: never).
        A reader that follows the file (the dashboard's live page) reads the renamed file to
        its end first.
    keep_files : int, optional
        Keep at most this many rotated files; older ones are deleted, counted in
        :meth:`status` (``deleted_files``), never silently (default: keep all).

    Notes
    -----
    The full path writes about 2.2 GB per machine-day (500 Hz torque in 100 ms messages),
    so a runtime that runs for weeks needs rotation and retention, or a store.
    """

    name = "jsonl"
    needs: tuple[str, ...] = ()  # results only

    def __init__(self, path: str | PathLike[str], *, kinds: set[str] | None = None,
                 rotate_bytes: int | None = None, keep_files: int | None = None) -> None:
        if rotate_bytes is not None and rotate_bytes <= 0:
            raise ConfigError(f"rotate_bytes {rotate_bytes}: give a positive size")
        if keep_files is not None and keep_files < 1:
            raise ConfigError(f"keep_files {keep_files}: keep at least 1 rotated file")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.kinds = kinds
        self.rotate_bytes = rotate_bytes
        self.keep_files = keep_files
        self._f: IO[bytes] = self.path.open("ab")
        self._size = self._f.tell()
        if self._size:
            # a crash (kill -9) mid-write leaves a torn last line: end it, so the next
            # message starts a line of its own (readers skip the torn one; it is kept)
            with self.path.open("rb") as r:
                r.seek(-1, os.SEEK_END)
                torn = r.read(1) != b"\n"
            if torn:
                self._f.write(b"\n")
                self._f.flush()
                self._size += 1
        self.written = 0
        self.rotations = 0
        self.deleted_files = 0
        self.deleted_bytes = 0

    def rotated_files(self) -> list[Path]:
        """The rotated files, oldest first."""
        return rotated_files(self.path)

    def write(self, messages: list[dict[str, Any]], chunk: Chunk | None) -> None:
        lines = [e + b"\n" for m, e in zip(messages, encoded(messages), strict=True)
                 if self.kinds is None or m["kind"] in self.kinds]
        if lines:
            data = b"".join(lines)
            self._f.write(data)
            self._f.flush()
            self._size += len(data)
            self.written += len(lines)
            if self.rotate_bytes is not None and self._size >= self.rotate_bytes:
                self._rotate()

    def _rotate(self) -> None:
        import datetime as dt

        self._f.close()
        stamp = dt.datetime.now(dt.UTC).strftime("%Y%m%dT%H%M%S%fZ")
        target = self.path.with_name(f"{self.path.stem}.{stamp}{self.path.suffix}")
        os.replace(self.path, target)
        self._f = self.path.open("ab")
        self._size = 0
        self.rotations += 1
        if self.keep_files is not None:
            old = self.rotated_files()
            for p in old[:max(len(old) - self.keep_files, 0)]:
                size = p.stat().st_size
                p.unlink()
                self.deleted_files += 1
                self.deleted_bytes += size

    def status(self) -> dict[str, Any]:
        return {"path": str(self.path), "written": self.written, "bytes": self._size,
                "rotations": self.rotations, "deleted_files": self.deleted_files,
                "deleted_bytes": self.deleted_bytes}

    def close(self) -> None:
        self._f.close()


class MqttSink:
    """Publish messages to ``<topic_prefix>/<machine>/<kind>`` with store-and-forward.

    Every message goes through a :class:`~cnctwin.edge.forward_log.ForwardLog` on disk (the
    ``outbox`` directory) and is removed when the broker acknowledged it (QoS 1). While the
    broker is unreachable the queue grows (bounded; the oldest are dropped and counted); the
    sink retries the connection with exponential backoff (``retry_s``, doubled after each
    failed attempt up to ``max_retry_s``, +-10 % jitter; paho's own reconnect is off) and
    then sends the backlog oldest first. A lost connection discards the client (and its
    in-flight messages, which are still in the queue) and a new one is made, so only the
    queue decides what is sent and in which order.

    Parameters
    ----------
    host, port : str, int
        Broker.
    state_dir : str or path-like
        Directory of the queue (``outbox/``). Messages still queued in an ``outbox.sqlite``
        there (the queue before session 27) are moved into it first, then that file is
        removed.
    machine : str
        Machine name in the topics.
    topic_prefix : str, default 'cnctwin'
        First topic level.
    max_queue_messages : int, default 200000
        Queue bound (at ~20 messages/s about 2.8 h of backlog).
    retry_s : float, default 2.0
        First wait before reconnecting [s].
    max_retry_s : float, default 60.0
        Longest wait between attempts while the broker stays away [s].
    max_inflight : int, default 100
        Messages published but not yet acknowledged.
    username, password : str, optional
        Broker credentials.
    """

    name = "mqtt"
    needs: tuple[str, ...] = ()  # results only

    def __init__(self, host: str, port: int = 1883, *, state_dir: str | PathLike[str],
                 machine: str, topic_prefix: str = "cnctwin",
                 max_queue_messages: int = 200_000, retry_s: float = 2.0,
                 max_retry_s: float = 60.0,
                 max_inflight: int = 100, username: str | None = None,
                 password: str | None = None, security: MqttSecurity | None = None) -> None:
        from cnctwin.iotools.mqtt import _paho

        self._mqtt = _paho()
        self.host, self.port = host, int(port)
        self.machine = machine or "machine"
        self.topic_prefix = topic_prefix.rstrip("/")
        self.retry_s = retry_s
        self.max_retry_s = max(max_retry_s, retry_s)
        self.max_inflight = max_inflight
        self.username, self.password = username, password
        self.security = security
        self.queue = ForwardLog(Path(state_dir) / "outbox", max_messages=max_queue_messages)
        _move_legacy_queue(Path(state_dir) / "outbox.sqlite", self.queue)
        self._client: Any = None
        self._connected = threading.Event()
        self._lost = threading.Event()
        self._lock = threading.Lock()
        self._acked: list[int] = []
        self._done: list[int] = []  # queue ids acknowledged, deleted with the next write
        self._last_write = -1e9
        self._inflight: dict[int, int] = {}  # mid -> queue id
        self._last_id = 0
        self._fresh: list[tuple[int, str, bytes]] = []  # just queued, in memory: sent w/o SELECT
        self._last_attempt = -1e9
        self._failures = 0  # failed connection attempts in a row (the backoff exponent)
        self._delay_s = 0.0
        self._rng = random.Random()  # jitter, so that a plant's runtimes do not retry in step
        self.attempts = 0
        self.connects = 0
        self.disconnects = 0
        self.last_error = ""

    def topic(self, kind: str) -> str:
        """Topic of a message kind."""
        return f"{self.topic_prefix}/{self.machine}/{kind}"

    # ---------------------------------------------------------------- connection
    def _on_connect(self, client: Any, userdata: Any, flags: Any, rc: Any,
                    properties: Any = None) -> None:
        if getattr(rc, "is_failure", False):
            self.last_error = refusal(rc, self.host, self.port)
            self._failed()
            self._lost.set()
            return
        self._failures = 0
        self._connected.set()

    def _on_disconnect(self, client: Any, userdata: Any, *args: Any) -> None:
        self._connected.clear()
        self._lost.set()

    def _on_publish(self, client: Any, userdata: Any, mid: int, *args: Any) -> None:
        with self._lock:
            self._acked.append(mid)

    def _drop_client(self) -> None:
        self._remove_done()  # acknowledged: not to be sent again from the queue
        c = self._client
        self._client = None
        self._connected.clear()
        self._lost.clear()
        with self._lock:
            self._inflight.clear()
            self._acked.clear()
        self._last_id = 0  # re-send from the oldest queued message
        if c is not None:
            self.disconnects += 1
            # its callbacks off first: the DISCONNECT of a live connection calls
            # on_disconnect, which would mark the next client lost before it connects
            c.on_connect = c.on_disconnect = c.on_publish = None
            with contextlib.suppress(Exception):  # the connection is already gone
                c.disconnect()
            c.loop_stop()

    def _new_client(self) -> Any:
        """A paho client with this sink's user and TLS."""
        m = self._mqtt
        # paho's client with its PUBACK read without two objects per acknowledgement
        c = receiving_client(m)(callback_api_version=m.CallbackAPIVersion.VERSION2)
        if self.username:
            c.username_pw_set(self.username, self.password)
        if self.security is not None:
            self.security.apply(c)
        return c

    def _failed(self) -> None:
        """One more failed attempt: the next waits longer (exponential backoff, jitter)."""
        self._failures += 1
        self._delay_s = reconnect_delay_s(self._failures, base_s=self.retry_s,
                                          max_s=self.max_retry_s) \
            * self._rng.uniform(0.9, 1.1)

    def _connect(self) -> None:
        now = time.monotonic()
        if now - self._last_attempt < self._delay_s:
            return
        self._last_attempt = now
        self.attempts += 1
        self._delay_s = self.retry_s  # a lost connection is retried after retry_s
        c = self._new_client()
        c.on_connect = self._on_connect
        c.on_disconnect = self._on_disconnect
        c.on_publish = self._on_publish
        c.max_inflight_messages_set(self.max_inflight)
        c.reconnect_delay_set(min_delay=3600, max_delay=3600)  # we reconnect ourselves
        try:
            c.connect(self.host, self.port, keepalive=30)
        except OSError as exc:
            self.last_error = connect_error(exc, self.host, self.port)
            self._failed()
            return
        # no network thread: the runtime's thread does the socket work in pump() (a thread
        # per sink cost ~10 us of CPU per cycle in GIL hand-overs on a busy core)
        self._client = c
        self.connects += 1

    def check(self, timeout_s: float = 5.0) -> str:
        """Connect once now: a refusal (user, password) or a TLS failure is an error.

        A broker that cannot be reached is not (store-and-forward keeps the results until it
        can); its reason is returned (empty when connected).

        Raises
        ------
        ConfigError
            The broker refused the credentials, or TLS failed (its certificate not trusted).
        """
        import ssl

        c = self._new_client()
        done = threading.Event()
        result: list[Any] = []

        def on_connect(client: Any, userdata: Any, flags: Any, rc: Any, *a: Any) -> None:
            result.append(rc)
            done.set()

        c.on_connect = on_connect
        try:
            c.connect(self.host, self.port, keepalive=30)
        except ssl.SSLError as exc:
            raise ConfigError(connect_error(exc, self.host, self.port)) from None
        except OSError as exc:
            return connect_error(exc, self.host, self.port)
        c.loop_start()
        try:
            if not done.wait(timeout_s):
                return f"no CONNACK from {self.host}:{self.port} within {timeout_s} s"
            if getattr(result[0], "is_failure", False):
                raise ConfigError(refusal(result[0], self.host, self.port))
            return ""
        finally:
            with contextlib.suppress(Exception):
                c.disconnect()
            c.loop_stop()

    @property
    def connected(self) -> bool:
        """Connected to the broker (CONNACK received, not lost since)."""
        return self._connected.is_set() and not self._lost.is_set()

    # ---------------------------------------------------------------- sending
    def _io(self) -> None:
        """Socket work without waiting: read acknowledgements, write what is pending.

        paho's external-loop calls, not ``loop()``: that one makes a socket pair to wake a
        network thread, and every publish then writes a byte to it and every call selects on
        it (two system calls per message and one per call for a thread this sink does not
        have); a read on the non-blocking socket with nothing to read returns at once."""
        c = self._client
        if c is not None:
            rc = c.loop_read()
            if rc == 0 and c.want_write():
                rc = c.loop_write()
            if rc == 0:
                rc = c.loop_misc()
            if rc != 0 and not self._lost.is_set():
                self.last_error = f"connection lost (rc {rc})"
                self._connected.clear()
                self._lost.set()

    REMOVE_IDLE_S = 2.0
    """While results flow (a write within this time) the acknowledged messages are deleted
    in the next write's transaction, not in a transaction of their own per pump: one SQLite
    commit per chunk instead of two (~0.1 ms of CPU per machine-second, BENCHMARKS.md,
    session 25). An acknowledged message not yet deleted is not sent again (a lost
    connection deletes them first) and counts as sent in :meth:`status`."""

    def _remove_done(self) -> None:
        if self._done:
            self.queue.remove(self._done)
            self._done = []

    def pump(self, *, remove: bool | None = None) -> None:
        """Connect if needed, remove acknowledged messages, send the next ones in order.

        Parameters
        ----------
        remove : bool, optional
            Delete the acknowledged messages now; by default only when no write came
            within :attr:`REMOVE_IDLE_S` (else the next write's transaction does it).
        """
        self._io()
        if self._client is not None and self._lost.is_set():
            self._drop_client()
        if self._client is None:
            self._connect()
            return
        if not self._connected.is_set():
            if time.monotonic() - self._last_attempt > max(self.retry_s, 5.0):
                self.last_error = "no CONNACK"
                self._drop_client()
                self._failed()
            return
        self._done += self._take_acked()
        if remove is None:
            remove = time.monotonic() - self._last_write >= self.REMOVE_IDLE_S \
                or len(self._done) >= 1000
        if remove:
            self._remove_done()
        self._send()

    def _take_acked(self) -> list[int]:
        """Queue ids of the messages the broker acknowledged since the last call."""
        ids: list[int] = []
        with self._lock:
            early: list[int] = []
            for mid in self._acked:
                if mid in self._inflight:
                    ids.append(self._inflight.pop(mid))
                else:  # the ack beat the map entry: keep it for the next pump
                    early.append(mid)
            self._acked = early[-1000:]
        return ids

    def _send(self) -> None:
        room = self.max_inflight - len(self._inflight)
        if room <= 0 or self._client is None:
            return
        fresh = self._fresh
        self._fresh = []
        if fresh and fresh[0][0] <= self._last_id + 1:  # no backlog before them: no SELECT
            nxt = [x for x in fresh if x[0] > self._last_id][:room]
        elif self._last_id >= self.queue.enqueued:
            return  # everything ever queued has gone out: nothing to SELECT (an idle pump)
        else:
            nxt = self.queue.peek(room, after_id=self._last_id)
            if not nxt:  # the ids up to the newest were sent (and deleted) or dropped
                self._last_id = self.queue.enqueued
        c = self._client
        # a chunk's messages (its torque and status) leave in one send, not one each
        with c.holding_writes():
            for qid, topic, payload in nxt:
                info = c.publish(topic, payload, qos=1)
                if info.rc != 0:
                    self.last_error = f"publish failed (rc {info.rc})"
                    self._lost.set()
                    return
                with self._lock:
                    self._inflight[info.mid] = qid
                self._last_id = qid
        if nxt and c.loop_write() != 0 and not self._lost.is_set():
            self.last_error = "connection lost while sending"
            self._connected.clear()
            self._lost.set()

    def write(self, messages: list[dict[str, Any]], chunk: Chunk | None) -> None:
        items = [(self.topic(m["kind"]), e)
                 for m, e in zip(messages, encoded(messages), strict=True)]
        if self._client is not None and self._connected.is_set():
            # the acknowledgements of what went out with the last chunk, read now that they
            # have had the time to come (read right after a send, the socket had none: a
            # system call and paho's read path for nothing, every chunk)
            self._io()
        ready = self._client is not None and self._connected.is_set() \
            and not self._lost.is_set()
        # one write per chunk: the acknowledged messages go out of the queue with the new
        # ones in
        if ready:
            self._done += self._take_acked()
        ids = self.queue.put_many(items, remove=self._done or None)
        self._done = []
        self._last_write = time.monotonic()
        if ready:
            self._fresh = [(i, t, p) for i, (t, p) in zip(ids, items, strict=True)]
            self._send()
            if self._client is not None and self._client.want_write():
                self._io()  # (the socket took only part: the rest now, not a chunk later)
        else:
            self.pump()

    def flush(self, *, timeout_s: float = 10.0) -> bool:
        """Send until the queue is empty or ``timeout_s`` passed; True if empty."""
        deadline = time.monotonic() + timeout_s
        while len(self.queue) and time.monotonic() < deadline:
            self.pump(remove=True)
            time.sleep(0.01)
        return len(self.queue) == 0

    def status(self) -> dict[str, Any]:
        return {"broker": f"{self.host}:{self.port}", "connected": self.connected,
                "queued": len(self.queue) - len(self._done),
                "dropped_oldest": self.queue.dropped,
                **({"outbox_issues": self.queue.issues} if self.queue.issues else {}),
                "sent": self.queue.sent + len(self._done), "connects": self.connects,
                "disconnects": self.disconnects, "last_error": self.last_error,
                "failed_attempts": self._failures,
                "retry_in_s": round(max(self._delay_s - (time.monotonic()
                                                         - self._last_attempt), 0.0), 3)
                if self._client is None else 0.0,
                "topic": self.topic("<kind>")}

    def close(self, *, timeout_s: float = 5.0) -> None:
        """Try to send the backlog for ``timeout_s``; what is left stays on disk."""
        self.flush(timeout_s=timeout_s)
        self._drop_client()
        self.queue.close()


def _move_legacy_queue(path: Path, log: ForwardLog) -> None:
    """Move what an older version left queued in its SQLite outbox into the empty ``log``
    (with its counts of sent and dropped messages), then remove the SQLite files. A crash in
    between moves them again on the next start: sent at least once, as always."""
    if not path.exists():
        return
    old = ForwardQueue(path)
    try:
        if not log.enqueued:
            log.continue_counts(sent=old.sent, dropped=old.dropped)
        after = 0
        while batch := old.peek(1000, after_id=after):
            log.put_many([(t, p) for _, t, p in batch])
            after = batch[-1][0]
    finally:
        old.close()
    for suffix in ("", "-wal", "-shm"):
        Path(f"{path}{suffix}").unlink(missing_ok=True)


class StoreSink:
    """Append derived per-cycle values and hole rows to a :mod:`cnctwin.store`.

    Every ``block_cycles`` cycles one recording is ingested with id
    ``edge-<machine>-<first cycle>`` and ``source_format='edge'``: HF columns are the derived
    values (``CUT_TORQUE|SP1`` [Nm], ``ANOMALY_SCORE|SP1`` [-]) on the cycles processed, and
    ``meta.attrs`` holds the ``holes`` rows and ``alarms`` completed in that block. The hole
    rows also go to the store's hole table (:meth:`cnctwin.store.Store.append_holes`, under the
    block's recording id), where ``store.holes(machine=...)`` finds them; a replay of the same
    stream writes the same ids, so each hole is stored once.

    Nothing is lost across a crash (``kill -9``): at every runtime checkpoint the open block
    is written as it stands (the same id, replaced when it grows), and a resumed runtime
    (:meth:`resume`) reloads it, fills what the crash cut off from the runtime's
    ``results.jsonl`` and continues it under the same id; the cycles the resumed runtime
    repeats reach this sink again (:attr:`replays`), so every cycle and hole is stored once.
    An embedded store is opened only while a block is written (``lock_timeout_s`` wait), so
    a dashboard, ``cnctwin ingest`` or a query can use it beside the runtime; a block that
    could not be written stays in memory and is written with the next one.

    Parameters
    ----------
    url : str or path-like
        Store (:func:`cnctwin.store.open`).
    machine : str
        Machine name of the recordings.
    block_cycles : int, default 30000
        Cycles per stored block (60 s at 2 ms).
    lock_timeout_s : float, default 30
        How long a write waits for an embedded store another process holds [s].
    """

    name = "store"
    needs: tuple[str, ...] = ()  # derived values and results only
    replays = True
    """The runtime hands this sink the results a resumed run repeats (writes are by id)."""

    def __init__(self, url: str | PathLike[str], *, machine: str,
                 block_cycles: int = 30_000, lock_timeout_s: float = 30.0) -> None:
        import cnctwin.store

        if block_cycles < 1:
            raise ConfigError(f"block_cycles must be >= 1, not {block_cycles}")
        self.url = url
        self.lock_timeout_s = float(lock_timeout_s)
        with cnctwin.store.open(url, lock_timeout_s=self.lock_timeout_s) as st:
            self.store_url = str(st.url)  # made (or found) now: a wrong URL fails at start
        self.machine = machine or "machine"
        self.block_cycles = block_cycles
        self._cyc: list[np.ndarray] = []
        self._t: list[np.ndarray] = []
        self._der: list[dict[str, np.ndarray]] = []
        self._tq_cyc: list[np.ndarray] = []
        self._tq_val: list[np.ndarray] = []
        self._tq_column = "CUT_TORQUE|SP1"
        self._n = 0
        self._holes: list[dict[str, Any]] = []
        self._alarms: list[dict[str, Any]] = []
        self._issues: list[str] = []
        self._first: int | None = None  # first cycle of the open block (its id)
        self._dirty = False
        self.blocks: list[str] = []
        self._hole_keys: set[tuple[str, int]] = set()
        self.holes_written = 0
        self.write_errors = 0
        self.last_error: str | None = None
        self._cycle_time_s = 0.002

    @property
    def _prefix(self) -> str:
        safe = "".join(ch if ch.isalnum() or ch in "._-" else "_" for ch in self.machine)
        return f"edge-{safe}-"

    def write(self, messages: list[dict[str, Any]], chunk: Chunk | None) -> None:
        for m in messages:
            if m["kind"] == "hole":
                self._holes = [h for h in self._holes if h["cycle"] != m["cycle"]] + [m]
                self._dirty = True
            elif m["kind"] == "alarm":
                self._alarms.append(m)
                self._dirty = True
            elif m["kind"] == "torque":
                c0 = int(m["first_cycle"])
                self._tq_cyc.append(np.arange(c0, c0 + int(m["n"]), dtype=np.int64))
                self._tq_val.append(np.asarray(m["torque_nm"], dtype=np.float64))
        if chunk is not None and len(chunk):
            self._cycle_time_s = chunk.cycle_time_s
            if self._first is None:
                self._first = int(chunk.cycles[0])
            self._cyc.append(chunk.cycles)
            self._t.append(chunk.time_ns)
            self._der.append({c: v for c, v in chunk.derived.items()
                              if not c.startswith("CUT_TORQUE")})
            self._n += len(chunk)
            self._dirty = True
            if self._n >= self.block_cycles:
                self._ingest(final=False)

    def checkpoint(self) -> None:
        """Write the open block as it stands (called before the runtime's checkpoint)."""
        if self._dirty:
            self._ingest(final=False, whole=True)

    def _torque(self) -> tuple[np.ndarray, np.ndarray]:
        """Torque cycles (sorted, unique) and values received so far."""
        if not self._tq_cyc:
            return np.empty(0, dtype=np.int64), np.empty(0)
        c = np.concatenate(self._tq_cyc)
        v = np.concatenate(self._tq_val)
        c, first = np.unique(c, return_index=True)  # a resumed run repeats a few cycles
        return c, v[first]

    def _ingest(self, *, final: bool, whole: bool = False) -> None:
        """Write the open block; with ``final`` or ``whole`` all of it, else (a full block)
        up to the newest torque value, the rest starting the next block."""
        if not self._n and not self._holes and not self._alarms:
            return
        cyc = np.concatenate(self._cyc) if self._cyc else np.empty(0, dtype=np.int64)
        t = np.concatenate(self._t) if self._t else np.empty(0, dtype=np.int64)
        cols = sorted({c for d in self._der for c in d})
        data = {c: np.concatenate([d.get(c, np.full(len(k), np.nan))
                                   for d, k in zip(self._der, self._cyc, strict=True)])
                for c in cols}
        if cyc.size > 1 and np.any(np.diff(cyc) < 0):  # rows restored after a restart
            order = np.argsort(cyc, kind="stable")
            cyc, t = cyc[order], t[order]
            data = {c: v[order] for c, v in data.items()}
        tq_c, tq_v = self._torque()
        # the torque of the newest cycle comes with the next chunk: a full block ends at the
        # newest torque value and the rest starts the next one (no NaN at block ends)
        n_block = cyc.size
        if tq_c.size and not (final or whole):
            n_block = int(np.searchsorted(cyc, tq_c[-1], side="right"))
        blk = slice(0, n_block)
        pos = np.searchsorted(tq_c, cyc[blk])
        ok = pos < tq_c.size
        tq = np.full(n_block, np.nan)
        hit = ok.copy()
        hit[ok] = tq_c[pos[ok]] == cyc[blk][ok]
        tq[hit] = tq_v[pos[hit]]
        block = {c: v[blk] for c, v in data.items()}
        if tq_c.size or self._tq_column in cols:
            block[self._tq_column] = tq
        hf = pd.DataFrame(block, index=pd.Index(cyc[blk], name="cycle"))
        hf.insert(0, "time", pd.to_datetime(t[blk], unit="ns", utc=True))
        meta = RecordingMeta(machine=self.machine, cycle_time_s=self._cycle_time_s,
                             source_format="edge", gaps=find_gaps(cyc[blk]),
                             units={c: ("Nm" if c.startswith("CUT_TORQUE") else "-")
                                    for c in block},
                             issues=list(self._issues),
                             attrs={"holes": self._holes, "alarms": self._alarms})
        first = self._first if self._first is not None else (
            int(cyc[0]) if cyc.size else int(self._holes[0]["cycle"]))
        rid = f"{self._prefix}{first}"
        if not self._write(rid, Recording(hf, meta=meta), final=final):
            return
        if whole and not final:
            self._dirty = False
            return
        # the block is complete: the rest (cycles after the newest torque) starts the next
        rest = slice(n_block, None)
        keep_tq = tq_c > (cyc[n_block - 1] if n_block else -1)
        self._cyc = [cyc[rest]] if cyc[rest].size else []
        self._t = [t[rest]] if cyc[rest].size else []
        self._der = [{c: v[rest] for c, v in data.items()}] if cyc[rest].size else []
        self._tq_cyc = [tq_c[keep_tq]] if keep_tq.any() else []
        self._tq_val = [tq_v[keep_tq]] if keep_tq.any() else []
        self._n = int(cyc[rest].size)
        self._first = int(cyc[rest][0]) if cyc[rest].size else None
        self._holes, self._alarms, self._issues = [], [], []
        self._dirty = bool(self._n)

    def _write(self, rid: str, rec: Recording, *, final: bool) -> bool:
        """Ingest one block (and its holes); False (kept for the next try) when the store
        is held by another process beyond the wait and this is not the last write."""
        import cnctwin.store
        from cnctwin.exceptions import StoreError

        try:
            with cnctwin.store.open(self.url, lock_timeout_s=self.lock_timeout_s) as st:
                st.ingest(rec, recording_id=rid)
                if self._holes:
                    st.append_holes(rid, [m["row"] for m in self._holes])
        except StoreError as exc:
            self.write_errors += 1
            self.last_error = str(exc)
            if final:
                raise
            return False
        if rid not in self.blocks:
            self.blocks.append(rid)
        self._hole_keys |= {(rid, int(m["row"]["hole"])) for m in self._holes}
        self.holes_written = len(self._hole_keys)
        return True

    def resume(self, after_cycle: int, *, results: str | PathLike[str] | None = None) -> None:
        """Continue the block a crashed run left open, up to ``after_cycle``.

        The newest stored block of this machine that starts at or before ``after_cycle`` is
        reloaded (cycles, derived values, holes, alarms up to ``after_cycle``) and continued
        under its id; what the crash kept from the store but ``results`` (the runtime's JSON
        lines file) holds (torque, holes, alarms up to ``after_cycle``) is added from there,
        flagged in the block's issues (derived values other than the torque are not in that
        file and stay NaN on those cycles).
        """
        import cnctwin.store

        with cnctwin.store.open(self.url, lock_timeout_s=self.lock_timeout_s) as st:
            cat = st.recordings(machine=self.machine)
            ids = [str(r) for r in cat["recording_id"]] if len(cat) else []
            firsts = sorted(int(r[len(self._prefix):]) for r in ids
                            if r.startswith(self._prefix)
                            and r[len(self._prefix):].lstrip("-").isdigit())
            firsts = [f for f in firsts if f <= after_cycle]
            rec = st.load(f"{self._prefix}{firsts[-1]}") if firsts else None
        stored_last = torque_last = -1
        if rec is not None:
            keep = rec.cycles <= after_cycle
            cyc = rec.cycles[keep]
            self._first = firsts[-1]
            self._cycle_time_s = rec.meta.cycle_time_s
            if cyc.size:
                hf = rec.hf[keep]
                self._cyc = [cyc]
                self._t = [hf["time"].to_numpy(dtype="datetime64[ns]").view(np.int64)]
                self._der = [{c: hf[c].to_numpy(dtype=np.float64) for c in rec.columns
                              if c != self._tq_column}]
                self._n = int(cyc.size)
                if self._tq_column in rec.columns:
                    tq = hf[self._tq_column].to_numpy(dtype=np.float64)
                    known = ~np.isnan(tq)
                    self._tq_cyc, self._tq_val = [cyc[known]], [tq[known]]
                    torque_last = int(cyc[known][-1]) if known.any() else -1
                stored_last = int(cyc[-1])
            self._holes = [m for m in rec.meta.attrs.get("holes", [])
                           if int(m["cycle"]) <= after_cycle]
            self._alarms = [m for m in rec.meta.attrs.get("alarms", [])
                            if int(m["cycle"]) <= after_cycle]
            self._issues = list(rec.meta.issues)
        if results is not None:
            self._fill_from_results(Path(results), stored_last, torque_last, after_cycle)
        self._dirty = True

    def _fill_from_results(self, path: Path, stored_last: int, torque_last: int,
                           after_cycle: int) -> None:
        """Torque after ``torque_last``, holes and alarms after ``stored_last``, up to
        ``after_cycle``, from the runtime's results file (what the crash kept from the
        store)."""
        cyc_l: list[np.ndarray] = []
        t_l: list[np.ndarray] = []
        held = {int(m["cycle"]) for m in self._holes}
        alarms = {(int(m["cycle"]), m.get("detector")) for m in self._alarms}
        # the open block is at most block_cycles long: the newest rotated file and the
        # current one hold it (read in that order: the holes stay in time order)
        newest = list(itertools.islice(tail_messages(path, tail_bytes=64 << 20), 2))
        for msgs in reversed(newest):
            for m in msgs:
                kind = m.get("kind")
                if kind == "torque":
                    c0, n = int(m["first_cycle"]), int(m["n"])
                    c = np.arange(c0, c0 + n, dtype=np.int64)
                    sel = (c > torque_last) & (c <= after_cycle)
                    if not sel.any():
                        continue
                    self._tq_cyc.append(c[sel])
                    self._tq_val.append(np.asarray(m["torque_nm"], dtype=np.float64)[sel])
                    t0 = pd.Timestamp(m["time"]).value if m.get("time") else 0
                    cyc_l.append(c[sel])
                    t_l.append(t0 + np.round((c[sel] - c0) * self._cycle_time_s * 1e9)
                               .astype(np.int64))
                elif kind == "hole" and stored_last < int(m["cycle"]) <= after_cycle \
                        and int(m["cycle"]) not in held:
                    self._holes.append(m)
                    held.add(int(m["cycle"]))
                elif kind == "alarm" and stored_last < int(m["cycle"]) <= after_cycle \
                        and (int(m["cycle"]), m.get("detector")) not in alarms:
                    self._alarms.append(m)
        if cyc_l:
            cyc = np.concatenate(cyc_l)
            cyc, first = np.unique(cyc, return_index=True)
            t = np.concatenate(t_l)[first]
            have = np.concatenate(self._cyc) if self._cyc else np.empty(0, dtype=np.int64)
            new = ~np.isin(cyc, have)
            if new.any():
                self._cyc.append(cyc[new])
                self._t.append(t[new])
                self._der.append({})
                self._n += int(new.sum())
                if self._first is None:
                    self._first = int(cyc[new][0])
                self._issues.append(
                    f"cycles {int(cyc[new][0])}-{int(cyc[new][-1])}: restored from "
                    f"{path.name} after a restart (the store missed them); only "
                    f"{self._tq_column} is known there")

    def status(self) -> dict[str, Any]:
        return {"store": self.store_url, "blocks": len(self.blocks),
                "pending_cycles": self._n, "holes": self.holes_written,
                "write_errors": self.write_errors}

    def close(self) -> None:
        self._ingest(final=True)
