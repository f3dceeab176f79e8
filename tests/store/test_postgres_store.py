"""PostgreSQL backend specifics: URL/schema handling, block layout, bytes per sample.

The behaviour shared with DuckDB is in ``test_store_backends.py``.
"""

from __future__ import annotations

import numpy as np
import pytest

from cnctwin.exceptions import ConfigError, StoreError
from cnctwin.store import open as open_store
from cnctwin.store.postgres_store import DEFAULT_SCHEMA, PostgresStore, parse_pg_url

from .store_helpers import make_recording

pytestmark = pytest.mark.postgres


def test_parse_pg_url() -> None:
    assert parse_pg_url("postgresql://u@h:5/db?schema=abc&sslmode=disable") == (
        "postgresql://u@h:5/db?sslmode=disable", "abc")
    assert parse_pg_url("postgresql://u@h/db")[1] == DEFAULT_SCHEMA == "cnctwin"
    assert parse_pg_url("postgresql://u@h/db?options=-csearch_path%3Dplant7,public")[1] == (
        "plant7")
    with pytest.raises(ConfigError, match="schema name"):
        parse_pg_url("postgresql://u@h/db?schema=bad;drop")


def test_unreachable_server_is_store_error() -> None:
    with pytest.raises(StoreError, match=r"cannot connect to PostgreSQL at .*start the server"):
        PostgresStore("postgresql://postgres:secret@127.0.0.1:1/none")


def test_password_not_in_repr(pg_database: str) -> None:
    with open_store(pg_database.replace("postgres@", "postgres:pw@")) as st:
        assert "pw" not in repr(st) and "***" in repr(st)


def test_default_schema_and_create_false(pg_database: str) -> None:
    with pytest.raises(StoreError, match="no cnctwin schema 'absent'"):
        open_store(f"{pg_database}?schema=absent", create=False)
    with open_store(pg_database) as st:
        assert isinstance(st, PostgresStore) and st.schema == "cnctwin"
        n = st.sql("SELECT count(*) AS n FROM information_schema.tables "
                   "WHERE table_schema = 'cnctwin'")
        # recordings, hf_run, hf_block, lf, events, external, holes + view hf_long
        assert int(n["n"].iloc[0]) == 8
    with open_store(pg_database, create=False) as st:  # idempotent re-open
        assert st.recordings().empty


def test_block_layout(pg_url: str) -> None:
    # 2500 rows, 7 cycles missing after row 500: runs of 500 and 2000 cycles ->
    # blocks of 500 | 1000, 1000 per signal (blocks never cross a gap)
    rec = make_recording(machine="m1", start="2024-03-02T08:00:00", n=2500, gap=(500, 7))
    with open_store(pg_url) as st:
        rid = st.ingest(rec)
        blocks = st.sql(
            "SELECT signal, first_cycle, n, t0_ns, cardinality(samples) AS len FROM hf_block "
            f"WHERE recording_id = '{rid}' ORDER BY signal, first_cycle"
        )
        runs = st.sql(f"SELECT first_cycle, n FROM hf_run WHERE recording_id = '{rid}' "
                      "ORDER BY first_cycle")
    assert len(blocks) == 9
    one = blocks[blocks["signal"] == "ENC_POS|X1"]
    assert one["first_cycle"].tolist() == [1000, 1507, 2507]
    assert one["n"].tolist() == one["len"].tolist() == [500, 1000, 1000]
    t0 = np.datetime64("2024-03-02T08:00:00", "ns").astype(np.int64)
    # t0 of each block = start + (cycle - 1000) x 2 ms
    assert one["t0_ns"].tolist() == [t0 + (c - 1000) * 2_000_000 for c in (1000, 1507, 2507)]
    assert runs.to_dict("list") == {"first_cycle": [1000, 1507], "n": [500, 2000]}


def test_bytes_per_sample(pg_url: str) -> None:
    """float8[] blocks: ~8 B/sample on disk, against ~42 B/sample for one row per value
    (docs/reference/physics-and-performance.md section 5, measured on this 2-vCPU machine)."""
    rec = make_recording(machine="m1", start="2024-03-02T08:00:00", n=60_000)
    with open_store(pg_url) as st:
        st.ingest(rec)
        size = st.sql("SELECT pg_total_relation_size('hf_block') AS b")["b"].iloc[0]
    per_sample = int(size) / (60_000 * 3)
    assert 4.0 < per_sample < 9.5
