"""Capture4Analysis reader, the long tables: NC events, LF values, the job description.

Block and call events (``HFBlockEvent``, ``HFCallEvent``) become the events table of
:data:`~cnctwin.recording.EVENT_COLUMNS` (fields outside that schema are kept as extra
columns); LF values are aligned by ``HFProbeCounter`` and their own wall-clock ``timestamp``
is kept in ``meta.attrs["lf_wall_clock"]``. Private to :mod:`cnctwin.iotools.capture4analysis`.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pandas as pd

from cnctwin.iotools._c4a_format import parse_times, to_float
from cnctwin.iotools._c4a_state import opt_int
from cnctwin.recording import EVENT_COLUMNS, CounterGap, cycles_to_time, empty_lf

__all__ = [
    "drop_repeated_boundary_event",
    "events_frame",
    "lf_frame",
    "parse_job_description",
]

_BLOCK_FIELDS = {
    "HFProbeCounter": "cycle",
    "Channel": "channel",
    "SeekOffset": "seek_offset",
    "SelectedTool": "selected_tool",
    "ActiveTool": "active_tool",
    "GCode": "gcode",
    "IpoGC": "ipo_gcode",
    "ipoReadError": "ipo_read_error",
    "laBuf": "la_buf",
}
_CALL_FIELDS = {
    "HFProbeCounter": "cycle",
    "Channel": "channel",
    "SeekOffset": "seek_offset",
    "CallStackLevel": "call_stack_level",
    "Path": "path",
}
_INT_EVENT_COLUMNS = (
    "channel", "seek_offset", "selected_tool", "active_tool", "call_stack_level", "la_buf",
)
_EXTRA_EVENT_COLUMNS = ("ipo_read_error", "la_buf")
"""Block-event fields kept beside :data:`~cnctwin.recording.EVENT_COLUMNS`."""


def parse_job_description(items: Any, issues: list[str]) -> dict[str, Any]:
    """``Header.JobDescription`` (a list of ``"key": value`` fragments) as one dict."""
    out: dict[str, Any] = {}
    if items is None:
        return out
    if not isinstance(items, list):
        issues.append("Header.JobDescription is not a list of fragments; kept as item0")
        out["item0"] = items
        return out
    for k, s in enumerate(items):
        if not isinstance(s, str):
            out[f"item{k}"] = s
            continue
        try:
            part = json.loads("{" + s + "}")
        except json.JSONDecodeError:
            issues.append(f"Header.JobDescription[{k}] is not a JSON fragment; kept as text")
            out[f"item{k}"] = s
            continue
        out.update(part)
    return out


def events_frame(events: list[dict[str, Any]], issues: list[str]) -> pd.DataFrame:
    """The events table, sorted by cycle (stable: arrival order within a cycle)."""
    cols: dict[str, list[Any]] = {c: [] for c in (*EVENT_COLUMNS, *_EXTRA_EVENT_COLUMNS)}
    unknown: dict[str, list[Any]] = {}
    for i, ev in enumerate(events):
        kind = ev["__kind"]
        mapping = _BLOCK_FIELDS if kind == "block" else _CALL_FIELDS
        row: dict[str, Any] = {"cycle": ev["__cycle"], "kind": kind}
        for key, value in ev.items():
            if key.startswith("__") or key == "HFProbeCounter":
                continue
            col = mapping.get(key)
            if col is None:
                unknown.setdefault(key, [None] * i).append(value)
                continue
            row[col] = value
        for lst in unknown.values():
            if len(lst) < i + 1:
                lst.extend([None] * (i + 1 - len(lst)))
        for c, lst in cols.items():
            lst.append(row.get(c))
    if unknown:
        issues.append(
            f"event fields not in the event schema kept as extra columns: {', '.join(unknown)}"
        )
    frame: dict[str, Any] = {}
    for c, lst in cols.items():
        if c == "cycle":
            frame[c] = pd.Series(lst, dtype="int64")
        elif c in _INT_EVENT_COLUMNS:
            frame[c] = pd.Series([opt_int(v) for v in lst], dtype="Int64")
        else:
            frame[c] = pd.Series(lst, dtype="object")
    for key, lst in unknown.items():
        frame[key] = pd.Series(lst + [None] * (len(events) - len(lst)), dtype="object")
    df = pd.DataFrame(frame)
    if len(df):
        df = df.sort_values("cycle", kind="stable").reset_index(drop=True)
    return df


def lf_frame(
    lf: list[dict[str, Any]], anchors: list[tuple[int, pd.Timestamp]], cycle_time_s: float,
    issues: list[str], attrs: dict[str, Any], gaps: list[CounterGap],
) -> pd.DataFrame:
    """The LF table (``cycle, time, signal, value, text``) timed by the HF clock."""
    if not lf:
        return empty_lf()
    order = sorted(range(len(lf)), key=lambda i: lf[i]["__cycle"])
    lf = [lf[i] for i in order]
    cycles = np.array([e["__cycle"] for e in lf], dtype=np.int64)
    values = np.full(len(lf), np.nan)
    texts: list[Any] = []
    n_str = n_text = 0
    types: dict[str, str] = {}
    for i, e in enumerate(lf):
        v = e.get("value")
        if isinstance(v, str):
            n_str += 1
            f = to_float(v)
            texts.append(v)
        else:
            f = to_float(v)
            texts.append(None if v is None else str(v))
        if f is None:
            n_text += 1
        else:
            values[i] = f
        addr = str(e.get("address", ""))
        if "value_type" in e:
            types.setdefault(addr, str(e["value_type"]))
    time = cycles_to_time(cycles, anchors, cycle_time_s=cycle_time_s, gaps=gaps)
    df = pd.DataFrame({
        "cycle": cycles,
        "time": pd.Series(time, dtype="datetime64[ns, UTC]"),
        "signal": pd.Series([str(e.get("address", "")) for e in lf], dtype="object"),
        "value": values,
        "text": pd.Series(texts, dtype="object"),
    })
    if n_str:
        issues.append(
            f"LF values arrive as JSON strings: {n_str - n_text} of {len(lf)} converted to float, "
            f"{n_text} non-numeric kept as text only (value NaN)"
        )
    attrs["lf_value_types"] = types
    wall = [e.get("timestamp") for e in lf]
    attrs["lf_wall_clock"] = wall
    stamps = [w for w in wall if isinstance(w, str)]
    if stamps and anchors:
        try:
            lf_ns = parse_times(stamps).asi8
        except (ValueError, TypeError):
            issues.append("LF timestamps could not be parsed; kept as text in attrs")
        else:
            hf_ns = np.asarray(time.asi8)[[i for i, w in enumerate(wall) if isinstance(w, str)]]
            offset_s = float(np.median(lf_ns - hf_ns)) / 1e9
            attrs["lf_wall_clock_offset_s"] = offset_s
            issues.append(
                f"LF values aligned by HFProbeCounter; their own wall-clock timestamps differ "
                f"from the HF clock by {offset_s:+.3f} s (median; kept in "
                "meta.attrs['lf_wall_clock'])"
            )
    return df


def drop_repeated_boundary_event(
    prev: list[dict[str, Any]], nxt: list[dict[str, Any]], label: str, issues: list[str]
) -> None:
    """Remove from ``nxt`` the block event Siemens repeats at the start of a chained file."""
    last_prev = next((e for e in reversed(prev) if e["__kind"] == "block"), None)
    first_next = next((i for i, e in enumerate(nxt) if e["__kind"] == "block"), None)
    if last_prev is None or first_next is None:
        return

    def core(e: dict[str, Any]) -> dict[str, Any]:
        return {k: v for k, v in e.items() if k not in ("__where",)}

    if core(last_prev) == core(nxt[first_next]):
        ev = nxt.pop(first_next)
        issues.append(
            f"{label}: removed the repeated block event at cycle {ev['__cycle']} "
            f"({ev.get('GCode')!r}) at the start of the file (Siemens repeats the last block "
            "event of the previous file)"
        )
