"""The per-hole table of the store (``append_holes`` / ``holes``), once per backend.

Hole rows are built here with the columns and dtypes of ``cnctwin.usecases.holes.hole_record``
(closed-form values, NaN and <NA> where the record has them); what is read back is compared
with those inputs. The edge test ``tests/edge/test_store_holes_edge.py`` checks rows computed
by the runtime against the batch ``hole_records``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd
import pytest

from cnctwin.exceptions import ConfigError, StoreError
from cnctwin.store import Store
from cnctwin.store import open as open_store
from cnctwin.store.base import HOLE_TABLE_COLUMNS
from cnctwin.usecases.holes import HOLE_COLUMNS

from .store_helpers import make_recording

T0 = pd.Timestamp("2024-03-02T08:00:00.123456789Z")  # ns part: SQL timestamps hold only us


def hole_frame(first: int, n: int, *, t0: pd.Timestamp = T0) -> pd.DataFrame:
    """``n`` hole rows numbered from ``first``, hole ``h`` cut at ``t0 + 2.5 h`` s, with
    hole_record's dtypes."""
    rows: list[dict[str, Any]] = []
    for k in range(n):
        h = first + k
        row: dict[str, Any] = {c: float(h) + 0.25 for c, kind in HOLE_TABLE_COLUMNS.items()
                               if kind == "float"}
        row.update({"hole": h, "set": h // 6, "position_in_set": h % 6,
                    "start_cycle": 1000 + 1250 * h, "cut_start_cycle": 1100 + 1250 * h,
                    "cut_end_cycle": 1900 + 1250 * h, "end_cycle": 1950 + 1250 * h,
                    "start_time": t0 + pd.Timedelta(seconds=2.5 * h),
                    "surface_source": "cycle", "tool": 3 if k % 2 == 0 else pd.NA,
                    "cycle": "CYCLE81" if k % 2 == 0 else ""})
        row["thrust_proxy"] = np.nan  # no Z drive values recorded
        rows.append(row)
    df = pd.DataFrame(rows, columns=list(HOLE_TABLE_COLUMNS))
    df["tool"] = df["tool"].astype("Int64")
    for col, kind in HOLE_TABLE_COLUMNS.items():
        if kind == "int" and col != "tool":
            df[col] = df[col].astype("int64")
    return df


@pytest.fixture
def two(store: Store) -> dict[str, str]:
    return {
        "a": store.ingest(make_recording(machine="m1", start="2024-03-02T08:00:00", n=500)),
        "b": store.ingest(make_recording(machine="m2", start="2024-03-02T09:00:00", n=500)),
    }


def _values(df: pd.DataFrame) -> pd.DataFrame:
    return df.drop(columns=["recording_id", "machine"]).reset_index(drop=True)


def test_schema_is_the_hole_record_columns() -> None:
    # the stored columns are hole_record's, in its order (HOLE_COLUMNS documents them)
    from cnctwin.usecases.holes import _columns

    assert list(HOLE_TABLE_COLUMNS) == _columns()
    documented = {c for c in HOLE_COLUMNS if not c.startswith("dev_")}
    assert documented <= set(HOLE_TABLE_COLUMNS)


def test_round_trip(store: Store, two: dict[str, str]) -> None:
    holes = hole_frame(0, 4)
    assert store.append_holes(two["a"], holes) == 4
    got = store.holes(recording_id=two["a"])
    assert list(got.columns) == ["recording_id", "machine", *HOLE_TABLE_COLUMNS]
    assert set(got["machine"]) == {"m1"} and set(got["recording_id"]) == {two["a"]}
    # exact: start_time keeps its nanoseconds, NaN stays NaN, <NA> tool stays <NA>
    pd.testing.assert_frame_equal(_values(got), holes)


def test_reappend_is_idempotent_and_replaces(store: Store, two: dict[str, str]) -> None:
    store.append_holes(two["a"], hole_frame(0, 3))
    store.append_holes(two["a"], hole_frame(0, 3))  # a restarted runtime sends them again
    assert store.holes()["hole"].tolist() == [0, 1, 2]
    changed = hole_frame(2, 2)  # hole 2 recomputed, hole 3 new
    changed["depth_mm"] = [20.006, 19.98]
    store.append_holes(two["a"], changed)
    got = store.holes(recording_id=two["a"])
    assert got["hole"].tolist() == [0, 1, 2, 3]
    assert got["depth_mm"].tolist()[2:] == [20.006, 19.98]


def test_filters(store: Store, two: dict[str, str]) -> None:
    store.append_holes(two["a"], hole_frame(0, 3))
    store.append_holes(two["b"], hole_frame(0, 2, t0=T0 + pd.Timedelta(hours=1)))
    assert len(store.holes()) == 5
    assert store.holes(machine="m2")["recording_id"].tolist() == [two["b"]] * 2
    # cut starts at T0, T0 + 2.5 s, T0 + 5 s (m1) and T0 + 1 h, + 2.5 s (m2)
    win = store.holes(start=T0 + pd.Timedelta(seconds=1), end=T0 + pd.Timedelta(seconds=5))
    assert win["hole"].tolist() == [1, 2] and set(win["machine"]) == {"m1"}
    late = store.holes(start="2024-03-02T08:30:00")
    assert late["machine"].tolist() == ["m2", "m2"]
    assert store.holes(machine="nope").empty
    assert list(store.holes(machine="nope").columns)[:3] == ["recording_id", "machine", "hole"]


def test_rows_from_edge_messages_and_extra_columns(store: Store, two: dict[str, str]) -> None:
    # the edge runtime's hole messages carry start_time as ISO text and may hold more keys
    holes = hole_frame(0, 2)
    rows: list[dict[str, Any]] = []
    for rec in holes.to_dict("records"):
        r = {str(k): v for k, v in rec.items()}
        r["start_time"] = r["start_time"].isoformat()
        r["tool"] = None if pd.isna(r["tool"]) else int(r["tool"])
        r["thrust_proxy"] = None
        r["wear_um"] = 12.5
        rows.append(r)
    store.append_holes(two["b"], rows)
    got = store.holes(recording_id=two["b"])
    assert got["wear_um"].tolist() == [12.5, 12.5]  # kept, not dropped
    pd.testing.assert_frame_equal(_values(got).drop(columns="wear_um"), holes)


def test_errors(store: Store, two: dict[str, str]) -> None:
    with pytest.raises(StoreError, match="not in the store"):
        store.append_holes("no-such-recording", hole_frame(0, 1))
    with pytest.raises(ConfigError, match="'hole' column"):
        store.append_holes(two["a"], pd.DataFrame({"depth_mm": [1.0]}))
    bad = hole_frame(0, 1)
    bad["depth_mm"] = bad["depth_mm"].astype(object)
    bad.loc[0, "depth_mm"] = "deep"
    with pytest.raises(ConfigError, match="depth_mm"):
        store.append_holes(two["a"], bad)
    with pytest.raises(ConfigError, match="twice"):
        store.append_holes(two["a"], pd.concat([hole_frame(0, 1)] * 2))
    assert store.holes().empty  # nothing half-written


def test_delete_and_reingest(store_url: str, two: dict[str, str], store: Store) -> None:
    store.append_holes(two["a"], hole_frame(0, 2))
    store.append_holes(two["b"], hole_frame(0, 1))
    # re-ingesting a recording replaces its signals and keeps its holes
    store.ingest(make_recording(machine="m1", start="2024-03-02T08:00:00", n=500),
                 recording_id=two["a"])
    assert len(store.holes(recording_id=two["a"])) == 2
    assert store.delete(two["a"])
    assert store.holes()["recording_id"].tolist() == [two["b"]]
    # visible from another connection, and to SQL
    store.close()
    with open_store(store_url) as again:
        assert again.holes()["hole"].tolist() == [0]
        assert int(again.sql("SELECT count(*) AS n FROM holes")["n"].iloc[0]) == 1


def test_a_store_made_before_a_hole_column_gets_it(store_url: str, backend: str) -> None:
    """``torque_last_nm`` came with issue 24: a store whose hole table predates it gets the
    column when opened for writing (NULL for the holes stored before), and keeps its holes."""
    with open_store(store_url) as st:
        rid = st.ingest(make_recording(machine="m1", start="2024-03-02T08:00:00", n=500))
        st.append_holes(rid, hole_frame(0, 2))
        if backend == "duckdb":
            st.con.execute("ALTER TABLE holes DROP COLUMN torque_last_nm")  # type: ignore[attr-defined]
        else:
            st.conn.execute("ALTER TABLE holes DROP COLUMN torque_last_nm")  # type: ignore[attr-defined]
    if backend == "duckdb":  # an old store read as it is: the column reads as NaN
        with open_store(store_url, read_only=True) as st:
            old = st.holes()
        assert len(old) == 2 and old["torque_last_nm"].isna().all()
    with open_store(store_url) as st:
        st.append_holes(rid, hole_frame(2, 1))
        got = st.holes(recording_id=rid)
    assert got["hole"].tolist() == [0, 1, 2]
    assert got["torque_last_nm"].isna().tolist() == [True, True, False]
    assert got["torque_last_nm"].iloc[2] == pytest.approx(2.25)
