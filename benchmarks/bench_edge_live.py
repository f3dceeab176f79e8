"""Many machines live: N simulated machines publish Databus messages through a real mosquitto,
one ``cnctwin edge run --config plant.toml`` serves them all; latency and CPU per machine.

What runs (all on this machine, sharing its cores):

* a private mosquitto on a free port;
* the publisher (this process, one thread): every machine replays the same simulated drilling
  run (tool-wear scenario, thesis §5.1: 20 mm CYCLE81 holes at 2400 rpm) as Industrial Edge
  Databus ``bulk`` messages (documented payload: ``{"seq", "vals": [{"id", "qc", "ts",
  "val"}]}``), ``--cycles-per-message`` cycles per message (default 500 = one message per
  second, the size a plant of many machines is configured for, docs/edge.md; 50 = 100 ms),
  paced in real time; the machines are not synchronised: machine m of M sends m/M of a
  message period after machine 0, as independent controls would. Every machine replays the
  same data, so each message is encoded once before the clock starts;
* the plant: ``cnctwin edge run --config plant.toml`` with one worker process per core; every
  machine runs the full path (torque + holes + physics anomaly detector) and publishes its
  results (MQTT, store-and-forward queue, QoS 1) to the same broker.

Reported, in one run:

* latency, as the runtime measures it: from the arrival of a message at the runtime (the
  MQTT client's receive callback) to the results handed to the MQTT sink (published), per
  chunk; p50/p99/max over every chunk of every machine (``status.json`` of each machine);
* latency end to end, as a consumer sees it: from the publisher's send of the message that
  holds a torque result's last cycle to the arrival of that result at a subscriber (two
  broker hops included: an upper bound of the above);
* CPU of the whole plant (supervisor + workers, from ``/proc`` of the process tree, from
  the first published message to 1 s after the last: start-up not counted) per
  machine-second of data: machines one core serves at 500 Hz on this path, Databus
  decoding and MQTT in and out included; beside it the physical need (500 cycles/s per
  machine) and the bare estimator floor measured in the same run.

Run: ``.venv/bin/python benchmarks/bench_edge_live.py [--machines 100] [--seconds 30]
[--cycles-per-message 500] [--status-s 1] [--baseline-rev COMMIT]`` (``--baseline-rev``: the
same run also with the plant of an earlier commit, ``git archive``, side by side).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import orjson

from _common import cpu_model

NEED = 500.0
COLUMNS = ["CURRENT|SP1", "CMD_SPEED|SP1", "DES_POS|X1", "ENC_POS|X1", "DES_POS|Y1",
           "ENC_POS|Y1", "DES_POS|Z1", "ENC_POS|Z1", "TORQUE|Z1", "CURRENT|Z1"]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _mosquitto(port: int, conf_dir: Path) -> subprocess.Popen[bytes]:
    exe = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
    if not os.path.exists(exe):
        sys.exit("mosquitto not found: apt-get install mosquitto")
    conf = conf_dir / "mosquitto.conf"
    conf.write_text(f"listener {port} 127.0.0.1\nallow_anonymous true\n"
                    "max_queued_messages 100000\nmax_inflight_messages 100\n")
    proc = subprocess.Popen([exe, "-c", str(conf)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    for _ in range(100):
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.2):
                return proc
        except OSError:
            time.sleep(0.05)
    proc.kill()
    sys.exit("mosquitto did not start")


def _tree_cpu_s(pid: int) -> float:
    """User + system CPU [s] of a process and its children so far (/proc; Linux)."""
    tick = os.sysconf("SC_CLK_TCK")
    total = 0.0
    todo = [pid]
    while todo:
        p = todo.pop()
        try:
            fields = Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()
            total += (int(fields[11]) + int(fields[12])) / tick
            for task in Path(f"/proc/{p}/task").iterdir():
                kids = (task / "children").read_text().split()
                todo += [int(k) for k in kids]
        except (OSError, IndexError, ValueError):
            continue
    return total


def _decode_cost_ms(payload: bytes, repeat: int = 200) -> dict[str, float]:
    """CPU per message [ms] of the plant's Databus pass (``DatabusDecoder.decode_columns``) and
    of its numba scan alone, on one of the bench's messages, in this process."""
    from cnctwin.iotools import _databus_scan as scan
    from cnctwin.iotools.databus import DatabusDecoder

    _, topic, meta = _metadata(0)
    dec = DatabusDecoder(meta)
    if dec.decode_columns(payload, topic=topic) is None:
        raise SystemExit("the bench's message left the fast path: fix the publisher")
    c0 = time.process_time()
    for _ in range(repeat):
        dec.decode_columns(payload, topic=topic)
    full = (time.process_time() - c0) / repeat
    lut = scan.id_table({str(i + 1): i for i in range(1 + len(COLUMNS))})
    buf = np.frombuffer(payload, dtype=np.uint8)
    arrays = scan._scan_arrays(buf.size)
    fn = scan._scanner()
    c0 = time.process_time()
    for _ in range(repeat):
        scan._call(fn, buf, lut, arrays)
    return {"decode": full * 1e3, "scan": (time.process_time() - c0) / repeat * 1e3}


def _batches(env: dict[str, str] | None) -> bool:
    """Whether the plant code run with ``env`` (None: this code) has ``batch-s`` (a
    baseline older than it runs its messages unbatched)."""
    if env is None:
        return True
    cli = Path(env["PYTHONPATH"]) / "cnctwin" / "cli" / "edge.py"
    return cli.exists() and '"--batch-s"' in cli.read_text(encoding="utf-8")


def _metadata(k: int) -> tuple[str, str, bytes]:
    meta = f"ie/m/j/simatic/v1/m{k:03d}/dp"
    data = f"ie/d/j/simatic/v1/m{k:03d}/dp/r/NCK/hf"
    defs = [{"name": "CYCLE", "id": "1", "dataType": "DInt"}] + [
        {"name": c, "id": str(i + 2), "dataType": "LReal"} for i, c in enumerate(COLUMNS)]
    doc = {"seq": 1, "hashVersion": 1, "applicationName": f"mill-{k:03d}", "connections": [
        {"name": "NCK", "type": "sinumerik", "dataPoints": [
            {"name": "hf", "topic": data, "publishType": "bulk",
             "dataPointDefinitions": defs}]}]}
    return meta, data, orjson.dumps(doc)


def _measure(args: argparse.Namespace, tmp: Path, payloads: list[bytes], n_cyc: int,
             env: dict[str, str] | None) -> dict[str, Any]:
    """One run: a private broker, the plant (with ``env``: another code's PYTHONPATH), the
    publisher; the figures of the table."""
    import paho.mqtt.client as mqtt

    cpm = args.cycles_per_message
    batched = _batches(env)
    port = _free_port()
    broker = _mosquitto(port, tmp)
    topics = [_metadata(k) for k in range(args.machines)]
    pub = mqtt.Client(callback_api_version=mqtt.CallbackAPIVersion.VERSION2,
                      client_id="bench-publisher")
    pub.max_inflight_messages_set(1000)
    pub.connect("127.0.0.1", port)
    pub.loop_start()
    for meta, _, doc in topics:
        pub.publish(meta, doc, qos=1, retain=True).wait_for_publish(timeout=10)

    lines = [f"workers = {args.workers}" if args.workers else "", 'out = "state"', "",
             "[defaults]", f'model = "{tmp / "spindle.json"}"',
             f'publish = "mqtt://127.0.0.1:{port}/results"', "learn-s = 5",
             "idle-timeout-s = 5", "session-expiry-s = 0", "no-twin = true",
             f"status-s = {args.status_s}",
             f"batch-s = {args.batch_s}" if batched else "", ""]
    for k, (meta, _, _) in enumerate(topics):
        lines += ["[[machine]]", f'name = "mill-{k:03d}"',
                  f'source = "mqtt://127.0.0.1:{port}/{meta}"', ""]
    shutil.rmtree(tmp / "state", ignore_errors=True)
    (tmp / "plant.toml").write_text("\n".join(lines), encoding="utf-8")

    # a consumer of the results: arrival time of every torque message
    got: list[tuple[str, int, int, int]] = []  # machine, first_cycle, n, arrival ns
    runs: set[str] = set()
    lock = threading.Lock()

    def on_message(client: Any, userdata: Any, msg: Any) -> None:
        t = time.time_ns()
        m = orjson.loads(msg.payload)
        with lock:
            if m.get("kind") == "torque":
                got.append((m["machine"], m["first_cycle"], m["n"], t))
            elif m.get("kind") == "run":
                runs.add(m["machine"])

    sub = mqtt.Client(callback_api_version=mqtt.CallbackAPIVersion.VERSION2,
                      client_id="bench-consumer")
    sub.on_message = on_message
    sub.connect("127.0.0.1", port)
    sub.subscribe("results/#", qos=0)
    sub.loop_start()

    plant = subprocess.Popen([sys.executable, "-m", "cnctwin", "edge", "run", "--config",
                              str(tmp / "plant.toml"), "--quiet"], cwd=tmp, env=env,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 180
    while len(runs) < args.machines:
        if plant.poll() is not None or time.monotonic() > deadline:
            out, err = plant.communicate()
            sys.exit(f"the plant did not start all machines ({len(runs)}): "
                     f"{err.decode()[-2000:]}")
        time.sleep(0.2)
    time.sleep(1.0)  # every data subscription in place

    base = 10_000_000
    cpu_start = _tree_cpu_s(plant.pid)  # start-up (imports, connects) not counted
    # real time: message j of machine m at t0 + (j + 1 + m / M) * period; the machines are
    # not synchronised (their messages spread over the period, as independent controls')
    sent_ns = np.zeros((args.machines, len(payloads)), dtype=np.int64)
    start = time.perf_counter()
    period = cpm / NEED
    for j, payload in enumerate(payloads):
        for m, (_, topic, _) in enumerate(topics):
            due = start + (j + 1 + m / args.machines) * period
            wait = due - time.perf_counter()
            if wait > 0:
                time.sleep(wait)
            sent_ns[m, j] = time.time_ns()
            pub.publish(topic, payload, qos=1)
    lag_end = time.perf_counter() - (start + (len(payloads) + 1) * period)
    time.sleep(1.0)  # the last messages processed; the idle timeout has not ended a machine
    cpu_s = _tree_cpu_s(plant.pid) - cpu_start
    out, err = plant.communicate(timeout=300)
    time.sleep(1.0)
    sub.loop_stop()
    pub.loop_stop()
    broker.terminate()
    broker.wait(timeout=10)

    summary = json.loads(out.decode().strip().splitlines()[-1])
    cycles = sum(int(v.get("cycles") or 0) for v in summary.values())
    errors = {k: v for k, v in summary.items() if "error" in v}
    lat_p99, lat_p50, lat_max, lost = [], [], [], 0
    pipe_cpu_s = 0.0
    for name in summary:
        st = json.loads((tmp / "state" / name / "status.json").read_text())
        lm = st["latency_ms"]
        if lm["p99"] is not None:
            lat_p99.append(lm["p99"])
            lat_p50.append(lm["p50"])
            lat_max.append(lm["max"])
        lost += sum(int(v) for v in st["overload"].values())
        pipe_cpu_s += float(st.get("cpu_s") or 0.0)
    # end to end: per torque result, arrival - send of the message holding its last cycle
    ext = []
    for machine, first, n, t_rx in got:
        m = int(machine.split("-")[1])
        last = first + n - 1 - base
        if last == n_cyc - 1 and n == 1:
            # the torque estimator's derivative holds each message's last cycle back until
            # the next message; the very last one comes out when the stream ends (idle
            # timeout), which is not a latency of the pipeline
            continue
        j = last // cpm
        if 0 <= j < sent_ns.shape[1]:
            ext.append((t_rx - sent_ns[m, j]) / 1e6)
    e = np.asarray(ext)
    return {"batched": batched, "lag_end_ms": lag_end * 1e3, "errors": len(errors),
            "cycles": cycles,
            "lost": lost, "p50": float(np.median(lat_p50)), "p99_median": float(
                np.median(lat_p99)), "p99_worst": max(lat_p99), "max": max(lat_max),
            "e2e_p50": float(np.percentile(e, 50)), "e2e_p99": float(np.percentile(e, 99)),
            "cpu_s": cpu_s, "pipe_cpu_s": pipe_cpu_s,
            "per_core": cycles / cpu_s / NEED}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--machines", type=int, default=100)
    ap.add_argument("--seconds", type=float, default=30.0, help="machine time published")
    ap.add_argument("--cycles-per-message", type=int, default=500)
    ap.add_argument("--workers", type=int, default=0, help="plant workers (0: the cores)")
    ap.add_argument("--status-s", type=float, default=1.0,
                    help="the machines' status interval (edge run --status-s) [s]")
    ap.add_argument("--batch-s", type=float, default=0.0,
                    help="the machines' batch interval (edge run --batch-s; this code only) "
                    "[s]")
    ap.add_argument("--baseline-rev", metavar="COMMIT",
                    help="also run the plant with the code of this commit (git archive), in "
                    "the same run, and show both side by side")
    ap.add_argument("--keep", action="store_true", help="keep the temporary folder")
    args = ap.parse_args()
    from cnctwin.edge import save_spindle_model
    from cnctwin.sim import scenarios as sc
    from cnctwin.spindle import SpindleModel, StreamingTorqueEstimator

    tmp = Path(tempfile.mkdtemp(prefix="bench_live_"))
    n_cyc = int(args.seconds * NEED)
    holes = max(1, int(args.seconds / 4.4) + 1)
    rec = sc.tool_wear_run(n_holes=holes, holes_per_set=6, dynamometer=False,
                           seed=0).recording
    n_cyc = min(n_cyc, rec.n_cycles)
    data = {c: rec.hf[c].to_numpy(dtype=np.float64)[:n_cyc] for c in COLUMNS}
    model = SpindleModel(1.04, 8.42e-5, 0.35, j_kgm2=0.0045)
    save_spindle_model(model, tmp / "spindle.json")

    # floor, same run: the bare estimator over the same chunks
    est = StreamingTorqueEstimator(model)
    c0 = time.process_time()
    cpm = args.cycles_per_message
    for k in range(0, n_cyc, cpm):
        est.update(data["CURRENT|SP1"][k:k + cpm], data["CMD_SPEED|SP1"][k:k + cpm])
    floor = n_cyc / (time.process_time() - c0)

    # every machine replays the same data: each message is encoded once, before the clock
    # starts, and sent to every machine's topic (the publisher stands for the controls; its
    # JSON encoding is not the plant's work and would only take CPU from it here)
    base = 10_000_000
    t_ms0 = int(time.time() * 1000) + 2000
    payloads: list[bytes] = []
    for j, k in enumerate(range(0, n_cyc, cpm)):
        vals: list[dict[str, Any]] = []
        for c in range(k, min(k + cpm, n_cyc)):
            sec, ms = divmod(t_ms0 + 2 * c, 1000)
            ts = time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(sec)) + f".{ms:03d}Z"
            vals.append({"id": "1", "qc": 3, "ts": ts, "val": base + c})
            vals += [{"id": str(i + 2), "qc": 3, "ts": ts, "val": float(data[col][c])}
                     for i, col in enumerate(COLUMNS)]
        payloads.append(orjson.dumps({"seq": j + 1, "vals": vals}))

    decode_ms = _decode_cost_ms(payloads[len(payloads) // 2])

    codes: list[tuple[str, dict[str, str] | None]] = [("this code", None)]
    if args.baseline_rev:
        from _common import export_rev

        old = export_rev(args.baseline_rev, Path(tempfile.mkdtemp(dir=tmp)))
        codes.append((f"code of {args.baseline_rev}", {**os.environ, "PYTHONPATH": str(old)}))
    # with a baseline: each code twice, in the order A B B A, the better run reported (the
    # first plant of a run can cost ~30 % more CPU per cycle than the same code after it:
    # BENCHMARKS.md, "Replay plant, re-measured")
    order = codes + codes[::-1] if len(codes) > 1 else codes
    best: dict[str, dict[str, Any]] = {}
    for label, env in order:
        r = _measure(args, tmp, payloads, n_cyc, env)
        if label not in best or r["per_core"] > best[label]["per_core"]:
            best[label] = r
    res = [(label, best[label]) for label, _ in codes]
    load = os.getloadavg()
    print(f"machine: {cpu_model()}, {os.cpu_count()} vCPU; load average "
          f"{load[0]:.1f}/{load[1]:.1f}/{load[2]:.1f}; python {platform.python_version()}")
    for label, r in res:
        print(f"{label}: {args.machines} machines x {n_cyc} cycles ({n_cyc / NEED:.0f} s, "
              f"{cpm} cycles per message, {1 + len(COLUMNS)} datapoints, status every "
              f"{args.status_s:g} s, batches of {args.batch_s if r['batched'] else 0:g}"
              " s); publisher behind schedule at the end by "
              f"{r['lag_end_ms']:.0f} ms; errors {r['errors']}; cycles processed "
              f"{r['cycles']} of {args.machines * n_cyc}; counted losses {r['lost']}")
    print()
    print("| figure | " + " | ".join(label for label, _ in res) + " |")
    print("|---|" + "---|" * len(res))
    rows = [("latency arrival -> publish, p50 of the machines' p50 [ms]", "p50", ".1f"),
            ("latency arrival -> publish, median of the machines' p99 [ms]", "p99_median",
             ".1f"),
            ("latency arrival -> publish, worst machine's p99 [ms]", "p99_worst", ".1f"),
            ("latency arrival -> publish, max [ms]", "max", ".1f"),
            ("end to end (send -> result at a subscriber), p50 [ms]", "e2e_p50", ".1f"),
            ("end to end, p99 [ms]", "e2e_p99", ".1f"),
            (f"plant CPU [s] for {n_cyc / NEED * args.machines:.0f} machine-seconds",
             "cpu_s", ".1f"),
            ("of which the machines' pipelines (`cpu_s` in status.json: chunk -> results in "
             "the sinks, checkpoints) [s]", "pipe_cpu_s", ".1f"),
            ("**machines at 500 Hz per core, live, whole plant process** (Databus + full "
             "path + MQTT)", "per_core", ".0f")]
    for title, key, fmt in rows:
        print(f"| {title} | " + " | ".join(format(r[key], fmt) for _, r in res) + " |")
    print(f"| floor: bare estimator, same chunks, machines per core | {floor / NEED:,.0f} |"
          + " |" * (len(res) - 1))
    print(f"| one message's Databus pass in this process (`decode_columns`), of which the "
          f"numba scan [ms] | {decode_ms['decode']:.2f}, {decode_ms['scan']:.2f} |"
          + " |" * (len(res) - 1))
    if args.keep:
        print(f"kept: {tmp}")
    else:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
