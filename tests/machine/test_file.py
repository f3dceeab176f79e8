"""The machine file: one schema, one loader, one validator (issue 12, point 1)."""

from __future__ import annotations

from pathlib import Path

import pytest

from cnctwin.exceptions import ConfigError
from cnctwin.machine import (
    Machine,
    MachineFile,
    ParameterRecord,
    Provenance,
    load_machine,
    parameter_unit,
    save_machine,
)


def _identified(value: float, unc: float) -> ParameterRecord:
    return ParameterRecord(value, unc, Provenance.now("unit test", ["air.json", "cut.json"]),
                           valid_range=(500.0, 4000.0), valid_quantity="speed_rpm")


def test_round_trip_keeps_values_records_and_defaults(tmp_path: Path) -> None:
    mf = MachineFile().with_records({
        "spindle.kt_nm_per_a": _identified(1.12, 0.004),
        "axes.Y1.coulomb_n": _identified(210.0, 3.0),
        "axes.X1.jerk_time_s": ParameterRecord(0.008, identified=False,
                                               reason="CTRL_POS is not recorded"),
    })
    p = save_machine(mf, tmp_path / "m.toml")
    back = load_machine(p)
    assert back.machine == mf.machine
    assert back.records == mf.records
    assert back.value("spindle.kt_nm_per_a") == 1.12
    assert back.is_identified("axes.Y1.coulomb_n")
    assert not back.is_identified("axes.X1.jerk_time_s")
    # silent parameters keep the documented default
    assert back.value("axes.X1.kv_m_min_per_mm") == Machine().axis("X1").kv_m_min_per_mm
    rec = back.record("spindle.kt_nm_per_a")
    assert rec is not None and rec.interval95() == pytest.approx((1.12 - 0.00784, 1.12 + 0.00784))


def test_hand_written_plain_values(tmp_path: Path) -> None:
    p = tmp_path / "m.toml"
    p.write_text('name = "cell3"\n[spindle]\nkt_nm_per_a = 0.95\npole_count = 4\n'
                 '[axes.X1]\nkv_m_min_per_mm = 3\n[axes.Z1]\n', encoding="utf-8")
    mf = load_machine(p)
    assert mf.machine.name == "cell3"
    assert mf.machine.axis_names == ("X1", "Z1")
    assert mf.value("axes.X1.kv_m_min_per_mm") == 3.0
    assert isinstance(mf.value("axes.X1.kv_m_min_per_mm"), float)
    assert mf.records == {}


@pytest.mark.parametrize(("text", "needle"), [
    ("[spindle]\nkt_nm_per_amp = 1.0\n", "spindle.kt_nm_per_amp"),
    ("[axes.X1]\nkv = 2.0\n", "axes.X1.kv"),
    ("[axes.X1]\nkv_m_min_per_mm = 200.0\n", "axes.X1.kv_m_min_per_mm = 200.0 is out of range"),
    ("[spindle]\nkt_nm_per_a = { value = 1.0, unit = \"Nm/mA\" }\n", "'Nm/A'"),
    ("[spindle]\nkt_nm_per_a = { uncertainty = 0.1 }\n", "without 'value'"),
    ("[spindle]\nkt_nm_per_a = \"one\"\n", "spindle.kt_nm_per_a must be a number"),
    ("[spindle]\ncoulomb_friction_nm = -1.0\n", "spindle.coulomb_friction_nm = -1.0"),
    ("[spindle]\npole_count = 5\n", "even integer"),
    ("schema_version = 7\n", "update cnctwin"),
    ("colour = 1\n", "unknown keys ['colour']"),
    ("[spindle\nkt = 1\n", "not valid TOML"),
])
def test_bad_files_name_the_key(tmp_path: Path, text: str, needle: str) -> None:
    p = tmp_path / "bad.toml"
    p.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError) as err:
        load_machine(p)
    assert needle in str(err.value)
    assert str(p) in str(err.value)


def test_missing_file_says_how_to_create_it(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cnctwin calibrate"):
        load_machine(tmp_path / "none.toml")


def test_units_from_key_names() -> None:
    # the names carry the units (conventions: units in names)
    assert parameter_unit("axes.X1.kv_m_min_per_mm") == "(m/min)/mm"
    assert parameter_unit("axes.X1.coulomb_n") == "N"
    assert parameter_unit("axes.X1.jerk_time_s") == "s"
    assert parameter_unit("spindle.coulomb_friction_nm") == "Nm"
    assert parameter_unit("axes.X1.ffw_weight") == "-"


def test_saved_machine_file_has_the_users_permissions(tmp_path: Path) -> None:
    """Issue 29, pt 5: the machine file was written 0600 (mkstemp's mode) while every other
    output is 0644: a new file gets the umask, a replaced file keeps its mode."""
    import os
    import stat

    from cnctwin.machine import MachineFile, save_machine

    old = os.umask(0o022)
    try:
        p = save_machine(MachineFile(), tmp_path / "m.toml")
        assert stat.S_IMODE(p.stat().st_mode) == 0o644
        p.chmod(0o640)  # the user restricted it: a recalibration keeps that
        save_machine(MachineFile(), p)
        assert stat.S_IMODE(p.stat().st_mode) == 0o640
    finally:
        os.umask(old)


def test_the_documented_example_is_a_valid_machine_file(tmp_path: Path) -> None:
    """Issue 29, pt 5: docs/machine-file.md's example, copied verbatim, failed at line 7
    (TOML inline tables cannot span lines). It loads now, with the values it states."""
    import re

    from cnctwin.machine import load_machine

    doc = (Path(__file__).resolve().parents[2] / "docs" / "machine-file.md").read_text()
    example = re.search(r"```toml\n(.*?)```", doc, re.S)
    assert example is not None
    p = tmp_path / "machine.toml"
    p.write_text(example.group(1), encoding="utf-8")
    mf = load_machine(p)
    assert mf.value("spindle.kt_nm_per_a") == pytest.approx(1.021)
    assert mf.is_identified("spindle.kt_nm_per_a")
    assert not mf.is_identified("spindle.inertia_kg_m2")
    assert mf.machine.name == "dmc60h-cell3"


def test_round_trip_keeps_seven_significant_digits(tmp_path: Path) -> None:
    """Values with every digit the file promises (7 significant; uncertainty 3): a writer
    that rounds harder, or a reader that parses to float32, loses them. Values of two
    significant digits (the test above) cannot tell."""
    vals = {"spindle.kt_nm_per_a": (1.043219, 0.00421),
            "spindle.viscous_friction_nm_per_rpm": (8.423517e-05, 7.41e-07),
            "axes.X1.kv_m_min_per_mm": (2.487613, 0.00312),
            "axes.Y1.coulomb_n": (149.8172, 1.87)}
    mf = MachineFile().with_records({k: _identified(v, u) for k, (v, u) in vals.items()})
    back = load_machine(save_machine(mf, tmp_path / "m.toml"))
    for key, (v, u) in vals.items():
        rec = back.record(key)
        assert rec is not None
        assert rec.value == v, key  # exactly: 7 digits written, 7 read
        assert rec.uncertainty == u, key
        assert back.value(key) == v
    # more digits than the file keeps are rounded to 7 significant, not truncated
    mf = MachineFile().with_records({"spindle.kt_nm_per_a": _identified(1.04321987, 0.004)})
    back = load_machine(save_machine(mf, tmp_path / "m2.toml"))
    assert back.value("spindle.kt_nm_per_a") == 1.04322
