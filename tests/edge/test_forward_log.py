"""The MQTT sink's outbox as an append-only log (:class:`cnctwin.edge.forward_log.ForwardLog`).

Checked against the SQLite queue it replaces (:class:`cnctwin.edge.forward.ForwardQueue`, a
different implementation of the same contract: SQLite keeps the rows): random sequences of
appends, acknowledgements (repeated, unknown and out of order among them), restarts and a
bound, with segments small enough that they roll and are deleted all the time, must leave
both with the same messages in the same order and the same counts. Then what only a log
has: a write cut off by a crash, a write that fails, the older SQLite outbox moved in.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cnctwin.edge import ForwardQueue
from cnctwin.edge import forward_log as fl
from cnctwin.edge.forward_log import ForwardLog
from cnctwin.exceptions import ConfigError


def _state(q: ForwardQueue | ForwardLog) -> tuple[object, ...]:
    return (q.enqueued, q.dropped, q.sent, len(q), q.peek(10_000))


_op = st.one_of(
    st.tuples(st.just("put"), st.lists(st.binary(max_size=40), max_size=6)),
    # acknowledge some of the queued (by position), plus ids never given or already gone
    st.tuples(st.just("ack"), st.lists(st.integers(0, 12), max_size=6),
              st.lists(st.integers(-3, 80), max_size=2)),
    st.tuples(st.just("restart")),
)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                 HealthCheck.function_scoped_fixture])
@given(ops=st.lists(_op, min_size=1, max_size=40), bound=st.integers(1, 9),
       segment=st.integers(1, 400))
def test_the_log_keeps_what_the_sqlite_queue_keeps(tmp_path_factory: pytest.TempPathFactory,
                                                   ops: list[tuple], bound: int,
                                                   segment: int) -> None:
    d = tmp_path_factory.mktemp("q")
    ref = ForwardQueue(d / "ref.sqlite", max_messages=bound)
    log = ForwardLog(d / "log", max_messages=bound, segment_bytes=segment)
    n = 0
    try:
        for op in ops:
            if op[0] == "put":
                items = [(f"t/{n + k}", p) for k, p in enumerate(op[1])]
                n += len(items)
                assert log.put_many(items) == ref.put_many(items)
            elif op[0] == "ack":
                queued = [i for i, _, _ in ref.peek(10_000)]
                ids = [queued[k] for k in op[1] if k < len(queued)] + op[2]
                ref.put_many([], remove=[i for i in ids if i > 0])
                log.remove(ids)
            else:
                ref.close()
                log.close()
                ref = ForwardQueue(d / "ref.sqlite", max_messages=bound)
                log = ForwardLog(d / "log", max_messages=bound, segment_bytes=segment)
                assert log.issues == []
            assert _state(log) == _state(ref)
            # after one id, as the sink asks while it sends
            some = ref.peek(3)
            if some:
                assert log.peek(2, after_id=some[0][0]) == ref.peek(2, after_id=some[0][0])
        # segments whose messages are all done are deleted: what is left holds the queue
        segs = sorted((d / "log").glob("*.log"))
        assert len(segs) <= len(log) + 1
    finally:
        ref.close()
        log.close()


def test_a_write_cut_off_by_a_crash_loses_only_itself(tmp_path: Path) -> None:
    """A crash in the middle of a write (the last record only partly on disk, or damaged)
    costs that record alone: the log names the bytes it removed and goes on."""
    log = ForwardLog(tmp_path / "o")
    log.put_many([("a", b"1" * 100), ("a", b"2" * 100)])
    log.remove([1])
    size = (tmp_path / "o" / f"{1:020d}.log").stat().st_size
    log.put_many([("a", b"3" * 100)])
    log.close()
    seg = tmp_path / "o" / f"{1:020d}.log"
    whole = seg.read_bytes()
    for cut in (size + 1, size + 20, len(whole) - 1):
        seg.write_bytes(whole[:cut])
        log = ForwardLog(tmp_path / "o")
        assert [p for _, _, p in log.peek(10)] == [b"2" * 100], cut
        assert (log.enqueued, log.sent, len(log)) == (2, 1, 1)
        assert "cut off" in log.issues[0] and str(seg) in log.issues[0]
        assert seg.stat().st_size == size  # cut away: the next record follows a whole one
        assert log.put_many([("a", b"4")]) == [3]
        log.close()
        log = ForwardLog(tmp_path / "o")
        assert log.issues == [] and [p for _, _, p in log.peek(10)] == [b"2" * 100, b"4"]
        log.close()
    damaged = bytearray(whole)
    damaged[-10] ^= 0xFF  # a flipped byte in the last record's payload
    seg.write_bytes(bytes(damaged))
    log = ForwardLog(tmp_path / "o")
    assert "checksum" in log.issues[0] and [p for _, _, p in log.peek(10)] == [b"2" * 100]
    log.close()


def test_a_failed_write_leaves_no_part_of_a_record(tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    log = ForwardLog(tmp_path / "o")
    log.put_many([("a", b"1")])
    real = os.writev

    def half(fd: int, parts: list[bytes]) -> int:
        data = b"".join(parts)
        os.write(fd, data[: len(data) // 2])
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(fl.os, "writev", half)
    with pytest.raises(OSError, match="No space"):
        log.put_many([("a", b"2" * 50)], remove=[1])
    monkeypatch.setattr(fl.os, "writev", real)
    assert (log.enqueued, len(log), log.sent) == (1, 1, 0)  # the acknowledgement too: not kept
    assert log.put_many([("a", b"3")], remove=[1]) == [2]
    log.close()
    log = ForwardLog(tmp_path / "o")
    assert log.issues == [] and log.peek(10) == [(2, "a", b"3")] and log.sent == 1
    log.close()


def test_the_older_sqlite_outbox_is_moved_in_with_its_counts(tmp_path: Path) -> None:
    """A plant upgraded while its broker was away: what the SQLite outbox held is sent from
    the log, the counts of sent and dropped messages go on, the SQLite files are gone."""
    from cnctwin.edge import MqttSink

    old = ForwardQueue(tmp_path / "outbox.sqlite", max_messages=4)
    old.put_many([(f"cnctwin/m/{k}", f"{k}".encode()) for k in range(6)])  # 2 dropped
    old.put_many([], remove=[3])  # 1 sent
    old.close()
    sink = MqttSink("127.0.0.1", 1, state_dir=tmp_path, machine="m")
    try:
        q = sink.queue
        assert [(t, p) for _, t, p in q.peek(10)] == [
            ("cnctwin/m/3", b"3"), ("cnctwin/m/4", b"4"), ("cnctwin/m/5", b"5")]
        assert (q.enqueued, q.dropped, q.sent, len(q)) == (6, 2, 1, 3)
        assert not list(tmp_path.glob("outbox.sqlite*"))
    finally:
        sink.close(timeout_s=0)
    log = ForwardLog(tmp_path / "outbox")
    assert (log.enqueued, log.dropped, log.sent, len(log)) == (6, 2, 1, 3)
    with pytest.raises(ConfigError, match="not empty"):
        log.continue_counts(sent=0, dropped=0)
    log.close()


def test_bad_options_say_which(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="max_messages"):
        ForwardLog(tmp_path / "o", max_messages=0)
    with pytest.raises(ConfigError, match="segment_bytes"):
        ForwardLog(tmp_path / "o", segment_bytes=0)
