"""Shared fixtures: paths of the vendored real recordings and service helpers."""

from __future__ import annotations

from pathlib import Path

import pytest

TESTS_DATA_DIR = Path(__file__).parent / "data"
REAL_DIR = TESTS_DATA_DIR / "real"
C4A_FILE = REAL_DIR / "capture4analysis" / "example_data_ff429d74-6482-4d4f-80e1-31419d9bd56c.json"
TRACE_FILE = REAL_DIR / "sinumerik-trace" / "Tav23362_2140_frenata_15_4_26_EmgTest.xml"
UMICH_DIR = REAL_DIR / "umich-cnc-mill"
VICOMTECH_FILE = REAL_DIR / "vicomtech-turning-wear" / "Dataset_Machine_tool_wear.csv"


@pytest.fixture(scope="session")
def c4a_file() -> Path:
    """The real Capture4Analysis recording (SINUMERIK 840D sl, 5 axes + spindle)."""
    return C4A_FILE


@pytest.fixture(scope="session")
def trace_file() -> Path:
    """The real SINUMERIK Solution Line servo trace (emergency-brake test)."""
    return TRACE_FILE
