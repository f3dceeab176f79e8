"""DuckDB/Parquet backend specifics: file layout, URL forms, machine names, plain-Parquet reads.

The behaviour shared with PostgreSQL is in ``test_store_backends.py``.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pyarrow.parquet as pq
import pytest

from cnctwin.exceptions import ConfigError, StoreError
from cnctwin.store import DuckDBStore
from cnctwin.store import open as open_store

from .store_helpers import make_recording


def test_open_url_forms(tmp_path: Path) -> None:
    for url in (str(tmp_path / "a"), f"file://{tmp_path / 'b'}", f"duckdb://{tmp_path / 'c'}",
                tmp_path / "d"):
        with open_store(url) as st:
            assert isinstance(st, DuckDBStore)
        assert (Path(str(url).split("://")[-1]) / "catalog.duckdb").exists()
    with pytest.raises(ConfigError, match="not supported"):
        open_store("s3://bucket/store")
    with pytest.raises(StoreError, match="no cnctwin store"):
        open_store(tmp_path / "missing", create=False)
    assert not (tmp_path / "missing").exists()


def test_layout_partitions_by_machine_and_day(tmp_path: Path) -> None:
    # 23:59:58 + 1500 cycles: 1000 cycles (2 s) before midnight, 500 after
    rec = make_recording(machine="m1", start="2024-03-01T23:59:58", n=1500)
    with open_store(tmp_path) as st:
        rid = st.ingest(rec)
    d1 = tmp_path / "hf" / "machine=m1" / "day=2024-03-01" / f"{rid}.parquet"
    d2 = tmp_path / "hf" / "machine=m1" / "day=2024-03-02" / f"{rid}.parquet"
    t1, t2 = pq.read_table(d1), pq.read_table(d2)  # plain pyarrow reads the files
    assert (t1.num_rows, t2.num_rows) == (1000, 500)
    assert t1.column_names == ["recording_id", "cycle", "time", "CURRENT|SP1", "ENC_POS|X1",
                               "ENC_POS|Y1"]
    assert t1.schema.field("CURRENT|SP1").metadata == {b"unit": b"A"}
    assert t2.column("cycle")[0].as_py() == 2000
    assert t2.column("time")[0].as_py() == pd.Timestamp("2024-03-02T00:00:00Z")
    assert (tmp_path / "lf" / "machine=m1" / f"{rid}.parquet").exists()
    assert (tmp_path / "events" / "machine=m1" / f"{rid}.parquet").exists()
    assert not list(tmp_path.rglob("*.tmp"))


def test_reingest_removes_stale_day_files(tmp_path: Path) -> None:
    with open_store(tmp_path) as st:
        st.ingest(make_recording(machine="m1", start="2024-03-01T23:59:58", n=1500),
                  recording_id="job")
        st.ingest(make_recording(machine="m1", start="2024-03-02T10:00:00", n=10),
                  recording_id="job")
    assert sorted(p.parent.name for p in (tmp_path / "hf").rglob("*.parquet")) == [
        "day=2024-03-02"]


def test_odd_machine_name(tmp_path: Path) -> None:
    name = "Halle 3/DMU 50 (ü)"
    with open_store(tmp_path) as st:
        rid = st.ingest(make_recording(machine=name, start="2024-03-02T08:00:00", n=50))
        assert list(st.recordings(machine=name)["recording_id"]) == [rid]
        assert len(st.query_signals(["CURRENT"], machine=name)) == 50
        wide = st.sql("SELECT DISTINCT machine, day FROM hf")
    (d,) = [p for p in (tmp_path / "hf").iterdir()]
    assert "/" not in d.name[len("machine="):] and " " not in d.name
    assert d.name == "machine=Halle%203%2FDMU%2050%20%28%C3%BC%29"
    assert wide["machine"].iloc[0] == name  # DuckDB decodes the hive value


def test_wide_hf_view(tmp_path: Path) -> None:
    with open_store(tmp_path) as st:
        st.ingest(make_recording(machine="m1", start="2024-03-01T23:59:58", n=1500))
        st.ingest(make_recording(machine="m2", start="2024-03-02T08:00:00", n=100))
        per_day = st.sql(
            "SELECT machine, CAST(day AS VARCHAR) AS day, count(*) AS n, "
            "max(\"ENC_POS|X1\") AS x_max FROM hf GROUP BY ALL ORDER BY machine, day"
        )
    assert per_day[["machine", "day", "n"]].to_dict("list") == {
        "machine": ["m1", "m1", "m2"], "day": ["2024-03-01", "2024-03-02", "2024-03-02"],
        "n": [1000, 500, 100]}
    # ENC_POS|X1 = 0.01 mm x cycle; the last m1 cycle is 1000 + 1499
    assert per_day["x_max"].iloc[1] == pytest.approx(24.99, abs=1e-9)


def test_empty_store_sql(tmp_path: Path) -> None:
    with open_store(tmp_path) as st:
        assert st.sql("SELECT count(*) AS n FROM hf_long")["n"].iloc[0] == 0
        assert st.sql("SELECT count(*) AS n FROM events")["n"].iloc[0] == 0
        assert st.recordings().empty


def test_closed_store_raises(tmp_path: Path) -> None:
    st = open_store(tmp_path)
    st.close()
    st.close()  # idempotent
    with pytest.raises(StoreError, match="closed"):
        st.recordings()
