"""A plant worker's live machines on one MQTT connection, driven from one thread (issue 28,
point 1).

Truth: each machine's results from a replay of the same signals (``ReplaySource``, same
processors, uninterrupted); a live machine of a plant must give exactly those torque values,
holes and alarms, with the others sharing its connection and thread, and across a ``kill -9``
of the worker (persistent session, acknowledgements held until checkpoints: the broker
delivers again what no checkpoint covered, each machine skips what its results hold).
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from cnctwin.edge import (
    AnomalyProcessor,
    DatabusSource,
    EdgeRuntime,
    HoleProcessor,
    JsonLinesSink,
    ReplaySource,
    TorqueProcessor,
    save_spindle_model,
)
from cnctwin.edge.plant import run_machines
from cnctwin.iotools.mqtt import MqttHub
from cnctwin.recording import Recording, RecordingMeta
from cnctwin.spindle import SpindleModel
from tests._services import Broker
from tests.edge._databus import bulk_messages, read_results, torque_of
from tests.edge.conftest import publisher

pytestmark = pytest.mark.mqtt
COLUMNS = ["CURRENT|SP1", "CMD_SPEED|SP1", "DES_POS|Z1", "ENC_POS|Z1"]
PER_MSG = 100
MODEL = SpindleModel(1.01, 8.3e-5, 0.34, j_kgm2=0.0045)


def _topics(k: int) -> tuple[str, str]:
    return f"ie/m/j/simatic/v1/nck{k}/dp", f"ie/d/j/simatic/v1/nck{k}/dp/r/NCK/hf"


def _metadata(k: int) -> bytes:
    defs = [{"name": "CYCLE", "id": "1", "dataType": "DInt"}] + [
        {"name": c, "id": str(i + 2), "dataType": "LReal"} for i, c in enumerate(COLUMNS)]
    return json.dumps({"seq": 1, "hashVersion": 1, "applicationName": f"mill-{k}",
                       "connections": [{"name": "NCK", "type": "sinumerik", "dataPoints": [
                           {"name": "hf", "topic": _topics(k)[1], "publishType": "bulk",
                            "dataPointDefinitions": defs}]}]}).encode()


@pytest.fixture(scope="module")
def signals(wear_recording: Recording) -> Recording:
    """The 3-hole drilling run's drive signals as the Databus carries them (no NC events)."""
    hf = wear_recording.hf[["time", *COLUMNS]].copy()
    return Recording(hf, meta=RecordingMeta(machine="mill", cycle_time_s=0.002,
                                            source_format="databus"))


def _messages(rec: Recording) -> list[bytes]:
    return bulk_messages(rec, COLUMNS, PER_MSG)


def _processors() -> list[Any]:
    return [TorqueProcessor(MODEL), HoleProcessor(MODEL),
            AnomalyProcessor(model=MODEL, learn_s=3.0)]


_read = read_results


_torque = torque_of


@pytest.fixture(scope="module")
def reference(signals: Recording, tmp_path_factory: pytest.TempPathFactory
              ) -> list[dict[str, Any]]:
    d = tmp_path_factory.mktemp("reference")
    EdgeRuntime(ReplaySource(signals, chunk_cycles=PER_MSG), _processors(),
                [JsonLinesSink(d / "results.jsonl")], state_dir=d).run()
    ref = _read(d / "results.jsonl")
    assert sum(m["kind"] == "hole" for m in ref) == 3
    return ref


def _run_on_hub(hub: MqttHub, broker: Broker, tmp_path: Path, machines: range,
                reports: list[tuple[str, str, Any]], stop: threading.Event, *,
                idle_timeout_s: float, batch_s: Any = lambda k: 0.0) -> threading.Thread:
    """``run_machines`` in a thread (as a plant worker runs it): live machines ``mill-<k>``
    on ``hub``, each with the test's processors and its results in JSON lines."""
    def build(k: int) -> Any:
        def make() -> EdgeRuntime:
            src = DatabusSource("127.0.0.1", broker.port, metadata_topic=_topics(k)[0],
                                machine=f"mill-{k}", idle_timeout_s=idle_timeout_s, hub=hub,
                                batch_s=batch_s(k))
            src.start()
            d = tmp_path / f"mill-{k}"
            return EdgeRuntime(src, _processors(), [JsonLinesSink(d / "results.jsonl")],
                               state_dir=d)
        return make

    runner = threading.Thread(target=run_machines, args=([(f"mill-{k}", build(k))
                                                          for k in machines],),
                              kwargs={"report": lambda *r: reports.append(r), "stop": stop})
    runner.start()
    return runner


def _same_as_reference(msgs: list[dict[str, Any]], ref: list[dict[str, Any]]) -> None:
    seqs = [m["seq"] for m in msgs]
    assert len(seqs) == len(set(seqs)), "a seq was given to two messages"
    cyc, tau = _torque(msgs)
    rcyc, rtau = _torque(ref)
    np.testing.assert_array_equal(cyc, rcyc)  # every cycle once, in order
    np.testing.assert_allclose(tau, rtau, rtol=1e-12, atol=1e-12)
    holes = [m["row"] for m in msgs if m["kind"] == "hole"]
    ref_holes = [m["row"] for m in ref if m["kind"] == "hole"]
    assert [(h["hole"], h["start_cycle"], h["end_cycle"]) for h in holes] == \
        [(h["hole"], h["start_cycle"], h["end_cycle"]) for h in ref_holes]
    for h, r in zip(holes, ref_holes, strict=True):
        assert h["torque_mean_nm"] == pytest.approx(r["torque_mean_nm"], rel=1e-9)
    assert [m["cycle"] for m in msgs if m["kind"] == "alarm"] == \
        [m["cycle"] for m in ref if m["kind"] == "alarm"]


def test_six_machines_share_one_connection_and_one_thread(
        broker: Broker, signals: Recording, reference: list[dict[str, Any]],
        tmp_path: Path) -> None:
    """Six live machines in one process (as a plant worker runs them): one MQTT connection,
    no thread per machine while they run (the hub's network thread and the driving thread
    only), each machine's results those of its own replay; three of them in batches of
    0.25 s (``batch_s``: several messages as one chunk), with the same results."""
    machines = range(1, 7)
    pub = publisher(broker.port)
    for k in machines:
        pub.publish(_topics(k)[0], _metadata(k), qos=1, retain=True).wait_for_publish(5)
    hub = MqttHub("127.0.0.1", broker.port)
    baseline = threading.active_count()
    peak = [0]
    stop = threading.Event()
    reports: list[tuple[str, str, Any]] = []

    runner = _run_on_hub(hub, broker, tmp_path, machines, reports, stop, idle_timeout_s=2.0,
                         batch_s=lambda k: 0.25 if k > 3 else 0.0)
    deadline = time.monotonic() + 60
    while sum(r[1] == "started" for r in reports) < len(machines):
        assert time.monotonic() < deadline, reports
        time.sleep(0.05)
    payloads = _messages(signals)
    for p in payloads:
        for k in machines:
            pub.publish(_topics(k)[1], p, qos=1)
        peak[0] = max(peak[0], threading.active_count())
        time.sleep(PER_MSG * 0.002 / 8)  # 8x real time
    runner.join(timeout=120)
    assert not runner.is_alive()
    pub.loop_stop()
    pub.disconnect()
    # the runner's own thread, the hub's network thread, the publisher's: never one per
    # machine (the build threads end when their machine is handed to the runner)
    assert peak[0] <= baseline + 3, (baseline, peak[0])
    assert sorted(r[0] for r in reports if r[1] == "done") == [f"mill-{k}" for k in machines]
    for k in machines:
        _same_as_reference(_read(tmp_path / f"mill-{k}" / "results.jsonl"), reference)
        chunks = json.loads((tmp_path / f"mill-{k}" / "status.json").read_text())["chunks"]
        # a chunk per message (two may merge when the thread is late: a loaded machine), or
        # per 0.25 s batch of ~10 messages sent at 8x real time
        assert chunks > len(payloads) / 2 if k <= 3 else chunks < len(payloads) / 3, \
            (k, chunks)


def test_a_batch_longer_than_the_tick_is_one_chunk(broker: Broker, signals: Recording,
                                                   tmp_path: Path) -> None:
    """Messages every 0.1 s in batches of 1 s, with the worker's idle tick every 0.5 s: one
    chunk per batch (a tick does its own work and leaves the gathering messages alone; it
    took them as a chunk of their own before, two chunks per batch, each paying the work per
    chunk), every cycle processed once."""
    k = 7
    pub = publisher(broker.port)
    pub.publish(_topics(k)[0], _metadata(k), qos=1, retain=True).wait_for_publish(5)
    hub = MqttHub("127.0.0.1", broker.port)
    stop = threading.Event()
    reports: list[tuple[str, str, Any]] = []
    runner = _run_on_hub(hub, broker, tmp_path, range(k, k + 1), reports, stop,
                         idle_timeout_s=2.0, batch_s=lambda k: 1.0)
    deadline = time.monotonic() + 60
    while not any(r[1] == "started" for r in reports):
        assert time.monotonic() < deadline, reports
        time.sleep(0.05)
    payloads = _messages(signals)[:45]
    t0 = time.monotonic()
    for j, p in enumerate(payloads):  # 4.5 s of messages, one every 0.1 s
        time.sleep(max(t0 + 0.1 * j - time.monotonic(), 0.0))
        pub.publish(_topics(k)[1], p, qos=1)
    runner.join(timeout=60)
    pub.loop_stop()
    pub.disconnect()
    assert not runner.is_alive() and [r[1] for r in reports] == ["started", "done"], reports
    st = json.loads((tmp_path / f"mill-{k}" / "status.json").read_text())
    assert st["cycles"] == len(payloads) * PER_MSG
    # the first message at once, then a batch per second (4.5 s), the end's idle flush:
    # two chunks per second were 9 or more
    assert st["chunks"] <= 7, st["chunks"]


def test_batch_s_is_refused_outside_a_plant(tmp_path: Path, wear_run: dict[str, Any],
                                            capsys: pytest.CaptureFixture[str]) -> None:
    from cnctwin.cli import main

    model = save_spindle_model(MODEL, tmp_path / "spindle.json")
    assert main(["edge", "run", "--source", str(wear_run["path"]), "--model", str(model),
                 "--out", str(tmp_path / "o"), "--batch-s", "0.5", "--quiet"]) == 2
    assert "--batch-s 0.5: give 0, or a positive number of seconds for a live Databus " \
        "machine of a plant" in capsys.readouterr().err


def test_a_plant_worker_killed_twice_gives_every_machine_its_results_exactly_once(
        persistent_broker: Broker, signals: Recording, reference: list[dict[str, Any]],
        tmp_path: Path) -> None:
    """Three live machines in one worker process on one persistent session; the worker is
    killed (SIGKILL) twice while the controls publish and restarted by the supervisor: every
    machine's torque of every cycle once, its holes and alarms those of its replay."""
    broker = persistent_broker
    machines = range(1, 4)
    model = save_spindle_model(MODEL, tmp_path / "spindle.json")
    lines = ["workers = 1", 'out = "state"', "", "[defaults]", f'model = "{model}"',
             "learn-s = 3", "no-twin = true", "session-expiry-s = 600",
             "idle-timeout-s = 4", ""]
    for k in machines:
        lines += ["[[machine]]", f'name = "mill-{k}"',
                  f'source = "mqtt://127.0.0.1:{broker.port}/{_topics(k)[0]}"', ""]
    plant = tmp_path / "plant.toml"
    plant.write_text("\n".join(lines), encoding="utf-8")
    pub = publisher(broker.port)
    for k in machines:
        pub.publish(_topics(k)[0], _metadata(k), qos=1, retain=True).wait_for_publish(5)
    proc = subprocess.Popen([sys.executable, "-m", "cnctwin", "edge", "run", "--config",
                             str(plant), "--quiet"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, cwd=tmp_path)
    status = [tmp_path / "state" / f"mill-{k}" / "status.json" for k in machines]

    def worker() -> int:
        pids = subprocess.run(["pgrep", "-P", str(proc.pid), "-f", "spawn_main"],
                              capture_output=True, text=True).stdout.split()
        return int(pids[0]) if pids else 0

    def cycles() -> int:  # processed by every machine, over the worker's restarts
        got = []
        for k in machines:
            res = tmp_path / "state" / f"mill-{k}" / "results.jsonl"
            msgs = _read(res) if res.exists() else []
            got.append(sum(m["n"] for m in msgs if m["kind"] == "torque"))
        return min(got)

    payloads = _messages(signals)
    try:
        deadline = time.monotonic() + 120
        while not all(s.exists() for s in status):  # connected and subscribed
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "the plant did not start"
            time.sleep(0.1)
        kills = [len(payloads) // 3, 2 * len(payloads) // 3]
        for j, p in enumerate(payloads):
            if j in kills:  # the worker dies mid-stream; the controls go on publishing
                while cycles() < (j - 8) * PER_MSG:
                    assert time.monotonic() < deadline + 120, "the plant fell behind"
                    time.sleep(0.02)
                pid = worker()
                assert pid
                subprocess.run(["kill", "-9", str(pid)], check=True)
            for k in machines:
                pub.publish(_topics(k)[1], p, qos=1).wait_for_publish(10)
            time.sleep(PER_MSG * 0.002 / 4)  # 4x real time
        out, err = proc.communicate(timeout=240)  # the machines end 4 s after the last data
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            proc.communicate(timeout=60)
        pub.loop_stop()
        pub.disconnect()
    assert proc.returncode == 0, err.decode()[-3000:]
    summary = json.loads(out.decode().strip().splitlines()[-1])
    assert sorted(summary) == [f"mill-{k}" for k in machines]
    assert not any("error" in v for v in summary.values()), summary
    for k in machines:
        msgs = _read(tmp_path / "state" / f"mill-{k}" / "results.jsonl")
        _same_as_reference(msgs, reference)
        runs = [m["resumed"] for m in msgs if m["kind"] == "run"]
        assert [r["from_checkpoint"] for r in runs] == [False, True, True], k


def test_the_hub_holds_unclaimed_messages_refuses_a_shared_topic_and_unsubscribes_an_ended_machine(
        broker: Broker) -> None:
    """What a resumed session delivers before its machine subscribed is handed over in order
    when it does; a topic claimed by two machines is refused (naming it); a machine that
    ends while others go on unsubscribes (nothing of it is held any more), while a stop of
    the whole process keeps the subscriptions (its session keeps them for the restart)."""
    from cnctwin.exceptions import ConfigError

    hub = MqttHub("127.0.0.1", broker.port)
    a, b = hub.port(), hub.port()
    hub.start(10)
    mid = hub.client.subscribe("t/early", 1)  # as a resumed session has it already
    deadline = time.monotonic() + 10
    while not hub.client.acked(mid):
        assert time.monotonic() < deadline
        time.sleep(0.02)
    pub = publisher(broker.port)
    for j in range(3):
        pub.publish("t/early", f"{j}".encode(), qos=1).wait_for_publish(5)
    while len(hub._pending) < 3:
        assert time.monotonic() < deadline, hub._pending
        time.sleep(0.02)
    a.subscribe("t/early", 1)
    assert [a.queue.get(timeout=5)[1] for _ in range(3)] == [b"0", b"1", b"2"]
    assert a in hub.take_touched()
    with pytest.raises(ConfigError, match="'t/early' belongs to two machines"):
        b.subscribe("t/early", 1)
    b.subscribe("t/b", 1)
    a.stop()  # b goes on: a's topic is unsubscribed
    time.sleep(0.5)
    pub.publish("t/early", b"late", qos=1).wait_for_publish(5)
    time.sleep(0.5)
    assert not hub._pending and a.queue.empty()
    assert "t/early" not in hub.client.topics
    hub.closing = True  # the whole process stops: b's subscription stays with the session
    b.stop()
    assert "t/b" in hub.client.topics
    pub.loop_stop()
    pub.disconnect()


def test_a_machines_own_client_id_is_refused_in_a_plant(broker: Broker, tmp_path: Path) -> None:
    """A plant's live machines share their worker's connection and session: a machine's own
    ``mqtt-client-id`` would be ignored, so it is refused, naming the worker's id."""
    model = save_spindle_model(MODEL, tmp_path / "spindle.json")
    plant = tmp_path / "plant.toml"
    plant.write_text("\n".join([
        'out = "state"', "[defaults]", f'model = "{model}"', "no-twin = true", "",
        "[[machine]]", 'name = "mill-1"', 'mqtt-client-id = "mine"',
        f'source = "mqtt://127.0.0.1:{broker.port}/{_topics(1)[0]}"', ""]), encoding="utf-8")
    proc = subprocess.run([sys.executable, "-m", "cnctwin", "edge", "run", "--config",
                           str(plant), "--quiet"], capture_output=True, text=True,
                          cwd=tmp_path, timeout=120)
    assert proc.returncode == 1, proc.stderr
    assert "machine mill-1: mqtt-client-id = 'mine': the live machines of a plant share " \
        "their worker's MQTT connection and session (client id cnctwin-edge-plant-" \
        in proc.stderr
    assert "Traceback" not in proc.stderr


def test_a_driven_hub_reconnects_after_a_broker_restart_and_loses_nothing(
        persistent_broker: Broker, signals: Recording, reference: list[dict[str, Any]],
        tmp_path: Path) -> None:
    """Once its machines are built the worker's thread drives the hub's socket itself (no
    network thread); the broker stops mid-stream and comes back (its persistence keeps the
    session and what was not acknowledged): the hub reconnects on its own (paho's back-off:
    1 s, then 2 s: data again within 3 s, inside the machines' idle timeout), and every
    machine gives exactly the results of its replay."""
    broker = persistent_broker
    machines = range(1, 4)
    pub = publisher(broker.port)
    for k in machines:
        pub.publish(_topics(k)[0], _metadata(k), qos=1, retain=True).wait_for_publish(5)
    hub = MqttHub("127.0.0.1", broker.port, client_id="plant-test-driven",
                  session_expiry_s=600)
    stop = threading.Event()
    reports: list[tuple[str, str, Any]] = []

    runner = _run_on_hub(hub, broker, tmp_path, machines, reports, stop, idle_timeout_s=6.0)
    deadline = time.monotonic() + 60
    while sum(r[1] == "started" for r in reports) < len(machines) or not hub.driven:
        assert time.monotonic() < deadline, reports
        time.sleep(0.05)
    payloads = _messages(signals)
    half = len(payloads) // 2
    try:
        for j, p in enumerate(payloads):
            if j == half:
                broker.stop()
                time.sleep(1.5)  # the hub's first attempt (after 1 s) fails
                broker.start()
                while not pub.is_connected():
                    assert time.monotonic() < deadline + 60, "the publisher did not reconnect"
                    time.sleep(0.05)
            for k in machines:
                pub.publish(_topics(k)[1], p, qos=1).wait_for_publish(10)
            time.sleep(PER_MSG * 0.002 / 8)
        runner.join(timeout=120)
    finally:
        stop.set()
        pub.loop_stop()
        pub.disconnect()
    assert not runner.is_alive()
    assert sorted(r[0] for r in reports if r[1] == "done") == [f"mill-{k}" for k in machines], \
        reports
    for k in machines:
        _same_as_reference(_read(tmp_path / f"mill-{k}" / "results.jsonl"), reference)
