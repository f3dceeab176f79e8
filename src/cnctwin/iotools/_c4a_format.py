"""Value and time conventions of the Capture4Analysis format, shared by reader and writer.

* Numbers may arrive as JSON numbers or as numeric strings (LF values always are strings):
  :func:`to_float`.
* Times are ISO 8601 UTC strings with ``Z`` (``2023-12-22T14:25:56.836Z``): :func:`parse_times`
  reads them, :func:`fmt_time` writes them with the fewest sub-second digits that keep them
  exact.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import pandas as pd

__all__ = ["fmt_time", "parse_times", "to_float"]


def to_float(value: Any) -> float | None:
    """Float of a JSON scalar; ``None`` if it is not numeric (booleans are not numbers)."""
    if isinstance(value, bool):
        return None
    if isinstance(value, (int, float)):
        return float(value)
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            return None
    return None


def parse_times(values: Sequence[str]) -> pd.DatetimeIndex:
    """ISO 8601 time strings -> UTC ``DatetimeIndex`` [ns]."""
    idx = pd.DatetimeIndex(pd.to_datetime(list(values), utc=True, format="ISO8601"))
    return idx.as_unit("ns")


def fmt_time(ts: pd.Timestamp) -> str:
    """ISO time with ``Z``, with the fewest sub-second digits (3, 6 or 9) that keep it exact."""
    ts = pd.Timestamp(ts)
    ts = ts.tz_localize("UTC") if ts.tzinfo is None else ts.tz_convert("UTC")
    ns = ts.value % 1_000_000_000
    base = ts.strftime("%Y-%m-%dT%H:%M:%S")
    if ns % 1_000_000 == 0:
        frac = f"{ns // 1_000_000:03d}"
    elif ns % 1000 == 0:
        frac = f"{ns // 1000:06d}"
    else:
        frac = f"{ns:09d}"
    return f"{base}.{frac}Z"
