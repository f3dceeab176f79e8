"""Adaptive feed in closed loop with the simulated control, in one process (issue 26, points 1
and 3; the OPC UA loop between two processes is the next step).

The simulator plays the program at the override the controller requests
(:class:`cnctwin.sim.override.OverridePlayer`, ramped, 50-120 %); the controller reads each
50 ms chunk's spindle current through the calibrated soft sensor and sets the next chunk's
override. The part: a 16 mm slot, 2 mm deep in AISI 1045 at a conservative F450 (3000 rpm,
0.075 mm/tooth: 2.38 Nm by the closed form, Altintas eq. 2.47), with hidden hardness steps
along X (x 1.0, 1.15, 0.95) the controller is not told. Target 2.6 Nm. By the model the
override needed is 115 %, 92 % and 124 % (capped at 120 %: 2.54 Nm, -2.3 %); so the torque can
be held within 5 % everywhere. Judged: within +-5 % of the target over >= 90 % of the
cutting time after settling (0.5 s after the entry and after each hardness step), the cycle
time shorter than at 100 %, the applied override always inside its bounds.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd
import pytest

from cnctwin.engagement import Stock, ZMap
from cnctwin.machine.tools import EndMill
from cnctwin.sim.config import ScenarioConfig
from cnctwin.sim.gcode import parse_program
from cnctwin.sim.machine import Machine
from cnctwin.sim.override import OverridePlayer, plan_of
from cnctwin.sim.recorder import MemorySink
from cnctwin.sim.simulation import simulate
from cnctwin.sim.stockcut import StockMillingProcess, ToolDispatch
from cnctwin.spindle import SpindleModel
from cnctwin.usecases.adaptive import AdaptiveFeedController

PROGRAM = """G90 G17 G94 G64
T2 M6
S3000 M3
G0 X-12 Y20 Z5
G0 Z-2
G1 X160 F450
G0 Z20
G0 X0 Y0
M30
"""
STEPS = ((-100.0, 1.0), (60.0, 1.15), (110.0, 0.95))
TARGET_NM = 2.6


class _Observer:
    """A sink that forwards to memory and shows each chunk to the controller, with the
    edge's own engagement model (the program's set points through a Z-map of the stock: does
    the model expect a cut at the chunk's end?)."""

    def __init__(self, ctrl: AdaptiveFeedController, player: OverridePlayer) -> None:
        self.inner = MemorySink()
        self.ctrl = ctrl
        self.player = player
        self.model_zmap = ZMap(Stock(0.0, 0.0, -30.0, 150.0, 40.0, 0.0))
        self.applied: list[np.ndarray] = []
        self.stop_cycle: int | None = None

    def open(self, columns: list[str], meta: Any) -> None:
        self.inner.open(columns, meta)

    def write(self, chunk: Any) -> None:
        self.inner.write(chunk)
        eng = self.model_zmap.sweep(chunk.hf["DES_POS|X1"], chunk.hf["DES_POS|Y1"],
                                    chunk.hf["DES_POS|Z1"], diameter_mm=16.0)
        k = eng.engaged.size
        expect = bool(eng.engaged[int(0.8 * k):].all()) if k else False
        st = self.ctrl.update(chunk.hf["CURRENT|SP1"], chunk.hf["CMD_SPEED|SP1"],
                              expect_cut=expect)
        if st.breakage and self.stop_cycle is None:
            self.stop_cycle = int(chunk.cycles[-1])

    def close(self, meta: Any) -> Any:
        return self.inner.close(meta)


def _run(adaptive: bool, break_x: float | None = None, *, speed_rpm: float = 3000.0
         ) -> dict[str, Any]:
    # the same feed per tooth (0.075 mm) at another speed: the same torque, another power
    feed = 450.0 * speed_rpm / 3000.0
    prog = parse_program(PROGRAM.replace("S3000", f"S{speed_rpm:g}").replace(
        "F450", f"F{feed:g}"))
    machine = Machine.thesis_default()
    cfg = ScenarioConfig.build(None, machine=machine)
    plan = plan_of(prog, machine)
    player = OverridePlayer(plan, prog, min_pct=50.0, max_pct=120.0, rate_pct_per_s=200.0)
    s = machine.spindle
    model = SpindleModel(s.kt_nm_per_a, s.viscous_friction_nm_per_rpm, s.coulomb_friction_nm,
                         j_kgm2=s.inertia_kg_m2)
    ctrl = AdaptiveFeedController(model, target_nm=TARGET_NM, min_pct=50.0, max_pct=120.0,
                                  gain=0.3)
    rng = np.random.default_rng([3, 1])
    mill = StockMillingProcess(cfg, material=cfg.materials["aisi1045"],
                               zmap=ZMap(Stock(0.0, 0.0, -30.0, 150.0, 40.0, 0.0)),
                               tool=EndMill(), hardness_along_x=STEPS, break_at_x_mm=break_x,
                               surface_z_mm=0.0,
                               faults=(), rng=rng, truth=None, daq=None)
    sink = _Observer(ctrl, player)
    ovr: list[np.ndarray] = []

    def chunks() -> Any:
        for c in player.chunks(lambda: ctrl.state.override_pct if adaptive else 100.0,
                               chunk_cycles=25):
            ovr.append(c.override_pct)
            yield c

    dispatch = ToolDispatch({2: mill})
    frames: list[pd.DataFrame] = []

    def hook(ci: Any) -> Any:  # keep the hidden truth of each chunk
        out = dispatch(ci)
        if out.truth:
            frames.append(pd.DataFrame({k: out.truth[k] for k in ("cutting_torque_nm",
                                                                   "hardness_factor")}))
        return out

    simulate(chunks(), machine, seed=3, cutting=hook, sink=sink)
    truth = pd.concat(frames, ignore_index=True) if frames else None
    return {"n": int(sum(o.size for o in ovr)), "override": np.concatenate(ovr),
            "truth": truth, "ctrl": ctrl, "broken_cycle": mill.broken_cycle,
            "stop_cycle": sink.stop_cycle}


@pytest.fixture(scope="module")
def runs() -> dict[str, dict[str, Any]]:
    return {"fixed": _run(False), "adaptive": _run(True)}


def _share_within(a: dict[str, Any]) -> tuple[float, int]:
    t = a["truth"]
    assert t is not None
    torque = t["cutting_torque_nm"].to_numpy(dtype=np.float64)
    hard = t["hardness_factor"].to_numpy(dtype=np.float64)
    cutting = np.nan_to_num(torque) > 0.5
    # settled: 0.5 s (250 cycles) after the entry and after each hardness step
    change = np.flatnonzero((np.diff(hard) != 0) | (np.diff(cutting.astype(int)) != 0)) + 1
    settled = cutting.copy()
    for k in change:
        settled[k:k + 250] = False
    # the cutting torque per 0.1 s (the tooth-passing and the drive's 2 ms sampling removed)
    w = 50
    nwin = torque.size // w
    win = np.array([settled[i * w:(i + 1) * w].all() for i in range(nwin)])
    mean = np.array([torque[i * w:(i + 1) * w].mean() for i in range(nwin)])
    judged = mean[win]
    inside = np.abs(judged / TARGET_NM - 1.0) <= 0.05
    return float(inside.mean()) if judged.size else float("nan"), int(judged.size)


def test_the_loop_holds_the_torque_through_hidden_hardness_steps(runs: dict[str, Any]) -> None:
    share, n = _share_within(runs["adaptive"])
    assert n >= 20
    assert share >= 0.90, share


@pytest.mark.parametrize("speed_rpm", [1500.0, 4500.0])
def test_the_loop_is_stable_across_the_speed_range(speed_rpm: float) -> None:
    """The same chip at half and 1.5 times the speed (F225 at 1500 rpm, F675 at 4500 rpm): the
    controller's gain comes from the torque model, not from the speed, so the loop holds the
    target as at 3000 rpm (at 6000 rpm 76 % of the windows: docs/adaptive.md)."""
    share, n = _share_within(_run(True, speed_rpm=speed_rpm))
    assert n >= 10
    assert share >= 0.90, (speed_rpm, share)


def test_the_adaptive_part_is_shorter_and_stays_in_bounds(runs: dict[str, Any]) -> None:
    fixed, adaptive = runs["fixed"], runs["adaptive"]
    assert adaptive["n"] < fixed["n"]
    o = adaptive["override"]
    assert o.min() >= 50.0 - 1e-9 and o.max() <= 120.0 + 1e-9
    # the fixed run's torque: below the target where the hardness is 1 (2.38 Nm, closed form)
    t = fixed["truth"]
    torque = t["cutting_torque_nm"].to_numpy(dtype=np.float64)
    hard = t["hardness_factor"].to_numpy(dtype=np.float64)
    sel = (np.nan_to_num(torque) > 0.5) & (hard == 1.0)
    assert np.mean(torque[sel]) == pytest.approx(2.38, rel=0.05)


def _current_for(model: SpindleModel, torque_nm: float, n_rpm: float, k: int = 50) -> np.ndarray:
    """The spindle current that gives this cutting torque at a steady speed (Eq. 4.4 by hand)."""
    return np.full(k, (torque_nm + model.b_nm_per_rpm * n_rpm + model.tau_f_nm)
                   / model.kt_nm_per_a)


def test_controller_on_a_plant_by_hand_air_overload_and_breakage() -> None:
    """A plant T(o) = 1.0 + 2.0 o/100 Nm (edge 1 Nm, chip 2 Nm at 100 %) and target 2.6 Nm:
    the model's override is (2.6 - 1.0)/2.0 = 80 %; with edge_share 1/2.6 the controller's
    model is the plant's, so gain 1 reaches it in one step and gain 0.5 halves the error each
    step. Air gives the maximum; 0.3 s above 1.5 x target a feed hold; a collapse to air after
    0.5 s of cut while feeding a stop. (The speed is constant from the first sample: no
    settling time, ``settle_s=0``.)"""
    model = SpindleModel(1.04, 8.42e-5, 0.35)
    n = np.full(50, 3000.0)
    ctrl = AdaptiveFeedController(model, target_nm=2.6, gain=1.0, edge_share=1.0 / 2.6,
                                  settle_s=0.0)
    st = ctrl.update(_current_for(model, 1.0 + 2.0, 3000.0), n)
    assert st.cutting and st.override_pct == pytest.approx(80.0, abs=1e-6)
    half = AdaptiveFeedController(model, target_nm=2.6, gain=0.5, edge_share=1.0 / 2.6,
                                  settle_s=0.0)
    o = 100.0
    for _ in range(8):
        o = half.update(_current_for(model, 1.0 + 2.0 * o / 100.0, 3000.0), n).override_pct
    assert o == pytest.approx(80.0, abs=0.5)
    # air: the maximum
    assert half.update(_current_for(model, 0.05, 3000.0), n,
                       expect_cut=False).override_pct == 120.0
    assert not half.state.breakage  # the model expected the cut to end: no breakage
    # overload: 0.3 s at 5 Nm (> 3.9 Nm) -> feed hold, the minimum
    ov = AdaptiveFeedController(model, target_nm=2.6, settle_s=0.0)
    for _ in range(3):
        st = ov.update(_current_for(model, 5.0, 3000.0), n)
    assert st.overload and st.override_pct == 50.0
    # breakage: 0.6 s of cut at the target, then air while the program feeds -> stop
    br = AdaptiveFeedController(model, target_nm=2.6, settle_s=0.0)
    for _ in range(6):
        br.update(_current_for(model, 2.6, 3000.0), n)
    assert not br.state.breakage
    assert br.update(_current_for(model, 0.05, 3000.0), n, expect_cut=True).breakage


def test_a_spindle_run_up_in_one_value_chunks_is_no_cut() -> None:
    """The live loop over OPC UA gets one 20 ms value per chunk, so no chunk holds the two
    samples the inertia term J dOmega/dt needs: a run-up's current (the thesis machine's
    spindle to 3000 rpm in 0.19 s: ~25 Nm of rotor torque) read as cutting torque was an
    overload and a feed hold 0.2 s into a healthy part (the loaded CI's closed loop, session
    26). Samples while the speed command changes and 0.3 s after (and at the stream's start,
    its past unknown) carry no cut: no overload, no cut, the override at its maximum in air,
    and the cut after the run-up is measured (within 2 % of its 2.6 Nm)."""
    sp = Machine.thesis_default().spindle
    model = SpindleModel(sp.kt_nm_per_a, sp.viscous_friction_nm_per_rpm,
                         sp.coulomb_friction_nm, j_kgm2=sp.inertia_kg_m2)
    fs = 50.0
    n = np.r_[np.linspace(207.0, 3000.0, 10), np.full(40, 3000.0)]
    domega = np.gradient(n, 1.0 / fs) * 2.0 * np.pi / 60.0
    cut = np.r_[np.zeros(30), np.full(20, 2.6)]  # air, then a cut at the target
    i = (cut + model.j_kgm2 * domega + model.b_nm_per_rpm * n + model.tau_f_nm) \
        / model.kt_nm_per_a
    ctrl = AdaptiveFeedController(model, target_nm=2.6, fs_hz=fs, update_s=0.1)
    states = []
    for k in range(n.size):
        st = ctrl.update(i[k:k + 1], n[k:k + 1])
        states.append((st.cutting, st.override_pct, st.overload))
    assert not any(o for _, _, o in states)
    assert not any(c for c, _, _ in states[:30])
    assert states[29][1] == 120.0  # air after the run-up: the maximum
    assert any(c for c, _, _ in states[30:])
    assert ctrl.state.torque_nm == pytest.approx(2.6, rel=0.02)


def test_edge_run_adaptive_emits_override_messages(tmp_path: Any,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    """``edge run --adaptive``: on a replayed program that mills with T2 and drills with T1,
    the results stream carries ``override`` messages for T2 only (the adapted tool), with the
    interface's keys, inside the bounds; air raises the override to the maximum. Bad
    configurations: one line, exit 2."""
    import json

    from cnctwin.cli import main
    from cnctwin.edge.model_file import save_spindle_model

    (tmp_path / "tools.toml").write_text(
        '[tools.1]\nkind = "drill"\ndiameter_mm = 8.5\n\n[tools.2]\nkind = "end_mill"\n'
        'diameter_mm = 16\nflutes = 2\nhelix_deg = 30\nmax_chip_mm = 0.2\n')
    (tmp_path / "p.mpf").write_text(
        "G90 G94 G64\nT2 M6\nS3000 M3\nG0 X-12 Y20 Z5\nG0 Z-2\nG1 X70 F450\nG0 Z10\n"
        "T1 M6\nS2400 M3\nG95 F0.16\nMCALL CYCLE81(10, 0, 2, -12)\nX20 Y60\nMCALL\nG0 Z50\nM30\n")
    assert main(["simulate", "--program", str(tmp_path / "p.mpf"), "--material", "aisi1045",
                 "--tools", str(tmp_path / "tools.toml"), "--stock", "0,0,-30,80,80,0",
                 "--out", str(tmp_path / "sim")]) == 0
    s = Machine.thesis_default().spindle
    model = save_spindle_model(
        SpindleModel(s.kt_nm_per_a, s.viscous_friction_nm_per_rpm, s.coulomb_friction_nm,
                     j_kgm2=s.inertia_kg_m2), tmp_path / "spindle.json")
    cfg = tmp_path / "adaptive.toml"
    cfg.write_text("min_pct = 50\nmax_pct = 120\n[tools.2]\ntarget_nm = 2.6\n")
    capsys.readouterr()
    assert main(["edge", "run", "--source", str(tmp_path / "sim" / "p.json"), "--model",
                 str(model), "--adaptive", str(cfg), "--out", str(tmp_path / "edge"),
                 "--quiet", "--no-anomaly", "--no-twin"]) == 0
    rows = [json.loads(x) for f in sorted((tmp_path / "edge").glob("*.jsonl"))
            for x in f.read_text().splitlines() if x.strip()]
    ov = [r for r in rows if r.get("kind") == "override"]
    assert ov and {r["tool"] for r in ov} == {2}
    assert {"cycle", "tool", "override_pct", "target", "measured"} <= set(ov[0])
    assert all(50.0 <= r["override_pct"] <= 120.0 for r in ov)
    assert all(r["target"] == 2.6 for r in ov)
    assert [r["heartbeat"] for r in ov] == list(range(1, len(ov) + 1))  # one per message
    assert all((r["min_pct"], r["max_pct"]) == (50.0, 120.0) for r in ov)
    cut = [r for r in ov if r.get("cutting")]
    assert cut and any(r["override_pct"] > 100.0 for r in cut)  # 2.38 Nm < 2.6: faster
    # a power target: 816.8 W at 3000 rpm is 2.6 Nm (P / omega), held as torque
    cfg.write_text("[tools.2]\ntarget_w = 816.8\n")
    assert main(["edge", "run", "--source", str(tmp_path / "sim" / "p.json"), "--model",
                 str(model), "--adaptive", str(cfg), "--out", str(tmp_path / "edge_w"),
                 "--quiet", "--no-anomaly", "--no-twin"]) == 0
    rows_w = [json.loads(x) for f in sorted((tmp_path / "edge_w").glob("*.jsonl"))
              for x in f.read_text().splitlines() if x.strip()]
    ov_w = [r for r in rows_w if r.get("kind") == "override" and r.get("cutting")]
    assert ov_w and all(r["target_w"] == 816.8 for r in ov_w)
    assert np.median([r["target"] for r in ov_w]) == pytest.approx(2.6, rel=0.01)
    # bad configurations
    for text, needle in (("min_pct = 130\nmax_pct = 120\n[tools.2]\ntarget_nm = 2\n",
                          "override bounds min_pct 130 .. max_pct 120"),
                         ("[tools.2]\n", "tools.2: give target_nm, target_w, target_from"),
                         ("[tools.2]\ntarget = 2\n", "tools.2.target is not a key")):
        cfg.write_text(text)
        capsys.readouterr()
        assert main(["edge", "run", "--source", str(tmp_path / "sim" / "p.json"), "--model",
                     str(model), "--adaptive", str(cfg), "--out", str(tmp_path / "e2"),
                     "--quiet"]) == 2
        err = capsys.readouterr().err
        assert needle in err and len(err.strip().splitlines()) == 1, err


def test_an_injected_breakage_gives_the_stop_request_within_100_ms() -> None:
    """The cutter breaks when the tool passes X 80 (hidden, mid-slot): the controller's stop
    request (``state.breakage``) comes with the chunk in which the torque collapsed, within
    50 cycles (100 ms) of the break; no breakage is reported before it (the healthy runs
    above report none)."""
    r = _run(True, break_x=80.0)
    assert r["broken_cycle"] is not None and r["stop_cycle"] is not None
    delay = r["stop_cycle"] - r["broken_cycle"]
    assert 0 <= delay <= 50, delay
    assert r["ctrl"].state.override_pct == 50.0  # feed held at the minimum


def test_healthy_runs_report_no_breakage(runs: dict[str, Any]) -> None:
    assert not runs["adaptive"]["ctrl"].state.breakage
    assert not runs["adaptive"]["ctrl"].state.overload


def test_an_override_above_100_stays_within_the_axes_acceleration_limits() -> None:
    """A square at F6000 whose corners the NC plans near the axes' 3000 mm/s^2 (thesis
    machine, MD32300): played at 150 % by time scaling alone the corners would need
    (1.5)^2 x the plan's acceleration (measured 4600-4800 mm/s^2); the player caps the
    override there (a o^2 <= a_max, anticipated at its ramp rate), so the executed set points
    stay within the limit (finite differences of the played positions), and still run faster
    than at 100 % on the straights."""
    prog = parse_program("G90 G94 G64\nG0 X0 Y0 Z0\nG1 X50 F6000\nG1 Y50\nG1 X0\nG1 Y0\nM30\n")
    machine = Machine.thesis_default()
    plan = plan_of(prog, machine)
    limits = {ax.name: (ax.max_velocity_mm_min, ax.max_accel_mm_s2, ax.max_jerk_mm_s3)
              for ax in machine.axes}
    dt = machine.cycle_time_s

    def played(axis_limits: Any) -> tuple[float, int]:
        pl = OverridePlayer(plan, prog, max_pct=150.0, axis_limits=axis_limits)
        chunks = list(pl.chunks(lambda: 150.0, chunk_cycles=50))
        acc = 0.0
        for ax in ("X1", "Y1"):
            x = np.concatenate([c.des_pos[ax] for c in chunks])
            acc = max(acc, float(np.abs(np.gradient(np.gradient(x, dt), dt)).max()))
        return acc, sum(c.block_index.size for c in chunks)

    blind, n_blind = played(None)
    capped, n_capped = played(limits)
    assert blind > 1.2 * limits["X1"][1]  # the uncapped player would exceed it
    assert capped <= limits["X1"][1] * 1.01, capped
    n_plan = int(np.asarray(plan.spindle_speed_cmd_rpm).size)
    assert n_blind < n_capped < n_plan  # faster than 100 %, slower than blind 150 %
