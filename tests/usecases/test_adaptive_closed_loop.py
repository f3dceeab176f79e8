"""Adaptive feed in closed loop between two processes over OPC UA (issue 26, point 4).

The control: ``cnctwin simulate --program PART.mpf ... --serve-opcua URL --realtime`` serves
the part in real time (values every 20 ms) and plays it at the override its PLC passes on
(heartbeat watchdog 0.5 s, clamp 50-120 %, stop request ends the program). The edge:
``cnctwin edge run --source URL --nodes OUT/nodes.toml --adaptive ADAPTIVE.toml`` over a
Basic256Sha256 SignAndEncrypt session with a user, writing the override back. Both are real
processes started as a user starts them.

The part: a 16 mm slot 2 mm deep in AISI 1045 at F450 (3000 rpm), hidden hardness x 1.0 /
1.15 / 0.95 along X (``--set part.hardness_along_x``), target 2.6 Nm; by the closed form the
torque is 2.38 Nm at 100 % and hardness 1 (Altintas eq. 2.47, test_adaptive_loop.py), so the
loop must speed up (~110 %), slow down in the hard zone (~88 %) and speed up again (capped at
120 %). Judged from the control's log of the hidden truth (``control.csv``): the cutting
torque (power at a fixed speed) within +-5 % of the target over >= 90 % of the settled cutting
time; the cycle time shorter than the same part at the programmed feed; no drive limit
exceeded. A cutter breaking at X 60 (hidden): the stop request ends the program within
100 ms of the break (served and read every 10 ms in that case: at 20 ms the two quantization
terms left ~20 ms of margin and the loaded 2-worker suite measured 130 ms once; at 10 ms
46-94 ms with both cores busy besides the two processes). The edge killed mid-part: the PLC
falls back to 100 % within its heartbeat time (0.5 s) plus one control read (20 ms).

The edge's spindle model is the simulated machine's (the thesis machine); its calibration
from air cuts is tested in tests/calibration.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

from cnctwin.sim.programs import ADAPTIVE_SLOT
from tests._services import free_port

pytestmark = pytest.mark.xdist_group("adaptive_realtime")

PROGRAM = ADAPTIVE_SLOT.program
TOOLS = ADAPTIVE_SLOT.tools
STOCK = ADAPTIVE_SLOT.stock
HARDNESS = "part.hardness_along_x=" + json.dumps([list(p) for p in
                                                 ADAPTIVE_SLOT.hardness_along_x])
TARGET_NM = ADAPTIVE_SLOT.target_nm
INTERVAL_S = 0.02
EXE = str(Path(sys.executable).parent / "cnctwin")


@pytest.fixture(scope="module")
def setup(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    import asyncio

    from asyncua.crypto.cert_gen import setup_self_signed_certificate
    from cryptography.x509.oid import ExtendedKeyUsageOID

    from cnctwin.edge.model_file import save_spindle_model
    from cnctwin.sim.machine import Machine
    from cnctwin.spindle import SpindleModel

    d = tmp_path_factory.mktemp("loop")
    (d / "p.mpf").write_text(PROGRAM)
    (d / "tools.toml").write_text(TOOLS)
    (d / "adaptive.toml").write_text("min_pct = 50\nmax_pct = 120\ngain = 0.5\n"
                                     f"update_s = 0.1\n[tools.2]\ntarget_nm = {TARGET_NM}\n")
    asyncio.run(setup_self_signed_certificate(
        d / "edge-key.pem", d / "edge-cert.der", "urn:cnctwin:test:edge", "localhost",
        [ExtendedKeyUsageOID.CLIENT_AUTH], {"commonName": "edge"}))
    s = Machine.thesis_default().spindle
    save_spindle_model(SpindleModel(s.kt_nm_per_a, s.viscous_friction_nm_per_rpm,
                                    s.coulomb_friction_nm, j_kgm2=s.inertia_kg_m2),
                       d / "spindle.json")
    return {"dir": d}


def _env() -> dict[str, str]:
    return {**os.environ, "CNCTWIN_OPCUA_PASSWORD": "loop-secret"}


def _sim(d: Path, name: str, url: str, *extra: str,
         interval_s: float = INTERVAL_S) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [EXE, "simulate", "--program", str(d / "p.mpf"), "--material", "aisi1045", "--tools",
         str(d / "tools.toml"), "--stock", STOCK, "--set", HARDNESS, *extra,
         "--out", str(d / name), "--serve-opcua", url, "--realtime", "--serve-interval-s",
         str(interval_s), "--serve-user", "operator", "--wait-for-client-s", "60"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env())


def _edge_cmd(d: Path, name: str, url: str, interval_s: float = INTERVAL_S) -> list[str]:
    return [EXE, "edge", "run", "--source", url, "--nodes", str(d / name / "nodes.toml"),
            "--interval-s", str(interval_s), "--adaptive", str(d / "adaptive.toml"),
            "--model", str(d / "spindle.json"), "--security", "Basic256Sha256_SignAndEncrypt",
            "--client-cert", str(d / "edge-cert.der"), "--client-key", str(d / "edge-key.pem"),
            "--user", "operator", "--tools", str(d / "tools.toml"), "--stock", STOCK,
            "--out", str(d / f"{name}-edge"), "--quiet", "--no-anomaly", "--no-twin",
            "--idle-timeout-s", "8"]


def _wait_nodes(d: Path, name: str, sim: subprocess.Popen[str]) -> None:
    deadline = time.time() + 90
    while not (d / name / "nodes.toml").exists():
        assert sim.poll() is None, sim.communicate()
        assert time.time() < deadline, "the simulator did not start serving"
        time.sleep(0.1)


def _loop(d: Path, name: str, *extra: str, kill_after_s: float | None = None,
          interval_s: float = INTERVAL_S) -> dict[str, Any]:
    url = f"opc.tcp://127.0.0.1:{free_port()}"
    sim = _sim(d, name, url, *extra, interval_s=interval_s)
    edge = None
    try:
        _wait_nodes(d, name, sim)
        edge = subprocess.Popen(_edge_cmd(d, name, url, interval_s), stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, env=_env())
        if kill_after_s is not None:
            # killed once it has been writing for a while (the program is cutting then)
            deadline = time.time() + 60
            status = d / f"{name}-edge" / "status.json"
            while time.time() < deadline:
                time.sleep(0.2)
                try:
                    st = json.loads(status.read_text())
                except (OSError, ValueError):
                    continue
                if st.get("sinks", {}).get("control", {}).get("written", 0) >= \
                        kill_after_s / 0.02:
                    break
            os.kill(edge.pid, signal.SIGKILL)
        out, err = sim.communicate(timeout=120)
        assert sim.returncode == 0, err
        if kill_after_s is None:
            _, e_err = edge.communicate(timeout=60)
            assert edge.returncode == 0, e_err
    finally:
        for p in (sim, edge):
            if p is not None and p.poll() is None:
                p.kill()
                p.wait(10)
    o = d / name
    return {"summary": json.loads((o / "adaptive.json").read_text()),
            "log": pd.read_csv(o / "control.csv"),
            "truth": json.loads((o / "truth.json").read_text()), "stdout": out}


@pytest.fixture(scope="module")
def adaptive(setup: dict[str, Any]) -> dict[str, Any]:
    return _loop(setup["dir"], "adaptive")


def test_the_loop_holds_the_torque_through_hidden_hardness_steps(
        adaptive: dict[str, Any]) -> None:
    from cnctwin.usecases.adaptive_report import cut_share_within

    share = cut_share_within(adaptive["log"], TARGET_NM, tolerance=0.05, settle_s=0.5)
    assert share >= 0.90, share
    s = adaptive["summary"]
    assert s["writes"] > 200 and s["fallbacks"] == 0 and s["stop_request"] is None
    # the override followed the hardness: faster in the soft zones, slower in the hard one
    log = adaptive["log"]
    cut = log["cutting_torque_nm"] > 0.3
    hard = log.loc[cut & ((log["hardness_factor"] - 1.15).abs() < 1e-6), "applied_pct"]
    soft = log.loc[cut & ((log["hardness_factor"] - 0.95).abs() < 1e-6), "applied_pct"]
    assert hard.median() < 95.0 < 105.0 < soft.median()


def test_the_online_model_factor_tracks_the_hidden_hardness(setup: dict[str, Any],
                                                           adaptive: dict[str, Any]) -> None:
    """The edge's engagement model (Z-map of the stock swept by the recorded positions, the
    library's AISI 1045 coefficients) predicts the mean torque A + B c; the measured-to-model
    ratio it adapts online must follow the hardness hidden in the simulator (1.0 / 1.15 / 0.95)
    within 5 % in each zone's second half (the EWMA settled; the soft sensor's own error
    included)."""
    from cnctwin.sim.config import START_CYCLE, START_TIME

    d = setup["dir"]
    rows = [json.loads(x) for x in (d / "adaptive-edge" / "results.jsonl").read_text()
            .splitlines() if x.strip()]
    ov = [r for r in rows if r.get("kind") == "override" and r.get("cutting")
          and "model_factor" in r]
    assert len(ov) > 100
    t0 = pd.Timestamp(START_TIME)
    t0 = t0.tz_localize("UTC") if t0.tzinfo is None else t0
    cyc = np.array([START_CYCLE + round((pd.Timestamp(r["time"]) - t0).total_seconds() / 0.002)
                    for r in ov])
    log = adaptive["log"]
    k = np.searchsorted(log["cycle"].to_numpy(), cyc, side="right") - 1
    hard = log["hardness_factor"].to_numpy()[np.clip(k, 0, len(log) - 1)]
    factor = np.array([r["model_factor"] for r in ov])
    for h in (1.0, 1.15, 0.95):
        zone = np.flatnonzero(np.abs(hard - h) < 1e-6)
        assert zone.size > 10, h
        late = factor[zone[zone.size // 2:]]
        assert np.median(late) == pytest.approx(h, rel=0.05), (h, np.median(late))


def test_the_adaptive_part_is_shorter_and_within_every_limit(setup: dict[str, Any],
                                                             adaptive: dict[str, Any]) -> None:
    from cnctwin.engagement import parse_stock
    from cnctwin.machine import read_tool_table
    from cnctwin.sim.part import part_program

    d = setup["dir"]
    fixed = part_program(None, program=d / "p.mpf", material="aisi1045",
                         tools=read_tool_table(d / "tools.toml"), stock=parse_stock(STOCK),
                         overrides={"part.hardness_along_x": [list(p) for p in
                                                    ADAPTIVE_SLOT.hardness_along_x]})
    t_fixed = fixed.truth["limits"]["cycle_time_s"]
    t_adapt = adaptive["summary"]["cycle_time_s"]
    assert t_adapt < t_fixed - 0.2, (t_adapt, t_fixed)
    assert adaptive["truth"]["limits"]["warnings"] == []
    log = adaptive["log"]
    cut = log["cutting_torque_nm"] > 0.3
    assert log.loc[cut, "applied_pct"].between(50.0 - 1e-6, 120.0 + 1e-6).all()
    assert log["requested_pct"].between(50.0, 120.0).all()
    # loop latency: a served sample to the override computed from it applied
    lat = adaptive["summary"]["latency_ms"]
    assert lat["n"] > 100 and lat["p50"] is not None


def test_an_injected_breakage_stops_the_program_within_100_ms(setup: dict[str, Any]) -> None:
    r = _loop(setup["dir"], "breakage", "--set", "part.break_at_x_mm=60", interval_s=0.01)
    s = r["summary"]
    assert s["breakage_cycle"] is not None, s
    assert s["stop_request"] == "stop"
    assert s["stop_after_breakage_ms"] is not None
    assert 0.0 <= s["stop_after_breakage_ms"] <= 100.0, s["stop_after_breakage_ms"]


def test_the_edge_killed_mid_part_falls_back_to_100_within_the_heartbeat(
        setup: dict[str, Any]) -> None:
    r = _loop(setup["dir"], "killed", kill_after_s=5.0)
    s = r["summary"]
    assert s["fallbacks"] == 1, s
    assert s["fallback_after_last_heartbeat_s"][0] <= 0.5 + INTERVAL_S + 0.05, s
    log = r["log"]
    # after the fallback the control plays 100 % to the end of the part
    last_adapted = int(np.flatnonzero(log["requested_pct"].to_numpy() != 100.0).max())
    assert (log["requested_pct"].iloc[last_adapted + 1:] == 100.0).all()
    assert last_adapted < len(log) - 100  # well before the end: the part went on at 100 %
    assert s["stop_request"] is None


@pytest.mark.parametrize("case", ["unknown_tool", "not_writable", "no_security"])
def test_bad_configuration_is_one_line_and_writes_nothing(
        setup: dict[str, Any], tmp_path: Path, case: str,
        capsys: pytest.CaptureFixture[str]) -> None:
    """Against a live server whose PLC logs every write: one line, exit 2, no write."""
    from cnctwin.cli import main
    from cnctwin.edge.sinumerik_live import (
        LiveSinumerikServer,
        PlcOverride,
        write_live_node_file,
    )
    from cnctwin.recording import RecordingMeta

    d = setup["dir"]
    url = f"opc.tcp://127.0.0.1:{free_port()}"
    plc = PlcOverride()
    nodes = tmp_path / "nodes.toml"
    srv = LiveSinumerikServer(url, plc, interval_s=INTERVAL_S, users={"operator": "loop-secret"},
                              cert_file=tmp_path / "srv.der", key_file=tmp_path / "srv.pem",
                              on_listening=lambda s, t: write_live_node_file(
                                  s, t, nodes, interval_s=INTERVAL_S))
    cols = [f"{c}|{a}" for a in ("X1", "Y1", "Z1", "SP1") for c in ("ENC_POS", "CURRENT")]
    cols.append("CMD_SPEED|SP1")
    srv.open(cols, RecordingMeta(machine="m", cycle_time_s=0.002,
                                 axis_map={"1": "X1", "2": "Y1", "3": "Z1", "4": "SP1"},
                                 time_anchors=[(0, pd.Timestamp("2026-01-01", tz="UTC"))]))
    try:
        cmd = _edge_cmd(d, "x", url)[2:]
        cmd[cmd.index("--nodes") + 1] = str(nodes)
        cmd[cmd.index("--out") + 1] = str(tmp_path / "edge")
        cmd[cmd.index("--idle-timeout-s") + 1] = "1"
        if case == "unknown_tool":
            bad = tmp_path / "adaptive.toml"
            bad.write_text("[tools.5]\ntarget_nm = 2\n")
            cmd[cmd.index("--adaptive") + 1] = str(bad)
            needle = "tools.5 is not in the tool table"
        elif case == "not_writable":
            text = nodes.read_text().replace(
                'override_pct = "ns=2;s=/Plc/DB120.DBB0"',
                'override_pct = "ns=2;s=/Channel/MachineAxis/actToolBasePos[u1,1]"')
            nodes.write_text(text)
            needle = "is not writable for user 'operator'"
        else:
            i = cmd.index("--security")
            cmd[i + 1] = "None"
            needle = "only over a secured session"
        os.environ["CNCTWIN_OPCUA_PASSWORD"] = "loop-secret"
        try:
            capsys.readouterr()
            code = main(["edge", *cmd])
        finally:
            del os.environ["CNCTWIN_OPCUA_PASSWORD"]
        err = capsys.readouterr().err
        assert code == 2, err
        assert needle in err and len(err.strip().splitlines()) == 1, err
        assert plc.writes == []
    finally:
        srv.stop()
