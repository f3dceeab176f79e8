"""Storage of recordings: embedded DuckDB + Parquet (default) or PostgreSQL.

::

    import cnctwin.store
    with cnctwin.store.open("/tmp/cnctwin-store") as st:
        rid = st.ingest(rec)
        cur = st.query_signals(["CURRENT|SP1"], start="2023-12-22T13:23:41Z")
        rec2 = st.load(rid)

URLs understood by :func:`open`:

* a plain path, ``file:///abs/path`` or ``duckdb:///abs/path`` (``duckdb://rel/path``):
  :class:`~cnctwin.store.duckdb_store.DuckDBStore`;
* ``postgresql://user@host:port/db?schema=name`` (``postgres://`` too):
  :class:`~cnctwin.store.postgres_store.PostgresStore`; the schema defaults to ``cnctwin``.
"""

from __future__ import annotations

import os
import urllib.parse
import urllib.request

from cnctwin.exceptions import ConfigError
from cnctwin.store.base import CATALOG_COLUMNS, Store, default_recording_id
from cnctwin.store.duckdb_store import DuckDBStore

__all__ = [
    "CATALOG_COLUMNS",
    "DuckDBStore",
    "PostgresStore",
    "Store",
    "default_recording_id",
    "open",
]


def open(
    url_or_path: str | os.PathLike[str], *, create: bool = True, read_only: bool = False,
    lock_timeout_s: float = 0.0,
) -> Store:
    """Open (and by default create) a store.

    Parameters
    ----------
    url_or_path : str or path-like
        A directory (embedded DuckDB + Parquet store), ``file://``/``duckdb://`` URL of one, or
        a ``postgresql://`` URL (optional ``?schema=name``, default schema ``cnctwin``).
    create : bool, default True
        Create the directory / schema if missing; with False a missing store raises
        :class:`~cnctwin.exceptions.StoreError`.
    read_only : bool, default False
        Open an embedded store's catalog read-only, so that several processes (the fleet's
        workers) can read it at once; PostgreSQL serves concurrent readers anyway.
    lock_timeout_s : float, default 0
        How long to wait [s] for an embedded store that another process holds (DuckDB allows
        one writer or several readers per catalog, never both); PostgreSQL does not need it.

    Returns
    -------
    Store
        A :class:`DuckDBStore` or :class:`PostgresStore`.

    Raises
    ------
    ConfigError
        For a URL scheme that is not supported.
    StoreError
        If the store is missing (``create=False``) or the server cannot be reached.
    """
    text = os.fspath(url_or_path)
    scheme = text.split("://", 1)[0].lower() if "://" in text else ""
    if scheme in ("postgresql", "postgres"):
        from cnctwin.store.postgres_store import PostgresStore

        return PostgresStore(text, create=create)
    if scheme == "duckdb":
        text = text[len("duckdb://"):]
    elif scheme == "file":
        text = urllib.request.url2pathname(urllib.parse.urlparse(text).path)
    elif scheme:
        raise ConfigError(
            f"store URL scheme {scheme!r} is not supported; use a directory path, "
            "file:///path, duckdb:///path or postgresql://user@host:port/db"
        )
    return DuckDBStore(text, create=create and not read_only, read_only=read_only,
                       lock_timeout_s=lock_timeout_s)


def __getattr__(name: str) -> object:
    # PostgresStore imports psycopg (the 'postgres' extra) only when asked for.
    if name == "PostgresStore":
        from cnctwin.store.postgres_store import PostgresStore

        return PostgresStore
    raise AttributeError(f"module 'cnctwin.store' has no attribute {name!r}")
