"""The plant at a glance: one status per machine from its edge runtime's state directory.

Each ``cnctwin edge run --out DIR`` keeps ``DIR/status.json`` (rewritten every second) and
appends every result to ``DIR/results.jsonl`` (docs/edge.md). :func:`machine_state` turns the
two into what an operator looks for beside the machine: is it running, cutting, in alarm, or
is its data stale; the latest torque, hole and alarm. Only the tail of the results file is
read (the newest messages of the newest run), so a machine costs the same whatever the size
of its history.

State rules, first match wins:

1. ``waiting``: no ``status.json`` yet (the runtime has not started).
2. ``finished``: the runtime ended cleanly (a replayed file at its end, a stopped runtime).
3. ``stale``: the runtime has not written its status for ``stale_s`` (it hangs or died), or
   its newest data is older than ``stale_s`` (the machine or its connection sends nothing).
4. ``alarm``: an ``alarm`` within ``alarm_hold_s`` of machine time before the newest torque.
5. ``cutting``: a hole is open (``hole_start`` newer than the last ``hole``), or the newest
   torque message's mean cutting torque is above ``cutting_nm``.
6. ``running``: otherwise (data flows, the spindle is not cutting).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import orjson
import pandas as pd

from cnctwin.edge.sinks import tail_lines
from cnctwin.recording import jsonable
from cnctwin.web.live import LiveSource

__all__ = ["STATES", "PlantStatusOptions", "machine_state", "plant_state"]

STATES: tuple[str, ...] = ("waiting", "finished", "stale", "alarm", "cutting", "running")
"""The states of :func:`machine_state`, in the order their rules are tried."""

_KINDS = ("torque", "hole", "hole_start", "alarm")


@dataclass(frozen=True)
class PlantStatusOptions:
    """Thresholds of the plant view.

    Attributes
    ----------
    stale_s : float
        Status or data older than this is stale [s].
    alarm_hold_s : float
        An alarm keeps the machine in ``alarm`` this long [s of machine time].
    cutting_nm : float
        Mean cutting torque of the newest torque message above which the spindle cuts [Nm].
    tail_bytes : int
        How much of the end of ``results.jsonl`` is read [bytes].
    """

    stale_s: float = 10.0
    alarm_hold_s: float = 60.0
    cutting_nm: float = 0.3
    tail_bytes: int = 1 << 20


def _newest_messages(results: Path, tail_bytes: int) -> dict[str, dict[str, Any]]:
    """The newest message of each kind in :data:`_KINDS` since the newest ``run`` message."""
    lines = tail_lines(results, tail_bytes=tail_bytes)
    found: dict[str, dict[str, Any]] = {}
    for line in reversed(lines):
        if not line.strip():
            continue
        try:
            msg = orjson.loads(line)
        except orjson.JSONDecodeError:
            continue  # a line a crash cut short
        kind = msg.get("kind") if isinstance(msg, dict) else None
        if kind == "run":
            break  # older lines belong to an earlier run
        if kind in _KINDS and kind not in found:
            found[kind] = msg
            if len(found) == len(_KINDS):
                break
    return found


def _seconds(text: Any) -> float | None:
    if not text:
        return None
    try:
        return float(pd.Timestamp(text).value) / 1e9
    except (ValueError, TypeError):
        return None


def _finite_mean(values: Any) -> float | None:
    vals = [float(v) for v in values or [] if v is not None and math.isfinite(float(v))]
    return sum(vals) / len(vals) if vals else None


def machine_state(live: LiveSource, *, options: PlantStatusOptions | None = None,
                  now_s: float | None = None) -> dict[str, Any]:
    """The operator's view of one machine (rules in the module docstring).

    Parameters
    ----------
    live : LiveSource
        The machine's edge state directory.
    options : PlantStatusOptions, optional
        Thresholds; default :class:`PlantStatusOptions`.
    now_s : float, optional
        Wall-clock time [s since the epoch]; default now.

    Returns
    -------
    dict
        ``machine``, ``directory``, ``state`` (one of :data:`STATES`), ``reason`` (why, in
        words), ``updated`` (UTC of the status), ``status_age_s``, ``data_age_s``,
        ``cycles``, ``holes``, ``alarms``, ``torque`` (``time``, ``cycle``,
        ``torque_mean_nm``, ``torque_max_nm``, ``speed_rpm``), ``hole`` (``time``,
        ``hole``, ``depth_mm``, ``torque_mean_nm``, ``partial``), ``alarm`` (``time``,
        ``detector``, ``score``, ``threshold``, ``message``, ``hole``); a part that is not
        there yet is None. Strict JSON values (no NaN).
    """
    opt = options if options is not None else PlantStatusOptions()
    now = time.time() if now_s is None else now_s
    status = live.status()
    newest = _newest_messages(live.results, opt.tail_bytes)
    name = str(status.get("machine") or live.directory.name)
    out: dict[str, Any] = {"machine": name, "directory": str(live.directory),
                           "updated": status.get("updated"), "status_age_s": None,
                           "data_age_s": status.get("data_age_s"),
                           "cycles": status.get("cycles"), "holes": status.get("holes"),
                           "alarms": status.get("alarms"),
                           "torque": None, "hole": None, "alarm": None}
    tq = newest.get("torque")
    if tq is not None:
        out["torque"] = {"time": tq.get("time"), "cycle": tq.get("cycle"),
                         "torque_mean_nm": _finite_mean(tq.get("torque_nm")),
                         "torque_max_nm": max((abs(float(v)) for v in tq.get("torque_nm") or []
                                               if v is not None and math.isfinite(float(v))),
                                              default=None),
                         "speed_rpm": _finite_mean(tq.get("speed_rpm"))}
    hole = newest.get("hole")
    if hole is not None:
        row = hole.get("row") or {}
        out["hole"] = {"time": hole.get("time"), "hole": hole.get("hole"),
                       "depth_mm": row.get("depth_mm"),
                       "torque_mean_nm": row.get("torque_mean_nm"),
                       "partial": bool(hole.get("partial") or row.get("partial") or False)}
    alarm = newest.get("alarm")
    if alarm is not None:
        out["alarm"] = {k: alarm.get(k) for k in ("time", "detector", "score", "threshold",
                                                   "message", "hole")}
    updated = _seconds(status.get("updated"))
    if updated is not None:
        out["status_age_s"] = max(now - updated, 0.0)
    out["state"], out["reason"] = _state(status, newest, out, opt)
    return dict(jsonable(out))


def _state(status: dict[str, Any], newest: dict[str, dict[str, Any]], out: dict[str, Any],
           opt: PlantStatusOptions) -> tuple[str, str]:
    if "state" not in status:
        return "waiting", str(status.get("note") or "no status.json yet")
    if status.get("state") == "finished":
        return "finished", "the runtime ended cleanly"
    age = out["status_age_s"]
    if age is None or age > opt.stale_s:
        return "stale", (f"no status for {age:.0f} s (runtime stopped or hung?)"
                         if age is not None else "status without a time")
    data_age = status.get("data_age_s")
    if data_age is not None and math.isfinite(float(data_age)) and data_age > opt.stale_s:
        return "stale", f"newest data {float(data_age):.0f} s old (machine or link silent?)"
    t_torque = _seconds((newest.get("torque") or {}).get("time"))
    t_alarm = _seconds((newest.get("alarm") or {}).get("time"))
    if t_alarm is not None and (t_torque is None or t_torque - t_alarm <= opt.alarm_hold_s):
        det = (newest.get("alarm") or {}).get("detector", "detector")
        return "alarm", f"{det} alarm"
    hole_start = newest.get("hole_start")
    if hole_start is not None and (newest.get("hole") is None or int(
            hole_start.get("cycle", 0)) > int(newest["hole"].get("cycle", 0))):
        return "cutting", "a hole is being drilled"
    mean = (out["torque"] or {}).get("torque_mean_nm")
    if mean is not None and abs(mean) > opt.cutting_nm:
        return "cutting", f"cutting torque {mean:.2f} Nm"
    return "running", "data flows, no cut"


def plant_state(lives: dict[str, LiveSource], *, options: PlantStatusOptions | None = None,
                now_s: float | None = None) -> list[dict[str, Any]]:
    """:func:`machine_state` of every machine, in the given order.

    Parameters
    ----------
    lives : dict
        Label -> the machine's state directory.
    options : PlantStatusOptions, optional
        Thresholds.
    now_s : float, optional
        Wall-clock time [s since the epoch]; default now.

    Returns
    -------
    list of dict
        One :func:`machine_state` per machine, with its ``label``.
    """
    rows = []
    for label, live in lives.items():
        row = machine_state(live, options=options, now_s=now_s)
        row["label"] = label
        rows.append(row)
    return rows
