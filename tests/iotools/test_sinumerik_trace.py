"""Tests of the SINUMERIK servo-trace reader on the real trace (emergency-brake test, axis 7).

Facts below were read by hand from ``tests/data/real/sinumerik-trace/
Tav23362_2140_frenata_15_4_26_EmgTest.xml`` (grep/sed on the XML): 10 ``dataSignal``s in the
single ``dataFrame``; ``servoSampleRate="0.002"``; ``stopInc="45.416000"``; 22428 ``<rec>``
elements; first ``<rec time="0.000000" f1=... f10="0.000000" ...>``, last
``<rec time="45.416000" ... f10="180.000000" ... f7="0.991272"/>``; 4 ms signals f2 (aaStat), f8
(measPos1), f9 (measPos2) have ``datapointCount="11354"`` and appear in 11354 records; f10
(position setpoint) appears in 3302 records.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cnctwin.exceptions import FormatError, TruncatedFileError
from cnctwin.iotools import read_sinumerik_trace
from cnctwin.recording import Recording


@pytest.fixture(scope="module")
def rec(trace_file: Path) -> Recording:
    return read_sinumerik_trace(trace_file)


def test_grid_and_signals(rec: Recording) -> None:
    # 45.416 s / 2 ms + 1 = 22709 grid points (= datapointCount of the 2 ms signals)
    assert rec.n_cycles == 22709
    assert rec.meta.cycle_time_s == 0.002
    assert rec.duration_s == pytest.approx(45.416, abs=1e-9)
    assert len(rec.columns) == 10
    assert set(rec.columns) == {
        "DES_POS|AX7", "ENC1_POS|AX7", "ENC2_POS|AX7", "FOLLOWING_ERROR|AX7", "CURRENT|AX7",
        "CMD_SPEED|AX7", "SPEED_ACT|AX7", "SPEED_ACT_MOTOR|AX7", "ACC_SETPOINT|AX7",
        "AXIS_STATUS|AX7",
    }
    assert rec.cycles[0] == 0 and rec.cycles[-1] == 22708
    assert not rec.meta.gaps
    # frameHeader startTime="2012-01-20T20:01:47.526Z" is the anchor of cycle 0
    assert rec.hf["time"].iloc[0] == pd.Timestamp("2012-01-20T20:01:47.526Z")
    assert rec.hf["time"].iloc[-1] == pd.Timestamp("2012-01-20T20:02:32.942Z")


def test_original_names_kept(rec: Recording) -> None:
    sig = rec.meta.attrs["trace_signals"]
    assert sig["FOLLOWING_ERROR|AX7"]["name"] == "/Nck/!SD/nckServoDataFlwErr64 [u1, 7]"
    assert sig["DES_POS|AX7"]["description"] == "Position setpoint (64 bit)"
    assert sig["DES_POS|AX7"]["records"] == 3302
    assert sig["ENC1_POS|AX7"]["records"] == 11354
    assert sig["AXIS_STATUS|AX7"]["interval_s"] == 0.004


def test_units_rotary_inferred(rec: Recording) -> None:
    # position setpoint 0 -> 180 while velocity setpoint 18: 108 units/s per 18 = 6 -> deg, rpm
    assert rec.meta.attrs["rotary"] is True
    assert rec.meta.units["DES_POS|AX7"] == "deg"
    assert rec.meta.units["CMD_SPEED|AX7"] == "rpm"
    assert rec.meta.units["ACC_SETPOINT|AX7"] == "deg/s^2"
    assert rec.meta.units["CURRENT|AX7"] == "A"
    assert any("inferred rotary" in i for i in rec.meta.issues)


def test_sample_and_hold(rec: Recording) -> None:
    hf = rec.hf
    # first and last records (hand-read from the XML)
    assert hf["CURRENT|AX7"].iloc[0] == pytest.approx(-0.798340)
    assert hf["FOLLOWING_ERROR|AX7"].iloc[0] == pytest.approx(-0.000172)
    assert hf["CURRENT|AX7"].iloc[-1] == pytest.approx(0.991272)
    assert hf["DES_POS|AX7"].iloc[-1] == 180.0
    # rec time=0.004 writes only f4; current (f7) is held from time 0.002 (-0.791687)
    assert hf.loc[2, "CURRENT|AX7"] == pytest.approx(-0.791687)
    # 4 ms signals: no value at t=0 (NaN, not invented), first value at 0.002 held at 0.004
    assert np.isnan(hf["ENC1_POS|AX7"].iloc[0])
    assert hf.loc[1, "ENC1_POS|AX7"] == pytest.approx(-0.0056)
    assert hf.loc[2, "ENC1_POS|AX7"] == pytest.approx(-0.0056)
    held = [i for i in rec.meta.issues if "held" in i]
    assert len(held) == 10
    assert any("AXIS_STATUS|AX7" in i and "every 4 ms" in i for i in held)


def test_ranges(rec: Recording) -> None:
    hf = rec.hf
    assert hf["DES_POS|AX7"].min() == 0.0 and hf["DES_POS|AX7"].max() == 180.0
    assert hf["CMD_SPEED|AX7"].abs().max() == pytest.approx(18.0)
    assert hf["ACC_SETPOINT|AX7"].abs().max() == pytest.approx(303.500022)
    assert hf["CURRENT|AX7"].min() == pytest.approx(-36.430904)
    assert hf["CURRENT|AX7"].max() == pytest.approx(37.395569)
    assert hf["FOLLOWING_ERROR|AX7"].abs().max() == pytest.approx(0.678045)
    assert set(np.unique(hf["AXIS_STATUS|AX7"].dropna())) == {1.0, 3.0, 4.0}


def test_brake_visible_in_speed(rec: Recording) -> None:
    """The three 180 deg moves end in a braking ramp: 18 rpm -> 0 in about 0.55 s."""
    speed = rec.signal("SPEED_ACT", "AX7")
    t = rec.time_s
    # first move: cruising at 18 rpm at 8.0 s, standing (< 0.1 rpm) at 8.60 s
    assert speed[t == 8.0].iloc[0] == pytest.approx(18.0, abs=0.05)
    assert abs(speed[np.isclose(t, 8.6)].iloc[0]) < 0.1
    # deceleration of the actual speed: steepest -57.9 rpm/s at 8.27 s (setpoint ramp
    # ACC_SETPOINT = -303.5 deg/s^2 = -50.6 rpm/s); tolerance 0.1 rpm/s
    dv = np.gradient(speed.to_numpy(), rec.meta.cycle_time_s)
    i = int(np.argmin(dv))
    assert dv[i] == pytest.approx(-57.933, abs=0.1)
    assert t[i] == pytest.approx(8.27, abs=1e-9)
    # axis status $AA_STAT: 1 (traversing) during the move, 4 (exact stop fine) before it
    st = rec.signal("AXIS_STATUS", "AX7")
    assert st[np.isclose(t, 6.0)].iloc[0] == 4.0
    assert st[np.isclose(t, 7.5)].iloc[0] == 1.0


def test_axis_map_and_rotary_override(trace_file: Path) -> None:
    rec = read_sinumerik_trace(trace_file, axis_map={7: "C2"}, rotary=False)
    assert "DES_POS|C2" in rec.columns
    assert rec.meta.units["DES_POS|C2"] == "mm"
    assert rec.meta.axis_map == {7: "C2"}


_HEAD = """<?xml version="1.0" encoding="utf-8" ?>
<traceSession version="01.00.03.02">
<traceCaptureSetup><sampleRateSettings servoSampleRate="0.002"/></traceCaptureSetup>
<traceData dataFrames="1"><dataFrame>
<frameHeader startTime="2020-01-01T00:00:00.000Z" stopInc="0.006" dropOuts="0"/>
<dataSignal id="f1" interval="0.002000" name="/Nck/!SD/nckServoDataActCurr32 [u1, 1]"
 unitsType="current" description="iq"/>
"""


def _write(tmp_path: Path, body: str, tail: str = "</dataFrame></traceData></traceSession>\n",
           ) -> Path:
    p = tmp_path / "t.xml"
    p.write_text(_HEAD + body + tail, encoding="utf-8")
    return p


def test_small_synthetic_trace(tmp_path: Path) -> None:
    # hand-written: three records, the middle one empty -> held
    p = _write(tmp_path, '<rec time="0.000" f1="1.5"/><rec time="0.002"/><rec time="0.006" '
                         'f1="2.5"/>')
    rec = read_sinumerik_trace(p)
    assert rec.signal("CURRENT|X1").tolist() == [1.5, 1.5, 1.5, 2.5]
    assert rec.meta.units["CURRENT|X1"] == "A"


def test_not_a_trace(tmp_path: Path) -> None:
    p = tmp_path / "x.xml"
    p.write_text("<foo/>", encoding="utf-8")
    with pytest.raises(FormatError, match="not <traceSession>"):
        read_sinumerik_trace(p)


def test_bad_value(tmp_path: Path) -> None:
    p = _write(tmp_path, '<rec time="0.000" f1="1.5"/><rec time="0.002" f1="abc"/>')
    with pytest.raises(FormatError) as ei:
        read_sinumerik_trace(p)
    assert ei.value.position == "dataFrame[1]/rec[2]" and ei.value.field == "f1"
    rec = read_sinumerik_trace(p, salvage=True)
    assert rec.meta.partial
    assert rec.signal("CURRENT|X1").tolist() == [1.5, 1.5]


def test_undeclared_id(tmp_path: Path) -> None:
    p = _write(tmp_path, '<rec time="0.000" f1="1.5" f9="2"/>')
    with pytest.raises(FormatError, match="f9"):
        read_sinumerik_trace(p)


def test_off_grid_time(tmp_path: Path) -> None:
    p = _write(tmp_path, '<rec time="0.000" f1="1.5"/><rec time="0.001" f1="2"/>')
    with pytest.raises(FormatError, match="not on the 2 ms servo grid"):
        read_sinumerik_trace(p)


def test_truncated(tmp_path: Path) -> None:
    p = _write(tmp_path, '<rec time="0.000" f1="1.5"/><rec time="0.002" f1="2.0"/><rec ti',
               tail="")
    with pytest.raises(TruncatedFileError) as ei:
        read_sinumerik_trace(p)
    assert ei.value.position is not None and ei.value.position.startswith("line ")
    rec = read_sinumerik_trace(p, salvage=True)
    assert rec.meta.partial
    assert rec.signal("CURRENT|X1").tolist() == [1.5, 2.0]


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(FormatError, match="not found"):
        read_sinumerik_trace(tmp_path / "nope.xml")
