"""Capture4Analysis reader, file access: the documents of a run in a directory or a zip.

A run may span several files chained by ``Footer.FilePathChain``; they sit in one directory
(plain or each zipped) or in one zip archive. :class:`Opener` finds the first document and
resolves the following ones by name; a damaged zip is inflated from its first local header
when ``salvage`` is on. Private to :mod:`cnctwin.iotools.capture4analysis`.
"""

from __future__ import annotations

import io
import re
import struct
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

from cnctwin.exceptions import FormatError, TruncatedFileError

__all__ = ["Opener", "Source", "inflate_damaged_zip"]


@dataclass
class Source:
    """One JSON document of a run: its bytes and where it came from."""

    name: str  # file name (for chain resolution) or zip member name
    label: str  # what error messages show: path or "archive.zip:member.json"
    data: bytes
    salvaged_zip: bool = False


def inflate_damaged_zip(raw: bytes, label: str) -> tuple[str, bytes] | None:
    """Inflate the first local file entry of a damaged zip as far as it goes."""
    pos = raw.find(b"PK\x03\x04")
    if pos < 0 or pos + 30 > len(raw):
        return None
    (_, _, _, method, _, _, _, _, _, n_name, n_extra) = struct.unpack(
        "<IHHHHHIIIHH", raw[pos : pos + 30]
    )
    name = raw[pos + 30 : pos + 30 + n_name].decode("utf-8", "replace")
    start = pos + 30 + n_name + n_extra
    body = raw[start:]
    if method == 0:
        return name, body
    if method != 8:
        return None
    d = zlib.decompressobj(-15)
    out = bytearray()
    step = 1 << 20
    for i in range(0, len(body), step):
        try:
            out += d.decompress(body[i : i + step])
        except zlib.error:
            break
        if d.eof:
            break
    return name, bytes(out)


class Opener:
    """Resolves file names of a chain in a directory or inside one zip archive.

    With ``data`` the document (or zip archive) is already in memory and ``label`` names it;
    chained files are then found only inside that archive.
    """

    def __init__(self, path: Path, *, salvage: bool, issues: list[str],
                 data: bytes | None = None, label: str | None = None) -> None:
        self.path = path
        self.label = str(path) if label is None else label
        self.data = data
        self.salvage = salvage
        self.issues = issues
        self.zip: zipfile.ZipFile | None = None
        self.zip_salvaged: Source | None = None
        is_zip = data[:2] == b"PK" if data is not None else path.suffix.lower() == ".zip"
        if is_zip:
            try:
                self.zip = zipfile.ZipFile(path if data is None else io.BytesIO(data))
            except (zipfile.BadZipFile, OSError) as exc:
                if not salvage:
                    raise TruncatedFileError(
                        f"broken zip archive ({exc}); re-download the file, or read it with "
                        "salvage=True to recover what can be inflated",
                        path=self.label,
                    ) from exc
                raw = path.read_bytes() if data is None else data
                got = inflate_damaged_zip(raw, self.label)
                if got is None:
                    raise TruncatedFileError(
                        f"broken zip archive ({exc}) and no entry could be recovered",
                        path=self.label,
                    ) from exc
                name, member = got
                self.issues.append(
                    f"broken zip archive ({exc}); inflated {len(member)} bytes of entry "
                    f"{name!r} directly from its local header"
                )
                self.zip_salvaged = Source(Path(name).name, f"{self.label}:{name}", member, True)

    def members(self) -> list[str]:
        if self.zip is None:
            return []
        return [i.filename for i in self.zip.infolist() if i.filename.lower().endswith(".json")]

    def first(self) -> Source:
        if self.zip_salvaged is not None:
            return self.zip_salvaged
        if self.zip is None:
            data = self.path.read_bytes() if self.data is None else self.data
            return Source(self.path.name, self.label, data)
        members = self.members()
        if not members:
            raise FormatError(
                "zip archive holds no .json file; expected a Capture4Analysis JSON inside",
                path=self.label,
            )
        start = members[0]
        if len(members) > 1:
            # the chain starts at the member whose footer has no Previous inside this archive
            base = {Path(m).name: m for m in members}
            prev_re = re.compile(rb'"Previous"\s*:\s*(null|"((?:[^"\\]|\\.)*)")')
            starts = []
            for m in members:
                tail = self._read_member(m)[-4096:]
                hit = prev_re.search(tail)
                prev = None if hit is None or hit.group(2) is None else hit.group(2).decode()
                if prev is None or Path(prev).name not in base:
                    starts.append(m)
            if starts:
                start = starts[0]
            if len(starts) > 1:
                self.issues.append(
                    f"zip archive holds {len(starts)} chain starts ({', '.join(starts)}); "
                    f"read the run starting at {start!r} only"
                )
        return Source(Path(start).name, f"{self.label}:{start}", self._read_member(start))

    def _read_member(self, member: str) -> bytes:
        assert self.zip is not None
        try:
            return self.zip.read(member)
        except (zipfile.BadZipFile, zlib.error, OSError, EOFError) as exc:
            raise TruncatedFileError(
                f"broken zip entry {member!r} ({exc}); re-download the archive",
                path=self.label,
            ) from exc

    def next(self, name: str) -> Source | None:
        """The chained file ``name`` (same zip or same directory), or None if absent."""
        bare = Path(name.replace("\\", "/")).name
        if self.zip is not None:
            for m in self.members():
                if Path(m).name == bare:
                    return Source(bare, f"{self.label}:{m}", self._read_member(m))
            return None
        if self.zip_salvaged is not None or self.data is not None:
            return None
        folder = self.path.parent
        for cand in (folder / bare, folder / (bare + ".zip"), folder / (Path(bare).stem + ".zip")):
            if cand.is_file():
                if cand.suffix.lower() == ".zip":
                    sub = Opener(cand, salvage=self.salvage, issues=self.issues)
                    src = sub.first()
                    return src
                return Source(cand.name, str(cand), cand.read_bytes())
        return None

    def close(self) -> None:
        if self.zip is not None:
            self.zip.close()

