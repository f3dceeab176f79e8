"""Tests of the dynamometer readers and ``attach_external``.

No real dynamometer file is vendored; the fixtures are small hand-made files written by each
test (CSV text typed below; the TDMS file written with ``nptdms.TdmsWriter``). Expected values
are the typed numbers times the stated unit factors (1 kN = 1000 N, 1 N*cm = 0.01 N*m,
1 ms = 0.001 s).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cnctwin.exceptions import CnctwinWarning, ConfigError, FormatError
from cnctwin.iotools import (
    attach_external,
    read_dynamometer_csv,
    read_dynamometer_tdms,
    read_sinumerik_trace,
)

SIM = "time_s,fx_n,fy_n,fz_n,mz_nm\n0.0,1.0,2.0,3.0,0.5\n0.001,1.5,2.5,3.5,0.6\n" \
      "0.002,2.0,3.0,4.0,0.7\n"


def _w(tmp_path: Path, text: str, name: str = "d.csv") -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


def test_simulator_layout(tmp_path: Path) -> None:
    ch = read_dynamometer_csv(_w(tmp_path, SIM))
    assert list(ch.data.columns) == ["fx_n", "fy_n", "fz_n", "mz_nm"]
    assert ch.data.index.name == "time_s"
    assert ch.data.index.tolist() == [0.0, 0.001, 0.002]
    assert ch.fs_hz == pytest.approx(1000.0)
    assert ch.data["fz_n"].tolist() == [3.0, 3.5, 4.0]
    assert ch.units == {"fx_n": "N", "fy_n": "N", "fz_n": "N", "mz_nm": "N*m"}


def test_header_variants_and_units(tmp_path: Path) -> None:
    text = "Time [ms];Fx [kN];Fy (N);F_z [N];Mz [Ncm]\n0;0,1;2;3;50\n2;0,2;2;3;60\n"
    ch = read_dynamometer_csv(_w(tmp_path, text))
    assert ch.data.index.tolist() == pytest.approx([0.0, 0.002])
    assert ch.data["fx_n"].tolist() == pytest.approx([100.0, 200.0])
    assert ch.data["mz_nm"].tolist() == pytest.approx([0.5, 0.6])
    assert ch.fs_hz == pytest.approx(500.0)


def test_no_time_needs_fs(tmp_path: Path) -> None:
    p = _w(tmp_path, "Fx,Fy,Fz,Mz\n1,2,3,4\n5,6,7,8\n")
    with pytest.raises(FormatError, match="fs_hz"):
        read_dynamometer_csv(p)
    ch = read_dynamometer_csv(p, fs_hz=10_000.0)
    assert ch.data.index.tolist() == [0.0, 1e-4]


def test_fs_mismatch_warns(tmp_path: Path) -> None:
    with pytest.warns(CnctwinWarning, match="1000 Hz"):
        read_dynamometer_csv(_w(tmp_path, SIM), fs_hz=2000.0)


def test_unknown_unit(tmp_path: Path) -> None:
    with pytest.raises(FormatError, match="unknown unit") as ei:
        read_dynamometer_csv(_w(tmp_path, "t,Fx [lbf]\n0,1\n"))
    assert ei.value.field == "Fx [lbf]"


def test_no_force_column(tmp_path: Path) -> None:
    with pytest.raises(FormatError, match="no force"):
        read_dynamometer_csv(_w(tmp_path, "a,b\n1,2\n"))


def test_bad_value_and_row(tmp_path: Path) -> None:
    with pytest.raises(FormatError) as ei:
        read_dynamometer_csv(_w(tmp_path, SIM.replace("1.5", "x")))
    assert ei.value.position == "line 3" and ei.value.field == "fx_n"
    with pytest.raises(FormatError) as ei:
        read_dynamometer_csv(_w(tmp_path, SIM + "0.003,1\n"))
    assert ei.value.position == "line 5"


def test_time_not_increasing(tmp_path: Path) -> None:
    with pytest.raises(FormatError, match="increasing"):
        read_dynamometer_csv(_w(tmp_path, SIM.replace("0.002,", "0.0005,")))


def test_tdms(tmp_path: Path) -> None:
    from nptdms import ChannelObject, TdmsWriter

    p = tmp_path / "dyn.tdms"
    fx = np.array([10.0, 20.0, 30.0, 40.0])
    with TdmsWriter(str(p)) as w:
        props = {"wf_increment": 0.0002, "wf_start_offset": 0.0, "unit_string": "N"}
        w.write_segment([
            ChannelObject("Kistler", "Fx", fx, properties=props),
            ChannelObject("Kistler", "Fy", fx * 2, properties=props),
            ChannelObject("Kistler", "Fz", fx * 3, properties={**props, "unit_string": "kN"}),
            ChannelObject("Kistler", "Mz", fx / 10, properties={**props, "unit_string": "Nm"}),
        ])
    ch = read_dynamometer_tdms(p)
    assert ch.fs_hz == pytest.approx(5000.0)
    assert ch.data.index.to_numpy() == pytest.approx([0.0, 0.0002, 0.0004, 0.0006])
    assert ch.data["fz_n"].tolist() == pytest.approx([30e3, 60e3, 90e3, 120e3])
    assert ch.data["mz_nm"].tolist() == pytest.approx([1.0, 2.0, 3.0, 4.0])


def test_tdms_not_tdms(tmp_path: Path) -> None:
    with pytest.raises(FormatError, match="TDMS"):
        read_dynamometer_tdms(_w(tmp_path, "hello", "x.tdms"))


def test_attach_external(tmp_path: Path, trace_file: Path) -> None:
    rec = read_sinumerik_trace(trace_file)
    ch = read_dynamometer_csv(_w(tmp_path, SIM))
    rec2 = attach_external(rec, ch)
    assert "dynamometer" in rec2.external and not rec.external
    assert rec2.hf is rec.hf
    assert rec2.meta.source_files[-1] == ch.source
    with pytest.raises(ConfigError, match="already has"):
        attach_external(rec2, ch)
    assert attach_external(rec2, ch, replace=True).external["dynamometer"] is ch


def test_a_force_without_a_unit_is_not_assumed_to_be_newtons(tmp_path: Path) -> None:
    """The KIT merged CSV's f_x, f_y, f_z carry no unit (and are ~200x smaller than N):
    the reader keeps them as fx/fy/fz with the unit 'unknown' (issue 13)."""
    ch = read_dynamometer_csv(_w(tmp_path, "time,f_x,f_y,f_z,Mz [Nm]\n0,1,2,3,4\n0.02,5,6,7,8\n"))
    assert list(ch.data.columns) == ["fx", "fy", "fz", "mz_nm"]
    assert ch.units == {"fx": "unknown", "fy": "unknown", "fz": "unknown", "mz_nm": "N*m"}
    assert ch.data["fx"].tolist() == [1.0, 5.0]  # not scaled
