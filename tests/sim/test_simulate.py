"""End-to-end tests of :func:`cnctwin.sim.simulation.simulate`, read back through Recordings.

Expected values: e = v / Kv (docs/reference/physics-and-performance.md §1.2), thesis §3.1.2 (contour
deviation near zero while following error follows the path), statics for cutting forces.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cnctwin.recording import Recording
from cnctwin.sim.machine import Machine
from cnctwin.sim.recorder import (
    FLOAT32_CODES,
    Capture4AnalysisSink,
    ParquetChunkSink,
    read_parquet_chunks,
)
from cnctwin.sim.simulation import CuttingInput, CuttingOutput, simulate

SQUARE = """G90 G17 G54
T6 M6
S2400 M3
G0 X0 Y0 Z5
G1 Z-1 F400
G1 X5 F400
G1 Y5
G1 X0
G1 Y0
G0 Z5
M5
M30
"""

LINE = """G90
G0 X0 Y0 Z0
G1 X20 F400
M30
"""


@pytest.fixture(scope="module")
def square() -> Recording:
    rec = simulate(SQUARE, seed=3).recording
    assert rec is not None
    return rec


def test_columns_units_meta(square: Recording) -> None:
    for axis in ("X1", "Y1", "Z1", "C1", "B1", "SP1"):
        for code in ("DES_POS", "ENC_POS", "CTRL_POS", "CTRL_DIFF", "CTRL_DIFF2", "CONT_DEV",
                     "VEL_FFW", "TORQUE_FFW", "CMD_SPEED", "CURRENT", "TORQUE", "LOAD",
                     "POWER"):
            assert square.has(code, axis)
    assert square.meta.units["TORQUE|Z1"] == "N" and square.meta.units["CMD_SPEED|SP1"] == "rpm"
    assert square.meta.source_format == "sim"
    assert square.cycles[0] == 5_000_000
    assert square.hf["time"].iloc[0] == pd.Timestamp("2026-01-01T08:00:00Z")
    assert square.events["cycle"].min() == 5_000_000
    assert square.meta.axis_map[6] == "SP1"


def test_lf_values_every_100_ms(square: Recording) -> None:
    lf = square.lf
    assert set(np.unique(np.diff(np.unique(lf["cycle"])))) == {50}  # 100 ms at 2 ms
    sp = lf[lf["signal"] == "SPEED_SMOOTHED|SP1"].set_index("cycle")["value"]
    assert sp.iloc[-15:-8].mean() == pytest.approx(2400.0, rel=0.01)  # S2400 before M5
    assert {"MOTOR_TEMP|X1", "IQ_ACT|SP1", "TORQUE_UTIL|Z1",
            "CURRENT_ABS_SMOOTHED|Y1"} <= set(lf["signal"])


def test_ctrl_diff2_identity(square: Recording) -> None:
    for axis in ("X1", "Y1", "Z1"):
        np.testing.assert_array_equal(
            square.signal("CTRL_DIFF2", axis).to_numpy(),
            (square.signal("CTRL_POS", axis) - square.signal("ENC_POS", axis)).to_numpy(),
        )


def test_square_following_error_vs_contour_deviation(square: Recording) -> None:
    # thesis §3.1.2 / Fig. 3.2: following error follows the corners, CONT_DEV stays near 0
    for axis in ("X1", "Y1"):
        fe = (square.signal("DES_POS", axis) - square.signal("ENC_POS", axis)).to_numpy()
        cd = square.signal("CONT_DEV", axis).to_numpy()
        fe_rms = np.sqrt(np.mean(fe**2))
        assert np.sqrt(np.mean(cd**2)) < 0.1 * fe_rms
        assert np.abs(fe).max() > 0.02  # ~ v x (jerk delay + MD32810) = 33 um at 400 mm/min


def test_following_error_v_over_kv_through_recording() -> None:
    # docs/reference/physics-and-performance.md §1.2: 400 mm/min at Kv 2.5 without FFW -> 0.160 mm
    # (+-2 %)
    m = Machine.thesis_default().with_overrides(
        {"axes.X1.ffw_mode": 0, "axes.X1.jerk_filter_type": 0})
    rec = simulate(LINE, m).recording
    assert rec is not None
    fe = rec.signal("DES_POS", "X1") - rec.signal("ENC_POS", "X1")
    v = rec.signal("CMD_SPEED", "X1") * 60.0  # mm/s (catalog) -> mm/min
    steady = fe[(v > 399.0) & (v < 401.0)]
    assert len(steady) > 500
    assert steady.median() == pytest.approx(0.160, rel=0.02)


def test_same_seed_identical_and_chunking_invariant(square: Recording) -> None:
    again = simulate(SQUARE, seed=3, chunk_cycles=333).recording
    assert again is not None
    pd.testing.assert_frame_equal(again.hf, square.hf)
    pd.testing.assert_frame_equal(again.lf, square.lf)
    other = simulate(SQUARE, seed=4).recording
    assert other is not None
    assert not np.array_equal(other.hf["CURRENT|X1"], square.hf["CURRENT|X1"])


def test_dropped_cycles_are_gaps() -> None:
    res = simulate(SQUARE, seed=1, dropped_cycles=0.01)
    rec = res.recording
    assert rec is not None
    missing = sum(g.missing for g in rec.meta.gaps)
    assert missing == res.truth["n_dropped"] > 0
    assert rec.n_cycles + missing == res.trajectory["n_cycles"] - (
        (rec.cycles[0] - 5_000_000) + (5_000_000 + res.trajectory["n_cycles"] - 1
                                       - rec.cycles[-1]))


def test_cutting_hook_force_and_torque() -> None:
    # statics: a constant +Z thrust F adds -F x lead / (2 pi Kt) to the Z current;
    # spindle current rises by ~ M / Kt (thesis Eq. 3.1)
    m = Machine.thesis_default()
    seen: list[CuttingInput] = []

    def hook(ci: CuttingInput) -> CuttingOutput:
        seen.append(ci)
        on = ci.time_s > 2.0
        return CuttingOutput(spindle_torque_nm=np.where(on, 4.0, 0.0),
                             force_n={"Z1": np.where(on, 2000.0, 0.0)},
                             truth={"load_on": on.astype(float)})

    prog = "G90\nS2400 M3\nG4 F5\nM30\n"
    base = simulate(prog, m, seed=2).recording
    res = simulate(prog, m, seed=2, cutting=hook)
    rec = res.recording
    assert rec is not None and base is not None and seen
    z = m.axis("Z1")
    late = rec.time_s > 3.0
    dz = (rec.hf["CURRENT|Z1"][late] - base.hf["CURRENT|Z1"][late]).mean()
    assert dz == pytest.approx(-2000.0 * z.screw_pitch_mm / 1000 / (2 * np.pi) / z.kt_nm_per_a,
                               rel=0.01)
    dsp = (rec.hf["CURRENT|SP1"][late] - base.hf["CURRENT|SP1"][late]).mean()
    assert dsp == pytest.approx(4.0 / m.spindle.kt_nm_per_a, rel=0.05)
    assert res.truth["per_cycle"]["load_on"].iloc[-1] == 1.0


def test_parquet_sink_round_trip(tmp_path: Path, square: Recording) -> None:
    sink = ParquetChunkSink(tmp_path / "run")
    res = simulate(SQUARE, seed=3, sink=sink, chunk_cycles=1000)
    assert res.recording is None
    assert len(sink.files) == 3
    back = read_parquet_chunks(tmp_path / "run")
    # drive values (FLOAT32_CODES) are stored as float32: equal to float32 rounding (relative
    # 2**-24); positions, differences, speeds, cycles and the recomputed time exactly
    f32 = [c for c in square.hf.columns if c.split("|")[0] in FLOAT32_CODES]
    assert "CURRENT|SP1" in f32 and "ENC_POS|Z1" not in f32
    exact = [c for c in square.hf.columns if c not in f32]
    pd.testing.assert_frame_equal(back.hf[exact], square.hf[exact], check_freq=False)
    for c in f32:
        assert back.hf[c].dtype == np.float64
        np.testing.assert_allclose(back.hf[c].to_numpy(), square.hf[c].to_numpy(),
                                   rtol=2.0**-24, atol=1e-30)
    assert len(back.lf) == len(square.lf)
    pd.testing.assert_frame_equal(back.lf.reset_index(drop=True),
                                  square.lf.reset_index(drop=True), check_dtype=False)


def test_parquet_sink_stores_incompressible_columns_uncompressed(tmp_path: Path) -> None:
    # recorder.py ParquetChunkSink Notes: codecs learned from the first (fully compressed) file
    import pyarrow.parquet as pq

    sink = ParquetChunkSink(tmp_path / "run")
    simulate(SQUARE, seed=3, sink=sink, chunk_cycles=1000)

    def codecs(path: Path) -> dict[str, str]:
        rg = pq.read_metadata(path).row_group(0)
        return {rg.column(i).path_in_schema: rg.column(i).compression
                for i in range(rg.num_columns)}

    first, second = codecs(sink.files[0]), codecs(sink.files[1])
    assert set(first.values()) == {"LZ4_RAW"} or set(first.values()) == {"LZ4"}
    # float32 current noise does not compress; a constant column (C1 never moves) does
    assert second["CURRENT|X1"] == "UNCOMPRESSED"
    assert second["TORQUE_FFW|C1"] == first["TORQUE_FFW|C1"] != "UNCOMPRESSED"
    rg = pq.read_metadata(sink.files[1]).row_group(0)
    assert "DELTA_BINARY_PACKED" in rg.column(0).encodings


@pytest.mark.parametrize("compression", ["zstd", "snappy", "none"])
def test_parquet_sink_codecs_round_trip(tmp_path: Path, square: Recording,
                                        compression: str) -> None:
    # learned per-column codecs with every codec (zstd level 1 only on compressed columns)
    sink = ParquetChunkSink(tmp_path / "run", compression=compression, float32_codes=())
    simulate(SQUARE, seed=3, sink=sink, chunk_cycles=1000)
    pd.testing.assert_frame_equal(read_parquet_chunks(tmp_path / "run").hf, square.hf,
                                  check_freq=False)


@pytest.mark.parametrize("file_format", ["parquet", "arrow"])
def test_parquet_sink_float64_option(tmp_path: Path, square: Recording, file_format: str) -> None:
    sink = ParquetChunkSink(tmp_path / "run", float32_codes=(), file_format=file_format)
    simulate(SQUARE, seed=3, sink=sink, chunk_cycles=1000)
    assert sink.files[0].suffix == f".{file_format}"
    back = read_parquet_chunks(tmp_path / "run")
    pd.testing.assert_frame_equal(back.hf, square.hf, check_freq=False)


def test_capture4analysis_sink(tmp_path: Path, square: Recording) -> None:
    from cnctwin.iotools import read_recording

    sink = Capture4AnalysisSink(tmp_path / "run.json")
    simulate(SQUARE, seed=3, sink=sink)
    back = read_recording(sink.files[0])
    np.testing.assert_array_equal(back.cycles, square.cycles)
    np.testing.assert_array_equal(back.hf["ENC_POS|Z1"].to_numpy(),
                                  square.hf["ENC_POS|Z1"].to_numpy())
    assert len(back.events) >= len(square.events)


def test_read_recording_opens_chunk_directory(tmp_path: Path, square: Recording) -> None:
    from cnctwin.iotools import read_recording

    simulate(SQUARE, seed=3, sink=ParquetChunkSink(tmp_path / "run"), chunk_cycles=1000)
    back = read_recording(tmp_path / "run")
    np.testing.assert_array_equal(back.cycles, square.cycles)
    np.testing.assert_array_equal(back.hf["ENC_POS|Z1"].to_numpy(),
                                  square.hf["ENC_POS|Z1"].to_numpy())
