"""Recordings as Parquet: a directory of Parquet files with the metadata in the schema.

Layout written by :func:`write_parquet` (``path`` is a directory, e.g. ``run.parquet/``)::

    run.parquet/
        hf.parquet            cycle (int64), time (timestamp[ns, UTC]), CODE|AXIS (float64)
                              schema metadata b"cnctwin.meta": RecordingMeta as JSON
                              field metadata b"unit": the unit of each column
        lf.parquet            LF values in long form (cycle, time, signal, value, text)
        events.parquet        NC events (EVENT_COLUMNS and any extra columns)
        external/<name>.parquet   external channels (index time_s); schema metadata
                              b"cnctwin.channel": units, fs_hz, offset_s, drift_ppm, ...

:func:`read_parquet` reads that directory, its ``hf.parquet`` directly, or any single Parquet
file with a ``cycle`` column (e.g. ``Recording.to_arrow()`` written by hand); a missing
``cnctwin.meta`` gives default metadata and an issue.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
import orjson
import pandas as pd

from cnctwin.exceptions import FormatError
from cnctwin.recording import (
    ExternalChannel,
    Recording,
    RecordingMeta,
    meta_from_json,
    meta_to_json,
)

__all__ = ["read_parquet", "write_parquet"]

_META_KEY = b"cnctwin.meta"
_CHANNEL_KEY = b"cnctwin.channel"
_UNIT_KEY = b"unit"


def _with_units(table: Any, units: dict[str, str], extra: dict[bytes, bytes]) -> Any:
    import pyarrow as pa

    fields = [
        f.with_metadata({_UNIT_KEY: units.get(f.name, "").encode()}) for f in table.schema
    ]
    metadata = dict(table.schema.metadata or {})
    metadata.update(extra)
    return table.cast(pa.schema(fields, metadata=metadata))


def write_parquet(rec: Recording, path: str | PathLike[str]) -> Path:
    """Write a recording as a directory of Parquet files (layout in the module docstring).

    Parameters
    ----------
    rec : Recording
        The recording.
    path : str or path-like
        Output directory (created; files in it are replaced).

    Returns
    -------
    Path
        The directory.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    out = Path(path)
    if out.exists() and not out.is_dir():
        raise FormatError("exists and is not a directory; the Parquet layout is a directory",
                          path=str(out))
    out.mkdir(parents=True, exist_ok=True)
    hf = pa.Table.from_pandas(rec.hf.reset_index(), preserve_index=False)
    hf = _with_units(hf, rec.meta.units, {_META_KEY: meta_to_json(rec.meta).encode()})
    pq.write_table(hf, out / "hf.parquet")
    pq.write_table(pa.Table.from_pandas(rec.lf, preserve_index=False), out / "lf.parquet")
    pq.write_table(pa.Table.from_pandas(rec.events, preserve_index=False),
                   out / "events.parquet")
    ext_dir = out / "external"
    if rec.external:
        ext_dir.mkdir(exist_ok=True)
    for name, ch in rec.external.items():
        info = {k: v for k, v in dataclasses.asdict(ch).items() if k != "data"}
        data = ch.data.copy()
        data.index = data.index.rename("time_s")
        table = pa.Table.from_pandas(data.reset_index(), preserve_index=False)
        table = _with_units(table, ch.units, {_CHANNEL_KEY: orjson.dumps(info, default=str)})
        pq.write_table(table, ext_dir / f"{name}.parquet")
    return out


def _objects(df: pd.DataFrame) -> pd.DataFrame:
    """String columns back to ``object`` (pandas 3 reads Arrow strings as ``str``)."""
    for c in df.columns:
        if pd.api.types.is_string_dtype(df[c].dtype) and df[c].dtype != object:
            df[c] = df[c].astype(object).where(df[c].notna(), None)
    return df


def read_parquet(path: str | PathLike[str], *,
                 columns: Iterable[str] | None = None) -> Recording:
    """Read a recording written by :func:`write_parquet`.

    Parameters
    ----------
    path : str or path-like
        The directory, its ``hf.parquet``, or a single Parquet file with a ``cycle`` column.
    columns : iterable of str, optional
        Only these HF columns (full names ``CODE|AXIS`` or signal codes, as
        :meth:`cnctwin.recording.Recording.select`); the others are not read from the file
        (Parquet is columnar). Names the file does not have are ignored. Default: all.

    Returns
    -------
    Recording

    Raises
    ------
    FormatError
        Not a Parquet file, or no ``cycle`` column.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    p = Path(path)
    folder: Path | None = None
    if p.is_dir():
        folder = p
        p = p / "hf.parquet"
        if not p.is_file():
            raise FormatError("directory holds no hf.parquet; not a cnctwin Parquet recording",
                              path=str(folder))
    elif p.name == "hf.parquet":
        folder = p.parent
    try:
        names = None
        if columns is not None:
            from cnctwin.signals import parse_column

            wanted = set(columns)
            names = [n for n in pq.read_schema(p).names
                     if n in ("cycle", "time") or n in wanted or parse_column(n)[0] in wanted]
        table = pq.read_table(p, columns=names)
    except (pa.ArrowInvalid, OSError) as exc:
        raise FormatError(f"not a readable Parquet file ({exc})", path=str(p)) from exc
    md = table.schema.metadata or {}
    issues: list[str] = []
    if _META_KEY in md:
        meta = meta_from_json(md[_META_KEY])
    else:
        meta = RecordingMeta(source_format="parquet")
        issues.append("no cnctwin metadata in the Parquet schema; defaults used")
    for f in table.schema:
        if f.metadata and _UNIT_KEY in f.metadata and f.metadata[_UNIT_KEY]:
            meta.units[f.name] = f.metadata[_UNIT_KEY].decode()
    if "cycle" not in table.column_names:
        raise FormatError(f"no 'cycle' column (columns: {table.column_names[:6]} ...)",
                          path=str(p), field="cycle")
    hf = table.to_pandas()
    del table
    hf = hf.set_index("cycle")
    hf.index = hf.index.astype(np.int64)
    for c in hf.columns:
        if c != "time" and hf[c].dtype != np.float64:
            hf[c] = hf[c].astype(np.float64)
    lf = events = None
    external: dict[str, ExternalChannel] = {}
    if folder is not None:
        if (folder / "lf.parquet").is_file():
            lf = _objects(pq.read_table(folder / "lf.parquet").to_pandas())
        if (folder / "events.parquet").is_file():
            events = _objects(pq.read_table(folder / "events.parquet").to_pandas())
        ext_dir = folder / "external"
        if ext_dir.is_dir():
            for f in sorted(ext_dir.glob("*.parquet")):
                t = pq.read_table(f)
                info = orjson.loads((t.schema.metadata or {}).get(_CHANNEL_KEY, b"{}"))
                data = t.to_pandas().set_index("time_s")
                info.pop("data", None)
                kw = {k: v for k, v in info.items()
                      if k in {x.name for x in dataclasses.fields(ExternalChannel)}}
                kw.setdefault("name", f.stem)
                external[kw["name"]] = ExternalChannel(data=data, **kw)
    meta.issues.extend(issues)
    return Recording(hf, lf=lf, events=events, external=external, meta=meta)
