"""Reader for the older SINUMERIK Edge (Manage MyMachines /Insights Hub app SDK) HF message.

One message is a JSON document::

    {"header": {"message_type": "dataobject", "key": "dataobject",
                "source_id": "sinumerik_adapter_840Dsl"},
     "body": {"datapoint": [
        {"address": "CYCLE", "timestamp": "2094-01-01T07:18:06.354000", "quality_mode": "hf",
         "period_ms": 2, "content": [{"value": [6, 8, 9, 10]}]},
        {"address": "ENC1_POS|1", "timestamp": "...", "quality_mode": "hf", "period_ms": 2,
         "content": [{"value": [20.0, 30.0, 40.0, 50.0]}]}]}}

The CYCLE datapoint carries the position-control counter of each sample; every other datapoint
holds one value per CYCLE entry (``content[].value`` lists are concatenated). Time follows the
SDK's rule t(i) = t(i-1) + (CYCLE(i) - CYCLE(i-1)) * period_ms, i.e. the ``timestamp`` of the
CYCLE datapoint is the time of its first sample and the counter is the clock; it becomes the
recording's time anchor. Timestamps without a zone are taken as UTC (noted in ``meta.issues``).
Addresses ``CODE|n`` become ``CODE|<axis name>`` through the axis map.

Source: Siemens, "Manage MyMachines /Edge app publishing, developer documentation: time
behaviour" (documentation.mindsphere.io, developer-docu/time-behaviour.html).
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Iterator
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from cnctwin.exceptions import FormatError
from cnctwin.recording import (
    CYCLE_COUNTER_MODULUS,
    Recording,
    RecordingMeta,
    find_gaps,
    unwrap_cycles,
)
from cnctwin.signals import DEFAULT_AXIS_MAP

__all__ = ["EdgeDataobjectAssembler", "parse_edge_dataobject", "read_edge_dataobject"]


def _load(message: str | bytes | dict[str, Any], label: str) -> dict[str, Any]:
    if isinstance(message, dict):
        return message
    if not isinstance(message, (str, bytes, bytearray)):
        raise FormatError(f"message is a {type(message).__name__}, not a JSON object",
                          path=label)
    try:
        doc = json.loads(message)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        pos = f"line {exc.lineno}, column {exc.colno}" if isinstance(
            exc, json.JSONDecodeError) else None
        raise FormatError(f"not JSON: {exc}", path=label, position=pos) from None
    if not isinstance(doc, dict):
        raise FormatError("top level is not an object", path=label)
    return doc


def _column(address: str, amap: dict[int, str], issues: list[str]) -> str:
    code, sep, num = address.partition("|")
    if not sep:
        return address
    if num.isdigit():
        n = int(num)
        if n not in amap:
            issues.append(f"axis number {n} of {address!r} not in the axis map; named AX{n}")
            return f"{code}|AX{n}"
        return f"{code}|{amap[n]}"
    return address


def parse_edge_dataobject(
    message: str | bytes | dict[str, Any],
    *,
    axis_map: dict[int, str] | None = None,
    source: str = "<message>",
    salvage: bool = False,
) -> Recording:
    """Decode one ``dataobject`` message into a recording.

    Parameters
    ----------
    message : str, bytes or dict
        The JSON message (text, bytes or already decoded).
    axis_map : dict, optional
        Axis number -> name; default :data:`~cnctwin.signals.DEFAULT_AXIS_MAP`.
    source : str, default '<message>'
        Label used in error messages and ``meta.source_files`` (file name or topic).
    salvage : bool, default False
        Datapoints whose length differs from CYCLE are cut or padded with NaN (and listed)
        instead of raising.

    Returns
    -------
    Recording
        ``meta.cycle_time_s`` = CYCLE ``period_ms`` / 1000; anchor (first CYCLE, timestamp).

    Raises
    ------
    FormatError
        Wrong ``message_type``, no CYCLE datapoint, non-numeric values, value lists whose
        length differs from CYCLE (position ``body.datapoint[i]``, field = address).
    """
    doc = _load(message, source)
    issues: list[str] = []
    partial = False
    header = doc.get("header") or {}
    mtype = header.get("message_type")
    if mtype != "dataobject":
        raise FormatError(f"header.message_type is {mtype!r}, expected 'dataobject'",
                          path=source, field="header.message_type")
    dps = (doc.get("body") or {}).get("datapoint")
    if not isinstance(dps, list):
        raise FormatError("body.datapoint is missing or not a list", path=source,
                          field="body.datapoint")
    amap = dict(DEFAULT_AXIS_MAP if axis_map is None else axis_map)
    values: dict[str, tuple[int, np.ndarray, dict[str, Any]]] = {}
    for i, dp in enumerate(dps):
        pos = f"body.datapoint[{i}]"
        if not isinstance(dp, dict) or "address" not in dp:
            raise FormatError("datapoint without an address", path=source, position=pos,
                              field="address")
        addr = str(dp["address"])
        vals: list[Any] = []
        for content in dp.get("content") or []:
            v = content.get("value") if isinstance(content, dict) else None
            if v is None:
                continue
            vals.extend(v if isinstance(v, list) else [v])
        try:
            arr = np.asarray([np.nan if x is None else float(x) for x in vals],
                             dtype=np.float64)
        except (TypeError, ValueError):
            bad = next(x for x in vals if not _is_number(x))
            raise FormatError(f"value {bad!r} is not a number", path=source, position=pos,
                              field=addr) from None
        if addr in values:
            issues.append(f"{pos}: address {addr!r} appears twice; the later one is kept")
        values[addr] = (i, arr, dp)
    if "CYCLE" not in values:
        raise FormatError("no CYCLE datapoint: the message has no time base", path=source,
                          field="CYCLE")
    ci, craw, cdp = values.pop("CYCLE")
    if np.isnan(craw).any():
        raise FormatError("CYCLE contains null values", path=source,
                          position=f"body.datapoint[{ci}]", field="CYCLE")
    cycles, wraps = unwrap_cycles(craw.astype(np.int64))
    period_ms = cdp.get("period_ms", 2)
    try:
        cycle_time_s = float(period_ms) / 1000.0
    except (TypeError, ValueError):
        raise FormatError(f"period_ms {period_ms!r} is not a number", path=source,
                          position=f"body.datapoint[{ci}]", field="period_ms") from None
    cols: dict[str, np.ndarray] = {}
    for addr, (i, arr, dp) in values.items():
        if arr.size != cycles.size:
            msg = (f"{arr.size} values, CYCLE has {cycles.size}")
            if not salvage:
                raise FormatError(msg + " (pass salvage=True to cut/pad with NaN)",
                                  path=source, position=f"body.datapoint[{i}]", field=addr)
            issues.append(f"{addr}: {msg}; " + ("cut" if arr.size > cycles.size else
                                               "padded with NaN"))
            partial = True
            fixed = np.full(cycles.size, np.nan)
            fixed[: min(arr.size, cycles.size)] = arr[: cycles.size]
            arr = fixed
        p_ms = dp.get("period_ms")
        if p_ms is not None and p_ms != period_ms:
            issues.append(f"{addr}: period_ms {p_ms} differs from CYCLE's {period_ms}")
        if dp.get("quality_mode") not in (None, "hf"):
            issues.append(f"{addr}: quality_mode {dp.get('quality_mode')!r}")
        cols[_column(addr, amap, issues)] = arr
    anchors: list[tuple[int, pd.Timestamp]] = []
    ts_raw = cdp.get("timestamp")
    if ts_raw and cycles.size:
        try:
            ts = pd.Timestamp(ts_raw)
        except ValueError:
            raise FormatError(f"timestamp {ts_raw!r} is not a date-time", path=source,
                              position=f"body.datapoint[{ci}]", field="timestamp") from None
        if ts.tzinfo is None:
            ts = ts.tz_localize("UTC")
            issues.append(f"timestamp {ts_raw!r} has no zone; taken as UTC")
        anchors = [(int(cycles[0]), ts)]
    else:
        issues.append("no CYCLE timestamp: times start at the Unix epoch")
    hf = pd.DataFrame(cols, index=pd.Index(cycles, name="cycle"))
    meta = RecordingMeta(
        machine=str(header.get("source_id", "")),
        cycle_time_s=cycle_time_s,
        axis_map=amap,
        source_files=[source],
        source_format="edge_dataobject",
        time_anchors=anchors,
        gaps=find_gaps(cycles),
        wraps=wraps,
        issues=issues,
        partial=partial,
        attrs={"header": dict(header)},
    )
    return Recording(hf, meta=meta)


def _is_number(x: Any) -> bool:
    try:
        float(x)
    except (TypeError, ValueError):
        return False
    return True


def read_edge_dataobject(
    path_or_bytes: str | PathLike[str] | bytes,
    *,
    axis_map: dict[int, str] | None = None,
    salvage: bool = False,
) -> Recording:
    """Read a ``dataobject`` message from a file or from bytes.

    A file may hold one message or several (a JSON array of messages, or one message per line
    as JSON Lines); several messages are joined with :class:`EdgeDataobjectAssembler`.

    Parameters
    ----------
    path_or_bytes : str, path-like or bytes
        File path, or the message bytes.
    axis_map : dict, optional
        Axis number -> name.
    salvage : bool, default False
        See :func:`parse_edge_dataobject`.

    Returns
    -------
    Recording
    """
    if isinstance(path_or_bytes, bytes):
        label = "<bytes>"
        raw = path_or_bytes
    else:
        p = Path(path_or_bytes)
        label = str(p)
        if not p.exists():
            raise FormatError("file not found", path=label)
        raw = p.read_bytes()
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise FormatError(f"not UTF-8 text ({exc.reason})", path=label,
                          position=f"byte {exc.start}") from None
    stripped = text.strip()
    messages: list[Any]
    if stripped.startswith("["):
        try:
            messages = json.loads(stripped)
        except json.JSONDecodeError as exc:
            raise FormatError(f"not JSON: {exc.msg}", path=label,
                              position=f"line {exc.lineno}, column {exc.colno}") from None
    else:
        try:
            messages = [json.loads(stripped)]
        except json.JSONDecodeError:
            messages = []
            for n, line in enumerate(stripped.splitlines(), start=1):
                if line.strip():
                    try:
                        messages.append(json.loads(line))
                    except json.JSONDecodeError as exc:
                        raise FormatError(f"not JSON: {exc.msg}", path=label,
                                          position=f"line {n}, column {exc.colno}") from None
    asm = EdgeDataobjectAssembler(axis_map=axis_map, salvage=salvage, source=label)
    for m in messages:
        asm.feed(m)
    return asm.recording()


class EdgeDataobjectAssembler:
    """Join a stream of ``dataobject`` messages into one recording.

    Parameters
    ----------
    axis_map : dict, optional
        Axis number -> name.
    salvage : bool, default False
        See :func:`parse_edge_dataobject`.
    source : str, default '<stream>'
        Label for messages and ``meta.source_files``.

    Examples
    --------
    >>> asm = EdgeDataobjectAssembler()
    >>> for msg in messages:          # doctest: +SKIP
    ...     chunk = asm.feed(msg)     # the recording of this message
    >>> rec = asm.recording()         # doctest: +SKIP
    """

    def __init__(
        self,
        *,
        axis_map: dict[int, str] | None = None,
        salvage: bool = False,
        source: str = "<stream>",
    ) -> None:
        self.axis_map = axis_map
        self.salvage = salvage
        self.source = source
        self._chunks: list[Recording] = []

    def __len__(self) -> int:
        """Number of messages fed."""
        return len(self._chunks)

    def feed(self, message: str | bytes | dict[str, Any]) -> Recording:
        """Decode one message, keep it, and return its own recording."""
        label = f"{self.source}#{len(self._chunks) + 1}"
        rec = parse_edge_dataobject(message, axis_map=self.axis_map, source=label,
                                    salvage=self.salvage)
        self._chunks.append(rec)
        return rec

    def feed_many(self, messages: Iterable[str | bytes | dict[str, Any]]) -> Iterator[
            Recording]:
        """Feed several messages, yielding each message's recording."""
        for m in messages:
            yield self.feed(m)

    def recording(self, *, clear: bool = False) -> Recording:
        """All messages fed so far as one recording.

        Rows are ordered by cycle; a cycle that arrives twice keeps its first arrival, like
        the Capture4Analysis and flat-CSV readers (the duplicate is listed in
        ``meta.issues``, with whether its values were identical). Columns missing in some
        messages are NaN there.

        Parameters
        ----------
        clear : bool, default False
            Forget the fed messages afterwards (for windowed streaming).
        """
        if not self._chunks:
            raise FormatError("no dataobject message fed yet", path=self.source)
        first = self._chunks[0]
        issues: list[str] = []
        for i, c in enumerate(self._chunks):
            issues += [f"message {i + 1}: {x}" for x in c.meta.issues]
            if c.meta.cycle_time_s != first.meta.cycle_time_s:
                issues.append(f"message {i + 1}: period {c.meta.cycle_time_s * 1e3:g} ms "
                              f"differs from the first message's "
                              f"{first.meta.cycle_time_s * 1e3:g} ms")
        # a counter wrap between two messages: shift the later chunks up by the modulus
        parts = []
        shift = 0
        prev_last: int | None = None
        for c in self._chunks:
            part = c.hf.drop(columns="time")
            if prev_last is not None and len(part) and \
                    int(part.index[0]) + shift < prev_last - CYCLE_COUNTER_MODULUS // 2:
                shift += CYCLE_COUNTER_MODULUS
                issues.append("the CYCLE counter wrapped between two messages")
            if shift:
                part.index = part.index + shift
            if len(part):
                prev_last = int(part.index[-1])
            parts.append(part)
        hf = pd.concat(parts)
        colsets = {tuple(c.columns) for c in self._chunks}
        if len(colsets) > 1:
            issues.append("messages carry different datapoints; missing ones are NaN")
        dup = hf.index.duplicated(keep="first")
        if dup.any():
            kept = hf[~dup]
            again = hf[dup]
            same = bool(np.array_equal(again.to_numpy(dtype=np.float64),
                                       kept.loc[again.index].to_numpy(dtype=np.float64),
                                       equal_nan=True))
            issues.append(f"{int(dup.sum())} duplicate HF rows (cycles that arrived twice, "
                          f"e.g. {int(again.index[0])}, {'identical' if same else 'DIFFERENT'} "
                          "values): kept the first arrival")
            hf = kept
        raw = hf.index.to_numpy()
        if raw.size > 1 and (np.diff(raw) < 0).any():
            issues.append("messages arrived out of cycle order; rows sorted by cycle")
        hf = hf.sort_index(kind="stable")
        anchors = [a for c in self._chunks for a in c.meta.time_anchors]
        meta = RecordingMeta(
            machine=first.meta.machine,
            cycle_time_s=first.meta.cycle_time_s,
            axis_map=dict(first.meta.axis_map),
            source_files=[self.source],
            source_format="edge_dataobject",
            time_anchors=anchors,
            gaps=find_gaps(hf.index.to_numpy()),
            wraps=sum(c.meta.wraps for c in self._chunks),
            issues=issues,
            partial=any(c.meta.partial for c in self._chunks),
            attrs={"messages": len(self._chunks), "header": first.meta.attrs.get("header")},
        )
        if clear:
            self._chunks = []
        return Recording(hf, meta=meta)
