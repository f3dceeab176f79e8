"""Tests of the signal catalog (cnctwin.signals)."""

from __future__ import annotations

import pytest

from cnctwin import SignalNotFoundError
from cnctwin.signals import CATALOG, HF_CODES, LF_CODES, axis_kind, lookup, parse_column, unit

# SINUMERIK Connector FAQ (docs/reference/data-formats.md section 1.3): every HF code.
CONNECTOR_CODES = {
    "CYCLE", "ENC_POS", "ENC1_POS", "ENC2_POS", "DES_POS", "CTRL_POS", "CTRL_DIFF", "CTRL_DIFF2",
    "CONT_DEV", "VEL_FFW", "TORQUE_FFW", "CMD_SPEED", "CURRENT", "TORQUE", "LOAD", "POWER",
}


def test_catalog_has_every_connector_code_and_table_2_2() -> None:
    assert set(HF_CODES) == CONNECTOR_CODES
    # Thesis Table 2.2: five LF drive values.
    assert {CATALOG[c].thesis_name for c in LF_CODES} == {
        "Actual speed smoothed", "Smoothed absolute current", "Temperature",
        "Actual quadrature-axis current", "Torque utilization",
    }


@pytest.mark.parametrize(
    ("alias", "code"),
    [("ActualAxisPosition", "ENC_POS"), ("CommandedAxisPosition", "DES_POS"),
     ("ControlDiff2", "CTRL_DIFF2"), ("CountourDeviation", "CONT_DEV"),
     ("Encoder position", "ENC_POS"), ("CURRENT|SP1", "CURRENT")],
)
def test_aliases_resolve(alias: str, code: str) -> None:
    assert lookup(alias).code == code


def test_units_depend_on_axis_kind() -> None:
    assert unit("ENC_POS|X1") == "mm"
    assert unit("ENC_POS|C1") == "deg"
    assert unit("TORQUE|SP1") == "Nm"
    assert unit("TORQUE|Z1") == "N"
    assert axis_kind("SP1") == "spindle"
    assert parse_column("CYCLE") == ("CYCLE", None)


def test_unknown_signal_lists_known_codes() -> None:
    with pytest.raises(SignalNotFoundError, match="known codes"):
        lookup("NOPE")


def test_glossary_page_is_generated_from_the_catalog() -> None:
    # docs/glossary.md is generated (make docs); it must not drift from the catalog.
    from pathlib import Path

    from cnctwin.signals import glossary_markdown

    page = Path(__file__).parents[1] / "docs" / "glossary.md"
    assert page.read_text(encoding="utf-8") == glossary_markdown(), "run `make docs`"
