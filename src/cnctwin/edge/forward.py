"""Store-and-forward: a bounded, ordered, on-disk queue of outgoing messages (SQLite).

Every result message is first appended to the queue (one SQLite file in the state
directory) and removed only when the broker has acknowledged it (MQTT QoS 1 PUBACK). While the
broker is unreachable messages accumulate on disk; when it is back they are re-sent oldest
first. The queue is bounded (``max_messages``): when full, the oldest messages are deleted and
*counted* (``dropped``, persisted in the file), and the status message reports the count, so
nothing disappears silently. Delivery is at-least-once: a message sent just before a
connection loss may arrive twice; its ``seq`` lets the consumer drop the repeat.

The file survives a restart of the runtime (messages queued before a power loss are sent
after it). SQLite is in the standard library; WAL mode keeps appends cheap.
"""

from __future__ import annotations

import sqlite3
from os import PathLike
from pathlib import Path

from cnctwin.exceptions import ConfigError

__all__ = ["ForwardQueue", "QueueCounts"]

_SCHEMA = """
CREATE TABLE IF NOT EXISTS outbox (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    topic TEXT NOT NULL,
    payload BLOB NOT NULL
);
CREATE TABLE IF NOT EXISTS counters (name TEXT PRIMARY KEY, value INTEGER NOT NULL);
INSERT OR IGNORE INTO counters VALUES ('dropped', 0), ('enqueued', 0), ('sent', 0);
"""
# only 'dropped' is kept up to date; 'enqueued' and 'sent' are derived (ForwardQueue.__init__)
# and their rows stay for the versions before that, which read them


class QueueCounts:
    """The counts of a store-and-forward queue (:class:`ForwardQueue`,
    :class:`~cnctwin.edge.forward_log.ForwardLog`): ids are given in order from 1, never
    reused; what was appended is sent, dropped or still queued."""

    _last_id: int
    _dropped: int

    def __len__(self) -> int:  # messages queued
        raise NotImplementedError

    @property
    def dropped(self) -> int:
        """Messages deleted unsent because the bound was hit (over the queue's life)."""
        return self._dropped

    @property
    def enqueued(self) -> int:
        """Messages ever appended (the newest id)."""
        return self._last_id

    @property
    def sent(self) -> int:
        """Messages acknowledged and removed."""
        return self._last_id - self._dropped - len(self)


class ForwardQueue(QueueCounts):
    """Bounded FIFO of ``(topic, payload)`` on disk.

    Parameters
    ----------
    path : str or path-like
        SQLite file (created with its directory).
    max_messages : int, default 200000
        Bound; the oldest are dropped (and counted) beyond it.
    """

    def __init__(self, path: str | PathLike[str], *, max_messages: int = 200_000) -> None:
        if max_messages < 1:
            raise ConfigError(f"max_messages must be >= 1, not {max_messages}")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.max_messages = int(max_messages)
        self._db = sqlite3.connect(str(self.path), isolation_level=None,
                                   check_same_thread=False)
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute("PRAGMA synchronous=NORMAL")
        self._db.executescript(_SCHEMA)
        self._len = int(self._db.execute("SELECT count(*) FROM outbox").fetchone()[0])
        # AUTOINCREMENT keeps the largest id ever given (never reused): the messages ever
        # appended; sent = appended - dropped - queued. Only the drops are a counter of their
        # own, so a transaction touches the queue's pages alone (no counter page per chunk).
        row = self._db.execute("SELECT seq FROM sqlite_sequence WHERE name = 'outbox'"
                               ).fetchone()
        self._last_id = int(row[0]) if row else 0
        self._dropped = int(self._db.execute("SELECT value FROM counters WHERE name = "
                                             "'dropped'").fetchone()[0])

    def __len__(self) -> int:
        return self._len

    def put_many(self, items: list[tuple[str, bytes]], *,
                 remove: list[int] | None = None) -> list[int]:
        """Append messages in order, and delete acknowledged ones, in one transaction.

        Parameters
        ----------
        items : list of (str, bytes)
            ``(topic, payload)`` to append.
        remove : list of int, optional
            Ids of acknowledged messages to delete in the same transaction (one commit per
            chunk of results instead of two).

        Returns
        -------
        list of int
            The ids of the appended messages, in order (those the bound dropped at once
            included; :attr:`dropped` counts the drops).
        """
        if not items and not remove:
            return []
        db = self._db
        db.execute("BEGIN")
        drop = 0
        first = self._last_id + 1  # one writer: the ids are ours to give, consecutive
        ids = list(range(first, first + len(items)))
        n0 = self._len
        try:
            if remove:
                self._delete(remove)
            if items:
                db.executemany("INSERT INTO outbox (id, topic, payload) VALUES (?, ?, ?)",
                               [(i, t, p) for i, (t, p) in zip(ids, items, strict=True)])
                self._len += len(items)
                drop = max(self._len - self.max_messages, 0)
                if drop:
                    db.execute("DELETE FROM outbox WHERE id IN (SELECT id FROM outbox ORDER "
                               "BY id LIMIT ?)", (drop,))
                    db.execute("UPDATE counters SET value = value + ? WHERE name = "
                               "'dropped'", (drop,))
                    self._len -= drop
            db.execute("COMMIT")
        except BaseException:
            db.execute("ROLLBACK")
            self._len = n0
            raise
        self._dropped += drop
        self._last_id += len(items)
        return ids

    def peek(self, n: int, *, after_id: int = 0) -> list[tuple[int, str, bytes]]:
        """The oldest ``n`` messages with id > ``after_id``: ``(id, topic, payload)``."""
        rows = self._db.execute("SELECT id, topic, payload FROM outbox WHERE id > ? "
                                "ORDER BY id LIMIT ?", (after_id, n)).fetchall()
        return [(int(i), str(t), bytes(p)) for i, t, p in rows]

    def _delete(self, ids: list[int]) -> None:
        cur = self._db.executemany("DELETE FROM outbox WHERE id = ?", [(i,) for i in ids])
        self._len -= cur.rowcount if cur.rowcount >= 0 else len(ids)

    def remove(self, ids: list[int]) -> None:
        """Delete acknowledged messages."""
        if not ids:
            return
        db = self._db
        db.execute("BEGIN")
        n0 = self._len
        try:
            self._delete(ids)
            db.execute("COMMIT")
        except BaseException:
            db.execute("ROLLBACK")
            self._len = n0
            raise

    def close(self) -> None:
        """Close the file."""
        self._db.close()
