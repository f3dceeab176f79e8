"""Format detection behind :func:`cnctwin.read_recording`.

Readers are imported lazily (``importlib``) inside the dispatch, so one missing or broken
reader module gives a clear :class:`~cnctwin.exceptions.FormatError` for that format only.
"""

from __future__ import annotations

import importlib
import zipfile
from collections.abc import Callable, Iterable
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from cnctwin.exceptions import FormatError
from cnctwin.recording import ExternalChannel, Recording, RecordingMeta

__all__ = ["SUPPORTED_FORMATS", "detect_format", "read_recording"]

SUPPORTED_FORMATS: dict[str, tuple[str, str, str]] = {
    "capture4analysis": (
        "cnctwin.iotools.capture4analysis", "read_capture4analysis",
        ".json or .zip with Header/Payload (Capture4Analysis, SINUMERIK Data Recorder)",
    ),
    "edge_dataobject": (
        "cnctwin.iotools.edge_dataobject", "read_edge_dataobject",
        ".json with header/body.datapoint (SINUMERIK Edge dataobject)",
    ),
    "sinumerik_trace": (
        "cnctwin.iotools.sinumerik_trace", "read_sinumerik_trace",
        ".xml SINUMERIK servo trace",
    ),
    "parquet": (
        "cnctwin.iotools.parquet", "read_parquet",
        ".parquet file or cnctwin Parquet directory",
    ),
    "sim_chunks": (
        "cnctwin.sim.recorder", "read_parquet_chunks",
        "cnctwin simulator chunk directory (meta.json + hf_*.parquet/.arrow)",
    ),
    "flat_csv": (
        "cnctwin.iotools.flat_csv", "read_flat_csv",
        "*_hfdata.csv flattened CSV (KIT layout)",
    ),
    "umich": (
        "cnctwin.iotools.umich", "read_umich",
        ".csv UMich CNC mill experiment (X1_ActualPosition column)",
    ),
    "kit_merged": (
        "cnctwin.iotools.kit_merged", "read_kit_merged",
        ".csv KIT merged milling layout (curr_sp, v_sp, f_x ... columns)",
    ),
    "dynamometer": (
        "cnctwin.iotools.dynamometer", "read_dynamometer_tdms",
        ".tdms dynamometer recording",
    ),
}
"""Format name -> (module, function, description)."""


def _supported() -> str:
    """The formats in one line (the details are in docs/real-data.md)."""
    return ("Capture4Analysis / Data Recorder .json or .zip, Edge dataobject .json, servo "
            "trace .xml, .parquet, CSV exports (*_hfdata.csv, UMich, KIT), dynamometer .tdms "
            "(docs/real-data.md)")


_MAGIC: tuple[tuple[bytes, str], ...] = (
    (b"\x89PNG", "a PNG image"), (b"\xff\xd8\xff", "a JPEG image"), (b"GIF8", "a GIF image"),
    (b"%PDF", "a PDF document"), (b"PK\x03\x04", "a zip archive"), (b"\x1f\x8b", "a gzip file"),
    (b"PAR1", "a Parquet file"), (b"SQLite format 3", "an SQLite database"),
    (b"TDSm", "a TDMS file"), (b"\x7fELF", "a program"))


def describe_content(head: bytes, *, size: int | None = None) -> str:
    """What the first bytes of a file that is not the expected recording are, in words.

    Parameters
    ----------
    head : bytes
        The first bytes (up to 64 kB) of the file.
    size : int, optional
        The file's size [bytes].

    Returns
    -------
    str
        E.g. ``"the file is empty (0 bytes)"``, ``"a PNG image"``, ``"a JSON array"``,
        ``"a JSON object with the keys a, b"``.
    """
    if size == 0 or not head:
        return "the file is empty (0 bytes)"
    for magic, what in _MAGIC:
        if head.startswith(magic):
            return what
    text = head.lstrip(b"\xef\xbb\xbf \t\r\n")
    if not text:
        return "the file holds only white space"
    if b"\x00" in head[:4096]:
        return "a binary file, not text"
    first = text[:1]
    if first == b"[":
        return "a JSON array, not an object"
    if first == b"{":
        import json

        try:
            doc = json.loads(head.decode("utf-8", "replace"))
        except ValueError:
            return "JSON-like text that does not parse (cut short or broken)"
        keys = [str(k) for k in doc][:8] if isinstance(doc, dict) else []
        return (f"a JSON object with the keys {', '.join(keys)}" if keys
                else "an empty JSON object")
    sample = text[:40].decode("utf-8", "replace").splitlines()[0] if text else ""
    return f"text that is not JSON (it starts with {sample!r})"


def _sniff_json(head: bytes) -> str | None:
    text = head.lstrip(b"\xef\xbb\xbf \t\r\n")
    if not text.startswith(b"{"):
        return None
    if b'"Header"' in text or b'"Payload"' in text:
        return "capture4analysis"
    if b'"header"' in text and (b'"body"' in text or b'"datapoint"' in text):
        return "edge_dataobject"
    if b'"body"' in text and b'"datapoint"' in text:
        return "edge_dataobject"
    return None


def detect_format(path: str | PathLike[str]) -> str:
    """Name of the format of ``path`` (a key of :data:`SUPPORTED_FORMATS`).

    Raises
    ------
    FormatError
        If no format matches; the message lists the supported formats.
    """
    p = Path(path)
    if not p.exists():
        raise FormatError("file not found", path=str(p))
    name = p.name.lower()
    suffix = p.suffix.lower()
    if p.is_dir():
        if (p / "meta.json").is_file() and any(p.glob("hf_0*.*")):
            return "sim_chunks"
        if (p / "hf.parquet").is_file() or any(p.glob("*.parquet")):
            return "parquet"
        raise FormatError(f"directory is not a cnctwin Parquet recording; supported: "
                          f"{_supported()}", path=str(p))
    if suffix == ".parquet":
        return "parquet"
    if suffix == ".tdms":
        return "dynamometer"
    if suffix == ".xml":
        return "sinumerik_trace"
    if suffix == ".zip":
        try:
            with zipfile.ZipFile(p) as zf:
                members = [m for m in zf.namelist() if m.lower().endswith(".json")]
                if members:
                    with zf.open(members[0]) as fh:
                        kind = _sniff_json(fh.read(65536))
                    if kind:
                        return kind
        except (zipfile.BadZipFile, OSError, EOFError):
            return "capture4analysis"  # let the reader report (or salvage) the broken zip
        raise FormatError(f"zip archive holds no recognised JSON recording; supported: "
                          f"{_supported()}", path=str(p))
    with p.open("rb") as fh:
        head = fh.read(65536)
    if suffix == ".json" or head.lstrip()[:1] == b"{":
        kind = _sniff_json(head)
        if kind:
            return kind
        if suffix == ".json":
            raise FormatError(
                f"not a recording: {describe_content(head, size=p.stat().st_size)}; a JSON "
                "recording has Header/Payload (Capture4Analysis, Data Recorder) or "
                f"header/body.datapoint (Edge dataobject). cnctwin reads {_supported()}",
                path=str(p))
    if suffix == ".csv":
        if name.endswith(("_hfdata.csv", "_header.csv", "_hfblockevent.csv",
                          "_hfcallevent.csv")):
            return "flat_csv"
        first_line = head.split(b"\n", 1)[0]
        if b"X1_ActualPosition" in first_line:
            return "umich"
        header = next((ln for ln in head.decode("utf-8", "replace").splitlines()
                       if ln.strip() and not ln.lstrip().startswith("#")), "")
        from cnctwin.iotools.kit_merged import looks_like_kit_merged

        if looks_like_kit_merged(header):
            return "kit_merged"
        raise FormatError(
            "CSV not recognised (expected <TRIAL>_hfdata.csv, a UMich experiment CSV with "
            f"X1_ActualPosition or the KIT merged layout); supported: {_supported()}",
            path=str(p))
    if head.startswith(b"PAR1"):
        return "parquet"
    if head.lstrip().startswith(b"<"):
        return "sinumerik_trace"
    if head.startswith(b"TDSm"):
        return "dynamometer"
    raise FormatError(f"format not recognised; supported: {_supported()}", path=str(p))


def _reader(kind: str, path: Path) -> Callable[..., Any]:
    module_name, func_name, desc = SUPPORTED_FORMATS[kind]
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise FormatError(
            f"looks like {desc}, but its reader is not available ({module_name}: {exc})",
            path=str(path),
        ) from exc
    func = getattr(module, func_name, None)
    if func is None:
        raise FormatError(
            f"looks like {desc}, but its reader is not available ({module_name} has no "
            f"{func_name})", path=str(path),
        )
    return func


def read_recording(path: str | PathLike[str], *, salvage: bool = False,
                   columns: Iterable[str] | None = None) -> Recording:
    """Open any supported recording, detecting its format from name and content.

    Parameters
    ----------
    path : str or path-like
        The file (or the first file of a chained Capture4Analysis run, or a Parquet
        directory).
    salvage : bool, default False
        Keep what can be read from damaged input and mark the recording partial
        (``rec.meta.partial``) instead of raising. Passed to readers that support it.
    columns : iterable of str, optional
        Only these HF columns (full names or signal codes; names the recording does not have
        are ignored). A reader that can skip columns (Parquet) reads only these; the others
        read everything and keep these. Default: all.

    Returns
    -------
    Recording

    Raises
    ------
    FormatError
        If the format is not recognised (the message lists the supported formats), its
        reader is not available, or the file is damaged (and ``salvage`` is False).
    """
    p = Path(path)
    kind = detect_format(p)
    func = _reader(kind, p)
    import inspect

    try:
        params = inspect.signature(func).parameters
    except (TypeError, ValueError):  # pragma: no cover - builtins
        params = {}  # type: ignore[assignment]
    kwargs: dict[str, Any] = {}
    if "salvage" in params:
        kwargs["salvage"] = salvage
    if columns is not None:
        columns = list(columns)
        if "columns" in params:
            kwargs["columns"] = columns
    rec = func(p, **kwargs)
    if isinstance(rec, ExternalChannel):
        # a source with its own clock only (dynamometer): an empty HF table plus the channel
        hf = pd.DataFrame(index=pd.Index(np.empty(0, dtype=np.int64), name="cycle"))
        meta = RecordingMeta(source_files=[str(p)], source_format=kind, issues=[
            f"{kind} file has no HF data; its samples are in rec.external[{rec.name!r}]"])
        return Recording(hf, external={rec.name: rec}, meta=meta)
    if not isinstance(rec, Recording):
        # readers may return a Recording plus extras; the first element is the recording
        if isinstance(rec, tuple) and rec and isinstance(rec[0], Recording):
            rec = rec[0]
        else:
            raise FormatError(f"reader {func.__module__}.{func.__name__} did not return a "
                              "Recording", path=str(p))
    if columns is not None and "columns" not in params:
        rec = rec.select(signals=columns)
    return rec


def reads_columns(path: str | PathLike[str]) -> bool:
    """Whether the reader of this recording's format reads only the columns asked for
    (:func:`read_recording` ``columns``), so that reading twice (first none, then what is
    needed) costs less than reading everything once."""
    import inspect

    p = Path(path)
    try:
        func = _reader(detect_format(p), p)
        return "columns" in inspect.signature(func).parameters
    except (FormatError, TypeError, ValueError):
        return False
