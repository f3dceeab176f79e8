"""Fixtures of the store tests: a store per backend, synthetic recordings, the real C4A file.

PostgreSQL: the server named by env ``CNCTWIN_PG_URL`` (default
``postgresql://postgres@127.0.0.1:5432/postgres``). The session creates a database of its own
(unique name), each test gets a fresh schema in it, and the database is dropped at the end. If
the server cannot be reached the PostgreSQL tests are skipped, or fail when ``CI=true``.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from cnctwin.iotools import read_capture4analysis
from cnctwin.recording import Recording
from cnctwin.store import Store
from cnctwin.store import open as open_store


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
