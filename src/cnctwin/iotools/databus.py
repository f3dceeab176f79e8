"""Decoder for the Siemens Industrial Edge Databus payload format (connector metadata + data).

Connectors (S7, OPC UA, Modbus, ...) publish a retained **metadata** message on
``ie/m/j/simatic/v1/<instance>/dp``::

    {"seq": 1, "hashVersion": 123, "applicationName": "...", "connections": [
        {"name": "PLC_1", "type": "s7", "dataPoints": [
            {"name": "default", "topic": "ie/d/j/simatic/v1/s7c1/dp/r/PLC_1/default",
             "publishType": "bulk",
             "dataPointDefinitions": [{"name": "Axis_X_Load", "id": "101",
                                       "dataType": "LReal"}]}]}]}

and **data** messages on the ``topic`` of each data point collection:

* ``bulk``: ``{"seq": 84631, "vals": [{"id": "101", "qc": 3, "ts": "...Z", "val": 80}]}``
* ``timeseries``: ``{"seq": .., "records": [{"ts": "...", "rseq": .., "vals": [{"id", "val",
  "qc"}]}]}`` (a value without ``ts`` takes its record's ``ts``)
* ``single`` (deprecated): ``{"seq": .., "val": .., "ts": .., "qc": ..}``; the datapoint is
  the single definition of the collection whose ``topic`` the message came on.

Rules from the payload-format documentation (industrial-edge/common-databus-payload-format,
PayloadFormat.md; developer.siemens.com/industrial-edge/databus): ids are opaque and not stable
across reconfiguration (a new metadata message replaces the id map); numbers may be quoted or
unquoted and 64-bit integers come as strings; ``qc`` 0 = BAD, 1 = UNCERTAIN, 2 = GOOD
(non-cascade), 3 = GOOD (cascade).

Output choice: :meth:`DatabusDecoder.recording` returns a :class:`~cnctwin.recording.Recording`
whose HF table is on a cycle base derived from the timestamps: cycle = floor(ts / cycle_time_s)
counted from the Unix epoch (so windows of one stream share one cycle numbering), one row per
cycle in which any value arrived, NaN where a datapoint had no value (nothing is held or
interpolated). Text values go to the LF long table. Every decoded value, with its exact
timestamp, id and quality, is also kept in ``meta.attrs["databus_values"]`` (a DataFrame);
values with quality BAD or UNCERTAIN are kept and counted in ``meta.issues``.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from itertools import chain, pairwise, repeat
from typing import Any

import msgspec
import numpy as np
import pandas as pd
from numpy.typing import NDArray

from cnctwin.exceptions import ConfigError, FormatError
from cnctwin.iotools._databus_scan import BulkScan, id_table, scan_bulk
from cnctwin.recording import Recording, RecordingMeta

__all__ = ["QC_NAMES", "DatabusColumns", "DatabusDecoder", "DatabusValue"]

QC_NAMES: dict[int, str] = {0: "BAD", 1: "UNCERTAIN", 2: "GOOD", 3: "GOOD_CASCADE"}
"""Databus quality codes."""


@dataclass(frozen=True)
class DatabusValue:
    """One decoded datapoint value.

    Attributes
    ----------
    topic : str
        Topic the data message came on.
    id : str
        Datapoint id (as in the message).
    name : str
        Datapoint name from the metadata (``""`` if the id is unknown).
    column : str
        Recording column (``name_map`` entry, else the name).
    time : pandas.Timestamp
        UTC timestamp of the value.
    value : float or str or None
        Numeric value as float; text as str.
    qc : int or None
        Quality code (0 BAD, 1 UNCERTAIN, 2/3 GOOD).
    seq : int or None
        Message sequence number.
    """

    topic: str
    id: str
    name: str
    column: str
    time: pd.Timestamp
    value: float | str | None
    qc: int | None
    seq: int | None


@dataclass(frozen=True)
class DatabusColumns:
    """The numeric values of bulk data messages as arrays on the cycle base (the fast path).

    Attributes
    ----------
    cycles : numpy.ndarray of int64
        floor(ts / cycle_time_s) of each row, increasing, unique.
    columns : dict of str to numpy.ndarray
        Column -> float64 value per row (NaN where the datapoint had no value in that cycle).
    n_values : int
        Values decoded.
    issues : list of str
        Oddities (values sharing a cycle with a later value of the same datapoint, quality
        BAD or UNCERTAIN), counted as :meth:`DatabusDecoder.recording` counts them.
    """

    cycles: NDArray[np.int64]
    columns: dict[str, NDArray[np.float64]]
    n_values: int
    issues: list[str]


def merge_columns(batches: list[DatabusColumns]) -> DatabusColumns:
    """One :class:`DatabusColumns` of several (messages of one or more topics), by cycle.

    A value of a later batch replaces one of the same column and cycle (counted).
    """
    if len(batches) == 1:
        return batches[0]
    keys = list(batches[0].columns)
    if all(list(b.columns) == keys and b.cycles.size for b in batches) and all(
            int(a.cycles[-1]) < int(b.cycles[0]) for a, b in pairwise(batches)):
        # messages in cycle order with the same datapoints (a live connector's): one after
        # the other
        return DatabusColumns(np.concatenate([b.cycles for b in batches]),
                              {c: np.concatenate([b.columns[c] for b in batches])
                               for c in keys},
                              sum(b.n_values for b in batches),
                              [i for b in batches for i in b.issues])
    cyc = np.unique(np.concatenate([b.cycles for b in batches]))
    cols: dict[str, NDArray[np.float64]] = {}
    issues: list[str] = []
    replaced = 0
    for b in batches:
        issues += b.issues
        pos = np.searchsorted(cyc, b.cycles)
        for c, v in b.columns.items():
            a = cols.get(c)
            if a is None:
                a = cols[c] = np.full(cyc.size, np.nan)
            else:
                replaced += int((np.isfinite(a[pos]) & np.isfinite(v)).sum())
            ok = ~np.isnan(v)
            a[pos[ok]] = v[ok]
    if replaced:
        issues.append(f"{replaced} values shared a cycle with a later value of the same "
                      "datapoint (another message); the last is kept")
    return DatabusColumns(cyc, cols, sum(b.n_values for b in batches), issues)


class _BulkValue(msgspec.Struct, gc=False):
    """One value of a bulk message as the fast path accepts it (anything else: None)."""

    id: str
    ts: str
    val: int | float
    qc: int = 3


class _Bulk(msgspec.Struct, gc=False):
    vals: list[_BulkValue]
    seq: int | str | float | None = None


_BULK_DECODER = msgspec.json.Decoder(_Bulk)


def _utc_ns(stamps: list[str]) -> NDArray[np.int64] | None:
    """Plain UTC times (``_PLAIN_UTC``, years 1678-2261, what the ns base holds) as ns since
    the epoch; None for anything else (numpy also reads "now", "NaT", offsets: the general
    path parses or names those)."""
    if not all(map(_PLAIN_UTC.fullmatch, stamps)) or min(stamps)[:4] < "1678" \
            or max(stamps)[:4] > "2261":
        return None
    core = [t[:-1] if t[-1] == "Z" else t for t in stamps]
    try:
        t_ns = np.array(core, dtype="datetime64[ns]").view(np.int64)
    except ValueError:
        return None
    if (t_ns == np.iinfo(np.int64).min).any():
        return None
    return t_ns

_PLAIN_UTC = re.compile(r"\d{4}-\d\d-\d\d(?:T\d\d(?::\d\d(?::\d\d(?:\.\d{1,9})?)?)?)?Z?")
"""``YYYY-MM-DD[Thh[:mm[:ss[.f]]]][Z]``: a UTC time numpy reads as the general path does."""


def _quality_issues(qc: NDArray[np.int64], col: NDArray[np.int64], names: list[str]
                    ) -> list[str]:
    """Issues counting the values of quality BAD and UNCERTAIN per column (as
    :meth:`DatabusDecoder.recording` counts them)."""
    issues = []
    for q, label in ((0, "BAD"), (1, "UNCERTAIN")):
        bad = np.flatnonzero(qc == q)
        if bad.size:
            per: dict[str, int] = {}
            for j in bad.tolist():
                c = names[int(col[j])]
                per[c] = per.get(c, 0) + 1
            issues.append(f"{bad.size} values with quality {label} (qc={q}) kept: {per}")
    return issues


def _load(message: str | bytes | dict[str, Any], label: str) -> dict[str, Any]:
    if isinstance(message, dict):
        return message
    try:
        doc = json.loads(message)
    except json.JSONDecodeError as exc:
        raise FormatError(f"not JSON: {exc.msg}", path=label,
                          position=f"line {exc.lineno}, column {exc.colno}") from None
    except UnicodeDecodeError as exc:
        raise FormatError(f"not UTF-8 text: {exc}", path=label) from None
    if not isinstance(doc, dict):
        raise FormatError("top level is not a JSON object", path=label)
    return doc


def _value(raw: Any) -> tuple[float | str | None, bool]:
    """Numeric value (quoted or not) as float; text kept; flag for precision loss."""
    if raw is None:
        return None, False
    if isinstance(raw, bool):
        return float(raw), False
    if isinstance(raw, int):
        return float(raw), abs(raw) > 2**53
    if isinstance(raw, float):
        return raw, False
    if isinstance(raw, str):
        s = raw.strip()
        try:
            if s.lstrip("+-").isdigit():
                i = int(s)
                return float(i), abs(i) > 2**53
            f = float(s)
            if math.isfinite(f) or s.lower() in ("nan", "inf", "-inf"):
                return f, False
        except ValueError:
            pass
        if s.lower() in ("true", "false"):
            return float(s.lower() == "true"), False
        return raw, False
    return json.dumps(raw), False


class DatabusDecoder:
    """Decode Databus metadata and data messages into values and recordings.

    Parameters
    ----------
    metadata : str, bytes or dict, optional
        A metadata message to start with (else call :meth:`update_metadata` first).
    name_map : dict, optional
        Datapoint name -> recording column, e.g. ``{"Axis_X_Load": "LOAD|X1"}``. Unmapped
        names are used as columns as they are.
    cycle_time_s : float, default 0.002
        Cycle base of :meth:`recording` [s].
    salvage : bool, default False
        Keep values with an id the metadata does not know (column ``UNKNOWN_ID_<id>``, listed
        in :attr:`issues`) instead of raising.

    Attributes
    ----------
    values : list of DatabusValue
        Values decoded since the last :meth:`recording` with ``clear=True``.
    issues : list of str
        Oddities seen (unknown ids, sequence gaps, metadata replacements, precision loss).
    """

    def __init__(
        self,
        metadata: str | bytes | dict[str, Any] | None = None,
        *,
        name_map: dict[str, str] | None = None,
        cycle_time_s: float = 0.002,
        salvage: bool = False,
    ) -> None:
        if cycle_time_s <= 0:
            raise ConfigError(f"cycle_time_s must be > 0, not {cycle_time_s}")
        self.name_map = dict(name_map or {})
        self.cycle_time_s = cycle_time_s
        self.salvage = salvage
        self.values: list[DatabusValue] = []
        self.issues: list[str] = []
        self.metadata: dict[str, Any] | None = None
        self._ids: dict[str, dict[str, str]] = {}
        self._topics: dict[str, dict[str, Any]] = {}
        self._last_seq: dict[str, int] = {}
        self._lut: NDArray[np.int64] | None = None
        self._lut_names: list[str] = []
        self._names_of: dict[bytes, list[str]] = {}  # scan's column indexes -> names
        if metadata is not None:
            self.update_metadata(metadata)

    # ------------------------------------------------------------------ metadata
    @property
    def data_topics(self) -> list[str]:
        """Data topics announced by the current metadata."""
        return list(self._topics)

    def update_metadata(self, message: str | bytes | dict[str, Any], *,
                        topic: str = "<metadata>") -> None:
        """Replace the id map with the one of a (new) metadata message.

        Raises
        ------
        FormatError
            If the message has no ``connections`` list or a definition lacks ``id``/``name``.
        """
        doc = _load(message, topic)
        try:
            self._update_metadata(doc, topic)
        except FormatError:
            raise
        except (TypeError, AttributeError, KeyError, IndexError, ValueError) as exc:
            raise FormatError(f"unexpected metadata structure ({type(exc).__name__}: {exc})",
                              path=topic) from None

    def _update_metadata(self, doc: dict[str, Any], topic: str) -> None:
        conns = doc.get("connections")
        if not isinstance(conns, list):
            raise FormatError("metadata has no 'connections' list", path=topic,
                              field="connections")
        ids: dict[str, dict[str, str]] = {}
        topics: dict[str, dict[str, Any]] = {}
        names_seen: dict[str, str] = {}
        for ci, conn in enumerate(conns):
            if not isinstance(conn, dict):
                raise FormatError("connection is not an object", path=topic,
                                  position=f"connections[{ci}]")
            dps = conn.get("dataPoints") or []
            if not isinstance(dps, list):
                raise FormatError("'dataPoints' is not a list", path=topic,
                                  position=f"connections[{ci}]", field="dataPoints")
            for di, dp in enumerate(dps):
                if not isinstance(dp, dict):
                    raise FormatError("data point is not an object", path=topic,
                                      position=f"connections[{ci}].dataPoints[{di}]")
                defs = dp.get("dataPointDefinitions") or []
                if not isinstance(defs, list) or not all(isinstance(d, dict) for d in defs):
                    raise FormatError("'dataPointDefinitions' is not a list of objects",
                                      path=topic, position=f"connections[{ci}].dataPoints"
                                      f"[{di}]", field="dataPointDefinitions")
                t = dp.get("topic")
                if t is not None and not isinstance(t, str):
                    raise FormatError(f"topic {t!r} is not a string", path=topic,
                                      position=f"connections[{ci}].dataPoints[{di}]",
                                      field="topic")
                if t:
                    topics[t] = {"publishType": dp.get("publishType", ""),
                                 "ids": [str(d.get("id")) for d in defs],
                                 "connection": conn.get("name", "")}
                for ki, d in enumerate(defs):
                    pos = f"connections[{ci}].dataPoints[{di}].dataPointDefinitions[{ki}]"
                    if "id" not in d or "name" not in d:
                        raise FormatError("definition without id or name", path=topic,
                                          position=pos)
                    name = str(d["name"])
                    column = self.name_map.get(name, name)
                    if column in names_seen and names_seen[column] != conn.get("name", ""):
                        column = f"{conn.get('name', '')}.{name}"
                    names_seen[column] = conn.get("name", "")
                    ids[str(d["id"])] = {"name": name, "column": column,
                                         "dataType": str(d.get("dataType", "")),
                                         "connection": str(conn.get("name", ""))}
        if self.metadata is not None and ids != self._ids:
            self.issues.append(
                f"metadata replaced (hashVersion {self.metadata.get('hashVersion')} -> "
                f"{doc.get('hashVersion')}); ids are resolved with the new map from now on"
            )
        self.metadata = doc
        self._ids = ids
        self._topics = topics
        names = list(dict.fromkeys(v["column"] for v in ids.values()))
        index = {c: j for j, c in enumerate(names)}
        self._lut_names = names
        self._names_of = {}
        self._lut = id_table({k: index[v["column"]] for k, v in ids.items()})

    # ------------------------------------------------------------------ data
    def decode(self, message: str | bytes | dict[str, Any], *, topic: str = "<data>",
               ) -> list[DatabusValue]:
        """Decode one data message (bulk, timeseries or single) and keep its values.

        Returns
        -------
        list of DatabusValue

        Raises
        ------
        FormatError
            No metadata yet, an unknown id (unless ``salvage``), a missing or bad ``ts``, or an
            unrecognised message shape; position e.g. ``vals[3]``, field ``id``.
        """
        if self.metadata is None:
            raise FormatError("data message before any metadata message: subscribe to the "
                              "metadata topic first", path=topic)
        try:
            return self._decode(message, topic)
        except FormatError:
            raise
        except (TypeError, AttributeError, KeyError, IndexError, ValueError,
                OverflowError) as exc:  # a shape the checks below did not foresee
            raise FormatError(f"unexpected message structure ({type(exc).__name__}: {exc})",
                              path=topic) from None

    def _seq(self, doc: dict[str, Any], topic: str) -> int | None:
        seq = doc.get("seq")
        seq_i = int(seq) if isinstance(seq, (int, str)) and str(seq).isdigit() else None
        if seq_i is not None:
            last = self._last_seq.get(topic)
            if last is not None and seq_i != last + 1:
                self.issues.append(f"{topic}: seq jumped from {last} to {seq_i}")
            self._last_seq[topic] = seq_i
        return seq_i

    def decode_columns(self, message: bytes | str, *, topic: str = "<data>"
                       ) -> DatabusColumns | None:
        """Decode a bulk message of numeric values straight into arrays (the fast path).

        The live edge source calls this for every data message: no object per value, one
        timestamp parse per cycle rather than per value. Values are the same as
        :meth:`decode` followed by :meth:`recording` gives.

        Returns
        -------
        DatabusColumns or None
            None when the message is anything else than well-formed ``bulk`` numbers (a
            text value, a quoted or 64-bit number, an unknown id, a timestamp with an offset,
            no metadata yet, not JSON, ...): then call :meth:`decode`, which handles every
            shape and names what is wrong.
        """
        if self.metadata is None:
            return None
        if self._lut is not None and isinstance(message, bytes):
            # one numba pass over the bytes for the regular HF layout (no object per value)
            scan = scan_bulk(message, self._lut)
            if scan is not None:
                got = self._scanned(scan, topic)
                if got is not None:
                    return got
        try:  # typed decode in C: every value an object with str id/ts, number val, int qc
            # (the UTF-8 check first: msgspec does not look inside the keys it skips)
            text = message.decode("utf-8") if isinstance(message, bytes) else message
            doc = _BULK_DECODER.decode(text)
        except (msgspec.DecodeError, UnicodeDecodeError):  # the general path names it
            return None
        vals = doc.vals
        if not vals:
            return None
        ids = self._ids
        vid = [v.id for v in vals]
        if not set(vid) <= ids.keys():
            return None
        ts = [v.ts for v in vals]
        raw = [v.val for v in vals]
        try:
            value = np.array(raw, dtype=np.float64)
        except OverflowError:
            return None
        big = np.flatnonzero(np.abs(value) > 2**53)
        if big.size and any(type(raw[k]) is int for k in big.tolist()):
            return None  # a 64-bit integer a float cannot hold: the general path says so
        n = len(vals)
        # the regular layout of a bulk HF message: the same k ids, in the same order, for
        # each timestamp in turn; then the values are the grid row by row
        t0 = ts[0]
        k = next((j for j, t in enumerate(ts) if t != t0), n)
        rows_ts = ts[::k]
        regular = (n % k == 0 and vid == vid[:k] * (n // k)
                   and ts == list(chain.from_iterable(repeat(t, k) for t in rows_ts))
                   and len({ids[x]["column"] for x in vid[:k]}) == k)
        step = round(self.cycle_time_s * 1e9)
        issues: list[str] = []
        t_ns = _utc_ns(rows_ts) if regular else None
        if t_ns is not None and (t_ns.size < 2 or bool((np.diff(t_ns // step) > 0).all())):
            names = [ids[x]["column"] for x in vid[:k]]
            grid = value.reshape(n // k, k)
            cycles = t_ns // step
            col = np.tile(np.arange(k, dtype=np.int64), n // k)
        else:  # any order: rows from the distinct timestamps, values scattered
            uniq = {t: j for j, t in enumerate(dict.fromkeys(ts))}
            t_ns = _utc_ns(list(uniq))
            if t_ns is None:
                return None
            cycles, ts_row = np.unique(t_ns // step, return_inverse=True)
            row = ts_row[np.array([uniq[t] for t in ts], dtype=np.int64)]
            names = list(dict.fromkeys(ids[x]["column"] for x in dict.fromkeys(vid)))
            col_index = {c: j for j, c in enumerate(names)}
            id_col = {x: col_index[ids[x]["column"]] for x in dict.fromkeys(vid)}
            col = np.array([id_col[x] for x in vid], dtype=np.int64)
            grid = np.full((cycles.size, len(names)), np.nan)
            key = row * len(names) + col
            if np.unique(key).size == key.size:
                grid[row, col] = value
            else:  # the last value of a column in a cycle wins, as in recording()
                _, first_rev = np.unique(key[::-1], return_index=True)
                last = key.size - 1 - first_rev
                grid[row[last], col[last]] = value[last]
                issues.append(f"{key.size - last.size} values shared a cycle with a later "
                              "value of the same datapoint; the last is kept in the HF table")
        self._seq({"seq": doc.seq}, topic)
        cols = {c: grid[:, j].copy() for j, c in enumerate(names)}
        qc = [v.qc for v in vals]
        if min(qc) < 2:
            issues += _quality_issues(np.array(qc), col, names)
        return DatabusColumns(cycles, cols, n, issues)

    def _scanned(self, scan: BulkScan, topic: str) -> DatabusColumns | None:
        """:class:`DatabusColumns` of a :func:`scan_bulk` result (None: rows not in cycle
        order, which the scattering path sorts out)."""
        step = round(self.cycle_time_s * 1e9)
        cycles = scan.t_ns // step
        if cycles.size > 1 and not bool((cycles[1:] > cycles[:-1]).all()):
            return None
        key = scan.cols.tobytes()  # the same datapoints in every message of a connector
        names = self._names_of.get(key)
        if names is None:
            names = self._names_of[key] = [self._lut_names[int(c)] for c in scan.cols]
        self._seq({"seq": scan.seq}, topic)
        # the columns as the rows of one transposed copy (one copy, not one per column;
        # per 100 ms message this bookkeeping cost as much as the scan: BENCHMARKS.md)
        by_column = scan.values.reshape(cycles.size, scan.k).T.copy()
        cols = dict(zip(names, by_column, strict=True))
        issues: list[str] = []
        if scan.qc.min() < 2:
            col = np.tile(np.arange(scan.k, dtype=np.int64), cycles.size)
            issues = _quality_issues(scan.qc, col, names)
        return DatabusColumns(cycles, cols, int(scan.values.size), issues)

    def _decode(self, message: str | bytes | dict[str, Any], topic: str,
                ) -> list[DatabusValue]:
        doc = _load(message, topic)
        seq_i = self._seq(doc, topic)
        out: list[DatabusValue] = []
        if "vals" in doc:
            if not isinstance(doc["vals"], list):
                raise FormatError("'vals' is not a list", path=topic, field="vals")
            for i, v in enumerate(doc["vals"]):
                out.append(self._one(v, v.get("ts") if isinstance(v, dict) else None,
                                     topic, f"vals[{i}]", seq_i))
        elif "records" in doc:
            if not isinstance(doc["records"], list):
                raise FormatError("'records' is not a list", path=topic, field="records")
            for r_i, rec in enumerate(doc["records"]):
                vals = rec.get("vals") if isinstance(rec, dict) else None
                if not isinstance(vals, list):
                    raise FormatError("record without a 'vals' list", path=topic,
                                      position=f"records[{r_i}]", field="vals")
                for i, v in enumerate(vals):
                    ts = v.get("ts", rec.get("ts")) if isinstance(v, dict) else None
                    out.append(self._one(v, ts, topic, f"records[{r_i}].vals[{i}]", seq_i))
        elif "val" in doc:
            info = self._topics.get(topic)
            if info is None or len(info["ids"]) != 1:
                raise FormatError(
                    "'single' message: cannot tell the datapoint (the topic is not a "
                    "one-definition collection in the metadata)", path=topic, field="val")
            v = {"id": info["ids"][0], "val": doc["val"], "qc": doc.get("qc")}
            out.append(self._one(v, doc.get("ts"), topic, "val", seq_i))
        else:
            raise FormatError("not a Databus data message (no 'vals', 'records' or 'val')",
                              path=topic)
        self.values.extend(out)
        return out

    def _one(self, v: Any, ts: Any, topic: str, pos: str, seq: int | None) -> DatabusValue:
        if not isinstance(v, dict) or "id" not in v:
            raise FormatError("value without an id", path=topic, position=pos, field="id")
        vid = str(v["id"])
        info = self._ids.get(vid)
        if info is None:
            if not self.salvage:
                raise FormatError(
                    f"id {vid!r} is not in the current metadata (known: "
                    f"{sorted(self._ids)[:20]}); the connector may have been reconfigured: "
                    "wait for the new metadata, or decode with salvage=True",
                    path=topic, position=pos, field="id")
            self.issues.append(f"{topic} {pos}: unknown id {vid!r} kept as UNKNOWN_ID_{vid}")
            info = {"name": "", "column": f"UNKNOWN_ID_{vid}"}
        if ts is None:
            raise FormatError("value without a timestamp", path=topic, position=pos,
                              field="ts")
        try:
            t = pd.Timestamp(ts)
            if pd.isna(t):
                raise ValueError("NaT")
            t = t.as_unit("ns")  # the cycle base counts ns: years 1678-2261
        except (ValueError, TypeError, OverflowError):
            raise FormatError(f"timestamp {str(ts)[:80]!r} is not a date-time", path=topic,
                              position=pos, field="ts") from None
        t = t.tz_localize("UTC") if t.tzinfo is None else t.tz_convert("UTC")
        value, lost = _value(v.get("val"))
        if lost:
            self.issues.append(f"{topic} {pos}: 64-bit integer {v.get('val')!r} beyond 2**53 "
                               "lost precision as float")
        qc_raw = v.get("qc")
        try:
            qc = int(qc_raw) if qc_raw is not None else None
        except (TypeError, ValueError, OverflowError):
            raise FormatError(f"qc {qc_raw!r} is not an integer", path=topic, position=pos,
                              field="qc") from None
        return DatabusValue(topic=topic, id=vid, name=info["name"], column=info["column"],
                            time=t, value=value, qc=qc, seq=seq)

    # ------------------------------------------------------------------ output
    def values_frame(self, values: list[DatabusValue] | None = None) -> pd.DataFrame:
        """Values as a long table (``time, column, name, id, value, text, qc, topic, seq``)."""
        vals = self.values if values is None else values
        return pd.DataFrame({
            "time": pd.to_datetime([v.time for v in vals], utc=True),
            "column": pd.Series([v.column for v in vals], dtype=object),
            "name": pd.Series([v.name for v in vals], dtype=object),
            "id": pd.Series([v.id for v in vals], dtype=object),
            "value": np.array([v.value if isinstance(v.value, float) else np.nan
                               for v in vals], dtype=np.float64),
            "text": pd.Series([v.value if isinstance(v.value, str) else None for v in vals],
                              dtype=object),
            "qc": pd.array([v.qc for v in vals], dtype="Int64"),
            "topic": pd.Series([v.topic for v in vals], dtype=object),
            "seq": pd.array([v.seq for v in vals], dtype="Int64"),
        })

    def recording(self, *, clear: bool = False, machine: str = "") -> Recording:
        """The values decoded so far as a recording on a ``cycle_time_s`` base.

        Parameters
        ----------
        clear : bool, default False
            Forget the values (and issues) afterwards (for windows of a stream).
        machine : str, optional
            Stored in ``meta.machine``; default the metadata's ``applicationName``.

        Returns
        -------
        Recording
            Cycle = floor(ns since epoch / cycle ns); time anchor (0, epoch). Several values
            of one column in one cycle: the last is kept (counted in ``meta.issues``).
        """
        df = self.values_frame()
        step_ns = round(self.cycle_time_s * 1e9)
        issues = list(self.issues)
        if df.empty:
            hf = pd.DataFrame(index=pd.Index(np.empty(0, dtype=np.int64), name="cycle"))
        else:
            ns = df["time"].astype("datetime64[ns, UTC]").astype("int64").to_numpy()
            cyc = np.floor_divide(ns, step_ns)
            df["cycle"] = cyc
            num = df[df["text"].isna()]
            dup = num.duplicated(subset=["cycle", "column"], keep="last")
            if dup.any():
                issues.append(f"{int(dup.sum())} values shared a cycle with a later value of "
                              "the same datapoint; the last is kept in the HF table (all are in "
                              "meta.attrs['databus_values'])")
            hf = num[~dup].pivot(index="cycle", columns="column", values="value")
            hf.columns.name = None
            hf.index = hf.index.astype(np.int64)
            hf.index.name = "cycle"
            hf = hf.sort_index()
            for q, label in ((0, "BAD"), (1, "UNCERTAIN")):
                bad = df[df["qc"] == q]
                if len(bad):
                    per = bad.groupby("column").size().to_dict()
                    issues.append(f"{len(bad)} values with quality {label} (qc={q}) kept: "
                                  f"{per}")
        txt = df[df["text"].notna()] if not df.empty else df
        lf = None
        if len(txt):
            lf = pd.DataFrame({
                "cycle": txt["cycle"].astype(np.int64).to_numpy(),
                "time": txt["time"].to_numpy(),
                "signal": txt["column"].to_numpy(dtype=object),
                "value": np.full(len(txt), np.nan),
                "text": txt["text"].to_numpy(dtype=object),
            })
        units: dict[str, str] = {}
        meta = RecordingMeta(
            machine=machine or str((self.metadata or {}).get("applicationName", "")),
            cycle_time_s=self.cycle_time_s,
            units=units,
            source_files=sorted({v.topic for v in self.values}),
            source_format="databus",
            time_anchors=[(0, pd.Timestamp(0, tz="UTC"))],
            gaps=[],  # values are irregular: rows without values are not gaps
            issues=issues,
            attrs={"databus_values": df, "datapoints": dict(self._ids),
                   "hashVersion": (self.metadata or {}).get("hashVersion")},
        )
        if clear:
            self.values = []
            self.issues = []
        return Recording(hf, lf=lf, meta=meta)
