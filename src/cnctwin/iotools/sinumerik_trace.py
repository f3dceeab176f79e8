"""Reader for SINUMERIK Solution Line servo-trace XML files (``<traceSession>``).

The servo trace of SINUMERIK Operate ("SINUMERIK Solution Line Trace") saves its session as XML:
``traceCaptureSetup`` (signal list, sample rates), display settings, and ``traceData`` with one
or more ``dataFrame`` elements. Each frame declares its signals as
``<dataSignal id="f4" key="s5" name="/Nck/!SD/nckServoDataFlwErr64 [u1, 7]" interval="0.002000"
unitsType="posn" .../>`` and then holds records ``<rec time="0.002000" f4="-0.000086" .../>``.

Records are **sparse**: a signal appears in a record only when its value changed (the first and
the last record of a frame carry every 2 ms signal). Signals with a slower ``interval`` (4 ms
IPO-cycle signals such as ``aaStat`` or ``measPos1``) are written every interval. The value of a
signal between two of its records is therefore the last written value: the reader rebuilds a
regular grid at the servo sample rate (2 ms) by sample-and-hold (forward fill), which is what the
format means, not an interpolation. Before a signal's first record the grid holds NaN (nothing is
invented). Which signals were held, and how many grid points were filled, is listed in
``rec.meta.issues``.

Signal mapping (by the OPI variable in ``name``; the axis number is the second number of
``[u1, 7]``):

============================================  ==================  ===========================
trace variable                                column              unit (linear / rotary)
============================================  ==================  ===========================
``nckServoDataCmdPos*`` (position setpoint)   ``DES_POS|AX``      mm / deg
``measPos1`` (measuring system 1)             ``ENC1_POS|AX``     mm / deg
``measPos2`` (measuring system 2)             ``ENC2_POS|AX``     mm / deg
``nckServoDataFlwErr*`` (following error)     ``FOLLOWING_ERROR``  mm / deg
``nckServoDataActCurr*`` (iq actual)          ``CURRENT|AX``      A
``nckServoDataCmdVelCtrlIn*`` (vel. setpt)    ``CMD_SPEED|AX``    mm/min / rpm
``nckServoDataActVelMot32`` (act. speed)      ``SPEED_ACT|AX``    mm/min / rpm
``nckServoDataActVelMotorSide*``              ``SPEED_ACT_MOTOR``  not stated in the file
``nckServoDataCmdAccCtrlIn*`` (acc. setpt)    ``ACC_SETPOINT|AX`` mm/s^2 / deg/s^2
``aaStat`` (axis status, $AA_STAT)            ``AXIS_STATUS|AX``  code (1 moving, 3/4 exact
                                                                  stop coarse/fine)
============================================  ==================  ===========================

``CMD_SPEED`` here is the velocity setpoint at the position-controller *input* (the derivative
of the position setpoint); the Capture4Analysis ``CMD_SPEED`` additionally contains the
position-controller correction. Unknown trace variables are kept as ``TRACE_<variable>|AX`` with
the file's ``unitsType`` as unit.

The trace has no CYCLE counter: the cycle index is ``round(time / servoSampleRate)`` counted
from the first frame's ``startTime`` (cycle 0), and ``startTime`` is the time anchor.

Units: the file states only a units *type* (``posn``, ``velo``, ``accel``). Whether an axis is
rotary is taken from ``rotary=`` or, if not given, inferred from the data: on a rotary axis the
position setpoint changes by 6 deg/s per rpm of velocity setpoint, on a linear axis by
1/60 mm/s per mm/min (a factor of 360 apart). The inference is recorded in ``meta.issues``.
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any
from xml.parsers import expat

import numpy as np
import pandas as pd

from cnctwin.exceptions import FormatError, TruncatedFileError
from cnctwin.recording import Recording, RecordingMeta, find_gaps
from cnctwin.signals import DEFAULT_AXIS_MAP

__all__ = ["TRACE_VARIABLE_MAP", "read_sinumerik_trace"]

_EOF_ERRORS = frozenset({
    expat.errors.codes[expat.errors.XML_ERROR_NO_ELEMENTS],
    expat.errors.codes[expat.errors.XML_ERROR_UNCLOSED_TOKEN],
    expat.errors.codes[expat.errors.XML_ERROR_PARTIAL_CHAR],
})
"""expat error codes of an XML document that ends early."""

TRACE_VARIABLE_MAP: dict[str, str] = {
    "nckServoDataCmdPos2ndEnc64": "DES_POS",
    "nckServoDataCmdPos1stEnc64": "DES_POS",
    "nckServoDataCmdPos64": "DES_POS",
    "nckServoDataCmdPos32": "DES_POS",
    "measPos1": "ENC1_POS",
    "measPos2": "ENC2_POS",
    "nckServoDataFlwErr64": "FOLLOWING_ERROR",
    "nckServoDataFlwErr32": "FOLLOWING_ERROR",
    "nckServoDataActCurr32": "CURRENT",
    "nckServoDataActCurr64": "CURRENT",
    "nckServoDataCmdVelCtrlIn64": "CMD_SPEED",
    "nckServoDataCmdVelCtrlIn32": "CMD_SPEED",
    "nckServoDataActVelMot32": "SPEED_ACT",
    "nckServoDataActVelMot64": "SPEED_ACT",
    "nckServoDataActVelMotorSide64": "SPEED_ACT_MOTOR",
    "nckServoDataActVelMotorSide32": "SPEED_ACT_MOTOR",
    "nckServoDataCmdAccCtrlIn64": "ACC_SETPOINT",
    "nckServoDataCmdAccCtrlIn32": "ACC_SETPOINT",
    "aaStat": "AXIS_STATUS",
}
"""OPI trace variable (without path and ``[u..]``) -> column code."""

_UNITS: dict[str, tuple[str, str]] = {
    # code -> (linear unit, rotary unit)
    "DES_POS": ("mm", "deg"),
    "ENC1_POS": ("mm", "deg"),
    "ENC2_POS": ("mm", "deg"),
    "FOLLOWING_ERROR": ("mm", "deg"),
    "CURRENT": ("A", "A"),
    "CMD_SPEED": ("mm/min", "rpm"),
    "SPEED_ACT": ("mm/min", "rpm"),
    "SPEED_ACT_MOTOR": ("", ""),
    "ACC_SETPOINT": ("mm/s^2", "deg/s^2"),
    "AXIS_STATUS": ("", ""),
}
_UNITS_TYPE: dict[str, tuple[str, str]] = {
    "posn": ("mm", "deg"),
    "velo": ("mm/min", "rpm"),
    "accel": ("mm/s^2", "deg/s^2"),
    "current": ("A", "A"),
}

_NAME_RE = re.compile(r"^(?P<path>.*?)(?P<var>[A-Za-z_][\w]*)\s*(?:\[(?P<idx>[^\]]*)\])?\s*$")


@dataclass(frozen=True)
class _TraceSignal:
    fid: str
    name: str
    variable: str
    axis_number: int | None
    interval_s: float
    units_type: str
    description: str
    declared_count: int | None


def _parse_signal_name(name: str) -> tuple[str, int | None]:
    """``"/Nck/!SD/nckServoDataFlwErr64 [u1, 7]"`` -> ``("nckServoDataFlwErr64", 7)``."""
    m = _NAME_RE.match(name.strip())
    if not m:
        return re.sub(r"\W+", "_", name).strip("_"), None
    var = m.group("var")
    idx = m.group("idx")
    axis: int | None = None
    if idx:
        nums = re.findall(r"\d+", idx)
        if len(nums) >= 2:
            axis = int(nums[1])
        elif len(nums) == 1 and not idx.strip().lower().startswith("u"):
            axis = int(nums[0])
    return var, axis


def _float_attr(el: ET.Element, attr: str, path: str, position: str) -> float:
    raw = el.get(attr)
    if raw is None:
        raise FormatError(f"missing attribute {attr!r}", path=path, position=position, field=attr)
    try:
        return float(raw)
    except ValueError:
        raise FormatError(
            f"attribute {attr!r} is {raw!r}, not a number", path=path, position=position,
            field=attr,
        ) from None


def read_sinumerik_trace(
    path: str | PathLike[str],
    *,
    axis_map: dict[int, str] | None = None,
    rotary: bool | None = None,
    salvage: bool = False,
) -> Recording:
    """Read a SINUMERIK Solution Line servo trace (XML) onto a regular servo-cycle grid.

    Parameters
    ----------
    path : str or path-like
        The ``.xml`` trace file.
    axis_map : dict, optional
        Axis number (the ``7`` in ``[u1, 7]``) -> axis name. Default: the thesis machine's
        :data:`~cnctwin.signals.DEFAULT_AXIS_MAP` for numbers 1-6, ``AX<n>`` otherwise.
    rotary : bool, optional
        Whether the traced axes are rotary (units deg, rpm) or linear (mm, mm/min). Default:
        inferred from the ratio of position-setpoint rate to velocity setpoint.
    salvage : bool, default False
        For a damaged file (truncated XML, bad values) keep the records read so far, skip bad
        values, set ``meta.partial`` and list what was skipped in ``meta.issues``.

    Returns
    -------
    Recording
        ``hf`` on a grid of the servo sample rate (``meta.cycle_time_s``), cycle 0 = the first
        frame's ``startTime``. ``meta.attrs["trace_signals"]`` maps each column to the original
        trace signal (name, description, key, interval, unitsType, record count).

    Raises
    ------
    FormatError
        Not a trace file, unknown signal id in a record, a non-numeric value, or a time off the
        sample grid (unless ``salvage``). :class:`~cnctwin.exceptions.TruncatedFileError` for
        XML that ends early.

    Notes
    -----
    Sample-and-hold reconstruction: for grid point :math:`k` (time :math:`k\\,T_s`), the value
    of signal :math:`s` is the value of its last record with time :math:`\\le k\\,T_s`.
    """
    p = Path(path)
    spath = str(p)
    if not p.exists():
        raise FormatError("file not found", path=spath)
    amap = dict(DEFAULT_AXIS_MAP if axis_map is None else axis_map)
    issues: list[str] = []
    partial = False

    servo_s: float | None = None
    session_name = ""
    version = ""
    frames: list[dict[str, Any]] = []
    cur: dict[str, Any] | None = None
    root_seen = False
    try:
        for event, el in ET.iterparse(spath, events=("start", "end")):
            tag = el.tag
            if event == "start":
                if not root_seen:
                    root_seen = True
                    if tag != "traceSession":
                        raise FormatError(
                            f"root element is <{tag}>, not <traceSession>: not a SINUMERIK "
                            "servo trace", path=spath, position="line 1",
                        )
                    version = el.get("version", "")
                if tag == "dataFrame":
                    cur = {"signals": {}, "recs": [], "header": {}}
                continue
            # end events
            if tag == "sampleRateSettings" and servo_s is None and el.get("servoSampleRate"):
                servo_s = _float_attr(el, "servoSampleRate", spath, "sampleRateSettings")
            elif tag == "sessionSettings" and not session_name:
                session_name = el.get("sessionName", "")
            elif tag == "frameHeader" and cur is not None:
                cur["header"] = dict(el.attrib)
            elif tag == "dataSignal" and cur is not None:
                fid = el.get("id", "")
                name = el.get("name", "")
                var, axis = _parse_signal_name(name)
                cnt = el.get("datapointCount")
                cur["signals"][fid] = _TraceSignal(
                    fid=fid, name=name, variable=var, axis_number=axis,
                    interval_s=_float_attr(el, "interval", spath, f"dataSignal id={fid}"),
                    units_type=el.get("unitsType", ""), description=el.get("description", ""),
                    declared_count=int(cnt) if cnt and cnt.isdigit() else None,
                )
            elif tag == "rec" and cur is not None:
                cur["recs"].append(dict(el.attrib))
                el.clear()
            elif tag == "dataFrame" and cur is not None:
                frames.append(cur)
                cur = None
    except ET.ParseError as exc:
        line_no, col_no = exc.position if hasattr(exc, "position") else (0, 0)
        msg = f"XML error: {exc}"
        if not salvage:
            # input that ends early (expat: no element found / unclosed token) is truncated;
            # any other error (bad syntax, binary junk) is a plain FormatError
            cls = TruncatedFileError if getattr(exc, "code", None) in _EOF_ERRORS else FormatError
            raise cls(
                msg + " (pass salvage=True to keep the records read so far)",
                path=spath, position=f"line {line_no}, column {col_no}",
            ) from None
        issues.append(f"{msg} at line {line_no}, column {col_no}; kept the records read before it")
        partial = True
        if cur is not None and cur["recs"]:
            frames.append(cur)

    if not frames:
        raise FormatError(
            "no <traceData>/<dataFrame> with records found", path=spath, field="traceData"
        )
    if servo_s is None:
        intervals = [s.interval_s for f in frames for s in f["signals"].values()]
        servo_s = min(intervals) if intervals else 0.002
        issues.append(f"no servoSampleRate in traceCaptureSetup; grid = smallest signal "
                      f"interval {servo_s * 1e3:g} ms")

    # ---------------------------------------------------------------- frames -> grid
    t0: pd.Timestamp | None = None
    frame_parts: list[pd.DataFrame] = []
    sig_info: dict[str, _TraceSignal] = {}
    rec_counts: dict[str, int] = {}
    held: dict[str, int] = {}
    for fi, frame in enumerate(frames):
        hdr = frame["header"]
        start_raw = hdr.get("startTime")
        start = pd.Timestamp(start_raw) if start_raw else None
        if start is not None and start.tzinfo is None:
            start = start.tz_localize("UTC")
        if t0 is None:
            t0 = start
            offset = 0
        elif start is not None:
            offset = round((start - t0).total_seconds() / servo_s)
        else:
            offset = 0
        if hdr.get("dropOuts") not in (None, "0"):
            issues.append(f"dataFrame {fi + 1}: the trace reports {hdr['dropOuts']} drop-outs")
        signals: dict[str, _TraceSignal] = frame["signals"]
        recs: list[dict[str, str]] = frame["recs"]
        if not recs:
            continue
        times = np.empty(len(recs))
        cols: dict[str, np.ndarray] = {fid: np.full(len(recs), np.nan) for fid in signals}
        for j, r in enumerate(recs):
            pos = f"dataFrame[{fi + 1}]/rec[{j + 1}]"
            t_raw = r.pop("time", None)
            try:
                times[j] = float(t_raw) if t_raw is not None else math.nan
            except ValueError:
                times[j] = math.nan
            if not math.isfinite(times[j]):
                if not salvage:
                    raise FormatError(f"record has no valid time ({t_raw!r})", path=spath,
                                      position=pos, field="time")
                issues.append(f"{pos}: no valid time, record skipped")
                partial = True
                continue
            for fid, raw in r.items():
                col = cols.get(fid)
                if col is None:
                    if not salvage:
                        raise FormatError(
                            f"value for signal id {fid!r}, which no <dataSignal> declares "
                            f"(declared: {', '.join(signals)})", path=spath, position=pos,
                            field=fid,
                        )
                    issues.append(f"{pos}: undeclared signal id {fid!r} skipped")
                    partial = True
                    continue
                try:
                    col[j] = float(raw)
                except ValueError:
                    if not salvage:
                        raise FormatError(f"value {raw!r} is not a number", path=spath,
                                          position=pos, field=fid) from None
                    issues.append(f"{pos}: value {raw!r} of {fid} is not a number, skipped")
                    partial = True
        ok = np.isfinite(times)
        k = np.rint(times / servo_s)
        off_grid = ok & (np.abs(k * servo_s - times) > 0.25 * servo_s)
        if off_grid.any():
            j = int(np.flatnonzero(off_grid)[0])
            if not salvage:
                raise FormatError(
                    f"record time {times[j]} s is not on the {servo_s * 1e3:g} ms servo grid",
                    path=spath, position=f"dataFrame[{fi + 1}]/rec[{j + 1}]", field="time",
                )
            issues.append(f"{int(off_grid.sum())} records off the servo grid were rounded to it")
        kk = k[ok].astype(np.int64) + offset
        if kk.size > 1 and (np.diff(kk) <= 0).any():
            j = int(np.flatnonzero(np.diff(kk) <= 0)[0]) + 1
            raise FormatError("record times are not strictly increasing", path=spath,
                              position=f"dataFrame[{fi + 1}]/rec[{j + 1}]", field="time")
        part = pd.DataFrame({fid: v[ok] for fid, v in cols.items()}, index=kk)
        full = np.arange(int(kk[0]), int(kk[-1]) + 1, dtype=np.int64)
        part = part.reindex(full)
        for fid, s in signals.items():
            key = f"{fi}:{fid}"
            col = part[fid].to_numpy()
            n_written = int(np.isfinite(col).sum())
            first = np.flatnonzero(np.isfinite(col))
            filled_before = int(first[0]) if first.size else len(col)
            filled = part[fid].ffill()
            n_held = int(np.isfinite(filled.to_numpy()).sum()) - n_written
            part[fid] = filled
            rec_counts[key] = n_written
            held[key] = n_held
            sig_info[key] = s
            if s.declared_count is not None and s.interval_s > servo_s * 1.5 and \
                    n_written != s.declared_count:
                issues.append(f"{s.name}: {n_written} records, the file declares "
                              f"{s.declared_count}")
            if filled_before:
                issues.append(f"{s.name}: NaN on the first {filled_before} grid point(s), "
                              "before its first record")
        part.columns = [f"{fi}:{c}" for c in part.columns]
        frame_parts.append(part)

    grid = pd.concat(frame_parts, axis=1) if len(frame_parts) > 1 else frame_parts[0]
    if len(frame_parts) > 1:
        grid = grid.groupby(level=0).last()
    grid.index.name = "cycle"

    # ---------------------------------------------------------------- columns, units
    def axis_name(n: int | None) -> str:
        if n is None:
            return "AX"
        if n in amap:
            return amap[n]
        return f"AX{n}"

    unknown_axes = sorted({s.axis_number for s in sig_info.values()
                           if s.axis_number is not None and s.axis_number not in amap})
    if unknown_axes:
        issues.append(
            "axis number(s) " + ", ".join(map(str, unknown_axes)) + " not in the axis map; "
            "named " + ", ".join(f"AX{n}" for n in unknown_axes) + " (pass axis_map= to name them)"
        )
    names: dict[str, str] = {}
    owner: dict[str, str] = {}  # column -> trace signal name
    for key, s in sig_info.items():
        code = TRACE_VARIABLE_MAP.get(s.variable, f"TRACE_{s.variable}")
        cname = f"{code}|{axis_name(s.axis_number)}"
        if owner.setdefault(cname, s.name) != s.name:  # two variables map to one code
            cname = f"{code}_{s.variable}|{axis_name(s.axis_number)}"
            owner[cname] = s.name
        names[key] = cname
    # same signal in several frames -> merge columns
    hf_cols: dict[str, pd.Series] = {}
    for key, cname in names.items():
        if cname in hf_cols:
            hf_cols[cname] = hf_cols[cname].combine_first(grid[key])
        else:
            hf_cols[cname] = grid[key]
    hf = pd.DataFrame(hf_cols, index=grid.index)

    is_rotary = rotary
    if is_rotary is None:
        is_rotary = _infer_rotary(hf, servo_s, issues)
    units: dict[str, str] = {}
    trace_signals: dict[str, dict[str, Any]] = {}
    for key, cname in names.items():
        s = sig_info[key]
        code = cname.split("|", 1)[0]
        pair = _UNITS.get(code) or _UNITS_TYPE.get(s.units_type, ("", ""))
        units[cname] = pair[1] if is_rotary else pair[0]
        trace_signals[cname] = {
            "name": s.name, "variable": s.variable, "description": s.description,
            "key": s.fid, "interval_s": s.interval_s, "units_type": s.units_type,
            "records": rec_counts[key], "held_grid_points": held[key],
        }
        if held[key]:
            kind = ("written every " f"{s.interval_s * 1e3:g} ms, held on the "
                    f"{servo_s * 1e3:g} ms grid") if s.interval_s > servo_s * 1.5 else \
                "written on change, held between changes"
            issues.append(f"{cname} ({s.name}): {kind}: {held[key]} of {len(hf)} grid points "
                          "are held values")
    if "SPEED_ACT_MOTOR" in {c.split("|")[0] for c in hf.columns}:
        issues.append("SPEED_ACT_MOTOR: the trace gives no unit (unitsType 'veloRot'); "
                      "kept unscaled")

    meta = RecordingMeta(
        machine=session_name,
        cycle_time_s=servo_s,
        axis_map={n: axis_name(n) for n in sorted({s.axis_number for s in sig_info.values()
                                                   if s.axis_number is not None})},
        units=units,
        source_files=[spath],
        source_format="servo_trace",
        time_anchors=[(0, t0)] if t0 is not None else [],
        gaps=find_gaps(hf.index.to_numpy()),
        issues=issues,
        partial=partial,
        attrs={
            "trace_signals": trace_signals,
            "trace_version": version,
            "session_name": session_name,
            "frames": len(frames),
            "rotary": bool(is_rotary),
        },
    )
    if t0 is None:
        issues.append("no frameHeader startTime: times start at the Unix epoch")
    return Recording(hf, meta=meta)


def _infer_rotary(hf: pd.DataFrame, servo_s: float, issues: list[str]) -> bool:
    """Rotary (deg, rpm) or linear (mm, mm/min), from d(DES_POS)/dt versus CMD_SPEED."""
    for col in hf.columns:
        code, _, axis = col.partition("|")
        if code != "DES_POS" or f"CMD_SPEED|{axis}" not in hf.columns:
            continue
        pos = hf[col].to_numpy()
        vel = hf[f"CMD_SPEED|{axis}"].to_numpy()
        rate = np.gradient(pos, servo_s)
        m = np.isfinite(rate) & np.isfinite(vel) & (np.abs(vel) > 0.1 * np.nanmax(np.abs(vel)))
        if m.sum() < 10:
            continue
        ratio = float(np.median(rate[m] / vel[m]))
        rot = abs(math.log10(abs(ratio) / 6.0)) < abs(math.log10(abs(ratio) * 60.0)) \
            if ratio != 0 else False
        issues.append(
            f"axis kind inferred {'rotary (deg, rpm)' if rot else 'linear (mm, mm/min)'} from "
            f"d({col})/dt = {ratio:.4g} x {code.replace('DES_POS', 'CMD_SPEED')}|{axis} "
            "(rotary: 6 deg/s per rpm; linear: 1/60 mm/s per mm/min); pass rotary= to override"
        )
        return rot
    issues.append("axis kind could not be inferred (no motion); assumed linear (mm, mm/min)")
    return False
