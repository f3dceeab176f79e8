"""Capture4Analysis / SINUMERIK Data Recorder JSON files: reader (writer re-exported).

The format (Siemens "Analyze MyWorkpiece /Capture4Analysis" and its successor "SINUMERIK Data
Recorder") is one JSON object per file, ``{"Header": ..., "Payload": [...], "Footer": ...}``,
optionally zipped, and a job run may span several files chained by
``Footer.FilePathChain`` (see ``docs/reference/data-formats.md`` section 1).

* :func:`read_capture4analysis` reads a ``.json`` or ``.zip`` (one or more chained files) into a
  :class:`~cnctwin.recording.Recording`.
* :func:`parse_capture4analysis` parses one document (JSON or zip) held in memory, e.g. a Data
  Recorder MQTT message; :func:`read_capture4analysis` runs the same document parser on each
  file of a chain.
* :class:`Capture4AnalysisWriter` and :func:`write_capture4analysis` live in
  :mod:`cnctwin.iotools.capture4analysis_writer` and are re-exported here.

Reading rules (each repair is written to ``rec.meta.issues``):

* HF columns are matched by ``Address`` (``CURRENT|6``), never by ``Name``; the axis name comes
  from the header's ``Axis``; empty ``Axis`` fields are filled from ``axis_map``; unknown axis
  numbers keep ``CODE|<n>``. Each file of a chain is mapped with its own header.
* The cycle counter is the clock: times come from ``Initial`` and the ``HFTimestamp`` anchors
  (:func:`~cnctwin.recording.cycles_to_time`). Wrap-around is unwrapped, gaps are reported,
  rows are sorted by cycle and duplicate cycles keep the first arrival.
* LF values are aligned by ``HFProbeCounter`` (their ``timestamp`` runs on another clock; it is
  kept in ``meta.attrs["lf_wall_clock"]``).
* Unknown payload keys (``ExternalData``) are kept in ``meta.attrs["payload_other"]``.

The reader is split by topic into private modules: ``_c4a_source`` (files, zip archives,
chains), ``_c4a_state`` (state of a run, counter unwrapping), ``_c4a_header`` (signal list,
slow row conversion), ``_c4a_document`` (one JSON document, truncation salvage),
``_c4a_frames`` (events, LF) and ``_c4a_assemble`` (metadata, time anchors, HF table).
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path
from typing import Any

from cnctwin.exceptions import ConfigError, FormatError
from cnctwin.iotools._c4a_assemble import assemble
from cnctwin.iotools._c4a_document import FilePart, read_document
from cnctwin.iotools._c4a_source import Opener, Source
from cnctwin.iotools._c4a_state import ReadState

# the writer lives in its own module; re-exported here so existing imports keep working
from cnctwin.iotools.capture4analysis_writer import (
    Capture4AnalysisWriter,
    write_capture4analysis,
)
from cnctwin.recording import Recording

__all__ = [
    "Capture4AnalysisWriter",
    "parse_capture4analysis",
    "read_capture4analysis",
    "write_capture4analysis",
]


# ====================================================================== the chain
def _read_run(opener: Opener, reader: ReadState, *, follow_chain: bool, stop_note: str
              ) -> Recording:
    """Read the first document of ``opener`` and, with ``follow_chain``, the files chained to it.

    ``stop_note`` says in ``meta.issues`` why a ``FilePathChain.Next`` was not followed.
    """
    try:
        src: Source | None = opener.first()
        parts: list[FilePart] = []
        files: list[str] = []
        visited: set[str] = set()
        while src is not None:
            visited.add(src.name)
            files.append(src.label)
            part = read_document(reader, src)
            src.data = b""
            parts.append(part)
            chain = (part.footer or {}).get("FilePathChain") or {}
            if len(parts) == 1 and isinstance(chain, dict) and chain.get("Previous"):
                reader.issues.append(
                    f"{part.label} continues a run (Previous {chain['Previous']!r}, Index "
                    f"{chain.get('Index')}); earlier files were not read"
                )
            nxt = chain.get("Next") if isinstance(chain, dict) else None
            if not nxt or not follow_chain:
                if nxt:
                    reader.issues.append(f"run continues in {nxt!r}; not read ({stop_note})")
                break
            if Path(str(nxt)).name in visited:
                reader.issues.append(f"file chain loops back to {nxt!r}; stopped there")
                break
            src = opener.next(str(nxt))
            if src is None:
                reader.issues.append(
                    f"run continues in {nxt!r}, which is not in the same "
                    f"{'zip' if opener.zip is not None else 'directory'}; recording is incomplete"
                )
                reader.partial = True
    finally:
        opener.close()
    return assemble(parts, reader, files)


def _check_axis_map(axis_map: Any) -> None:
    if axis_map is not None and not isinstance(axis_map, dict):
        raise ConfigError("axis_map must be a dict {axis number: axis name}")


# ====================================================================== public reader
def parse_capture4analysis(
    data: bytes,
    *,
    source: str = "<bytes>",
    axis_map: dict[int, str] | None = None,
    salvage: bool = False,
) -> Recording:
    """Parse one Capture4Analysis / SINUMERIK Data Recorder document held in memory.

    Parameters
    ----------
    data : bytes
        The JSON document, or a zip archive holding it (``PK`` signature; Data Recorder MQTT
        messages may be zipped). Of an archive with several chained members the chain start
        is parsed.
    source : str, default ``"<bytes>"``
        Where the bytes came from (file name, MQTT topic); used in error messages,
        ``meta.issues`` and ``meta.source_files`` (``"<source>:<member>"`` for a zip).
    axis_map : dict, optional
        Axis number -> axis name for empty ``Axis`` fields; default
        :data:`cnctwin.signals.DEFAULT_AXIS_MAP`.
    salvage : bool, default False
        Keep what can be read from damaged input instead of raising (see
        :func:`read_capture4analysis`).

    Returns
    -------
    Recording
        What :func:`read_capture4analysis` returns for a file with these bytes and
        ``follow_chain=False``: a ``Footer.FilePathChain.Next`` is not followed, only noted in
        ``meta.issues``.

    Raises
    ------
    ConfigError
        ``data`` is not bytes (pass a path to :func:`read_capture4analysis` instead).
    FormatError
        Invalid JSON, missing Header, wrong value types; ``path`` is ``source``.
    TruncatedFileError
        The JSON ends early or the zip is broken (and ``salvage`` is False).

    Notes
    -----
    :func:`read_capture4analysis` parses each file of a chain with the same document parser;
    this entry point skips the file system, so a stream (MQTT message, HTTP body) needs no
    temporary file.
    """
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise ConfigError(
            f"data must be bytes, not {type(data).__name__}; to read a file pass its path to "
            "read_capture4analysis"
        )
    _check_axis_map(axis_map)
    reader = ReadState(axis_map=axis_map, salvage=salvage)
    opener = Opener(Path(source), salvage=salvage, issues=reader.issues, data=bytes(data),
                     label=source)
    return _read_run(opener, reader, follow_chain=False,
                     stop_note="one document parsed; read_capture4analysis follows chains")


def read_capture4analysis(
    path: str | PathLike[str],
    *,
    axis_map: dict[int, str] | None = None,
    salvage: bool = False,
    follow_chain: bool = True,
) -> Recording:
    """Read a Capture4Analysis / SINUMERIK Data Recorder recording.

    Parameters
    ----------
    path : str or path-like
        A ``.json`` file or a ``.zip`` holding one or more chained JSON files.
    axis_map : dict, optional
        Axis number -> axis name used to repair empty ``Axis`` fields in the header; default
        :data:`cnctwin.signals.DEFAULT_AXIS_MAP` (``{1: "X1", ..., 6: "SP1"}``).
    salvage : bool, default False
        Keep what can be read from damaged input (truncated JSON, rows of the wrong length,
        non-numeric values, a broken zip) instead of raising; sets ``rec.meta.partial`` and
        describes what was lost in ``rec.meta.issues``.
    follow_chain : bool, default True
        Follow ``Footer.FilePathChain.Next`` to the following files of the run (same
        directory or same zip) and concatenate them.

    Returns
    -------
    Recording
        HF table indexed by the unwrapped cycle counter with ``CODE|AXIS`` columns, LF values,
        block/call events and metadata (header fields in ``meta.attrs``).

    Raises
    ------
    FormatError
        Invalid JSON, missing Header, wrong value types, rows of the wrong length; the message
        names the file and the position (byte offset or ``Payload[i].HFData[j]``).
    TruncatedFileError
        The JSON ends early or the zip is broken (and ``salvage`` is False).

    Notes
    -----
    Time of cycle :math:`c` is :math:`t = t_0 + (c - c_0)\\,T_c` with the cycle time
    :math:`T_c` = ``CycleTimeMs`` and :math:`t_0 - c_0 T_c` the median over the ``Initial`` and
    ``HFTimestamp`` anchors (:func:`cnctwin.recording.cycles_to_time`).

    The file is scanned once for its structure and each payload entry is parsed separately
    with orjson, so the Python objects of one entry at a time are alive; HF rows go straight
    into a preallocated column-major float64 array.
    """
    p = Path(path)
    if not p.is_file():
        raise FormatError("file not found", path=str(p))
    _check_axis_map(axis_map)
    reader = ReadState(axis_map=axis_map, salvage=salvage)
    opener = Opener(p, salvage=salvage, issues=reader.issues)
    return _read_run(opener, reader, follow_chain=follow_chain, stop_note="follow_chain=False")

