"""The publish sink reconnects with exponential backoff (issue 14, point 5): not every 2 s
for ever while a broker is away, and at once again after it came back."""

from __future__ import annotations

import socket
import time
from pathlib import Path

from cnctwin.edge.sinks import MqttSink, reconnect_delay_s


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_delay_doubles_up_to_the_bound() -> None:
    got = [reconnect_delay_s(k, base_s=0.5, max_s=5.0) for k in range(8)]
    assert got == [0.5, 0.5, 1.0, 2.0, 4.0, 5.0, 5.0, 5.0]


def test_attempts_back_off_while_the_broker_is_away(tmp_path: Path) -> None:
    # nothing listens on the port: every attempt is refused at once
    sink = MqttSink("127.0.0.1", _free_port(), state_dir=tmp_path, machine="m1",
                    retry_s=0.1, max_retry_s=0.8)
    try:
        end = time.monotonic() + 3.0
        while time.monotonic() < end:
            sink.pump()
            time.sleep(0.005)
        # waits 0.1, 0.2, 0.4, 0.8, 0.8, ... (+-10 %): attempts at 0, 0.1, 0.3, 0.7, 1.5, 2.3
        # and ~3.1 s (6, or 7 with the jitter); a fixed 0.1 s would have made ~30
        assert 5 <= sink.attempts <= 7, sink.attempts
        st = sink.status()
        assert st["failed_attempts"] == sink.attempts
        assert 0.0 <= st["retry_in_s"] <= 0.88
        assert "refused" in st["last_error"] or "connect" in st["last_error"]
    finally:
        sink.close(timeout_s=0.1)
