"""Live MQTT: Databus messages in, results out, and store-and-forward across a broker restart.

A private mosquitto on a free loopback port (conftest.Broker). Databus payloads are built as
in tests/iotools (documented structure, docs/reference/data-formats.md §2): metadata on the
metadata topic
(retained), bulk data messages with one value per datapoint and cycle.
"""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

from cnctwin.edge import DatabusSource, EdgeRuntime, MqttSink, TorqueProcessor
from cnctwin.spindle import SpindleModel
from tests.edge.conftest import Broker, Collector, publisher

pytestmark = pytest.mark.mqtt
META = "ie/m/j/simatic/v1/nck1/dp"
DATA = "ie/d/j/simatic/v1/nck1/dp/r/NCK/hf"


def _metadata() -> dict[str, Any]:
    return {"seq": 1, "hashVersion": 7, "applicationName": "mill-7", "connections": [
        {"name": "NCK", "type": "sinumerik", "dataPoints": [
            {"name": "hf", "topic": DATA, "publishType": "bulk", "dataPointDefinitions": [
                {"name": "Cycle", "id": "1", "dataType": "DInt"},
                {"name": "Spindle_Current", "id": "2", "dataType": "LReal"},
                {"name": "Spindle_Speed", "id": "3", "dataType": "LReal"}]}]}]}


def _bulk(seq: int, cycles: np.ndarray, t0: pd.Timestamp, i: np.ndarray,
          n: np.ndarray) -> bytes:
    vals = []
    for k, c in enumerate(cycles):
        ts = (t0 + pd.Timedelta(milliseconds=2 * k)).strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z"
        vals += [{"id": "1", "qc": 3, "ts": ts, "val": int(c)},
                 {"id": "2", "qc": 3, "ts": ts, "val": float(i[k])},
                 {"id": "3", "qc": 3, "ts": ts, "val": float(n[k])}]
    return json.dumps({"seq": seq, "vals": vals}).encode()


def _live_source(broker: Broker, *, idle_timeout_s: float) -> tuple[Collector, Any,
                                                                  DatabusSource]:
    """A result collector, a publisher that has sent the (retained) metadata, and a started
    live source reading the documented test datapoints."""
    out = Collector(broker.port)
    pub = publisher(broker.port)
    pub.publish(META, json.dumps(_metadata()).encode(), qos=1,
                retain=True).wait_for_publish(timeout=5)
    src = DatabusSource("127.0.0.1", broker.port, metadata_topic=META,
                        name_map={"Cycle": "CYCLE", "Spindle_Current": "CURRENT|SP1",
                                  "Spindle_Speed": "CMD_SPEED|SP1"},
                        window_s=0.05, idle_timeout_s=idle_timeout_s)
    src.start()
    return out, pub, src


def test_databus_in_results_out_with_wrap(broker: Broker, tmp_path: Path) -> None:
    model = SpindleModel(1.04, 8.42e-5, 0.35, j_kgm2=0.002)
    rng = np.random.default_rng(3)
    n_cyc = 600
    raw = (np.arange(n_cyc) + 2**31 - 250) % 2**31  # the counter wraps after 250 cycles
    speed = np.linspace(2000.0, 2400.0, n_cyc)
    current = 3.0 + 0.2 * rng.standard_normal(n_cyc)
    out, pub, src = _live_source(broker, idle_timeout_s=1.5)
    sink = MqttSink("127.0.0.1", broker.port, state_dir=tmp_path / "state",
                    machine="mill-7")
    rt = EdgeRuntime(src, [TorqueProcessor(model)], [sink], state_dir=tmp_path)
    th = threading.Thread(target=rt.run, daemon=True)
    th.start()
    t0 = pd.Timestamp("2025-03-01T10:00:00Z")
    try:
        for s, k in enumerate(range(0, n_cyc, 100)):
            sl = slice(k, k + 100)
            pub.publish(DATA, _bulk(s + 1, raw[sl], t0 + pd.Timedelta(milliseconds=2 * k),
                                    current[sl], speed[sl]), qos=1).wait_for_publish(timeout=5)
        th.join(timeout=30)
        assert not th.is_alive()
        assert out.wait(lambda: sum(m["n"] for m in out.of_kind("torque")) >= n_cyc)
    finally:
        pub.loop_stop()
        pub.disconnect()
        out.close()
    tq = sorted(out.of_kind("torque"), key=lambda m: m["seq"])
    cyc = np.concatenate([np.arange(m["first_cycle"], m["first_cycle"] + m["n"]) for m in tq])
    tau = np.concatenate([m["torque_nm"] for m in tq])
    assert np.array_equal(cyc, np.arange(n_cyc) + 2**31 - 250)  # unwrapped, continuous
    np.testing.assert_array_equal(tau, model.cutting_torque(current, speed))  # batch Eq. 4.4
    assert all(t == "cnctwin/mill-7/torque" for t, m in out.messages if m["kind"] == "torque")
    assert tq[0]["units"]["torque_nm"] == "Nm"
    status = json.loads((tmp_path / "status.json").read_text())
    assert status["wraps"] == 1 and status["gaps"] == 0 and status["cycles"] == n_cyc


def _msgs(start: int, n: int) -> list[dict[str, Any]]:
    return [{"seq": s, "kind": "torque", "machine": "m1", "cycle": s, "first_cycle": s,
             "n": 1, "torque_nm": [float(s)]} for s in range(start, start + n)]


def test_store_and_forward_across_broker_restart(broker: Broker, tmp_path: Path) -> None:
    sink = MqttSink("127.0.0.1", broker.port, state_dir=tmp_path, machine="m1", retry_s=0.2,
                    max_queue_messages=50)
    rx = Collector(broker.port)
    sink.write(_msgs(0, 10), None)
    assert sink.flush(timeout_s=10)
    assert rx.wait(lambda: len(rx.of_kind("torque")) >= 10)
    rx.close()
    broker.stop()
    deadline = time.monotonic() + 10
    while sink.connected and time.monotonic() < deadline:  # the loss is noticed
        sink.pump()
        time.sleep(0.05)
    assert not sink.connected
    sink.write(_msgs(10, 70), None)  # broker down: 70 messages, bound 50
    for _ in range(5):
        sink.pump()
    st = sink.status()
    assert st["queued"] == 50 and st["dropped_oldest"] == 20  # counted, not silent
    broker.start()  # same port
    rx2 = Collector(broker.port)
    try:
        assert sink.flush(timeout_s=20)
        assert rx2.wait(lambda: len(rx2.of_kind("torque")) >= 50)
        seqs = [m["seq"] for m in rx2.of_kind("torque")]
        assert sink.queue.sent == 60
    finally:
        rx2.close()
        sink.close(timeout_s=1)
    # the 50 newest, oldest first, each once (20..29 were dropped by the bound)
    assert seqs == list(range(30, 80))


def test_acknowledged_messages_leave_with_the_next_write_while_results_flow(
        broker: Broker, tmp_path: Path) -> None:
    """While results flow, the messages the broker acknowledged are deleted in the next
    write's transaction (one commit per chunk), counted as sent meanwhile; a lost connection
    does not send them again; once the writes stop a pump deletes them."""
    sink = MqttSink("127.0.0.1", broker.port, state_dir=tmp_path, machine="m1", retry_s=0.2)
    rx = Collector(broker.port)
    removes: list[int] = []
    real_remove = sink.queue.remove
    sink.queue.remove = lambda ids: (removes.append(len(ids)), real_remove(ids))[1]
    try:
        sink.write(_msgs(0, 1), None)
        assert sink.flush(timeout_s=10)  # connected; the flush deletes at once
        removes.clear()
        for k in range(1, 6):  # a chunk's results, then the idle pumps of its period
            sink.write(_msgs(k * 10, 3), None)
            deadline = time.monotonic() + 5
            while sink.status()["queued"] and time.monotonic() < deadline:
                sink.pump()
                time.sleep(0.01)
            st = sink.status()
            assert (st["queued"], st["sent"]) == (0, 1 + 3 * k)
        assert removes == []  # no transaction of their own
        assert len(sink.queue) == 3  # the last chunk's, deleted with the next write
        sink._drop_client()  # a lost connection: the acknowledged ones are not sent again
        assert len(sink.queue) == 0 and removes == [3]
        sink.write(_msgs(100, 2), None)
        assert sink.flush(timeout_s=10)
        assert rx.wait(lambda: len(rx.of_kind("torque")) >= 18)
        time.sleep(0.3)
        seqs = sorted(m["seq"] for m in rx.of_kind("torque"))
        assert seqs == [0, *(s for k in range(1, 6) for s in range(k * 10, k * 10 + 3)),
                        100, 101]  # each once
        # no write for REMOVE_IDLE_S: the pump deletes them
        sink.write(_msgs(200, 1), None)
        sink.REMOVE_IDLE_S = 0.2
        deadline = time.monotonic() + 5
        while len(sink.queue) and time.monotonic() < deadline:
            sink.pump()
            time.sleep(0.05)
        assert len(sink.queue) == 0 and sink.status()["sent"] == 19
    finally:
        rx.close()
        sink.close(timeout_s=1)


def test_queue_survives_restart(tmp_path: Path) -> None:
    from cnctwin.edge import ForwardQueue

    q = ForwardQueue(tmp_path / "outbox.sqlite", max_messages=3)
    q.put_many([("t", b"a"), ("t", b"b"), ("t", b"c"), ("t", b"d")])
    q.close()
    q2 = ForwardQueue(tmp_path / "outbox.sqlite", max_messages=3)
    assert [p for _, _, p in q2.peek(10)] == [b"b", b"c", b"d"] and q2.dropped == 1
    # acknowledged ones leave; the counts hold across a restart: 4 appended = 1 dropped +
    # 2 sent + 1 queued (by hand)
    ids = [i for i, _, _ in q2.peek(2)]
    q2.put_many([], remove=ids)
    q2.remove([ids[0]])  # an acknowledgement seen twice removes nothing more
    assert (q2.enqueued, q2.dropped, q2.sent, len(q2)) == (4, 1, 2, 1)
    q2.close()
    q3 = ForwardQueue(tmp_path / "outbox.sqlite", max_messages=3)
    assert (q3.enqueued, q3.dropped, q3.sent, len(q3)) == (4, 1, 2, 1)
    q3.remove([i for i, _, _ in q3.peek(5)])  # empty: the ids still go on, never reused
    assert q3.put_many([("t", b"e")]) == [5] and q3.sent == 3
    q3.close()


def test_cli_live_databus(broker: Broker, tmp_path: Path,
                          capfd: pytest.CaptureFixture[str]) -> None:
    from cnctwin.cli import main
    from cnctwin.edge import save_spindle_model

    model = SpindleModel(1.04, 8.42e-5, 0.35)
    mfile = save_spindle_model(model, tmp_path / "spindle.json")
    nmap = tmp_path / "map.json"
    nmap.write_text(json.dumps({"Cycle": "CYCLE", "Spindle_Current": "CURRENT|SP1",
                                "Spindle_Speed": "CMD_SPEED|SP1"}))
    pub = publisher(broker.port)
    rx = Collector(broker.port, "plant/#")
    pub.publish(META, json.dumps(_metadata()).encode(), qos=1,
                retain=True).wait_for_publish(timeout=5)
    raw = np.arange(5000, 5200)
    current = np.full(200, 3.0)
    speed = np.full(200, 2400.0)
    # retained, so the CLI gets it whenever its data subscription is in place (no sleep)
    pub.publish(DATA, _bulk(1, raw, pd.Timestamp("2025-03-01T10:00:00Z"), current, speed),
                qos=1, retain=True).wait_for_publish(timeout=5)
    codes: list[int] = []
    # the Databus scanner is compiled once per process (numba; ~13 s alone on a cold clone,
    # 30-50 s beside the other test worker): done here, outside the 30 s the CLI gets below;
    # the source's own prepare_scanner() then finds it in memory (a test before this one in
    # the same worker may have dropped it: test_databus_numbers' fallback case)
    from cnctwin.iotools._databus_scan import prepare_scanner

    prepare_scanner()
    th = threading.Thread(target=lambda: codes.append(main([
        "edge", "run", "--source", f"mqtt://127.0.0.1:{broker.port}/{META}",
        "--name-map", str(nmap), "--model", str(mfile), "--out", str(tmp_path / "out"),
        "--publish", f"mqtt://127.0.0.1:{broker.port}/plant", "--no-holes", "--no-anomaly",
        "--idle-timeout-s", "1.5", "--quiet"])), daemon=True)
    th.start()
    try:
        th.join(timeout=30)
        assert not th.is_alive() and codes == [0]
        assert rx.wait(lambda: sum(m["n"] for m in rx.of_kind("torque")) >= 200)
        topics = {t for t, m in rx.messages if m.get("kind") == "torque"}
    finally:
        pub.loop_stop()
        pub.disconnect()
        rx.close()
    assert topics == {"plant/mill-7/torque"}  # machine from the metadata's applicationName
    err = capfd.readouterr().err
    # the operator sees what it waits for, and which session it got
    assert f"waiting for the Databus metadata on {META}" in err
    assert "MQTT session cnctwin-edge-" in err and "(new;" in err
    tau = np.concatenate([m["torque_nm"] for m in sorted(rx.of_kind("torque"),
                                                         key=lambda m: m["seq"])])
    # thesis Eq. 4.4 by hand: 1.04 * 3.0 - 8.42e-5 * 2400 - 0.35 = 2.56792 Nm
    np.testing.assert_allclose(tau, 2.56792, rtol=1e-12)


def test_idle_live_runtime_reports_and_measures_latency(broker: Broker, tmp_path: Path) -> None:
    """Before any data arrives the runtime already publishes its ``run`` message and keeps its
    status current (an idle live source ticks the runtime); once data flows, the status holds
    the arrival-to-publish latency of the chunks (p50/p99/max [ms])."""
    model = SpindleModel(1.04, 8.42e-5, 0.35)
    out, pub, src = _live_source(broker, idle_timeout_s=4.0)
    sink = MqttSink("127.0.0.1", broker.port, state_dir=tmp_path / "state", machine="mill-7")
    rt = EdgeRuntime(src, [TorqueProcessor(model)], [sink], state_dir=tmp_path,
                     status_every_s=0.5)
    th = threading.Thread(target=rt.run, daemon=True)
    th.start()
    try:
        assert out.wait(lambda: out.of_kind("run") and len(out.of_kind("status")) >= 2,
                        timeout_s=10), "no run/status message while idle"
        idle = json.loads((tmp_path / "status.json").read_text())
        assert idle["cycles"] == 0 and idle["latency_ms"]["p99"] is None
        t0 = pd.Timestamp("2025-03-01T10:00:00Z")
        for s, k in enumerate(range(0, 300, 50)):
            c = np.arange(k, k + 50)
            pub.publish(DATA, _bulk(s + 1, c, t0 + pd.Timedelta(milliseconds=2 * k),
                                    np.full(50, 3.0), np.full(50, 2400.0)),
                        qos=1).wait_for_publish(timeout=5)
            time.sleep(0.1)
        th.join(timeout=30)
        assert not th.is_alive()
    finally:
        pub.loop_stop()
        pub.disconnect()
        out.close()
    st = rt.final_status
    assert st is not None and st["cycles"] == 300
    lat = st["latency_ms"]
    # each message is its own chunk, processed within a fraction of its 100 ms period
    assert lat["chunks"] == 6 and 0.0 <= lat["p50"] <= lat["p99"] <= lat["max"] < 1000.0
    # the pipeline's own CPU (its thread): positive, and no more than the wall time it was
    # busy (thread CPU cannot exceed it); what a machine costs a core
    assert 0.0 < st["cpu_s"] <= st["cycles"] / st["cycles_per_busy_s"] + 1e-3
    assert st["cycles_per_cpu_s"] == pytest.approx(300 / st["cpu_s"], rel=0.01)  # cpu_s: to the us
