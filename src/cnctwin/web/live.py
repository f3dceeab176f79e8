"""Live view: the edge runtime's ``results.jsonl`` tailed into Server-Sent Events.

``cnctwin edge run ... --out DIR`` appends every result message (``torque``, ``hole_start``,
``hole``, ``alarm``, ``gap``, ``status``; docs/edge.md) as one JSON line to
``DIR/results.jsonl`` and rewrites ``DIR/status.json`` every second. The dashboard follows that
file like ``tail -f``: each complete new line becomes one SSE event named after the message
kind, with the line as its data. A partly written last line waits for its newline; a file that
shrinks (a new run) is followed from its start again.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
from collections.abc import AsyncIterator, Iterable
from pathlib import Path
from typing import IO, Any

from cnctwin.exceptions import ConfigError

__all__ = ["LiveSource", "directory_labels", "sse_event", "tail_lines"]


def sse_event(data: str, *, event: str | None = None, event_id: str | None = None) -> str:
    """One Server-Sent Event (``event:``/``id:``/``data:`` lines, blank line).

    Parameters
    ----------
    data : str
        Event data (one line per ``data:``).
    event : str, optional
        Event name.
    event_id : str, optional
        Event id.

    Returns
    -------
    str
    """
    head = ""
    if event:
        head += f"event: {event}\n"
    if event_id is not None:
        head += f"id: {event_id}\n"
    body = "".join(f"data: {line}\n" for line in data.splitlines() or [""])
    return head + body + "\n"


async def tail_lines(path: Path, *, from_start: bool, poll_s: float = 0.2,
                     ) -> AsyncIterator[str]:
    """Complete lines appended to ``path``, forever (from its start or from its end).

    A missing file is waited for; a file that shrinks is read again from the start; a file
    that is rotated (renamed and replaced by a new one, ``JsonLinesSink(rotate_bytes=...)``) is
    read to its end through the open handle before the new file is followed from its start,
    so no line is skipped across a rotation.

    Parameters
    ----------
    path : path-like
        The file.
    from_start : bool
        Read what the file holds first; else only what is appended.
    poll_s : float, default 0.2
        Poll interval [s].
    """
    f: IO[bytes] | None = None
    buf = b""
    started = False

    def lines_of(chunk: bytes) -> list[str]:
        nonlocal buf
        buf += chunk
        *lines, buf = buf.split(b"\n")
        return [ln.decode("utf-8", errors="replace") for ln in lines if ln.strip()]

    try:
        while True:
            if f is None:
                try:
                    f = path.open("rb")
                except FileNotFoundError:
                    started = True  # created later: read it from its start
                    await asyncio.sleep(poll_s)
                    continue
                if not started and not from_start:
                    f.seek(0, os.SEEK_END)
                started = True
            chunk = f.read()
            if chunk:
                for line in lines_of(chunk):
                    yield line
                continue
            try:
                st: os.stat_result | None = os.stat(path)
            except FileNotFoundError:
                st = None
            if st is not None and st.st_ino != os.fstat(f.fileno()).st_ino:
                # rotated: what was written to the old file before the rename is read above
                # (a last read here closes the race), then the new file from its start
                for line in lines_of(f.read()):
                    yield line
                f.close()
                f, buf = None, b""
                continue
            if st is not None and st.st_size < f.tell():  # truncated: a new run
                f.seek(0)
                buf = b""
                continue
            await asyncio.sleep(poll_s)
    finally:
        if f is not None:
            f.close()


def directory_labels(paths: Iterable[str | os.PathLike[str]]) -> dict[str, Path]:
    """A label for each edge state directory: the machine its ``status.json`` names (the
    ``--machine`` of the run), else its folder name (a folder with a generic name such as
    ``state`` or ``out`` with its parent's: ``mill-7/state``); primed when two share one.

    Parameters
    ----------
    paths : iterable of path-like
        State directories (``cnctwin edge run --out DIR``) or their ``results.jsonl``.

    Returns
    -------
    dict
        Label -> path, in the given order.
    """
    out: dict[str, Path] = {}
    for item in paths:
        p = Path(item)
        d = p.parent if p.suffix.lower() == ".jsonl" else p
        named = LiveSource(d).status().get("machine")  # the --machine of the run
        label = named.strip() if isinstance(named, str) and named.strip() else _folder_label(d)
        while label in out:  # two state directories of one name in different folders
            label += "'"
        out[label] = p
    return out


_GENERIC = {"state", "out", "edge", "output", "results", "run", "data", "live", "tmp"}


def _folder_label(d: Path) -> str:
    name = d.name or str(d)
    if name.lower() in _GENERIC and d.parent.name:
        return f"{d.parent.name}/{name}"
    return name


class LiveSource:
    """The state directory of an edge run (``cnctwin edge run --out DIR``).

    Parameters
    ----------
    path : path-like
        The directory (holding ``results.jsonl``/``status.json``) or the JSON lines file.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        p = Path(path)
        if p.suffix.lower() == ".jsonl":
            self.results = p
            self.directory = p.parent
        else:
            self.directory = p
            self.results = p / "results.jsonl"
        if not self.directory.exists():
            raise ConfigError(f"live directory {self.directory} does not exist; give the --out "
                              "DIR of `cnctwin edge run` (it may be started after the dashboard, "
                              "but the directory must exist)")

    def status(self) -> dict[str, Any]:
        """The last ``status.json`` of the run (empty with a note when there is none yet)."""
        f = self.directory / "status.json"
        try:
            doc: dict[str, Any] = json.loads(f.read_text(encoding="utf-8"))
        except FileNotFoundError:
            return {"note": f"no {f.name} yet in {self.directory} (is `cnctwin edge run` "
                            "running with this --out?)", "results": str(self.results)}
        except json.JSONDecodeError as exc:  # written atomically; still say what happened
            return {"note": f"{f} is not valid JSON: {exc}", "error": True}
        except (OSError, UnicodeDecodeError) as exc:
            return {"note": f"{f} cannot be read: {exc}", "error": True}
        if not isinstance(doc, dict):
            return {"note": f"{f} holds a JSON {type(doc).__name__}, not the runtime's status "
                            "object (written by another program?)", "error": True}
        doc["results"] = str(self.results)
        return doc

    async def events(self, *, from_start: bool = False, limit: int | None = None,
                     kinds: set[str] | None = None, poll_s: float = 0.2,
                     heartbeat_s: float = 15.0, until_finished: bool = False
                     ) -> AsyncIterator[str]:
        """SSE events of the new result lines (all kinds, or only ``kinds``).

        Each event is named after the message ``kind`` and carries the line as data; its id is
        the message ``seq``. ``limit`` ends the stream after that many events with an ``end``
        event (tests, one-shot clients: a browser's EventSource would otherwise reconnect and
        replay); so does ``until_finished`` once the run's final status (``state``
        ``finished``) is the newest line (the end event then says ``"finished": true``). A
        comment line is sent every ``heartbeat_s`` without data so proxies keep the
        connection.
        """
        n = 0
        finished = False
        lines = tail_lines(self.results, from_start=from_start, poll_s=poll_s)
        pending: asyncio.Task[str] | None = None
        try:
            while limit is None or n < limit:
                if pending is None:
                    pending = asyncio.ensure_future(lines.__anext__())
                done, _ = await asyncio.wait(
                    {pending}, timeout=min(heartbeat_s, 2 * poll_s) if finished else heartbeat_s)
                if not done:
                    if finished:  # the run's last line was its final status: nothing follows
                        break
                    yield ": keep-alive\n\n"
                    continue
                line = pending.result()
                pending = None
                try:
                    msg = json.loads(line)
                    kind = str(msg.get("kind", "message"))
                    seq = msg.get("seq")
                except (json.JSONDecodeError, AttributeError):
                    kind, seq = "invalid", None
                finished = until_finished and kind == "status" and \
                    isinstance(msg, dict) and msg.get("state") == "finished"
                if kinds is not None and kind not in kinds:
                    continue
                n += 1
                yield sse_event(line, event=kind, event_id=None if seq is None else str(seq))
            yield sse_event(json.dumps({"events": n, "finished": finished}), event="end")
        finally:
            # the client went away: the tail generator may be inside __anext__ in the pending
            # task; cancel that task and let it finish before closing the generator, else
            # aclose() raises "asynchronous generator is already running"
            if pending is not None:
                pending.cancel()
                with contextlib.suppress(asyncio.CancelledError, StopAsyncIteration):
                    await pending
            await lines.aclose()  # type: ignore[attr-defined]
