"""Overload is visible (issue 14, point 2): a full input queue and a forward queue that
discards its oldest messages are counted in status.json, raised as alarm messages and shown by
``cnctwin edge status``; never silent."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from cnctwin.cli.edge import status_table
from cnctwin.edge import EdgeRuntime, JsonLinesSink, MqttSink, ReplaySource, TorqueProcessor
from cnctwin.edge.pipeline import Chunk
from cnctwin.spindle import SpindleModel
from tests._services import free_port


class _DroppingSource(ReplaySource):
    """A replay whose (simulated) receive queue drops 3 messages at every 10th chunk."""

    def __init__(self, path: Path) -> None:
        super().__init__(path, chunk_cycles=50)
        self.dropped = 0

    def chunks(self) -> Iterator[Chunk]:
        for k, ch in enumerate(super().chunks()):
            if k % 10 == 9:
                self.dropped += 3
            yield ch


def test_input_and_forward_losses_are_counted_and_alarmed(c4a_file: Path,
                                                          tmp_path: Path) -> None:
    model = SpindleModel.from_parameters("thesis_spinner_840dsl")
    src = _DroppingSource(c4a_file)
    # a broker that is never there and a forward queue of 20 messages: the oldest go
    mqtt = MqttSink("127.0.0.1", free_port(), state_dir=tmp_path, machine="m1",
                    max_queue_messages=20, retry_s=3600.0)
    rt = EdgeRuntime(src, [TorqueProcessor(model)],
                     [JsonLinesSink(tmp_path / "results.jsonl"), mqtt], state_dir=tmp_path,
                     machine="m1", status_every_s=0.0)
    final = rt.run()
    mqtt.close(timeout_s=0.1)
    assert final["overload"]["input_dropped"] == src.dropped > 0
    assert final["overload"]["forward_dropped"] > 0
    status = json.loads((tmp_path / "status.json").read_text())
    assert status["overload"]["input_dropped"] == src.dropped
    msgs = [json.loads(x) for x in (tmp_path / "results.jsonl").read_text().splitlines()]
    alarms = [m for m in msgs if m["kind"] == "alarm" and m["detector"] == "runtime-overload"]
    got = {k: sum(a["count"] for a in alarms if a["overload"] == k) for k in final["overload"]}
    assert got["input_dropped"] == final["overload"]["input_dropped"]  # every loss alarmed once
    # the forward queue is full: each alarm message itself displaces one more old message;
    # those of the last status round (at most one per counter) are counted, not alarmed again
    assert 0 <= final["overload"]["forward_dropped"] - got["forward_dropped"] <= 2
    text = _render(status_table(status))
    assert "LOSSES" in text and "input dropped" in text


def _render(table: Any) -> str:
    from rich.console import Console

    con = Console(record=True, width=200)
    con.print(table)
    return con.export_text()
