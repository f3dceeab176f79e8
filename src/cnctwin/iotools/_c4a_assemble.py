"""Capture4Analysis reader, assembly of a run: metadata, time anchors, the HF table.

The parts of the files of a run (:class:`~cnctwin.iotools._c4a_document.FilePart`) become one
:class:`~cnctwin.recording.Recording`: header fields go to ``meta.attrs``, the ``Initial`` and
``HFTimestamp`` anchors give the time axis, HF blocks are concatenated (columns in the first
file's order, later files mapped by name), sorted by cycle with duplicate cycles keeping the
first arrival, and every repair is written to ``meta.issues``. Private to
:mod:`cnctwin.iotools.capture4analysis`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from cnctwin.iotools._c4a_document import FilePart
from cnctwin.iotools._c4a_format import parse_times, to_float
from cnctwin.iotools._c4a_frames import (
    drop_repeated_boundary_event,
    events_frame,
    lf_frame,
    parse_job_description,
)
from cnctwin.iotools._c4a_state import ReadState, nearest_unwrap, opt_int
from cnctwin.recording import (
    CYCLE_COUNTER_MODULUS,
    Recording,
    RecordingMeta,
    cycles_to_time,
    find_gaps,
)

__all__ = ["assemble"]

_M = CYCLE_COUNTER_MODULUS
_KNOWN_HEADER = frozenset({
    "Version", "Format", "Description", "MachineInfo", "JobDescription", "SignalListHFData",
    "SignalListLFData", "SignalListExternalData", "TimeStamp", "CycleTimeMs", "Initial",
    "Metadata",
})


def assemble(parts: list[FilePart], reader: ReadState, files: list[str]) -> Recording:
    """One :class:`~cnctwin.recording.Recording` from the parts of a run, in file order."""
    issues = reader.issues
    attrs: dict[str, Any] = {}
    machine, cycle_time_s = _header_attrs(parts, issues, attrs)
    anchors = _time_anchors(parts, cycle_time_s, issues, attrs)
    names, cycles, values = _hf_block(parts, issues)
    gaps = find_gaps(cycles)
    for g in gaps:
        issues.append(
            f"cycle counter gap: {g.missing} cycles missing between {g.after_cycle} and "
            f"{g.before_cycle} ({g.missing * cycle_time_s:.3f} s)"
        )
    wraps = int(cycles[-1] // _M - cycles[0] // _M) if cycles.size else 0
    if wraps:
        issues.append(f"cycle counter wrapped {wraps} time(s) at 2**31; unwrapped")
    if reader.string_conversions:
        total = sum(reader.string_conversions.values())
        declared = [n for p in parts if p.columns for n in p.columns.declared_string]
        issues.append(
            f"{total} HF values given as strings converted to float (columns "
            f"{', '.join(sorted(reader.string_conversions))}"
            f"{'; declared STRING: ' + ', '.join(sorted(set(declared))) if declared else ''})"
        )
    if reader.nulls:
        issues.append(
            f"{sum(reader.nulls.values())} HF values were null, kept as NaN (columns "
            f"{', '.join(sorted(reader.nulls))})"
        )

    hf = pd.DataFrame(values.T, index=pd.Index(cycles, name="cycle"), columns=names, copy=False)
    hf.insert(
        0, "time", cycles_to_time(cycles, anchors, cycle_time_s=cycle_time_s, gaps=gaps)
    )

    # events (repeated boundary event dropped) and LF
    events: list[dict[str, Any]] = []
    for i_part, p in enumerate(parts):
        if i_part > 0:
            drop_repeated_boundary_event(parts[i_part - 1].events, p.events, p.label, issues)
    for p in parts:
        events.extend(p.events)
    lf = [e for p in parts for e in p.lf]
    lf_df = lf_frame(lf, anchors, cycle_time_s, issues, attrs, gaps)
    ev_df = events_frame(events, issues)

    axis_map = dict(sorted(reader.seen_axes.items()))
    meta = RecordingMeta(
        machine=machine,
        cycle_time_s=cycle_time_s,
        axis_map=axis_map,
        source_files=files,
        source_format="capture4analysis",
        time_anchors=anchors,
        gaps=gaps,
        wraps=wraps,
        issues=issues,
        partial=reader.partial,
        attrs=attrs,
    )
    return Recording(hf, lf=lf_df, events=ev_df, meta=meta)


def _header_attrs(parts: list[FilePart], issues: list[str], attrs: dict[str, Any]
                  ) -> tuple[str, float]:
    """Fill ``attrs`` from the first header and the footers; return (machine, cycle time [s])."""
    header = parts[0].header
    cycle_ms = header.get("CycleTimeMs", 2)
    cycle_f = to_float(cycle_ms)
    if cycle_f is None or cycle_f <= 0:
        issues.append(f"Header.CycleTimeMs {cycle_ms!r} unusable; assumed 2 ms")
        cycle_f = 2.0
    cycle_time_s = cycle_f / 1000.0
    machine_info = header.get("MachineInfo") or {}
    machine = str(machine_info.get("MachineName", "")) if isinstance(machine_info, dict) else ""
    attrs["version"] = header.get("Version")
    attrs["format"] = header.get("Format")
    attrs["description"] = header.get("Description")
    attrs["machine_info"] = machine_info
    attrs["job_description"] = parse_job_description(header.get("JobDescription"), issues)
    attrs["header_timestamp"] = header.get("TimeStamp")
    attrs["initial"] = header.get("Initial")
    attrs["signal_list_hf"] = header.get("SignalListHFData")
    attrs["signal_list_lf"] = header.get("SignalListLFData")
    attrs["signal_list_external"] = header.get("SignalListExternalData")
    attrs["header_metadata"] = header.get("Metadata")
    extra_header = {k: v for k, v in header.items() if k not in _KNOWN_HEADER}
    if extra_header:
        attrs["header_other"] = extra_header
        issues.append(f"header fields not interpreted, kept in meta.attrs['header_other']: "
                      f"{', '.join(extra_header)}")
    attrs["footers"] = [p.footer for p in parts]
    for p in parts:
        errs = (p.footer or {}).get("ErrorMessages")
        if errs:
            issues.append(f"{p.label}: recorder reported errors in the Footer: {errs}")
    other: dict[str, list[Any]] = {}
    for p in parts:
        for k, v in p.other.items():
            other.setdefault(k, []).extend(v)
    if other:
        attrs["payload_other"] = other
        for k, v in other.items():
            issues.append(
                f"payload key {k!r} ({len(v)} entries) not interpreted; kept in "
                f"meta.attrs['payload_other'][{k!r}]"
            )
    return machine, cycle_time_s


def _time_anchors(parts: list[FilePart], cycle_time_s: float, issues: list[str],
                  attrs: dict[str, Any]) -> list[tuple[int, pd.Timestamp]]:
    """Time anchors: ``Initial`` first, then the ``HFTimestamp`` entries in arrival order."""
    raw_anchors: list[tuple[int, str]] = []
    first = parts[0]
    initial = first.header.get("Initial")
    c0: Any = opt_int(initial.get("HFProbeCounter")) if isinstance(initial, dict) else pd.NA
    if c0 is not pd.NA and isinstance(initial, dict) and "Time" in initial:
        ref = int(first.cycles[0]) if first.cycles.size else int(c0)
        raw_anchors.append((nearest_unwrap(int(c0), ref), str(initial["Time"])))
    elif initial is not None:
        issues.append(f"Header.Initial {initial!r} has no integer HFProbeCounter and Time; "
                      "not used as a time anchor")
    for p in parts:
        raw_anchors.extend(p.anchors)
    anchors: list[tuple[int, pd.Timestamp]] = []
    if raw_anchors:
        try:
            times = parse_times([t for _, t in raw_anchors])
        except (ValueError, TypeError):
            anchors = _parse_anchors_one_by_one(raw_anchors, issues)
        else:
            anchors = [(c, t) for (c, _), t in zip(raw_anchors, times, strict=True)]
        if not anchors:
            issues.append("no time anchor could be parsed; times start at the Unix epoch")
    else:
        issues.append("no Initial/HFTimestamp time anchors; times start at the Unix epoch")
    if len(anchors) > 1:
        step_ns = round(cycle_time_s * 1e9)
        a_c = np.array([a[0] for a in anchors], dtype=np.int64)
        a_ns = np.array([a[1].value for a in anchors], dtype=np.int64)
        off = a_ns - (a_c - a_c[0]) * step_ns
        spread_ms = float(off.max() - off.min()) / 1e6
        attrs["anchor_spread_ms"] = spread_ms
        if spread_ms > 50.0:
            med = np.median(off)
            far = np.abs(off - med) > 25e6
            issues.append(
                f"time anchors disagree with the cycle counter by up to {spread_ms / 1e3:.3f} s: "
                f"{int(far.sum())} of {len(anchors)} anchors (cycles {int(a_c[far].min())}.."
                f"{int(a_c[far].max())}) are off the median by "
                f"{float(np.median(off[far] - med)) / 1e9:+.3f} s; sections between "
                "counter gaps are timed by their own anchors where time stays monotonic, else the "
                "counter with the median offset is the clock (wall clock stepped, or the counter "
                "jumped)"
            )
    return anchors


def _parse_anchors_one_by_one(raw: list[tuple[int, str]], issues: list[str]
                              ) -> list[tuple[int, pd.Timestamp]]:
    """Parse anchors singly, keep the good ones and name the bad ones in ``issues``."""
    good: list[tuple[int, pd.Timestamp]] = []
    bad: list[str] = []
    for c, t in raw:
        try:
            good.append((c, parse_times([t])[0]))
        except (ValueError, TypeError):
            bad.append(f"{t!r} at cycle {c}")
    shown = ", ".join(bad[:5]) + (" ..." if len(bad) > 5 else "")
    issues.append(f"{len(bad)} of {len(raw)} time anchors are not ISO 8601 times and were not "
                  f"used: {shown}")
    return good


def _hf_block(parts: list[FilePart], issues: list[str]
              ) -> tuple[list[str], NDArray[np.int64], NDArray[np.float64]]:
    """Concatenated HF block of the run: (column names, cycles, values columns x rows).

    Columns in the first file's order, later files mapped by name (NaN where a file lacks
    one); rows sorted by cycle, a duplicate cycle keeps its first arrival.
    """
    names: list[str] = []
    for p in parts:
        if p.columns is not None:
            for n in p.columns.names:
                if n not in names:
                    names.append(n)
    cyc_parts = []
    val_parts = []
    for p in parts:
        if p.columns is None or p.cycles.size == 0:
            continue
        if p.columns.names == names:
            val_parts.append(p.values)
        else:
            block = np.full((len(names), p.cycles.size), np.nan)
            pos = {n: i for i, n in enumerate(p.columns.names)}
            missing = [n for n in names if n not in pos]
            for i, n in enumerate(names):
                if n in pos:
                    block[i] = p.values[pos[n]]
            if missing:
                issues.append(f"{p.label}: columns {', '.join(missing)} absent; NaN there")
            val_parts.append(block)
        cyc_parts.append(p.cycles)
    if cyc_parts:
        cycles = cyc_parts[0] if len(cyc_parts) == 1 else np.concatenate(cyc_parts)
        values = val_parts[0] if len(val_parts) == 1 else np.concatenate(val_parts, axis=1)
    else:
        cycles = np.empty(0, dtype=np.int64)
        values = np.empty((len(names), 0))
    for p in parts:  # free memory early
        p.values = np.empty((0, 0))
    if cycles.size > 1 and not bool(np.all(np.diff(cycles) > 0)):
        order = np.argsort(cycles, kind="stable")
        n_moved = int(np.count_nonzero(order != np.arange(order.size)))
        cycles = cycles[order]
        values = values[:, order]
        if n_moved:
            issues.append(f"HF rows arrived out of order; {n_moved} rows sorted by cycle")
        dup = np.flatnonzero(np.diff(cycles) == 0) + 1
        if dup.size:
            same = bool(np.array_equal(values[:, dup], values[:, dup - 1], equal_nan=True))
            keep = np.ones(cycles.size, dtype=bool)
            keep[dup] = False
            issues.append(
                f"{dup.size} duplicate HF rows (same cycle, e.g. {int(cycles[dup[0]])}, "
                f"{'identical' if same else 'DIFFERENT'} values): kept the first arrival"
            )
            cycles = cycles[keep]
            values = values[:, keep]
    return names, cycles, values
