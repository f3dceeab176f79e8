"""Readers for rotary/table dynamometer recordings (CSV and NI TDMS) as external channels.

A dynamometer has its own clock, so it is read into an
:class:`~cnctwin.recording.ExternalChannel` (index ``time_s`` = the source's own time [s]) and
attached to a recording with :func:`attach_external`; the clock offset/drift to the HF cycle
base is estimated later by alignment.

Canonical columns: ``fx_n``, ``fy_n``, ``fz_n`` [N] and ``mz_nm`` [N*m]. The cnctwin simulator
writes exactly ``time_s,fx_n,fy_n,fz_n,mz_nm`` (comma-separated, header line, SI units). Common
variants are accepted (case-insensitive; delimiter ``,`` ``;`` or tab; decimal comma with ``;``):

* time: ``time_s``, ``time``, ``t``, ``Time [s]``, ``t (s)``, ``time_ms`` / ``[ms]`` (-> s);
* forces: ``fx_n``, ``Fx``, ``F_x``, ``Fx [N]``, ``Fx (kN)`` (-> N), ``force_x``; same for y, z;
* torque: ``mz_nm``, ``Mz``, ``M_z``, ``Mz [Nm]``, ``Mz [N*m]``, ``Mz [Ncm]`` (-> N*m),
  ``torque_z``, ``torque``.

A unit in brackets or parentheses (or as a ``_n`` / ``_kn`` / ``_nm`` suffix) is converted to
the canonical unit; an unknown unit raises :class:`~cnctwin.exceptions.FormatError` listing the
accepted ones. A force or torque header without any unit (``Fx``, ``f_x``) is never taken for
newtons: the column is kept as ``fx`` / ``fy`` / ``fz`` / ``mz`` with the unit ``"unknown"``
(:data:`UNKNOWN_UNIT_COLUMNS`); a calibration that needs the torque in N*m then says so.
Without a time column the sample rate ``fs_hz`` is required.

TDMS (NI DAQ, e.g. Kistler with an NI card): channels are found by the same names in one group;
time comes from a time channel or from the waveform properties ``wf_increment`` [s] and
``wf_start_offset`` [s]; units from the ``unit_string`` property.
"""

from __future__ import annotations

import re
import warnings
from os import PathLike
from pathlib import Path

import numpy as np
import pandas as pd

from cnctwin.exceptions import CnctwinWarning, ConfigError, FormatError
from cnctwin.iotools._csvtable import header_delimiter, read_csv_table
from cnctwin.iotools._text import read_utf8_text
from cnctwin.recording import ExternalChannel, Recording

__all__ = [
    "DYNAMOMETER_COLUMNS",
    "UNKNOWN_UNIT_COLUMNS",
    "attach_external",
    "read_dynamometer_csv",
    "read_dynamometer_tdms",
]

DYNAMOMETER_COLUMNS: dict[str, str] = {"fx_n": "N", "fy_n": "N", "fz_n": "N", "mz_nm": "N*m"}
"""Canonical dynamometer columns and their units."""

UNKNOWN_UNIT_COLUMNS: dict[str, str] = {"fx_n": "fx", "fy_n": "fy", "fz_n": "fz", "mz_nm": "mz"}
"""Column of a force/torque whose header states no unit (its unit is recorded as unknown)."""

_FORCE_SCALE = {"n": 1.0, "kn": 1e3, "mn": 1e-3, "dan": 10.0}
_TORQUE_SCALE = {"nm": 1.0, "n*m": 1.0, "n.m": 1.0, "n m": 1.0, "n·m": 1.0, "ncm": 1e-2,
                 "nmm": 1e-3, "knm": 1e3}
_TIME_SCALE = {"s": 1.0, "sec": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "min": 60.0}
_UNIT_RE = re.compile(r"^\s*(?P<name>.*?)\s*[\[(](?P<unit>[^\])]*)[\])]\s*$")


_UNKNOWN = set(UNKNOWN_UNIT_COLUMNS.values())


def _split_unit(header: str) -> tuple[str, str | None]:
    """``"Fx [kN]"`` -> ``("fx", "kn")``; ``"fx_n"`` -> ``("fx_n", None)``."""
    m = _UNIT_RE.match(header)
    if m:
        return m.group("name").strip().lower(), m.group("unit").strip().lower()
    return header.strip().lower(), None


def _normalise(name: str) -> str:
    return re.sub(r"[\s_\-.]+", "", name)


_TIME_NAMES = {"time", "t", "timestamp", "zeit"}
_AXIS_NAMES: dict[str, tuple[str, ...]] = {
    "fx_n": ("fx", "forcex", "f_x"),
    "fy_n": ("fy", "forcey", "f_y"),
    "fz_n": ("fz", "forcez", "f_z"),
    "mz_nm": ("mz", "torquez", "m_z", "torque"),
}


def _classify(header: str, *, path: str) -> tuple[str, float] | None:
    """Canonical column and scale factor for a header, or None if not a dynamometer column."""
    name, unit = _split_unit(header)
    n = _normalise(name)
    # unit as a suffix: time_s, time_ms, fx_n, fx_kn, mz_nm
    suffix_unit: str | None = None
    for canon_base in ("time", *[a for names in _AXIS_NAMES.values() for a in names]):
        base = _normalise(canon_base)
        if n.startswith(base) and n != base:
            rest = n[len(base):]
            if rest in _FORCE_SCALE or rest in _TORQUE_SCALE or rest in _TIME_SCALE:
                suffix_unit = rest
                n = base
                break
    u = unit if unit is not None else suffix_unit
    if n in _TIME_NAMES:
        if u is None:
            return "time_s", 1.0
        if u not in _TIME_SCALE:
            raise FormatError(f"unknown time unit {u!r}; accepted: {sorted(_TIME_SCALE)}",
                              path=path, position="line 1", field=header)
        return "time_s", _TIME_SCALE[u]
    for canon, aliases in _AXIS_NAMES.items():
        if n in {_normalise(a) for a in aliases}:
            table = _TORQUE_SCALE if canon == "mz_nm" else _FORCE_SCALE
            if u is None:
                # no unit stated: kept under the bare name with the unit unknown, never
                # assumed to be newtons
                return UNKNOWN_UNIT_COLUMNS[canon], 1.0
            key = u.replace(" ", "") if canon == "mz_nm" else u
            if key not in table and u not in table:
                raise FormatError(
                    f"unknown unit {u!r} for {canon}; accepted: {sorted(table)}", path=path,
                    position="line 1", field=header,
                )
            return canon, table.get(key, table.get(u, 1.0))
    return None


def read_dynamometer_csv(
    path: str | PathLike[str],
    *,
    fs_hz: float | None = None,
    name: str = "dynamometer",
) -> ExternalChannel:
    """Read a dynamometer CSV (time, Fx, Fy, Fz, Mz) into an external channel.

    Parameters
    ----------
    path : str or path-like
        The CSV file (see the module docstring for accepted headers and units).
    fs_hz : float, optional
        Sample rate [Hz]. Required if the file has no time column (time = i / fs_hz); with a
        time column it is estimated from the median time step, and a given ``fs_hz`` that
        differs by more than 1 % raises a :class:`~cnctwin.exceptions.CnctwinWarning`.
    name : str, default 'dynamometer'
        Channel name.

    Returns
    -------
    ExternalChannel
        ``data`` indexed by ``time_s`` [s] with the canonical columns found
        (``fx_n``, ``fy_n``, ``fz_n`` [N], ``mz_nm`` [N*m]); other numeric columns are kept
        under their lower-cased header with unit ``""``.

    Raises
    ------
    FormatError
        No force column, unknown units, rows of the wrong length or non-numeric values (line
        and column named), or no time column and no ``fs_hz``.
    """
    p = Path(path)
    spath = str(p)
    text = read_utf8_text(p)
    if not text.strip():
        raise FormatError("empty file", path=spath)
    table = read_csv_table(text, path=spath, delimiter=header_delimiter(text.splitlines()[0]))
    header = table.header
    kinds: list[tuple[str, float] | None] = [_classify(h, path=spath) for h in header]
    canon = [k[0] for k in kinds if k is not None]
    if not any(c in DYNAMOMETER_COLUMNS or c in _UNKNOWN for c in canon):
        raise FormatError(
            f"no force/torque column found in header {header}; expected e.g. "
            "time_s,fx_n,fy_n,fz_n,mz_nm or Time [s],Fx [N],Fy [N],Fz [N],Mz [Nm]",
            path=spath, position="line 1",
        )
    dup = {c for c in canon if canon.count(c) > 1}
    if dup:
        raise FormatError(f"columns map twice onto {sorted(dup)}", path=spath,
                          position="line 1")
    decimal_comma = table.has_decimal_comma()
    cols: dict[str, np.ndarray] = {}
    units: dict[str, str] = {}
    for j, (h, k) in enumerate(zip(header, kinds, strict=True)):
        values = table.numbers(j, decimal_comma=decimal_comma)
        if k is None:
            key = _normalise(h.lower()) or f"col{j}"
            cols[key] = values
            units[key] = ""
        else:
            cols[k[0]] = values * k[1]
            if k[0] != "time_s":
                units[k[0]] = DYNAMOMETER_COLUMNS.get(k[0], "unknown")
    return _channel(cols, units, fs_hz=fs_hz, name=name, source=spath)


def _channel(cols: dict[str, np.ndarray], units: dict[str, str], *, fs_hz: float | None,
             name: str, source: str) -> ExternalChannel:
    n = len(next(iter(cols.values()))) if cols else 0
    time = cols.pop("time_s", None)
    if time is None:
        if fs_hz is None:
            raise FormatError("no time column: pass fs_hz= (sample rate [Hz])", path=source,
                              field="time_s")
        time = np.arange(n, dtype=np.float64) / fs_hz
        est: float | None = fs_hz
    else:
        if np.isnan(time).any():
            raise FormatError("empty time value", path=source, field="time_s",
                              position=f"line {int(np.flatnonzero(np.isnan(time))[0]) + 2}")
        dt = np.diff(time)
        if (dt <= 0).any():
            i = int(np.flatnonzero(dt <= 0)[0])
            raise FormatError("time is not strictly increasing", path=source,
                              position=f"line {i + 3}", field="time_s")
        est = float(1.0 / np.median(dt)) if dt.size else fs_hz
        if fs_hz is not None and est is not None and abs(est - fs_hz) > 0.01 * fs_hz:
            warnings.warn(f"{source}: time column gives {est:.6g} Hz, fs_hz={fs_hz:g} was "
                          "given; using the time column", CnctwinWarning, stacklevel=3)
    data = pd.DataFrame(cols, index=pd.Index(time, name="time_s"))
    units = {k: units.get(k, "") for k in data.columns}
    return ExternalChannel(name=name, data=data, units=units, fs_hz=est, source=source)


def read_dynamometer_tdms(
    path: str | PathLike[str],
    *,
    group: str | None = None,
    name: str = "dynamometer",
) -> ExternalChannel:
    """Read a dynamometer recording from an NI TDMS file (needs ``npTDMS``).

    Parameters
    ----------
    path : str or path-like
        The ``.tdms`` file.
    group : str, optional
        Group holding the force channels; default the first group that has one.
    name : str, default 'dynamometer'
        Channel name.

    Returns
    -------
    ExternalChannel
        As :func:`read_dynamometer_csv`; ``fs_hz`` = 1 / ``wf_increment``.

    Raises
    ------
    FormatError
        Not a TDMS file, no force channel, channels of different lengths, no time information.
    """
    try:
        from nptdms import TdmsFile
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError("read_dynamometer_tdms needs npTDMS: pip install 'cnctwin[tdms]'"
                          ) from exc
    p = Path(path)
    spath = str(p)
    if not p.exists():
        raise FormatError("file not found", path=spath)
    with p.open("rb") as fh:
        magic = fh.read(4)
    if magic != b"TDSm":
        raise FormatError(f"not a TDMS file: starts with {magic!r}, not the 'TDSm' lead-in",
                          path=spath, position="byte 0")
    try:
        tdms = TdmsFile.read(spath)
    except Exception as exc:  # npTDMS raises ValueError/KeyError/struct.error on bad input
        raise FormatError(f"not a readable TDMS file: {exc}", path=spath) from None
    groups = tdms.groups()
    chosen = None
    for g in groups:
        if group is not None and g.name != group:
            continue
        if any((k := _classify_tdms(ch.name, ch.properties, spath)) is not None
               and k[0] in DYNAMOMETER_COLUMNS for ch in g.channels()):
            chosen = g
            break
    if chosen is None:
        raise FormatError(
            f"no group with a force channel (Fx, fx_n, ...); groups: "
            f"{[g.name for g in groups]}", path=spath, field=group,
        )
    cols: dict[str, np.ndarray] = {}
    units: dict[str, str] = {}
    inc: float | None = None
    start = 0.0
    for ch in chosen.channels():
        k = _classify_tdms(ch.name, ch.properties, spath)
        values = np.asarray(ch[:], dtype=np.float64)
        if k is None:
            cols[_normalise(ch.name.lower())] = values
            continue
        cols[k[0]] = values * k[1]
        if k[0] != "time_s":
            units[k[0]] = DYNAMOMETER_COLUMNS.get(k[0], "unknown")
            if "wf_increment" in ch.properties and inc is None:
                inc = float(ch.properties["wf_increment"])
                start = float(ch.properties.get("wf_start_offset", 0.0))
    lengths = {c: v.size for c, v in cols.items()}
    if len(set(lengths.values())) > 1:
        raise FormatError(f"channels have different lengths {lengths}", path=spath,
                          field=chosen.name)
    if "time_s" not in cols and inc is not None:
        n = next(iter(lengths.values()))
        cols["time_s"] = start + np.arange(n) * inc
    return _channel(cols, units, fs_hz=1.0 / inc if inc else None, name=name, source=spath)


def _classify_tdms(ch_name: str, props: dict[str, object], path: str) -> tuple[str, float] | None:
    unit = props.get("unit_string")
    header = f"{ch_name} [{unit}]" if unit and not _UNIT_RE.match(ch_name) else ch_name
    return _classify(header, path=path)


def attach_external(
    rec: Recording,
    channel: ExternalChannel,
    *,
    name: str | None = None,
    replace: bool = False,
) -> Recording:
    """A new recording with an external channel attached (the input is not modified).

    Parameters
    ----------
    rec : Recording
        The recording.
    channel : ExternalChannel
        Channel to attach (shared, not copied).
    name : str, optional
        Key in ``rec.external``; default ``channel.name``.
    replace : bool, default False
        Replace a channel of the same name instead of raising.

    Returns
    -------
    Recording
        Same HF/LF/event tables (not copied), a copied ``meta`` with the channel's source
        appended to ``source_files``.

    Raises
    ------
    ConfigError
        If a channel of that name exists and ``replace`` is False.
    """
    key = name or channel.name
    if key in rec.external and not replace:
        raise ConfigError(f"recording already has an external channel {key!r} "
                          f"(channels: {sorted(rec.external)}); pass replace=True")
    meta = rec.meta.copy()
    if channel.source and channel.source not in meta.source_files:
        meta.source_files.append(channel.source)
    return Recording(rec.hf, lf=rec.lf, events=rec.events,
                     external={**rec.external, key: channel}, meta=meta)
