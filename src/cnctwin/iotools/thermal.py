"""Reader for thermal-camera readings (one temperature per hole or per frame) as an external
channel.

Readings are irregular (typically one per drilled hole), so the channel has ``fs_hz = None``.
The cnctwin simulator writes ``time_s,hole,temperature_c`` (comma-separated, header line,
seconds on the camera's own clock, hole number from 1, degrees Celsius). Accepted variants
(case-insensitive; delimiter ``,`` ``;`` or tab; decimal comma with ``;``):

* time: ``time_s``, ``time``, ``t``, ``Time [s]``, ``time_ms`` / ``[ms]``, or a clock/datetime
  text (``00:01:02.500``, ``2024-05-01T10:00:01.5``; FLIR exports) -> seconds since the first
  reading;
* hole: ``hole``, ``hole_index``, ``hole_no``, ``Hole #``;
* temperature: ``temperature_c``, ``temperature``, ``temp_c``, ``temp``, ``T``, and FLIR-style
  measurement columns with a unit (``Sp1 [°C]``, ``Bx1 Max [°C]``, ``Bx1.Max (C)``,
  ``El1 Avg [K]``, ``... [°F]``) -> converted to °C.

Leading metadata lines (FLIR files start with ``File:``, ``Date:``, ``Emissivity:`` ...) are
skipped up to the first line that has a temperature column. The canonical ``temperature_c`` is
the column named temperature/temp, else the first ``Max`` measurement, else the first
temperature column; every temperature column is also kept as ``<name>_c``.

The index is ``time_s`` when the file has a time column; otherwise it is the hole number
(index name ``hole``) and the channel cannot be time-aligned until times are assigned.
"""

from __future__ import annotations

import csv
import re
from os import PathLike
from pathlib import Path

import numpy as np
import pandas as pd

from cnctwin.exceptions import FormatError
from cnctwin.iotools._csvtable import read_csv_table
from cnctwin.iotools._text import read_utf8_text
from cnctwin.recording import ExternalChannel

__all__ = ["THERMAL_CAMERA_FILE", "find_thermal_camera", "read_thermal_camera_csv"]

_UNIT_RE = re.compile(r"^\s*(?P<name>.*?)\s*[\[(](?P<unit>[^\])]*)[\])]\s*$")
_TEMP_UNITS = {"°c": "c", "c": "c", "degc": "c", "deg c": "c", "celsius": "c", "k": "k",
               "kelvin": "k", "°f": "f", "f": "f", "degf": "f"}
_TIME_UNITS = {"s": 1.0, "sec": 1.0, "ms": 1e-3, "min": 60.0}
_TIME_NAMES = {"time", "t", "timestamp", "zeit", "time_s", "times", "time_ms", "timems"}
_HOLE_NAMES = {"hole", "holeindex", "holeno", "holenumber", "hole#", "holenr", "hole_idx",
               "holeidx"}
_TEMP_NAMES = {"temperature", "temperaturec", "temp", "tempc", "t_c", "tc"}


def _norm(s: str) -> str:
    return re.sub(r"[\s_\-.]+", "", s.strip().lower())


def _to_c(values: np.ndarray, unit: str) -> np.ndarray:
    if unit == "k":
        return values - 273.15
    if unit == "f":
        return (values - 32.0) * 5.0 / 9.0
    return values


def _classify(header: str) -> tuple[str, str | float] | None:
    """('time', scale) | ('hole', '') | ('temp', unit) | None."""
    m = _UNIT_RE.match(header)
    name, unit = (m.group("name"), m.group("unit").strip().lower()) if m else (header, None)
    n = _norm(name)
    if n in _TIME_NAMES:
        if n in ("timems",):
            return "time", 1e-3
        if unit is not None and unit in _TIME_UNITS:
            return "time", _TIME_UNITS[unit]
        return "time", 1.0
    if n in _HOLE_NAMES or n.startswith("hole"):
        return "hole", ""
    if unit is not None and unit in _TEMP_UNITS:
        return "temp", _TEMP_UNITS[unit]
    if n in _TEMP_NAMES:
        return "temp", "c"
    return None


def _parse_time(cells: list[str], path: str, line0: int, field: str) -> np.ndarray:
    try:
        return np.array([float(c) for c in cells], dtype=np.float64)
    except ValueError:
        pass
    if all(re.fullmatch(r"\d+:\d{2}(:\d{2})?([.,]\d+)?", c.strip()) for c in cells):
        out = []
        for c in cells:
            parts = [float(x.replace(",", ".")) for x in c.strip().split(":")]
            if len(parts) == 2:
                parts = [0.0, *parts]
            out.append(parts[0] * 3600 + parts[1] * 60 + parts[2])
        t = np.asarray(out)
        return t - t[0]
    ts = pd.to_datetime(pd.Series(cells), errors="coerce", utc=True, format="ISO8601")
    if ts.isna().any():
        i = int(np.flatnonzero(ts.isna().to_numpy())[0])
        raise FormatError(f"time {cells[i]!r} is neither seconds, hh:mm:ss nor a date-time",
                          path=path, position=f"line {line0 + i}", field=field)
    return (ts - ts.iloc[0]).dt.total_seconds().to_numpy(dtype=np.float64)


def read_thermal_camera_csv(
    path: str | PathLike[str],
    *,
    name: str = "thermal_camera",
) -> ExternalChannel:
    """Read thermal-camera readings into an external channel.

    Parameters
    ----------
    path : str or path-like
        CSV file (see the module docstring for accepted headers).
    name : str, default 'thermal_camera'
        Channel name.

    Returns
    -------
    ExternalChannel
        ``data`` with ``temperature_c`` [°C] (plus ``hole`` and any further temperature
        columns as ``<name>_c``), indexed by ``time_s`` [s] or, without a time column, by
        ``hole``. ``fs_hz`` is None (irregular readings).

    Raises
    ------
    FormatError
        No temperature column, neither time nor hole column, rows of the wrong length,
        non-numeric values (line and column named).
    """
    p = Path(path)
    spath = str(p)
    text = read_utf8_text(p)
    lines = text.splitlines()
    header_line = None
    delim = ","
    for i, line in enumerate(lines[:100]):
        d = max((";", ",", "\t"), key=line.count)
        cells = next(csv.reader([line], delimiter=d)) if line.strip() else []  # header only
        kinds = [_classify(c) for c in cells]
        if len(cells) >= 2 and any(k is not None and k[0] == "temp" for k in kinds):
            header_line, delim = i, d
            break
    if header_line is None:
        raise FormatError(
            "no header with a temperature column found in the first 100 lines; expected e.g. "
            "time_s,hole,temperature_c or FLIR columns like 'Sp1 [°C]'", path=spath,
        )
    table = read_csv_table(text, path=spath, delimiter=delim, header_line=header_line + 1)
    if not table.n_rows:
        raise FormatError("no readings after the header", path=spath,
                          position=f"line {header_line + 1}")
    decimal_comma = table.has_decimal_comma()
    header = table.header
    kinds = [_classify(h) for h in header]
    cols: dict[str, np.ndarray] = {}
    units: dict[str, str] = {}
    time_s: np.ndarray | None = None
    hole: np.ndarray | None = None
    temps: list[tuple[str, np.ndarray]] = []
    first_line = int(table.lines[0])
    for j, (h, k) in enumerate(zip(header, kinds, strict=True)):
        if k is not None and k[0] == "time":
            cells = [c.strip() for c in table.text(j)]
            if decimal_comma:
                cells = [c.replace(",", ".") for c in cells]
            time_s = _parse_time(cells, spath, first_line, h) * float(k[1])
            continue
        try:
            vals = table.numbers(j, decimal_comma=decimal_comma)
        except FormatError:
            if k is None:  # a text column (frame label, comment): not a reading
                continue
            raise
        if k is None:
            key = _norm(h) or f"col{j}"
            cols[key] = vals
            units[key] = ""
        elif k[0] == "hole":
            hole = vals
        else:
            temps.append((h, _to_c(vals, str(k[1]))))
    if not temps:
        raise FormatError("no temperature column", path=spath, position="line 1")
    if time_s is None and hole is None:
        raise FormatError("neither a time nor a hole column; expected time_s or hole",
                          path=spath, position=f"line {header_line + 1}")
    pick = next((i for i, (h, _) in enumerate(temps) if _norm(_UNIT_RE.sub(
        r"\g<name>", h)) in _TEMP_NAMES), None)
    if pick is None:
        pick = next((i for i, (h, _) in enumerate(temps) if "max" in h.lower()), 0)
    out: dict[str, np.ndarray] = {"temperature_c": temps[pick][1]}
    out_units = {"temperature_c": "degC"}
    for i, (h, v) in enumerate(temps):
        if i == pick and _norm(_UNIT_RE.sub(r"\g<name>", h)) in _TEMP_NAMES:
            continue
        m = _UNIT_RE.match(h)
        key = _norm(m.group("name") if m else h) + "_c"
        out[key] = v
        out_units[key] = "degC"
    if hole is not None:
        out["hole"] = hole
        out_units["hole"] = ""
    out.update(cols)
    out_units.update(units)
    if time_s is not None:
        if np.isnan(time_s).any() or (np.diff(time_s) < 0).any():
            raise FormatError("time values missing or decreasing", path=spath, field="time_s")
        index = pd.Index(time_s, name="time_s")
    else:
        assert hole is not None
        out.pop("hole")
        out_units.pop("hole")
        index = pd.Index(hole, name="hole")
    data = pd.DataFrame(out, index=index)
    return ExternalChannel(name=name, data=data, units=out_units, fs_hz=None, source=spath)


THERMAL_CAMERA_FILE = "thermal_camera.csv"
"""File name of the camera readings beside a recording (what the simulator writes)."""


def find_thermal_camera(recording_path: str | PathLike[str]) -> Path | None:
    """The thermal-camera file that belongs to a recording, if one lies beside it.

    Parameters
    ----------
    recording_path : str or path-like
        A recording file, or a recording directory (the Parquet layouts).

    Returns
    -------
    pathlib.Path or None
        ``thermal_camera.csv`` in the recording file's folder, or inside or beside a
        recording directory (``cnctwin simulate tool_wear_run --out DIR`` writes it there);
        None when there is none.
    """
    p = Path(recording_path)
    folders = [p, p.parent] if p.is_dir() else [p.parent]
    for folder in folders:
        cand = folder / THERMAL_CAMERA_FILE
        if cand.is_file():
            return cand
    return None
