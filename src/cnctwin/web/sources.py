"""Where the dashboard's recordings come from: a cnctwin store and/or recording files.

Every recording gets an id: ``store:<recording_id>`` for a stored one, ``file:<n>`` for the
n-th recording file given (directories are expanded to the recording files in them, sorted).
The :class:`Catalog` summarises each one (from the store's catalog row, or by reading the file
once), reads single signals for the plots and whole recordings for the use-case analyses, and
keeps the most recently used ones in memory.
"""

from __future__ import annotations

import contextlib
import json
import os
import threading
from collections import OrderedDict
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from cnctwin.exceptions import CnctwinError, ConfigError, SignalNotFoundError, StoreError
from cnctwin.recording import Recording, RecordingMeta
from cnctwin.web.quality import SignalQuality, signal_quality, signal_quality_of

__all__ = ["RECORDING_SUFFIXES", "Catalog", "Entry", "SignalData", "expand_recording_paths"]

STORE_WAIT_S = 10.0
"""How long a dashboard request waits for an embedded store that a writer holds [s]."""

RECORDING_SUFFIXES: tuple[str, ...] = (".json", ".zip", ".xml", ".parquet", ".tdms")
"""File suffixes taken as recordings when a directory is given (CSV is left out: a directory
of recordings also holds hole tables and camera/dynamometer CSVs; give CSV recordings by name)."""


def expand_recording_paths(paths: Sequence[str | os.PathLike[str]]) -> list[Path]:
    """Recording files of ``paths``: files as given, directories expanded (sorted, one level).

    A directory that is itself a recording (a Parquet recording, a simulator chunk directory)
    is kept as one, also one level down (a scenario's output directory); the simulator's truth
    files beside it (``truth.json``, ``truth_per_cycle*.parquet``) are not recordings.

    Parameters
    ----------
    paths : sequence or path-like
        Files and directories.

    Returns
    -------
    list of pathlib.Path
        The recordings, directories expanded and sorted.

    Raises
    ------
    ConfigError
        If a path does not exist (naming it).
    """
    out: list[Path] = []
    for raw in paths:
        p = Path(raw)
        if not p.exists():
            raise ConfigError(f"recording path {p} does not exist; give a recording file or a "
                              "directory of recordings (cnctwin info FILE checks one)")
        if p.is_dir() and not _is_recording_dir(p) and not p.name.endswith(".parquet"):
            for c in sorted(p.iterdir()):
                if c.name.startswith("."):
                    continue
                if c.is_dir():
                    if _is_recording_dir(c):  # e.g. a simulator scenario's chunk directory
                        out.append(c)
                elif c.suffix.lower() in RECORDING_SUFFIXES and c.name not in _SIDECARS and \
                        not c.name.startswith("truth_per_cycle"):
                    out.append(c)
        else:
            out.append(p)
    return out


_SIDECARS = frozenset({"truth.json", "meta.json", "events.parquet", "lf.parquet"})
"""Files of a simulator output directory that are not recordings (the truth beside a scenario's
output, the parts of a chunk directory)."""


def _is_recording_dir(p: Path) -> bool:
    """A directory that is one recording: a simulator chunk directory (``meta.json`` +
    ``hf_*`` files) or a cnctwin Parquet recording (``hf.parquet``)."""
    return ((p / "meta.json").is_file() and any(p.glob("hf_0*.*"))) or (
        p / "hf.parquet").is_file()


@dataclass
class Entry:
    """One recording in the dashboard."""

    id: str
    kind: str  # "store" or "file"
    label: str
    machine: str = ""
    start_time: pd.Timestamp | None = None
    end_time: pd.Timestamp | None = None
    n_cycles: int = 0
    first_cycle: int | None = None
    last_cycle: int | None = None
    cycle_time_s: float = 0.002
    columns: list[str] = field(default_factory=list)
    units: dict[str, str] = field(default_factory=dict)
    source_format: str = ""
    issues: list[str] = field(default_factory=list)
    quality: SignalQuality | None = None
    error: str = ""
    path: Path | None = None

    @property
    def duration_s(self) -> float:
        """Counter span, gaps included [s]."""
        if self.first_cycle is None or self.last_cycle is None:
            return 0.0
        return (self.last_cycle - self.first_cycle) * self.cycle_time_s

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary."""
        return {
            "id": self.id, "kind": self.kind, "label": self.label, "machine": self.machine,
            "start_time": self.start_time.isoformat() if self.start_time is not None else None,
            "end_time": self.end_time.isoformat() if self.end_time is not None else None,
            "n_cycles": self.n_cycles, "first_cycle": self.first_cycle,
            "last_cycle": self.last_cycle, "cycle_time_s": self.cycle_time_s,
            "duration_s": self.duration_s, "n_signals": len(self.columns),
            "source_format": self.source_format, "issues": list(self.issues),
            "quality": self.quality.to_dict() if self.quality is not None else None,
            "error": self.error,
        }


@dataclass(frozen=True)
class SignalData:
    """One HF signal of a recording on its counter time base."""

    name: str
    unit: str
    cycles: NDArray[np.int64]
    values: NDArray[np.float64]
    cycle_time_s: float

    @property
    def time_s(self) -> NDArray[np.float64]:
        """Seconds since the recording's first cycle (gaps keep their length) [s]."""
        if self.cycles.size == 0:
            return np.empty(0)
        return (self.cycles - self.cycles[0]).astype(np.float64) * self.cycle_time_s


def _entry_from_recording(entry_id: str, kind: str, label: str, rec: Recording,
                          path: Path | None) -> Entry:
    c = rec.cycles
    t = rec.hf["time"]
    return Entry(
        id=entry_id, kind=kind, label=label, machine=rec.meta.machine,
        start_time=pd.Timestamp(t.iloc[0]) if len(t) else None,
        end_time=pd.Timestamp(t.iloc[-1]) if len(t) else None,
        n_cycles=rec.n_cycles, first_cycle=int(c[0]) if c.size else None,
        last_cycle=int(c[-1]) if c.size else None, cycle_time_s=rec.meta.cycle_time_s,
        columns=rec.columns, units={k: rec.meta.units.get(k, "") for k in rec.columns},
        source_format=rec.meta.source_format, issues=list(rec.meta.issues),
        quality=signal_quality_of(rec), path=path,
    )


def _entry_from_catalog(row: pd.Series) -> Entry:
    from cnctwin.recording import meta_from_json

    meta: RecordingMeta = meta_from_json(str(row["meta"]))
    n = int(row["n_cycles"])
    first = None if pd.isna(row["first_cycle"]) else int(row["first_cycle"])
    last = None if pd.isna(row["last_cycle"]) else int(row["last_cycle"])
    return Entry(
        id=f"store:{row['recording_id']}", kind="store", label=str(row["recording_id"]),
        machine=str(row["machine"] or ""),
        start_time=None if pd.isna(row["start_time"]) else pd.Timestamp(row["start_time"]),
        end_time=None if pd.isna(row["end_time"]) else pd.Timestamp(row["end_time"]),
        n_cycles=n, first_cycle=first, last_cycle=last,
        cycle_time_s=float(row["cycle_time_s"]), columns=list(json.loads(row["columns"])),
        units=dict(json.loads(row["units"])), source_format=str(row["source_format"] or ""),
        issues=list(json.loads(row["issues"])),
        quality=signal_quality(meta, n_cycles=n, first_cycle=first, last_cycle=last),
    )


class Catalog:
    """The recordings of one dashboard: a store (optional) and recording files.

    Parameters
    ----------
    store_url : str, optional
        A cnctwin store (directory or ``postgresql://`` URL). The dashboard only reads it: an
        embedded (DuckDB) store is opened read-only for each request and closed after it, so
        ``cnctwin ingest``, ``edge run --store`` and other dashboards work beside it; a
        PostgreSQL store keeps one connection.
    recordings : sequence of path-like
        Recording files or directories of them (read with ``cnctwin.read_recording``).
    cache_size : int, default 4
        Whole recordings kept in memory (least recently used are dropped).

    Raises
    ------
    StoreError
        If the store does not exist or cannot be opened (the message says how to make one).
    ConfigError
        If a recording path does not exist.
    """

    def __init__(self, *, store_url: str | None = None,
                 recordings: Sequence[str | os.PathLike[str]] = (), cache_size: int = 4,
                 salvage: bool = False) -> None:
        self._lock = threading.RLock()
        self.store_url = store_url
        self.store: Any = None  # a PostgreSQL store's connection, kept open
        if store_url is not None:
            with self._stored():  # it must exist (the error says how to make one)
                pass
        self.paths = expand_recording_paths(recordings)
        self.salvage = salvage
        self.cache_size = max(1, int(cache_size))
        self._recs: OrderedDict[str, Recording] = OrderedDict()
        self._signals: OrderedDict[tuple[str, str], SignalData] = OrderedDict()
        self._file_entries: dict[str, Entry] = {}

    @contextlib.contextmanager
    def _stored(self) -> Iterator[Any]:
        """The store for one request (an embedded one opened read-only, then closed)."""
        if self.store is not None:
            yield self.store
            return
        import cnctwin.store as store_mod
        from cnctwin.store.duckdb_store import DuckDBStore

        assert self.store_url is not None
        try:
            st = store_mod.open(self.store_url, create=False, read_only=True,
                                lock_timeout_s=STORE_WAIT_S)
        except StoreError as exc:
            raise StoreError(
                f"{exc}. Create the store and fill it with `cnctwin ingest FILE... --store "
                f"{self.store_url}`, or start the dashboard on files with --recording PATH"
            ) from exc
        if not isinstance(st, DuckDBStore):  # a server serves readers beside writers
            self.store = st
            yield st
            return
        try:
            yield st
        finally:
            st.close()

    # ------------------------------------------------------------------ listing
    def entries(self) -> list[Entry]:
        """Every recording: stored ones by start time, then the files in the order given."""
        out: list[Entry] = []
        with self._lock:
            if self.store_url is not None:
                with self._stored() as st:
                    cat = st.recordings()
                out.extend(_entry_from_catalog(row) for _, row in cat.iterrows())
            for k, p in enumerate(self.paths):
                out.append(self._file_entry(f"file:{k}", p))
        return out

    def _file_entry(self, entry_id: str, path: Path) -> Entry:
        if entry_id not in self._file_entries:
            try:
                rec = self._load_file(entry_id, path)
                self._file_entries[entry_id] = _entry_from_recording(
                    entry_id, "file", path.name, rec, path)
            except CnctwinError as exc:  # listed with its error, not dropped
                self._file_entries[entry_id] = Entry(id=entry_id, kind="file", label=path.name,
                                                     error=str(exc), path=path)
        return self._file_entries[entry_id]

    def entry(self, entry_id: str) -> Entry:
        """The summary of one recording.

        Raises
        ------
        StoreError
            If there is no such id (the message lists the ids there are).
        """
        with self._lock:
            if entry_id.startswith("file:"):
                k = self._file_index(entry_id)
                return self._file_entry(entry_id, self.paths[k])
            for e in self.entries():
                if e.id == entry_id:
                    return e
        raise self._unknown(entry_id)

    def _unknown(self, entry_id: str) -> StoreError:
        ids = [e.id for e in self.entries()]
        shown = ", ".join(ids[:10]) + (" ..." if len(ids) > 10 else "")
        return StoreError(f"no recording {entry_id!r} in this dashboard; it has: "
                          f"{shown or 'none (start it with --store or --recording)'}")

    def _file_index(self, entry_id: str) -> int:
        try:
            k = int(entry_id.split(":", 1)[1])
        except ValueError:
            raise self._unknown(entry_id) from None
        if not 0 <= k < len(self.paths):
            raise self._unknown(entry_id)
        return k

    # ------------------------------------------------------------------ reading
    def _remember(self, entry_id: str, rec: Recording) -> Recording:
        self._recs[entry_id] = rec
        self._recs.move_to_end(entry_id)
        while len(self._recs) > self.cache_size:
            self._recs.popitem(last=False)
        return rec

    def _load_file(self, entry_id: str, path: Path) -> Recording:
        if entry_id in self._recs:
            self._recs.move_to_end(entry_id)
            return self._recs[entry_id]
        from cnctwin.iotools import read_recording
        from cnctwin.iotools.thermal import find_thermal_camera, read_thermal_camera_csv

        rec = read_recording(path, salvage=self.salvage)
        camera = find_thermal_camera(path) if "thermal_camera" not in rec.external else None
        if camera is not None:
            # the simulator (and a user's camera export) writes the readings beside the
            # recording: the tool-temperature soft sensor calibrates on them
            try:
                rec.external["thermal_camera"] = read_thermal_camera_csv(camera)
                rec.meta.issues.append(f"thermal camera readings from {camera}")
            except CnctwinError as exc:
                rec.meta.issues.append(f"thermal camera file {camera} not used: {exc}")
        return self._remember(entry_id, rec)

    def recording(self, entry_id: str) -> Recording:
        """The whole recording (cached)."""
        with self._lock:
            if entry_id in self._recs:
                self._recs.move_to_end(entry_id)
                return self._recs[entry_id]
            if entry_id.startswith("file:"):
                k = self._file_index(entry_id)
                return self._load_file(entry_id, self.paths[k])
            if entry_id.startswith("store:") and self.store_url is not None:
                with self._stored() as st:
                    return self._remember(entry_id, st.load(entry_id[len("store:"):]))
        raise self._unknown(entry_id)

    def signal(self, entry_id: str, name: str) -> SignalData:
        """One HF column (``CURRENT|SP1``) of a recording.

        A stored recording is read column by column (``Store.query_signals``) so a plot does
        not load the whole recording; a file is read whole once and cached.

        Raises
        ------
        SignalNotFoundError
            If the recording has no such column (the message names it and lists the columns).
        """
        with self._lock:
            key = (entry_id, name)
            if key in self._signals:
                self._signals.move_to_end(key)
                return self._signals[key]
            e = self.entry(entry_id)
            if name not in e.columns:
                raise SignalNotFoundError(
                    f"signal {name!r} is not in recording {entry_id!r}; it has: "
                    f"{', '.join(e.columns) or 'no HF signals'}")
            if entry_id in self._recs or e.kind == "file":
                rec = self.recording(entry_id)
                s = rec.signal(name)
                data = SignalData(name, e.units.get(name, ""), rec.cycles,
                                  s.to_numpy(dtype=np.float64), rec.meta.cycle_time_s)
            else:
                with self._stored() as st:
                    df = st.query_signals([name], recording_id=entry_id[len("store:"):])
                data = SignalData(name, e.units.get(name, ""),
                                  df.index.to_numpy(dtype=np.int64),
                                  df[name].to_numpy(dtype=np.float64), e.cycle_time_s)
            self._signals[key] = data
            while len(self._signals) > 8 * self.cache_size:
                self._signals.popitem(last=False)
            return data

    def close(self) -> None:
        """Close the store (idempotent)."""
        with self._lock:
            if self.store is not None:
                self.store.close()
                self.store = None
            self._recs.clear()
            self._signals.clear()


def require_columns(rec: Recording, columns: Sequence[str], what: str) -> None:
    """Raise :class:`ConfigError` naming the missing columns ``what`` needs."""
    missing = [c for c in columns if not rec.has(c)]
    if missing:
        raise ConfigError(f"{what} needs {', '.join(missing)}; this recording has none of "
                          f"them. Signals present: {', '.join(rec.columns[:20])}")
