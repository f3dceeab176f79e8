"""Fixtures of the store tests: a store per backend, synthetic recordings, the real C4A file.

PostgreSQL: the server named by env ``CNCTWIN_PG_URL`` (default
``postgresql://postgres@127.0.0.1:5432/postgres``). The session creates a database of its own
(unique name), each test gets a fresh schema in it, and the database is dropped at the end. If
the server cannot be reached the PostgreSQL tests are skipped, or fail when ``CI=true``.
"""

from __future__ import annotations

import json
import os
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from cnctwin.iotools import read_capture4analysis
from cnctwin.recording import Recording
from cnctwin.store import Store
from cnctwin.store import open as open_store

DEFAULT_PG_URL = "postgresql://postgres@127.0.0.1:5432/postgres"


# ---------------------------------------------------------------------------- PostgreSQL
def _pg_admin_url() -> str:
    return os.environ.get("CNCTWIN_PG_URL", DEFAULT_PG_URL)


def _with_database(url: str, database: str) -> str:
    import urllib.parse

    parts = urllib.parse.urlsplit(url)
    return urllib.parse.urlunsplit(parts._replace(path=f"/{database}"))


@pytest.fixture(scope="session")
def pg_database() -> Iterator[str]:
    """URL of a fresh PostgreSQL database for this session (dropped afterwards)."""
    import psycopg

    admin = _pg_admin_url()
    try:
        conn = psycopg.connect(admin, autocommit=True, connect_timeout=5)
    except psycopg.Error as exc:
        msg = (
            f"PostgreSQL not reachable at {admin}; install/start postgresql or set "
            f"CNCTWIN_PG_URL ({exc})"
        )
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(msg)
        pytest.skip(msg)
    name = f"cnctwin_test_{uuid.uuid4().hex[:12]}"
    with conn:
        conn.execute(f'CREATE DATABASE "{name}"')
    try:
        yield _with_database(admin, name)
    finally:
        with psycopg.connect(admin, autocommit=True, connect_timeout=5) as c:
            c.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


@pytest.fixture
def pg_url(pg_database: str) -> str:
    """URL of a fresh schema (``?schema=t_<hex>``) in the session database."""
    return f"{pg_database}?schema=t_{uuid.uuid4().hex[:10]}"


# ---------------------------------------------------------------------------- stores
@pytest.fixture(params=["duckdb", pytest.param("postgres", marks=pytest.mark.postgres)])
def backend(request: pytest.FixtureRequest) -> str:
    return str(request.param)


@pytest.fixture
def store_url(backend: str, tmp_path: Path, request: pytest.FixtureRequest) -> str:
    """URL of an empty store of the backend under test."""
    if backend == "duckdb":
        return str(tmp_path / "store")
    return str(request.getfixturevalue("pg_url"))


@pytest.fixture
def store(store_url: str) -> Iterator[Store]:
    with open_store(store_url) as st:
        yield st


@pytest.fixture(scope="session")
def c4a_rec(c4a_file: Path) -> Recording:
    """The real C4A recording, read by the project reader."""
    return read_capture4analysis(c4a_file)


@pytest.fixture(scope="session")
def c4a_raw(c4a_file: Path) -> dict[str, Any]:
    """The real C4A JSON document, for checks straight against the file."""
    doc: dict[str, Any] = json.loads(c4a_file.read_text())
    return doc
