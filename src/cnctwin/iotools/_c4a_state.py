"""Capture4Analysis reader, the state shared by the files of one run.

:class:`ReadState` collects the repairs (``issues``, ``partial``), keeps the axis numbering
seen in the headers and unwraps the 31-bit cycle counter across files; :func:`line_col` and
:func:`opt_int` are the small conversions every part of the reader uses. Private to
:mod:`cnctwin.iotools.capture4analysis`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from cnctwin.exceptions import FormatError
from cnctwin.iotools._c4a_format import to_float
from cnctwin.recording import CYCLE_COUNTER_MODULUS
from cnctwin.signals import DEFAULT_AXIS_MAP

__all__ = ["ReadState", "line_col", "nearest_unwrap", "opt_int"]

_M = CYCLE_COUNTER_MODULUS


def line_col(data: bytes | memoryview, pos: int) -> str:
    """``"byte 123 (line 4, column 7)"`` for an absolute offset."""
    raw = bytes(data[: max(pos, 0)]) if isinstance(data, memoryview) else data[: max(pos, 0)]
    line = raw.count(b"\n") + 1
    col = pos - (raw.rfind(b"\n") + 1) + 1
    return f"byte {pos} (line {line}, column {col})"


def nearest_unwrap(raw: int, ref: int) -> int:
    """The unwrapped counter ``raw + k*2**31`` closest to ``ref``."""
    return raw + _M * round((ref - raw) / _M)


def opt_int(value: Any) -> Any:
    """``int`` of an integral JSON scalar (number or numeric string), else ``pd.NA``."""
    if value is None:
        return pd.NA
    if isinstance(value, bool):
        return int(value)
    if isinstance(value, int):
        return value
    f = to_float(value)
    if f is None or not np.isfinite(f) or f != int(f):
        return pd.NA
    return int(f)


class ReadState:
    """State shared across the files of one chain.

    Parameters
    ----------
    axis_map : dict, optional
        Axis number -> axis name for empty ``Axis`` header fields; default
        :data:`cnctwin.signals.DEFAULT_AXIS_MAP`.
    salvage : bool
        Keep what can be read from damaged input (and flag it) instead of raising.
    """

    def __init__(self, *, axis_map: dict[int, str] | None, salvage: bool) -> None:
        self.explicit_map = axis_map is not None
        self.axis_map = dict(DEFAULT_AXIS_MAP if axis_map is None else axis_map)
        self.salvage = salvage
        self.issues: list[str] = []
        self.partial = False
        self.ref: int | None = None  # last unwrapped counter, for nearest-wrap unwrapping
        self.seen_axes: dict[int, str] = {}
        self.string_conversions: dict[str, int] = {}
        self.nulls: dict[str, int] = {}

    # ------------------------------------------------------------------ counters
    def unwrap_one(self, raw: int) -> int:
        """Unwrap one counter value next to the previous one."""
        value = raw if self.ref is None else nearest_unwrap(raw, self.ref)
        self.ref = value
        return value

    def unwrap_block(self, raw: NDArray[np.int64]) -> NDArray[np.int64]:
        """Unwrap a block of counter values (wraps inside the block included)."""
        if raw.size == 0:
            return raw
        first = self.unwrap_one(int(raw[0]))
        step = np.diff(raw)
        fix = np.zeros(raw.size, dtype=np.int64)
        if step.size and (step.min() < -(_M // 2) or step.max() > _M // 2):
            k = (step < -(_M // 2)).astype(np.int64) - (step > _M // 2).astype(np.int64)
            fix[1:] = np.cumsum(k) * _M
        out = raw - raw[0] + first + fix
        self.ref = int(out[-1])
        return out

    # ------------------------------------------------------------------ bad entries
    def bad(self, label: str, where: str, msg: str, *, fld: str | None = None) -> None:
        """Raise :class:`FormatError` for a bad payload entry, or skip and flag it (salvage)."""
        if not self.salvage:
            raise FormatError(msg + "; read with salvage=True to skip it",
                              path=label, position=where, field=fld)
        self.issues.append(f"{label}: {where}: {msg}; entry skipped")
        self.partial = True
