"""Behaviour every store backend must show (run once per backend: DuckDB, PostgreSQL).

Synthetic recordings come from ``conftest.make_recording``: CURRENT|SP1 is a 3 A, 5 Hz sine
of the cycle counter time and ENC_POS|X1 is 0.01 mm per cycle, so values read back are checked
against those closed forms at the returned cycles (not against the stored frame).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd
import pytest

from cnctwin.exceptions import SignalNotFoundError, StoreError
from cnctwin.recording import Recording
from cnctwin.store import Store
from cnctwin.store import open as open_store
from cnctwin.store.base import normalize_events, normalize_lf

from .store_helpers import current_a, make_recording, position_mm

STEP = pd.Timedelta("2ms")


@pytest.fixture
def three(store: Store) -> dict[str, Any]:
    """Two machines; m1 has a midnight-spanning recording with a gap and one in the morning."""
    recs = {
        # 23:59:58 + 3000 cycles (6 s) crosses midnight; 25 cycles missing after row 500
        "night": make_recording(machine="m1", start="2024-03-01T23:59:58", n=3000,
                                gap=(500, 25), extra=True),
        "morning": make_recording(machine="m1", start="2024-03-02T08:00:00", n=2000,
                                  first_cycle=9_000_000),
        "other": make_recording(machine="m2", start="2024-03-02T08:00:01", n=1500),
    }
    ids = {k: store.ingest(r) for k, r in recs.items()}
    return {"recs": recs, "ids": ids}


def test_ingest_is_idempotent_per_id(store: Store) -> None:
    rec = make_recording(machine="m1", start="2024-03-02T08:00:00", n=1200)
    rid1 = store.ingest(rec)
    rid2 = store.ingest(rec)  # same content -> same deterministic id -> replaced, not doubled
    assert rid1 == rid2
    cat = store.recordings()
    assert list(cat["recording_id"]) == [rid1]
    assert int(cat["n_cycles"].iloc[0]) == 1200
    n = store.sql(f"SELECT count(*) AS n FROM hf_long WHERE recording_id = '{rid1}'")
    assert int(n["n"].iloc[0]) == 1200 * 3  # 3 signals x 1200 cycles, nothing doubled


def test_reingest_same_id_replaces_content(store: Store) -> None:
    long = make_recording(machine="m1", start="2024-03-01T23:59:59", n=1500)  # 2 days
    short = make_recording(machine="m1", start="2024-03-02T08:00:00", n=100)  # 1 day
    store.ingest(long, recording_id="job-1")
    store.ingest(short, recording_id="job-1")
    back = store.load("job-1")
    assert back.n_cycles == 100
    assert back.hf["time"].iloc[0] == pd.Timestamp("2024-03-02T08:00:00Z")
    q = store.query_signals(["ENC_POS|X1"], start="2024-03-01", end="2024-03-03")
    assert len(q) == 100  # the first version's rows (both days) are gone


def test_recordings_catalog(store: Store, three: dict[str, Any]) -> None:
    cat = store.recordings()
    assert len(cat) == 3
    night = cat.set_index("recording_id").loc[three["ids"]["night"]]
    assert night["machine"] == "m1"
    # 3000 rows, gap of 25 -> last cycle = 1000 + 2999 + 25
    assert int(night["first_cycle"]) == 1000
    assert int(night["last_cycle"]) == 1000 + 2999 + 25
    assert int(night["n_cycles"]) == 3000
    assert int(night["n_gaps"]) == 1
    assert bool(night["partial"]) is True
    assert pd.Timestamp(night["start_time"]) == pd.Timestamp("2024-03-01T23:59:58Z")
    assert pd.Timestamp(night["end_time"]) == pd.Timestamp("2024-03-01T23:59:58Z") + (
        2999 + 25
    ) * STEP
    import json

    assert json.loads(night["columns"]) == ["CURRENT|SP1", "ENC_POS|X1", "ENC_POS|Y1"]
    assert json.loads(night["units"]) == {"CURRENT|SP1": "A", "ENC_POS|X1": "mm",
                                          "ENC_POS|Y1": "mm"}
    assert len(json.loads(night["issues"])) == 2
    # filters
    assert set(store.recordings(machine="m2")["recording_id"]) == {three["ids"]["other"]}
    day2 = store.recordings(start="2024-03-02T00:00:00Z", end="2024-03-02T07:00:00Z")
    assert list(day2["recording_id"]) == [three["ids"]["night"]]  # overlaps past midnight
    assert store.recordings(machine="m9").empty


def test_query_across_midnight_and_gap(store: Store, three: dict[str, Any]) -> None:
    rid = three["ids"]["night"]
    start = pd.Timestamp("2024-03-01T23:59:59.990Z")
    end = pd.Timestamp("2024-03-02T00:00:00.010Z")
    q = store.query_signals(["CURRENT|SP1", "ENC_POS|X1"], start=start, end=end,
                            recording_id=rid)
    # inclusive range of 20 ms at 2 ms = 11 cycles, all after the gap (gap is at 1 s)
    assert len(q) == 11
    assert q.index.name == "cycle"
    assert list(q.columns) == ["time", "CURRENT|SP1", "ENC_POS|X1"]
    assert q["time"].iloc[0] == start and q["time"].iloc[-1] == end
    assert np.all(np.diff(q.index.to_numpy()) == 1)
    c = q.index.to_numpy()
    np.testing.assert_allclose(q["CURRENT|SP1"].to_numpy(), current_a(c), rtol=0, atol=1e-12)
    np.testing.assert_allclose(q["ENC_POS|X1"].to_numpy(), position_mm(c), rtol=0, atol=1e-12)
    # the whole recording: 3000 rows, the 25-cycle gap is kept as a jump in the counter
    full = store.query_signals(["ENC_POS|X1"], recording_id=rid)
    assert len(full) == 3000
    steps = np.diff(full.index.to_numpy())
    assert sorted(set(steps.tolist())) == [1, 26]
    assert int(np.flatnonzero(steps == 26)[0]) == 499


def test_query_by_machine_and_codes(store: Store, three: dict[str, Any]) -> None:
    q = store.query_signals(["ENC_POS"], machine="m1", start="2024-03-02T08:00:00Z",
                            end="2024-03-02T08:00:01Z")
    # code expands to every axis; only the morning recording of m1 overlaps: 501 cycles
    assert list(q.columns) == ["time", "ENC_POS|X1", "ENC_POS|Y1"]
    assert q.index.names == ["recording_id", "cycle"]
    assert set(q.index.get_level_values(0)) == {three["ids"]["morning"]}
    assert len(q) == 501
    both = store.query_signals(["CURRENT|SP1"], start="2024-03-02T08:00:01Z",
                               end="2024-03-02T08:00:01.004Z")
    # m1 morning (cycles at 08:00:01.000/.002/.004) and m2 other (starts 08:00:01.000)
    assert both.groupby(level=0).size().to_dict() == {
        three["ids"]["morning"]: 3, three["ids"]["other"]: 3}


def test_query_unknown_signal_raises(store: Store, three: dict[str, Any]) -> None:
    with pytest.raises(SignalNotFoundError, match=r"TORQUE.*available columns.*CURRENT\|SP1"):
        store.query_signals(["TORQUE"], machine="m1")


def test_query_empty_range(store: Store, three: dict[str, Any]) -> None:
    q = store.query_signals(["CURRENT|SP1"], start="2030-01-01", end="2030-01-02")
    assert q.empty
    assert list(q.columns) == ["time", "CURRENT|SP1"]


def test_load_round_trip(store: Store, three: dict[str, Any]) -> None:
    orig: Recording = three["recs"]["night"]
    back = store.load(three["ids"]["night"])
    pd.testing.assert_frame_equal(back.hf, orig.hf)  # bit-exact float64 and ns times
    # events and LF come back in the canonical dtypes (texts object/None, ints Int64)
    pd.testing.assert_frame_equal(back.events, normalize_events(orig.events))
    assert back.events["gcode"].tolist() == ["M17", None, "G1 X10 F400"]
    assert back.events["channel"].tolist() == [1, 1, pd.NA]
    pd.testing.assert_frame_equal(back.lf, normalize_lf(orig.lf))
    assert back.lf["value"].tolist()[1:] == [41.5, 42.25]
    assert back.lf["text"].tolist()[0] == "182437"
    assert back.meta.gaps == orig.meta.gaps
    assert back.meta.issues == orig.meta.issues
    assert back.meta.partial is True
    assert back.meta.axis_map == orig.meta.axis_map
    assert back.meta.units == orig.meta.units
    assert back.meta.time_anchors == orig.meta.time_anchors
    assert back.meta.attrs == orig.meta.attrs
    assert back.meta.source_files == orig.meta.source_files
    ext = back.external["dynamometer"]
    pd.testing.assert_frame_equal(ext.data, orig.external["dynamometer"].data)
    assert (ext.fs_hz, ext.offset_s, ext.drift_ppm, ext.aligned, ext.units) == (
        2.0, 0.25, 12.0, True, {"torque_nm": "Nm"})


def test_load_unknown_raises(store: Store) -> None:
    with pytest.raises(StoreError, match="not in the store"):
        store.load("nope")


def test_sql_views(store: Store, three: dict[str, Any]) -> None:
    rid = three["ids"]["night"]
    per_signal = store.sql(
        f"SELECT signal, count(*) AS n, min(cycle) AS c0 FROM hf_long "
        f"WHERE recording_id = '{rid}' GROUP BY signal ORDER BY signal"
    )
    assert per_signal["signal"].tolist() == ["CURRENT|SP1", "ENC_POS|X1", "ENC_POS|Y1"]
    assert per_signal["n"].astype(int).tolist() == [3000] * 3
    assert per_signal["c0"].astype(int).tolist() == [1000] * 3
    v = store.sql(
        f"SELECT value FROM hf_long WHERE recording_id = '{rid}' "
        "AND signal = 'ENC_POS|X1' AND cycle = 2000"
    )
    assert float(v["value"].iloc[0]) == pytest.approx(20.0, abs=1e-12)  # 0.01 mm x 2000
    t = store.sql(
        f"SELECT time FROM hf_long WHERE recording_id = '{rid}' "
        "AND signal = 'ENC_POS|X1' AND cycle = 1000"
    )
    assert pd.Timestamp(t["time"].iloc[0]).tz_localize(None) == pd.Timestamp(
        "2024-03-01T23:59:58") or pd.Timestamp(t["time"].iloc[0]) == pd.Timestamp(
        "2024-03-01T23:59:58Z")
    ev = store.sql(f"SELECT count(*) AS n FROM events WHERE recording_id = '{rid}'")
    assert int(ev["n"].iloc[0]) == 3
    lf = store.sql(f"SELECT count(*) AS n FROM lf WHERE recording_id = '{rid}'")
    assert int(lf["n"].iloc[0]) == 3
    r = store.sql("SELECT count(*) AS n FROM recordings")
    assert int(r["n"].iloc[0]) == 3


def test_sql_error_is_store_error(store: Store) -> None:
    with pytest.raises(StoreError, match="hf_long"):
        store.sql("SELECT * FROM no_such_table")


def test_delete(store: Store, three: dict[str, Any]) -> None:
    assert store.delete(three["ids"]["other"]) is True
    assert store.delete(three["ids"]["other"]) is False
    assert len(store.recordings()) == 2
    with pytest.raises(StoreError):
        store.load(three["ids"]["other"])


def test_reopen_sees_data(store_url: str) -> None:
    rec = make_recording(machine="m1", start="2024-03-02T08:00:00", n=300)
    with open_store(store_url) as st:
        rid = st.ingest(rec)
    with open_store(store_url, create=False) as st:
        assert list(st.recordings()["recording_id"]) == [rid]
        assert st.load(rid).n_cycles == 300


def test_bad_recording_id(store: Store) -> None:
    from cnctwin.exceptions import ConfigError

    rec = make_recording(machine="m1", start="2024-03-02T08:00:00", n=10)
    with pytest.raises(ConfigError, match="recording id"):
        store.ingest(rec, recording_id="../escape")


# ---------------------------------------------------------------------------- real data
def test_real_c4a_round_trip(store: Store, c4a_rec: Recording, c4a_raw: dict[str, Any]) -> None:
    rid = store.ingest(c4a_rec)
    cat = store.recordings(machine="sinumerik_adapter_840Dsl")
    assert list(cat["recording_id"]) == [rid]
    # Payload[*].HFData holds 3818 rows (counted in the file); one counter gap (the C4A sample
    # is known to miss cycles: signals.py CYCLE note)
    n_rows = sum(len(p["HFData"]) for p in c4a_raw["Payload"] if "HFData" in p)
    assert int(cat["n_cycles"].iloc[0]) == n_rows == c4a_rec.n_cycles
    back = store.load(rid)
    pd.testing.assert_frame_equal(back.hf, c4a_rec.hf)
    assert back.meta.gaps == c4a_rec.meta.gaps
    assert back.meta.issues == c4a_rec.meta.issues
    assert len(back.events) == len(c4a_rec.events)
    assert len(back.lf) == len(c4a_rec.lf)
    # values straight from the file: the first HFData row (cycle 5558098); column order of
    # Header.SignalListHFData (index 0 is CYCLE)
    first = next(p["HFData"] for p in c4a_raw["Payload"] if "HFData" in p)[0]
    sig_list = c4a_raw["Header"]["SignalListHFData"]
    wanted = {f"{s['Address'].split('|')[0]}|{s['Axis']}": first[i]
              for i, s in enumerate(sig_list) if i > 0}
    q = store.query_signals(list(wanted), recording_id=rid)
    assert q.index[0] == first[0] == 5558098
    for col, raw in wanted.items():
        assert q[col].iloc[0] == pytest.approx(raw, abs=1e-12), col
    cur = store.query_signals(["CURRENT"], recording_id=rid)
    assert len(cur) == n_rows
    assert all(c.startswith("CURRENT|") for c in cur.columns[1:])
