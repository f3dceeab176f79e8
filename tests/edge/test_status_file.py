"""``status.json`` rewritten through two spare inodes (cnctwin.edge.status_file): readers see a
whole file at every moment, a restart never overwrites the current file in place, and the
temporary-file way takes over where hard links fail."""

from __future__ import annotations

import itertools
import json
import os
import stat
import threading
from pathlib import Path

import pytest

from cnctwin.edge.status_file import StatusFile


def _content(k: int) -> bytes:
    # lengths differ a lot, so that a torn read (old tail, new head) would not parse
    return json.dumps({"k": k, "pad": "x" * (3000 if k % 2 else 10)}).encode()


def test_a_reader_sees_only_whole_files_while_the_writer_rewrites(tmp_path: Path) -> None:
    """A reader that reads what it opened within one status interval (here 20 ms; a
    runtime's is 1 s) sees a whole file, never an older one after a newer one. (A naive
    writer, in place into ``status.json``, fails here: a few % of its rewrites read torn.)"""
    import time

    f = StatusFile(tmp_path / "status.json")
    f.write(_content(0))
    stop = threading.Event()
    seen: list[int] = []
    bad: list[bytes] = []

    def reader() -> None:
        while not stop.is_set():
            data = (tmp_path / "status.json").read_bytes()
            try:
                seen.append(json.loads(data)["k"])
            except ValueError:
                bad.append(data[:80])

    th = threading.Thread(target=reader)
    th.start()
    try:
        for k in range(1, 200):
            f.write(_content(k))
            time.sleep(0.02)
    finally:
        stop.set()
        th.join()
    assert not bad, f"{len(bad)} torn reads, e.g. {bad[0]!r}"
    back = [(a, b) for a, b in itertools.pairwise(seen) if b < a]
    assert not back, f"an older file after a newer one: {back[:5]}"
    assert json.loads((tmp_path / "status.json").read_bytes())["k"] == 199
    assert f.swapping
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == [".status.json.a", ".status.json.b", "status.json"]


def test_a_restart_writes_the_spare_that_is_not_the_current_file(tmp_path: Path) -> None:
    """The current ``status.json`` is also one spare's inode: a new writer must choose the
    other one (a reader holding the current file keeps its content), also when the last run
    died between the rename and the hard link (one spare name missing)."""
    path = tmp_path / "status.json"
    f = StatusFile(path)
    f.write(b'{"run": 1}')
    f.write(b'{"run": 2}')
    for crash_between_rename_and_link in (False, True):
        if crash_between_rename_and_link:
            cur = path.stat().st_ino
            for p in tmp_path.glob(".status.json.*"):
                if p.stat().st_ino == cur:
                    p.unlink()
        with path.open("rb") as held:
            before = held.read()
            g = StatusFile(path)
            g.write(b'{"run": 3}')
            held.seek(0)
            assert held.read() == before  # the file a reader had open was not rewritten
        assert path.read_bytes() == b'{"run": 3}'


def test_where_hard_links_fail_the_temporary_file_is_renamed_over(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def no_links(*a: object, **k: object) -> None:
        raise OSError(1, "Operation not permitted")

    monkeypatch.setattr(os, "link", no_links)
    f = StatusFile(tmp_path / "status.json")
    f.write(b"{}")
    f.write(b'{"a": 1}')
    assert not f.swapping
    assert (tmp_path / "status.json").read_bytes() == b'{"a": 1}'
    assert sorted(p.name for p in tmp_path.iterdir()) == ["status.json"]


def test_the_file_has_the_users_umask(tmp_path: Path) -> None:
    old = os.umask(0o022)
    try:
        f = StatusFile(tmp_path / "status.json")
        f.write(b"{}")
        f.write(b"{}")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "status.json").stat().st_mode) == 0o644


def test_the_latency_window_gives_numpys_percentiles_of_the_most_recent_values() -> None:
    """The status's p50/p99/max come from a window kept sorted as values arrive; checked
    against numpy's percentile of the last ``size`` values (ties and evictions included)."""
    import numpy as np

    from cnctwin.edge.runtime import LatencyWindow

    rng = np.random.default_rng(7)
    values = np.round(rng.lognormal(-5, 1, 3000), 4)  # rounded: many ties
    w = LatencyWindow(500)
    assert np.isnan(w.percentile(50)) and len(w) == 0
    for i, v in enumerate(values):
        w.append(float(v))
        if i % 97 == 0 or i == values.size - 1:
            last = values[max(0, i - 499):i + 1]
            assert len(w) == last.size
            for q in (0, 1, 50, 99, 100):
                assert w.percentile(q) == pytest.approx(np.percentile(last, q), rel=1e-12)
            assert w.max() == last.max()
