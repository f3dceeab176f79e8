"""Fleet analyses, one task per (machine, day) partition of a store.

Each ``*_partition`` function is the whole work of one task: it opens the store (read-only),
loads the partition's recordings, runs the single-machine analysis of cnctwin on them and
returns a small table. The same functions run in one process (:func:`run_job` with
``client=None``) or on a Dask cluster, so both give the same rows.

A recording belongs to the UTC day its first cycle is in. A recording that cannot be loaded
or analysed is reported in the partition's ``issues`` and skipped; the partition is then
flagged partial (``partial`` column), never silently shortened.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike

from cnctwin.exceptions import CnctwinError, ConfigError
from cnctwin.fleet.cluster import map_tasks

__all__ = [
    "ESTIMATE_COLUMNS",
    "HEALTH_AXES",
    "LONG_RECORDING_S",
    "Partition",
    "compare_partition",
    "health_estimates",
    "health_partition",
    "health_signals",
    "health_table",
    "holes_partition",
    "machine_files_in",
    "partitions",
    "quality_partition",
    "run_job",
    "split_partitions",
]

HEALTH_AXES = ("X1", "Y1", "Z1")
"""Feed axes whose loop health is identified where they moved enough."""


LONG_RECORDING_S = 600.0
"""A recording longer than this (or than the window) is a stream, not a part cycle: a shift's
window takes only its first seconds (:func:`partitions`) [s]."""


@dataclass(frozen=True)
class Partition:
    """The recordings of one machine on one UTC day.

    Attributes
    ----------
    machine : str
        Machine name.
    day : str
        ``YYYY-MM-DD`` (UTC).
    recording_ids : tuple of str
        The recordings, in start-time order.
    n_cycles : int
        Their HF cycles analysed.
    cycle_ranges : tuple of (int, int)
        Per recording the inclusive cycle range analysed (a shift's window,
        :func:`partitions` ``window_s``); empty: the whole recordings.
    recorded_cycles : int or None
        All HF cycles of the day's recordings (None for a piece of a partition).
    """

    machine: str
    day: str
    recording_ids: tuple[str, ...]
    n_cycles: int
    cycle_ranges: tuple[tuple[int, int], ...] = ()
    recorded_cycles: int | None = None


def partitions(
    store_url: str, *, machines: Sequence[str] | None = None, window_s: float | None = None,
    shift_hours: float = 8.0, shift_start_h: float = 6.0,
) -> list[Partition]:
    """The (machine, day) partitions of a store, sorted by machine and day.

    Parameters
    ----------
    store_url : str
        The store.
    machines : sequence of str, optional
        Only these machines.
    window_s : float, optional
        Analyse only a window of each shift: the shift's first recordings (in start order)
        until ``window_s`` seconds are covered, each whole (a part cycle is the unit the
        analyses expect: holes and air plateaus cut at a window's edge would bias them); a
        recording longer than ``max(window_s, LONG_RECORDING_S)`` (a continuous stream, not
        a part cycle) is cut to its first that many seconds (``Partition.cycle_ranges``).
        With one recording per part cycle that is the shift's first part cycle(s). None:
        every recorded cycle.
    shift_hours : float, default 8
        Shift length [h]; a recording belongs to the shift its first cycle is in.
    shift_start_h : float, default 6
        Start of the first shift of the day [h after 00:00 UTC]; earlier recordings belong to
        the previous shift (the night shift's morning).

    Returns
    -------
    list of Partition
        Sorted by machine, then day; ``n_cycles`` are the cycles analysed,
        ``recorded_cycles`` all cycles of the day's recordings.
    """
    import cnctwin.store

    if window_s is not None and not (math.isfinite(window_s) and window_s > 0):
        raise ConfigError(f"window_s {window_s!r}: give a positive number of seconds per "
                          "shift, or None for every recorded cycle")
    if not (math.isfinite(shift_hours) and 0 < shift_hours <= 24):
        raise ConfigError(f"shift_hours {shift_hours!r}: give 0 < hours <= 24")
    with cnctwin.store.open(store_url, read_only=True) as st:
        cat = st.recordings()
    if cat.empty:
        return []
    cat = cat[cat["n_cycles"] > 0].copy()
    if machines:
        cat = cat[cat["machine"].isin(list(machines))]
    start = pd.to_datetime(cat["start_time"], utc=True)
    cat["day"] = start.dt.strftime("%Y-%m-%d")
    hours = (start - start.dt.floor("D")).dt.total_seconds() / 3600.0
    cat["shift"] = np.floor((hours - shift_start_h) / shift_hours).astype(int)
    cat = cat.sort_values(["machine", "day", "start_time", "recording_id"])
    out = []
    for (m, d), g in cat.groupby(["machine", "day"], sort=True):
        recorded = int(g["n_cycles"].sum())
        if window_s is None:
            out.append(Partition(str(m), str(d), tuple(g["recording_id"]), recorded,
                                 recorded_cycles=recorded))
            continue
        ids, ranges, n = [], [], 0
        for _, sg in g.groupby("shift", sort=True):
            left = float(window_s)
            for rid, n_rec, c0, c1, dt in zip(
                    sg["recording_id"].astype(str), sg["n_cycles"].to_numpy(dtype=np.int64),
                    sg["first_cycle"].to_numpy(dtype=np.int64),
                    sg["last_cycle"].to_numpy(dtype=np.int64),
                    sg["cycle_time_s"].to_numpy(dtype=np.float64), strict=True):
                if left <= 0:
                    break
                cap = max(1, math.ceil(max(window_s, LONG_RECORDING_S) / float(dt)))
                take = min(int(n_rec), cap)
                ids.append(rid)
                ranges.append((int(c0), int(c0) + take - 1 if take < n_rec else int(c1)))
                n += take
                left -= take * float(dt)
        out.append(Partition(str(m), str(d), tuple(ids), n, tuple(ranges), recorded))
    return out


def split_partitions(parts: Sequence[Partition], *, n_tasks: int) -> list[Partition]:
    """Split the largest partitions at recording boundaries until there are ``n_tasks``.

    The rule that keeps a cluster busy: at least ``n_tasks`` tasks (4 per worker: the last
    tasks' tail is then a quarter of a worker's share), made by halving the largest partition
    (by cycles) that still has two or more recordings; a piece is never smaller than one
    recording (or its window). Jobs that combine per (machine, day) (:func:`health_table`)
    give the same rows split or not.

    Parameters
    ----------
    parts : sequence of Partition
        The partitions (:func:`partitions`).
    n_tasks : int
        The least number of tasks wanted.

    Returns
    -------
    list of Partition
        Pieces in the partitions' order (each piece's recordings in their order).
    """
    pieces = [list(_records(p)) for p in parts]
    heads = list(parts)
    while len(pieces) < n_tasks:
        sizes = [sum(n for _, n, _ in pc) if len(pc) > 1 else -1 for pc in pieces]
        i = int(np.argmax(sizes))
        if sizes[i] < 0:
            break
        pc = pieces[i]
        cum = np.cumsum([n for _, n, _ in pc])
        k = int(np.clip(np.searchsorted(cum, cum[-1] / 2.0) + 1, 1, len(pc) - 1))
        pieces[i:i + 1] = [pc[:k], pc[k:]]
        heads[i:i + 1] = [heads[i], heads[i]]
    out = []
    for head, pc in zip(heads, pieces, strict=True):
        ranges = tuple(r for _, _, r in pc) if head.cycle_ranges else ()
        out.append(Partition(head.machine, head.day, tuple(rid for rid, _, _ in pc),
                             sum(n for _, n, _ in pc), ranges,
                             head.recorded_cycles if len(pc) == len(head.recording_ids)
                             else None))
    return out


def _records(part: Partition) -> list[tuple[str, int, tuple[int, int]]]:
    """(recording id, cycles, cycle range) of a partition's recordings (the range (0, -1)
    and the mean share of the cycles where the partition has no ranges)."""
    k = len(part.recording_ids)
    if part.cycle_ranges:
        return [(rid, b - a + 1, (a, b)) for rid, (a, b)
                in zip(part.recording_ids, part.cycle_ranges, strict=True)]
    return [(rid, part.n_cycles // max(k, 1), (0, -1)) for rid in part.recording_ids]


def _load(store_url: str, part: Partition, *, signals: Sequence[str] | None = None
          ) -> tuple[list[tuple[str, Any]], list[str]]:
    import cnctwin.store

    recs, issues = [], []
    ranges: Sequence[tuple[int, int] | None] = part.cycle_ranges or [None] * len(
        part.recording_ids)
    with cnctwin.store.open(store_url, read_only=True) as st:
        for rid, cyc in zip(part.recording_ids, ranges, strict=True):
            try:
                recs.append((rid, st.load(rid, signals=signals, cycles=cyc)))
            except (CnctwinError, OSError, ValueError) as exc:
                issues.append(f"{rid}: cannot load: {exc}")
    return recs, issues


def _spindle_model(machine_files: Mapping[str, str] | None, machine: str) -> Any:
    if not machine_files or machine not in machine_files:
        return None
    from cnctwin.machine import load_machine
    from cnctwin.spindle import SpindleModel

    return SpindleModel.from_machine(load_machine(machine_files[machine]))


def _program(rec: Any) -> str:
    ev = rec.events
    if "path" in ev.columns and "kind" in ev.columns:
        calls = ev.loc[ev["kind"] == "call", "path"].dropna()
        if len(calls):
            return str(calls.iloc[0])
    return ""


# ---------------------------------------------------------------------------- holes
def holes_partition(
    part: Partition, *, store_url: str, machine_files: Mapping[str, str] | None = None
) -> pd.DataFrame:
    """Per-hole records of one partition (:func:`cnctwin.usecases.holes.hole_record`).

    Parameters
    ----------
    part : Partition
        One (machine, day) of the store (:func:`partitions`).
    store_url : str
        The store (a directory, ``duckdb:///path`` or ``postgresql://...``).
    machine_files : mapping, optional
        Machine name -> machine file path; a machine without one is evaluated with the
        thesis machine's spindle model.

    Returns
    -------
    pandas.DataFrame
        ``machine``, ``day``, ``recording_id``, ``partial``, ``issues`` and the hole record
        columns (hole numbers restart in each recording; ``torque_*`` in Nm with the machine's
        own spindle model where ``machine_files`` names one, else the thesis machine's).
    """
    from cnctwin.usecases.holes import hole_record

    recs, issues = _load(store_url, part)
    model = _spindle_model(machine_files, part.machine)
    frames = []
    for rid, rec in recs:
        try:
            df = hole_record(rec, model=model)
        except CnctwinError as exc:
            issues.append(f"{rid}: no hole record: {exc}")
            continue
        df.insert(0, "recording_id", rid)
        frames.append(df)
    out = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()
    out.insert(0, "day", part.day)
    out.insert(0, "machine", part.machine)
    out["partial"] = bool(issues)
    out["issues"] = json.dumps(issues)
    out.attrs = {}
    return out


# ---------------------------------------------------------------------------- health
def _combine(values: ArrayLike, errors: ArrayLike) -> tuple[float, float]:
    """Mean of per-cycle estimates and its uncertainty: the larger of the propagated standard
    errors and the scatter between cycles (standard error of the mean)."""
    v = np.asarray(values, dtype=float)
    e = np.asarray(errors, dtype=float)
    n = v.size
    mean = float(v.mean())
    prop = float(np.sqrt(np.nansum(e**2)) / n) if np.isfinite(e).any() else math.nan
    scatter = float(v.std(ddof=1) / math.sqrt(n)) if n > 1 else math.nan
    unc = np.nanmax([prop, scatter]) if np.isfinite([prop, scatter]).any() else math.nan
    return mean, float(unc)


ESTIMATE_COLUMNS = ["machine", "day", "recording_id", "component", "parameter", "unit",
                    "value", "error", "issue"]
"""Columns of :func:`health_estimates`."""

_HEALTH_CODES = ("DES_POS", "ENC_POS", "ENC1_POS", "ENC2_POS", "CTRL_DIFF2", "CONT_DEV",
                 "VEL_FFW", "TORQUE_FFW", "CMD_SPEED", "CURRENT", "TORQUE", "FOLLOWING_ERROR")
"""The feed-axis signals the health job reads (those of the loop identification without the
setpoint chain); the spindle's signals are read whole."""


def health_signals(axes: Sequence[str] = HEALTH_AXES, spindle: str = "SP1") -> list[str]:
    """The HF columns :func:`health_estimates` reads (the rest of a recording is not loaded).

    Parameters
    ----------
    axes : sequence of str
        Feed axes identified.
    spindle : str
        Spindle axis name.

    Returns
    -------
    list of str
        ``CODE|AXIS`` column names.
    """
    from cnctwin.signals import HF_CODES

    return ([f"{c}|{a}" for a in axes for c in _HEALTH_CODES]
            + [f"{c}|{spindle}" for c in HF_CODES])


def health_estimates(
    part: Partition, *, store_url: str, machine_files: Mapping[str, str] | None = None,
    axes: Sequence[str] = HEALTH_AXES, spindle: str = "SP1",
) -> pd.DataFrame:
    """The health estimates of each recording (window) of a partition or a piece of one.

    Per feed axis that moved (:func:`cnctwin.servo.health.identify_window`, without the
    setpoint chain): ``kv_1_s``, ``coulomb_a`` (mean of the two directions' Coulomb current),
    ``viscous_a_s_per_mm``; per spindle: ``friction_current_a`` at the fastest air plateau
    (:func:`cnctwin.spindle.air_cut_statistics`) with its ``speed_rpm``; per tool:
    ``torque_per_hole_nm`` (mean cutting torque of the holes). Only the columns of
    :func:`health_signals` and the partition's cycle ranges (its shift windows) are read.

    Parameters
    ----------
    part : Partition
        A partition (:func:`partitions`) or a piece of one (:func:`split_partitions`).
    store_url : str
        The store (a directory, ``duckdb:///path`` or ``postgresql://...``).
    machine_files : mapping, optional
        Machine name -> machine file path; a machine without one is evaluated with the
        thesis machine's spindle model.
    axes : sequence of str, default ('X1', 'Y1', 'Z1')
        Feed axes to identify.
    spindle : str, default 'SP1'
        Spindle axis name.

    Returns
    -------
    pandas.DataFrame
        :data:`ESTIMATE_COLUMNS`: one row per estimate (``error`` its 1-sigma standard
        error) and one row per problem (``issue`` set, the estimate columns empty), in
        recording order.
    """
    from cnctwin.servo.health import identify_window
    from cnctwin.spindle import air_cut_statistics
    from cnctwin.usecases.holes import hole_record

    recs, issues = _load(store_url, part, signals=health_signals(axes, spindle))
    model = _spindle_model(machine_files, part.machine)
    rows: list[dict[str, Any]] = [{"recording_id": "", "issue": i} for i in issues]

    def add(rid: str, comp: str, param: str, unit: str, value: float, err: float) -> None:
        if math.isfinite(value):
            rows.append({"recording_id": rid, "component": comp, "parameter": param,
                         "unit": unit, "value": value, "error": err, "issue": None})

    def problem(rid: str, text: str) -> None:
        rows.append({"recording_id": rid, "issue": text})

    for rid, rec in recs:
        for ax in axes:
            if f"DES_POS|{ax}" not in rec.hf.columns:
                continue
            try:
                w = identify_window(rec, ax, setpoint_chain=False, n_bootstrap=20)
            except CnctwinError as exc:
                problem(rid, f"{rid} {ax}: {exc}")
                continue
            p = w.params
            if "kv_1_s" in p:
                add(rid, ax, "kv_1_s", "1/s", p["kv_1_s"].value, p["kv_1_s"].stderr)
            if "coulomb_pos" in p and "coulomb_neg" in p:
                c = 0.5 * (abs(p["coulomb_pos"].value) + abs(p["coulomb_neg"].value))
                e = 0.5 * math.hypot(p["coulomb_pos"].stderr, p["coulomb_neg"].stderr)
                add(rid, ax, "coulomb_a", p["coulomb_pos"].unit, c, e)
            if "viscous_pos" in p and "viscous_neg" in p:
                v = 0.5 * (p["viscous_pos"].value + p["viscous_neg"].value)
                e = 0.5 * math.hypot(p["viscous_pos"].stderr, p["viscous_neg"].stderr)
                add(rid, ax, "viscous_a_s_per_mm", p["viscous_pos"].unit, v, e)
        sp = spindle
        try:
            stats = air_cut_statistics(rec, spindle=sp)
            holes = hole_record(rec, model=model)
        except CnctwinError as exc:
            problem(rid, f"{rid}: {exc}")
            continue
        air = stats
        if len(holes):  # plateaus during drilling carry the cutting load
            busy = np.zeros(len(air), dtype=bool)
            a0 = air["start_cycle"].to_numpy()
            a1 = air["end_cycle"].to_numpy()
            for h0, h1 in zip(holes["start_cycle"], holes["end_cycle"], strict=True):
                busy |= (a0 <= h1) & (a1 >= h0)
            air = air[~busy]
        if len(air):
            top = air.sort_values("speed_rpm").iloc[-1]
            n = max(int(top["n_cycles"]), 2)
            add(rid, sp, "friction_current_a", "A", float(top["current_a"]),
                float(top["current_std_a"]) / math.sqrt(n))
            add(rid, sp, "speed_rpm", "rpm", float(top["speed_rpm"]), 0.0)
        for tool, g in holes.groupby(holes["tool"].fillna(0).astype(int)):
            t = g["torque_mean_nm"].to_numpy(dtype=float)
            t = t[np.isfinite(t)]
            if t.size:
                se = float(t.std(ddof=1) / math.sqrt(t.size)) if t.size > 1 else math.nan
                add(rid, f"T{tool}", "torque_per_hole_nm", "Nm", float(t.mean()), se)
    out = pd.DataFrame(rows, columns=ESTIMATE_COLUMNS)
    out["machine"] = part.machine
    out["day"] = part.day
    return out


def health_table(estimates: pd.DataFrame) -> pd.DataFrame:
    """Per (machine, day), component and parameter: the combined health estimate.

    Estimates of the day's recordings are averaged (:func:`_combine`); a (machine, day) with a
    problem row is ``partial`` and lists its problems in ``issues`` (JSON).

    Parameters
    ----------
    estimates : pandas.DataFrame
        :func:`health_estimates` rows of whole partitions or of their pieces, in recording
        order.

    Returns
    -------
    pandas.DataFrame
        One row per component and parameter: ``machine``, ``day``, ``component`` (axis,
        spindle or ``T<n>``), ``parameter``, ``value``, ``uncertainty`` (1 sigma), ``unit``,
        ``n`` (recordings that gave it), ``partial``, ``issues``.
    """
    cols = ["machine", "day", "component", "parameter", "value", "uncertainty", "unit", "n",
            "partial", "issues"]
    if estimates.empty:
        return pd.DataFrame(columns=cols)
    problems = estimates[estimates["issue"].notna()]
    issues = {k: list(g["issue"]) for k, g in problems.groupby(["machine", "day"], sort=False)}
    est = estimates[estimates["issue"].isna()]
    rows = []
    for (m, d, comp, param, unit), g in est.groupby(
            ["machine", "day", "component", "parameter", "unit"], sort=True):
        value, unc = _combine(g["value"].to_numpy(dtype=float),
                              g["error"].to_numpy(dtype=float))
        day_issues = issues.get((m, d), [])
        rows.append({"machine": m, "day": d, "component": comp, "parameter": param,
                     "value": value, "uncertainty": unc, "unit": unit, "n": len(g),
                     "partial": bool(day_issues), "issues": json.dumps(day_issues)})
    return pd.DataFrame(rows, columns=cols)


def health_partition(
    part: Partition, *, store_url: str, machine_files: Mapping[str, str] | None = None,
    axes: Sequence[str] = HEALTH_AXES, spindle: str = "SP1",
) -> pd.DataFrame:
    """Servo and spindle health of one partition (:func:`health_estimates` combined by
    :func:`health_table`).

    Parameters
    ----------
    part : Partition
        One (machine, day) of the store (:func:`partitions`).
    store_url : str
        The store (a directory, ``duckdb:///path`` or ``postgresql://...``).
    machine_files : mapping, optional
        Machine name -> machine file path; a machine without one is evaluated with the
        thesis machine's spindle model.
    axes : sequence of str, default ('X1', 'Y1', 'Z1')
        Feed axes to identify.
    spindle : str, default 'SP1'
        Spindle axis name.

    Returns
    -------
    pandas.DataFrame
        :func:`health_table` rows.
    """
    return health_table(health_estimates(part, store_url=store_url,
                                         machine_files=machine_files, axes=axes,
                                         spindle=spindle))


# ---------------------------------------------------------------------------- quality
def quality_partition(part: Partition, *, store_url: str) -> pd.DataFrame:
    """Signal-quality accounting of one partition: one row per recording.

    Columns ``machine``, ``day``, ``recording_id``, ``n_cycles``, ``duration_s``,
    ``coverage`` (recorded / spanned cycles), ``missing_cycles`` (counter gaps), ``n_gaps``,
    ``jitter_ms`` (std of the time step minus the cycle time), ``nan_fraction`` (of the HF
    values), ``partial`` (the reader flagged the recording partial), ``issues``.

    Parameters
    ----------
    part : Partition
        One (machine, day) of the store (:func:`partitions`).
    store_url : str
        The store (a directory, ``duckdb:///path`` or ``postgresql://...``).

    Returns
    -------
    pandas.DataFrame
        One row per recording (columns above).
    """
    recs, issues = _load(store_url, part)
    rows = []
    for rid, rec in recs:
        n = rec.n_cycles
        cyc = rec.cycles
        span = int(cyc[-1] - cyc[0] + 1) if n else 0
        missing = sum(max(0, g.before_cycle - g.after_cycle - 1) for g in rec.meta.gaps)
        t = rec.hf["time"].to_numpy(dtype="datetime64[ns]").view(np.int64)
        dt = np.diff(t) / 1e6
        step = np.diff(cyc)
        ok = step == 1
        jitter = float(np.std(dt[ok] - rec.meta.cycle_time_s * 1e3)) if ok.any() else math.nan
        vals = rec.hf[rec.columns].to_numpy(dtype=float)
        rows.append({
            "machine": part.machine, "day": part.day, "recording_id": rid, "n_cycles": n,
            "duration_s": n * rec.meta.cycle_time_s, "coverage": n / span if span else 0.0,
            "missing_cycles": int(missing), "n_gaps": len(rec.meta.gaps),
            "jitter_ms": jitter,
            "nan_fraction": float(np.isnan(vals).mean()) if vals.size else 0.0,
            "partial": bool(rec.meta.partial),
            "issues": json.dumps([*issues, *rec.meta.issues]),
        })
    if not rows and issues:
        rows.append({"machine": part.machine, "day": part.day, "recording_id": "",
                     "n_cycles": 0, "duration_s": 0.0, "coverage": 0.0, "missing_cycles": 0,
                     "n_gaps": 0, "jitter_ms": math.nan, "nan_fraction": math.nan,
                     "partial": True, "issues": json.dumps(issues)})
    return pd.DataFrame(rows)


# ---------------------------------------------------------------------------- compare
def compare_partition(
    part: Partition, *, store_url: str, machine_files: Mapping[str, str] | None = None
) -> pd.DataFrame:
    """Per recording: program, cycle time, torque per hole and following error.

    Columns ``machine``, ``day``, ``recording_id``, ``program``, ``cycle_time_s`` (recorded
    program duration), ``n_holes``, ``torque_per_hole_nm``, ``following_error_rms_mm`` and
    ``following_error_max_mm`` (CONT_DEV over the feed axes), ``issues``.

    Parameters
    ----------
    part : Partition
        One (machine, day) of the store (:func:`partitions`).
    store_url : str
        The store (a directory, ``duckdb:///path`` or ``postgresql://...``).
    machine_files : mapping, optional
        Machine name -> machine file path; a machine without one is evaluated with the
        thesis machine's spindle model.

    Returns
    -------
    pandas.DataFrame
        One row per recording (columns above).
    """
    from cnctwin.usecases.holes import hole_record

    recs, issues = _load(store_url, part)
    model = _spindle_model(machine_files, part.machine)
    rows = []
    for rid, rec in recs:
        try:
            holes = hole_record(rec, model=model)
            tq = float(holes["torque_mean_nm"].mean()) if len(holes) else math.nan
        except CnctwinError as exc:
            issues.append(f"{rid}: {exc}")
            holes, tq = pd.DataFrame(), math.nan
        dev = [c for c in rec.columns if c.startswith("CONT_DEV|")
               and c.split("|", 1)[1] in HEALTH_AXES]
        d = np.abs(rec.hf[dev].to_numpy(dtype=float)) if dev else np.zeros((0, 0))
        rows.append({
            "machine": part.machine, "day": part.day, "recording_id": rid,
            "program": _program(rec), "cycle_time_s": rec.n_cycles * rec.meta.cycle_time_s,
            "n_holes": len(holes), "torque_per_hole_nm": tq,
            "following_error_rms_mm": float(np.sqrt(np.nanmean(d**2))) if d.size else math.nan,
            "following_error_max_mm": float(np.nanmax(d)) if d.size else math.nan,
            "issues": json.dumps(issues),
        })
    return pd.DataFrame(rows)


# ---------------------------------------------------------------------------- running
def run_job(
    fn: Callable[..., pd.DataFrame], parts: Sequence[Partition], *, client: Any | None,
    progress: Callable[[int, int], None] | None = None, **kwargs: Any,
) -> pd.DataFrame:
    """``fn`` over every partition, on the cluster or (``client=None``) in this process.

    Parameters
    ----------
    fn : callable
        A partition job (e.g. :func:`health_partition`), called as ``fn(part, **kwargs)``.
    parts : sequence of Partition
        The partitions.
    client : distributed.Client or None
        The cluster (:func:`cnctwin.fleet.cluster.fleet_client`), or None to run here.
    progress : callable, optional
        Called with (done, total) after each partition.
    **kwargs
        Passed to ``fn``.

    Returns
    -------
    pandas.DataFrame
        The partitions' tables concatenated in partition order.
    """
    if client is None:
        frames = []
        for i, p in enumerate(parts):
            frames.append(fn(p, **kwargs))
            if progress is not None:
                progress(i + 1, len(parts))
    else:
        frames = map_tasks(client, fn, list(parts), key=fn.__name__, progress=progress,
                           **kwargs)
    frames = [f for f in frames if len(f)]
    if not frames:
        return pd.DataFrame()
    return pd.concat(frames, ignore_index=True)


def machine_files_in(directory: str | Path | None) -> dict[str, str]:
    """Machine name -> machine file path for every ``<name>.toml`` in a directory.

    Parameters
    ----------
    directory : str or path, optional
        Folder of machine files (``<machine name>.toml``); None gives an empty mapping.

    Returns
    -------
    dict
        Machine name -> path.
    """
    if directory is None:
        return {}
    d = Path(directory)
    return {p.stem: str(p) for p in sorted(d.glob("*.toml"))}
