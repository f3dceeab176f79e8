"""What a closed adaptive-feed loop did: the control's log, its summary, and the same part
with the adaptive feed off and on side by side (issue 26).

The simulated control (``cnctwin simulate --program ... --realtime``) logs per chunk the
requested and applied override and the hidden truth (cutting torque, hardness);
:func:`write_live_summary` writes it as ``control.csv`` and summarises it in
``adaptive.json``: cycle time, cutting torque and power spread while cutting, the override,
the stop request against the injected breakage, the heartbeat fallbacks and the loop latency
(sample served -> override applied). :func:`compare_runs` puts two summaries side by side.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

__all__ = ["compare_runs", "cut_share_within", "write_live_summary"]

CUT_NM = 0.3
"""Hidden cutting torque above which a chunk counts as cutting [Nm] (air is 0 in the truth)."""


def _stats(v: np.ndarray) -> dict[str, float | None]:
    v = v[np.isfinite(v)]
    if not v.size:
        return {"mean": None, "std": None, "p5": None, "p95": None, "min": None, "max": None}
    return {"mean": float(v.mean()), "std": float(v.std()), "p5": float(np.percentile(v, 5)),
            "p95": float(np.percentile(v, 95)), "min": float(v.min()), "max": float(v.max())}


def cut_share_within(log: pd.DataFrame, target: float, *, column: str = "cutting_torque_nm",
                     tolerance: float = 0.05, settle_s: float = 0.5,
                     cycle_time_s: float = 0.002, window_s: float = 0.1) -> float:
    """Share of the settled cutting time within ``tolerance`` of ``target``.

    Parameters
    ----------
    log : pandas.DataFrame
        ``control.csv`` (per chunk: ``cycle``, ``cutting_torque_nm``, ``hardness_factor``).
    target : float
        The target (torque [Nm] or power [W] per ``column``).
    column : str, default 'cutting_torque_nm'
        What is judged (``cutting_power_w`` for power).
    tolerance : float, default 0.05
        Relative band.
    settle_s : float, default 0.5
        Time after the entry into the cut and after each hardness change not judged [s].
    cycle_time_s : float, default 0.002
        Control cycle [s].
    window_s : float, default 0.1
        Judged on means over windows of this length (the tooth passing removed) [s].

    Returns
    -------
    float
        0..1 (NaN without a settled cutting window).
    """
    cyc = log["cycle"].to_numpy(dtype=np.int64)
    v = log[column].to_numpy(dtype=np.float64)
    cut = log["cutting_torque_nm"].to_numpy(dtype=np.float64) > CUT_NM
    hard = log["hardness_factor"].to_numpy(dtype=np.float64)
    t = (cyc - cyc[0]) * cycle_time_s if cyc.size else cyc.astype(float)
    change = np.flatnonzero((np.diff(hard) != 0) | (np.diff(cut.astype(int)) != 0)) + 1
    settled = cut.copy()
    for k in change:
        settled &= ~((t >= t[k]) & (t < t[k] + settle_s))
    win = np.floor(t / window_s).astype(np.int64)
    ok = []
    for w in np.unique(win[settled]):
        sel = win == w
        if settled[sel].all():
            ok.append(abs(float(np.mean(v[sel])) / target - 1.0) <= tolerance)
    return float(np.mean(ok)) if ok else math.nan


def write_live_summary(out: str | Path, *, log: list[dict[str, Any]], truth: dict[str, Any],
                       plc: Any, served_at: dict[int, float],
                       requested_at: list[float]) -> dict[str, Any]:
    """Write ``control.csv`` and ``adaptive.json`` of a real-time run.

    Parameters
    ----------
    out : str or path
        The run's directory.
    log : list of dict
        :attr:`cnctwin.sim.part.LiveOverride.log`.
    truth : dict
        The run's truth (``cycle_time_s``, ``limits.cycle_time_s``, ``breakage_cycle``,
        ``live``).
    plc : PlcOverride
        The PLC logic (its writes, fallbacks, stop request).
    served_at : dict
        Source time [ns] -> wall clock it was served [s].
    requested_at : list of float
        Wall-clock times the control read the PLC's override [s], in order.

    Returns
    -------
    dict
        The summary (also in ``adaptive.json``).
    """
    o = Path(out)
    df = pd.DataFrame(log)
    for k in ("cutting_torque_nm", "hardness_factor", "speed_rpm"):
        if k not in df:
            df[k] = np.nan
    df["cutting_power_w"] = df["cutting_torque_nm"] * df["speed_rpm"] * 2.0 * np.pi / 60.0
    df.to_csv(o / "control.csv", index=False)
    dt = float(truth["cycle_time_s"])  # the control cycle the run was simulated with
    cut = df["cutting_torque_nm"].to_numpy(dtype=float) > CUT_NM if len(df) else np.zeros(0,
                                                                                            bool)
    req = np.asarray(requested_at, dtype=np.float64)
    lat = []
    for t_w, key, v in plc.writes:
        if key != "data_time" or v is None or int(v) not in served_at:
            continue
        j = int(np.searchsorted(req, t_w))
        if j < req.size:
            lat.append(float(req[j]) - served_at[int(v)])
    lat_ms = np.asarray(lat) * 1e3
    live = truth.get("live") or {}
    brk, stopped = truth.get("breakage_cycle"), live.get("stopped_cycle")
    beats = [t for t, k, _ in plc.writes if k == "heartbeat"]
    fb = []
    for t in plc.fallbacks:
        before = [b for b in beats if b <= t]
        if before:
            fb.append(t - before[-1])
    summary = {
        "cycle_time_s": float(truth["limits"]["cycle_time_s"]),
        "cutting_time_s": float(cut.sum() * (df["cycle"].diff().median() if len(df) > 1
                                             else 0) * dt),
        "cutting_torque_nm": _stats(df["cutting_torque_nm"].to_numpy(float)[cut]),
        "cutting_power_w": _stats(df["cutting_power_w"].to_numpy(float)[cut]),
        "override_pct": _stats(df["applied_pct"].to_numpy(float)[cut] if len(df)
                               else np.zeros(0)),
        "override_bounds_pct": [plc.min_pct, plc.max_pct],
        "stop_request": plc.stop_request,
        "breakage_cycle": brk, "stopped_cycle": stopped,
        "stop_after_breakage_ms": (None if brk is None or stopped is None
                                   else float((stopped - brk) * dt * 1e3)),
        "writes": sum(1 for _, k, _ in plc.writes if k == "override_pct"),
        "heartbeat_s": plc.heartbeat_s,
        "fallbacks": len(plc.fallbacks),
        "fallback_after_last_heartbeat_s": fb,
        "latency_ms": {"n": int(lat_ms.size),
                       "p50": float(np.percentile(lat_ms, 50)) if lat_ms.size else None,
                       "p99": float(np.percentile(lat_ms, 99)) if lat_ms.size else None,
                       "what": "sample served by the control -> the override computed from "
                               "it applied by the control's interpolator"},
    }
    (o / "adaptive.json").write_text(json.dumps(summary, indent=2), encoding="utf-8")
    return summary


def compare_runs(off: dict[str, Any], on: dict[str, Any]) -> dict[str, Any]:
    """The same part with the adaptive feed off and on, side by side.

    Parameters
    ----------
    off, on : dict
        :func:`write_live_summary` results.

    Returns
    -------
    dict
        Per quantity ``off``, ``on`` and the change: cycle time, cutting torque and power
        mean and spread (standard deviation, p5-p95), override.
    """
    def row(a: Any, b: Any) -> dict[str, Any]:
        ch = None if a in (None, 0) or b is None else float(b / a - 1.0)
        return {"off": a, "on": b, "change": ch}

    out = {"cycle_time_s": row(off["cycle_time_s"], on["cycle_time_s"])}
    for q in ("cutting_torque_nm", "cutting_power_w", "override_pct"):
        for s in ("mean", "std", "p5", "p95"):
            out[f"{q}.{s}"] = row(off[q][s], on[q][s])
    return out
