"""Fixtures of the edge runtime tests: a short simulated drilling run, a spindle model file,
and a private mosquitto broker that a test can stop and restart on the same port."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

import cnctwin
from cnctwin.edge import load_spindle_model, save_spindle_model
from cnctwin.recording import Recording
from cnctwin.spindle import SpindleModel
from tests._services import Broker, require_mosquitto


@pytest.fixture(scope="session")
def wear_run(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """Simulated tool-wear run, 3 holes in one set (CYCLE81, 2400 rpm, 400 mm/min, 20 mm
    deep; thesis §5.1), written as a Capture4Analysis file: about 12.5 s of cycles."""
    from cnctwin.sim import scenarios as sc

    out = tmp_path_factory.mktemp("wear3")
    res = sc.tool_wear_run(out, n_holes=3, holes_per_set=3, dynamometer=False, fmt="c4a",
                           seed=7)
    path = next(p for p in res.recording_paths if str(p).endswith(".json"))
    return {"path": Path(path), "truth": res.truth, "dir": out}


@pytest.fixture(scope="session")
def wear_recording(wear_run: dict[str, Any]) -> Recording:
    return cnctwin.read_recording(wear_run["path"])


@pytest.fixture(scope="session")
def spindle_model(tmp_path_factory: pytest.TempPathFactory) -> SpindleModel:
    """A calibrated-looking model with an inertia term (so the streaming derivative is
    exercised), written and read back the way the CLI gets it."""
    m = SpindleModel(kt_nm_per_a=1.01, b_nm_per_rpm=8.3e-5, tau_f_nm=0.34, j_kgm2=0.0045)
    p = save_spindle_model(m, tmp_path_factory.mktemp("model") / "spindle.json",
                           source="test fixture")
    return load_spindle_model(p)


@pytest.fixture()
def persistent_broker(tmp_path: Path) -> Iterator[Broker]:
    """A mosquitto that keeps sessions and queued messages across its own restart."""
    b = Broker(require_mosquitto(), persistence_dir=tmp_path / "mosquitto")
    b.start()
    try:
        yield b
    finally:
        b.stop()


@pytest.fixture()
def broker() -> Iterator[Broker]:
    b = Broker(require_mosquitto())
    b.start()
    try:
        yield b
    finally:
        b.stop()


class Collector:
    """A subscriber that keeps (topic, JSON payload) of every message it receives."""

    def __init__(self, port: int, topic: str = "cnctwin/#") -> None:
        import paho.mqtt.client as mqtt

        self.messages: list[tuple[str, dict[str, Any]]] = []
        self._lock = threading.Lock()
        self._subscribed = threading.Event()
        c = mqtt.Client(callback_api_version=mqtt.CallbackAPIVersion.VERSION2)
        c.on_message = self._on_message
        c.on_subscribe = lambda *a: self._subscribed.set()
        c.connect("127.0.0.1", port)
        c.loop_start()
        c.subscribe(topic, qos=1)
        assert self._subscribed.wait(10), "no SUBACK within 10 s"
        self.client = c

    def _on_message(self, client: Any, userdata: Any, msg: Any) -> None:
        import json

        with self._lock:
            self.messages.append((msg.topic, json.loads(msg.payload)))

    def of_kind(self, kind: str) -> list[dict[str, Any]]:
        with self._lock:
            return [m for _, m in self.messages if m.get("kind") == kind]

    def wait(self, cond: Any, timeout_s: float = 20.0) -> bool:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if cond():
                return True
            time.sleep(0.02)
        return False

    def close(self) -> None:
        self.client.loop_stop()
        self.client.disconnect()


def publisher(port: int) -> Any:
    import paho.mqtt.client as mqtt

    c = mqtt.Client(callback_api_version=mqtt.CallbackAPIVersion.VERSION2)
    c.connect("127.0.0.1", port)
    c.loop_start()
    return c
