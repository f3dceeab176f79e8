"""Live hole context: which hole the tool is cutting and how far through it, sample by sample.

The batch hole record (:func:`cnctwin.usecases.holes.hole_record`) knows a hole's cut only
once it is complete: its ``progress`` is ``linspace(0, 1)`` from the first cycle in the
material (``cut_start_cycle``) to the bottom (``cut_end_cycle``). A live monitor needs the
same context *while* the tool cuts. :class:`CutTracker` derives it causally, one cycle at a
time, from signals every cycle carries:

* **in the cut**: the Z setpoint (``DES_POS``) moves down, the tool tip (``ENC_POS``) is at or
  below the workpiece surface and the spindle turns (``|CMD_SPEED|`` >= ``min_speed_rpm``);
  the same tests as the batch record (surface crossing of ``ENC_POS``, bottom = where the
  setpoint stops going down, spindle-off plunges are not holes);
* **tip depth** ``d = surface - ENC_POS`` [mm] and **progress** ``d / depth`` [-];
* **surface and depth** from the active drilling cycle of the NC program (``MCALL
  CYCLE81(RTP, RFP, SDIS, DP, DPR)``: surface RFP, depth ``RFP - DP`` or DPR), else from the
  last completed hole row (``surface_z_mm``, ``depth_mm``: the same NC program drills the
  same depth); without either (the first hole of a stream without NC events) the samples
  stay outside (not judged);
* **feed and speed of the cut**: median of the setpoint feed [mm/min] and ``|CMD_SPEED|``
  [rpm] over the first ``latch_cycles`` cycles in the material, then held (the batch row
  takes the plunge's feed and the median speed).

Latency: none for the hole number, depth and progress (each cycle's values come with that
cycle); the end of a cut is known on the first cycle whose setpoint no longer moves down
(one cycle after the bottom, which the batch record counts as the last cut cycle; the
detector does not judge the last 1 % of the cut anyway).
"""

from __future__ import annotations

import math
import re
import statistics
from dataclasses import dataclass

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from cnctwin.usecases.holes import HoleEvents, modal_cycle_call

__all__ = ["CutContext", "CutTracker", "drilling_cycle_geometry"]

_CYCLE = re.compile(r"\b(CYCLE8[1-9])\s*\(([^)]*)\)", re.IGNORECASE)


def drilling_cycle_geometry(block: str) -> tuple[float, float] | None:
    """Surface and depth of a SINUMERIK drilling-cycle call ``CYCLE8x(RTP, RFP, SDIS, DP, DPR)``.

    Parameters
    ----------
    block : str
        NC block text, e.g. ``'MCALL CYCLE81(10, 0, 2, -20)'``.

    Returns
    -------
    (surface_z_mm, depth_mm) or None
        Reference plane RFP [mm] and final depth below it [mm]: ``RFP - DP`` (DP absolute),
        else DPR (relative). None if the block calls no drilling cycle or lacks RFP and depth.

    Notes
    -----
    Parameter order of CYCLE81..CYCLE89 (SINUMERIK 840D sl, Programming Manual Cycles):
    RTP retraction plane, RFP reference plane, SDIS safety distance, DP final depth
    (absolute), DPR final depth relative to RFP.

    Examples
    --------
    >>> drilling_cycle_geometry("MCALL CYCLE81(10, 0, 2, -20)")
    (0.0, 20.0)
    """
    m = _CYCLE.search(block)
    if not m:
        return None
    parts = [p.strip() for p in m.group(2).split(",")]

    def num(i: int) -> float:
        try:
            return float(parts[i]) if len(parts) > i and parts[i] else math.nan
        except ValueError:
            return math.nan

    rfp, dp, dpr = num(1), num(3), num(4)
    depth = rfp - dp if math.isfinite(dp) else dpr
    if not (math.isfinite(rfp) and math.isfinite(depth) and depth > 0):
        return None
    return rfp, depth


@dataclass
class CutContext:
    """Hole context of a run of cycles (one value per cycle).

    Attributes
    ----------
    hole : numpy.ndarray
        Hole number while in the material, -1 outside [-].
    progress : numpy.ndarray
        Tip depth / hole depth, NaN outside [-].
    depth_mm : numpy.ndarray
        Tip depth below the surface, NaN outside [mm].
    feed_mm_min : numpy.ndarray
        Feed of the cut (latched setpoint feed), NaN outside [mm/min].
    speed_rpm : numpy.ndarray
        Spindle speed of the cut (latched ``|CMD_SPEED|``), NaN outside [rpm].
    """

    hole: NDArray[np.float64]
    progress: NDArray[np.float64]
    depth_mm: NDArray[np.float64]
    feed_mm_min: NDArray[np.float64]
    speed_rpm: NDArray[np.float64]


class CutTracker:
    """Causal per-cycle hole context (see the module docstring).

    Parameters
    ----------
    cycle_time_s : float, default 0.002
        Position-control cycle [s].
    min_speed_mm_s : float, default 0.05
        Setpoint speed above which Z counts as moving down [mm/s] (as the hole record).
    min_speed_rpm : float, default 10
        Slower spindle: a plunge is not a cut (as the hole record) [rpm].
    settle_s : float, default 1
        A re-entry at the same X/Y within this time after the last cut continues the hole
        (peck drilling) [s].
    latch_cycles : int, default 25
        In-material cycles over which the feed and speed of a cut are taken [-].
    first_hole : int, default 0
        Number of the first hole.
    """

    def __init__(self, *, cycle_time_s: float = 0.002, min_speed_mm_s: float = 0.05,
                 min_speed_rpm: float = 10.0, settle_s: float = 1.0, latch_cycles: int = 25,
                 first_hole: int = 0) -> None:
        self.cycle_time_s = cycle_time_s
        self.min_speed_mm_s, self.min_speed_rpm = min_speed_mm_s, min_speed_rpm
        self.settle_s, self.latch_cycles = settle_s, max(int(latch_cycles), 1)
        self.next_hole = first_hole
        self.nc_geometry: tuple[float, float] | None = None
        """(surface, depth) of the modal drilling cycle, from the NC events [mm]."""
        self.row_geometry: tuple[float, float] | None = None
        """(surface, depth) of the last completed hole row [mm] (fallback)."""
        self.nc_cancelled = False
        """The NC events cancelled the drilling cycle (``MCALL``, ``G80``): no hole until the
        next cycle call, so the last row's geometry is not used (a milling plunge is no hole)."""
        self.in_cut = False
        self.hole = -1
        self._prev_z: float | None = None
        self._deepest = math.inf
        self._last_out: int | None = None
        self._xy: tuple[float, ...] = ()
        self._feeds: list[float] = []
        self._speeds: list[float] = []
        self._feed = math.nan
        self._speed = math.nan

    def hole_done(self, row: dict[str, object]) -> None:
        """A hole row was completed (``hole``, ``surface_z_mm``, ``depth_mm``): keep its
        geometry as the fallback and number later cuts after it."""
        try:
            s, d = float(row["surface_z_mm"]), float(row["depth_mm"])  # type: ignore[arg-type]
            if math.isfinite(s) and math.isfinite(d) and d > 0:
                self.row_geometry = (s, d)
        except (KeyError, TypeError, ValueError):
            pass
        h = row.get("hole")
        # align the numbering with the hole table, unless a later cut has already begun
        if isinstance(h, int | float) and math.isfinite(h) and self.hole <= int(h):
            self.next_hole = int(h) + 1

    def restore_modal(self, events: pd.DataFrame | HoleEvents) -> None:
        """Set the modal drilling cycle from past NC events (a restart without state)."""
        evs = self._events(events)
        if evs:
            self.nc_geometry = evs[-1][1]
            self.nc_cancelled = evs[-1][1] is None

    def gap(self) -> None:
        """Missing cycles: the Z step across them is unknown; the cut (if any) ends."""
        self._prev_z = None
        if self.in_cut:
            self.in_cut = False

    def _events(self, events: pd.DataFrame | HoleEvents
                ) -> list[tuple[int, tuple[float, float] | None]]:
        ev = events if isinstance(events, HoleEvents) else HoleEvents.from_frame(events)
        out: list[tuple[int, tuple[float, float] | None]] = []
        for c, kind, g in zip(ev.cycle.tolist(), ev.kind.tolist(), ev.gcode.tolist(),
                              strict=True):
            if kind != "block":
                continue
            text = g if isinstance(g, str) else ""
            geo = drilling_cycle_geometry(text)
            if geo is not None:
                out.append((int(c), geo))
            elif modal_cycle_call(text) is False:
                out.append((int(c), None))
        return out

    def update(self, cycles: NDArray[np.int64], z_des_mm: NDArray[np.float64],
               z_enc_mm: NDArray[np.float64], speed_rpm: NDArray[np.float64], *,
               xy_des_mm: tuple[NDArray[np.float64], ...] = (),
               events: pd.DataFrame | HoleEvents | None = None) -> CutContext:
        """Hole context of the next consecutive cycles.

        Parameters
        ----------
        cycles : numpy.ndarray
            Consecutive cycle numbers.
        z_des_mm, z_enc_mm : numpy.ndarray
            Z setpoint and encoder position [mm].
        speed_rpm : numpy.ndarray
            Spindle speed command [rpm].
        xy_des_mm : tuple of numpy.ndarray
            X/Y setpoints [mm] (a move between cuts starts a new hole).
        events : pandas.DataFrame or HoleEvents, optional
            NC events of these cycles (the drilling-cycle calls give surface and depth).

        Returns
        -------
        CutContext
        """
        n = int(cycles.size)
        out = CutContext(np.full(n, -1.0), np.full(n, np.nan), np.full(n, np.nan),
                         np.full(n, np.nan), np.full(n, np.nan))
        if not n:
            return out
        evs = self._events(events) if events is not None else []
        # the geometry changes only at NC events: between them the chunk is one segment; an
        # event applies from the first cycle at or after it
        cyc = np.asarray(cycles, dtype=np.int64)
        j0 = 0
        for c, geo in evs:
            if c > int(cyc[-1]):
                break
            j = int(np.searchsorted(cyc, c, side="left"))
            if j > j0:
                self._segment(cyc, z_des_mm, z_enc_mm, speed_rpm, xy_des_mm, j0, j, out)
                j0 = j
            self.nc_geometry = geo
            self.nc_cancelled = geo is None
        self._segment(cyc, z_des_mm, z_enc_mm, speed_rpm, xy_des_mm, j0, n, out)
        return out

    def _segment(self, cyc: NDArray[np.int64], zd: NDArray[np.float64],
                 ze: NDArray[np.float64], sp: NDArray[np.float64],
                 xy: tuple[NDArray[np.float64], ...], j0: int, j1: int,
                 out: CutContext) -> None:
        """Cycles ``j0:j1`` (one NC geometry throughout) into ``out``: the in-cut test in
        array code, a loop only over the first cycles of each cut (hole number, latch of
        feed and speed), the rest of each run of cut cycles in array code."""
        step = self.min_speed_mm_s * self.cycle_time_s
        prev = self._prev_z
        zs = zd[j0:j1]
        zprev = np.empty(j1 - j0)
        zprev[0] = np.nan if prev is None else prev
        zprev[1:] = zs[:-1]
        geo = self.nc_geometry or (None if self.nc_cancelled else self.row_geometry)
        self._prev_z = float(zs[-1])
        if geo is None:
            inside = np.zeros(j1 - j0, dtype=bool)
        else:
            with np.errstate(invalid="ignore"):
                inside = (((zs - zprev) < -step) & (ze[j0:j1] <= geo[0])
                          & (np.abs(sp[j0:j1]) >= self.min_speed_rpm))
        edges = np.flatnonzero(np.diff(np.concatenate(([0], inside.view(np.int8), [0]))))
        pos = j0
        for s, e in zip((edges[0::2] + j0).tolist(), (edges[1::2] + j0).tolist(),
                        strict=True):
            if s > pos and self.in_cut:  # outside cycles before this run: the cut ended
                self.in_cut = False
                self._last_out = int(cyc[pos])
            assert geo is not None
            j = s
            if not self.in_cut:
                self.in_cut = True
                c = int(cyc[j])
                here = tuple(float(a[j]) for a in xy)
                same = (self._last_out is not None and self.hole >= 0
                        and (c - self._last_out) * self.cycle_time_s <= self.settle_s
                        and len(here) == len(self._xy)
                        and all(abs(a - b) < 0.01 for a, b in zip(here, self._xy, strict=True)))
                if not same:  # a new hole (else a peck re-entering the same hole)
                    self.hole = self.next_hole
                    self.next_hole += 1
                    self._deepest = math.inf
                    self._xy = here
                    self._feeds, self._speeds = [], []
            latched: list[tuple[int, float, float]] = []  # (cycle, feed, speed) so far
            while j < e and len(self._feeds) < self.latch_cycles:
                z_e = float(ze[j])
                if z_e < self._deepest:  # else a re-entry through material already cut
                    self._deepest = z_e
                    z_prev = float(zprev[j - j0])
                    self._feeds.append((z_prev - float(zd[j])) / self.cycle_time_s * 60.0)
                    self._speeds.append(abs(float(sp[j])))
                    self._feed = statistics.median(self._feeds)
                    self._speed = statistics.median(self._speeds)
                    latched.append((j, self._feed, self._speed))
                j += 1
            if latched:  # the latch cycles' context at once (each with its own medians)
                k = np.array([x[0] for x in latched], dtype=np.int64)
                d = geo[0] - ze[k]
                out.hole[k] = self.hole
                out.depth_mm[k] = d
                out.progress[k] = d / geo[1]
                out.feed_mm_min[k] = [x[1] for x in latched]
                out.speed_rpm[k] = [x[2] for x in latched]
            if j < e:  # feed and speed latched: the rest of the run at once
                z_run = ze[j:e]
                before = np.minimum.accumulate(np.concatenate([[self._deepest], z_run[:-1]]))
                self._deepest = float(min(self._deepest, float(z_run.min())))
                self._put(out, j, e, geo, z_run < before, ze)
            pos = e
        if pos < j1 and self.in_cut:
            self.in_cut = False
            self._last_out = int(cyc[pos])

    def _put(self, out: CutContext, j: int, e: int, geo: tuple[float, float],
             new: NDArray[np.bool_], ze: NDArray[np.float64]) -> None:
        """Context of the new-material cycles among ``j:e`` (the others stay outside)."""
        k = np.flatnonzero(new) + j
        d = geo[0] - ze[k]
        out.hole[k] = self.hole
        out.depth_mm[k] = d
        out.progress[k] = d / geo[1]
        out.feed_mm_min[k] = self._feed
        out.speed_rpm[k] = self._speed
