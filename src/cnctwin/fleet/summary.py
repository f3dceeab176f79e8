"""One row per machine from a fleet result directory: wear, drift and data quality, ranked.

Reads the Parquet tables the fleet jobs write (``health``, ``alarms``, ``wear``, ``quality``;
each optional) and summarizes them for the dashboard's fleet page and ``GET /api/fleet``.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from cnctwin.exceptions import ConfigError

__all__ = ["FLEET_TABLES", "SORT_KEYS", "fleet_summary", "read_fleet_tables"]

FLEET_TABLES = ("health", "alarms", "holes", "wear", "quality", "compare")
"""The tables a fleet result directory may hold (``<name>.parquet``)."""

SORT_KEYS = {
    "alarms": (["n_alarms", "wear_rise", "drift_size"], [False, False, False]),
    "wear": (["wear_rise", "n_alarms"], [False, False]),
    "drift": (["drift_size", "n_alarms"], [False, False]),
    "quality": (["coverage_min", "missing_cycles"], [True, False]),
}
"""Ranking orders of :func:`fleet_summary` (columns, ascending flags)."""


def read_fleet_tables(directory: str | os.PathLike[str]) -> dict[str, pd.DataFrame]:
    """The fleet tables present in ``directory`` (name -> table).

    Parameters
    ----------
    directory : str or path-like
        Result folder of ``cnctwin fleet ... --out``.

    Returns
    -------
    dict
        Job name -> its table.

    Raises
    ------
    ConfigError
        If the directory does not exist or holds none of :data:`FLEET_TABLES`.
    """
    d = Path(directory)
    if not d.is_dir():
        raise ConfigError(f"fleet result directory {d} does not exist; write one with "
                          "`cnctwin fleet health --store URL --out DIR`")
    out = {n: pd.read_parquet(d / f"{n}.parquet") for n in FLEET_TABLES
           if (d / f"{n}.parquet").exists()}
    if not out:
        raise ConfigError(f"{d} holds no fleet table ({', '.join(FLEET_TABLES)}.parquet); run "
                          "`cnctwin fleet health|wear|quality --store URL --out DIR`")
    return out


def _max_drift(health: pd.DataFrame) -> pd.DataFrame:
    """Per machine the largest relative change of a loop or friction parameter from its
    first day, with its sign (a Kv drop is negative) and what drifted."""
    keep = health[health["parameter"].isin(["kv_1_s", "coulomb_a", "friction_current_a"])]
    if keep.empty:
        return pd.DataFrame(columns=["max_drift", "drift_of"])
    keep = keep.sort_values("day")
    first = keep.groupby(["machine", "component", "parameter"])["value"].transform("first")
    rel = keep["value"] / first - 1.0
    biggest = rel.abs().groupby(keep["machine"]).idxmax().dropna()
    return pd.DataFrame({
        "max_drift": rel.loc[biggest.to_numpy()].to_numpy(),
        "drift_of": [f"{keep['component'].loc[i]!s} {keep['parameter'].loc[i]!s}"
                     for i in biggest.to_numpy()]}, index=biggest.index)


def fleet_summary(
    tables: dict[str, pd.DataFrame], *, sort: str = "alarms"
) -> pd.DataFrame:
    """Machines ranked by alarms, wear, drift or data quality.

    Parameters
    ----------
    tables : dict
        :func:`read_fleet_tables`.
    sort : {'alarms', 'wear', 'drift', 'quality'}
        Ranking (:data:`SORT_KEYS`); worst first.

    Returns
    -------
    pandas.DataFrame
        ``machine``, ``days``, ``n_alarms``, ``alarm_kinds`` (comma-separated), ``first_alarm``
        (day), ``wear_rise`` (largest torque-per-hole rise over the tool's first day [-]),
        ``max_drift`` (the largest relative change of Kv, Coulomb or spindle friction from
        the first day, signed: a Kv drop is negative [-]), ``drift_of`` (its component and
        parameter), ``drift_size`` (``|max_drift|``, the ranking key),
        ``coverage_min`` [-], ``missing_cycles``, ``jitter_ms_max``, ``partial_partitions``.
    """
    if sort not in SORT_KEYS:
        raise ConfigError(f"sort must be one of {sorted(SORT_KEYS)}, not {sort!r}")
    machines: set[str] = set()
    for t in tables.values():
        if "machine" in t:
            machines |= set(map(str, t["machine"]))
    rows: dict[str, dict[str, Any]] = {
        m: {"machine": m, "days": 0, "n_alarms": 0, "alarm_kinds": "", "first_alarm": None,
            "wear_rise": math.nan, "max_drift": math.nan, "drift_of": "",
            "drift_size": math.nan, "coverage_min": math.nan,
            "missing_cycles": 0, "jitter_ms_max": math.nan, "partial_partitions": 0}
        for m in machines}
    for t in tables.values():
        if "day" in t and "machine" in t:
            for m, n in t.groupby("machine")["day"].nunique().items():
                rows[str(m)]["days"] = max(rows[str(m)]["days"], int(n))
    alarms = tables.get("alarms")
    if alarms is not None and len(alarms):
        for m, g in alarms.groupby("machine"):
            r = rows[str(m)]
            r["n_alarms"] = len(g)
            r["alarm_kinds"] = ", ".join(sorted(set(g["kind"])))
            r["first_alarm"] = str(min(g["day"]))
    wear = tables.get("wear")
    health = tables.get("health")
    if wear is not None and len(wear):
        for m, v in wear.groupby("machine")["relative_increase"].max().items():
            rows[str(m)]["wear_rise"] = float(v)
    elif health is not None and len(health):
        tq = health[health["parameter"] == "torque_per_hole_nm"].sort_values("day")
        if len(tq):
            first = tq.groupby(["machine", "component"])["value"].transform("first")
            for m, v in (tq["value"] / first - 1.0).groupby(tq["machine"]).max().items():
                rows[str(m)]["wear_rise"] = float(v)
    if health is not None and len(health):
        for m, d in _max_drift(health).iterrows():
            rows[str(m)].update(max_drift=float(d["max_drift"]), drift_of=str(d["drift_of"]),
                                drift_size=abs(float(d["max_drift"])))
    partial: dict[str, set[str]] = {}
    for t in tables.values():
        if {"machine", "day", "partial"} <= set(t.columns):
            for m, d in t.loc[t["partial"].astype(bool), ["machine", "day"]].itertuples(
                    index=False):
                partial.setdefault(str(m), set()).add(str(d))
    q = tables.get("quality")
    if q is not None and len(q):
        for m, g in q.groupby("machine"):
            r = rows[str(m)]
            r["coverage_min"] = float(g["coverage"].min())
            r["missing_cycles"] = int(g["missing_cycles"].sum())
            j = g["jitter_ms"].to_numpy(dtype=float)
            r["jitter_ms_max"] = float(np.nanmax(j)) if np.isfinite(j).any() else math.nan
    for m, days in partial.items():
        rows[m]["partial_partitions"] = len(days)
    out = pd.DataFrame(list(rows.values()))
    if out.empty:
        return out
    cols, asc = SORT_KEYS[sort]
    return out.sort_values([*cols, "machine"], ascending=[*asc, True], na_position="last",
                           ignore_index=True)
