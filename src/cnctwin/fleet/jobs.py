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

from cnctwin.exceptions import CnctwinError
from cnctwin.fleet.cluster import map_tasks

__all__ = [
    "HEALTH_AXES",
    "Partition",
    "compare_partition",
    "health_partition",
    "holes_partition",
    "machine_files_in",
    "partitions",
    "quality_partition",
    "run_job",
]

HEALTH_AXES = ("X1", "Y1", "Z1")
"""Feed axes whose loop health is identified where they moved enough."""


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
        Their HF cycles.
    """

    machine: str
    day: str
    recording_ids: tuple[str, ...]
    n_cycles: int


def partitions(
    store_url: str, *, machines: Sequence[str] | None = None
) -> list[Partition]:
    """The (machine, day) partitions of a store, sorted by machine and day.

    Parameters
    ----------
    store_url : str
        The store.
    machines : sequence of str, optional
        Only these machines.

    Returns
    -------
    list of Partition
        Sorted by machine, then day.
    """
    import cnctwin.store

    with cnctwin.store.open(store_url, read_only=True) as st:
        cat = st.recordings()
    if cat.empty:
        return []
    cat = cat[cat["n_cycles"] > 0].copy()
    if machines:
        cat = cat[cat["machine"].isin(list(machines))]
    cat["day"] = pd.to_datetime(cat["start_time"], utc=True).dt.strftime("%Y-%m-%d")
    cat = cat.sort_values(["machine", "day", "start_time", "recording_id"])
    out = []
    for (m, d), g in cat.groupby(["machine", "day"], sort=True):
        out.append(Partition(str(m), str(d), tuple(g["recording_id"]), int(g["n_cycles"].sum())))
    return out


def _load(store_url: str, part: Partition) -> tuple[list[tuple[str, Any]], list[str]]:
    import cnctwin.store

    recs, issues = [], []
    with cnctwin.store.open(store_url, read_only=True) as st:
        for rid in part.recording_ids:
            try:
                recs.append((rid, st.load(rid)))
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
def _combine(values: Sequence[float], errors: Sequence[float]) -> tuple[float, float]:
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


def health_partition(
    part: Partition, *, store_url: str, machine_files: Mapping[str, str] | None = None,
    axes: Sequence[str] = HEALTH_AXES, spindle: str = "SP1",
) -> pd.DataFrame:
    """Servo and spindle health of one partition.

    Per feed axis that moved (:func:`cnctwin.servo.health.identify_window`, without the
    setpoint chain): ``kv_1_s``, ``coulomb_a`` (mean of the two directions' Coulomb current),
    ``viscous_a_s_per_mm``; per spindle: ``friction_current_a`` at the fastest air plateau
    (:func:`cnctwin.spindle.air_cut_statistics`) with its ``speed_rpm``; per tool:
    ``torque_per_hole_nm`` (mean cutting torque of the holes). Estimates of the day's cycles
    are averaged (:func:`_combine`).

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
        One row per component and parameter: ``machine``, ``day``, ``component`` (axis,
        spindle or ``T<n>``), ``parameter``, ``value``, ``uncertainty`` (1 sigma), ``unit``,
        ``n`` (cycles that gave it), ``partial``, ``issues``.
    """
    from cnctwin.servo.health import identify_window
    from cnctwin.spindle import air_cut_statistics
    from cnctwin.usecases.holes import hole_record

    recs, issues = _load(store_url, part)
    model = _spindle_model(machine_files, part.machine)
    acc: dict[tuple[str, str, str], tuple[list[float], list[float]]] = {}

    def add(comp: str, param: str, unit: str, value: float, err: float) -> None:
        if math.isfinite(value):
            vs, es = acc.setdefault((comp, param, unit), ([], []))
            vs.append(value)
            es.append(err)

    for rid, rec in recs:
        for ax in axes:
            if f"DES_POS|{ax}" not in rec.hf.columns:
                continue
            try:
                w = identify_window(rec, ax, setpoint_chain=False, n_bootstrap=20)
            except CnctwinError as exc:
                issues.append(f"{rid} {ax}: {exc}")
                continue
            p = w.params
            if "kv_1_s" in p:
                add(ax, "kv_1_s", "1/s", p["kv_1_s"].value, p["kv_1_s"].stderr)
            if "coulomb_pos" in p and "coulomb_neg" in p:
                c = 0.5 * (abs(p["coulomb_pos"].value) + abs(p["coulomb_neg"].value))
                e = 0.5 * math.hypot(p["coulomb_pos"].stderr, p["coulomb_neg"].stderr)
                add(ax, "coulomb_a", p["coulomb_pos"].unit, c, e)
            if "viscous_pos" in p and "viscous_neg" in p:
                v = 0.5 * (p["viscous_pos"].value + p["viscous_neg"].value)
                e = 0.5 * math.hypot(p["viscous_pos"].stderr, p["viscous_neg"].stderr)
                add(ax, "viscous_a_s_per_mm", p["viscous_pos"].unit, v, e)
        sp = spindle
        try:
            stats = air_cut_statistics(rec, spindle=sp)
            holes = hole_record(rec, model=model)
        except CnctwinError as exc:
            issues.append(f"{rid}: {exc}")
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
            add(sp, "friction_current_a", "A", float(top["current_a"]),
                float(top["current_std_a"]) / math.sqrt(n))
            add(sp, "speed_rpm", "rpm", float(top["speed_rpm"]), 0.0)
        for tool, g in holes.groupby(holes["tool"].fillna(0).astype(int)):
            t = g["torque_mean_nm"].to_numpy(dtype=float)
            t = t[np.isfinite(t)]
            if t.size:
                se = float(t.std(ddof=1) / math.sqrt(t.size)) if t.size > 1 else math.nan
                add(f"T{tool}", "torque_per_hole_nm", "Nm", float(t.mean()), se)
    rows = []
    for (comp, param, unit), (vs, es) in sorted(acc.items()):
        value, unc = _combine(vs, es)
        rows.append({"machine": part.machine, "day": part.day, "component": comp,
                     "parameter": param, "value": value, "uncertainty": unc, "unit": unit,
                     "n": len(vs)})
    out = pd.DataFrame(rows, columns=["machine", "day", "component", "parameter", "value",
                                      "uncertainty", "unit", "n"])
    out["partial"] = bool(issues)
    out["issues"] = json.dumps(issues)
    return out


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
