"""Contour geometry: distance of the actual path from the programmed path; circle test.

* :func:`contour_error`: signed normal distance of the ENC_POS path from the programmed path
  (the DES_POS polyline or a given polyline), corner rounding and overshoot.
* :func:`circle_test`: radius deviation and circularity in the manner of ISO 230-4
  (least-squares circle, circular deviation G about the LSC centre and the minimum zone),
  with the radial component of the NC's CONT_DEV for comparison.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike
from scipy import optimize
from scipy.spatial import cKDTree

from cnctwin.exceptions import IdentificationError
from cnctwin.recording import Recording
from cnctwin.servo._common import FloatArray

__all__ = [
    "CircleResult",
    "ContourErrorResult",
    "Corner",
    "circle_test",
    "contour_error",
    "fit_circle_lsq",
    "signed_distance_to_polyline",
]


@dataclass(frozen=True)
class Corner:
    """One corner of the programmed path.

    Attributes
    ----------
    x_mm, y_mm : float
        Corner point of the programmed path [mm].
    angle_deg : float
        Direction change at the corner [deg] (positive = left turn).
    rounding_mm : float
        Distance from the corner point to the nearest actual-path point (how much the actual
        path cuts the corner) [mm].
    overshoot_mm : float
        Largest distance of the actual path on the outer side of the programmed path near the
        corner (within ``window_mm``) [mm]; 0 if it stays inside.
    """

    x_mm: float
    y_mm: float
    angle_deg: float
    rounding_mm: float
    overshoot_mm: float


@dataclass(frozen=True)
class ContourErrorResult:
    """Contour error of a two-axis path.

    Attributes
    ----------
    axes : tuple of str
        The two axes.
    distance_mm : numpy.ndarray
        Signed normal distance of each actual (ENC_POS) point from the programmed path, positive
        to the left of the direction of travel [mm]; NaN where a position is missing.
    rms_mm, max_abs_mm : float
        RMS and largest absolute distance [mm].
    corners : list of Corner
        Corners of the programmed path (direction change > ``corner_deg``).
    """

    axes: tuple[str, str]
    distance_mm: FloatArray
    rms_mm: float
    max_abs_mm: float
    corners: list[Corner] = field(default_factory=list)


def _dedupe(path: FloatArray, tol: float = 1e-9) -> FloatArray:
    keep = np.concatenate([[True], np.linalg.norm(np.diff(path, axis=0), axis=1) > tol])
    return path[keep]


def signed_distance_to_polyline(points: FloatArray, path: FloatArray, *, k: int = 8) -> FloatArray:
    """Signed distance of points to a polyline, positive on the left of its direction.

    Parameters
    ----------
    points : numpy.ndarray, shape (n, 2)
        Points [mm]; rows with NaN give NaN.
    path : numpy.ndarray, shape (m, 2)
        Polyline vertices in travel order [mm]; dense polylines (DES_POS at 2 ms) are typical.
    k : int, default 8
        Nearest vertices whose adjacent segments are examined.

    Returns
    -------
    numpy.ndarray
        Signed distances [mm].
    """
    path = _dedupe(np.asarray(path, dtype=np.float64))
    pts = np.asarray(points, dtype=np.float64)
    out = np.full(len(pts), np.nan)
    if len(path) < 2:
        raise IdentificationError("the programmed path needs at least two distinct points")
    ok = np.isfinite(pts).all(axis=1)
    tree = cKDTree(path)
    kk = min(k, len(path))
    _, idx = tree.query(pts[ok], k=kk)
    idx = np.atleast_2d(idx).reshape(-1, kk)
    seg_a = path[:-1]
    seg_d = np.diff(path, axis=0)
    seg_len2 = np.einsum("ij,ij->i", seg_d, seg_d)
    best = np.full(idx.shape[0], np.inf)
    best_signed = np.full(idx.shape[0], np.nan)
    p = pts[ok]
    for cand in (idx - 1, idx):  # the segments before and after each nearby vertex
        cand = np.clip(cand, 0, len(seg_a) - 1)
        for j in range(cand.shape[1]):
            s = cand[:, j]
            a = seg_a[s]
            dvec = seg_d[s]
            t = np.clip(np.einsum("ij,ij->i", p - a, dvec) / seg_len2[s], 0.0, 1.0)
            proj = a + t[:, None] * dvec
            dist = np.linalg.norm(p - proj, axis=1)
            cross = dvec[:, 0] * (p[:, 1] - a[:, 1]) - dvec[:, 1] * (p[:, 0] - a[:, 0])
            better = dist < best - 1e-15
            best = np.where(better, dist, best)
            best_signed = np.where(better, np.where(cross >= 0, dist, -dist), best_signed)
    out[ok] = best_signed
    return out


def _corners(path: FloatArray, corner_deg: float, min_leg_mm: float) -> list[tuple[int, float]]:
    """Vertices where the direction changes by more than ``corner_deg`` (index, signed angle)."""
    p = _dedupe(path)
    if len(p) < 3:
        return []
    # directions over legs of at least min_leg_mm to ignore interpolation jitter
    res: list[tuple[int, float]] = []
    d = np.diff(p, axis=0)
    ang = np.arctan2(d[:, 1], d[:, 0])
    turn = np.angle(np.exp(1j * (ang[1:] - ang[:-1])))
    big = np.flatnonzero(np.abs(np.degrees(turn)) > corner_deg)
    for i in big.tolist():
        res.append((i + 1, float(np.degrees(turn[i]))))
    # merge corners closer than min_leg_mm (a blended corner spread over a few vertices)
    merged: list[tuple[int, float]] = []
    for i_raw, a in res:
        i = int(i_raw)
        if merged and np.linalg.norm(p[i] - p[merged[-1][0]]) < min_leg_mm:
            j, b = merged[-1]
            merged[-1] = (j, b + a)
        else:
            merged.append((i, a))
    return [(i, a) for i, a in merged if abs(a) > corner_deg]


def contour_error(
    rec: Recording,
    axes: tuple[str, str] = ("X1", "Y1"),
    *,
    path: ArrayLike | None = None,
    corner_deg: float = 30.0,
    window_mm: float = 2.0,
) -> ContourErrorResult:
    """Distance of the actual path (ENC_POS) from the programmed path.

    Parameters
    ----------
    rec : Recording
        Recording with ENC_POS (and DES_POS unless ``path`` is given) of both axes.
    axes : (str, str), default ('X1', 'Y1')
        The two axes spanning the plane.
    path : array-like, shape (m, 2), optional
        Programmed path as a polyline (corner points of a program) [mm]; default the DES_POS
        polyline (after the fine interpolator, one vertex per cycle).
    corner_deg : float, default 30
        Direction change that counts as a corner [deg].
    window_mm : float, default 2
        Half-length of the neighbourhood of a corner searched for overshoot [mm].

    Returns
    -------
    ContourErrorResult

    Notes
    -----
    The distance is the normal distance to the nearest segment, positive on the left of the
    direction of travel. Corner rounding is the distance from the corner point to the nearest
    actual point; overshoot is the largest distance on the outer side within ``window_mm``
    of the corner (contour-error definitions: Siemens A3 p. 73,
    docs/reference/physics-and-performance.md
    §1.2).
    """
    ax, ay = axes
    for code in ("ENC_POS",) + (("DES_POS",) if path is None else ()):
        for a in axes:
            if not rec.has(code, a):
                raise IdentificationError(
                    f"contour_error needs {code}|{a}; the recording has {', '.join(rec.columns)}")
    act = np.column_stack([rec.signal("ENC_POS", ax).to_numpy(float),
                           rec.signal("ENC_POS", ay).to_numpy(float)])
    if path is None:
        prog = np.column_stack([rec.signal("DES_POS", ax).to_numpy(float),
                                rec.signal("DES_POS", ay).to_numpy(float)])
        prog = prog[np.isfinite(prog).all(axis=1)]
    else:
        prog = np.asarray(path, dtype=np.float64)
        # densify a sparse program polyline so the vertex search finds the right segment
        dense = [prog[:1]]
        for a, b in itertools.pairwise(prog):
            n = max(math.ceil(np.linalg.norm(b - a) / 0.05), 1)
            dense.append(a + (b - a) * (np.arange(1, n + 1) / n)[:, None])
        prog = np.vstack(dense)
    dist = signed_distance_to_polyline(act, prog)
    good = dist[np.isfinite(dist)]
    corners: list[Corner] = []
    pd_ = _dedupe(prog)
    for i, ang in _corners(pd_, corner_deg, min_leg_mm=0.5 * window_mm):
        c = pd_[i]
        dc = np.linalg.norm(act - c, axis=1)
        near = np.isfinite(dc) & (dc <= window_mm)
        rounding = float(np.nanmin(dc)) if np.isfinite(dc).any() else float("nan")
        # outer side: right of travel for a left turn (negative distance) and vice versa
        outer = -np.sign(ang) * dist[near]
        over = float(max(np.nanmax(outer), 0.0)) if outer.size else 0.0
        corners.append(Corner(float(c[0]), float(c[1]), ang, rounding, over))
    return ContourErrorResult(
        (ax, ay), dist, float(np.sqrt(np.mean(good**2))) if good.size else float("nan"),
        float(np.max(np.abs(good))) if good.size else float("nan"), corners)


# ---------------------------------------------------------------------------- circle test
def fit_circle_lsq(x: FloatArray, y: FloatArray) -> tuple[float, float, float]:
    """Least-squares circle (geometric, Gauss-Newton from the algebraic Kasa fit).

    Parameters
    ----------
    x : numpy.ndarray
        X coordinates [mm].
    y : numpy.ndarray
        Y coordinates [mm].

    Returns
    -------
    (xc, yc, r) : float
        Centre and radius [mm].
    """
    a = np.column_stack([x, y, np.ones_like(x)])
    b = x * x + y * y
    sol, *_ = np.linalg.lstsq(a, b, rcond=None)
    xc, yc = sol[0] / 2, sol[1] / 2
    r0 = math.sqrt(max(sol[2] + xc * xc + yc * yc, 0.0))

    def resid(p: FloatArray) -> FloatArray:
        return np.hypot(x - p[0], y - p[1]) - p[2]

    res = optimize.least_squares(resid, np.array([xc, yc, r0]), method="lm", xtol=1e-14,
                                 ftol=1e-14)
    return float(res.x[0]), float(res.x[1]), float(res.x[2])


@dataclass(frozen=True)
class CircleResult:
    """Circular test (ISO 230-4 manner) of a two-axis circle.

    Attributes
    ----------
    axes : tuple of str
    center_mm : (float, float)
        Least-squares-circle centre of the actual path [mm].
    radius_mm : float
        LSC radius of the actual path [mm].
    nominal_radius_mm : float
        Programmed radius (given, or the LSC radius of DES_POS) [mm].
    radius_deviation_mm : float
        ``radius_mm - nominal_radius_mm`` (ISO 230-4 radius deviation F, LSC) [mm].
    circular_deviation_lsc_mm : float
        Max - min radial distance about the LSC centre (G, LSC reference) [mm].
    circular_deviation_mz_mm : float
        Minimum-zone circular deviation (centre optimised) [mm].
    angle_rad : numpy.ndarray
        Angle of each used sample about the LSC centre [rad].
    radial_deviation_mm : numpy.ndarray
        Actual radius minus LSC radius per used sample (the radial deviation plot) [mm].
    cont_dev_radial_mm : numpy.ndarray or None
        Radial component of CONT_DEV (x, y) per used sample [mm]; None without CONT_DEV.
    cont_dev_correlation : float
        Correlation of ``-cont_dev_radial_mm`` with the radial deviation (NaN without
        CONT_DEV). CONT_DEV = expected - actual position, so a path outside the circle shows
        as negative radial CONT_DEV.
    n_samples : int
        Samples on the circle used.
    """

    axes: tuple[str, str]
    center_mm: tuple[float, float]
    radius_mm: float
    nominal_radius_mm: float
    radius_deviation_mm: float
    circular_deviation_lsc_mm: float
    circular_deviation_mz_mm: float
    angle_rad: FloatArray
    radial_deviation_mm: FloatArray
    cont_dev_radial_mm: FloatArray | None
    cont_dev_correlation: float
    n_samples: int


def circle_test(
    rec: Recording,
    axes: tuple[str, str] = ("X1", "Y1"),
    *,
    center: tuple[float, float] | None = None,
    radius: float | None = None,
    band: float = 0.05,
) -> CircleResult:
    """Circularity of the actual path on a programmed circle (ISO 230-4 manner).

    Parameters
    ----------
    rec : Recording
        Recording with DES_POS and ENC_POS of both axes (CONT_DEV optional).
    axes : (str, str)
        The plane.
    center : (float, float), optional
        Programmed centre [mm]; default the LSC centre of DES_POS.
    radius : float, optional
        Programmed radius [mm]; default the LSC radius of DES_POS.
    band : float, default 0.05
        Samples whose DES_POS lies within ``band * radius`` of the programmed circle and that
        move are used (approach and retract moves are left out).

    Returns
    -------
    CircleResult

    Notes
    -----
    ISO 230-4:2005 "circular tests for numerically controlled machine tools": radius deviation F
    and circular deviation G about the least-squares circle centre; the minimum-zone value is
    given as well (Nelder-Mead on the centre).
    """
    ax, ay = axes
    for code in ("ENC_POS", "DES_POS"):
        for a in axes:
            if not rec.has(code, a):
                raise IdentificationError(f"circle_test needs {code}|{a}")
    dx = rec.signal("DES_POS", ax).to_numpy(float)
    dy = rec.signal("DES_POS", ay).to_numpy(float)
    ex = rec.signal("ENC_POS", ax).to_numpy(float)
    ey = rec.signal("ENC_POS", ay).to_numpy(float)
    ok = np.isfinite(dx) & np.isfinite(dy) & np.isfinite(ex) & np.isfinite(ey)
    moving = np.zeros_like(ok)
    moving[1:] = np.hypot(np.diff(dx), np.diff(dy)) > 0
    sel = ok & moving
    if sel.sum() < 20:
        raise IdentificationError("fewer than 20 moving samples; no circle to test")
    if center is None or radius is None:
        # programmed circle from DES_POS, refitted on its own inliers
        cx, cy, r = fit_circle_lsq(dx[sel], dy[sel])
        for _ in range(3):
            on = sel & (np.abs(np.hypot(dx - cx, dy - cy) - r) <= band * r)
            if on.sum() < 20:
                break
            cx, cy, r = fit_circle_lsq(dx[on], dy[on])
        cx = center[0] if center is not None else cx
        cy = center[1] if center is not None else cy
        r = radius if radius is not None else r
    else:
        cx, cy, r = center[0], center[1], float(radius)
    on = sel & (np.abs(np.hypot(dx - cx, dy - cy) - r) <= band * r)
    if on.sum() < 20:
        raise IdentificationError(
            f"fewer than 20 samples of DES_POS on the circle r={r:.4g} mm about ({cx:.4g}, "
            f"{cy:.4g}); give center= and radius= of the programmed circle")
    x, y = ex[on], ey[on]
    xc, yc, rr = fit_circle_lsq(x, y)
    rad = np.hypot(x - xc, y - yc)
    ang = np.arctan2(y - yc, x - xc)
    g_lsc = float(rad.max() - rad.min())

    def zone(c: FloatArray) -> float:
        rd = np.hypot(x - c[0], y - c[1])
        return float(rd.max() - rd.min())

    mz = optimize.minimize(zone, np.array([xc, yc]), method="Nelder-Mead",
                           options={"xatol": 1e-9, "fatol": 1e-12, "maxiter": 2000})
    g_mz = min(float(mz.fun), g_lsc)
    cdr: FloatArray | None = None
    corr = float("nan")
    if rec.has("CONT_DEV", ax) and rec.has("CONT_DEV", ay):
        cdx = rec.signal("CONT_DEV", ax).to_numpy(float)[on]
        cdy = rec.signal("CONT_DEV", ay).to_numpy(float)[on]
        cdr = cdx * np.cos(ang) + cdy * np.sin(ang)
        dev = rad - rr
        if np.std(cdr) > 0 and np.std(dev) > 0:
            corr = float(np.corrcoef(-cdr, dev)[0, 1])
    return CircleResult(axes, (xc, yc), rr, r, rr - r, g_lsc, g_mz, ang, rad - rr, cdr, corr,
                        int(on.sum()))
