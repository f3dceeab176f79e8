"""The adaptive feed's closed loop over OPC UA: the same part off and on, and the loop latency.

Two real processes, as a user starts them (tests/usecases/test_adaptive_closed_loop.py has
the same set-up): the control (``cnctwin simulate --program ... --serve-opcua URL
--realtime``, values every ``--interval-s``) and the edge (``cnctwin edge run --source URL
--adaptive ...`` over a Basic256Sha256 SignAndEncrypt session with a user). The part: a
16 mm slot in AISI 1045 at F450 with hidden hardness x 1.0 / 1.15 / 0.95 along X, target
2.6 Nm. "Off": the same control without an edge (the PLC's watchdog keeps 100 %).

Reported side by side (``--out DIR``: adaptive_loop.json and adaptive_loop.html): cycle time,
cutting torque and power (mean, spread), override; the share of the settled cutting time
within +-5 % of the target; the loop latency p50/p99 (a sample served by the control -> the
override computed from it applied by the control's interpolator; an event in the cut waits
up to one serving interval more, since a served value is the mean of its interval).

Run: ``.venv/bin/python benchmarks/bench_adaptive_loop.py [--interval-s 0.02] [--out DIR]``
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import pandas as pd

from cnctwin.sim.programs import ADAPTIVE_SLOT
from cnctwin.usecases.adaptive_report import compare_runs, cut_share_within

PROGRAM = ADAPTIVE_SLOT.program
TOOLS = ADAPTIVE_SLOT.tools
STOCK = ADAPTIVE_SLOT.stock
HARDNESS = "part.hardness_along_x=" + json.dumps([list(p) for p in
                                                 ADAPTIVE_SLOT.hardness_along_x])
TARGET_NM = ADAPTIVE_SLOT.target_nm
EXE = str(Path(sys.executable).parent / "cnctwin")


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _prepare(d: Path) -> None:
    from asyncua.crypto.cert_gen import setup_self_signed_certificate
    from cryptography.x509.oid import ExtendedKeyUsageOID

    from cnctwin.edge.model_file import save_spindle_model
    from cnctwin.sim.machine import Machine
    from cnctwin.spindle import SpindleModel

    (d / "p.mpf").write_text(PROGRAM)
    (d / "tools.toml").write_text(TOOLS)
    (d / "adaptive.toml").write_text("min_pct = 50\nmax_pct = 120\ngain = 0.5\n"
                                     f"update_s = 0.1\n[tools.2]\ntarget_nm = {TARGET_NM}\n")
    asyncio.run(setup_self_signed_certificate(
        d / "edge-key.pem", d / "edge-cert.der", "urn:cnctwin:bench:edge", "localhost",
        [ExtendedKeyUsageOID.CLIENT_AUTH], {"commonName": "edge"}))
    s = Machine.thesis_default().spindle
    save_spindle_model(SpindleModel(s.kt_nm_per_a, s.viscous_friction_nm_per_rpm,
                                    s.coulomb_friction_nm, j_kgm2=s.inertia_kg_m2),
                       d / "spindle.json")


def run(d: Path, name: str, *, edge: bool, interval_s: float) -> dict[str, Any]:
    env = {**os.environ, "CNCTWIN_OPCUA_PASSWORD": "bench-secret"}
    url = f"opc.tcp://127.0.0.1:{_port()}"
    sim = subprocess.Popen(
        [EXE, "simulate", "--program", str(d / "p.mpf"), "--material", "aisi1045", "--tools",
         str(d / "tools.toml"), "--stock", STOCK, "--set", HARDNESS, "--out", str(d / name),
         "--serve-opcua", url, "--realtime", "--serve-interval-s", str(interval_s),
         "--serve-user", "operator", "--wait-for-client-s", "60" if edge else "0"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    ed = None
    try:
        if edge:
            while not (d / name / "nodes.toml").exists():
                if sim.poll() is not None:
                    raise SystemExit(sim.communicate()[1])
                time.sleep(0.1)
            ed = subprocess.Popen(
                [EXE, "edge", "run", "--source", url, "--nodes", str(d / name / "nodes.toml"),
                 "--interval-s", str(interval_s), "--adaptive", str(d / "adaptive.toml"),
                 "--model", str(d / "spindle.json"), "--security",
                 "Basic256Sha256_SignAndEncrypt", "--client-cert", str(d / "edge-cert.der"),
                 "--client-key", str(d / "edge-key.pem"), "--user", "operator", "--tools",
                 str(d / "tools.toml"), "--stock", STOCK, "--out", str(d / f"{name}-edge"),
                 "--quiet", "--no-anomaly", "--no-twin", "--idle-timeout-s", "8"],
                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        _, err = sim.communicate(timeout=300)
        if sim.returncode:
            raise SystemExit(err)
        if ed is not None:
            ed.communicate(timeout=60)
    finally:
        for p in (sim, ed):
            if p is not None and p.poll() is None:
                p.kill()
    s = json.loads((d / name / "adaptive.json").read_text())
    s["within_5pct_of_target"] = cut_share_within(pd.read_csv(d / name / "control.csv"),
                                                  TARGET_NM)
    return s


def _html(cmp: dict[str, Any], on: dict[str, Any], interval_s: float) -> str:
    rows = "".join(
        f"<tr><td>{k}</td><td>{_f(v['off'])}</td><td>{_f(v['on'])}</td>"
        f"<td>{_pct(v['change'])}</td></tr>" for k, v in cmp.items())
    lat = on["latency_ms"]
    return (f"<!doctype html><meta charset='utf-8'><title>Adaptive feed: off and on</title>"
            f"<h1>Adaptive feed: the same part off and on</h1>"
            f"<p>Target {TARGET_NM} Nm; control serving every {interval_s * 1e3:g} ms. Within "
            f"+-5 % of the target: {100 * on['within_5pct_of_target']:.1f} % of the settled "
            f"cutting time. Loop latency p50 {_f(lat['p50'])} ms, p99 {_f(lat['p99'])} ms "
            f"({lat['what']}).</p><table border=1 cellpadding=4><tr><th>quantity</th>"
            f"<th>off</th><th>on</th><th>change</th></tr>{rows}</table>")


def _pct(v: Any) -> str:
    return "" if v is None else f"{100 * v:+.1f} %"


def _f(v: Any) -> str:
    return "-" if v is None else f"{v:.4g}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--interval-s", type=float, default=0.02)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        _prepare(d)
        off = run(d, "off", edge=False, interval_s=args.interval_s)
        on = run(d, "on", edge=True, interval_s=args.interval_s)
    cmp = compare_runs(off, on)
    out = args.out or Path("benchmarks/results")
    out.mkdir(parents=True, exist_ok=True)
    doc = {"interval_s": args.interval_s, "target_nm": TARGET_NM, "off": off, "on": on,
           "side_by_side": cmp,
           "interval_ms": 1e3 * args.interval_s,
           "machine": os.uname().nodename, "cores": os.cpu_count()}
    (out / "adaptive_loop.json").write_text(json.dumps(doc, indent=2))
    (out / "adaptive_loop.html").write_text(_html(cmp, on, args.interval_s))
    print(f"{'quantity':32s} {'off':>10s} {'on':>10s} {'change':>9s}")
    for k, v in cmp.items():
        ch = "" if v["change"] is None else f"{100 * v['change']:+.1f} %"
        print(f"{k:32s} {_f(v['off']):>10s} {_f(v['on']):>10s} {ch:>9s}")
    w_off, w_on = off["within_5pct_of_target"], on["within_5pct_of_target"]
    print(f"within +-5 % of {TARGET_NM} Nm (settled cutting time): off {100 * w_off:.1f} %, "
          f"on {100 * w_on:.1f} %")
    lat = on["latency_ms"]
    print(f"loop latency (sample served -> override applied): p50 {_f(lat['p50'])} ms, p99 "
          f"{_f(lat['p99'])} ms over {lat['n']} updates (a value is the mean of its "
          f"{doc['interval_ms']:g} ms interval, served at its end: add up to that from the "
          f"event in the cut); {out / 'adaptive_loop.json'}")


if __name__ == "__main__":
    main()
