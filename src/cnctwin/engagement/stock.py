"""The workpiece stock as a Z-map and the engagement of a cylindrical tool swept through it.

A Z-map stores, on a square grid in XY, the height of the top of the material in each cell
(Choi & Jerard, *Sculptured Surface Machining*, 1998, ch. 7; the Z-map is exact for 2.5-axis
work with flat-bottomed and drilling tools, which is what the supported G-code does). A tool
at ``(x, y, z)`` with radius R removes every cell whose centre lies within R of ``(x, y)``
down to ``z``.

The engagement per control cycle follows the feed-frame convention of
:func:`cnctwin.sim.cutting.milling_load`: the tooth angle phi is measured clockwise (seen
from the spindle, M3) from the left of the feed direction, so the front half of the tool is
0 <= phi <= pi. A bin of the front half is engaged when material stands at the tool's
periphery at that angle (above the tool's bottom); the entry and exit angles are the first
and last engaged bins, the axial depth the mean height of the material above the tool bottom
over the engaged bins. An arc that reaches within sqrt(2 cell / R) of a tangent is taken to
reach it (the wall is resolved to about a cell). A full slot gives 0..pi; a side step of
radial width ae on the left gives 0..arccos(1 - ae/R) (up milling), on the right
pi - arccos(1 - ae/R)..pi (down milling); a second pass over cut material gives no
engagement. Exit angles of a side step are resolved to a bin (1 deg) plus the cell's share
of ae.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from cnctwin.analysis.segments import runs_of
from cnctwin.exceptions import ConfigError

__all__ = ["Engagement", "Stock", "ZMap", "parse_stock", "runs_of"]

MIN_DEPTH_MM = 0.01
"""Material less than this above the tool bottom is not engaged [mm]: the tool's Z jitters by
micrometres (encoder noise, servo) over a floor it has cut itself."""

MAX_CELLS = 16_000_000
"""Largest grid a Z-map allocates (64 MB of float32); a finer cell is coarsened to fit."""


@dataclass(frozen=True)
class Stock:
    """A rectangular raw part (block stock), machine coordinates [mm].

    Attributes
    ----------
    x0_mm, y0_mm, z0_mm : float
        Lower corner [mm].
    x1_mm, y1_mm, z1_mm : float
        Upper corner [mm]; ``z1_mm`` is the top surface.
    """

    x0_mm: float
    y0_mm: float
    z0_mm: float
    x1_mm: float
    y1_mm: float
    z1_mm: float

    def __post_init__(self) -> None:
        vals = (self.x0_mm, self.y0_mm, self.z0_mm, self.x1_mm, self.y1_mm, self.z1_mm)
        if not all(math.isfinite(v) for v in vals):
            raise ConfigError(f"stock {vals}: every corner coordinate must be a finite number")
        for lo, hi, ax in ((self.x0_mm, self.x1_mm, "X"), (self.y0_mm, self.y1_mm, "Y"),
                           (self.z0_mm, self.z1_mm, "Z")):
            if not hi > lo:
                raise ConfigError(f"stock: {ax}1 = {hi} must be greater than {ax}0 = {lo} "
                                  "(give X0,Y0,Z0,X1,Y1,Z1, lower corner first)")

    def as_text(self) -> str:
        """The ``X0,Y0,Z0,X1,Y1,Z1`` form :func:`parse_stock` reads."""
        return ",".join(f"{v:g}" for v in (self.x0_mm, self.y0_mm, self.z0_mm, self.x1_mm,
                                           self.y1_mm, self.z1_mm))


def parse_stock(text: str) -> Stock:
    """Read a stock box from ``X0,Y0,Z0,X1,Y1,Z1`` [mm] (the ``--stock`` option).

    Parameters
    ----------
    text : str
        Six comma-separated numbers, lower corner then upper corner.

    Returns
    -------
    Stock

    Raises
    ------
    ConfigError
        Not six numbers, or a corner not below the other.
    """
    parts = [p.strip() for p in str(text).split(",")]
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        vals = []
    if len(vals) != 6:
        raise ConfigError(f"--stock {text!r}: give six numbers X0,Y0,Z0,X1,Y1,Z1 in mm "
                          "(lower corner, upper corner), e.g. --stock 0,0,-30,200,150,0")
    return Stock(*vals)


@dataclass(frozen=True)
class Engagement:
    """Engagement of the tool per control cycle (what :meth:`ZMap.sweep` returns).

    Attributes
    ----------
    entry_rad, exit_rad : numpy.ndarray
        Immersion in the feed frame (0..pi full slot) [rad]; NaN where nothing is engaged.
    axial_depth_mm : numpy.ndarray
        Mean height of the material above the tool bottom over the engaged angles [mm]; 0 in
        air.
    center_depth_mm : numpy.ndarray
        Height of the material above the tool bottom under the tool centre, before the cycle
        removed it [mm] (a plunge or a drill cuts there); 0 in air.
    removed_mm3 : numpy.ndarray
        Volume removed in the cycle [mm^3] (removal runs each half cell of travel, so the
        volume comes in steps; sum it over a block for the removal rate).
    feed_direction_rad : numpy.ndarray
        Direction of the XY motion, atan2(vy, vx) [rad] (held while the tool moves only in Z).
    """

    entry_rad: NDArray[np.float64]
    exit_rad: NDArray[np.float64]
    axial_depth_mm: NDArray[np.float64]
    center_depth_mm: NDArray[np.float64]
    removed_mm3: NDArray[np.float64]
    feed_direction_rad: NDArray[np.float64]

    def __len__(self) -> int:
        return int(self.axial_depth_mm.size)

    @property
    def engaged(self) -> NDArray[np.bool_]:
        """True where the periphery cuts (an immersion was found)."""
        return np.isfinite(self.entry_rad)

    @property
    def radial_fraction(self) -> NDArray[np.float64]:
        """Radial immersion ae / D from the angles: (cos(entry) - cos(exit)) / 2 [-]."""
        e = np.nan_to_num(self.entry_rad)
        x = np.nan_to_num(self.exit_rad)
        return np.where(self.engaged, 0.5 * (np.cos(e) - np.cos(x)), 0.0)


@numba.njit(cache=True, nogil=True)
def _sweep_kernel(h: NDArray[np.float32], x0: float, y0: float, cell: float,
                  px: NDArray[np.float64], py: NDArray[np.float64], pz: NDArray[np.float64],
                  radius: float, nbins: int, min_depth: float, state: NDArray[np.float64],
                  out: NDArray[np.float64]) -> None:  # pragma: no cover - compiled
    """Sweep the tool: out[:, 0..5] = entry, exit, depth, centre depth, volume, direction.

    state = [last removal x, y, z, feed direction, previous x, previous y, has previous,
    highest material z].
    """
    nx, ny = h.shape
    n = px.size
    step = 0.5 * cell
    r2 = radius * radius
    ztop = state[7]
    for i in range(n):
        x = px[i]
        y = py[i]
        z = pz[i]
        if state[6] > 0.5:
            dx = x - state[4]
            dy = y - state[5]
            if dx * dx + dy * dy > 1e-14:
                state[3] = math.atan2(dy, dx)
        state[4] = x
        state[5] = y
        state[6] = 1.0
        th = state[3]
        out[i, 0] = np.nan
        out[i, 1] = np.nan
        out[i, 2] = 0.0
        out[i, 3] = 0.0
        out[i, 4] = 0.0
        out[i, 5] = th
        if z >= ztop:
            continue
        # centre
        ic = math.floor((x - x0) / cell)
        jc = math.floor((y - y0) / cell)
        if 0 <= ic < nx and 0 <= jc < ny:
            d = h[ic, jc] - z
            if d > min_depth:
                out[i, 3] = d
        # periphery bins over the front half
        ct = math.cos(th)
        st = math.sin(th)
        first = -1
        last = -1
        dsum = 0.0
        cnt = 0
        for k in range(nbins):
            phi = (k + 0.5) * math.pi / nbins
            sp = math.sin(phi)
            cp = math.cos(phi)
            ux = sp * ct - cp * st
            uy = sp * st + cp * ct
            ii = math.floor((x + radius * ux - x0) / cell)
            jj = math.floor((y + radius * uy - y0) / cell)
            if ii < 0 or ii >= nx or jj < 0 or jj >= ny:
                continue
            d = h[ii, jj] - z
            if d > min_depth:
                if first < 0:
                    first = k
                last = k
                dsum += d
                cnt += 1
        if cnt > 0:
            out[i, 0] = first * math.pi / nbins
            out[i, 1] = (last + 1) * math.pi / nbins
            out[i, 2] = dsum / cnt
        # removal each half cell of travel (or of descent). Along a continuing path only the
        # half of the disc ahead (and two cells behind) can still hold material: the rest
        # lay within R of the earlier removals; after a descent, a jump or at the start the
        # whole disc
        mx = x - state[0]
        my = y - state[1]
        d2 = mx * mx + my * my
        descended = z <= state[2] - step
        if d2 >= step * step or descended or (cnt == 0 and out[i, 3] > 0.0):
            full = descended or d2 > r2 or not math.isfinite(d2)
            i0 = max(math.floor((x - radius - x0) / cell), 0)
            i1 = min(math.floor((x + radius - x0) / cell) + 1, nx)
            j0 = max(math.floor((y - radius - y0) / cell), 0)
            j1 = min(math.floor((y + radius - y0) / cell) + 1, ny)
            back = -2.0 * cell
            vol = 0.0
            for a in range(i0, i1):
                cx = x0 + (a + 0.5) * cell - x
                if not full and cx * ct < back - radius * abs(st):
                    continue  # the whole column lies behind
                for b in range(j0, j1):
                    cy = y0 + (b + 0.5) * cell - y
                    if not full and cx * ct + cy * st < back:
                        continue
                    if cx * cx + cy * cy <= r2 and h[a, b] > z:
                        vol += h[a, b] - z
                        h[a, b] = z
            out[i, 4] = vol * cell * cell
            state[0] = x
            state[1] = y
            state[2] = z


class ZMap:
    """Heights of the material top on a square XY grid (mutable: sweeping removes material).

    Parameters
    ----------
    stock : Stock
        The raw part.
    cell_mm : float, default 0.1
        Grid cell [mm] (coarsened, with a note in :attr:`cell_mm`, when the part would need
        more than :data:`MAX_CELLS` cells).

    Attributes
    ----------
    heights_mm : numpy.ndarray of float32, shape (nx, ny)
        Material top per cell [mm]; ``stock.z0_mm`` where everything is cut away.
    cell_mm : float
        The cell actually used [mm].
    """

    def __init__(self, stock: Stock, *, cell_mm: float = 0.1) -> None:
        if not (math.isfinite(cell_mm) and cell_mm > 0.0):
            raise ConfigError(f"cell_mm must be a positive number, got {cell_mm!r}")
        lx = stock.x1_mm - stock.x0_mm
        ly = stock.y1_mm - stock.y0_mm
        cell = max(cell_mm, math.sqrt(lx * ly / MAX_CELLS))
        self.stock = stock
        self.cell_mm = float(cell)
        nx = max(math.ceil(lx / cell), 1)
        ny = max(math.ceil(ly / cell), 1)
        self.heights_mm = np.full((nx, ny), stock.z1_mm, dtype=np.float32)
        self._state = np.array([np.inf, np.inf, np.inf, 0.0, 0.0, 0.0, 0.0, stock.z1_mm])

    def sweep(self, x_mm: ArrayLike, y_mm: ArrayLike, z_mm: ArrayLike, *,
              diameter_mm: float, bins: int = 180) -> Engagement:
        """Move a flat-bottomed cylindrical tool along a path, removing material.

        Parameters
        ----------
        x_mm, y_mm, z_mm : array-like
            Tool tip (centre of the flat bottom) per control cycle [mm]. Consecutive calls
            continue the path (the feed direction and the last removal carry over).
        diameter_mm : float
            Tool diameter [mm] (a drill removes its diameter down to its tip).
        bins : int, default 180
            Angular bins over the front half (1 deg each by default).

        Returns
        -------
        Engagement
        """
        x = np.ascontiguousarray(x_mm, dtype=np.float64)
        y = np.ascontiguousarray(y_mm, dtype=np.float64)
        z = np.ascontiguousarray(z_mm, dtype=np.float64)
        if not (x.shape == y.shape == z.shape and x.ndim == 1):
            raise ConfigError(f"sweep: x, y, z must be 1-D and of one length, got {x.shape}, "
                              f"{y.shape}, {z.shape}")
        if not (math.isfinite(diameter_mm) and diameter_mm > 0.0):
            raise ConfigError(f"sweep: diameter_mm must be positive, got {diameter_mm!r}")
        out = np.empty((x.size, 6), dtype=np.float64)
        s = self.stock
        _sweep_kernel(self.heights_mm, s.x0_mm, s.y0_mm, self.cell_mm, x, y, z,
                      0.5 * diameter_mm, int(bins), MIN_DEPTH_MM, self._state, out)
        # the wall of a cut is resolved to about a cell: a periphery point within
        # sqrt(2 cell / R) of the tangent falls into the last removal's cells, so an arc that
        # reaches that close to 0 (or pi) reaches it (a slot reads 0..pi, not 0.15..2.99)
        tol = math.sqrt(2.0 * self.cell_mm / (0.5 * diameter_mm)) + math.pi / bins
        entry = np.where(out[:, 0] <= tol, 0.0, out[:, 0])
        exit_ = np.where(out[:, 1] >= math.pi - tol, math.pi, out[:, 1])
        return Engagement(entry_rad=entry, exit_rad=exit_,
                          axial_depth_mm=out[:, 2].copy(), center_depth_mm=out[:, 3].copy(),
                          removed_mm3=out[:, 4].copy(), feed_direction_rad=out[:, 5].copy())

    def volume_mm3(self) -> float:
        """Material left above the stock bottom [mm^3]."""
        return float(np.sum(self.heights_mm.astype(np.float64) - self.stock.z0_mm)
                     * self.cell_mm**2)

    def height_at(self, x_mm: float, y_mm: float) -> float:
        """Material top at a point [mm] (the stock top outside the grid is not material: NaN)."""
        i = math.floor((x_mm - self.stock.x0_mm) / self.cell_mm)
        j = math.floor((y_mm - self.stock.y0_mm) / self.cell_mm)
        nx, ny = self.heights_mm.shape
        if 0 <= i < nx and 0 <= j < ny:
            return float(self.heights_mm[i, j])
        return math.nan
