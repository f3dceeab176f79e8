"""Format detection behind :func:`cnctwin.read_recording`."""

from __future__ import annotations

from os import PathLike
from pathlib import Path

from cnctwin.exceptions import FormatError
from cnctwin.recording import Recording

__all__ = ["read_recording"]


def read_recording(path: str | PathLike[str], *, salvage: bool = False) -> Recording:
    """Open any supported recording, detecting its format from name and content.

    Parameters
    ----------
    path : str or path-like
        The file (or the first file of a chained Capture4Analysis run).
    salvage : bool, default False
        Keep what can be read from damaged input and mark the recording partial
        (``rec.meta.partial``) instead of raising.

    Returns
    -------
    Recording

    Raises
    ------
    FormatError
        If the format is not recognised or the file is damaged (and ``salvage`` is False).
    """
    p = Path(path)
    if not p.exists():
        raise FormatError("file not found", path=str(p))
    raise FormatError(
        "format not recognised (no reader registered yet)", path=str(p)
    )
