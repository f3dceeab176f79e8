"""Reader for the KIT (wbk) merged milling CSVs: edge drive signals + dynamometer per row.

The DMG MORI DMC 60H recordings of the KIT series (S235JR plates; the EnKJneer/Masters-thesis
``Data/DMC_*.csv`` files) merge the SINUMERIK / Industrial Edge drive signals, filtered and
resampled to 50 Hz by the authors, with a dynamometer and with the authors' process
simulation, one row per 20 ms. The header (``kit_layout_sample.csv`` in the shared data):

``Unnamed: 0,time,pos_x,pos_y,pos_z,pos_sp,cmd_pos_x,...,cmd_v_sp,cont_dev_x,...,v_x,a_x,v_y,
a_y,v_z,a_z,v_sp,a_sp,time_diff,f_x,f_y,f_z,a_p,a_e,phi,curr_x,curr_y,curr_z,curr_sp,
f_x_sim,f_y_sim,f_z_sim,f_sp_sim,materialremoved_sim``

Any subset of these columns is read (the excerpts keep a few), and ``#`` lines are comments.

Mapping (``<a>`` is ``x``, ``y``, ``z``, ``sp`` -> ``X1``, ``Y1``, ``Z1``, ``SP1``):

* ``Unnamed: 0`` / ``idx``: the cycle counter (row number of the source, 50 Hz);
* ``time`` [s] -> ``time`` (from the Unix epoch: the files carry no clock);
* ``pos_<a>`` -> ``ENC_POS|<A>``, ``cmd_pos_<a>`` -> ``DES_POS|<A>``, ``cont_dev_<a>`` ->
  ``CONT_DEV|<A>`` [mm; spindle deg];
* ``cmd_v_<a>`` -> ``VELOCITY_CMD|<A>`` [mm/s]; the spindle's -> ``CMD_SPEED|SP1`` [rpm]
  (deg/s / 6);
* ``v_<a>`` -> ``VELOCITY_ACT|<A>`` [mm/s]; the spindle's -> ``SPEED_ACT|SP1`` [rpm];
* ``a_<a>`` -> ``ACCELERATION_ACT|<A>`` [mm/s^2; spindle deg/s^2];
* ``curr_<a>`` -> ``CURRENT|<A>`` [A, signed as recorded]; ``time_diff`` -> ``TIME_DIFF`` [s];
* ``f_x``, ``f_y``, ``f_z`` -> external channel ``dynamometer`` (``fx``, ``fy``, ``fz``), unit
  **unknown**;
* ``a_p``, ``a_e``, ``phi`` -> external ``process`` (``a_p_mm``, ``a_e_mm``, ``phi_deg``);
* ``*_sim`` -> external ``simulation`` (the authors' process model; forces in N, the removed
  material in an unstated unit).

The force unit is not
stated in the data set; the values are about 200 times smaller than the file's own simulated
force in N, so they are kept with the unit ``"unknown"`` and never taken for newtons. Columns
the reader does not know are kept as HF columns under their name with an empty unit and listed
in ``meta.issues``.
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path

import numpy as np
import pandas as pd

from cnctwin.exceptions import FormatError
from cnctwin.recording import ExternalChannel, Recording, RecordingMeta, find_gaps

__all__ = ["KIT_CYCLE_TIME_S", "looks_like_kit_merged", "read_kit_merged"]

KIT_CYCLE_TIME_S = 0.02
"""Row period of the merged files (resampled to 50 Hz by the authors) [s]."""

_AXES = {"x": "X1", "y": "Y1", "z": "Z1", "sp": "SP1"}
_DEG_S_TO_RPM = 1.0 / 6.0


def looks_like_kit_merged(header: str) -> bool:
    """True for a CSV header of the KIT merged layout (``curr_sp`` and a spindle column).

    Parameters
    ----------
    header : str
        The first line of a CSV file.

    Returns
    -------
    bool
    """
    cols = {c.strip() for c in header.split(",")}
    return "curr_sp" in cols and bool(cols & {"v_sp", "pos_sp", "cmd_v_sp"})


def _hf_name(col: str) -> tuple[str, str, float] | None:
    """KIT column -> (cnctwin column, unit, scale), or None for the non-HF columns."""
    for prefix, code in (("cmd_pos_", "DES_POS"), ("cmd_v_", "VELOCITY_CMD"),
                         ("cont_dev_", "CONT_DEV"), ("pos_", "ENC_POS"), ("v_", "VELOCITY_ACT"),
                         ("a_", "ACCELERATION_ACT"), ("curr_", "CURRENT")):
        if col.startswith(prefix) and col[len(prefix):] in _AXES:
            ax = _AXES[col[len(prefix):]]
            spindle = ax == "SP1"
            if code == "CURRENT":
                return f"CURRENT|{ax}", "A", 1.0
            if spindle and code == "VELOCITY_CMD":
                return "CMD_SPEED|SP1", "rpm", _DEG_S_TO_RPM
            if spindle and code == "VELOCITY_ACT":
                return "SPEED_ACT|SP1", "rpm", _DEG_S_TO_RPM
            unit = {"DES_POS": "mm", "ENC_POS": "mm", "CONT_DEV": "mm", "VELOCITY_CMD": "mm/s",
                    "VELOCITY_ACT": "mm/s", "ACCELERATION_ACT": "mm/s^2"}[code]
            if spindle:
                unit = unit.replace("mm", "deg")
            return f"{code}|{ax}", unit, 1.0
    if col == "time_diff":
        return "TIME_DIFF", "s", 1.0
    return None


def read_kit_merged(path: str | PathLike[str]) -> Recording:
    """Read a KIT merged milling CSV (or an excerpt with a subset of its columns).

    Parameters
    ----------
    path : str or path-like
        The CSV file.

    Returns
    -------
    Recording
        HF table on the 50 Hz row base (``meta.cycle_time_s = 0.02``, the cycle is the source
        row number, gaps in it are counter gaps), external channels ``dynamometer`` (unit
        unknown, on the recording's clock: ``aligned``), ``process`` and ``simulation`` where
        the file has them.

    Raises
    ------
    FormatError
        Not the KIT layout, no ``time`` column, non-numeric cells (line and column named),
        time not increasing.
    """
    p = Path(path)
    spath = str(p)
    try:
        df = pd.read_csv(p, comment="#", skip_blank_lines=True)
    except (OSError, UnicodeDecodeError, pd.errors.ParserError, pd.errors.EmptyDataError) as exc:
        raise FormatError(f"cannot read the CSV: {exc}", path=spath) from None
    df.columns = [str(c).strip() for c in df.columns]
    if not looks_like_kit_merged(",".join(df.columns)):
        raise FormatError("not the KIT merged layout (expected curr_sp and v_sp/pos_sp columns)",
                          path=spath, position="header")
    if "time" not in df.columns:
        raise FormatError("no 'time' column", path=spath, position="header", field="time")
    for c in df.columns:
        if not pd.api.types.is_numeric_dtype(df[c]):
            bad = pd.to_numeric(df[c], errors="coerce").isna() & df[c].notna()
            i = int(np.flatnonzero(bad.to_numpy())[0]) if bad.any() else 0
            raise FormatError(f"value {df[c].iloc[i]!r} is not a number", path=spath,
                              position=f"data row {i + 1}", field=c)
    issues: list[str] = ["the file carries no wall-clock time: times start at the Unix "
                         "epoch; the drive signals were filtered and resampled to 50 Hz by "
                         "the data set's authors"]
    idx_col = next((c for c in ("Unnamed: 0", "idx", "") if c in df.columns), None)
    t = df["time"].to_numpy(dtype=np.float64)
    if np.any(np.diff(t) <= 0):
        i = int(np.flatnonzero(np.diff(t) <= 0)[0])
        raise FormatError("time is not strictly increasing", path=spath,
                          position=f"data row {i + 2}", field="time")
    if idx_col is not None:
        cycles = df[idx_col].to_numpy(dtype=np.int64)
    else:
        cycles = np.round(t / KIT_CYCLE_TIME_S).astype(np.int64)
        issues.append("no row-number column: the cycle is time / 20 ms")
    hf: dict[str, np.ndarray] = {}
    units: dict[str, str] = {}
    dyn: dict[str, np.ndarray] = {}
    process: dict[str, np.ndarray] = {}
    sim: dict[str, np.ndarray] = {}
    sim_units: dict[str, str] = {}
    unknown: list[str] = []
    for c in df.columns:
        if c in ("time", idx_col):
            continue
        v = df[c].to_numpy(dtype=np.float64)
        m = _hf_name(c)
        if m is not None:
            hf[m[0]] = v * m[2]
            units[m[0]] = m[1]
        elif c in ("f_x", "f_y", "f_z"):
            dyn[c.replace("_", "")] = v
        elif c in ("a_p", "a_e"):
            process[f"{c}_mm"] = v
        elif c == "phi":
            process["phi_deg"] = v
        elif c.endswith("_sim"):
            sim[c] = v
            sim_units[c] = "N" if c.startswith("f_") else "unknown"
        else:
            hf[c] = v
            units[c] = ""
            unknown.append(c)
    if unknown:
        issues.append(f"columns kept under their own name (not mapped): {unknown}")
    data = pd.DataFrame(hf, index=pd.Index(cycles, name="cycle"))
    data.insert(0, "time", pd.to_datetime(np.round(t * 1e9).astype(np.int64), unit="ns",
                                          utc=True))
    index = pd.Index(t, name="time_s")
    external: dict[str, ExternalChannel] = {}
    if dyn:
        external["dynamometer"] = ExternalChannel(
            name="dynamometer", data=pd.DataFrame(dyn, index=index),
            units=dict.fromkeys(dyn, "unknown"), fs_hz=1.0 / KIT_CYCLE_TIME_S, aligned=True,
            source=spath)
        issues.append("dynamometer forces f_x, f_y, f_z: unit not stated in the data set "
                      "(about 1/200 of the simulated force in N): kept with the unit 'unknown'")
    if process:
        external["process"] = ExternalChannel(
            name="process", data=pd.DataFrame(process, index=index),
            units={k: "deg" if k == "phi_deg" else "mm" for k in process},
            fs_hz=1.0 / KIT_CYCLE_TIME_S, aligned=True, source=spath)
    if sim:
        external["simulation"] = ExternalChannel(
            name="simulation", data=pd.DataFrame(sim, index=index), units=sim_units,
            fs_hz=1.0 / KIT_CYCLE_TIME_S, aligned=True, source=spath)
    meta = RecordingMeta(machine="", cycle_time_s=KIT_CYCLE_TIME_S,
                         axis_map={1: "X1", 2: "Y1", 3: "Z1", 4: "SP1"}, units=units,
                         source_files=[spath], source_format="kit_merged",
                         time_anchors=[(int(cycles[0]), data["time"].iloc[0])] if len(df) else [],
                         gaps=find_gaps(cycles), issues=issues)
    return Recording(data, external=external, meta=meta)
