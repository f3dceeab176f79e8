"""A small file rewritten every second that readers always see whole (``status.json``).

The usual way, a temporary file renamed over the old one, is atomic but costly on ext4: a
rename that replaces a file makes the file system allocate and start writing the new file's
blocks at once (``auto_da_alloc``, a guard for programs that forget ``fsync``), ~0.1 ms
unloaded and ~0.5 ms on a busy plant worker, once per machine and second. :class:`StatusFile`
keeps two spare files (hard links, ``.status.json.a`` and ``.status.json.b`` beside it): the
new content is written in place into the spare that is *not* the current file, then renamed
over the file name and given its spare name back with a hard link. Readers open either the
old or the new inode, each complete (the rename is atomic), and the file system sees an
overwrite of already allocated blocks instead of a new file (18 us of CPU against 79 us:
``benchmarks/bench_edge_files.py``). Where hard links or the rename over an open file are not
possible (some network and Windows file systems), it falls back to the temporary file and
:func:`os.replace`.

The limit: a spare is rewritten two rounds after it was the file, so a reader that opened the
file and reads it more than one interval later (a process stalled between ``open`` and
``read`` for a second) may read the newer content or, rarely, a torn one. Readers read at
once (``read_status``, the dashboard, ``edge status``) and take an unreadable file as "not
readable now".

Nothing here is durable across a power loss (neither is the temporary-file way without
``fsync``): a status is rewritten a second later.
"""

from __future__ import annotations

import contextlib
import os
from os import PathLike
from pathlib import Path

__all__ = ["StatusFile"]


class StatusFile:
    """Rewrite ``path`` whole, cheaply and atomically for readers.

    Parameters
    ----------
    path : str or path-like
        The file (its directory must exist).

    Examples
    --------
    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> f = StatusFile(d / "status.json")
    >>> f.write(b'{"cycles": 1}'); f.write(b'{"cycles": 2}')
    >>> (d / "status.json").read_bytes()
    b'{"cycles": 2}'
    """

    def __init__(self, path: str | PathLike[str]) -> None:
        self.path = Path(path)
        self._spares = [self.path.with_name(f".{self.path.name}.{s}") for s in "ab"]
        self._next: int | None = None  # the spare to write next (None: not chosen yet)
        self.swapping = True  # False once the fallback is in use

    def _choose(self) -> int:
        """The spare that is not the current file (after a crash either may be)."""
        try:
            cur = os.stat(self.path).st_ino
        except FileNotFoundError:
            return 0
        for k, p in enumerate(self._spares):
            try:
                if os.stat(p).st_ino == cur:
                    return 1 - k
            except FileNotFoundError:
                pass
        return 0

    def write(self, data: bytes) -> None:
        """Replace the file's content with ``data``.

        Raises
        ------
        OSError
            The directory cannot be written (the fallback failed too).
        """
        if self.swapping:
            try:
                self._swap(data)
                return
            except OSError:
                self.swapping = False
                for p in self._spares:
                    with contextlib.suppress(OSError):
                        p.unlink()
        tmp = self.path.with_name(self.path.name + ".tmp")
        tmp.write_bytes(data)
        os.replace(tmp, self.path)

    def _swap(self, data: bytes) -> None:
        if self._next is None:
            self._next = self._choose()
        k = self._next
        spare = self._spares[k]
        # opened each time, not held: a plant worker serves hundreds of machines, each with
        # its queue and sockets, within the process's open-file limit
        fd = os.open(spare, os.O_WRONLY | os.O_CREAT, 0o666)  # the umask applies
        try:
            os.pwrite(fd, data, 0)
            os.ftruncate(fd, len(data))
        finally:
            os.close(fd)
        os.replace(spare, self.path)  # the file is now spare k's inode, complete
        os.link(self.path, spare)  # which keeps its spare name for the round after next
        self._next = 1 - k
