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
