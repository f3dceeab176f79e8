"""Parallel ingest of many recordings into a store: idempotent and crash-consistent.

Each recording (a file, or a Parquet recording directory) is one task: the worker hashes its
content (SHA-256), skips it if the store holds that hash already, reads it and writes it:

* into PostgreSQL directly, in one transaction per recording (concurrent writers are fine);
* into the embedded store as *staged* files (hidden ``.tmp`` names, no catalog connection:
  DuckDB admits one writing process), which the job's driver then enters into the catalog in
  one transaction per recording (:meth:`~cnctwin.store.DuckDBStore.commit`).

Either way a worker killed mid-task leaves no catalog entry (at most ``.tmp`` files, replaced
by the rerun), and a file ingested twice is stored once: its hash is kept in the recording's
``meta.attrs["source_sha256"]`` and its id is content-derived
(:func:`~cnctwin.store.default_recording_id`).
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from cnctwin.exceptions import CnctwinError, ConfigError
from cnctwin.fleet.cluster import map_tasks

__all__ = [
    "RECORDING_SUFFIXES",
    "IngestOutcome",
    "IngestReport",
    "content_hash",
    "find_recordings",
    "ingest_one",
    "ingest_recordings",
    "stored_hashes",
]

RECORDING_SUFFIXES = (".json", ".zip", ".csv", ".tsv", ".txt", ".tdms", ".parquet")
"""File suffixes taken as recordings when a directory is searched (besides Parquet recording
directories, which hold ``hf.parquet``)."""

_SKIP_NAMES = frozenset({"truth.json", "status.json", "machine.json"})


@dataclass(frozen=True)
class IngestOutcome:
    """What became of one recording.

    Attributes
    ----------
    path : str
        The file or recording directory.
    status : str
        ``"ingested"``, ``"already"`` (its content hash is stored) or ``"failed"``.
    sha256 : str
        Content hash (empty if the file could not be read at all).
    recording_id : str or None
        Id in the store.
    machine : str
        Machine name of the recording.
    n_cycles : int
        HF cycles.
    reason : str
        Why it failed (the reader's message), empty otherwise.
    staged : object, optional
        The embedded store's :class:`~cnctwin.store.duckdb_store.StagedRecording`, for the
        driver to commit.
    """

    path: str
    status: str
    sha256: str = ""
    recording_id: str | None = None
    machine: str = ""
    n_cycles: int = 0
    reason: str = ""
    staged: Any = field(default=None, repr=False, compare=False)


@dataclass(frozen=True)
class IngestReport:
    """Result of :func:`ingest_recordings`.

    Attributes
    ----------
    outcomes : list of IngestOutcome
        One per recording found, in input order.
    """

    outcomes: list[IngestOutcome]

    def count(self, status: str) -> int:
        """Number of outcomes with this status."""
        return sum(o.status == status for o in self.outcomes)

    @property
    def failed(self) -> list[IngestOutcome]:
        """The recordings that could not be ingested (path and reason)."""
        return [o for o in self.outcomes if o.status == "failed"]

    def to_frame(self) -> pd.DataFrame:
        """One row per recording: path, status, sha256, recording_id, machine, n_cycles,
        reason."""
        cols = ["path", "status", "sha256", "recording_id", "machine", "n_cycles", "reason"]
        return pd.DataFrame([{c: getattr(o, c) for c in cols} for o in self.outcomes],
                            columns=cols)


def find_recordings(paths: Iterable[str | os.PathLike[str]]) -> list[Path]:
    """The recordings named by files and directories (searched recursively), sorted.

    A directory holding ``hf.parquet`` is one recording (the Parquet layout); other
    directories are searched for files ending in :data:`RECORDING_SUFFIXES` (``truth.json``
    and hidden files skipped). A file named directly is taken whatever its suffix.

    Parameters
    ----------
    paths : iterable of str or path-like
        Files and directories.

    Returns
    -------
    list of pathlib.Path
        One path per recording, sorted.

    Raises
    ------
    ConfigError
        If a path does not exist.
    """
    out: list[Path] = []
    for p in map(Path, paths):
        if not p.exists():
            raise ConfigError(f"{p}: no such file or directory")
        if p.is_file() or (p / "hf.parquet").exists():
            out.append(p)
            continue
        for root, dirs, files in os.walk(p):
            r = Path(root)
            dirs[:] = sorted(d for d in dirs if not d.startswith("."))
            for d in list(dirs):
                if (r / d / "hf.parquet").exists():
                    out.append(r / d)
                    dirs.remove(d)
            out += [r / f for f in sorted(files)
                    if not f.startswith(".") and f not in _SKIP_NAMES
                    and f.lower().endswith(RECORDING_SUFFIXES)]
    seen: set[Path] = set()
    unique = []
    for p in out:
        if p not in seen:
            seen.add(p)
            unique.append(p)
    return sorted(unique)


def content_hash(path: str | os.PathLike[str]) -> str:
    """SHA-256 of a file, or of a recording directory's files (relative names and contents,
    in name order).

    Parameters
    ----------
    path : str or path-like
        A recording file or directory.

    Returns
    -------
    str
        Hex digest.
    """
    p = Path(path)
    h = hashlib.sha256()
    files = [p] if p.is_file() else sorted(f for f in p.rglob("*") if f.is_file())
    for f in files:
        if p.is_dir():
            h.update(str(f.relative_to(p)).encode() + b"\0")
        with f.open("rb") as fh:
            while block := fh.read(1 << 20):
                h.update(block)
    return h.hexdigest()


def stored_hashes(store: str | Any) -> frozenset[str]:
    """The ``source_sha256`` of every recording in the store (a URL or an open store).

    Parameters
    ----------
    store : str or Any
        Store URL or an open store.

    Returns
    -------
    frozenset of str
        Content hashes of the files already ingested.
    """
    import cnctwin.store

    if isinstance(store, str):
        with cnctwin.store.open(store) as st:
            return stored_hashes(st)
    cat = store.recordings()
    out = set()
    for text in cat.get("meta", pd.Series(dtype=object)):
        sha = json.loads(text).get("attrs", {}).get("source_sha256") if text else None
        if sha:
            out.add(str(sha))
    return frozenset(out)


def ingest_one(
    path: str, *, store_url: str, known: frozenset[str] = frozenset(), stage: bool = False,
    machine: str | None = None,
) -> IngestOutcome:
    """Read one recording and write it to the store (a fleet ingest task).

    Parameters
    ----------
    path : str
        File or recording directory.
    store_url : str
        The store (:func:`cnctwin.store.open`).
    known : frozenset of str
        Content hashes the store holds already (skipped).
    stage : bool, default False
        Stage into the embedded store's directory instead of writing the catalog (the driver
        commits); required for a DuckDB store written by several processes.
    machine : str, optional
        Machine name to file the recording under (default: the one it carries).

    Returns
    -------
    IngestOutcome
        ``failed`` with the reader's message for a file that cannot be read; never raises for
        bad input.
    """
    from cnctwin.iotools import read_recording
    from cnctwin.store import default_recording_id

    try:
        sha = content_hash(path)
    except OSError as exc:
        return IngestOutcome(path, "failed", reason=f"cannot read: {exc}")
    if sha in known:
        return IngestOutcome(path, "already", sha)
    try:
        rec = read_recording(path)
    except (CnctwinError, OSError, ValueError, KeyError) as exc:
        return IngestOutcome(path, "failed", sha, reason=f"{type(exc).__name__}: {exc}")
    if machine:
        rec.meta.machine = machine
    rec.meta.attrs["source_sha256"] = sha
    rid = default_recording_id(rec)
    name = rec.meta.machine
    if stage:
        from cnctwin.store.duckdb_store import stage_recording

        root = store_url.split("://", 1)[1] if "://" in store_url else store_url
        staged = stage_recording(root, rec, rid)
        return IngestOutcome(path, "ingested", sha, rid, name, rec.n_cycles, staged=staged)
    import cnctwin.store

    with cnctwin.store.open(store_url) as st:
        st.ingest(rec, recording_id=rid)
    return IngestOutcome(path, "ingested", sha, rid, name, rec.n_cycles)


def ingest_recordings(
    paths: Sequence[str | os.PathLike[str]], *, store_url: str, client: Any,
    machine: str | None = None, progress: Callable[[int, int], None] | None = None,
) -> IngestReport:
    """Ingest many recordings in parallel on a Dask cluster.

    Parameters
    ----------
    paths : sequence of path
        Files and directories (:func:`find_recordings`).
    store_url : str
        The store; an embedded store must be on a file system the workers share.
    client : distributed.Client
        The cluster (:func:`~cnctwin.fleet.cluster.fleet_client`).
    machine : str, optional
        File every recording under this machine name.
    progress : callable, optional
        ``progress(done, total)``.

    Returns
    -------
    IngestReport
    """
    import cnctwin.store
    from cnctwin.store.duckdb_store import DuckDBStore

    found = [str(p) for p in find_recordings(paths)]
    with cnctwin.store.open(store_url) as st:
        known = stored_hashes(st)
        stage = isinstance(st, DuckDBStore)
        store_ref = str(st.root) if isinstance(st, DuckDBStore) else store_url
    results = map_tasks(client, ingest_one, found, key="ingest", progress=progress,
                        store_url=store_ref, known=known, stage=stage, machine=machine)
    if stage:
        with cnctwin.store.open(store_url) as st:
            assert isinstance(st, DuckDBStore)
            committed: set[str] = set()
            for o in results:
                if o.staged is None:
                    continue
                if o.recording_id in committed:  # the same content twice in one job
                    for tmp, _ in o.staged.tmp_to_final:
                        Path(tmp).unlink(missing_ok=True)
                    continue
                st.commit(o.staged)
                committed.add(str(o.recording_id))
                _sweep_stale(st.root, o.staged.tmp_to_final)
    # a second copy of the same content in this job is "already" stored
    first: dict[str, int] = {}
    outcomes = []
    for i, o in enumerate(results):
        if o.status == "ingested" and o.sha256 in first:
            o = IngestOutcome(o.path, "already", o.sha256, o.recording_id, o.machine, o.n_cycles)
        elif o.status == "ingested":
            first[o.sha256] = i
        outcomes.append(o)
    return IngestReport(outcomes)


def _sweep_stale(root: Path, tmp_to_final: Sequence[tuple[str, str]]) -> None:
    """Remove files staged for the same final paths by a worker that died before its result
    reached the driver (``<final>.<pid>.tmp``)."""
    for _, rel in tmp_to_final:
        final = root / rel
        for stale in final.parent.glob(f"{final.name}.*.tmp"):
            stale.unlink(missing_ok=True)
