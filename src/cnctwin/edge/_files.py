"""File-system helpers shared by the edge's on-disk state (checkpoint slots, the outbox log)."""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

__all__ = ["sync_dir"]


def sync_dir(path: Path) -> None:
    """``fsync`` the directory ``path``: a file just created in it keeps its name after a
    power loss (nothing on a file system without directory sync)."""
    with contextlib.suppress(OSError):
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
