"""Live MQTT tests: a private mosquitto broker on a free loopback port.

The broker is started by the fixture (``mosquitto -p PORT``, mosquitto 2.x listens on loopback
only without a config file) and stopped by its pid. Databus payloads are hand-written
(same as in ``test_databus.py``; documented structure, docs/reference/data-formats.md section 2);
the Data
Recorder message is the real Capture4Analysis file (3818 HF rows, first CYCLE 5558098,
78 block events; counted by hand with python json), sent as JSON and as a zip archive.
"""

from __future__ import annotations

import io
import json
import threading
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from cnctwin.iotools.mqtt import MqttRecorder, subscribe_data_recorder
from tests._services import Broker, require_mosquitto

pytestmark = pytest.mark.mqtt
META_TOPIC = "ie/m/j/simatic/v1/s7c1/dp"
TOPIC = "ie/d/j/simatic/v1/s7c1/dp/r/PLC_1/default"


def metadata() -> dict[str, Any]:
    return {"seq": 1, "hashVersion": 123, "applicationName": "S7 Connector", "connections": [
        {"name": "PLC_1", "type": "s7", "dataPoints": [
            {"name": "default", "topic": TOPIC, "publishType": "bulk",
             "dataPointDefinitions": [
                 {"name": "Axis_X_Load", "id": "101", "dataType": "LReal"},
                 {"name": "Counter", "id": "102", "dataType": "LInt"},
                 {"name": "State", "id": "103", "dataType": "String"}]}]}]}


def bulk(seq: int) -> bytes:
    return json.dumps({"seq": seq, "vals": [
        {"id": "101", "qc": 3, "ts": "2021-03-10T22:23:04.146Z", "val": 80},
        {"id": "102", "qc": 3, "ts": "2021-03-10T22:23:04.146Z", "val": "9007199254740993"},
        {"id": "101", "qc": 0, "ts": "2021-03-10T22:23:04.156Z", "val": "81.5"},
        {"id": "103", "qc": 2, "ts": "2021-03-10T22:23:04.156Z", "val": "RUN"},
    ]}).encode()


@pytest.fixture(scope="module")
def broker() -> Iterator[int]:
    b = Broker(require_mosquitto())
    b.start()
    try:
        yield b.port
    finally:
        b.stop()


def _publisher(port: int) -> Any:
    import paho.mqtt.client as mqtt

    c = mqtt.Client(callback_api_version=mqtt.CallbackAPIVersion.VERSION2)
    c.connect("127.0.0.1", port)
    c.loop_start()
    return c


def test_databus_metadata_then_data(broker: int) -> None:
    pub = _publisher(broker)
    try:
        # retained metadata published before the recorder subscribes (as connectors do)
        pub.publish(META_TOPIC, json.dumps(metadata()).encode(), qos=1,
                    retain=True).wait_for_publish(timeout=5)
        with MqttRecorder("127.0.0.1", broker, metadata_topic=META_TOPIC,
                          name_map={"Axis_X_Load": "LOAD|X1"}) as rec:
            rec.wait_ready(timeout_s=10)
            assert TOPIC in rec.decoder.data_topics
            pub.publish(TOPIC, bulk(1), qos=1).wait_for_publish(timeout=5)
            pub.publish(TOPIC, bulk(2), qos=1).wait_for_publish(timeout=5)
            out = rec.collect(until=lambda d: len(d.values) >= 8, timeout_s=10)
        assert out.signal("LOAD|X1").tolist() == [80.0, 81.5]  # same timestamps twice
        assert len(out.meta.attrs["databus_values"]) == 8
        assert any("shared a cycle" in i for i in out.meta.issues)
        assert out.lf["text"].tolist() == ["RUN", "RUN"]
    finally:
        pub.loop_stop()
        pub.disconnect()


@pytest.mark.parametrize("zipped", [False, True])
def test_data_recorder_stream(broker: int, c4a_file: Path, zipped: bool) -> None:
    topic = "MACHINE_A/tapping/M8-40"
    ready = threading.Event()
    results: list[Any] = []

    def consume() -> None:
        results.extend(subscribe_data_recorder("127.0.0.1", broker, "MACHINE_A/#",
                                               max_messages=1, timeout_s=20, ready=ready))

    th = threading.Thread(target=consume, daemon=True)
    th.start()
    assert ready.wait(10), "Data Recorder subscription not acknowledged within 10 s"
    pub = _publisher(broker)
    try:
        payload = c4a_file.read_bytes()
        if zipped:  # the Data Recorder may send each message as a zip archive
            buf = io.BytesIO()
            with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
                zf.writestr("job.json", payload)
            payload = buf.getvalue()
        pub.publish(topic, payload, qos=1).wait_for_publish(timeout=10)
        th.join(timeout=30)
    finally:
        pub.loop_stop()
        pub.disconnect()
    assert not th.is_alive()
    assert len(results) == 1
    rec = results[0]
    assert rec.n_cycles == 3818
    assert rec.cycles[0] == 5558098 and rec.cycles[-1] == 5565774
    assert (rec.events["kind"] == "block").sum() == 78
    assert rec.meta.source_files == [topic]


@pytest.mark.parametrize("acked", [5, 3])
def test_a_driven_client_sends_its_held_acknowledgements(broker: int, acked: int) -> None:
    """A driven connection (a plant worker's hub) holds its PUBACKs up to ACK_HOLD_S and
    writes them together; held ones go out when it stops. Persistent session: 5 QoS 1
    messages received, ``acked`` acknowledged, stopped at once (no io() after the acks): the
    next connection with the same session gets exactly the 5 - acked others again."""
    import time

    from cnctwin.iotools.mqtt import _Client

    def client() -> _Client:
        c = _Client("127.0.0.1", broker, client_id=f"held-{acked}", username=None,
                    password=None, keepalive_s=30, max_queue=100, session_expiry_s=60,
                    manual_ack=True)
        c.start(10.0)
        return c

    def take(c: _Client, n: int, wait_s: float) -> list[Any]:
        got: list[Any] = []
        deadline = time.monotonic() + wait_s
        while time.monotonic() < deadline and len(got) < n:
            c.io()
            while not c.queue.empty():
                got.append(c.queue.get_nowait())
            time.sleep(0.01)
        return got

    first = client()
    mid = first.subscribe(f"held/{acked}", 1)
    deadline = time.monotonic() + 10
    while not first.acked(mid) and time.monotonic() < deadline:
        time.sleep(0.01)
    first.drive()
    pub = _publisher(broker)
    try:
        for k in range(5):
            pub.publish(f"held/{acked}", f"m{k}".encode(), qos=1).wait_for_publish(5)
        got = take(first, 5, 10.0)
        assert [g[1] for g in got] == [f"m{k}".encode() for k in range(5)]
        first.ack([g[3] for g in got[:acked]])
        assert len(first._acks) == acked  # held, not written yet
        first.stop()
        # mosquitto reads one packet per socket per turn of its loop: a connection taking
        # over the session at once may close the old one before it read all the PUBACKs
        # (then those messages only come again); give it the time a restart takes
        time.sleep(1.0)
        second = client()
        second.drive()
        again = take(second, 5, 1.5)
        second.stop()
    finally:
        pub.loop_stop()
        pub.disconnect()
    assert [g[1] for g in again] == [f"m{k}".encode() for k in range(acked, 5)]
