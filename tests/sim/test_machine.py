"""Tests of the machine description (:mod:`cnctwin.sim.machine`)."""

from __future__ import annotations

from pathlib import Path

import pytest

from cnctwin.exceptions import ConfigError
from cnctwin.machine import FeedAxis, Machine, SpindleMotor, dynamic_response_adaptation_times


def test_thesis_default_layout() -> None:
    m = Machine.thesis_default()
    assert m.name == "thesis-5axis-840Dsl"
    assert m.axis_names == ("X1", "Y1", "Z1", "C1", "B1")
    assert m.axis_map == {1: "X1", 2: "Y1", 3: "Z1", 4: "C1", 5: "B1", 6: "SP1"}
    assert m.cycle_time_s == 0.002 and m.inner_steps == 16  # 2 ms / 125 us (§1.1)
    assert isinstance(m.spindle, SpindleMotor)
    x = m.axis("X1")
    assert (x.kv_m_min_per_mm, x.ffw_mode, x.jerk_filter_type, x.jerk_time_s) == (2.5, 3, 2, 0.008)


def test_kv_unit_conversion() -> None:
    # MD10230: 1 (m/min)/mm = 16.666667 1/s (docs/reference/physics-and-performance.md §1.2)
    assert FeedAxis("X1", kv_m_min_per_mm=1.0).kv_per_s == pytest.approx(16.666667, rel=1e-7)


def test_reflected_inertia_and_lead() -> None:
    ax = FeedAxis("X1", screw_pitch_mm=10.0, mass_kg=400.0, motor_inertia_kgm2=0.0015)
    r = 0.010 / (2 * 3.141592653589793)
    assert ax.total_inertia_kgm2 == pytest.approx(0.0015 + 400.0 * r * r, rel=1e-12)
    assert ax.load_per_motor_rad == pytest.approx(10.0 / (2 * 3.141592653589793))
    c = FeedAxis("C1", rotary=True, gear_ratio=100.0, load_inertia_kgm2=2.0,
                 motor_inertia_kgm2=0.001)
    assert c.total_inertia_kgm2 == pytest.approx(0.001 + 2.0 / 100.0**2)


def test_toml_round_trip(tmp_path: Path) -> None:
    m = Machine.thesis_default().with_overrides({"axes.Z1.mass_kg": 321.0,
                                                 "spindle.kt_nm_per_a": 1.1})
    path = m.to_toml(tmp_path / "machine.toml")
    back = Machine.from_toml(path)
    assert back == m
    assert back.axis("Z1").mass_kg == 321.0 and back.spindle.kt_nm_per_a == 1.1


def test_toml_unknown_key(tmp_path: Path) -> None:
    p = tmp_path / "m.toml"
    p.write_text('name = "m"\n[axes.X1]\nkv = 3.0\n', encoding="utf-8")
    with pytest.raises(ConfigError, match="kv_m_min_per_mm"):
        Machine.from_toml(p)
    p.write_text("name = \n", encoding="utf-8")
    with pytest.raises(ConfigError, match="not valid TOML"):
        Machine.from_toml(p)


def test_overrides() -> None:
    m = Machine.thesis_default().with_overrides(
        {"axes.X1.kv_m_min_per_mm": 3.0, "spindle.kt_nm_per_a": 1.1, "inner_steps": 8}
    )
    assert m.axis("X1").kv_m_min_per_mm == 3.0
    assert m.axis("Y1").kv_m_min_per_mm == 2.5
    assert m.spindle.kt_nm_per_a == 1.1
    assert m.inner_steps == 8
    assert Machine.thesis_default().axis("X1").kv_m_min_per_mm == 2.5  # original unchanged


def test_unknown_override_lists_valid_keys() -> None:
    with pytest.raises(ConfigError, match=r"axes\.X1\.kv_m_min_per_mm") as exc:
        Machine.thesis_default().with_overrides({"axes.X1.kv": 3.0})
    assert "spindle.kt_nm_per_a" in str(exc.value)


@pytest.mark.parametrize(
    ("key", "value", "match"),
    [
        ("axes.X1.kv_m_min_per_mm", -1.0, "kv_m_min_per_mm"),
        ("axes.Y1.ffw_mode", 5, "MD32620"),
        ("axes.Z1.jerk_filter_type", 3, "jerk_filter_type"),
        ("axes.C1.ffw_weight", 1.5, "ffw_weight"),
        ("cycle_time_s", 0.0, "cycle_time_s"),
        ("inner_steps", 0, "inner_steps"),
    ],
)
def test_validation(key: str, value: object, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        Machine.thesis_default().with_overrides({key: value})


def test_dynamic_response_adaptation_times() -> None:
    # K3 / 802S example (docs/reference/physics-and-performance.md §1.2): DRA = difference of the
    # equivalent
    # times to the slowest axis; without FFW the equivalent time is 1/Kv
    fast = FeedAxis("Z1", ffw_mode=0, kv_m_min_per_mm=2.5)
    slow = FeedAxis("SP", ffw_mode=0, kv_m_min_per_mm=0.5)
    dra = dynamic_response_adaptation_times([fast, slow])
    assert dra["SP"] == 0.0
    assert dra["Z1"] == pytest.approx(1 / (0.5 * 16.666667) - 1 / (2.5 * 16.666667), rel=1e-6)
    assert dra["Z1"] == pytest.approx(0.096, rel=1e-3)
