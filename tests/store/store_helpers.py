"""Synthetic recordings with closed-form values for the store tests (a plain module so test
files can import it: ``import store_helpers``)."""

from __future__ import annotations

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike

from cnctwin.recording import (
    ExternalChannel,
    Recording,
)

# ---------------------------------------------------------------------------- synthetic data
CURRENT_AMPLITUDE_A = 3.0
CURRENT_FREQ_HZ = 5.0
FEED_MM_PER_CYCLE = 0.01


def current_a(cycles: np.ndarray, *, cycle_time_s: float = 0.002) -> np.ndarray:
    """The synthetic spindle current: 3 A sine at 5 Hz of the cycle counter time [A]."""
    return CURRENT_AMPLITUDE_A * np.sin(2 * np.pi * CURRENT_FREQ_HZ * cycles * cycle_time_s)


def position_mm(cycles: np.ndarray) -> np.ndarray:
    """The synthetic X position: 0.01 mm per cycle [mm]."""
    return FEED_MM_PER_CYCLE * cycles.astype(np.float64)


def make_recording(
    *,
    machine: str,
    start: str,
    n: int,
    first_cycle: int = 1_000,
    gap: tuple[int, int] | None = None,
    extra: bool = False,
) -> Recording:
    """A recording with CURRENT|SP1, ENC_POS|X1, ENC_POS|Y1 (and events/LF/issues if extra).

    ``gap=(i, k)`` removes ``k`` cycles after row ``i``.
    """
    cycles = np.arange(first_cycle, first_cycle + n, dtype=np.int64)
    if gap is not None:
        i, k = gap
        cycles = np.concatenate([cycles[:i], cycles[i:] + k])
    signals: dict[str, ArrayLike] = {
        "CURRENT|SP1": current_a(cycles),
        "ENC_POS|X1": position_mm(cycles),
        "ENC_POS|Y1": -position_mm(cycles),
    }
    rec = Recording.from_arrays(
        cycles, signals, start_time=start, machine=machine, axis_map={1: "X1", 2: "Y1", 6: "SP1"}
    )
    rec.meta.source_files = [f"/data/{machine}/{start[:10]}.json"]
    if extra:
        c = rec.cycles
        rec.events = pd.DataFrame(
            {
                "cycle": [int(c[3]), int(c[10]), int(c[-1])],
                "kind": ["block", "call", "block"],
                "channel": pd.array([1, 1, None], dtype="Int64"),
                "seek_offset": pd.array([39, 390, 41], dtype="Int64"),
                "gcode": ["M17", None, "G1 X10 F400"],
                "ipo_gcode": ["G0", None, "G1"],
                "selected_tool": pd.array([6, None, 6], dtype="Int64"),
                "active_tool": pd.array([6, None, 6], dtype="Int64"),
                "path": [None, "/_CUTTING", None],
                "call_stack_level": pd.array([None, 2, None], dtype="Int64"),
            }
        )
        t = rec.hf["time"]
        rec.lf = pd.DataFrame(
            {
                "cycle": [int(c[0]), int(c[0]), int(c[-1])],
                "time": [t.iloc[0], t.iloc[0], t.iloc[-1]],
                "signal": ["/Channel/State/actToolIdent", "MOTOR_TEMP|SP1", "MOTOR_TEMP|SP1"],
                "value": [np.nan, 41.5, 42.25],
                "text": ["182437", "41.5", "42.25"],
            }
        )
        rec.meta.issues.extend(["filled empty axis field of CURRENT|6 from the axis map",
                                "removed 1 duplicate block event"])
        rec.meta.partial = True
        rec.meta.attrs = {"header": {"RecorderVersion": "3.1.0-36"}, "job": ["a", "b"]}
        rec.external["dynamometer"] = ExternalChannel(
            name="dynamometer",
            data=pd.DataFrame(
                {"torque_nm": [0.1, 0.2, 0.4]}, index=pd.Index([0.0, 0.5, 1.0], name="time_s")
            ),
            units={"torque_nm": "Nm"},
            fs_hz=2.0,
            offset_s=0.25,
            drift_ppm=12.0,
            aligned=True,
            source="dyn.csv",
        )
    return rec
