"""Results rotation and retention (issue 14, point 5: ~2.2 GB per machine-day grew without
bound). The sink rotates by size and keeps a bounded number of files, counting what it
deletes; the dashboard's tail follows a rotation without skipping a line."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest

from cnctwin.edge import JsonLinesSink
from cnctwin.exceptions import ConfigError
from cnctwin.web.live import tail_lines


def _msgs(start: int, n: int) -> list[dict[str, object]]:
    return [{"kind": "torque", "machine": "m1", "seq": s, "first_cycle": 50 * s, "n": 50,
             "torque_nm": [0.5] * 50} for s in range(start, start + n)]


def test_rotation_keeps_every_line_and_bounds_the_files(tmp_path: Path) -> None:
    path = tmp_path / "results.jsonl"
    sink = JsonLinesSink(path, rotate_bytes=20_000, keep_files=3)
    for k in range(0, 400, 10):
        sink.write(_msgs(k, 10), None)
    sink.close()
    st = sink.status()
    rotated = sink.rotated_files()
    assert len(rotated) == 3 and st["rotations"] > 3
    assert st["deleted_files"] == st["rotations"] - 3 and st["deleted_bytes"] > 0
    # what is kept is contiguous and ends with the last message; nothing in between is lost
    seqs = [json.loads(x)["seq"] for p in [*rotated, path]
            for x in p.read_text().splitlines()]
    assert seqs == list(range(seqs[0], 400))
    # each rotated file stopped at the first write that reached the bound
    assert all(20_000 <= p.stat().st_size < 20_000 + 10 * 300 for p in rotated)


def test_bad_rotation_options() -> None:
    with pytest.raises(ConfigError, match="rotate_bytes"):
        JsonLinesSink("x.jsonl", rotate_bytes=0)
    with pytest.raises(ConfigError, match="keep_files"):
        JsonLinesSink("x.jsonl", keep_files=0)


def test_live_tail_follows_a_rotation(tmp_path: Path) -> None:
    path = tmp_path / "results.jsonl"
    sink = JsonLinesSink(path, rotate_bytes=5_000)

    async def run() -> list[int]:
        it = tail_lines(path, from_start=True, poll_s=0.005)
        got: list[int] = []

        async def reader() -> None:
            async for line in it:
                got.append(json.loads(line)["seq"])
                if len(got) == 200:
                    return

        task = asyncio.ensure_future(reader())
        for k in range(0, 200, 5):  # several rotations while the reader follows
            sink.write(_msgs(k, 5), None)
            await asyncio.sleep(0.002)
        await asyncio.wait_for(task, timeout=10)
        return got

    got = asyncio.run(run())
    sink.close()
    assert sink.rotations >= 5
    assert got == list(range(200))


def test_jsonl_sink_ends_a_line_a_crash_tore(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """A kill -9 mid-write leaves a torn last line; the next run's first message must start
    a line of its own (before: it was glued to the torn one and both were lost to readers)."""
    import json

    from cnctwin.edge.sinks import JsonLinesSink

    p = tmp_path / "results.jsonl"
    p.write_bytes(b'{"kind": "hole", "row": {"hole": 1}}\n{"kind": "hole", "row": {"ho')
    sink = JsonLinesSink(p)
    sink.write([{"kind": "hole", "row": {"hole": 2}}], None)
    lines = p.read_bytes().split(b"\n")
    assert lines[1] == b'{"kind": "hole", "row": {"ho'  # kept, on its own line
    assert json.loads(lines[2])["row"]["hole"] == 2
    assert lines[-1] == b""
    # a file that ends cleanly gets nothing added
    q = tmp_path / "clean.jsonl"
    q.write_bytes(b'{"kind": "x"}\n')
    JsonLinesSink(q).write([{"kind": "y"}], None)
    got = q.read_bytes().split(b"\n")
    assert [json.loads(x)["kind"] for x in got[:-1]] == ["x", "y"] and got[-1] == b""
