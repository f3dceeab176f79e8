"""The plant at a glance: one status per machine from its edge runtime's state directory.

Each ``cnctwin edge run --out DIR`` keeps ``DIR/status.json`` (rewritten every second) and
appends every result to ``DIR/results.jsonl`` (docs/edge.md). :func:`machine_state` turns the
two into what an operator looks for beside the machine: is it running, cutting, in alarm, or
is its data stale; the latest torque, hole and alarm. Only the tail of the results file is
read (the newest messages of the newest run), so a machine costs the same whatever the size
of its history.

State rules, first match wins:

0. ``error``: ``status.json`` is unreadable or not the runtime's status object (the reason
   names the file); a malformed value elsewhere shows as missing, never as an error page.
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

STATES: tuple[str, ...] = ("error", "waiting", "finished", "stale", "alarm", "cutting", "running")
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


def _number(v: Any) -> float | None:
    """A finite number, or None (a malformed value is not a number)."""
    if isinstance(v, bool) or not isinstance(v, int | float):
        return None
    f = float(v)
    return f if math.isfinite(f) else None


def _count(v: Any) -> int | None:
    f = _number(v)
    return int(f) if f is not None and f == int(f) else None


def _numbers(values: Any) -> list[float]:
    if not isinstance(values, list):
        return []
    return [f for f in (_number(v) for v in values) if f is not None]


def _finite_mean(values: Any) -> float | None:
    vals = _numbers(values)
    return sum(vals) / len(vals) if vals else None


def _text(v: Any) -> str | None:
    return v if isinstance(v, str) else None


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
    name = _text(status.get("machine")) or live.directory.name
    # every value is checked for its type: a malformed one shows as missing, never breaks
    # the page of the whole plant
    out: dict[str, Any] = {"machine": name, "directory": str(live.directory),
                           "updated": _text(status.get("updated")), "status_age_s": None,
                           "data_age_s": _number(status.get("data_age_s")),
                           "cycles": _count(status.get("cycles")),
                           "holes": _count(status.get("holes")),
                           "alarms": _count(status.get("alarms")),
                           "torque": None, "hole": None, "alarm": None}
    tq = newest.get("torque")
    if tq is not None:
        out["torque"] = {"time": _text(tq.get("time")), "cycle": _count(tq.get("cycle")),
                         "torque_mean_nm": _finite_mean(tq.get("torque_nm")),
                         "torque_max_nm": max((abs(v) for v in _numbers(tq.get("torque_nm"))),
                                              default=None),
                         "speed_rpm": _finite_mean(tq.get("speed_rpm"))}
    hole = newest.get("hole")
    if hole is not None:
        row: dict[str, Any] = hole["row"] if isinstance(hole.get("row"), dict) else {}
        out["hole"] = {"time": _text(hole.get("time")), "hole": _count(hole.get("hole")),
                       "depth_mm": _number(row.get("depth_mm")),
                       "torque_mean_nm": _number(row.get("torque_mean_nm")),
                       "partial": bool(hole.get("partial") or row.get("partial") or False)}
    alarm = newest.get("alarm")
    if alarm is not None:
        out["alarm"] = {"time": _text(alarm.get("time")),
                        "detector": _text(alarm.get("detector")),
                        "score": _number(alarm.get("score")),
                        "threshold": _number(alarm.get("threshold")),
                        "message": _text(alarm.get("message")),
                        "hole": _count(alarm.get("hole"))}
    updated = _seconds(out["updated"])
    if updated is not None:
        out["status_age_s"] = max(now - updated, 0.0)
    out["state"], out["reason"] = _state(status, newest, out, opt)
    return dict(jsonable(out))


def _state(status: dict[str, Any], newest: dict[str, dict[str, Any]], out: dict[str, Any],
           opt: PlantStatusOptions) -> tuple[str, str]:
    if status.get("error"):
        return "error", str(status.get("note"))
    if "state" not in status:
        return "waiting", str(status.get("note") or "no status.json yet")
    if status.get("state") == "finished":
        return "finished", "the runtime ended cleanly"
    age = out["status_age_s"]
    if age is None or age > opt.stale_s:
        return "stale", (f"no status for {age:.0f} s (runtime stopped or hung?)"
                         if age is not None else "status without a time")
    data_age = out["data_age_s"]
    if data_age is not None and data_age > opt.stale_s:
        return "stale", f"newest data {data_age:.0f} s old (machine or link silent?)"
    t_torque = _seconds((out["torque"] or {}).get("time"))
    t_alarm = _seconds((out["alarm"] or {}).get("time"))
    if t_alarm is not None and (t_torque is None or t_torque - t_alarm <= opt.alarm_hold_s):
        det = (out["alarm"] or {}).get("detector") or "detector"
        return "alarm", f"{det} alarm"
    hole_start = newest.get("hole_start")
    started = _count((hole_start or {}).get("cycle"))
    ended = _count((newest.get("hole") or {}).get("cycle"))
    if started is not None and (newest.get("hole") is None or ended is None
                                or started > ended):
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
        try:
            row = machine_state(live, options=options, now_s=now_s)
        except (OSError, ValueError, TypeError, KeyError, AttributeError) as exc:
            # the last line of defence: one machine's tile says so, the plant page stays up
            row = {"machine": label, "directory": str(live.directory), "state": "error",
                   "reason": f"state directory {live.directory}: {type(exc).__name__}: {exc}",
                   "updated": None, "status_age_s": None, "data_age_s": None,
                   "cycles": None, "holes": None, "alarms": None, "torque": None,
                   "hole": None, "alarm": None}
        row["label"] = label
        rows.append(row)
    return rows
