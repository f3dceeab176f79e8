"""The :class:`Recording`: one in-memory container for what an edge device records.

A recording holds

* ``hf``: the high-frequency table, one row per position-control cycle. Its index is the
  *unwrapped* CYCLE counter (``int64``, named ``"cycle"``; it keeps counting past the 2**31
  wrap-around of the raw counter). Column ``"time"`` is the UTC time of the cycle
  (``datetime64[ns, UTC]``); every other column is a signal named ``CODE|AXIS``
  (``CURRENT|SP1``, ``ENC_POS|Z1``) as ``float64``.
* ``lf``: low-frequency values in long form (columns ``cycle``, ``time``, ``signal``, ``value``,
  ``text``) on the same cycle base; :meth:`Recording.lf_wide` puts them on the HF rows.
* ``events``: NC block and call events (columns in :data:`EVENT_COLUMNS`) on the cycle base.
* ``external``: channels with their own clocks (dynamometer, thermal camera), each an
  :class:`ExternalChannel`.
* ``meta``: :class:`RecordingMeta`: machine, cycle time, axis map, units, source files, counter
  gaps and wrap-arounds, and every repair or drop the reader made (``issues``).

Nothing a reader accepted is silently dropped: what it repaired or could not keep is listed in
``meta.issues`` and, for incomplete input read with ``salvage=True``, ``meta.partial`` is set.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray

from cnctwin.exceptions import ConfigError, SignalNotFoundError
from cnctwin.signals import parse_column, unit

if TYPE_CHECKING:
    import polars
    import pyarrow

__all__ = [
    "CYCLE_COUNTER_MODULUS",
    "EVENT_COLUMNS",
    "LF_COLUMNS",
    "CounterGap",
    "ExternalChannel",
    "Recording",
    "RecordingMeta",
    "cycles_to_time",
    "empty_events",
    "empty_lf",
    "find_gaps",
    "jsonable",
    "meta_from_dict",
    "meta_from_json",
    "meta_to_dict",
    "meta_to_json",
    "nc_program_name",
    "unwrap_cycles",
]

def nc_program_name(path: str | None) -> str | None:
    """The main program's name as the operator knows it, from an NC ``call`` event's path.

    Parameters
    ----------
    path : str or None
        The control's internal path of a called program, e.g.
        ``/_N_MPF_DIR/_N_PART_MPF`` or ``/_N_WKS_DIR/_N_JOB_WPD/_N_PART_MPF``.

    Returns
    -------
    str or None
        ``'PART.MPF'``; None for a call that is not a main program (a cycle under
        ``/_CYCLES_DIR``, a subprogram ``_SPF``, a path without the ``_N_`` file prefix).

    Notes
    -----
    SINUMERIK stores a file ``NAME.EXT`` as ``_N_NAME_EXT`` in the passive file system
    (Siemens, SINUMERIK 840D sl Basic functions, K1: program names); main programs are MPF.

    Examples
    --------
    >>> nc_program_name("/_N_MPF_DIR/_N_PART_MPF")
    'PART.MPF'
    >>> nc_program_name("/_CYCLES_DIR/_CYCLE81") is None
    True
    """
    if not isinstance(path, str):
        return None
    leaf = path.rstrip("/").rsplit("/", 1)[-1]
    if not (leaf.startswith("_N_") and leaf.upper().endswith("_MPF")) or len(leaf) <= 7:
        return None
    return f"{leaf[3:-4]}.MPF"


CYCLE_COUNTER_MODULUS = 2**31
"""The raw CYCLE counter runs 0..2147483647 and then wraps (Siemens FAQ)."""

EVENT_COLUMNS: tuple[str, ...] = (
    "cycle",
    "kind",
    "channel",
    "seek_offset",
    "gcode",
    "ipo_gcode",
    "selected_tool",
    "active_tool",
    "path",
    "call_stack_level",
)
"""Columns of ``Recording.events``. ``kind`` is ``"block"`` or ``"call"``."""

LF_COLUMNS: tuple[str, ...] = ("cycle", "time", "signal", "value", "text")
"""Columns of ``Recording.lf``: ``value`` is float (NaN for text values), ``text`` the raw value."""


@dataclass(frozen=True)
class CounterGap:
    """A jump in the CYCLE counter: cycles ``after_cycle+1 .. before_cycle-1`` are missing."""

    after_cycle: int
    before_cycle: int

    @property
    def missing(self) -> int:
        """Number of missing cycles."""
        return self.before_cycle - self.after_cycle - 1


@dataclass
class ExternalChannel:
    """A source with its own clock (rotary dynamometer, thermal camera, accelerometer).

    Attributes
    ----------
    name : str
        Channel name (``"dynamometer"``).
    data : pandas.DataFrame
        Samples; index ``time_s`` is the source's own clock in seconds [s].
    units : dict
        Column -> unit.
    fs_hz : float or None
        Nominal sample rate [Hz]; ``None`` for irregular sources (one camera reading per hole).
    offset_s : float
        Estimated offset of the source clock to the recording time base: a sample at own time
        ``t`` happened at ``t + offset_s`` seconds after the first HF cycle [s]. Set by alignment.
    drift_ppm : float
        Estimated clock drift of the source [ppm]; own time is scaled by ``1 + drift_ppm*1e-6``.
    aligned : bool
        Whether ``offset_s``/``drift_ppm`` were estimated (by cross-correlation) or given.
    source : str
        File or stream the channel came from.
    """

    name: str
    data: pd.DataFrame
    units: dict[str, str] = field(default_factory=dict)
    fs_hz: float | None = None
    offset_s: float = 0.0
    drift_ppm: float = 0.0
    aligned: bool = False
    source: str = ""

    def time_on_recording_s(self) -> NDArray[np.float64]:
        """Sample times on the recording's time axis (seconds after the first HF cycle) [s]."""
        own = np.asarray(self.data.index, dtype=np.float64)
        return own * (1.0 + self.drift_ppm * 1e-6) + self.offset_s


@dataclass
class RecordingMeta:
    """Metadata of a recording.

    Attributes
    ----------
    machine : str
        Machine name (``Header.MachineInfo.MachineName`` for Capture4Analysis).
    cycle_time_s : float
        Position-control cycle time [s] (2 ms on the thesis machine).
    axis_map : dict
        Axis number (the ``|n`` in SINUMERIK addresses) -> axis name.
    units : dict
        Column -> unit (filled from the signal catalog where the source does not say).
    source_files : list of str
        Files the recording was read from, in order.
    source_format : str
        Reader that produced it (``"capture4analysis"``, ``"servo_trace"``, ``"sim"``, ...).
    time_anchors : list of (int, pandas.Timestamp)
        (unwrapped cycle, UTC time) pairs the time column was built from.
    gaps : list of CounterGap
        Jumps in the cycle counter.
    wraps : int
        How many times the raw 31-bit counter wrapped inside the recording.
    issues : list of str
        Every repair, drop or oddity the reader saw (empty axis fields filled from the axis map,
        duplicate events removed, a declared type ignored, ...). Nothing is dropped silently.
    partial : bool
        True when the input was incomplete and ``salvage=True`` kept what could be read.
    attrs : dict
        Source-specific extras (header fields, job description, simulator truth file, ...).
    """

    machine: str = ""
    cycle_time_s: float = 0.002
    axis_map: dict[int, str] = field(default_factory=dict)
    units: dict[str, str] = field(default_factory=dict)
    source_files: list[str] = field(default_factory=list)
    source_format: str = ""
    time_anchors: list[tuple[int, pd.Timestamp]] = field(default_factory=list)
    gaps: list[CounterGap] = field(default_factory=list)
    wraps: int = 0
    issues: list[str] = field(default_factory=list)
    partial: bool = False
    attrs: dict[str, Any] = field(default_factory=dict)

    def copy(self) -> RecordingMeta:
        """A deep-enough copy (lists and dicts copied)."""
        return dataclasses.replace(
            self,
            axis_map=dict(self.axis_map),
            units=dict(self.units),
            source_files=list(self.source_files),
            time_anchors=list(self.time_anchors),
            gaps=list(self.gaps),
            issues=list(self.issues),
            attrs=dict(self.attrs),
        )


# ---------------------------------------------------------------------------- meta <-> JSON
def jsonable(value: Any) -> Any:
    """``value`` with everything strict JSON cannot hold made plain (recursively).

    NaN, infinities and missing values (``None``, ``pd.NA``, ``pd.NaT``) become ``None``
    (JSON ``null``; a bare ``NaN`` is not JSON), numpy scalars and arrays Python numbers and
    lists, timestamps ISO 8601 text, mapping keys text; anything else its ``str()``.

    Parameters
    ----------
    value : object
        Any value.

    Returns
    -------
    object
        ``None``, ``bool``, ``int``, ``float``, ``str``, ``list`` or ``dict``.

    Examples
    --------
    >>> jsonable({1: np.float64("nan"), "t": [np.int64(2), True]})
    {'1': None, 't': [2, True]}
    """
    if value is None or value is pd.NA or value is pd.NaT:
        return None
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, int | np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        f = float(value)
        return f if math.isfinite(f) else None
    if isinstance(value, str):
        return value
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple | np.ndarray):
        return [jsonable(v) for v in value]
    if isinstance(value, pd.Timestamp):
        return value.isoformat()
    return str(value)


def meta_to_dict(meta: RecordingMeta) -> dict[str, Any]:
    """:class:`RecordingMeta` as plain JSON-ready values: the one encoding of the metadata.

    Every file and store that keeps a recording's metadata (Parquet schema metadata, the
    simulator's ``meta.json``, the stores' catalog) writes this form.

    Parameters
    ----------
    meta : RecordingMeta
        The metadata.

    Returns
    -------
    dict
        ``time_anchors`` as ``[cycle, ISO 8601 time]`` pairs, ``gaps`` as ``[after, before]``
        pairs, ``axis_map`` keys as text, ``attrs`` through :func:`jsonable`.
    """
    return {
        "machine": meta.machine,
        "cycle_time_s": float(meta.cycle_time_s),
        "axis_map": {str(k): v for k, v in meta.axis_map.items()},
        "units": dict(meta.units),
        "source_files": [str(s) for s in meta.source_files],
        "source_format": meta.source_format,
        "time_anchors": [[int(c), pd.Timestamp(t).isoformat()] for c, t in meta.time_anchors],
        "gaps": [[int(g.after_cycle), int(g.before_cycle)] for g in meta.gaps],
        "wraps": int(meta.wraps),
        "issues": list(meta.issues),
        "partial": bool(meta.partial),
        "attrs": jsonable(meta.attrs),
    }


def _anchor_time(value: Any) -> pd.Timestamp:
    if isinstance(value, int | np.integer):  # ns since the epoch (stores before one encoding)
        return pd.Timestamp(int(value), unit="ns", tz="UTC")
    return pd.Timestamp(value)


def meta_from_dict(doc: dict[str, Any]) -> RecordingMeta:
    """Inverse of :func:`meta_to_dict`; keys it does not know are ignored.

    Parameters
    ----------
    doc : dict
        As written by :func:`meta_to_dict`. Anchor times may also be integer nanoseconds since
        the epoch (the stores' catalog before the encodings were made one).

    Returns
    -------
    RecordingMeta

    Raises
    ------
    ConfigError
        If ``doc`` is not a mapping or a value has the wrong shape (names the key).
    """
    if not isinstance(doc, dict):
        raise ConfigError(f"recording metadata must be a JSON object, not {type(doc).__name__}")
    key = "machine"
    try:
        kw: dict[str, Any] = {}
        for key in ("machine", "source_format"):
            if key in doc:
                kw[key] = str(doc[key])
        key = "cycle_time_s"
        if key in doc:
            kw[key] = float(doc[key])
        key = "axis_map"
        kw[key] = {int(k): str(v) for k, v in (doc.get(key) or {}).items()}
        key = "units"
        kw[key] = {str(k): str(v) for k, v in (doc.get(key) or {}).items()}
        key = "source_files"
        kw[key] = [str(s) for s in doc.get(key) or []]
        key = "time_anchors"
        kw[key] = [(int(c), _anchor_time(t)) for c, t in doc.get(key) or []]
        key = "gaps"
        kw[key] = [CounterGap(int(a), int(b)) for a, b in doc.get(key) or []]
        key = "wraps"
        kw[key] = int(doc.get(key) or 0)
        key = "issues"
        kw[key] = [str(s) for s in doc.get(key) or []]
        key = "partial"
        kw[key] = bool(doc.get(key) or False)
        key = "attrs"
        kw[key] = dict(doc.get(key) or {})
    except (TypeError, ValueError, AttributeError) as exc:
        raise ConfigError(f"recording metadata: {key!r} has the wrong form ({exc}); "
                          "expected what meta_to_dict writes") from exc
    return RecordingMeta(**kw)


def meta_to_json(meta: RecordingMeta) -> str:
    """:func:`meta_to_dict` as JSON text (the one encoding of :class:`RecordingMeta`).

    Parameters
    ----------
    meta : RecordingMeta
        The metadata.

    Returns
    -------
    str

    Examples
    --------
    >>> m = RecordingMeta(machine="DMC", axis_map={1: "X1"})
    >>> meta_from_json(meta_to_json(m)) == m
    True
    """
    return json.dumps(meta_to_dict(meta))


def meta_from_json(text: str | bytes) -> RecordingMeta:
    """Inverse of :func:`meta_to_json`.

    Parameters
    ----------
    text : str or bytes
        JSON text.

    Returns
    -------
    RecordingMeta

    Raises
    ------
    ConfigError
        If the text is not JSON or not the metadata's form.
    """
    try:
        doc = json.loads(text)
    except ValueError as exc:
        raise ConfigError(f"recording metadata is not valid JSON: {exc}") from exc
    return meta_from_dict(doc)


def unwrap_cycles(
    raw: ArrayLike, *, modulus: int = CYCLE_COUNTER_MODULUS
) -> tuple[NDArray[np.int64], int]:
    """Unwrap a raw CYCLE counter that wraps at ``modulus``.

    A backward step larger than half the modulus is taken as a wrap-around and the following
    values are shifted up by ``modulus``.

    Parameters
    ----------
    raw : array-like of int
        Raw counter values in arrival order.
    modulus : int, default 2**31
        Counter period.

    Returns
    -------
    cycles : numpy.ndarray of int64
        Monotonic (across wraps) counter.
    wraps : int
        Number of wrap-arounds found.
    """
    c = np.asarray(raw, dtype=np.int64)
    if c.size < 2:
        return c.copy(), 0
    step = np.diff(c)
    wrap_at = step < -(modulus // 2)
    wraps = int(wrap_at.sum())
    if wraps == 0:
        return c.copy(), 0
    offset = np.concatenate([[0], np.cumsum(wrap_at, dtype=np.int64)]) * modulus
    return c + offset, wraps


def find_gaps(cycles: NDArray[np.int64]) -> list[CounterGap]:
    """Jumps larger than one in a sorted, unwrapped cycle counter.

    Parameters
    ----------
    cycles : numpy.ndarray
        Unwrapped cycle counter in recording order.

    Returns
    -------
    list of CounterGap
    """
    c = np.asarray(cycles, dtype=np.int64)
    if c.size < 2:
        return []
    idx = np.flatnonzero(np.diff(c) > 1)
    return [CounterGap(int(c[i]), int(c[i + 1])) for i in idx]


def _int_median(values: NDArray[np.int64]) -> int:
    # integer median: np.median goes through float64, which rounds epoch nanoseconds
    # (~1.7e18) to 256 ns steps
    srt = np.sort(values)
    mid = srt.size // 2
    return int(srt[mid]) if srt.size % 2 else (int(srt[mid - 1]) + int(srt[mid])) // 2


def cycles_to_time(
    cycles: ArrayLike,
    anchors: Sequence[tuple[int, pd.Timestamp]],
    *,
    cycle_time_s: float,
    gaps: Sequence[CounterGap] = (),
) -> pd.DatetimeIndex:
    """UTC time of each cycle from (cycle, time) anchors.

    The cycle counter is the clock: time advances by exactly ``cycle_time_s`` per cycle. The
    anchors set the absolute time; with several anchors the median offset is used, so a single
    late wall-clock stamp (the HFTimestamp is written when a chunk is sent) does not bend the
    time axis.

    A counter gap need not last as long as its missing cycles (the real Capture4Analysis sample
    jumps 3860 cycles while its wall-clock anchors advance 8 s less), so with ``gaps`` every
    contiguous section between gaps gets the median offset of its own anchors; a section without
    anchors takes the offset of the nearest section that has some. Time must not run backwards:
    if the sections' anchors would make it do so (they do in that sample: the anchors after the
    gap lie 0.28 s *before* the last cycle ahead of it), the whole recording follows the counter
    with the median offset of all anchors, as without ``gaps``.

    Parameters
    ----------
    cycles : array-like of int
        Unwrapped cycle counter.
    anchors : sequence of (int, pandas.Timestamp)
        Known (cycle, UTC time) pairs. If empty, times start at the Unix epoch.
    cycle_time_s : float
        Position-control cycle time [s].
    gaps : sequence of CounterGap, optional
        Counter gaps that split the recording into separately anchored sections.

    Returns
    -------
    pandas.DatetimeIndex
        tz-aware UTC times.
    """
    c = np.asarray(cycles, dtype=np.int64)
    step_ns = round(cycle_time_s * 1e9)
    if len(anchors) == 0:
        base_cycle = int(c[0]) if c.size else 0
        ns = (c - base_cycle) * step_ns
        return pd.DatetimeIndex(pd.to_datetime(ns, unit="ns", utc=True), name="time")
    a_cyc = np.array([a[0] for a in anchors], dtype=np.int64)
    a_ns = np.array([pd.Timestamp(a[1]).value for a in anchors], dtype=np.int64)
    base_cycle = int(a_cyc[0])
    offsets = a_ns - (a_cyc - base_cycle) * step_ns
    # section k holds the cycles after gap k-1 up to gap k (an anchor inside a gap belongs to
    # the section after it)
    bounds = np.array(sorted(g.after_cycle for g in gaps), dtype=np.int64)
    a_sec = np.searchsorted(bounds, a_cyc, side="left")
    n_sec = bounds.size + 1
    sec_off = np.full(n_sec, np.iinfo(np.int64).min, dtype=np.int64)
    for k in np.unique(a_sec):
        sec_off[k] = _int_median(offsets[a_sec == k])
    have = np.flatnonzero(sec_off != np.iinfo(np.int64).min)
    for k in range(n_sec):  # sections without anchors: nearest anchored section
        if sec_off[k] == np.iinfo(np.int64).min:
            sec_off[k] = sec_off[have[np.argmin(np.abs(have - k))]]
    c_sec = np.searchsorted(bounds, c, side="left")
    ns = sec_off[c_sec] + (c - base_cycle) * step_ns
    if n_sec > 1 and np.any(np.diff(ns) <= 0):
        ns = _int_median(offsets) + (c - base_cycle) * step_ns
    return pd.DatetimeIndex(pd.to_datetime(ns, unit="ns", utc=True), name="time")


def empty_events() -> pd.DataFrame:
    """An events table with no rows and the column types of :data:`EVENT_COLUMNS`.

    Returns
    -------
    pandas.DataFrame
        No rows, the :data:`EVENT_COLUMNS`.
    """
    return _empty_events_template().copy()


@functools.cache
def _empty_events_template() -> pd.DataFrame:
    # built once (1 ms of pandas dtype work; the edge runtime asks for one per hole), handed
    # out as copies, so no caller can change it
    return pd.DataFrame(
        {
            "cycle": pd.Series(dtype="int64"),
            "kind": pd.Series(dtype="object"),
            "channel": pd.Series(dtype="Int64"),
            "seek_offset": pd.Series(dtype="Int64"),
            "gcode": pd.Series(dtype="object"),
            "ipo_gcode": pd.Series(dtype="object"),
            "selected_tool": pd.Series(dtype="Int64"),
            "active_tool": pd.Series(dtype="Int64"),
            "path": pd.Series(dtype="object"),
            "call_stack_level": pd.Series(dtype="Int64"),
        }
    )


def empty_lf() -> pd.DataFrame:
    """An LF table with no rows and the column types of :data:`LF_COLUMNS`.

    Returns
    -------
    pandas.DataFrame
        No rows, the :data:`LF_COLUMNS`.
    """
    return _empty_lf_template().copy()


@functools.cache
def _empty_lf_template() -> pd.DataFrame:
    return pd.DataFrame(
        {
            "cycle": pd.Series(dtype="int64"),
            "time": pd.Series(dtype="datetime64[ns, UTC]"),
            "signal": pd.Series(dtype="object"),
            "value": pd.Series(dtype="float64"),
            "text": pd.Series(dtype="object"),
        }
    )


class Recording:
    """A recording of edge signals on one time base.

    Parameters
    ----------
    hf : pandas.DataFrame
        HF table indexed by the unwrapped cycle counter (``int64``), with a ``"time"`` column
        (UTC) and signal columns ``CODE|AXIS``. If ``"time"`` is missing it is built from
        ``meta.time_anchors`` and ``meta.cycle_time_s``.
    lf : pandas.DataFrame, optional
        LF values in long form (:data:`LF_COLUMNS`).
    events : pandas.DataFrame, optional
        NC events (:data:`EVENT_COLUMNS`).
    external : dict of ExternalChannel, optional
        Channels with their own clocks.
    meta : RecordingMeta, optional
        Metadata.

    Examples
    --------
    >>> import numpy as np
    >>> rec = Recording.from_arrays(np.arange(100, 105), {"CURRENT|SP1": np.ones(5)})
    >>> rec.n_cycles, rec.fs_hz
    (5, 500.0)
    >>> float(rec.signal("CURRENT", "SP1").sum())
    5.0
    """

    def __init__(
        self,
        hf: pd.DataFrame,
        *,
        lf: pd.DataFrame | None = None,
        events: pd.DataFrame | None = None,
        external: dict[str, ExternalChannel] | None = None,
        meta: RecordingMeta | None = None,
    ) -> None:
        self.meta = meta if meta is not None else RecordingMeta()
        if hf.index.name != "cycle":
            if "cycle" in hf.columns:
                hf = hf.set_index("cycle")
            else:
                raise ConfigError("hf table needs a 'cycle' index (the unwrapped CYCLE counter)")
        if hf.index.dtype != np.int64:
            hf.index = hf.index.astype(np.int64)
        if "time" not in hf.columns:
            hf.insert(
                0,
                "time",
                cycles_to_time(
                    hf.index.to_numpy(), self.meta.time_anchors,
                    cycle_time_s=self.meta.cycle_time_s, gaps=self.meta.gaps,
                ),
            )
        self.hf = hf
        self.lf = lf if lf is not None else empty_lf()
        self.events = events if events is not None else empty_events()
        self.external: dict[str, ExternalChannel] = dict(external or {})
        for col in self.columns:
            self.meta.units.setdefault(col, unit(col))

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_arrays(
        cls,
        cycles: ArrayLike,
        signals: dict[str, ArrayLike],
        *,
        start_time: pd.Timestamp | str | None = None,
        cycle_time_s: float = 0.002,
        machine: str = "",
        axis_map: dict[int, str] | None = None,
        source_format: str = "arrays",
    ) -> Recording:
        """Build a recording from a cycle counter and ``CODE|AXIS`` arrays.

        Parameters
        ----------
        cycles : array-like of int
            Cycle counter (raw; wrap-around is unwrapped and counted).
        signals : dict
            Column name -> values, each as long as ``cycles``.
        start_time : Timestamp or str, optional
            UTC time of the first cycle; default the Unix epoch.
        cycle_time_s : float, default 0.002
            Position-control cycle time [s].
        machine : str, optional
            Machine name.
        axis_map : dict, optional
            Axis number -> name.
        source_format : str, default 'arrays'
            Recorded in ``meta.source_format``.
        """
        c, wraps = unwrap_cycles(cycles)
        data: dict[str, NDArray[np.float64]] = {}
        for name, values in signals.items():
            arr = np.asarray(values, dtype=np.float64)
            if arr.shape != c.shape:
                raise ConfigError(
                    f"signal {name!r} has {arr.size} samples, the cycle counter {c.size}"
                )
            data[name] = arr
        anchors: list[tuple[int, pd.Timestamp]] = []
        if start_time is not None and c.size:
            t0 = pd.Timestamp(start_time)
            anchors = [(int(c[0]), t0.tz_localize("UTC") if t0.tzinfo is None else t0)]
        meta = RecordingMeta(
            machine=machine,
            cycle_time_s=cycle_time_s,
            axis_map=dict(axis_map or {}),
            source_format=source_format,
            time_anchors=anchors,
            gaps=find_gaps(c),
            wraps=wraps,
        )
        hf = pd.DataFrame(data, index=pd.Index(c, name="cycle"))
        return cls(hf, meta=meta)

    # ------------------------------------------------------------------ description
    @property
    def columns(self) -> list[str]:
        """Signal columns of the HF table (``CODE|AXIS``), without ``time``."""
        return [c for c in self.hf.columns if c != "time"]

    @property
    def signals(self) -> list[str]:
        """Distinct signal codes present (``["CMD_SPEED", "CURRENT", ...]``)."""
        return sorted({parse_column(c)[0] for c in self.columns})

    @property
    def axes(self) -> list[str]:
        """Distinct axis names present, in first-seen order."""
        seen: dict[str, None] = {}
        for c in self.columns:
            axis = parse_column(c)[1]
            if axis is not None:
                seen.setdefault(axis, None)
        return list(seen)

    @property
    def cycles(self) -> NDArray[np.int64]:
        """The unwrapped cycle counter of the HF rows."""
        return self.hf.index.to_numpy(dtype=np.int64)

    @property
    def n_cycles(self) -> int:
        """Number of HF rows (recorded cycles)."""
        return len(self.hf)

    @property
    def fs_hz(self) -> float:
        """HF sample rate, 1 / cycle time [Hz]."""
        return 1.0 / self.meta.cycle_time_s

    @property
    def duration_s(self) -> float:
        """Span from the first to the last cycle, gaps included [s]."""
        if self.n_cycles == 0:
            return 0.0
        c = self.cycles
        return float(c[-1] - c[0]) * self.meta.cycle_time_s

    @property
    def time_s(self) -> NDArray[np.float64]:
        """Seconds since the first recorded cycle, from the counter (gaps keep their length) [s]."""
        c = self.cycles
        if c.size == 0:
            return np.empty(0)
        return (c - c[0]).astype(np.float64) * self.meta.cycle_time_s

    def __len__(self) -> int:
        return self.n_cycles

    def __repr__(self) -> str:
        return (
            f"<Recording {self.meta.machine or '?'}: {self.n_cycles} cycles "
            f"({self.duration_s:.3f} s at {self.fs_hz:g} Hz), {len(self.columns)} signals on "
            f"axes {', '.join(self.axes) or '-'}, {len(self.events)} events, "
            f"{self.lf['signal'].nunique()} LF signals, {len(self.external)} external"
            f"{', PARTIAL' if self.meta.partial else ''}>"
        )

    # ------------------------------------------------------------------ access
    def signal(self, code: str, axis: str | None = None) -> pd.Series:
        """One HF signal as a Series indexed by cycle.

        Parameters
        ----------
        code : str
            Signal code (``"CURRENT"``) or full column name (``"CURRENT|SP1"``).
        axis : str, optional
            Axis name; required when ``code`` has no ``|axis`` part.

        Raises
        ------
        SignalNotFoundError
            Listing the columns that exist.
        """
        name = code if axis is None else f"{code}|{axis}"
        if name not in self.hf.columns or name == "time":
            raise SignalNotFoundError(
                f"signal {name!r} is not in this recording; it has: {', '.join(self.columns)}"
            )
        return self.hf[name]

    def has(self, code: str, axis: str | None = None) -> bool:
        """Whether the HF column exists."""
        name = code if axis is None else f"{code}|{axis}"
        return name in self.hf.columns and name != "time"

    def select(
        self,
        *,
        signals: Iterable[str] | None = None,
        axes: Iterable[str] | None = None,
        cycles: tuple[int | None, int | None] | None = None,
        time: tuple[pd.Timestamp | str | None, pd.Timestamp | str | None] | None = None,
        seconds: tuple[float | None, float | None] | None = None,
    ) -> Recording:
        """A new recording restricted to signals, axes and a cycle or time range.

        Parameters
        ----------
        signals : iterable of str, optional
            Signal codes (``"CURRENT"``) or full column names to keep.
        axes : iterable of str, optional
            Axis names to keep.
        cycles : (int or None, int or None), optional
            Inclusive range of the unwrapped cycle counter.
        time : (Timestamp or None, Timestamp or None), optional
            Inclusive UTC time range.
        seconds : (float or None, float or None), optional
            Inclusive range in seconds since the first cycle [s].

        Returns
        -------
        Recording
            LF values and events are cut to the same cycle range; external channels are kept.
        """
        cols = self.columns
        if signals is not None:
            wanted = set(signals)
            cols = [c for c in cols if c in wanted or parse_column(c)[0] in wanted]
        if axes is not None:
            wanted_axes = set(axes)
            cols = [c for c in cols if parse_column(c)[1] in wanted_axes]
        mask = np.ones(self.n_cycles, dtype=bool)
        c = self.cycles
        if cycles is not None:
            lo, hi = cycles
            if lo is not None:
                mask &= c >= lo
            if hi is not None:
                mask &= c <= hi
        if seconds is not None and c.size:
            lo_s, hi_s = seconds
            t = self.time_s
            if lo_s is not None:
                mask &= t >= lo_s
            if hi_s is not None:
                mask &= t <= hi_s
        if time is not None:
            lo_t, hi_t = time
            tt = self.hf["time"]
            if lo_t is not None:
                mask &= (tt >= pd.Timestamp(lo_t)).to_numpy()
            if hi_t is not None:
                mask &= (tt <= pd.Timestamp(hi_t)).to_numpy()
        hf = self.hf.loc[mask, ["time", *cols]]
        meta = self.meta.copy()
        meta.units = {k: v for k, v in meta.units.items() if k in cols}
        if hf.empty:
            lf = self.lf.iloc[0:0]
            events = self.events.iloc[0:0]
            meta.gaps = []
        else:
            c0, c1 = int(hf.index[0]), int(hf.index[-1])
            lf = self.lf[(self.lf["cycle"] >= c0) & (self.lf["cycle"] <= c1)]
            events = self.events[(self.events["cycle"] >= c0) & (self.events["cycle"] <= c1)]
            meta.gaps = [g for g in meta.gaps if g.after_cycle >= c0 and g.before_cycle <= c1]
        return Recording(
            hf, lf=lf.reset_index(drop=True), events=events.reset_index(drop=True),
            external=self.external, meta=meta,
        )

    def lf_wide(self, *, method: str = "ffill") -> pd.DataFrame:
        """LF values as columns on the HF cycle index.

        Parameters
        ----------
        method : {'ffill', 'exact'}
            ``'ffill'`` holds the last LF value (what the drive reported most recently);
            ``'exact'`` leaves NaN where no LF value arrived at that cycle.

        Returns
        -------
        pandas.DataFrame
            Index: HF cycles; one float column per LF signal.
        """
        if method not in ("ffill", "exact"):
            raise ConfigError(f"method must be 'ffill' or 'exact', not {method!r}")
        if self.lf.empty:
            return pd.DataFrame(index=self.hf.index)
        wide = self.lf.pivot_table(index="cycle", columns="signal", values="value", aggfunc="last")
        wide.columns.name = None
        if method == "exact":
            return wide.reindex(self.hf.index)
        union = wide.index.union(self.hf.index)
        return wide.reindex(union).ffill().reindex(self.hf.index)

    # ------------------------------------------------------------------ conversion
    def to_pandas(self, *, time_index: bool = False) -> pd.DataFrame:
        """The HF table (a view where pandas allows; no copy of the signal data).

        Parameters
        ----------
        time_index : bool, default False
            Index by UTC time instead of cycle (the cycle becomes a column).
        """
        if not time_index:
            return self.hf
        return self.hf.reset_index().set_index("time")

    def to_arrow(self) -> pyarrow.Table:
        """The HF table as a :class:`pyarrow.Table` with ``cycle`` and ``time`` columns.

        Column metadata carry the units (``b"unit"``).
        """
        import pyarrow as pa

        table = pa.Table.from_pandas(self.hf.reset_index(), preserve_index=False)
        fields = [
            f.with_metadata({b"unit": self.meta.units.get(f.name, "").encode()})
            for f in table.schema
        ]
        return table.cast(pa.schema(fields, metadata=table.schema.metadata))

    def to_polars(self) -> polars.DataFrame:
        """The HF table as a :class:`polars.DataFrame` (via Arrow, zero-copy for numeric columns).

        Requires the ``polars`` extra: ``pip install 'cnctwin[polars]'``.
        """
        try:
            import polars as pl
        except ImportError as exc:  # pragma: no cover - depends on the environment
            raise ImportError(
                "to_polars needs polars: pip install 'cnctwin[polars]'"
            ) from exc
        return pl.from_arrow(self.to_arrow())  # type: ignore[return-value]

    def copy(self) -> Recording:
        """A deep copy."""
        return Recording(
            self.hf.copy(),
            lf=self.lf.copy(),
            events=self.events.copy(),
            external={
                k: dataclasses.replace(v, data=v.data.copy(), units=dict(v.units))
                for k, v in self.external.items()
            },
            meta=self.meta.copy(),
        )
