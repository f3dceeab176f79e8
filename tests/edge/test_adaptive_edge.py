"""The wear-adaptive monitor live: simulated drilling runs with hidden faults
(:func:`cnctwin.validation.trials.fault_trial`, the fault hole and its size drawn from a seeded
generator the detector never sees) replayed through the edge runtime, against the batch
``backtest`` of the same detector on the same recording and against the simulator's onset.

The live detector gets its hole context from the hole processor's causal
:class:`~cnctwin.edge.cut.CutTracker` (tip depth below the NC cycle's reference plane / the
cycle's depth), the batch one from the complete hole record (progress linear in time from
``cut_start_cycle`` to ``cut_end_cycle``). The two progress scales differ by the following
error at the ends of the cut, so the first judged sample of a hole may move by a cycle; the
stated tolerance is 2 cycles (4 ms) per alarm (measured: 0 or 1 cycle).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from cnctwin.edge import (
    AnomalyProcessor,
    EdgeRuntime,
    HoleProcessor,
    ReplaySource,
    TorqueProcessor,
)
from cnctwin.edge.cut import CutTracker, drilling_cycle_geometry
from cnctwin.exceptions import ConfigError
from cnctwin.spindle import SpindleModel
from cnctwin.usecases.holes import hole_record
from cnctwin.usecases.monitoring import WearAdaptiveDetector
from cnctwin.validation.trials import fault_trial

from ._memsink import MemorySink

CYCLE_S = 0.002
TOL_S = 2 * CYCLE_S + 1e-9
# the twin of signal_stream (the batch stream's torque_nm), so both see the same torque
THESIS = SpindleModel.from_parameters("thesis_spinner_840dsl")


def _live(rec: Any, monitor: str, teach_holes: int, chunk_cycles: int = 50,
          ) -> tuple[list[float], list[int], MemorySink, AnomalyProcessor]:
    det = (WearAdaptiveDetector(expected="expected_torque_nm") if monitor == "physics"
           else WearAdaptiveDetector())
    an = AnomalyProcessor(det, model=THESIS, learn_s=0.0,
                          learn_holes=None if monitor == "physics" else teach_holes)
    mem = MemorySink()
    EdgeRuntime(ReplaySource(rec, chunk_cycles=chunk_cycles),
                [TorqueProcessor(THESIS), HoleProcessor(THESIS), an], [mem]).run()
    c0 = int(rec.cycles[0])
    # the detector under test (the hole processor's HoleLoadJudge alarms too: its own tests)
    alarms = [a for a in mem.kind("alarm") if a["detector"] == "WearAdaptiveDetector"]
    return ([(a["cycle"] - c0) * CYCLE_S for a in alarms], [a["hole"] for a in alarms],
            mem, an)


@pytest.mark.parametrize(
    ("kind", "seed", "monitor", "n_holes", "teach_holes", "max_delay_s"),
    [
        # breakage: the torque drops ~90 %; batch delay 6-8 ms (docs/validation-usecases.md)
        ("breakage", 0, "physics", 8, 4, 0.05),
        # hardness change +10-25 %: ~0.33 s (the EWMA over 50 samples and the warm-up)
        ("hardness", 1, "adaptive", 10, 6, 0.5),
        ("hardness", 3, "physics", 10, 4, 0.5),
        ("none", 2, "adaptive", 10, 6, None),
        ("none", 2, "physics", 10, 6, None),
    ],
)
def test_live_adaptive_alarms_equal_batch_backtest(kind: str, seed: int, monitor: str,
                                                   n_holes: int, teach_holes: int,
                                                   max_delay_s: float | None) -> None:
    trial = fault_trial(kind, seed, n_holes=n_holes, teach_holes=teach_holes, monitor=monitor)
    batch = trial.result.alarms_s
    rec = trial.scenario.recordings[0]
    live_s, live_holes, mem, an = _live(rec, monitor, teach_holes)
    assert len(mem.kind("hole")) == n_holes
    # same alarms as the batch backtest, each within 2 cycles
    assert len(live_s) == len(batch), (live_s, batch)
    np.testing.assert_allclose(live_s, batch, atol=TOL_S)
    # the live hole number of each alarm is the batch stream's hole at that time
    d = trial.data
    batch_holes = [int(d["hole"].iloc[int(np.searchsorted(d["time_s"], t))]) for t in batch]
    assert live_holes == batch_holes
    if kind == "none":
        assert live_s == []  # a fault-free run: no alarm live either
        assert an.scored > 0
        return
    # against the hidden truth: the first alarm is in the drawn hole, after the onset
    assert trial.onset_s is not None and max_delay_s is not None
    assert live_holes[0] == trial.hidden["hole"]
    assert trial.onset_s <= live_s[0] <= trial.onset_s + max_delay_s
    if monitor == "adaptive":  # the teach-in holes were learned, not scored
        assert an.learned > 0


def test_live_alarms_do_not_depend_on_the_chunking() -> None:
    # 7-cycle chunks: the held-back torque cycle falls elsewhere, the alarms stay the same
    trial = fault_trial("breakage", 0, n_holes=8, teach_holes=4, monitor="physics")
    rec = trial.scenario.recordings[0]
    a50, h50, _, _ = _live(rec, "physics", 4)
    a7, h7, _, _ = _live(rec, "physics", 4, chunk_cycles=7)
    assert a7 == a50 and h7 == h50 and len(a7) == 3


def test_live_context_against_the_hole_record(wear_recording: Any) -> None:
    # the simulated 3-hole run (CYCLE81(10, 0, 2, -20): surface 0, depth 20 mm)
    mem = MemorySink()
    ctx: dict[str, list[np.ndarray]] = {"cycle": [], "hole": [], "progress": []}

    class Grab:
        name = "grab"

        def process(self, chunk: Any) -> list[Any]:
            ctx["cycle"].append(chunk.cycles.copy())
            ctx["hole"].append(chunk.derived["HOLE|Z1"])
            ctx["progress"].append(chunk.derived["CUT_PROGRESS|Z1"])
            return []

        def gap(self, gap: Any) -> list[Any]:
            return []

        def finish(self) -> list[Any]:
            return []

    EdgeRuntime(ReplaySource(wear_recording, chunk_cycles=37),
                [HoleProcessor(THESIS), Grab()], [mem]).run()
    cyc = np.concatenate(ctx["cycle"])
    hole = np.concatenate(ctx["hole"])
    prog = np.concatenate(ctx["progress"])
    rows = hole_record(wear_recording, model=THESIS, store=False)
    assert sorted(set(hole.tolist()) - {-1.0}) == rows["hole"].tolist() == [0, 1, 2]
    for _, r in rows.iterrows():
        inside = cyc[hole == r["hole"]]
        # same first cycle in the material; the end one cycle later at most
        assert inside[0] == r["cut_start_cycle"]
        assert 0 <= r["cut_end_cycle"] - inside[-1] <= 1
        assert inside.size == inside[-1] - inside[0] + 1  # no hole in the run
        # progress by depth against the batch's linear-in-time progress: within 1 %
        sel = (cyc >= r["cut_start_cycle"]) & (cyc <= inside[-1])
        lin = (cyc[sel] - r["cut_start_cycle"]) / (r["cut_end_cycle"] - r["cut_start_cycle"])
        np.testing.assert_allclose(prog[sel], lin, atol=0.01)


def test_cycle_geometry_and_fallback_to_the_last_hole() -> None:
    # SINUMERIK CYCLE81(RTP, RFP, SDIS, DP, DPR): DP absolute, else DPR relative
    assert drilling_cycle_geometry("MCALL CYCLE81(10, 0, 2, -20)") == (0.0, 20.0)
    assert drilling_cycle_geometry("CYCLE83(10, 5, 2, , 12)") == (5.0, 12.0)
    assert drilling_cycle_geometry("G1 X10") is None
    # no NC events: the first plunge is not judged (no surface known), the second uses the
    # surface and depth of the completed first hole's row
    t = CutTracker()
    z = np.concatenate([np.linspace(2.0, -10.0, 601), np.full(50, -10.0)])
    one = t.update(np.arange(z.size), z, z, np.full(z.size, 2400.0))
    assert (one.hole == -1).all()
    t.hole_done({"hole": 0, "surface_z_mm": 0.0, "depth_mm": 10.0})
    two = t.update(np.arange(z.size) + z.size, z, z, np.full(z.size, 2400.0))
    inside = two.hole == 1
    assert inside.sum() == 501  # z <= 0 while moving down: 0, -0.02, .., -10 mm
    np.testing.assert_allclose(two.progress[inside][[0, -1]], [0.0, 1.0], atol=1e-9)
    # setpoint 0.02 mm per 2 ms cycle = 600 mm/min
    np.testing.assert_allclose(two.feed_mm_min[inside], 600.0, rtol=1e-9)


def test_adaptive_needs_the_hole_processor(wear_recording: Any) -> None:
    an = AnomalyProcessor(WearAdaptiveDetector(), model=THESIS, learn_holes=1)
    rt = EdgeRuntime(ReplaySource(wear_recording, chunk_cycles=50),
                     [TorqueProcessor(THESIS), an], [MemorySink()])
    with pytest.raises(ConfigError, match="hole processor"):
        rt.run()
    with pytest.raises(ConfigError, match="material"):
        AnomalyProcessor(WearAdaptiveDetector(), material="unobtainium")


def test_cli_physics_torque_on_a_fault_free_run(tmp_path: Any, wear_run: dict[str, Any],
                                               spindle_model: SpindleModel) -> None:
    import json

    from cnctwin.cli import main
    from cnctwin.edge import save_spindle_model

    mfile = save_spindle_model(spindle_model, tmp_path / "spindle.json")
    for det in ("physics-torque", "adaptive"):
        out = tmp_path / det
        code = main(["edge", "run", "--source", str(wear_run["path"]), "--model", str(mfile),
                     "--out", str(out), "--quiet", "--detector", det, "--learn-holes", "2"])
        assert code == 0
        msgs = [json.loads(x) for x in (out / "results.jsonl").read_text().splitlines()]
        assert sum(m["kind"] == "hole" for m in msgs) == 3
        assert not [m for m in msgs if m["kind"] == "alarm"], det  # fault-free: no alarm
    assert main(["edge", "run", "--source", str(wear_run["path"]), "--model", str(mfile),
                 "--out", str(tmp_path / "x"), "--quiet", "--detector", "adaptive",
                 "--no-holes"]) == 2


@pytest.mark.parametrize("chunk_cycles", [7, 50, 500])
def test_cut_tracker_context_does_not_depend_on_the_chunking(wear_recording: Any,
                                                             chunk_cycles: int) -> None:
    """CutTracker works on runs of cut cycles in array code; fed one cycle per update it is
    the plain per-cycle rule. Both give exactly the same context on the simulated drilling
    run with its NC events (events inside a chunk split it where the geometry changes)."""
    rec = wear_recording
    cyc = rec.cycles
    zd = rec.hf["DES_POS|Z1"].to_numpy()
    ze = rec.hf["ENC_POS|Z1"].to_numpy()
    sp = rec.hf["CMD_SPEED|SP1"].to_numpy()
    xy = (rec.hf["DES_POS|X1"].to_numpy(), rec.hf["DES_POS|Y1"].to_numpy())
    ev = rec.events
    ec = ev["cycle"].to_numpy()
    n = min(cyc.size, 12_000)  # three holes

    def run(size: int) -> tuple[list[Any], int]:
        t = CutTracker()
        out = []
        for k in range(0, n, size):
            sl = slice(k, min(k + size, n))
            e = ev[(ec >= cyc[sl][0]) & (ec <= cyc[sl][-1])]
            out.append(t.update(cyc[sl], zd[sl], ze[sl], sp[sl],
                                xy_des_mm=(xy[0][sl], xy[1][sl]), events=e))
        return out, t.next_hole

    fast, n_fast = run(chunk_cycles)
    slow, n_slow = run(1)
    assert n_fast == n_slow >= 2
    for name in ("hole", "progress", "depth_mm", "feed_mm_min", "speed_rpm"):
        a = np.concatenate([getattr(c, name) for c in fast])
        b = np.concatenate([getattr(c, name) for c in slow])
        np.testing.assert_array_equal(a, b, err_msg=name)
    assert (np.concatenate([c.hole for c in fast]) >= 0).sum() > 1000  # cutting was covered


@pytest.mark.parametrize("cancel", ["MCALL", "N120 MCALL", "n120 mcall ; end of the pattern",
                                    "/1 N120 MCALL", "G80"])
def test_a_cancelled_cycle_call_ends_the_live_hole_context(cancel: str) -> None:
    """After the modal drilling cycle is cancelled, a plunge into the material (a milling
    plunge) is no hole, however the control writes the cancelling block: real
    Capture4Analysis block texts carry block numbers (``N50 ...``, tests/data/real), which the
    live tracker did not recognise before (it kept the drilling cycle's geometry)."""
    import pandas as pd

    z = np.concatenate([np.linspace(2.0, -10.0, 601), np.full(50, -10.0),
                        np.linspace(-10.0, 2.0, 100)])
    n = z.size
    t = CutTracker()
    ev = pd.DataFrame({"cycle": [0], "kind": ["block"],
                       "gcode": ["N100 MCALL CYCLE81(10, 0, 2, -20)"]})
    one = t.update(np.arange(n), z, z, np.full(n, 2400.0), xy_des_mm=(np.zeros(n),),
                   events=ev)
    assert (one.hole == 0).sum() == 501  # a hole while the cycle is called
    ev = pd.DataFrame({"cycle": [n], "kind": ["block"], "gcode": [cancel]})
    two = t.update(np.arange(n) + n, z, z, np.full(n, 2400.0),
                   xy_des_mm=(np.full(n, 50.0),), events=ev)
    assert (two.hole == -1).all(), cancel
