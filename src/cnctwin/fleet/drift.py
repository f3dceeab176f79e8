"""Drift alarms and wear trends from the fleet's per-day tables.

Every machine is compared with itself: its reference is its own first day in the table (or
the first ``baseline_days``), so machines with different parameters (a Kv of 25 or of 65 1/s)
need no common threshold. A day raises an alarm when its change from the reference is both
large in engineering terms (relative threshold) and certain (``z`` threshold, the change over
the combined 1-sigma uncertainty):

==================  ==================================  ============  ====
kind                parameter (component)               relative      z
==================  ==================================  ============  ====
``kv_drop``         ``kv_1_s`` (axis)                   < -10 %       > 5
``friction_rise``   ``coulomb_a`` (axis),               > +25 %       > 5
                    ``friction_current_a`` (spindle)
``worn_tool``       ``torque_per_hole_nm`` (tool)       > +10 %       > 5
==================  ==================================  ============  ====

The relative thresholds sit well above the day-to-day scatter of a healthy machine (Kv is
identified to < 0.1 %, Coulomb current to ~3 %, torque per hole to ~1 % on the synthetic
fleet) and below the faults worth a service call (a 30 % Kv loss, an 80 % friction rise, a
drill near the end of its life: +25 % torque, thesis §5.1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

__all__ = ["DRIFT_RULES", "DriftRule", "drift_alarms", "wear_trend"]


@dataclass(frozen=True)
class DriftRule:
    """When a parameter's change from the machine's own reference is an alarm.

    Attributes
    ----------
    kind : str
        Alarm kind (``truth.json`` names).
    parameter : str
        Health parameter.
    relative : float
        Relative change that alarms: negative for a drop (alarm below), positive for a rise.
    z : float
        Least change over its combined uncertainty.
    """

    kind: str
    parameter: str
    relative: float
    z: float = 5.0


DRIFT_RULES = (
    DriftRule("kv_drop", "kv_1_s", -0.10),
    DriftRule("friction_rise", "coulomb_a", 0.25),
    DriftRule("friction_rise", "friction_current_a", 0.25),
    DriftRule("worn_tool", "torque_per_hole_nm", 0.10),
)
"""The rules of :func:`drift_alarms` (module docstring)."""

ALARM_COLUMNS = ["machine", "day", "kind", "axis", "component", "parameter", "value",
                 "reference", "relative_change", "z"]


def drift_alarms(
    health: pd.DataFrame, *, rules: tuple[DriftRule, ...] = DRIFT_RULES, baseline_days: int = 1,
) -> pd.DataFrame:
    """Alarms where a machine's health parameter drifted from its own reference days.

    Parameters
    ----------
    health : pandas.DataFrame
        :func:`~cnctwin.fleet.jobs.health_partition` rows (``machine``, ``day``,
        ``component``, ``parameter``, ``value``, ``uncertainty``).
    rules : tuple of DriftRule
        Default :data:`DRIFT_RULES`.
    baseline_days : int, default 1
        The first days of each machine that form its reference (mean of their values).

    Returns
    -------
    pandas.DataFrame
        One row per alarm (:data:`ALARM_COLUMNS`): ``axis`` is the axis of an axis
        parameter, the spindle's name for the spindle, None for a tool.
    """
    out = []
    if health.empty:
        return pd.DataFrame(columns=ALARM_COLUMNS)
    by_param = {r.parameter: r for r in rules}
    h = health[health["parameter"].isin(list(by_param))]
    for (machine, comp, param), g in h.groupby(["machine", "component", "parameter"]):
        g = g.sort_values("day")
        days = sorted(g["day"].unique())
        ref_days = days[:baseline_days]
        ref = g[g["day"].isin(ref_days)]
        ref_v = float(ref["value"].mean())
        ref_u = float(np.sqrt(np.nansum(ref["uncertainty"] ** 2)) / len(ref))
        rule = by_param[str(param)]
        for _, row in g[~g["day"].isin(ref_days)].iterrows():
            v, u = float(row["value"]), float(row["uncertainty"])
            if not (math.isfinite(v) and ref_v):
                continue
            rel = v / ref_v - 1.0
            sigma = math.hypot(u if math.isfinite(u) else 0.0, ref_u if math.isfinite(ref_u)
                               else 0.0)
            z = abs(v - ref_v) / sigma if sigma > 0 else math.inf
            hit = rel <= rule.relative if rule.relative < 0 else rel >= rule.relative
            if hit and z >= rule.z:
                axis = None if str(comp).startswith("T") else str(comp)
                out.append({"machine": machine, "day": row["day"], "kind": rule.kind,
                            "axis": axis, "component": comp, "parameter": param, "value": v,
                            "reference": ref_v, "relative_change": rel, "z": z})
    return pd.DataFrame(out, columns=ALARM_COLUMNS).sort_values(
        ["machine", "day", "kind"], ignore_index=True)


def wear_trend(holes: pd.DataFrame) -> pd.DataFrame:
    """Per machine, tool and day: holes, mean cutting torque and its rise over the first day.

    Parameters
    ----------
    holes : pandas.DataFrame
        :func:`~cnctwin.fleet.jobs.holes_partition` rows.

    Returns
    -------
    pandas.DataFrame
        ``machine``, ``tool``, ``day``, ``n_holes``, ``cumulative_holes`` (in the store),
        ``torque_mean_nm``, ``torque_sem_nm``, ``relative_increase`` (over the tool's first
        day on that machine), ``partial``.
    """
    cols = ["machine", "tool", "day", "n_holes", "cumulative_holes", "torque_mean_nm",
            "torque_sem_nm", "relative_increase", "partial"]
    if holes.empty or "torque_mean_nm" not in holes:
        return pd.DataFrame(columns=cols)
    h = holes.copy()
    h["tool"] = h["tool"].fillna(0).astype(int)
    g = h.groupby(["machine", "tool", "day"], sort=True)
    t = g.agg(n_holes=("torque_mean_nm", "size"), torque_mean_nm=("torque_mean_nm", "mean"),
              torque_std=("torque_mean_nm", "std"), partial=("partial", "any")).reset_index()
    t["torque_sem_nm"] = t["torque_std"] / np.sqrt(t["n_holes"])
    t["cumulative_holes"] = t.groupby(["machine", "tool"])["n_holes"].cumsum()
    first = t.groupby(["machine", "tool"])["torque_mean_nm"].transform("first")
    t["relative_increase"] = t["torque_mean_nm"] / first - 1.0
    return t[cols]
