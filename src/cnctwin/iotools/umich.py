"""Reader for the University of Michigan SMART lab "CNC Mill Tool Wear" data set.

18 milling experiments on 2" x 2" x 1.5" wax blocks in a CNC mill; one CSV per experiment
(``experiment_01.csv`` ...), one row per 100 ms (10 Hz), 48 data columns: for each of X1, Y1, Z1
and the spindle S1 the actual and command position, velocity and acceleration, current
feedback, DC-bus voltage, output current, output voltage and output power (Z1 has no power
column; S1 adds ``S1_SystemInertia``), then ``M1_CURRENT_PROGRAM_NUMBER``,
``M1_sequence_number``, ``M1_CURRENT_FEEDRATE`` and the ``Machining_Process`` phase. The copy
vendored in ``tests/data/real/umich-cnc-mill`` (ejhusom/cnc_milling_tool_wear) adds a leading
row-number column and a ``tool_condition`` column; ``experiments.csv`` holds the labels.

Column mapping (``VARIABLE_MAP``; ``S1`` becomes the spindle ``SP1``):

==========================  ==========================  ====================================
source suffix               column                      unit (as documented by the source)
==========================  ==========================  ====================================
``ActualPosition``          ``ENC_POS|<axis>``          mm
``CommandPosition``         ``DES_POS|<axis>``          mm
``CurrentFeedback``         ``CURRENT|<axis>``          A
``OutputPower``             ``POWER|<axis>``            W (source kW x 1000)
``ActualVelocity``          ``VELOCITY_ACT|<axis>``     mm/s
``CommandVelocity``         ``VELOCITY_CMD|<axis>``     mm/s
``ActualAcceleration``      ``ACCELERATION_ACT|<axis>`` mm/s^2
``CommandAcceleration``     ``ACCELERATION_CMD|<axis>`` mm/s^2
``DCBusVoltage``            ``DC_BUS_VOLTAGE|<axis>``   V
``OutputCurrent``           ``OUTPUT_CURRENT|<axis>``   A
``OutputVoltage``           ``OUTPUT_VOLTAGE|<axis>``   V
``SystemInertia``           ``SYSTEM_INERTIA|SP1``      kg*m^2
``M1_CURRENT_PROGRAM_NUMBER``  ``PROGRAM_NUMBER``        -
``M1_sequence_number``      ``SEQUENCE_NUMBER``          -
``M1_CURRENT_FEEDRATE``     ``FEEDRATE``                 mm/s
==========================  ==========================  ====================================

Cycle base: the data set has no clock and no absolute time; each row is one 100 ms sample, so
``meta.cycle_time_s = 0.1`` (10 Hz), the cycle index is the row number (0 = first row) and times
start at the Unix epoch (noted in ``meta.issues``).

Validity: the data set's description says rows with ``M1_CURRENT_FEEDRATE == 50`` or
``X1_ActualPosition == 198`` are not valid machining data. Such rows are kept; the ``VALID``
column is 1.0 for valid and 0.0 for invalid rows, and the count is in ``meta.issues``.
``Machining_Process`` phase changes become ``events`` (kind ``"block"``, ``gcode`` = phase).
"""

from __future__ import annotations

import re
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from cnctwin.exceptions import FormatError
from cnctwin.iotools._csvtable import read_csv_table
from cnctwin.recording import EVENT_COLUMNS, Recording, RecordingMeta

__all__ = [
    "UMICH_CYCLE_TIME_S",
    "VARIABLE_MAP",
    "read_umich",
    "read_umich_dataset",
    "read_umich_labels",
]

UMICH_CYCLE_TIME_S = 0.1
"""Sample period of the data set (10 Hz) [s]."""

AXIS_NAMES: dict[str, str] = {"X1": "X1", "Y1": "Y1", "Z1": "Z1", "S1": "SP1"}
"""Source axis prefix -> cnctwin axis name."""

VARIABLE_MAP: dict[str, tuple[str, str, float]] = {
    "ActualPosition": ("ENC_POS", "mm", 1.0),
    "CommandPosition": ("DES_POS", "mm", 1.0),
    "CurrentFeedback": ("CURRENT", "A", 1.0),
    "OutputPower": ("POWER", "W", 1000.0),
    "ActualVelocity": ("VELOCITY_ACT", "mm/s", 1.0),
    "CommandVelocity": ("VELOCITY_CMD", "mm/s", 1.0),
    "ActualAcceleration": ("ACCELERATION_ACT", "mm/s^2", 1.0),
    "CommandAcceleration": ("ACCELERATION_CMD", "mm/s^2", 1.0),
    "DCBusVoltage": ("DC_BUS_VOLTAGE", "V", 1.0),
    "OutputCurrent": ("OUTPUT_CURRENT", "A", 1.0),
    "OutputVoltage": ("OUTPUT_VOLTAGE", "V", 1.0),
    "SystemInertia": ("SYSTEM_INERTIA", "kg*m^2", 1.0),
}
"""Source column suffix -> (column code, unit, scale factor to that unit)."""

_M1_MAP: dict[str, tuple[str, str]] = {
    "M1_CURRENT_PROGRAM_NUMBER": ("PROGRAM_NUMBER", ""),
    "M1_sequence_number": ("SEQUENCE_NUMBER", ""),
    "M1_CURRENT_FEEDRATE": ("FEEDRATE", "mm/s"),
}
_REQUIRED = ("X1_ActualPosition", "M1_CURRENT_FEEDRATE", "Machining_Process")
_INVALID_FEEDRATE = 50.0
_INVALID_X1_POSITION = 198.0
_EXP_RE = re.compile(r"experiment_(\d+)", re.IGNORECASE)


_MISSING = ("", "na", "NA", "Na", "nA")
"""Cells read as a missing value (NaN); ``nan`` is NaN anyway."""


def _yes_no(value: str, name: str) -> bool | None:
    """``yes``/``no`` (and y/n, true/false, 1/0) as a bool; an empty cell is ``None``."""
    v = value.strip().lower()
    if v in ("yes", "y", "true", "1"):
        return True
    if v in ("no", "n", "false", "0"):
        return False
    if v == "":
        return None
    raise ValueError(f"{name} {value!r} is not yes or no")


def read_umich_labels(path: str | PathLike[str]) -> dict[int, dict[str, Any]]:
    """Read ``experiments.csv``: experiment number -> labels.

    Parameters
    ----------
    path : str or path-like
        ``experiments.csv`` (columns ``No, material, feedrate, clamp_pressure, tool_condition,
        machining_finalized, passed_visual_inspection``).

    Returns
    -------
    dict
        ``{1: {"material": "wax", "feedrate": 6.0, "clamp_pressure": 4.0,
        "tool_condition": "unworn", "machining_finalized": True,
        "passed_visual_inspection": True}, ...}``. ``passed_visual_inspection`` is ``None``
        where the source leaves it empty (machining not finalized). Feedrate [mm/s], clamp
        pressure [bar] as in the data set description.
    """
    p = Path(path)
    if not p.exists():
        raise FormatError("labels file not found", path=str(p))
    out: dict[int, dict[str, Any]] = {}
    table = read_csv_table(p, path=str(p))
    needed = {"No", "tool_condition"}
    if not needed <= set(table.header):
        raise FormatError(f"header must contain {sorted(needed)}, found {table.header}",
                          path=str(p), position="line 1")
    cells = [table.text(j) for j in range(len(table.header))]
    first_line: dict[int, int] = {}
    for k, line in enumerate(table.lines.tolist()):
        row = {h: cells[j][k] for j, h in enumerate(table.header)}
        try:
            no = int(row["No"])
            labels: dict[str, Any] = {
                "material": row.get("material", ""),
                "feedrate": float(row["feedrate"]) if row.get("feedrate") else None,
                "clamp_pressure": (float(row["clamp_pressure"])
                                   if row.get("clamp_pressure") else None),
                "tool_condition": row["tool_condition"].strip(),
                "machining_finalized": _yes_no(row.get("machining_finalized") or "",
                                               "machining_finalized"),
                "passed_visual_inspection": _yes_no(
                    row.get("passed_visual_inspection") or "", "passed_visual_inspection"),
            }
        except (TypeError, ValueError) as exc:
            raise FormatError(f"bad label row: {exc}", path=str(p),
                              position=f"line {line}") from None
        if no in first_line:
            raise FormatError(f"experiment {no} is listed twice (lines {first_line[no]} and "
                              f"{line})", path=str(p), position=f"line {line}", field="No")
        first_line[no] = line
        out[no] = labels
    return out


def read_umich(
    path: str | PathLike[str],
    *,
    experiments_csv: str | PathLike[str] | None = None,
) -> Recording:
    """Read one experiment CSV of the UMich CNC Mill Tool Wear data set.

    Parameters
    ----------
    path : str or path-like
        ``experiment_NN.csv``.
    experiments_csv : str or path-like, optional
        Labels file; default ``experiments.csv`` beside ``path`` if it exists.

    Returns
    -------
    Recording
        10 Hz HF table (``meta.cycle_time_s = 0.1``) with the mapped columns and ``VALID``;
        ``events`` at phase changes; labels in ``meta.attrs["labels"]`` and the experiment
        number in ``meta.attrs["experiment"]``.

    Raises
    ------
    FormatError
        Missing required columns, rows of the wrong length or non-numeric values (the message
        names the line and column).
    """
    p = Path(path)
    spath = str(p)
    if not p.exists():
        raise FormatError("file not found", path=spath)
    issues: list[str] = []
    table = read_csv_table(p, path=spath)
    if table.blank_lines:
        raise FormatError("empty line inside the data", path=spath,
                          position=f"line {table.blank_lines[0]}")
    raw = {h: j for j, h in enumerate(table.header)}
    first = table.header[0] if table.header else ""
    if first == "" or first.startswith("Unnamed"):
        raw.pop(first)
    missing = [c for c in _REQUIRED if c not in raw]
    if missing:
        raise FormatError(
            f"not a UMich CNC mill file: missing column(s) {missing}", path=spath,
            position="line 1", field=missing[0],
        )
    n = table.n_rows
    data: dict[str, np.ndarray] = {}
    units: dict[str, str] = {}
    mapping: dict[str, str] = {}
    for src, j in raw.items():
        if src in ("Machining_Process", "tool_condition"):
            continue
        values = table.numbers(j, missing=_MISSING)
        prefix, _, suffix = src.partition("_")
        if src in _M1_MAP:
            name, unit = _M1_MAP[src]
        elif prefix in AXIS_NAMES and suffix in VARIABLE_MAP:
            code, unit, scale = VARIABLE_MAP[suffix]
            name = f"{code}|{AXIS_NAMES[prefix]}"
            if scale != 1.0:
                values = values * scale
        else:
            name, unit = src, ""
            issues.append(f"column {src!r} is not in the UMich column map; kept as {src!r}")
        data[name] = values
        units[name] = unit
        mapping[name] = src
    n_nan = sum(int(np.isnan(v).sum()) for v in data.values())
    if n_nan:
        issues.append(f"{n_nan} empty or NaN cells kept as NaN")

    feed = data["FEEDRATE"]
    x1 = data["ENC_POS|X1"]
    invalid = (feed == _INVALID_FEEDRATE) | (x1 == _INVALID_X1_POSITION)
    data["VALID"] = (~invalid).astype(np.float64)
    units["VALID"] = ""
    issues.append(
        f"{int(invalid.sum())} of {n} rows are not valid machining data "
        f"(M1_CURRENT_FEEDRATE == 50: {int((feed == _INVALID_FEEDRATE).sum())}, "
        f"X1_ActualPosition == 198: {int((x1 == _INVALID_X1_POSITION).sum())}); kept, "
        "VALID = 0"
    )
    for name in ("CURRENT|Z1", "OUTPUT_VOLTAGE|Z1", "OUTPUT_CURRENT|Z1", "DC_BUS_VOLTAGE|Z1"):
        if name in data and n and np.all(data[name] == 0.0):
            issues.append(f"{name} ({mapping[name]}) is zero in every row (not recorded by "
                          "the source)")
    issues.append("no absolute time in the source: cycle = row number at 10 Hz, times start "
                  "at the Unix epoch")

    cycles = np.arange(n, dtype=np.int64)
    hf = pd.DataFrame(data, index=pd.Index(cycles, name="cycle"))

    phase = np.asarray(table.text(raw["Machining_Process"]), dtype=object)
    change = np.ones(n, dtype=bool)
    change[1:] = phase[1:] != phase[:-1]
    idx = np.flatnonzero(change)
    events = pd.DataFrame({c: pd.Series([None] * idx.size, dtype="object")
                           for c in EVENT_COLUMNS})
    events["cycle"] = cycles[idx]
    events["kind"] = "block"
    events["gcode"] = phase[idx]
    for c in ("channel", "seek_offset", "selected_tool", "active_tool", "call_stack_level"):
        events[c] = pd.Series([pd.NA] * idx.size, dtype="Int64")

    attrs: dict[str, Any] = {"column_map": mapping, "phases": sorted(set(phase.tolist()))}
    m = _EXP_RE.search(p.stem)
    exp_no = int(m.group(1)) if m else None
    attrs["experiment"] = exp_no
    if "tool_condition" in raw:
        conds = sorted(set(table.text(raw["tool_condition"])))
        attrs["tool_condition_column"] = conds[0] if len(conds) == 1 else conds
    lab_path = Path(experiments_csv) if experiments_csv is not None else \
        p.parent / "experiments.csv"
    if experiments_csv is not None or lab_path.exists():
        labels = read_umich_labels(lab_path)
        if exp_no is None or exp_no not in labels:
            issues.append(f"no label row for experiment {exp_no} in {lab_path}")
        else:
            attrs["labels"] = labels[exp_no]
            col_cond = attrs.get("tool_condition_column")
            if isinstance(col_cond, str) and col_cond != labels[exp_no]["tool_condition"]:
                issues.append(f"tool_condition column says {col_cond!r}, experiments.csv "
                              f"says {labels[exp_no]['tool_condition']!r}")
    meta = RecordingMeta(
        machine="UMich SMART lab CNC mill",
        cycle_time_s=UMICH_CYCLE_TIME_S,
        axis_map={1: "X1", 2: "Y1", 3: "Z1", 4: "SP1"},
        units=units,
        source_files=[spath],
        source_format="umich",
        issues=issues,
        attrs=attrs,
    )
    return Recording(hf, events=events, meta=meta)


def read_umich_dataset(
    directory: str | PathLike[str],
    *,
    experiments_csv: str | PathLike[str] | None = None,
) -> list[Recording]:
    """Read every ``experiment_*.csv`` in a directory, ordered by experiment number.

    Parameters
    ----------
    directory : str or path-like
        Folder with the experiment CSVs (and normally ``experiments.csv``).
    experiments_csv : str or path-like, optional
        Labels file; default ``experiments.csv`` in ``directory``.

    Returns
    -------
    list of Recording
    """
    d = Path(directory)
    if not d.is_dir():
        raise FormatError("not a directory", path=str(d))
    files = sorted(
        (f for f in d.glob("experiment_*.csv") if _EXP_RE.search(f.stem)),
        key=lambda f: int(_EXP_RE.search(f.stem).group(1)),  # type: ignore[union-attr]
    )
    if not files:
        raise FormatError("no experiment_*.csv files found", path=str(d))
    return [read_umich(f, experiments_csv=experiments_csv) for f in files]
