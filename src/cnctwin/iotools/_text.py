"""Reading a whole text file for the CSV readers, with the errors they share."""

from __future__ import annotations

from pathlib import Path

from cnctwin.exceptions import FormatError


def read_utf8_text(path: Path) -> str:
    """The file's text (UTF-8, a byte-order mark dropped).

    Raises
    ------
    FormatError
        ``file not found``, or ``not UTF-8 text`` naming the byte where decoding failed.
    """
    if not path.exists():
        raise FormatError("file not found", path=str(path))
    try:
        return path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise FormatError(f"not UTF-8 text ({exc.reason})", path=str(path),
                          position=f"byte {exc.start}") from None
