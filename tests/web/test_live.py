"""Live view: the results.jsonl of a real `cnctwin edge run` replay served as Server-Sent
Events, and the tail behaviour (partial lines, a new run truncating the file)."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from typing import Any

import pytest

from cnctwin.exceptions import ConfigError
from cnctwin.web.live import LiveSource, sse_event, tail_lines


@pytest.fixture(scope="module")
def edge_out(live_dir: Path) -> Path:
    """State directory of `cnctwin edge run` replaying the 12-hole wear run (conftest)."""
    return live_dir


def _events(text: str) -> list[tuple[str, str, str]]:
    out = []
    for block in text.strip().split("\n\n"):
        fields = dict(line.split(": ", 1) for line in block.splitlines() if ": " in line)
        out.append((fields.get("event", ""), fields.get("id", ""), fields.get("data", "")))
    return out


def test_stream_replays_results(edge_out: Path) -> None:
    from fastapi.testclient import TestClient

    from cnctwin.web import create_app

    lines = (edge_out / "results.jsonl").read_text().splitlines()
    with TestClient(create_app(live=edge_out)) as c:  # live only: no store, no files
        r = c.get("/api/live/stream", params={"from_start": "true", "limit": 40})
        assert r.status_code == 200 and r.headers["content-type"].startswith("text/event-stream")
        *ev, end = _events(r.text)
        assert end == ("end", "", '{"events": 40, "finished": false}')  # the browser closes on it
        assert [e[2] for e in ev] == lines[:40]  # every line, in order, unchanged
        assert all(e[0] == json.loads(e[2])["kind"] for e in ev)
        assert [e[1] for e in ev] == [str(json.loads(x)["seq"]) for x in lines[:40]]
        *holes, _ = _events(c.get("/api/live/stream", params={"from_start": "true",
                                                              "limit": 12, "kinds": "hole"}).text)
        assert [json.loads(e[2])["hole"] for e in holes] == list(range(12))
        st = c.get("/api/live/status").json()
        assert st["holes"] == 12 and st["results"] == str(edge_out / "results.jsonl")
        page = c.get("/live").text
        assert "EventSource" not in page and 'data-page="live"' in page


def test_no_live_source(client: Any) -> None:
    r = client.get("/api/live/status")
    assert r.status_code == 422 and "--live DIR" in r.json()["detail"]


def test_missing_live_dir(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cnctwin edge run"):
        LiveSource(tmp_path / "nope")


def test_tail_follows_appends_partial_lines_and_truncation(tmp_path: Path) -> None:
    f = tmp_path / "results.jsonl"
    f.write_text('{"seq": 0}\n')

    async def run() -> list[str]:
        got: list[str] = []
        it = tail_lines(f, from_start=False, poll_s=0.01)

        async def nxt() -> str:
            return await asyncio.wait_for(it.__anext__(), timeout=2.0)

        task = asyncio.ensure_future(nxt())
        await asyncio.sleep(0.05)
        with f.open("a") as fh:  # half a line, then the rest
            fh.write('{"seq": 1, "ki')
            fh.flush()
            await asyncio.sleep(0.05)
            assert not task.done()
            fh.write('nd": "torque"}\n')
        got.append(await task)
        f.write_text('{"seq": 0, "run": 2}\n')  # a new run: the file shrinks
        got.append(await nxt())
        await it.aclose()  # type: ignore[attr-defined]
        return got

    assert asyncio.run(run()) == ['{"seq": 1, "kind": "torque"}', '{"seq": 0, "run": 2}']


def test_sse_event_format() -> None:
    assert sse_event('{"a": 1}', event="hole", event_id="7") == \
        'event: hole\nid: 7\ndata: {"a": 1}\n\n'
    assert sse_event("a\nb") == "data: a\ndata: b\n\n"


def test_client_leaving_mid_stream_closes_cleanly(tmp_path: Path) -> None:
    # issue 14: a browser tab closed while the stream waits for the next line logged
    # "RuntimeError: aclose(): asynchronous generator is already running"
    (tmp_path / "results.jsonl").write_text(
        '{"kind": "torque", "seq": 0}\n{"kind": "torque", "seq": 1}\n')
    live = LiveSource(tmp_path)

    async def leave_after_two() -> list[str]:
        gen = live.events(from_start=True, poll_s=0.02, heartbeat_s=5.0)
        got = [await gen.__anext__(), await gen.__anext__()]
        # the third event waits for a line that never comes: the pending tail is running
        task = asyncio.ensure_future(gen.__anext__())
        await asyncio.sleep(0.1)
        task.cancel()  # what the server does when the client disconnects
        with pytest.raises(asyncio.CancelledError):
            await task
        await gen.aclose()  # must not raise
        return got

    got = asyncio.run(leave_after_two())
    assert [e.split("\n")[0] for e in got] == ["event: torque", "event: torque"]
