"""Flattened CSV export in the KIT CNC-milling layout.

The KIT data set (Ströbel et al. 2025, DOI 10.35097/hvvwn1kfwf7qt48z) publishes each trial as
``<TRIAL>_hfdata.csv``, ``<TRIAL>_header.csv`` and ``<TRIAL>_hfblockevent.csv``;
:func:`write_csv` writes a recording the same way, so
:func:`cnctwin.iotools.flat_csv.read_flat_csv` reads it back:

* ``<stem>_hfdata.csv``: ``CYCLE`` (raw counter, modulo 2**31), the HF columns by address
  ``CODE|n`` and, unless ``time=False``, an ISO 8601 UTC ``time`` column;
* ``<stem>_header.csv``: ``SignalName,Type,Axis,Address`` (axis names of the numbers);
* ``<stem>_hfblockevent.csv``:
  ``HFProbeCounter,Channel,SeekOffset,SelectedTool,ActiveTool,GCode,IpoGC,ipoReadError,laBuf``;
* ``<stem>_hfcallevent.csv``: ``HFProbeCounter,Channel,SeekOffset,CallStackLevel,Path``;
* ``<stem>_lfdata.csv``: ``HFProbeCounter,address,value`` (not part of the KIT layout).

Floats are written in the shortest form that reads back to the same float64; NaN is an empty
cell.
"""

from __future__ import annotations

import csv
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from cnctwin.recording import CYCLE_COUNTER_MODULUS, Recording
from cnctwin.signals import parse_column

__all__ = ["csv_stem", "write_csv"]

_BLOCK = (("HFProbeCounter", "cycle"), ("Channel", "channel"), ("SeekOffset", "seek_offset"),
          ("SelectedTool", "selected_tool"), ("ActiveTool", "active_tool"), ("GCode", "gcode"),
          ("IpoGC", "ipo_gcode"), ("ipoReadError", "ipo_read_error"), ("laBuf", "la_buf"))
_CALL = (("HFProbeCounter", "cycle"), ("Channel", "channel"), ("SeekOffset", "seek_offset"),
         ("CallStackLevel", "call_stack_level"), ("Path", "path"))


def csv_stem(path: str | PathLike[str]) -> Path:
    """The trial stem of ``run``, ``run.csv`` or ``run_hfdata.csv`` (-> ``run``).

    Parameters
    ----------
    path : str or path-like
        Any file of an export, or its stem.

    Returns
    -------
    pathlib.Path
    """
    p = Path(path)
    name = p.name
    for suffix in ("_hfdata.csv", ".csv"):
        if name.endswith(suffix):
            return p.with_name(name[: -len(suffix)])
    return p


def _cell(v: Any) -> Any:
    if v is None or v is pd.NA or (isinstance(v, float) and np.isnan(v)):
        return ""
    if isinstance(v, np.integer):
        return int(v)
    return v


def write_csv(
    rec: Recording, path: str | PathLike[str], *, time: bool = True
) -> dict[str, Path]:
    """Write a recording as flattened CSV files in the KIT layout.

    Parameters
    ----------
    rec : Recording
        The recording.
    path : str or path-like
        The stem (``out/T01``), or ``out/T01.csv`` / ``out/T01_hfdata.csv``.
    time : bool, default True
        Add an ISO 8601 UTC ``time`` column to ``_hfdata.csv`` (not in the KIT files; it keeps
        the absolute time for the reader).

    Returns
    -------
    dict
        ``{"hfdata": Path, "header": Path, "hfblockevent": Path, "hfcallevent": Path,
        "lfdata": Path}`` of the files written (event and LF files only when there is data).
    """
    import pyarrow as pa
    import pyarrow.csv as pacsv

    from cnctwin.iotools.capture4analysis_writer import _axis_numbers

    stem = csv_stem(path)
    stem.parent.mkdir(parents=True, exist_ok=True)
    out: dict[str, Path] = {}
    cols = rec.columns
    numbers = _axis_numbers(cols, rec.meta.axis_map or None)
    addresses: list[str] = []
    header_rows = [("CYCLE", "INTEGER", "Cycle", "CYCLE")]
    for c in cols:
        code, axis = parse_column(c)
        if axis is None or axis.isdigit():
            addr, axis_name = c, ""
        else:
            addr, axis_name = f"{code}|{numbers[axis]}", axis
        addresses.append(addr)
        header_rows.append((addr, "DOUBLE", axis_name, addr))

    arrays = [pa.array(rec.cycles % CYCLE_COUNTER_MODULUS, type=pa.int64())]
    names = ["CYCLE"]
    for c, addr in zip(cols, addresses, strict=True):
        arrays.append(pa.array(rec.hf[c].to_numpy(dtype=np.float64), from_pandas=True))
        names.append(addr)
    if time:
        t = rec.hf["time"].dt.strftime("%Y-%m-%dT%H:%M:%S.%fZ")
        arrays.append(pa.array(t.to_numpy(dtype=object), type=pa.string()))
        names.append("time")
    table = pa.Table.from_arrays(arrays, names=names)
    target = stem.with_name(stem.name + "_hfdata.csv")
    with target.open("wb") as fh:
        fh.write((",".join(names) + "\n").encode())
        pacsv.write_csv(table, fh, pacsv.WriteOptions(include_header=False,
                                                      quoting_style="needed"))
    out["hfdata"] = target

    target = stem.with_name(stem.name + "_header.csv")
    with target.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(("SignalName", "Type", "Axis", "Address"))
        w.writerows(header_rows)
    out["header"] = target

    ev = rec.events
    for kind, fields, key in (("block", _BLOCK, "hfblockevent"), ("call", _CALL, "hfcallevent")):
        sel = ev[ev["kind"] == kind] if len(ev) else ev
        if not len(sel):
            continue
        target = stem.with_name(f"{stem.name}_{key}.csv")
        with target.open("w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh, lineterminator="\n")
            w.writerow([f for f, _ in fields])
            present = [(f, c) for f, c in fields]
            for row in sel.to_dict("records"):
                cyc = int(row["cycle"]) % CYCLE_COUNTER_MODULUS
                w.writerow([cyc if c == "cycle" else _cell(row.get(c)) for _, c in present])
        out[key] = target

    if len(rec.lf):
        target = stem.with_name(stem.name + "_lfdata.csv")
        with target.open("w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh, lineterminator="\n")
            w.writerow(("HFProbeCounter", "address", "value"))
            for c, s, v, txt in zip(rec.lf["cycle"], rec.lf["signal"], rec.lf["value"],
                                    rec.lf["text"], strict=True):
                value = txt if isinstance(txt, str) else ("" if np.isnan(v) else repr(float(v)))
                w.writerow((int(c) % CYCLE_COUNTER_MODULUS, s, value))
        out["lfdata"] = target
    return out
