"""Shared fixtures: paths of the vendored real recordings and service helpers.

PostgreSQL: the server named by env ``CNCTWIN_PG_URL`` (default
``postgresql://postgres@127.0.0.1:5432/postgres``). The session creates a database of its own
(unique name), each test gets a fresh schema in it, and the database is dropped at the end. If
the server cannot be reached the PostgreSQL tests are skipped, or fail when ``CI=true``.
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

TESTS_DATA_DIR = Path(__file__).parent / "data"
REAL_DIR = TESTS_DATA_DIR / "real"
C4A_FILE = REAL_DIR / "capture4analysis" / "example_data_ff429d74-6482-4d4f-80e1-31419d9bd56c.json"
TRACE_FILE = REAL_DIR / "sinumerik-trace" / "Tav23362_2140_frenata_15_4_26_EmgTest.xml"
UMICH_DIR = REAL_DIR / "umich-cnc-mill"
VICOMTECH_FILE = REAL_DIR / "vicomtech-turning-wear" / "Dataset_Machine_tool_wear.csv"
DEFAULT_PG_URL = "postgresql://postgres@127.0.0.1:5432/postgres"


@pytest.fixture(scope="session")
def c4a_file() -> Path:
    """The real Capture4Analysis recording (SINUMERIK 840D sl, 5 axes + spindle)."""
    return C4A_FILE


@pytest.fixture(scope="session")
def trace_file() -> Path:
    """The real SINUMERIK Solution Line servo trace (emergency-brake test)."""
    return TRACE_FILE


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
