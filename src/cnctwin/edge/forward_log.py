"""Store-and-forward as an append-only log: the MQTT sink's outbox (``outbox/`` in the state
directory).

The same queue as :class:`~cnctwin.edge.forward.ForwardQueue` (bounded, ordered, on disk,
acknowledged messages removed, the oldest dropped and counted beyond the bound), kept as
records appended to segment files instead of rows of a SQLite table. A live plant appends one
chunk's results and removes the previous chunk's acknowledged ones every machine-second; in
SQLite that is a transaction (~0.35 ms of CPU per machine-second on a busy 2-vCPU worker,
5-6 % of a machine's whole cost), here one ``writev`` of the records (BENCHMARKS.md,
session 27).

Records (little-endian): a 20-byte header ``magic (u32), kind (u8), 0, topic length (u16),
body length (u32), value (u64)``, the body, and the CRC-32 of header and body (u32):

* ``MSG``: value the message id, body the topic (UTF-8) then the payload;
* ``DONE``: body the ids acknowledged (u64 each);
* ``DROP``: value the id through which the oldest were dropped, body the drop count (u64);
* ``STATE``: the first record of every segment after the first: value the id below which
  every message is done, body the drop count and the ids above it already acknowledged. A
  segment is deleted once every message in it is done; the newest segment, which holds the
  current state, never is.

Segments are named by the id of their first message (``<id>.log``, 20 digits) and closed
with an ``fsync`` once they reach ``segment_bytes``. Opening the log reads every record
(the CRC of each checked); a record cut off or damaged at the end of the newest segment (a
crash in the middle of a write) is cut away and named in :attr:`ForwardLog.issues`; the
messages before it are kept. Like the SQLite queue in WAL mode with ``synchronous=NORMAL``,
what was written survives a crash of the process at once and a power loss once the system
wrote it back (a closed segment: at once).

Delivery stays at least once: a message whose acknowledgement was not yet written may be
sent again after a restart; its ``seq`` lets the consumer drop the repeat.
"""

from __future__ import annotations

import bisect
import os
import struct
import zlib
from array import array
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path

from cnctwin.edge._files import sync_dir
from cnctwin.edge.forward import QueueCounts
from cnctwin.exceptions import ConfigError

__all__ = ["ForwardLog"]

_MAGIC = 0x424F5443  # b"CTOB"
_HEAD = struct.Struct("<IBxHIQ")
_CRC = struct.Struct("<I")
MSG, DONE, DROP, STATE = 1, 2, 3, 4
_SUFFIX = ".log"


@dataclass
class _Segment:
    """One segment file: where its messages' records are."""

    path: Path
    first_id: int  # id of its first message (its name)
    starts: array = field(default_factory=lambda: array("q"))  # record offsets, by id
    ends: array = field(default_factory=lambda: array("q"))
    size: int = 0

    @property
    def last_id(self) -> int:
        """Id of its last message (first_id - 1: none)."""
        return self.first_id + len(self.starts) - 1


def _record(kind: int, value: int, body: bytes | memoryview = b"", topic_len: int = 0,
            extra: bytes = b"") -> list[bytes]:
    """The pieces of one record (header, body, ``extra`` appended to the body, CRC)."""
    head = _HEAD.pack(_MAGIC, kind, topic_len, len(body) + len(extra), value)
    crc = zlib.crc32(extra, zlib.crc32(body, zlib.crc32(head)))
    return [head, bytes(body), extra, _CRC.pack(crc)] if extra else \
        [head, bytes(body), _CRC.pack(crc)]


def _ids(values: list[int] | set[int]) -> bytes:
    return array("Q", sorted(values)).tobytes()


def _u64(body: memoryview) -> array:
    out = array("Q")
    out.frombytes(body)
    return out


class ForwardLog(QueueCounts):
    """Bounded FIFO of ``(topic, payload)`` on disk, as an append-only log of segments.

    The interface of :class:`~cnctwin.edge.forward.ForwardQueue`.

    Parameters
    ----------
    path : str or path-like
        Directory of the segment files (created).
    max_messages : int, default 200000
        Bound; the oldest are dropped (and counted) beyond it.
    segment_bytes : int, default 16 MiB
        Size at which a segment is closed (synced) and a new one begun; a segment is deleted
        once all its messages are acknowledged or dropped.
    """

    def __init__(self, path: str | PathLike[str], *, max_messages: int = 200_000,
                 segment_bytes: int = 16 << 20) -> None:
        if max_messages < 1:
            raise ConfigError(f"max_messages must be >= 1, not {max_messages}")
        if segment_bytes < 1:
            raise ConfigError(f"segment_bytes must be >= 1, not {segment_bytes}")
        self.path = Path(path)
        self.path.mkdir(parents=True, exist_ok=True)
        self.max_messages = int(max_messages)
        self.segment_bytes = int(segment_bytes)
        self.issues: list[str] = []
        self._segs: list[_Segment] = []
        self._last_id = 0  # the newest id given
        self._done_through = 0  # every id at or below it acknowledged or dropped
        self._acked: set[int] = set()  # acknowledged ids above _done_through
        self._dropped = 0
        self._fd: int | None = None  # the newest segment, appended to
        self._read: tuple[int, int] | None = None  # (first id, fd) of an older one read
        self._open()

    # ------------------------------------------------------------------ counts
    def __len__(self) -> int:
        return self._last_id - self._done_through - len(self._acked)

    # ------------------------------------------------------------------ writing
    def put_many(self, items: list[tuple[str, bytes]], *,
                 remove: list[int] | None = None) -> list[int]:
        """Append messages in order, and remove acknowledged ones, in one write.

        Parameters
        ----------
        items : list of (str, bytes)
            ``(topic, payload)`` to append.
        remove : list of int, optional
            Ids of acknowledged messages (an id already removed, dropped or not yet given is
            ignored).

        Returns
        -------
        list of int
            The ids of the appended messages, in order (those the bound dropped at once
            included; :attr:`dropped` counts the drops).
        """
        if not items and not remove:
            return []
        if items and self._seg_full():
            self._roll()
        seg = self._segs[-1]
        done = self._new_acks(remove) if remove else []
        self._acked.update(done)  # (taken back if the write fails)
        try:
            parts: list[bytes] = _record(DONE, 0, _ids(done)) if done else []
            first = self._last_id + 1
            ids = list(range(first, first + len(items)))
            starts: list[int] = []
            ends: list[int] = []
            off = seg.size + sum(len(p) for p in parts)
            for i, (topic, payload) in zip(ids, items, strict=True):
                t = topic.encode("utf-8")
                rec = _record(MSG, i, t, len(t), payload)
                starts.append(off)
                off += sum(len(p) for p in rec)
                ends.append(off)
                parts += rec
            drop_through, drops = self._drops(len(items))
            if drops:
                parts += _record(DROP, drop_through, struct.pack("<Q", self._dropped + drops))
            self._write(parts)
        except BaseException:
            self._acked.difference_update(done)
            raise
        # written: now the state follows
        seg.starts.extend(starts)
        seg.ends.extend(ends)
        self._last_id += len(items)
        if drops:
            self._acked = {i for i in self._acked if i > drop_through}
            self._done_through = drop_through
            self._dropped += drops
        self._advance()
        return ids

    def continue_counts(self, *, sent: int, dropped: int) -> None:
        """Go on from another queue's counts (an older outbox moved into this empty log):
        the ids continue after its ``sent + dropped`` messages, so that :attr:`sent` and
        :attr:`dropped` go on from its figures.

        Raises
        ------
        ConfigError
            The log already holds messages.
        """
        if self._last_id or len(self._segs) != 1 or self._segs[0].size:
            raise ConfigError(f"the outbox {self.path} is not empty: its counts stay its own")
        if sent < 0 or dropped < 0:
            raise ConfigError(f"counts must be >= 0, not sent {sent}, dropped {dropped}")
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None
        self._segs.pop().path.unlink(missing_ok=True)
        self._last_id = self._done_through = sent + dropped
        self._dropped = dropped
        self._begin(self._last_id + 1)
        self._write(_record(STATE, self._done_through, struct.pack("<Q", dropped)))

    def remove(self, ids: list[int]) -> None:
        """Remove acknowledged messages."""
        if ids:
            self.put_many([], remove=ids)

    def _new_acks(self, ids: list[int]) -> list[int]:
        acked = self._acked
        lo, hi = self._done_through, self._last_id
        return sorted({i for i in ids if lo < i <= hi and i not in acked})

    def _drops(self, n_new: int) -> tuple[int, int]:
        """(id through which the oldest are dropped, how many of them were queued) to keep
        the bound after ``n_new`` more messages."""
        excess = len(self) + n_new - self.max_messages
        if excess <= 0:
            return self._done_through, 0
        i, dropped = self._done_through, 0
        while dropped < excess:
            i += 1
            if i not in self._acked:
                dropped += 1
        return i, dropped

    def _advance(self) -> None:
        """Move the done mark over the acknowledged ids right above it; delete the segments
        whose messages are all done (never the newest, which holds the state)."""
        acked, d = self._acked, self._done_through
        while d + 1 in acked:
            d += 1
            acked.discard(d)
        self._done_through = d
        while len(self._segs) > 1 and self._segs[0].last_id <= d:
            seg = self._segs.pop(0)
            if self._read is not None and self._read[0] == seg.first_id:
                os.close(self._read[1])
                self._read = None
            seg.path.unlink(missing_ok=True)

    def _write(self, parts: list[bytes]) -> None:
        if self._fd is None:
            raise ConfigError(f"the outbox {self.path} is closed")
        seg = self._segs[-1]
        total = sum(len(p) for p in parts)
        try:
            n = os.writev(self._fd, parts)
            if n < total:  # (a regular file writes it all, or fails)
                data = b"".join(parts)
                while n < total:
                    n += os.write(self._fd, data[n:])
        except OSError:
            # (a full disk): no part of a record may stay, or the next ones would follow
            # bytes that are no record and be cut away with them on the next start
            os.ftruncate(self._fd, seg.size)
            raise
        seg.size += total

    def _seg_full(self) -> bool:
        seg = self._segs[-1]  # (one with no message keeps its name: it is not rolled)
        return seg.size >= self.segment_bytes and len(seg.starts) > 0

    def _roll(self) -> None:
        """Close the newest segment (synced) and begin one with the state."""
        if self._fd is not None:
            os.fsync(self._fd)
            os.close(self._fd)
            self._fd = None
        self._begin(self._last_id + 1)
        body = struct.pack("<Q", self._dropped) + _ids(self._acked)
        self._write(_record(STATE, self._done_through, body))
        self._advance()

    def _begin(self, first_id: int) -> None:
        path = self.path / f"{first_id:020d}{_SUFFIX}"
        self._fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_APPEND | os.O_TRUNC, 0o644)
        self._segs.append(_Segment(path, first_id))
        sync_dir(self.path)  # the new name survives a power loss

    # ------------------------------------------------------------------ reading
    def peek(self, n: int, *, after_id: int = 0) -> list[tuple[int, str, bytes]]:
        """The oldest ``n`` messages with id > ``after_id``: ``(id, topic, payload)``."""
        out: list[tuple[int, str, bytes]] = []
        i = max(after_id, self._done_through)
        while len(out) < n and i < self._last_id:
            i += 1
            if i in self._acked:
                continue
            out.append((i, *self._message(i)))
        return out

    def _message(self, i: int) -> tuple[str, bytes]:
        segs = self._segs
        k = bisect.bisect_right([s.first_id for s in segs], i) - 1
        seg = segs[k]
        j = i - seg.first_id
        start, end = seg.starts[j], seg.ends[j]
        if k == len(segs) - 1:
            fd = self._fd
        else:
            if self._read is None or self._read[0] != seg.first_id:
                if self._read is not None:
                    os.close(self._read[1])
                self._read = (seg.first_id, os.open(seg.path, os.O_RDONLY))
            fd = self._read[1]
        assert fd is not None
        rec = os.pread(fd, end - start, start)
        _, _, tlen, _, _ = _HEAD.unpack_from(rec)
        h = _HEAD.size
        return rec[h:h + tlen].decode("utf-8"), rec[h + tlen:-_CRC.size]

    # ------------------------------------------------------------------ opening
    def _open(self) -> None:
        names = sorted((p for p in self.path.glob(f"*{_SUFFIX}") if p.stem.isdigit()),
                       key=lambda p: int(p.stem))
        for k, p in enumerate(names):
            self._load(p, newest=k == len(names) - 1)
        if not self._segs:
            self._begin(1)
        else:
            self._fd = os.open(self._segs[-1].path, os.O_RDWR | os.O_APPEND)
        self._advance()

    def _load(self, path: Path, *, newest: bool) -> None:
        data = path.read_bytes()
        seg = _Segment(path, int(path.stem))
        if seg.first_id != self._last_id + 1 and self._segs:
            self.issues.append(f"{path}: its first id {seg.first_id} does not follow "
                               f"{self._last_id}: the ids between are counted as dropped")
            self._dropped += seg.first_id - self._last_id - 1
        if not self._segs:
            self._done_through = seg.first_id - 1  # the ids before it were deleted: done
        self._last_id = seg.first_id - 1
        off, h, c = 0, _HEAD.size, _CRC.size
        while off < len(data):
            bad = ""
            if len(data) - off < h + c:
                bad = "a record cut off"
            else:
                magic, kind, _, blen, value = _HEAD.unpack_from(data, off)
                end = off + h + blen + c
                if magic != _MAGIC or end > len(data):
                    bad = "a record cut off" if magic == _MAGIC else "bytes that are no record"
                elif zlib.crc32(memoryview(data)[off:end - c]) != \
                        _CRC.unpack_from(data, end - c)[0]:
                    bad = "a record whose checksum does not match"
            if bad:
                self.issues.append(
                    f"{path}: {bad} at byte {off} of {len(data)} (a write cut off by a "
                    f"crash); the {len(data) - off} bytes from there were removed, the "
                    "messages before them kept")
                if newest:
                    os.truncate(path, off)
                data = data[:off]
                break
            body = memoryview(data)[off + h:end - c]
            if kind == MSG and value != self._last_id + 1:
                self.issues.append(
                    f"{path}: message {value} at byte {off} where {self._last_id + 1} was "
                    f"due; the {len(data) - off} bytes from there are not read")
                data = data[:off]
                break
            if kind == MSG:
                seg.starts.append(off)
                seg.ends.append(end)
                self._last_id = value
            elif kind == DONE:
                self._acked.update(i for i in _u64(body) if i > self._done_through)
            elif kind == DROP:
                self._done_through = max(self._done_through, value)
                self._dropped = struct.unpack_from("<Q", body)[0]
                self._acked = {i for i in self._acked if i > self._done_through}
            elif kind == STATE:
                self._done_through = max(self._done_through, value)
                self._dropped = struct.unpack_from("<Q", body)[0]
                self._acked = {i for i in _u64(body[8:]) if i > self._done_through}
            off = end
        seg.size = len(data)
        self._segs.append(seg)  # (the done mark moves over the acknowledged in _open)

    def close(self) -> None:
        """Close the files (they stay)."""
        for fd in (self._fd, self._read[1] if self._read else None):
            if fd is not None:
                os.close(fd)
        self._fd = self._read = None

