"""Tests of the thermal-camera reader on small hand-made CSV texts (typed below).

Expected values are the typed numbers with the stated conversions (K - 273.15, (F - 32) * 5/9).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from cnctwin.exceptions import FormatError
from cnctwin.iotools import read_thermal_camera_csv


def _w(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "cam.csv"
    p.write_text(text, encoding="utf-8")
    return p


def test_simulator_layout(tmp_path: Path) -> None:
    ch = read_thermal_camera_csv(_w(tmp_path, "time_s,hole,temperature_c\n1.5,1,35.2\n"
                                               "4.0,2,36.8\n7.25,3,38.1\n"))
    assert ch.fs_hz is None
    assert ch.data.index.name == "time_s"
    assert ch.data.index.tolist() == [1.5, 4.0, 7.25]
    assert ch.data["temperature_c"].tolist() == [35.2, 36.8, 38.1]
    assert ch.data["hole"].tolist() == [1.0, 2.0, 3.0]
    assert ch.units["temperature_c"] == "degC"


def test_hole_index_only(tmp_path: Path) -> None:
    ch = read_thermal_camera_csv(_w(tmp_path, "Hole #;Temperature [°C]\n1;30,5\n2;31,0\n"))
    assert ch.data.index.name == "hole"
    assert ch.data["temperature_c"].tolist() == [30.5, 31.0]


def test_flir_style(tmp_path: Path) -> None:
    text = ("File:,IR_0001.seq\nEmissivity:,0.95\n\n"
            "Frame,Time,Sp1 [°C],Bx1 Max [K],Bx1 Min [°F]\n"
            "1,00:00:01.000,25.0,310.15,77.0\n2,00:00:01.500,26.0,311.15,78.8\n")
    ch = read_thermal_camera_csv(_w(tmp_path, text))
    assert ch.data.index.tolist() == [0.0, 0.5]
    # canonical = the 'Max' measurement, converted from K
    assert ch.data["temperature_c"].tolist() == pytest.approx([37.0, 38.0])
    assert ch.data["sp1_c"].tolist() == pytest.approx([25.0, 26.0])
    assert ch.data["bx1min_c"].tolist() == pytest.approx([25.0, 26.0])
    assert ch.data["frame"].tolist() == [1.0, 2.0]


def test_datetime_time(tmp_path: Path) -> None:
    ch = read_thermal_camera_csv(_w(tmp_path, "timestamp,temp\n2024-05-01T10:00:00Z,20\n"
                                               "2024-05-01T10:00:02.5Z,21\n"))
    assert ch.data.index.tolist() == [0.0, 2.5]


def test_errors(tmp_path: Path) -> None:
    with pytest.raises(FormatError, match="no header with a temperature"):
        read_thermal_camera_csv(_w(tmp_path, "a,b\n1,2\n"))
    with pytest.raises(FormatError) as ei:
        read_thermal_camera_csv(_w(tmp_path, "time_s,temperature_c\n0,20\n1,hot\n"))
    assert ei.value.position == "line 3" and ei.value.field == "temperature_c"
    with pytest.raises(FormatError, match="fields"):
        read_thermal_camera_csv(_w(tmp_path, "time_s,temperature_c\n0,20,1\n"))
    with pytest.raises(FormatError, match="neither a time nor a hole"):
        read_thermal_camera_csv(_w(tmp_path, "label,temperature_c\nA,20\n"))
