"""The per-hole record: one row per drilled (or tapped) hole from drive signals and NC events.

Thesis chapter 5 analyses every use-case hole by hole: the mean spindle current of each of the
2676 holes (Figures 5.2, 5.3), the tool temperature over a set of 6 holes (Figure 5.5) and the
X/Y/Z deviations of each hole (Figures 5.6-5.9). :func:`hole_record` builds that table.

Segmentation
------------
Holes are found from the **Z motion** (works when a recording has no NC events, e.g. the
simulator's streamed wear run): a plunge is a run of downward Z movement; its *feed part* is the
final stretch at the slowest (cutting) speed, its *bottom* the Z minimum. A plunge that begins
inside the hole drilled just before at the same XY (peck drilling, CYCLE83) continues that hole.
**NC events** then add what motion cannot know: the drilling cycle (``CYCLE81`` ... ``CYCLE84``,
``G81`` ... ``G84`` in block texts, ``/_CYCLES_DIR/_CYCLE81`` call events), its reference plane
(the workpiece surface, RFP = 2nd cycle parameter) and the active tool. Without events the
surface is where the spindle current leaves its air-feed level.

**What is a hole.** Every plunge inside a drilling cycle (the cycle call is a hole, loaded or
not). Outside a drilling cycle (or without NC events) a plunge is a hole only when it drills:
X/Y stay where they are from the feed start to the retract and the spindle current leaves its
air level (``cycle`` = ``'plunge'``). A milling entry (plunge, then the contour at depth), a
ramp, a helix or a plunge through air is not a hole; each is named in ``attrs["issues"]``.

References
----------
.. [1] Thesis, Koç University, chapter 4.3 (mean over the first 0.6 s of each cut, Fig. 4.5) and
   chapter 5 (Figures 5.2-5.9).
.. [2] Siemens, SINUMERIK 840D sl Cycles programming manual: CYCLE81(RTP, RFP, SDIS, DP, DPR).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from cnctwin.analysis.segments import centered_mean, spindle_speed_rpm
from cnctwin.exceptions import ConfigError, SignalNotFoundError
from cnctwin.recording import Recording
from cnctwin.spindle import SpindleModel

__all__ = [
    "HOLE_COLUMNS",
    "HoleEvents",
    "HoleRows",
    "Plunge",
    "find_plunges",
    "hole_record",
    "hole_records",
    "holes_from_arrays",
    "holes_path",
    "modal_cycle_call",
    "read_holes",
    "write_holes",
]

HOLE_COLUMNS: dict[str, str] = {
    "hole": "hole index, 0-based, in drilling order [-]",
    "set": "set index (hole // set_size) [-]",
    "position_in_set": "position within the set, 0-based [-]",
    "start_cycle": "first cycle of the feed move of the plunge [-]",
    "cut_start_cycle": "first cycle in the material (Z at or below the surface) [-]",
    "cut_end_cycle": "cycle at which the bottom is reached [-]",
    "end_cycle": "last cycle before the retract starts (dwell included) [-]",
    "start_time": "UTC time of cut_start_cycle",
    "start_s": "cut start, seconds after the first cycle of the first recording [s]",
    "end_s": "bottom reached [s]",
    "extraction_s": "Z back above the surface on the retract (tool out of the hole) [s]",
    "cut_duration_s": "time in the material (feed parts from the surface to the bottom) [s]",
    "x_mm": "programmed X during the cut (median DES_POS) [mm]",
    "y_mm": "programmed Y during the cut [mm]",
    "surface_z_mm": "Z of the workpiece surface used [mm]",
    "surface_source": "'cycle' (RFP of the drilling cycle), 'current' (current onset) or 'feed'",
    "bottom_z_mm": "lowest actual Z (ENC_POS) [mm]",
    "depth_mm": "surface_z_mm - bottom_z_mm [mm]",
    "feed_mm_min": "median feed speed of the feed part [mm/min]",
    "speed_rpm": "median spindle speed during the cut [rpm]",
    "current_mean_a": "mean CURRENT|SP1 during the cut [A]",
    "current_peak_a": "max |CURRENT|SP1| during the cut [A]",
    "current_first_a": "mean CURRENT|SP1 over the first window_s of the cut [A]",
    "torque_first_nm": "mean estimated cutting torque over the first window_s [Nm]",
    "torque_mean_nm": "mean estimated cutting torque over the cut [Nm]",
    "torque_last_nm": "mean estimated cutting torque over the last window_s of the cut (its "
                      "last quarter if that is shorter), where the drill is fully engaged "
                      "[Nm]",
    "energy_j": "cutting energy, integral of torque x omega over the cut [J]",
    "thrust_proxy": "Z-axis load in the cut minus its air-feed level (unit in attrs) [-]",
    "reverse_current_fluct_a": "tapping: std of the sample-to-sample change of CURRENT while "
                               "the spindle runs in reverse to extract the tap (after 0.1 s), "
                               "NaN for other holes [A]",
    "reverse_z_fluct_mm": "tapping: the same of the Z following error (DES_POS - ENC_POS) "
                          "[mm]",
    "dev_{x,y,z}_{mean,maxabs,rms}_mm": "DES_POS - ENC_POS statistics during the cut [mm]",
    "tool": "active tool number (NC events), <NA> without events",
    "cycle": "drilling cycle name (CYCLE81 ...); 'plunge' for a straight Z plunge with "
             "drilling load outside any drilling cycle",
}
"""Columns of :func:`hole_record` with their meaning and unit."""

# a block's optional skip level and block number (``/1 N120``, ``:10`` a main block) before
# its first word
_BLOCK_HEAD = r"^\s*(?:/\d?\s*)?(?:[N:]\d+\s*)?"
_MCALL_ON = re.compile(_BLOCK_HEAD + r"MCALL\s+\S", re.IGNORECASE)
_MCALL_OFF = re.compile(_BLOCK_HEAD + r"MCALL\s*$|\bG80\b", re.IGNORECASE)


def modal_cycle_call(block: str) -> bool | None:
    """What an NC block does to the modal cycle call.

    Parameters
    ----------
    block : str
        The block's text as the control records it (block number and comment included,
        e.g. ``'N120 MCALL ; end of the drilling pattern'``).

    Returns
    -------
    bool or None
        True: a cycle is called modally from here on (``MCALL CYCLE81(...)``); False: the
        modal call is cancelled (a bare ``MCALL``; ``G80`` of the ISO dialect); None: neither.

    Notes
    -----
    SINUMERIK 840D sl, Programming Manual Job Planning, "MCALL": a modal subprogram or cycle
    call stays active for every following block with a path motion until ``MCALL`` without
    a name ends it. The comment (after ``;``) is not read.

    Examples
    --------
    >>> modal_cycle_call("N120 MCALL ; end of the pattern")
    False
    >>> modal_cycle_call("MCALL CYCLE81(10, 0, 2, -20)")
    True
    >>> modal_cycle_call("N130 G0 X10 ; MCALL later") is None
    True
    """
    text = block.split(";", 1)[0]
    if _MCALL_OFF.search(text):
        return False
    if _MCALL_ON.match(text):
        return True
    return None


_CYCLE_RE = re.compile(r"\b(CYCLE8[1-9]|G8[1-9])\b", re.IGNORECASE)
_CALL_RE = re.compile(r"_?(CYCLE8[1-9])", re.IGNORECASE)
_COUNT_RE = re.compile(r"CYCLE8[1-9]", re.IGNORECASE)
_PARAMS_RE = re.compile(r"CYCLE8[1-9]\s*\(([^)]*)\)", re.IGNORECASE)


@dataclass(frozen=True)
class Plunge:
    """Sample indices (row positions in the HF table) of one plunge of the Z axis.

    Attributes
    ----------
    start : int
        First downward sample (rapid approach included).
    feed_start : int
        First sample of the final constant-feed stretch.
    bottom : int
        Sample of the Z minimum.
    end : int
        Last sample before Z moves up again (dwell included).
    feed_mm_s : float
        Median feed speed of the feed stretch [mm/s].
    """

    start: int
    feed_start: int
    bottom: int
    end: int
    feed_mm_s: float


def _runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    starts = np.flatnonzero(d == 1)
    ends = np.flatnonzero(d == -1) - 1
    return list(zip(starts.tolist(), ends.tolist(), strict=True))


def find_plunges(
    z_mm: NDArray[np.float64],
    *,
    fs_hz: float,
    min_speed_mm_s: float = 0.05,
    min_travel_mm: float = 0.5,
    feed_factor: float = 1.5,
) -> list[Plunge]:
    """Plunges of a feed axis: runs of downward motion ending in a feed stretch.

    Parameters
    ----------
    z_mm : numpy.ndarray
        Z position per cycle (preferably the setpoint ``DES_POS``) [mm].
    fs_hz : float
        Sample rate [Hz].
    min_speed_mm_s : float, default 0.05
        Slower movement counts as standstill [mm/s].
    min_travel_mm : float, default 0.5
        Shortest feed travel that counts as a plunge [mm].
    feed_factor : float, default 1.5
        Samples faster than ``feed_factor`` x the feed speed belong to the rapid approach.

    Returns
    -------
    list of Plunge
        A plunge still moving down at the end of the data is left out (incomplete).

    Notes
    -----
    The feed speed of a plunge is the median speed over the last half of its downward run
    (the approach is short and fast, the cut long and slow); the feed stretch is the contiguous
    block of samples not faster than ``feed_factor`` times it that ends at the bottom.
    """
    z = np.asarray(z_mm, dtype=np.float64)
    if not np.isfinite(z).all():
        z = np.asarray(pd.Series(z).interpolate(limit_direction="both"), dtype=np.float64)
    if z.size < 3 or not np.isfinite(z).all():
        return []
    v = np.gradient(z) * fs_hz
    # down-runs separated only by standstill (exact stop between rapid and feed) are one plunge
    merged: list[list[int]] = []
    for s, e in _runs(v < -min_speed_mm_s):
        if merged and not (v[merged[-1][1] + 1 : s] > min_speed_mm_s).any():
            merged[-1][1] = e
        else:
            merged.append([s, e])
    out: list[Plunge] = []
    for s, e in merged:
        if e >= z.size - 2:
            continue  # still moving down when the recording ends: an incomplete plunge
        hi = min(e + 2, z.size)
        bottom = s + int(np.argmin(z[s:hi]))
        speed = -v[s : bottom + 1]
        moving = speed[speed > min_speed_mm_s]
        if moving.size < 3:
            continue
        feed = float(np.median(moving[moving.size // 2 :]))
        if feed <= 0:
            continue
        fast = np.flatnonzero(speed > feed_factor * feed)
        feed_start = s + (int(fast[-1]) + 1 if fast.size else 0)
        feed_start = min(feed_start, bottom)
        if z[feed_start] - z[bottom] < min_travel_mm:
            continue
        up = np.flatnonzero(v[bottom:] > min_speed_mm_s)
        end = bottom + int(up[0]) - 1 if up.size else z.size - 1
        out.append(Plunge(s, feed_start, bottom, max(end, bottom), feed))
    return out


def _event_arrays(ev: pd.DataFrame, *cols: str) -> tuple[Any, ...]:
    """The cycle column (sorted, stable) and the named columns as object arrays (None for a
    missing value): plain arrays, since the event tables are small and pandas' per-call
    overhead (string dtypes, sorting a frame) dominated the per-hole cost at the edge."""
    ec = ev["cycle"].to_numpy(dtype=np.int64)
    order = np.argsort(ec, kind="stable")
    out: list[Any] = [ec[order]]
    for c in cols:
        if c in ev.columns:  # None for NaN, NA and None alike
            out.append(ev[c].to_numpy(dtype=object, na_value=None)[order])  # type: ignore[call-overload]
        else:
            out.append(np.full(len(ec), None, dtype=object))
    return tuple(out)


@dataclass(frozen=True)
class HoleEvents:
    """The NC events a hole row reads, as plain arrays sorted by cycle.

    Attributes
    ----------
    cycle : numpy.ndarray
        Cycle of each event (int64, ascending).
    kind, gcode, path, active_tool : numpy.ndarray
        Object arrays (None where the event has no value): ``block``/``call``/..., the block
        text, the called program path, the active tool number.
    """

    cycle: NDArray[np.int64]
    kind: NDArray[np.object_]
    gcode: NDArray[np.object_]
    path: NDArray[np.object_]
    active_tool: NDArray[np.object_]

    @classmethod
    def from_frame(cls, events: pd.DataFrame) -> HoleEvents:
        """The arrays of an NC event table (:attr:`Recording.events`).

        Parameters
        ----------
        events : pandas.DataFrame
            Event table with a ``cycle`` column; ``kind``, ``gcode``, ``path`` and
            ``active_tool`` are read where present.

        Returns
        -------
        HoleEvents
        """
        if events.empty:
            return _NO_HOLE_EVENTS
        return cls(*_event_arrays(events, "kind", "gcode", "path", "active_tool"))

    @classmethod
    def concat(cls, parts: Sequence[HoleEvents]) -> HoleEvents:
        """Events of consecutive stretches as one (stable order by cycle).

        Parameters
        ----------
        parts : sequence of HoleEvents
            The parts, in stream order.

        Returns
        -------
        HoleEvents
        """
        parts = [e for e in parts if len(e)]
        if not parts:
            return _NO_HOLE_EVENTS
        if len(parts) == 1:
            return parts[0]
        cyc = np.concatenate([e.cycle for e in parts])
        order = np.argsort(cyc, kind="stable")
        return cls(cyc[order], *(np.concatenate([getattr(e, f) for e in parts])[order]
                                 for f in ("kind", "gcode", "path", "active_tool")))

    def until(self, cycle: int) -> HoleEvents:
        """The events at or before ``cycle``.

        Parameters
        ----------
        cycle : int
            Last cycle kept.

        Returns
        -------
        HoleEvents
        """
        k = int(np.searchsorted(self.cycle, cycle, side="right"))
        if k == len(self):
            return self
        return self.take(0, k)

    def take(self, start: int, stop: int | None = None) -> HoleEvents:
        """Events ``start:stop`` by position.

        Parameters
        ----------
        start : int
            First position kept.
        stop : int, optional
            Position after the last kept; default the end.

        Returns
        -------
        HoleEvents
        """
        sl = slice(start, stop)
        return HoleEvents(self.cycle[sl], self.kind[sl], self.gcode[sl], self.path[sl],
                          self.active_tool[sl])

    def __len__(self) -> int:
        return int(self.cycle.size)


_NO_HOLE_EVENTS = HoleEvents(np.empty(0, dtype=np.int64), *(np.empty(0, dtype=object)
                                                            for _ in range(4)))


def _cycle_info(ev: HoleEvents, cycles: NDArray[np.int64]) -> tuple[list[str], list[float]]:
    """Drilling-cycle name and reference plane (RFP) active at each cycle, from NC events."""
    n = len(cycles)
    names = [""] * n
    rfp = [math.nan] * n
    if not len(ev):
        return names, rfp
    # modal state walked in event order
    cur_name, cur_rfp = "", math.nan
    state_name: list[str] = []
    state_rfp: list[float] = []
    for kind, text, path in zip(ev.kind.tolist(), ev.gcode.tolist(), ev.path.tolist(),
                                strict=True):
        if kind == "block":
            t = str(text or "").upper()
            m = _CYCLE_RE.search(t)
            if m:
                cur_name = m.group(1).upper()
                p = _PARAMS_RE.search(t)
                if p:
                    parts = [x.strip() for x in p.group(1).split(",")]
                    try:
                        cur_rfp = float(parts[1]) if len(parts) > 1 and parts[1] else math.nan
                    except ValueError:
                        cur_rfp = math.nan
            elif modal_cycle_call(t) is False:
                cur_name, cur_rfp = "", math.nan
        elif kind == "call":
            m = _CALL_RE.search(str(path or ""))
            if m and not cur_name:
                cur_name = m.group(1).upper()
        state_name.append(cur_name)
        state_rfp.append(cur_rfp)
    idx = np.searchsorted(ev.cycle, cycles, side="right") - 1
    for k, j in enumerate(idx.tolist()):
        if j >= 0:
            names[k] = state_name[j]
            rfp[k] = float(state_rfp[j])
    return names, rfp


def _active_tool(ev: HoleEvents, cycles: NDArray[np.int64]) -> list[int | None]:
    tools = ev.active_tool
    known = np.array([t is not None for t in tools.tolist()], dtype=bool)
    if not known.any():
        return [None] * len(cycles)
    tc, tv = ev.cycle[known], tools[known]
    idx = np.searchsorted(tc, cycles, side="right") - 1
    return [int(tv[j]) if j >= 0 else None for j in idx.tolist()]


def _contact(
    current: NDArray[np.float64], lo: int, hi: int, fs_hz: float
) -> int | None:
    """First sample in [lo, hi] where |I| leaves its air-feed level (None if it never does)."""
    a = np.abs(current[lo : hi + 1])
    if a.size < 10 or not np.isfinite(a).all():
        return None
    k = max(5, min(round(0.1 * fs_hz), a.size // 5))
    smv = centered_mean(a, max(3, round(0.02 * fs_hz)))
    air = float(np.median(smv[:k]))
    noise = 1.4826 * float(np.median(np.abs(a[:k] - np.median(a[:k]))))
    top = float(np.quantile(smv, 0.9))
    thr = max(6.0 * noise, 0.1 * (top - air))
    if top - air <= thr:
        return None
    above = np.flatnonzero(smv - air > thr)
    if not above.size:
        return None
    # walk back to where the rise begins (the threshold is crossed part-way up the ramp)
    k0 = int(above[0])
    floor = max(2.0 * noise, 0.02 * (top - air))
    while k0 > 0 and smv[k0 - 1] - air > floor:
        k0 -= 1
    return lo + k0


_DRILL_LOAD_NM = 0.25
"""Median cutting torque over a plunge's feed part above which it drills when the current's
rise from its air level is not in the data (a plunge that starts in the material, e.g. after
a restart) [Nm]; an uncalibrated spindle model's air offset is ~0.1 Nm."""


def _not_a_drilled_hole(xd: NDArray[np.float64] | None, yd: NDArray[np.float64] | None,
                        lo: int, hi: int, loaded: bool, *, xy_tol_mm: float = 0.01) -> str:
    """Why a plunge outside a drilling cycle is no hole ('' if it is one).

    A drilled hole keeps X/Y from the feed start to the retract and loads the spindle; a
    milling entry moves X/Y at depth (a plunge, then the contour), a ramp or a helix moves
    X/Y while Z goes down, and a plunge through air never leaves the air level of the current.
    """
    for arr, ax in ((xd, "X"), (yd, "Y")):
        if arr is None:
            continue
        seg = arr[lo : hi + 1]
        seg = seg[np.isfinite(seg)]
        if seg.size and float(seg.max() - seg.min()) > xy_tol_mm:
            return (f"the {ax} setpoint moves {float(seg.max() - seg.min()):.3g} mm while Z "
                    "is down (a milling entry, ramp or helix)")
    if not loaded:
        return "no drilling load (the spindle current never leaves its air level)"
    return ""


def _zload(cols: Mapping[str, NDArray[np.float64]], z_axis: str
           ) -> tuple[NDArray[np.float64], str, bool] | None:
    for code, unit in (("TORQUE", "Nm"), ("CURRENT", "A")):
        col = f"{code}|{z_axis}"
        if col in cols:
            return cols[col], f"{col} [{unit}]", True
    des, enc = f"DES_POS|{z_axis}", f"ENC_POS|{z_axis}"
    if des in cols and enc in cols:
        return cols[des] - cols[enc], f"{des} - {enc} (following error) [mm]", False
    return None


def _dev(cols: Mapping[str, NDArray[np.float64]], axis: str, idx: NDArray[np.int64]
         ) -> tuple[float, float, float]:
    des, enc = f"DES_POS|{axis}", f"ENC_POS|{axis}"
    if not (des in cols and enc in cols):
        return (math.nan, math.nan, math.nan)
    d = cols[des][idx] - cols[enc][idx]
    d = d[np.isfinite(d)]
    if d.size == 0:
        return (math.nan, math.nan, math.nan)
    return float(d.mean()), float(np.abs(d).max()), float(np.sqrt(np.mean(d * d)))


@dataclass(frozen=True)
class HoleRows:
    """What :func:`holes_from_arrays` found: one dict per hole and the notes of the table.

    Attributes
    ----------
    rows : list of dict
        One dict per hole with the keys of :data:`HOLE_COLUMNS` (``start_time`` a UTC
        ``pandas.Timestamp``, ``tool`` an int or None, NaN where a value is not known).
    attrs : dict
        ``thrust_source``, ``spindle_model``, ``z_source``, ``event_cycle_calls``,
        ``window_s``, ``set_size`` and ``issues`` (list of str).
    """

    rows: list[dict[str, Any]]
    attrs: dict[str, Any]

    def to_frame(self) -> pd.DataFrame:
        """The rows as the table :func:`hole_record` returns (typed columns, ``attrs``).

        Returns
        -------
        pandas.DataFrame
        """
        ints = ("hole", "set", "position_in_set", "start_cycle", "cut_start_cycle",
                "cut_end_cycle", "end_cycle")
        columns: dict[str, Any] = {}
        for col in _columns():  # one frame, typed as built (astype per column ~0.2 ms each)
            vals: list[Any] = [r[col] for r in self.rows]
            columns[col] = (pd.array(vals, dtype="Int64") if col == "tool"
                            else np.asarray(vals, dtype=np.int64) if col in ints
                            else pd.Series(vals, dtype=object) if not self.rows else vals)
        df = pd.DataFrame(columns)
        df.attrs.update(self.attrs)
        return df


_HOLE_SIGNALS = ("DES_POS", "ENC_POS")


def holes_from_arrays(
    columns: Mapping[str, NDArray[np.float64]],
    cycles: NDArray[np.int64],
    time_ns: NDArray[np.int64],
    *,
    cycle_time_s: float,
    speed_rpm: NDArray[np.float64] | None,
    events: HoleEvents | None = None,
    spindle: str = "SP1",
    z_axis: str = "Z1",
    xy_axes: tuple[str, str] = ("X1", "Y1"),
    model: SpindleModel | None = None,
    window_s: float = 0.6,
    set_size: int = 6,
    first_hole: int = 0,
    origin_ns: int | None = None,
    min_travel_mm: float = 0.5,
    min_speed_rpm: float = 10.0,
    tool_kinds: Mapping[int, str] | None = None,
) -> HoleRows:
    """The per-hole rows from plain arrays: the work of :func:`hole_record` without a
    :class:`~cnctwin.recording.Recording` (the edge runtime calls it on its buffer).

    Parameters
    ----------
    columns : mapping of str to numpy.ndarray
        HF signals by column name, float64, one value per cycle: ``CURRENT|<spindle>`` and
        ``DES_POS|<z_axis>`` or ``ENC_POS|<z_axis>`` at least; ``DES_POS``/``ENC_POS`` of the
        X/Y axes and ``TORQUE``/``CURRENT`` of Z where recorded.
    cycles : numpy.ndarray
        Cycle counter per row (int64).
    time_ns : numpy.ndarray
        UTC time of each row [ns since the epoch] (int64).
    cycle_time_s : float
        Position-control cycle [s].
    speed_rpm : numpy.ndarray or None
        Spindle speed per row [rpm] (gaps filled from the neighbours); None: not recorded,
        torque and energy are NaN (noted in ``issues``).
    events : HoleEvents, optional
        NC events for the drilling cycle, reference plane and tool.
    spindle, z_axis, xy_axes, model, window_s, set_size, first_hole, min_travel_mm, \
min_speed_rpm
        As in :func:`hole_record`.
    origin_ns : int, optional
        UTC time that ``start_s``/``end_s``/``extraction_s`` count from [ns]; default the
        first row.
    tool_kinds : mapping, optional
        T number -> kind from the tool table (``"drill"``, ``"tap"``, ``"end_mill"``): a
        Z plunge outside a drilling cycle by an end mill is not a hole (an entry in
        ``issues`` says so); without it such a plunge is judged by its load and position.

    Returns
    -------
    HoleRows

    Raises
    ------
    SignalNotFoundError
        Without spindle current or Z position.
    ConfigError
        ``set_size`` < 1.
    """
    if set_size < 1:
        raise ConfigError(f"set_size must be >= 1, not {set_size}")
    i_col = f"CURRENT|{spindle}"
    z_des, z_enc = f"DES_POS|{z_axis}", f"ENC_POS|{z_axis}"
    if i_col not in columns or not (z_des in columns or z_enc in columns):
        raise SignalNotFoundError(
            f"the hole rows need {i_col!r} and {z_des!r} or {z_enc!r}; the data has: "
            f"{', '.join(columns)}")
    issues: list[str] = []
    ct = cycle_time_s
    fs = 1.0 / ct
    z_src = z_des if z_des in columns else z_enc
    zm = columns[z_src]
    za = columns.get(z_enc, zm)
    current = columns[i_col]
    if speed_rpm is not None:
        speed = np.asarray(speed_rpm, dtype=np.float64)
        if not np.isfinite(speed).all():
            speed = np.asarray(pd.Series(speed).ffill().bfill().fillna(0.0), dtype=np.float64)
    else:
        speed = np.full(current.size, math.nan)
        issues.append(f"no spindle speed for {spindle}: torque and energy are NaN")
    if model is None:
        model = SpindleModel.from_parameters("thesis_spinner_840dsl")
        model_note = "thesis_spinner_840dsl (default, not calibrated to this machine)"
    else:
        model_note = model.describe()
    with np.errstate(invalid="ignore"):
        torque = model.cutting_torque(current, speed, fs_hz=fs)
    zl = _zload(columns, z_axis)
    ev = events if events is not None else _NO_HOLE_EVENTS
    t0 = int(origin_ns) if origin_ns is not None else (int(time_ns[0]) if len(time_ns) else 0)

    def t_s(k: int) -> float:
        return float(np.float64(int(time_ns[k]) - t0) / 1e9)

    plunges = find_plunges(zm, fs_hz=fs, min_travel_mm=min_travel_mm)
    starts = (cycles[[p.feed_start for p in plunges]] if plunges
              else np.empty(0, dtype=np.int64))
    names, rfps = _cycle_info(ev, starts)
    tools = _active_tool(ev, starts)
    xd = columns.get(f"DES_POS|{xy_axes[0]}")
    yd = columns.get(f"DES_POS|{xy_axes[1]}")

    # group peck plunges into holes: a plunge starting inside the previous hole continues it
    groups: list[list[int]] = []
    for k, p in enumerate(plunges):
        if groups:
            q = plunges[groups[-1][0]]
            same_xy = all(
                arr is None or abs(float(arr[p.feed_start]) - float(arr[q.feed_start])) < 0.01
                for arr in (xd, yd)
            )
            first_top = float(zm[q.feed_start])
            if same_xy and float(zm[p.feed_start]) < first_top - 0.5:
                groups[-1].append(k)
                continue
        groups.append([k])

    rows: list[dict[str, Any]] = []
    for grp in groups:
        first = plunges[grp[0]]
        last = plunges[grp[-1]]
        bottom = min((plunges[i].bottom for i in grp), key=lambda b: float(za[b]))
        name, rfp = names[grp[0]], rfps[grp[0]]
        lo, hi = first.feed_start, bottom
        if math.isfinite(rfp):
            surface, src = rfp, "cycle"
            inside = np.flatnonzero(za[lo : hi + 1] <= rfp)
            cut_start = lo + int(inside[0]) if inside.size else lo
        else:
            c = _contact(current, lo, hi, fs)
            if c is not None:
                cut_start, surface, src = c, float(za[c]), "current"
            else:
                cut_start, surface, src = lo, float(zm[lo]), "feed"
        tool_no = tools[grp[0]]
        if not name and tool_kinds is not None and tool_no is not None and tool_kinds.get(
                int(tool_no)) == "end_mill":
            issues.append(f"Z plunge at cycle {int(cycles[first.feed_start])} outside a "
                          f"drilling cycle is not a hole: T{int(tool_no)} is an end mill "
                          "(tool table)")
            continue
        if not name:
            seg_tq = torque[lo : hi + 1]
            loaded = src == "current" or bool(
                np.isfinite(seg_tq).any() and float(np.nanmedian(seg_tq)) > _DRILL_LOAD_NM)
            why = _not_a_drilled_hole(xd, yd, first.feed_start, last.end, loaded)
            if why:
                issues.append(f"Z plunge at cycle {int(cycles[first.feed_start])} outside a "
                              f"drilling cycle is not a hole: {why}")
                continue
        cut_end = max(hi, cut_start)
        # samples in the material: the feed parts of all plunges of the hole (peck retracts
        # and re-approaches excluded), from the surface on
        parts = []
        deepest = math.inf
        for i in grp:
            seg = np.arange(max(plunges[i].feed_start, cut_start), plunges[i].bottom + 1)
            parts.append(seg[zm[seg] < deepest])  # new material only (not the re-entry)
            deepest = min(deepest, float(zm[plunges[i].bottom]))
        sl = np.concatenate(parts)
        if sl.size == 0:
            sl = np.arange(cut_start, cut_end + 1)
        sp = np.abs(speed[sl])
        sp = sp[np.isfinite(sp)]
        n_med = float(np.median(sp)) if sp.size else math.nan
        if not n_med >= min_speed_rpm:  # NaN (no speed signal): cannot be told from a move
            issues.append(f"plunge at cycle {int(cycles[first.feed_start])} with the spindle "
                          f"at {n_med:.3g} rpm (< min_speed_rpm {min_speed_rpm:g}) is not a "
                          "hole: skipped")
            continue
        h = len(rows)
        nwin = max(1, round(window_s * fs))
        fw = sl[:nwin]
        lw = sl[-min(nwin, max(1, sl.size // 4)):]  # a short cut: its last quarter
        omega = speed[sl] * 2.0 * math.pi / 60.0
        energy = float(np.nansum(torque[sl] * omega) * ct)
        thrust = math.nan
        if zl is not None:
            # feed in air before contact; its first half may still hold the exact-stop ramp
            air = zl[0][lo + (cut_start - lo) // 2 : cut_start]
            air = air[np.isfinite(air)]
            if air.size >= 5:
                # positive = pushing the tool into the part: the Z load (and the lag of the
                # encoder behind the setpoint) grows negative while the axis pushes down
                thrust = -float(np.nanmean(zl[0][sl]) - np.mean(air))
        out_idx = np.flatnonzero(za[last.end:] > surface)
        extraction = last.end + int(out_idx[0]) if out_idx.size else len(za) - 1
        fluct_i, fluct_z = _reverse_fluctuation(current, zm, za, speed, n_med, bottom,
                                                extraction, fs)
        row: dict[str, Any] = {
            "hole": first_hole + h,
            "set": (first_hole + h) // set_size,
            "position_in_set": (first_hole + h) % set_size,
            "start_cycle": int(cycles[first.feed_start]),
            "cut_start_cycle": int(cycles[cut_start]),
            "cut_end_cycle": int(cycles[cut_end]),
            "end_cycle": int(cycles[last.end]),
            "start_time": pd.Timestamp(int(time_ns[cut_start]), unit="ns", tz="UTC"),
            "start_s": t_s(cut_start),
            "end_s": t_s(cut_end),
            "extraction_s": t_s(extraction),
            "cut_duration_s": float(sl.size * ct),
            "x_mm": float(np.median(xd[sl])) if xd is not None else math.nan,
            "y_mm": float(np.median(yd[sl])) if yd is not None else math.nan,
            "surface_z_mm": float(surface),
            "surface_source": src,
            "bottom_z_mm": float(za[bottom]),
            "depth_mm": float(surface - za[bottom]),
            "feed_mm_min": float(first.feed_mm_s * 60.0),
            "speed_rpm": (float(np.nanmedian(speed[sl])) if np.isfinite(speed[sl]).any()
                          else math.nan),
            "current_mean_a": float(np.nanmean(current[sl])),
            "current_peak_a": float(np.nanmax(np.abs(current[sl]))),
            "current_first_a": float(np.nanmean(current[fw])),
            "torque_first_nm": float(np.nanmean(torque[fw])),
            "torque_mean_nm": float(np.nanmean(torque[sl])),
            "torque_last_nm": (float(np.nanmean(torque[lw])) if np.isfinite(torque[lw]).any()
                               else math.nan),
            "energy_j": energy,
            "thrust_proxy": thrust,
            "reverse_current_fluct_a": fluct_i,
            "reverse_z_fluct_mm": fluct_z,
        }
        for ax, tag in ((xy_axes[0], "x"), (xy_axes[1], "y"), (z_axis, "z")):
            m, mx, rms = _dev(columns, ax, sl)
            row[f"dev_{tag}_mean_mm"] = m
            row[f"dev_{tag}_maxabs_mm"] = mx
            row[f"dev_{tag}_rms_mm"] = rms
        row["tool"] = tools[grp[0]]
        row["cycle"] = name or "plunge"
        rows.append(row)
    n_calls = _count_cycle_calls(ev)
    if n_calls and n_calls != len(rows):
        issues.append(f"{n_calls} drilling-cycle calls in the NC events but {len(rows)} holes "
                      "found in the Z motion")
    return HoleRows(rows, {
        "thrust_source": zl[1] if zl is not None else "none",
        "spindle_model": model_note,
        "z_source": z_src,
        "event_cycle_calls": n_calls,
        "window_s": window_s,
        "set_size": set_size,
        "issues": issues,
    })


def hole_record(
    rec: Recording,
    *,
    spindle: str = "SP1",
    z_axis: str = "Z1",
    xy_axes: tuple[str, str] = ("X1", "Y1"),
    model: SpindleModel | None = None,
    window_s: float = 0.6,
    set_size: int = 6,
    first_hole: int = 0,
    time_origin: pd.Timestamp | None = None,
    min_travel_mm: float = 0.5,
    min_speed_rpm: float = 10.0,
    store: bool = True,
    tool_kinds: Mapping[int, str] | None = None,
) -> pd.DataFrame:
    """One row per hole: segmentation, current, torque, energy, thrust, deviations, tool.

    Parameters
    ----------
    rec : Recording
        Recording with ``CURRENT|<spindle>`` and ``DES_POS|<z_axis>`` or ``ENC_POS|<z_axis>``.
    spindle : str, default 'SP1'
        Spindle axis name.
    z_axis : str, default 'Z1'
        Drilling (feed) axis.
    xy_axes : (str, str), default ('X1', 'Y1')
        Lateral axes for the hole position and deviations.
    model : SpindleModel, optional
        Calibrated spindle model for the cutting torque (thesis Eq. 4.4). Default: the thesis
        parameter set ``'thesis_spinner_840dsl'`` (not calibrated to this machine; noted in
        ``attrs["spindle_model"]``).
    window_s : float, default 0.6
        Length of the first window of each cut (thesis §4.3: first 0.6 s) [s].
    set_size : int, default 6
        Holes per set (thesis §5.1).
    first_hole : int, default 0
        Index of the first hole (to continue numbering across files).
    time_origin : pandas.Timestamp, optional
        UTC time that ``start_s``/``end_s``/``extraction_s`` count from; default the first
        cycle of ``rec``.
    min_travel_mm : float, default 0.5
        Shortest feed travel counted as a plunge [mm].
    min_speed_rpm : float, default 10
        A plunge whose median |spindle speed| in the cut is lower is a positioning move, not a
        hole: skipped with an entry in ``attrs["issues"]``; so is a plunge without a spindle
        speed signal (it cannot be told from a positioning move) [rpm].
    store : bool, default True
        Also store the table in ``rec.meta.attrs["holes"]``.
    tool_kinds : mapping, optional
        T number -> kind from the tool table: a plunge of an end mill outside a drilling
        cycle is not a hole (:func:`holes_from_arrays`).

    Returns
    -------
    pandas.DataFrame
        Columns :data:`HOLE_COLUMNS`; ``attrs`` hold ``thrust_source``, ``spindle_model``,
        ``z_source``, ``event_cycle_calls`` and ``issues`` (oddities seen).

    Raises
    ------
    SignalNotFoundError
        Without spindle current or Z position.

    Notes
    -----
    Cutting torque ``tau_c = Kt I - B n - tau_f sign(n) - J dOmega/dt`` (thesis Eq. 3.1/4.4);
    energy ``E = sum(tau_c * omega) * dt`` with ``omega = 2 pi n / 60`` over the cut (surface
    to bottom). The thrust proxy is the mean Z-axis torque (or current, or following error when
    the drive values are not recorded) in the cut minus its mean during the feed in air just
    before contact, which removes gravity, friction and the velocity-proportional lag.
    """
    i_col = f"CURRENT|{spindle}"
    if not rec.has(i_col):
        raise SignalNotFoundError(
            f"hole_record needs {i_col!r}; the recording has: {', '.join(rec.columns)}"
        )
    z_des, z_enc = f"DES_POS|{z_axis}", f"ENC_POS|{z_axis}"
    if not (rec.has(z_des) or rec.has(z_enc)):
        raise SignalNotFoundError(
            f"hole_record segments holes from the Z motion and needs {z_des!r} or {z_enc!r}; "
            f"pass z_axis=... (the recording has: {', '.join(rec.columns)})"
        )
    names = [i_col, f"TORQUE|{z_axis}", f"CURRENT|{z_axis}",
             *(f"{c}|{a}" for a in (*xy_axes, z_axis) for c in _HOLE_SIGNALS)]
    cols = {c: rec.hf[c].to_numpy(dtype=np.float64) for c in names if rec.has(c)}
    try:
        speed: NDArray[np.float64] | None = spindle_speed_rpm(rec, spindle)[0]
    except SignalNotFoundError:
        speed = None
    t_ns = rec.hf["time"].to_numpy(dtype="datetime64[ns]").view(np.int64)
    origin = (None if time_origin is None
              else int(pd.Timestamp(time_origin).as_unit("ns").value))
    found = holes_from_arrays(cols, rec.cycles, t_ns, cycle_time_s=rec.meta.cycle_time_s,
                              speed_rpm=speed, events=HoleEvents.from_frame(rec.events),
                              spindle=spindle, z_axis=z_axis, xy_axes=xy_axes, model=model,
                              window_s=window_s, set_size=set_size, first_hole=first_hole,
                              origin_ns=origin, min_travel_mm=min_travel_mm,
                              min_speed_rpm=min_speed_rpm, tool_kinds=tool_kinds)
    df = found.to_frame()
    if store:
        rec.meta.attrs["holes"] = df
    return df


def _columns() -> list[str]:
    cols = [c for c in HOLE_COLUMNS if not c.startswith("dev_") and c not in ("tool", "cycle")]
    for tag in ("x", "y", "z"):
        cols += [f"dev_{tag}_mean_mm", f"dev_{tag}_maxabs_mm", f"dev_{tag}_rms_mm"]
    return [*cols, "tool", "cycle"]


def _count_cycle_calls(ev: HoleEvents) -> int:
    return sum(1 for k, p in zip(ev.kind.tolist(), ev.path.tolist(), strict=True)
               if k == "call" and p is not None and _COUNT_RE.search(str(p)))


def _reverse_fluctuation(current: NDArray[np.float64], z_des: NDArray[np.float64],
                         z_enc: NDArray[np.float64], speed: NDArray[np.float64],
                         n_cut: float, bottom: int, extraction: int, fs: float
                         ) -> tuple[float, float]:
    """Fluctuation of the current and of the Z following error while a tap is extracted with
    the spindle reversed (thesis Fig. 5.10: a loose tap stick-slips there); NaN without a
    reversal of at least 0.2 s after its first 0.1 s and after the reversal's current
    transient."""
    seg = np.arange(bottom, extraction + 1)
    with np.errstate(invalid="ignore"):
        rev = seg[speed[seg] * np.sign(n_cut) < -1.0]
    skip = round(0.1 * fs)
    rev = rev[skip:]
    if rev.size < round(0.2 * fs) or not np.all(np.diff(rev) == 1):
        if rev.size >= round(0.2 * fs):  # the longest run only
            runs = np.split(rev, np.flatnonzero(np.diff(rev) != 1) + 1)
            rev = max(runs, key=len)
        if rev.size < round(0.2 * fs):
            return math.nan, math.nan
    # the reversal's own transient (the spindle brakes and turns at its current limit, in
    # a deep or hard hole longer than the 0.1 s skipped): cut off where the current is last
    # far (8 robust spreads of the settled second half) from its settled level in the first
    # half, so only the extraction itself is judged
    c = current[rev]
    half = c[c.size // 2:]
    half = half[np.isfinite(half)]
    if half.size:
        ref = float(np.median(half))
        spread = 1.4826 * float(np.median(np.abs(half - ref)))
        with np.errstate(invalid="ignore"):
            far = np.flatnonzero(np.abs(c[:c.size // 2] - ref) > 8.0 * spread + 1e-9)
        if far.size:
            rev = rev[int(far[-1]) + 1 + round(0.02 * fs):]
            if rev.size < round(0.2 * fs):
                return math.nan, math.nan
    fi = float(np.nanstd(np.diff(current[rev])))
    fz = float(np.nanstd(np.diff(z_des[rev] - z_enc[rev]))) if z_des is not z_enc else math.nan
    return fi, fz


def hole_records(
    recordings: Sequence[Recording],
    *,
    spindle: str = "SP1",
    z_axis: str = "Z1",
    xy_axes: tuple[str, str] = ("X1", "Y1"),
    model: SpindleModel | None = None,
    window_s: float = 0.6,
    set_size: int = 6,
) -> pd.DataFrame:
    """:func:`hole_record` over several recordings in time order (e.g. one file per set).

    Hole numbers continue across the recordings and all times count from the first cycle of
    the earliest recording. Each recording also keeps its own rows in ``meta.attrs["holes"]``.

    Parameters
    ----------
    recordings : sequence of Recording
        Recordings of one machine and tool, any order (sorted by their first time).
    spindle : str, default 'SP1'
        Spindle axis name.
    z_axis : str, default 'Z1'
        Drilling (feed) axis.
    xy_axes : (str, str), default ('X1', 'Y1')
        Lateral axes for the hole position and deviations.
    model : SpindleModel, optional
        Calibrated spindle model; default the thesis parameter set (noted in the attrs).
    window_s : float, default 0.6
        Length of the first window of each cut [s].
    set_size : int, default 6
        Holes per set.

    Returns
    -------
    pandas.DataFrame
        One row per hole (columns of :func:`hole_record`).
    """
    if not recordings:
        raise ConfigError("hole_records needs at least one recording")
    recs = sorted(recordings, key=lambda r: pd.Timestamp(r.hf["time"].iloc[0]))
    origin = pd.Timestamp(recs[0].hf["time"].iloc[0])
    parts = []
    n = 0
    issues: list[str] = []
    for r in recs:
        df = hole_record(r, spindle=spindle, z_axis=z_axis, xy_axes=xy_axes, model=model,
                         window_s=window_s, set_size=set_size, first_hole=n, time_origin=origin)
        parts.append(df)
        issues += df.attrs.get("issues", [])
        n += len(df)
    out = pd.concat(parts, ignore_index=True)
    out.attrs.update({**parts[0].attrs, "issues": issues,
                      "event_cycle_calls": sum(p.attrs["event_cycle_calls"] for p in parts)})
    return out


def holes_path(recording_path: str | PathLike[str]) -> Path:
    """Where the hole table of a recording file goes: ``<name>.holes.parquet`` beside it.

    Parameters
    ----------
    recording_path : str or path-like
        The recording file or directory.

    Returns
    -------
    pathlib.Path
        ``<recording>.holes.parquet`` beside it.
    """
    p = Path(recording_path)
    return p.with_name(p.name.split(".")[0] + ".holes.parquet")


def write_holes(holes: pd.DataFrame, path: str | PathLike[str]) -> Path:
    """Write a hole table to Parquet (attrs kept as JSON in the file metadata).

    Parameters
    ----------
    holes : pandas.DataFrame
        Output of :func:`hole_record`.
    path : str or path-like
        Target file; use :func:`holes_path` to put it beside the recording.

    Returns
    -------
    pathlib.Path
    """
    import json

    import pyarrow as pa
    import pyarrow.parquet as pq

    p = Path(path)
    table = pa.Table.from_pandas(holes, preserve_index=False)
    meta = dict(table.schema.metadata or {})
    meta[b"cnctwin.holes"] = json.dumps(holes.attrs, default=str).encode()
    pq.write_table(table.replace_schema_metadata(meta), p)
    return p


def read_holes(path: str | PathLike[str]) -> pd.DataFrame:
    """Read a hole table written by :func:`write_holes` (attrs restored).

    Parameters
    ----------
    path : str or path-like
        A file written by :func:`write_holes`.

    Returns
    -------
    pandas.DataFrame
        The hole table with its attrs.
    """
    import json

    import pyarrow.parquet as pq

    table = pq.read_table(Path(path))
    df = table.to_pandas()
    raw = (table.schema.metadata or {}).get(b"cnctwin.holes")
    if raw:
        df.attrs.update(json.loads(raw))
    return df
