"""MTConnect out under load (issue 27, point 4): many HTTP clients and a stalled SHDR agent.

Two measurements, each beside its baseline in one run, on a simulated drilling run (the
tool-wear scenario, 78 signals at 500 Hz, ``--holes`` holes: about 5 s each) written as
Capture4Analysis JSON, as the edge device records it:

1. **A stalled SHDR agent.** ``cnctwin edge run --source RUN.json --shdr tcp://...
   --mtconnect-sample-hz 500`` replayed as fast as it goes, alternately without an agent and
   with one agent that connects and never reads (``--repeat`` times each): the runtime's
   cycles per second (``status.json``), and whether the agent was dropped and counted
   (``shdr_dropped_clients``). Before the per-agent queues the runtime froze at the first
   full socket buffer.
2. **200 HTTP clients.** The same replay at real time (``--speed 1``) with ``--mtconnect``;
   ``--clients`` threads each poll ``/current`` and follow ``/sample?from=nextSequence``
   for ``--seconds``: requests, errors, latency p50/p99/max. The clients run in this
   process (threads, the GIL): their own overhead is part of the latency.

Run: ``.venv/bin/python benchmarks/bench_mtconnect_clients.py [--clients 200 --seconds 30]``
"""

from __future__ import annotations

import argparse
import json
import os
import re
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

REAL = Path("run.json")  # set in main(): the simulated run
EXE = str(Path(sys.executable).parent / "cnctwin")


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _model(d: Path) -> Path:
    from cnctwin.edge import save_spindle_model
    from cnctwin.spindle import SpindleModel

    return Path(save_spindle_model(SpindleModel.from_parameters("thesis_spinner_840dsl"),
                                   d / "spindle.json"))


def stalled_agent_run(d: Path, model: Path, *, stalled: bool, tag: str,
                      speed: float = 0.0) -> dict[str, float]:
    port = _port()
    out = d / f"shdr-{tag}"
    cmd = [EXE, "edge", "run", "--source", str(REAL), "--model", str(model), "--out",
           str(out), "--quiet", "--no-twin", "--shdr", f"tcp://127.0.0.1:{port}",
           "--mtconnect-sample-hz", "500", "--status-s", "0.5", "--speed", str(speed)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    sock = None
    if stalled:
        deadline = time.time() + 30
        while sock is None and time.time() < deadline:
            try:
                sock = socket.create_connection(("127.0.0.1", port), timeout=1)
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
            except OSError:
                time.sleep(0.02)
    try:
        proc.communicate(timeout=600)
    finally:
        if sock is not None:
            sock.close()
    st = json.loads((out / "status.json").read_text())
    mt = st.get("sinks", {}).get("mtconnect", {})
    return {"cycles": st["cycles"], "cycles_per_s": st["cycles_per_s"],
            "dropped": mt.get("shdr_dropped_clients", 0), "connected_at_end":
            mt.get("shdr_clients", 0)}


def clients_run(d: Path, model: Path, *, clients: int, seconds: float,
                period_s: float = 0.0) -> dict[str, float]:
    port = _port()
    url = f"http://127.0.0.1:{port}"
    proc = subprocess.Popen(
        [EXE, "edge", "run", "--source", str(REAL), "--model", str(model), "--out",
         str(d / f"agent{period_s:g}"), "--quiet", "--no-twin", "--speed", "1",
         "--mtconnect", url],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 60
    while time.time() < deadline:
        try:
            urllib.request.urlopen(f"{url}/probe", timeout=2).read()
            break
        except OSError:
            time.sleep(0.2)
    lat: list[float] = []
    errors: list[str] = []
    lock = threading.Lock()
    stop = time.time() + seconds

    def client() -> None:
        nxt = None
        while time.time() < stop:
            if period_s:
                time.sleep(period_s)
            q = "/current" if nxt is None else f"/sample?from={nxt}&count=1000"
            t0 = time.perf_counter()
            try:
                with urllib.request.urlopen(url + q, timeout=30) as r:
                    body = r.read()
                dt = time.perf_counter() - t0
                m = re.search(rb'nextSequence="(\d+)"', body)
                nxt = int(m.group(1)) if m else None
                with lock:
                    lat.append(dt)
            except Exception as exc:  # counted, the run goes on
                with lock:
                    errors.append(f"{type(exc).__name__}: {exc}"[:120])
                nxt = None

    threads = [threading.Thread(target=client, daemon=True) for _ in range(clients)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(seconds + 60)
    proc.terminate()
    proc.wait(30)
    lat.sort()

    def q(p: float) -> float:
        return 1e3 * lat[min(len(lat) - 1, int(p * len(lat)))] if lat else float("nan")
    return {"requests": len(lat), "errors": len(errors), "first_errors": errors[:3],
            "p50_ms": q(0.5), "p99_ms": q(0.99), "max_ms": 1e3 * lat[-1] if lat else
            float("nan"), "per_s": len(lat) / seconds}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--clients", type=int, default=200)
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--holes", type=int, default=12)
    args = ap.parse_args()
    global REAL
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        subprocess.run([EXE, "simulate", "tool_wear_run", "--out", str(d / "sim"), "--option",
                        f"n_holes={args.holes}", "--format", "c4a"], check=True,
                       capture_output=True)
        REAL = sorted((d / "sim").glob("tool_wear_run*.json"))[0]
        from cnctwin.iotools import read_recording

        n = read_recording(REAL).n_cycles
        print(f"machine: {os.cpu_count()} cores; recording {REAL.name}: {n} cycles "
              f"({n * 0.002:.0f} s)")
        model = _model(d)
        free, stalled = [], []
        for i in range(args.repeat):
            free.append(stalled_agent_run(d, model, stalled=False, tag=f"free{i}"))
            stalled.append(stalled_agent_run(d, model, stalled=True, tag=f"stalled{i}"))
        f = sorted(r["cycles_per_s"] for r in free)[len(free) // 2]
        s = sorted(r["cycles_per_s"] for r in stalled)[len(stalled) // 2]
        print(f"SHDR at 500 Hz, replay as fast as it goes (median of {args.repeat}):")
        print(f"  without an agent            {f:10.0f} cycles/s")
        print(f"  with an agent that never reads {s:7.0f} cycles/s  ({100 * (s / f - 1):+.1f} %); "
              f"dropped and counted: {[r['dropped'] for r in stalled]}; all cycles: "
              f"{[r['cycles'] for r in stalled]}")
        slow = stalled_agent_run(d, model, stalled=True, tag="slow", speed=5.0)
        print(f"  at 5x real time ({n * 0.002 / 5:.0f} s) with the agent that never reads: "
              f"dropped and counted {slow['dropped']}, all {slow['cycles']} cycles processed")
        for period in (0.0, 1.0):
            c = clients_run(d, model, clients=args.clients, seconds=args.seconds,
                            period_s=period)
            how = "back to back" if not period else f"every {period:g} s"
            print(f"{args.clients} HTTP clients polling {how} for {args.seconds:g} s against "
                  f"the agent of a real-time replay: {c['requests']} requests "
                  f"({c['per_s']:.0f}/s), {c['errors']} errors {c['first_errors']}, latency "
                  f"p50 {c['p50_ms']:.1f} ms, p99 {c['p99_ms']:.1f} ms, max "
                  f"{c['max_ms']:.1f} ms")


if __name__ == "__main__":
    main()
