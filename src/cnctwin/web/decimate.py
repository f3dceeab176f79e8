"""Min/max (envelope) decimation of a signal to a pixel budget.

A plot ``px`` pixels wide cannot show more than one vertical stroke per pixel column. Keeping the
minimum and the maximum sample of each column's share of the signal (in the order they occur)
draws the same strokes as the full signal: no peak is lost, and the payload is at most
``2 px + 2`` points however long the recording is (the M4 idea of Jugel et al., reduced to
min/max since the first and last sample are kept once for the whole range).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cnctwin.exceptions import ConfigError

__all__ = ["Envelope", "bucket_starts", "envelope_decimate"]


@dataclass(frozen=True)
class Envelope:
    """A signal reduced to the min and max sample of each bucket.

    Attributes
    ----------
    index : numpy.ndarray of int64
        Positions of the kept samples in the input, increasing.
    x : numpy.ndarray of float64
        ``x`` of the kept samples (e.g. seconds since the first cycle) [s].
    y : numpy.ndarray of float64
        Values of the kept samples (NaN where the input is NaN, only when not decimated).
    bucket_starts : numpy.ndarray of int64
        First sample of each bucket (``n_buckets + 1`` entries, the last is ``n_source``); one
        bucket when the input was kept whole.
    n_source : int
        Samples in the input.
    exact : bool
        True when every sample is kept (the input fits into the budget).
    """

    index: NDArray[np.int64]
    x: NDArray[np.float64]
    y: NDArray[np.float64]
    bucket_starts: NDArray[np.int64]
    n_source: int
    exact: bool

    @property
    def n_points(self) -> int:
        """Number of kept samples."""
        return int(self.index.size)


def bucket_starts(n: int, n_buckets: int) -> NDArray[np.int64]:
    """Start index of each of ``n_buckets`` near-equal buckets of ``n`` samples (and ``n``).

    Bucket ``i`` holds samples ``starts[i] .. starts[i+1]-1``; sizes differ by at most one.

    Parameters
    ----------
    n : int
        Number of samples.
    n_buckets : int
        Number of buckets (at most ``n``).

    Returns
    -------
    numpy.ndarray of int64
        ``n_buckets + 1`` indices, the last one ``n``.
    """
    if n_buckets < 1:
        raise ConfigError(f"n_buckets must be at least 1, not {n_buckets}")
    return (np.arange(n_buckets + 1, dtype=np.int64) * n) // n_buckets


def _extreme_positions(y: NDArray[np.float64], starts: NDArray[np.int64],
                       ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Positions of the min and of the max sample of each bucket (NaN ignored; -1 if all NaN)."""
    n_b = starts.size - 1
    sizes = np.diff(starts)
    has_nan = bool(np.isnan(y).any())
    lo = np.where(np.isnan(y), np.inf, y) if has_nan else y
    hi = np.where(np.isnan(y), -np.inf, y) if has_nan else y
    imin = np.empty(n_b, dtype=np.int64)
    imax = np.empty(n_b, dtype=np.int64)
    # buckets come in at most two sizes (k and k+1); each size class is one strided 2-D view
    for k in np.unique(sizes):
        sel = np.flatnonzero(sizes == k)
        if k == 0:
            imin[sel] = imax[sel] = -1
            continue
        # consecutive runs of same-size buckets are contiguous in memory: reshape them
        run_breaks = np.flatnonzero(np.diff(sel) != 1) + 1
        for run in np.split(sel, run_breaks):
            a, b = int(starts[run[0]]), int(starts[run[-1] + 1])
            blk_lo = lo[a:b].reshape(run.size, int(k))
            blk_hi = hi[a:b].reshape(run.size, int(k))
            base = starts[run]
            imin[run] = base + np.argmin(blk_lo, axis=1)
            imax[run] = base + np.argmax(blk_hi, axis=1)
    if has_nan:
        imin[~np.isfinite(lo[np.maximum(imin, 0)])] = -1
        imax[~np.isfinite(hi[np.maximum(imax, 0)])] = -1
    return imin, imax


def envelope_decimate(x: ArrayLike, y: ArrayLike, *, px: int) -> Envelope:
    """Reduce a signal to the min and max sample of each of ``px`` buckets.

    Parameters
    ----------
    x : array-like of float
        Sample positions (time [s]), increasing, as long as ``y``.
    y : array-like of float
        Sample values.
    px : int
        Pixel budget: number of buckets (plot width in pixels). At most ``2 px + 2`` samples
        are kept; an input of up to ``2 px`` samples is kept whole.

    Returns
    -------
    Envelope
        Kept sample positions and values in input order.

    Notes
    -----
    The buckets split the samples (not the x range) into ``px`` near-equal parts
    (:func:`bucket_starts`). For each bucket the first minimum and the first maximum (by
    ``numpy.argmin``/``argmax``) are kept; the first and last sample of the input are always
    kept so the plotted range is the data's range. NaN samples are skipped; a bucket that is
    all NaN contributes nothing. Cost: one pass over ``y`` per extreme (two reads of the
    data), no copy unless ``y`` holds NaN.

    Examples
    --------
    >>> import numpy as np
    >>> y = np.zeros(1000); y[123] = 5.0; y[777] = -3.0
    >>> env = envelope_decimate(np.arange(1000.0), y, px=10)
    >>> float(env.y.max()), float(env.y.min()), env.n_points <= 22
    (5.0, -3.0, True)
    """
    if px < 1:
        raise ConfigError(f"px (pixel budget) must be at least 1, not {px}")
    xa = np.asarray(x, dtype=np.float64)
    ya = np.asarray(y, dtype=np.float64)
    if xa.shape != ya.shape or ya.ndim != 1:
        raise ConfigError(f"x and y must be 1-D of one length, not {xa.shape} and {ya.shape}")
    n = int(ya.size)
    if n <= 2 * px:
        idx = np.arange(n, dtype=np.int64)
        return Envelope(idx, xa.copy(), ya.copy(), np.array([0, n], dtype=np.int64), n, True)
    starts = bucket_starts(n, px)
    imin, imax = _extreme_positions(ya, starts)
    keep = np.concatenate([[0, n - 1], imin[imin >= 0], imax[imax >= 0]])
    idx = np.unique(keep)  # sorted, min==max collapsed
    return Envelope(idx, xa[idx], ya[idx], starts, n, False)
