"""Replay of a simulated drilling recording through the edge runtime, against the batch
analysis of the same recording and the simulator's truth.

Truth: ``tool_wear_run`` (thesis §5.1: AISI 1045, 8.5 mm drill, 20 mm deep CYCLE81 holes)
with 3 holes; its ``truth.json`` lists each hole's first cycle in the material.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

import cnctwin.store
from cnctwin.edge import (
    AnomalyProcessor,
    EdgeRuntime,
    HoleProcessor,
    JsonLinesSink,
    ReplaySource,
    StoreSink,
    TorqueProcessor,
    load_spindle_model,
    read_status,
    save_spindle_model,
)
from cnctwin.exceptions import ConfigError
from cnctwin.recording import Recording
from cnctwin.spindle import SpindleModel, speed_change_flags
from cnctwin.usecases.holes import hole_records

from ._memsink import MemorySink


def _torque(messages: list[dict[str, Any]]) -> tuple[np.ndarray, np.ndarray]:
    cyc = np.concatenate([np.arange(m["first_cycle"], m["first_cycle"] + m["n"])
                          for m in messages])
    tau = np.concatenate([np.asarray(m["torque_nm"], dtype=np.float64) for m in messages])
    return cyc, tau


def _run(rec: Recording, model: SpindleModel, chunk: int, **kw: Any) -> MemorySink:
    mem = MemorySink()
    EdgeRuntime(ReplaySource(rec, chunk_cycles=chunk),
                [TorqueProcessor(model), HoleProcessor(model)], [mem, *kw.get("sinks", [])],
                state_dir=kw.get("state_dir")).run()
    return mem


@pytest.mark.parametrize("chunk", [1, 37, 500])
def test_streamed_torque_equals_batch(wear_recording: Recording, spindle_model: SpindleModel,
                                      chunk: int) -> None:
    rec = wear_recording
    if chunk == 1:  # one cycle per chunk is slow through the hole buffer: torque only
        mem = MemorySink()
        EdgeRuntime(ReplaySource(rec, chunk_cycles=1), [TorqueProcessor(spindle_model)],
                    [mem]).run()
    else:
        mem = _run(rec, spindle_model, chunk)
    cyc, tau = _torque(mem.kind("torque"))
    assert np.array_equal(cyc, rec.cycles)  # every cycle once, in order, none invented
    n = rec.hf["CMD_SPEED|SP1"].to_numpy()
    batch = spindle_model.cutting_torque(rec.hf["CURRENT|SP1"].to_numpy(), n)
    # StreamingTorqueEstimator reproduces the vectorized derivative exactly (spindle.py);
    # the run-up and the braking are flagged, no cutting torque (speed_change_flags)
    flags = speed_change_flags(n, fs_hz=rec.fs_hz)
    assert (flags == 1).sum() > 150  # run-up and braking, each with 0.3 s of settling
    np.testing.assert_array_equal(tau, np.where(flags == 0, batch, np.nan))


def test_hole_rows_equal_batch_and_truth(wear_run: dict[str, Any], wear_recording: Recording,
                                         spindle_model: SpindleModel) -> None:
    rec = wear_recording
    mem = _run(rec, spindle_model, 50)
    rows = pd.DataFrame([m["row"] for m in mem.kind("hole")])
    batch = hole_records([rec], model=spindle_model)
    assert len(rows) == len(batch) == len(wear_run["truth"]["holes"]) == 3
    for col in batch.columns:
        b = batch[col]
        s = rows[col]
        if col == "start_time":
            assert [pd.Timestamp(x) for x in s] == list(b), col
        elif pd.api.types.is_float_dtype(b):
            # same computation on the same samples: equal to rounding
            np.testing.assert_allclose(s.to_numpy(dtype=float), b.to_numpy(), rtol=1e-12,
                                       atol=1e-12, equal_nan=True, err_msg=col)
        else:
            assert s.tolist() == [None if v is pd.NA else v for v in b.tolist()], col
    # simulator truth: first cycle in the material of each hole, 20 mm depth
    truth = wear_run["truth"]["holes"]
    for k, t in enumerate(truth):
        assert abs(int(rows["cut_start_cycle"].iloc[k]) - t["cut_first_cycle"]) <= 2
        assert math.isclose(float(rows["depth_mm"].iloc[k]), wear_run["truth"]["depth_mm"],
                            abs_tol=0.05)
    # a hole is reported after its plunge started, and live (before the stream ends)
    starts = mem.kind("hole_start")
    holes = mem.kind("hole")
    assert len(starts) == 3
    for st, h in zip(starts, holes, strict=True):
        assert st["cycle"] <= h["row"]["start_cycle"] + 5 and st["seq"] < h["seq"]
    # live: each hole is out before the next plunge begins (the X/Y setpoint moved on)
    assert holes[0]["seq"] < starts[1]["seq"] and holes[1]["seq"] < starts[2]["seq"]
    status = [m for m in mem.messages if m["kind"] == "status"][-1]
    assert status["holes"] == 3 and status["cycles"] == rec.n_cycles


def test_jsonl_and_store_sinks(tmp_path: Path, wear_recording: Recording,
                               spindle_model: SpindleModel) -> None:
    rec = wear_recording
    jl = JsonLinesSink(tmp_path / "out" / "results.jsonl")
    st = StoreSink(tmp_path / "store", machine="mill-1", block_cycles=2500)
    _run(rec, spindle_model, 50, sinks=[jl, st], state_dir=tmp_path / "out")
    lines = [json.loads(x) for x in (tmp_path / "out" / "results.jsonl").read_text().splitlines()]
    assert [m["seq"] for m in lines] == list(range(len(lines)))
    assert {m["kind"] for m in lines} >= {"torque", "hole_start", "hole", "status"}
    assert read_status(tmp_path / "out")["state"] == "finished"
    n = rec.hf["CMD_SPEED|SP1"].to_numpy()
    batch = np.where(speed_change_flags(n, fs_hz=rec.fs_hz) == 0,
                     spindle_model.cutting_torque(rec.hf["CURRENT|SP1"].to_numpy(), n), np.nan)
    with cnctwin.store.open(tmp_path / "store") as store:
        cat = store.recordings(machine="mill-1")
        assert len(cat) == 3  # 6246 cycles in blocks of about 2500
        parts = [store.load(rid) for rid in sorted(cat["recording_id"])]
    parts.sort(key=lambda r: int(r.cycles[0]))
    cyc = np.concatenate([p.cycles for p in parts])
    tau = np.concatenate([p.hf["CUT_TORQUE|SP1"].to_numpy() for p in parts])
    assert np.array_equal(cyc, rec.cycles)
    # blocks end at the newest estimated cycle (the inertia term holds one back): NaN only
    # where a speed change is flagged (no cutting torque there)
    np.testing.assert_array_equal(tau, batch)
    holes = [h for p in parts for h in p.meta.attrs["holes"]]
    assert [h["hole"] for h in holes] == [0, 1, 2]
    assert parts[0].meta.units["CUT_TORQUE|SP1"] == "Nm"


def test_anomaly_processor_learns_then_scores(wear_recording: Recording,
                                              spindle_model: SpindleModel) -> None:
    mem = MemorySink()
    an = AnomalyProcessor(model=spindle_model, learn_s=4.0)
    EdgeRuntime(ReplaySource(wear_recording, chunk_cycles=100),
                [TorqueProcessor(spindle_model), an], [mem]).run()
    assert an.learned == 2000  # 4 s at 500 Hz
    assert an.scored == wear_recording.n_cycles - 2000
    assert all(m["detector"] == "PhysicsResidualDetector" for m in mem.kind("alarm"))


@pytest.mark.parametrize("suffix", [".json", ".toml"])
def test_model_file_round_trip(tmp_path: Path, suffix: str) -> None:
    m = SpindleModel(1.04, 8.42e-5, 0.35, j_kgm2=0.01, kt_temp_coeff_per_k=-0.001,
                     reference_temperature_c=25.0)
    p = save_spindle_model(m, tmp_path / f"spindle{suffix}")
    assert load_spindle_model(p) == m
    # without a Stribeck term the file has no such keys (earlier versions read it); with one
    # it round-trips
    assert "stribeck" not in p.read_text(encoding="utf-8")
    ms = SpindleModel(1.0, 8e-5, 0.38, stribeck_torque_nm=0.23, stribeck_speed_rpm=502.0)
    assert load_spindle_model(save_spindle_model(ms, tmp_path / f"s2{suffix}")) == ms
    bad = tmp_path / "bad.json"
    bad.write_text('{"kt_nm_per_a": 1.0, "b_nm_per_rpm": 1e-4}')
    with pytest.raises(ConfigError, match="tau_f_nm"):
        load_spindle_model(bad)


def test_a_parquet_replay_reads_only_the_columns_the_pipeline_needs(
        tmp_path: Path, wear_recording: Recording, spindle_model: SpindleModel) -> None:
    """Issue 28: a replay plant reads only what its processors and sinks use. A Parquet file
    is opened with its clock, metadata and events; the runtime then asks for the union of the
    pipeline's ``needs`` (torque, holes, anomaly: 11 of the file's columns) and the results
    equal those of the whole recording in memory, message for message."""
    from cnctwin.edge.pipeline import needed_columns
    from cnctwin.iotools.parquet import write_parquet

    rec = wear_recording
    path = tmp_path / "rec.parquet"
    write_parquet(rec, path)
    model = spindle_model

    def procs() -> list[Any]:
        return [TorqueProcessor(model), HoleProcessor(model),
                AnomalyProcessor(model=model, learn_s=5.0)]

    want = needed_columns([*procs(), MemorySink()])
    assert want is not None and "CURRENT|SP1" in want and "DES_POS|Z1" in want
    assert len(want) < len(rec.columns)
    src = ReplaySource(path, chunk_cycles=50)
    assert src.recording.columns == []  # nothing of the HF table read yet
    assert src.identity()["n_cycles"] == rec.n_cycles  # the clock is there (checkpoints)
    mem = MemorySink()
    EdgeRuntime(src, procs(), [mem]).run()
    assert sorted(src.recording.columns) == sorted(c for c in want if rec.has(c))
    ref = MemorySink()
    EdgeRuntime(ReplaySource(rec, chunk_cycles=50), procs(), [ref]).run()

    def plain(msgs: list[dict[str, Any]]) -> list[str]:  # NaN compares equal as text
        return [json.dumps(m, sort_keys=True) for m in msgs
                if m["kind"] not in ("status", "run")]

    assert plain(mem.messages) == plain(ref.messages)
    assert len([m for m in mem.messages if m["kind"] == "hole"]) == 3
    # a part that does not say what it needs gets every column
    assert needed_columns([TorqueProcessor(model), object()]) is None
    src2 = ReplaySource(path, chunk_cycles=50)
    src2.select_columns(None)
    assert src2.recording.columns == rec.columns


def test_a_stop_ends_a_paced_replay_during_a_recorded_pause(
        wear_recording: Recording, spindle_model: SpindleModel) -> None:
    """A real-time replay of a recording with a 10 min pause in its cycles (a machine left
    idle) waits for the pause; a stop (SIGTERM, Ctrl-C) ends it at once, not 10 min later."""
    import threading
    import time

    rec = wear_recording.select(cycles=(None, int(wear_recording.cycles[999])))
    hf = rec.hf.copy()
    late = hf.iloc[500:].copy()
    late.index = late.index + 300_000  # 600 s later
    late["time"] = late["time"] + pd.Timedelta(seconds=600)
    paused = Recording(pd.concat([hf.iloc[:500], late]), meta=rec.meta)
    sink = MemorySink()
    rt = EdgeRuntime(ReplaySource(paused, chunk_cycles=100, speed=1.0),
                     [TorqueProcessor(spindle_model)], [sink])
    th = threading.Thread(target=rt.run)
    th.start()
    deadline = time.monotonic() + 30
    while sum(m["n"] for m in sink.messages if m["kind"] == "torque") < 400:
        assert time.monotonic() < deadline, "the first second was not replayed"
        time.sleep(0.05)
    time.sleep(1.0)  # now in the pause
    t0 = time.monotonic()
    rt.stop()
    th.join(timeout=10)
    assert not th.is_alive(), "the stop waited for the pace"
    assert time.monotonic() - t0 < 2.0
    assert rt.final_status is not None and rt.final_status["state"] == "finished"
