"""Figures in the manner of thesis Fig. 3.2 / 3.3 (matplotlib, Agg; Figure objects returned).

* :func:`plot_tool_path`: X-Y tool path with DES_POS, CTRL_POS (if recorded) and ENC_POS, the
  deviations from DES_POS magnified by a factor (stated in the legend).
* :func:`plot_error_signals`: per-axis following error, CTRL_DIFF2 and CONT_DEV vs time.
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import numpy as np
from matplotlib.figure import Figure
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from cnctwin.exceptions import ConfigError, IdentificationError
from cnctwin.recording import Recording
from cnctwin.servo.geometry import signed_distance_to_polyline

__all__ = ["plot_error_signals", "plot_tool_path"]


def _magnified(path: NDArray[np.float64], pts: NDArray[np.float64], magnify: float,
               deviation: str) -> NDArray[np.float64]:
    """Points drawn with their deviation from ``path`` magnified."""
    if deviation == "total":
        return path + magnify * (pts - path)
    # normal deviation: nearest vertex of the path plus the magnified signed normal distance
    good = np.isfinite(path).all(axis=1)
    p = path[good]
    keep = np.concatenate([[True], np.linalg.norm(np.diff(p, axis=0), axis=1) > 1e-12])
    p = p[keep]
    out = np.full(pts.shape, np.nan)
    if len(p) < 2:
        return out
    dist = signed_distance_to_polyline(pts, p)
    tang = np.gradient(p, axis=0)
    tang /= np.maximum(np.linalg.norm(tang, axis=1), 1e-300)[:, None]
    normal = np.column_stack([-tang[:, 1], tang[:, 0]])  # left of travel
    ok = np.isfinite(pts).all(axis=1)
    _, idx = cKDTree(p).query(pts[ok])
    out[ok] = p[idx] + magnify * dist[ok][:, None] * normal[idx]
    return out


def plot_tool_path(
    rec: Recording, axes: tuple[str, str] = ("X1", "Y1"), *, magnify: float = 50.0,
    deviation: str = "normal",
) -> Figure:
    """Tool path in the plane of two axes (thesis Fig. 3.2a / 3.3a).

    Parameters
    ----------
    rec : Recording
        Recording with DES_POS and ENC_POS of both axes (CTRL_POS optional).
    axes : (str, str)
        Horizontal and vertical axis.
    magnify : float, default 50
        Deviations from DES_POS are drawn ``magnify`` times enlarged [-].
    deviation : {'normal', 'total'}, default 'normal'
        ``'normal'``: the signed distance from the DES_POS path (the contour error) is
        magnified, so the lag along the path does not smear corners; ``'total'``: the whole
        vector ``position - DES_POS`` of the same cycle is magnified.

    Returns
    -------
    matplotlib.figure.Figure
    """
    ax_x, ax_y = axes
    for a in axes:
        for code in ("DES_POS", "ENC_POS"):
            if not rec.has(code, a):
                raise IdentificationError(f"plot_tool_path needs {code}|{a}")
    fig = Figure(figsize=(6.5, 6.0))
    ax = fig.add_subplot(1, 1, 1)
    dx = rec.signal("DES_POS", ax_x).to_numpy(float)
    dy = rec.signal("DES_POS", ax_y).to_numpy(float)
    if deviation not in ("normal", "total"):
        raise ConfigError(f"deviation must be 'normal' or 'total', not {deviation!r}")
    ax.plot(dx, dy, color="k", lw=1.0, label="desired position (DES_POS)")
    path = np.column_stack([dx, dy])
    what = "normal deviation" if deviation == "normal" else "deviation"
    if rec.has("CTRL_POS", ax_x) and rec.has("CTRL_POS", ax_y):
        c = np.column_stack([rec.signal("CTRL_POS", ax_x).to_numpy(float),
                             rec.signal("CTRL_POS", ax_y).to_numpy(float)])
        m = _magnified(path, c, magnify, deviation)
        ax.plot(m[:, 0], m[:, 1], color="tab:orange", lw=1.0,
                label=f"controller input position (CTRL_POS), {what} x{magnify:g}")
    e = np.column_stack([rec.signal("ENC_POS", ax_x).to_numpy(float),
                         rec.signal("ENC_POS", ax_y).to_numpy(float)])
    m = _magnified(path, e, magnify, deviation)
    ax.plot(m[:, 0], m[:, 1], color="tab:blue", lw=1.0,
            label=f"encoder position (ENC_POS), {what} x{magnify:g}")
    unit = rec.meta.units.get(f"DES_POS|{ax_x}", "mm")
    ax.set_xlabel(f"{ax_x} [{unit}]")
    ax.set_ylabel(f"{ax_y} [{unit}]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, lw=0.3)
    ax.legend(loc="best", fontsize=7)
    ax.set_title("Tool path with position-related signals")
    fig.tight_layout()
    return fig


def plot_error_signals(rec: Recording, axis: str) -> Figure:
    """Position-error signals of one axis vs time (thesis Fig. 3.2b,c / 3.3b,c).

    Following error ``DES_POS - ENC_POS``, ``CTRL_DIFF2`` (or ``CTRL_POS - ENC_POS``) and
    ``CONT_DEV``, whichever can be formed from the recording.

    Parameters
    ----------
    rec : Recording
        A recording with the axis' DES_POS/ENC_POS (and CONT_DEV, CTRL_POS where recorded).
    axis : str
        Axis name.

    Returns
    -------
    matplotlib.figure.Figure
    """
    t = rec.time_s
    fig = Figure(figsize=(8.0, 3.6))
    ax = fig.add_subplot(1, 1, 1)
    unit = rec.meta.units.get(f"ENC_POS|{axis}", "mm")
    drawn = 0
    if rec.has("DES_POS", axis) and rec.has("ENC_POS", axis):
        fe = (rec.signal("DES_POS", axis) - rec.signal("ENC_POS", axis)).to_numpy(float)
        ax.plot(t, fe, lw=0.8, label="following error (DES_POS - ENC_POS)")
        drawn += 1
    if rec.has("CTRL_DIFF2", axis):
        ax.plot(t, rec.signal("CTRL_DIFF2", axis).to_numpy(float), lw=0.8,
                label="position controller difference (CTRL_DIFF2)")
        drawn += 1
    elif rec.has("CTRL_POS", axis) and rec.has("ENC_POS", axis):
        cd = (rec.signal("CTRL_POS", axis) - rec.signal("ENC_POS", axis)).to_numpy(float)
        ax.plot(t, cd, lw=0.8, label="CTRL_POS - ENC_POS")
        drawn += 1
    if rec.has("CONT_DEV", axis):
        ax.plot(t, rec.signal("CONT_DEV", axis).to_numpy(float), lw=0.8,
                label="contour deviation (CONT_DEV)")
        drawn += 1
    if rec.has("FOLLOWING_ERROR", axis):
        ax.plot(t, rec.signal("FOLLOWING_ERROR", axis).to_numpy(float), lw=0.8, ls="--",
                label="recorded following error")
        drawn += 1
    if drawn == 0:
        raise IdentificationError(f"no position-error signal can be formed for axis {axis}")
    ax.set_xlabel("time [s]")
    ax.set_ylabel(f"{axis} error [{unit}]")
    ax.grid(True, lw=0.3)
    ax.legend(loc="best", fontsize=7)
    ax.set_title(f"{axis}: positional error signals")
    fig.tight_layout()
    return fig
