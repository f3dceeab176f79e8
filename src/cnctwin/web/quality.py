"""Signal-quality accounting of a recording: effective rate, gaps, clock jitter, repairs.

Peers fall back silently to a lower rate or hide dropped samples (docs/reference/peers.md,
"ten features" no. 5); the dashboard shows what the recording's metadata says instead. Every
figure comes from :class:`~cnctwin.recording.RecordingMeta` and the cycle counter, so it can be
computed from a store's catalog row without loading the signals.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import pandas as pd

from cnctwin.recording import Recording, RecordingMeta

__all__ = ["SignalQuality", "signal_quality", "signal_quality_of"]


@dataclass(frozen=True)
class SignalQuality:
    """What a recording's time base looks like.

    Attributes
    ----------
    nominal_rate_hz : float
        1 / position-control cycle time [Hz].
    effective_rate_hz : float
        Recorded cycles per second of the counter span (gaps lower it) [Hz].
    coverage : float
        Recorded cycles / cycles the counter spans (1.0 without gaps).
    n_gaps : int
        Jumps in the cycle counter.
    missing_cycles : int
        Cycles the gaps leave out.
    missing_s : float
        Their duration [s].
    longest_gap_s : float
        Longest single gap [s].
    wraps : int
        Wrap-arounds of the 31-bit counter.
    n_anchors : int
        (cycle, wall-clock) anchors the time column was built from.
    anchor_jitter_ms : float
        Standard deviation of the anchors' wall-clock time about the counter's time line within
        each gap-free section [ms]; NaN with fewer than two anchors in one section.
    anchor_max_dev_ms : float
        Largest absolute deviation of an anchor from that line [ms].
    clock_step_s : float
        Largest difference between the gap-free sections' median anchor offsets: how far the
        wall clock and the counter disagree across gaps (a gap whose wall-clock length is not
        its missing cycles) [s]; 0 with one anchored section, NaN without anchors.
    partial : bool
        The reader kept what it could from damaged input (``salvage=True``).
    n_issues : int
        Repairs and oddities the reader listed in ``meta.issues``.
    """

    nominal_rate_hz: float
    effective_rate_hz: float
    coverage: float
    n_gaps: int
    missing_cycles: int
    missing_s: float
    longest_gap_s: float
    wraps: int
    n_anchors: int
    anchor_jitter_ms: float
    anchor_max_dev_ms: float
    clock_step_s: float
    partial: bool
    n_issues: int

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (for JSON)."""
        return asdict(self)


def _anchor_deviation_ms(meta: RecordingMeta) -> tuple[float, float, float]:
    """Std and max abs of anchor wall-clock minus the counter line, per gap-free section [ms],
    and the spread of the sections' median offsets [s]."""
    if not meta.time_anchors:
        return float("nan"), float("nan"), float("nan")
    cyc = np.array([a[0] for a in meta.time_anchors], dtype=np.int64)
    ns = np.array([pd.Timestamp(a[1]).value for a in meta.time_anchors], dtype=np.int64)
    step_ns = round(meta.cycle_time_s * 1e9)
    offset_ns = ns - (cyc - cyc[0]) * step_ns
    # difference in int64 first: epoch nanoseconds (~1.7e18) as float64 have 256 ns steps
    offset = (offset_ns - offset_ns[0]).astype(np.float64)
    bounds = np.array(sorted(g.after_cycle for g in meta.gaps), dtype=np.int64)
    section = np.searchsorted(bounds, cyc, side="left")
    devs = []
    medians = []
    for k in np.unique(section):
        sel = offset[section == k]
        medians.append(float(np.median(sel)))
        if sel.size >= 2:
            devs.append(sel - np.median(sel))
    step_s = (max(medians) - min(medians)) / 1e9
    if not devs:
        return float("nan"), float("nan"), step_s
    d = np.concatenate(devs) / 1e6
    return float(np.std(d)), float(np.max(np.abs(d))), step_s


def signal_quality(meta: RecordingMeta, *, n_cycles: int, first_cycle: int | None,
                   last_cycle: int | None) -> SignalQuality:
    """Signal-quality figures from a recording's metadata and counter range.

    Parameters
    ----------
    meta : RecordingMeta
        Metadata (gaps, wraps, anchors, issues, partial flag, cycle time).
    n_cycles : int
        Recorded HF rows.
    first_cycle, last_cycle : int or None
        First and last unwrapped cycle (None for an empty recording).

    Returns
    -------
    SignalQuality

    Notes
    -----
    ``effective_rate_hz = n_cycles / ((last - first + 1) * cycle_time_s)`` and
    ``coverage = n_cycles / (last - first + 1)``: the counter is the clock
    (docs/reference/data-formats.md
    §1.2), so missing cycles lower the rate instead of stretching time. The anchor jitter
    measures how far the wall-clock stamps a source wrote scatter about that clock.
    """
    dt = float(meta.cycle_time_s)
    span = (int(last_cycle) - int(first_cycle) + 1) if (
        first_cycle is not None and last_cycle is not None and n_cycles) else 0
    missing = sum(g.missing for g in meta.gaps)
    jitter, max_dev, clock_step = _anchor_deviation_ms(meta)
    return SignalQuality(
        nominal_rate_hz=1.0 / dt,
        effective_rate_hz=n_cycles / (span * dt) if span else float("nan"),
        coverage=n_cycles / span if span else float("nan"),
        n_gaps=len(meta.gaps),
        missing_cycles=int(missing),
        missing_s=missing * dt,
        longest_gap_s=max((g.missing for g in meta.gaps), default=0) * dt,
        wraps=int(meta.wraps),
        n_anchors=len(meta.time_anchors),
        anchor_jitter_ms=jitter,
        anchor_max_dev_ms=max_dev,
        clock_step_s=clock_step,
        partial=bool(meta.partial),
        n_issues=len(meta.issues),
    )


def signal_quality_of(rec: Recording) -> SignalQuality:
    """:func:`signal_quality` of a loaded recording.

    Parameters
    ----------
    rec : Recording
        The recording.

    Returns
    -------
    SignalQuality
        As :func:`signal_quality`.
    """
    c = rec.cycles
    return signal_quality(rec.meta, n_cycles=rec.n_cycles,
                          first_cycle=int(c[0]) if c.size else None,
                          last_cycle=int(c[-1]) if c.size else None)
