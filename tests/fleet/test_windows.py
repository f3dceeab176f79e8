"""Shift windows and task sizing of the fleet health job (issue 28, point 3).

* :func:`cnctwin.fleet.partitions` with ``window_s``: per (machine, day) and shift, the
  shift's first recordings, whole, until the window is covered; a stream longer than
  ``max(window_s, LONG_RECORDING_S)`` only its first seconds; the night shift's morning part
  is a shift of its own. Checked on a store of synthetic recordings with known start times.
* :func:`cnctwin.fleet.split_partitions`: the rule that keeps 16 workers busy (4 tasks per
  worker, split at recording boundaries) on a fleet of few large partitions, and the health
  table of the pieces equals the unsplit partitions' (the fleet's recordings re-ingested as
  one machine: 2 partitions of 4 recordings each).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from tests.fleet.conftest import cnctwin

pytestmark = pytest.mark.xdist_group("fleet")


def _rec(start: str, seconds: float, machine: str = "M1") -> object:
    from cnctwin.recording import Recording

    n = round(seconds / 0.002)
    x = np.sin(np.arange(n) / 500.0)
    return Recording.from_arrays(np.arange(n), {"DES_POS|X1": x, "ENC_POS|X1": x},
                                 start_time=start, machine=machine)


@pytest.fixture(scope="module")
def shift_store(tmp_path_factory: pytest.TempPathFactory) -> str:
    import cnctwin.store

    url = str(tmp_path_factory.mktemp("shifts") / "store")
    recs = [("2026-03-02T03:00:00Z", 12.0),   # night shift (22-06) of the day before
            ("2026-03-02T06:10:00Z", 12.0),   # early shift: 12 s, then 12 s covers 20 s
            ("2026-03-02T06:30:00Z", 12.0),
            ("2026-03-02T07:00:00Z", 12.0),   # not needed
            ("2026-03-02T15:00:00Z", 1500.0),  # late shift: a 25-min stream, cut to 600 s
            ("2026-03-02T15:40:00Z", 12.0),
            ("2026-03-02T23:30:00Z", 8.0)]    # night shift
    with cnctwin.store.open(url, create=True) as st:
        for start, s in recs:
            st.ingest(_rec(start, s))  # type: ignore[arg-type]
    return url


def test_each_shift_gets_its_first_recordings_until_the_window(shift_store: str) -> None:
    from cnctwin.fleet import LONG_RECORDING_S, partitions

    (full,) = partitions(shift_store)
    (win,) = partitions(shift_store, window_s=20.0)
    assert full.n_cycles == full.recorded_cycles == round((5 * 12 + 8 + 1500) / 0.002)
    assert win.recorded_cycles == full.recorded_cycles
    starts = {rid: i for i, rid in enumerate(full.recording_ids)}  # start order
    picked = [starts[r] for r in win.recording_ids]
    assert picked == [0, 1, 2, 4, 6]  # 07:00 (window covered) and 15:40 (stream) left out
    lengths = [b - a + 1 for a, b in win.cycle_ranges]
    assert lengths == [6000, 6000, 6000, round(LONG_RECORDING_S / 0.002), 4000]
    assert win.n_cycles == sum(lengths)
    # a window longer than the stream limit cuts the stream there instead
    (wide,) = partitions(shift_store, window_s=900.0)
    assert [b - a + 1 for a, b in wide.cycle_ranges][4] == round(900.0 / 0.002)
    with pytest.raises(Exception, match="window_s"):
        partitions(shift_store, window_s=0.0)


def test_the_store_reads_only_the_window_and_the_columns(shift_store: str) -> None:
    import cnctwin.store
    from cnctwin.fleet import partitions

    (win,) = partitions(shift_store, window_s=20.0)
    rid, (a, b) = win.recording_ids[3], win.cycle_ranges[3]
    with cnctwin.store.open(shift_store, read_only=True) as st:
        whole = st.load(rid)
        part = st.load(rid, signals=["ENC_POS"], cycles=(a, b))
    assert part.columns == ["ENC_POS|X1"] and part.n_cycles == b - a + 1
    pd.testing.assert_frame_equal(part.hf, whole.select(signals=["ENC_POS"], cycles=(a, b)).hf)


def test_split_rule_keeps_16_workers_busy_and_the_table_unchanged(
        fleet_dir: Path, tmp_path: Path) -> None:
    from cnctwin.fleet import (
        health_estimates,
        health_partition,
        health_table,
        partitions,
        run_job,
        split_partitions,
    )

    # few large partitions: 4 machines' recordings of both days ingested as one machine
    src = tmp_path / "big"
    for m in ("M001", "M002", "M003", "M004"):
        for f in (fleet_dir / m).rglob("*"):
            if f.is_file():
                dest = src / m / f.relative_to(fleet_dir / m)
                dest.parent.mkdir(parents=True, exist_ok=True)
                dest.write_bytes(f.read_bytes())
    store = str(tmp_path / "store")
    cnctwin("fleet", "ingest", str(src), "--store", store, "--machine", "BIG",
            "--workers", "1")
    parts = partitions(store)
    assert [len(p.recording_ids) for p in parts] == [4, 4]
    pieces = split_partitions(parts, n_tasks=4 * 16)
    # 64 wanted; a piece is never smaller than one recording: 8 tasks of one recording each
    assert len(pieces) == 8 and all(len(p.recording_ids) == 1 for p in pieces)
    assert [r for p in pieces for r in p.recording_ids] == [
        r for p in parts for r in p.recording_ids]  # order kept
    assert len(split_partitions(parts, n_tasks=4)) == 4  # 2 workers: halves
    whole = run_job(health_partition, parts, client=None, store_url=store)
    split = health_table(run_job(health_estimates, pieces, client=None, store_url=store))
    key = ["machine", "day", "component", "parameter"]
    pd.testing.assert_frame_equal(split.sort_values(key, ignore_index=True),
                                  whole.sort_values(key, ignore_index=True))
    assert (whole["n"] == 4).any()  # the day's 4 recordings combined


@pytest.mark.parametrize("bad", [["--window-s", "0"], ["--window-s", "x"],
                                 ["--window-s", "20", "--all-cycles"], ["--shift-hours", "-1"]])
def test_bad_window_options_are_one_line(shift_store: str, tmp_path: Path,
                                         bad: list[str]) -> None:
    res = cnctwin("fleet", "health", "--store", shift_store, "--out", str(tmp_path / "r"),
                  *bad, check=False)
    assert res.returncode == 2
    assert "Traceback" not in res.stderr
    assert ("--window-s" in res.stderr or "--shift-hours" in res.stderr
            or "--all-cycles" in res.stderr), res.stderr
