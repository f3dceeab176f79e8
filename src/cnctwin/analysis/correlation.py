"""Correlation matrices of signals, raw and low-pass filtered (thesis Fig. 3.7 and 3.9)."""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from cnctwin.analysis.filters import FilterWarning, lowpass
from cnctwin.exceptions import ConfigError

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["PAGE_WIDTH_IN", "correlation_label", "correlation_matrix", "plot_correlation_heatmaps"]


def correlation_label(cutoff_hz: float | None) -> str:
    """Label of one matrix: ``'raw'`` or ``'lowpass 10 Hz'``.

    Parameters
    ----------
    cutoff_hz : float, optional
        Low-pass cutoff [Hz]; None for the raw signals.

    Returns
    -------
    str
    """
    return "raw" if cutoff_hz is None else f"lowpass {cutoff_hz:g} Hz"


def correlation_matrix(
    df: pd.DataFrame,
    *,
    cutoffs_hz: Sequence[float | None] = (None, 100.0, 50.0, 10.0),
    fs_hz: float,
    order: int = 4,
    method: str = "pearson",
) -> dict[str, pd.DataFrame]:
    """Pearson correlation matrices of the columns of ``df``, raw and after low-pass filters.

    Parameters
    ----------
    df : pandas.DataFrame
        Uniformly sampled signals, one per column (e.g. the cutting region of
        ``rec.hf`` plus the aligned dynamometer torque from
        :func:`~cnctwin.analysis.align.external_on_hf`). Non-numeric columns are ignored.
    cutoffs_hz : sequence of float or None, default (None, 100, 50, 10)
        ``None`` = raw data; a number = zero-phase Butterworth low-pass at that cutoff [Hz]
        (thesis Fig. 3.7 a-d).
    fs_hz : float
        Sample rate [Hz].
    order : int, default 4
        Filter order.
    method : {'pearson', 'spearman', 'kendall'}, default 'pearson'
        Passed to :meth:`pandas.DataFrame.corr`.

    Returns
    -------
    dict of str to pandas.DataFrame
        ``{'raw': ..., 'lowpass 100 Hz': ..., ...}`` in the order of ``cutoffs_hz``.
        Constant columns give NaN rows/columns (correlation undefined).

    Notes
    -----
    Missing samples (NaN) inside a column are filled by linear interpolation before
    filtering (an IIR filter cannot skip them); leading/trailing rows that stay NaN are cut.
    Both repairs are reported with a :class:`~cnctwin.analysis.filters.FilterWarning`.
    """
    num = df.select_dtypes(include=[np.number]).astype(np.float64)
    if num.shape[1] < 2:
        raise ConfigError(
            f"need at least two numeric columns to correlate, got {list(num.columns)}"
        )
    if num.isna().to_numpy().any():
        n_nan = int(num.isna().to_numpy().sum())
        num = num.interpolate(method="linear", limit_area="inside")
        before = len(num)
        num = num.dropna(how="any")
        warnings.warn(
            f"{n_nan} missing samples: inner gaps interpolated linearly, "
            f"{before - len(num)} edge rows cut before filtering",
            FilterWarning,
            stacklevel=2,
        )
    if len(num) < 3:
        raise ConfigError(f"only {len(num)} complete rows; cannot correlate")
    out: dict[str, pd.DataFrame] = {}
    for cutoff in cutoffs_hz:
        if cutoff is None:
            data = num
        else:
            filt = lowpass(num.to_numpy(), float(cutoff), fs_hz=fs_hz, order=order, axis=0)
            data = pd.DataFrame(filt, index=num.index, columns=num.columns)
        with np.errstate(invalid="ignore", divide="ignore"):
            out[correlation_label(cutoff)] = data.corr(method=method)  # type: ignore[arg-type]
    return out


PAGE_WIDTH_IN = 11.0
"""Width of a report page's figure area [inch] (1100 px at 100 dpi, the report's width)."""


def plot_correlation_heatmaps(
    matrices: Mapping[str, pd.DataFrame],
    *,
    titles: Sequence[str] | None = None,
    annotate: bool = True,
    ncols: int | None = None,
    cmap: str = "RdBu_r",
    figsize_in: tuple[float, float] | None = None,
) -> Figure:
    """Heatmaps of correlation matrices side by side (thesis Fig. 3.7, Fig. 3.9).

    Parameters
    ----------
    matrices : mapping of str to pandas.DataFrame
        Output of :func:`correlation_matrix` (or any square correlation frames).
    titles : sequence of str, optional
        Panel titles; default the mapping keys prefixed with a), b), ...
    annotate : bool, default True
        Write the coefficient into each cell.
    ncols : int, optional
        Panels per row; default 2 (one if there is one), so the figure fits a report page
        at its own size and the labels stay readable.
    cmap : str, default 'RdBu_r'
        Colormap, fixed to the range [-1, 1].
    figsize_in : (float, float), optional
        Figure size [inch]; default at most :data:`PAGE_WIDTH_IN` wide, cells 0.25-0.55 in
        (annotations only where a cell is at least 0.3 in).

    Returns
    -------
    matplotlib.figure.Figure
        A figure not attached to pyplot (Agg canvas); save it with ``fig.savefig(path)``.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    keys = list(matrices)
    if not keys:
        raise ConfigError("no correlation matrices to plot")
    n = len(keys)
    ncols = ncols or min(n, 2)
    nrows = int(np.ceil(n / ncols))
    size = max(len(matrices[k]) for k in keys)
    cell = min(0.55, max(0.25, ((PAGE_WIDTH_IN - 0.8) / ncols - 1.8) / max(size, 1)))
    figsize = figsize_in or (ncols * (1.8 + size * cell) + 0.8, nrows * (1.6 + size * cell))
    annotate = annotate and cell >= 0.3
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, ncols, squeeze=False)
    letters = "abcdefghijklmnopqrstuvwxyz"
    im = None
    for i, key in enumerate(keys):
        ax = axes[i // ncols][i % ncols]
        m = matrices[key]
        im = ax.imshow(m.to_numpy(dtype=float), vmin=-1.0, vmax=1.0, cmap=cmap)
        labels = [str(c) for c in m.columns]
        ax.set_xticks(range(len(labels)), labels, rotation=60, ha="right", fontsize=8)
        ax.set_yticks(range(len(labels)), [str(c) for c in m.index], fontsize=8)
        title = titles[i] if titles is not None else f"{letters[i % 26]}) {key}"
        ax.set_title(title, fontsize=10)
        if annotate:
            vals = m.to_numpy(dtype=float)
            for r in range(vals.shape[0]):
                for c in range(vals.shape[1]):
                    v = vals[r, c]
                    txt = "–" if not np.isfinite(v) else f"{v:.2f}"
                    ax.text(c, r, txt, ha="center", va="center", fontsize=7,
                            color="white" if np.isfinite(v) and abs(v) > 0.6 else "black")
    for j in range(n, nrows * ncols):
        axes[j // ncols][j % ncols].set_visible(False)
    if im is not None:
        fig.colorbar(im, ax=axes.ravel().tolist(), shrink=0.8, label="correlation")
    return fig
