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
from dataclasses import dataclass

import numpy as np
import pandas as pd
from numpy.typing import NDArray

__all__ = ["CutContext", "CutTracker", "drilling_cycle_geometry"]

_CYCLE = re.compile(r"\b(CYCLE8[1-9])\s*\(([^)]*)\)", re.IGNORECASE)
_CANCEL = re.compile(r"^\s*MCALL\s*$|\bG80\b", re.IGNORECASE)


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

    def gap(self) -> None:
        """Missing cycles: the Z step across them is unknown; the cut (if any) ends."""
        self._prev_z = None
        if self.in_cut:
            self.in_cut = False

    def _events(self, events: pd.DataFrame) -> list[tuple[int, tuple[float, float] | None]]:
        if events.empty or "gcode" not in events.columns:
            return []
        # plain lists: a chunk holds a few events, pandas' string and sort calls cost ~3 ms
        cyc = events["cycle"].to_numpy(dtype=np.int64)
        order = np.argsort(cyc, kind="stable").tolist()
        kinds = events["kind"].astype(object).tolist()
        texts = events["gcode"].astype(object).tolist()
        out: list[tuple[int, tuple[float, float] | None]] = []
        for k in order:
            if kinds[k] != "block":
                continue
            c, g = int(cyc[k]), texts[k]
            text = str(g) if isinstance(g, str) else ""
            geo = drilling_cycle_geometry(text)
            if geo is not None:
                out.append((int(c), geo))
            elif _CANCEL.search(text):
                out.append((int(c), None))
        return out

    def update(self, cycles: NDArray[np.int64], z_des_mm: NDArray[np.float64],
               z_enc_mm: NDArray[np.float64], speed_rpm: NDArray[np.float64], *,
               xy_des_mm: tuple[NDArray[np.float64], ...] = (),
               events: pd.DataFrame | None = None) -> CutContext:
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
        events : pandas.DataFrame, optional
            NC events of these cycles (the drilling-cycle calls give surface and depth).

        Returns
        -------
        CutContext
        """
        n = int(cycles.size)
        hole = np.full(n, -1.0)
        prog = np.full(n, np.nan)
        dep = np.full(n, np.nan)
        feed = np.full(n, np.nan)
        spd = np.full(n, np.nan)
        evs = self._events(events) if events is not None else []
        if not evs and n:
            fast = self._update_array(cycles, z_des_mm, z_enc_mm, speed_rpm)
            if fast is not None:
                return fast
        k = 0
        step = self.min_speed_mm_s * self.cycle_time_s
        cyc = cycles.tolist()
        zd, ze, sp = z_des_mm.tolist(), z_enc_mm.tolist(), speed_rpm.tolist()
        xy = [a.tolist() for a in xy_des_mm]
        for j in range(n):
            c = cyc[j]
            while k < len(evs) and evs[k][0] <= c:
                self.nc_geometry = evs[k][1]
                k += 1
            z = zd[j]
            prev = self._prev_z
            self._prev_z = z
            down = prev is not None and z - prev < -step
            geo = self.nc_geometry or self.row_geometry
            inside = (down and geo is not None and ze[j] <= geo[0]
                      and abs(sp[j]) >= self.min_speed_rpm)
            if not inside:
                if self.in_cut:
                    self.in_cut = False
                    self._last_out = c
                continue
            assert geo is not None
            here = tuple(a[j] for a in xy)
            if not self.in_cut:
                self.in_cut = True
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
            if ze[j] >= self._deepest or prev is None:  # re-entry through material already cut
                continue
            self._deepest = ze[j]
            if len(self._feeds) < self.latch_cycles:
                self._feeds.append((prev - z) / self.cycle_time_s * 60.0)
                self._speeds.append(abs(sp[j]))
                self._feed = float(np.median(self._feeds))
                self._speed = float(np.median(self._speeds))
            d = geo[0] - ze[j]
            hole[j] = self.hole
            dep[j] = d
            prog[j] = d / geo[1]
            feed[j] = self._feed
            spd[j] = self._speed
        return CutContext(hole, prog, dep, feed, spd)

    def _update_array(self, cycles: NDArray[np.int64], z_des_mm: NDArray[np.float64],
                      z_enc_mm: NDArray[np.float64], speed_rpm: NDArray[np.float64]
                      ) -> CutContext | None:
        """:meth:`update` in array code for the two common chunks without NC events: the
        tool outside the material throughout, or inside one hole throughout (feed and speed
        already latched). None for any other chunk (the loop handles it)."""
        n = int(cycles.size)
        prev = self._prev_z
        step = self.min_speed_mm_s * self.cycle_time_s
        zprev = np.empty(n)
        zprev[0] = np.nan if prev is None else prev
        zprev[1:] = z_des_mm[:-1]
        with np.errstate(invalid="ignore"):
            down = (z_des_mm - zprev) < -step
        geo = self.nc_geometry or self.row_geometry
        if geo is None:
            inside = np.zeros(n, dtype=bool)
        else:
            with np.errstate(invalid="ignore"):
                inside = down & (z_enc_mm <= geo[0]) & (np.abs(speed_rpm) >= self.min_speed_rpm)
        nan = np.full(n, np.nan)
        if not inside.any():
            if self.in_cut:
                self.in_cut = False
                self._last_out = int(cycles[0])
            self._prev_z = float(z_des_mm[-1])
            return CutContext(np.full(n, -1.0), nan, nan.copy(), nan.copy(), nan.copy())
        if not (inside.all() and self.in_cut and len(self._feeds) >= self.latch_cycles):
            return None
        assert geo is not None
        before = np.minimum.accumulate(np.concatenate([[self._deepest], z_enc_mm[:-1]]))
        new = z_enc_mm < before
        self._prev_z = float(z_des_mm[-1])
        self._deepest = float(min(self._deepest, float(z_enc_mm.min())))
        d = geo[0] - z_enc_mm
        hole = np.where(new, float(self.hole), -1.0)
        dep = np.where(new, d, np.nan)
        return CutContext(hole, np.where(new, d / geo[1], np.nan), dep,
                          np.where(new, self._feed, np.nan), np.where(new, self._speed, np.nan))
