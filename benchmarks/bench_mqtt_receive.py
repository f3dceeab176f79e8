"""The receive side of a live machine: CPU per Databus message with paho's own packet reader
against cnctwin's one-copy reader (``cnctwin.iotools._mqtt_read``), and the per-chunk steps
as NumPy code against the compiled loops, in one run.

What runs:

* a private mosquitto on a free port; a publisher thread sends 1 s Databus ``bulk`` messages
  (500 cycles x 11 datapoints, ~400 kB, the plant bench's size) every 20 ms with QoS 1;
* a receiver driven as a plant worker drives its hub (``select``, ``loop_read``, manual
  acknowledgement of each message), first with ``paho.mqtt.client.Client``, then with the
  one-copy client, then both again (A B B A; both runs of each shown, the better compared:
  the process's first run pays glibc's fresh mappings of large buffers); its thread's CPU
  per message (``time.thread_time``);
* the per-chunk steps (``samples_since``, ``SpeedChangeFlags.update`` on 500 samples) as the
  NumPy expressions they were and as the compiled loops they are, called back to back
  ("hot") and with a 2 ms sleep between calls, as a worker calls them between messages
  ("as in the plant"; the sleep's own cost measured and subtracted).

Run: ``.venv/bin/python benchmarks/bench_mqtt_receive.py [--messages 150]``.
"""

from __future__ import annotations

import argparse
import os
import platform
import select
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import orjson

from _common import cpu_model
from bench_edge_live import _free_port, _mosquitto


def _payload() -> bytes:
    vals = []
    for c in range(500):
        ts = f"2026-01-01T00:00:{(2 * c) // 1000:02d}.{(2 * c) % 1000:03d}Z"
        vals.append({"id": "1", "qc": 3, "ts": ts, "val": 10_000_000 + c})
        vals += [{"id": str(i + 2), "qc": 3, "ts": ts, "val": float(np.sin(0.01 * c + i))}
                 for i in range(10)]
    return orjson.dumps({"seq": 1, "vals": vals})


def _receive(cls: Any, port: int, payload: bytes, n: int, topic: str) -> float:
    """CPU of the receiving thread per message [us]."""
    import paho.mqtt.client as mqtt

    got = [0]
    c = cls(callback_api_version=mqtt.CallbackAPIVersion.VERSION2, client_id=f"rx-{topic}",
            manual_ack=True, protocol=mqtt.MQTTv5)

    def on_message(client: Any, userdata: Any, msg: Any) -> None:
        got[0] += 1
        client.ack(msg.mid, msg.qos)

    c.on_message = on_message
    c.connect("127.0.0.1", port)
    c.subscribe(topic, qos=1)
    for _ in range(20):
        c.loop(0.02)

    def publish() -> None:
        p = mqtt.Client(callback_api_version=mqtt.CallbackAPIVersion.VERSION2)
        p.connect("127.0.0.1", port)
        p.loop_start()
        time.sleep(0.3)
        for _ in range(n):
            p.publish(topic, payload, qos=1)
            time.sleep(0.02)
        time.sleep(0.5)
        p.loop_stop()

    th = threading.Thread(target=publish)
    th.start()
    t0 = time.thread_time()
    end = time.monotonic() + 0.3 + n * 0.02 + 3.0
    while got[0] < n and time.monotonic() < end:
        if select.select([c.socket()], [], [], 0.1)[0]:
            c.loop_read()
            if c.want_write():
                c.loop_write()
    cpu = time.thread_time() - t0
    th.join()
    c.disconnect()
    if got[0] < n:
        raise SystemExit(f"{cls.__name__} received {got[0]} of {n} messages")
    return cpu / n * 1e6


def _per_call_us(fn: Any, *, sleep_s: float, n: int = 800) -> float:
    t0 = time.thread_time()
    for _ in range(n):
        fn()
        if sleep_s:
            time.sleep(sleep_s)
    return (time.thread_time() - t0) / n * 1e6


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--messages", type=int, default=150)
    args = ap.parse_args()
    import paho.mqtt.client as mqtt

    from cnctwin.analysis.segments import _since
    from cnctwin.iotools._mqtt_read import receiving_client
    from cnctwin.spindle import SpeedChangeFlags

    payload = _payload()
    port = _free_port()
    broker = _mosquitto(port, Path(tempfile.mkdtemp(prefix="bench_rx_")))
    readers = {"paho's reader": mqtt.Client, "one-copy reader": receiving_client(mqtt)}
    runs: dict[str, list[float]] = {name: [] for name in readers}
    try:
        for k, name in enumerate([*readers, *reversed(list(readers))]):
            runs[name].append(_receive(readers[name], port, payload, args.messages,
                                       f"rx/{k}"))
    finally:
        broker.terminate()
        broker.wait(timeout=10)

    # the per-chunk steps: the former NumPy expressions against the compiled loops
    rng = np.random.default_rng(0)
    mask = rng.random(500) < 0.01
    speed = np.full(500, 2400.0)
    speed[100:150] = np.linspace(2400.0, 2000.0, 50)
    out = np.empty(500, dtype=np.int64)

    def since_numpy() -> Any:
        idx = np.arange(mask.size, dtype=np.int64)
        last = np.maximum.accumulate(np.where(mask, idx, -1))
        return np.where(last >= 0, idx - last, 5 + idx + 1)

    flags = SpeedChangeFlags()

    def flags_numpy_full() -> Any:  # the former update, samples_since as NumPy too
        prev = np.concatenate([[speed[0]], speed[:-1]])
        nxt = np.concatenate([speed[1:], [speed[-1]]])
        changed = ~((np.abs(speed - prev) <= 1.0) & (np.abs(nxt - speed) <= 1.0))
        idx = np.arange(changed.size, dtype=np.int64)
        last = np.maximum.accumulate(np.where(changed, idx, -1))
        since = np.where(last >= 0, idx - last, (1 << 40) + idx + 1)
        f = np.zeros(speed.size, dtype=np.int8)
        f[since <= 150] = 1
        f[~(np.abs(speed) >= 10.0)] = 2
        return f

    _since(mask, 5, out)  # compiled (or loaded from numba's cache) before timing
    flags.update(speed)
    sleep = _per_call_us(lambda: None, sleep_s=0.002)
    steps = [("samples_since, 500 samples", since_numpy, lambda: _since(mask, 5, out)),
             ("SpeedChangeFlags.update, 500 samples", flags_numpy_full,
              lambda: flags.update(speed))]

    print(f"machine: {cpu_model()}, {os.cpu_count()} vCPU; python {platform.python_version()}; "
          f"load average {os.getloadavg()[0]:.1f}")
    print(f"{args.messages} Databus messages of {len(payload) / 1e3:.0f} kB every 20 ms, QoS 1, "
          "manual acknowledgement, driven receiver\n")
    # the first run of the process pays glibc's fresh mappings of large buffers (its mmap
    # threshold rises as they are freed): both runs of each reader shown, the better compared
    best = {name: min(v) for name, v in runs.items()}
    print("| receive path | CPU per message [us], runs in order A B B A | better |\n|---|---|---|")
    for name in readers:
        print(f"| {name} | {', '.join(f'{v:.0f}' for v in runs[name])} | {best[name]:.0f} |")
    print(f"| ratio | | {best[next(iter(readers))] / best['one-copy reader']:.1f}x |\n")
    print("| per-chunk step | NumPy, hot [us] | compiled, hot [us] | NumPy, as in the plant [us] "
          "| compiled, as in the plant [us] |\n|---|---|---|---|---|")
    for title, numpy_fn, compiled in steps:
        row = [_per_call_us(numpy_fn, sleep_s=0.0), _per_call_us(compiled, sleep_s=0.0),
               _per_call_us(numpy_fn, sleep_s=0.002) - sleep,
               _per_call_us(compiled, sleep_s=0.002) - sleep]
        print(f"| {title} | " + " | ".join(f"{v:.1f}" for v in row) + " |")
    print(f"\n(the 2 ms sleep itself: {sleep:.1f} us of CPU per call, subtracted)")


if __name__ == "__main__":
    main()
