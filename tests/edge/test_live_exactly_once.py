"""Issue 14 acceptance, point 1: a drilling run streamed live through a real mosquitto into the
runtime as a real process, killed twice (SIGKILL) at random points and restarted, with the
broker stopped for 10 s once: every cycle's torque exactly once, the holes and alarms of the
uninterrupted run, no seq twice.

The machine: the simulated tool-wear run (5 CYCLE81 holes, thesis §5.1), its drive signals
published as Industrial Edge Databus ``bulk`` messages (the documented payload, 100 cycles per
message, the SINUMERIK cycle counter as the ``CYCLE`` datapoint), at 4x real time. The
reference: the same runtime options on the same signals, uninterrupted (in this process).
How it holds: the live source acknowledges a message to the broker only when a checkpoint of
the processors covers it (MQTT 5 persistent session, manual acknowledgement), so after a crash
the broker delivers again everything after the last checkpoint, the runtime restores the
checkpoint and does not emit again what its results already hold.
"""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from cnctwin.edge import (
    AnomalyProcessor,
    EdgeRuntime,
    HoleProcessor,
    JsonLinesSink,
    ReplaySource,
    TorqueProcessor,
    save_spindle_model,
)
from cnctwin.recording import Recording, RecordingMeta
from cnctwin.spindle import SpindleModel
from tests._services import Broker
from tests.edge._databus import bulk_messages, read_results, torque_of
from tests.edge.conftest import publisher

pytestmark = pytest.mark.mqtt
META = "ie/m/j/simatic/v1/nck1/dp"
DATA = "ie/d/j/simatic/v1/nck1/dp/r/NCK/hf"
COLUMNS = ["CURRENT|SP1", "CMD_SPEED|SP1", "DES_POS|X1", "ENC_POS|X1", "DES_POS|Y1",
           "ENC_POS|Y1", "DES_POS|Z1", "ENC_POS|Z1", "TORQUE|Z1", "CURRENT|Z1"]
PER_MSG = 100
MODEL = SpindleModel(1.01, 8.3e-5, 0.34, j_kgm2=0.0045)


def _metadata() -> bytes:
    defs = [{"name": "CYCLE", "id": "1", "dataType": "DInt"}] + [
        {"name": c, "id": str(i + 2), "dataType": "LReal"} for i, c in enumerate(COLUMNS)]
    return json.dumps({"seq": 1, "hashVersion": 1, "applicationName": "mill-1",
                       "connections": [{"name": "NCK", "type": "sinumerik", "dataPoints": [
                           {"name": "hf", "topic": DATA, "publishType": "bulk",
                            "dataPointDefinitions": defs}]}]}).encode()


@pytest.fixture(scope="module")
def signals(tmp_path_factory: pytest.TempPathFactory) -> Recording:
    """The drive signals of the 5-hole run, as the Databus carries them (no NC events)."""
    from cnctwin.sim import scenarios as sc

    rec = sc.tool_wear_run(n_holes=5, holes_per_set=5, dynamometer=False, seed=7).recording
    hf = rec.hf[["time", *COLUMNS]].copy()
    return Recording(hf, meta=RecordingMeta(machine="mill-1", cycle_time_s=0.002,
                                            source_format="databus"))


def _messages(rec: Recording) -> list[bytes]:
    return bulk_messages(rec, COLUMNS, PER_MSG)


_read = read_results


_torque = torque_of


def test_live_drilling_run_exactly_once_across_two_kills_and_a_broker_stop(
        persistent_broker: Broker, signals: Recording, tmp_path: Path) -> None:
    broker = persistent_broker
    n = signals.n_cycles
    assert n >= 10_000
    # the uninterrupted reference
    ref_dir = tmp_path / "reference"
    EdgeRuntime(ReplaySource(signals, chunk_cycles=PER_MSG),
                [TorqueProcessor(MODEL), HoleProcessor(MODEL),
                 AnomalyProcessor(model=MODEL, learn_s=3.0)],
                [JsonLinesSink(ref_dir / "results.jsonl")], state_dir=ref_dir).run()
    ref = _read(ref_dir / "results.jsonl")
    ref_holes = [m["row"] for m in ref if m["kind"] == "hole"]
    assert len(ref_holes) == 5

    model = save_spindle_model(MODEL, tmp_path / "spindle.json")
    out = tmp_path / "state"
    results = out / "results.jsonl"
    cmd = [sys.executable, "-m", "cnctwin", "edge", "run",
           "--source", f"mqtt://127.0.0.1:{broker.port}/{META}", "--model", str(model),
           "--out", str(out), "--learn-s", "3", "--quiet", "--no-twin"]
    payloads = _messages(signals)
    pub = publisher(broker.port)
    pub.publish(META, _metadata(), qos=1, retain=True).wait_for_publish(timeout=5)
    paused = threading.Event()
    sent = [0]
    lock = threading.Lock()
    pubs = [pub]

    def publish_all() -> None:
        for p in payloads:
            while paused.is_set():
                time.sleep(0.05)
            with lock:
                pubs[0].publish(DATA, p, qos=1).wait_for_publish(timeout=30)
            sent[0] += 1
            time.sleep(PER_MSG * 0.002 / 4)  # 4x real time

    def processed() -> int:
        return int(_torque(_read(results))[0].size) if results.exists() else 0

    def start() -> subprocess.Popen[bytes]:
        return subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)

    def wait_for(cycles: int, proc: subprocess.Popen[bytes], timeout_s: float = 120) -> None:
        end = time.monotonic() + timeout_s
        while processed() < cycles:
            assert proc.poll() is None, proc.communicate()[1].decode()[-2000:]
            assert time.monotonic() < end, f"{processed()} of {cycles} cycles"
            time.sleep(0.05)

    rng = random.Random(int(os.environ.get("CNCTWIN_TEST_SEED", "14")))
    run = start()
    # its persistent session exists before the control publishes (the runtime writes its
    # status once connected, subscribed and running; idle, every second)
    end = time.monotonic() + 120
    while not (out / "status.json").exists():
        assert run.poll() is None, run.communicate()[1].decode()[-2000:]
        assert time.monotonic() < end, "the runtime did not start"
        time.sleep(0.05)
    feeder = threading.Thread(target=publish_all, daemon=True)
    feeder.start()
    try:
        # kill 1: somewhere in the first two holes
        wait_for(rng.randint(1500, 3500), run)
        run.send_signal(signal.SIGKILL)
        run.wait(10)
        run = start()
        # the broker away for 10 s under the running runtime, the control waiting
        wait_for(processed() + rng.randint(500, 1500), run)
        paused.set()
        with lock:
            pubs[0].loop_stop()
            pubs[0].disconnect()
            broker.stop()
            time.sleep(10.0)
            broker.start()
            pubs[0] = publisher(broker.port)
        paused.clear()
        # kill 2: somewhere later
        wait_for(min(processed() + rng.randint(1000, 3000), n - 1500), run)
        run.send_signal(signal.SIGKILL)
        run.wait(10)
        feeder.join(timeout=120)
        assert sent[0] == len(payloads)
        run = subprocess.Popen([*cmd, "--idle-timeout-s", "4"], stdout=subprocess.DEVNULL,
                               stderr=subprocess.PIPE)
        _, err = run.communicate(timeout=180)
        assert run.returncode == 0, err.decode()[-2000:]
    finally:
        if run.poll() is None:
            run.kill()
        paused.clear()
        pubs[0].loop_stop()
        pubs[0].disconnect()
    msgs = _read(results)
    seqs = [m["seq"] for m in msgs]
    assert len(seqs) == len(set(seqs)), "a seq was given to two messages"
    cyc, tau = _torque(msgs)
    assert np.array_equal(cyc, np.unique(cyc)), "a cycle's torque twice or out of order"
    rcyc, rtau = _torque(ref)
    np.testing.assert_array_equal(cyc, rcyc)  # every input cycle, once
    np.testing.assert_allclose(tau, rtau, rtol=1e-12, atol=1e-12)
    holes = [m for m in msgs if m["kind"] == "hole"]
    assert not any(h.get("partial") for h in holes)
    assert [h["row"]["hole"] for h in holes] == [h["hole"] for h in ref_holes]
    for h, r in zip(holes, ref_holes, strict=True):
        for key in ("start_cycle", "end_cycle", "cut_start_cycle", "cut_end_cycle"):
            assert h["row"][key] == r[key], key
        assert h["row"]["torque_mean_nm"] == pytest.approx(r["torque_mean_nm"], rel=1e-9)
    assert [m["cycle"] for m in msgs if m["kind"] == "alarm"] == \
        [m["cycle"] for m in ref if m["kind"] == "alarm"]
    runs = [m["resumed"] for m in msgs if m["kind"] == "run"]
    assert [r["from_checkpoint"] for r in runs] == [False, True, True]
