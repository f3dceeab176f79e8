"""Trend figure of :func:`cnctwin.servo.health.track_loop_health` (matplotlib, Agg).

:func:`plot_health_trends`: one panel per parameter with the window estimates (1 standard error
bars), the baseline value with its +-2 and +-``z_alarm`` sigma bands, the baseline period shaded,
windows where the parameter could not be identified marked on the axis, and the alarms.
"""

from __future__ import annotations

import math

import matplotlib

matplotlib.use("Agg")

import numpy as np
from matplotlib.figure import Figure

from cnctwin.exceptions import IdentificationError
from cnctwin.servo.health import HealthResult

__all__ = ["plot_health_trends"]


def plot_health_trends(result: HealthResult, *, parameters: tuple[str, ...] | None = None,
                       ncols: int = 2) -> Figure:
    """Parameter trends over the windows with baseline bands and alarms.

    Parameters
    ----------
    result : HealthResult
        Output of :func:`~cnctwin.servo.health.track_loop_health`.
    parameters : tuple of str, optional
        Panels to draw; default every parameter identified in at least one window, in the
        order of :data:`~cnctwin.servo.health.HEALTH_PARAMETERS`.
    ncols : int, default 2
        Panel columns.

    Returns
    -------
    matplotlib.figure.Figure

    Raises
    ------
    IdentificationError
        If no parameter was identified in any window (nothing to draw).
    """
    from cnctwin.servo.health import HEALTH_PARAMETERS

    if parameters is None:
        seen = {p for w in result.windows for p in w.params}
        parameters = tuple(p for p in (*HEALTH_PARAMETERS, "speed_loop_bandwidth_hz")
                           if p in seen)
    if not parameters:
        raise IdentificationError(
            f"{result.axis}: no parameter was identified in any of the {len(result.windows)} "
            f"windows; see HealthWindow.not_identified for the reasons")
    n = len(parameters)
    ncols = max(1, min(ncols, n))
    nrows = math.ceil(n / ncols)
    fig = Figure(figsize=(6.0 * ncols, 2.4 * nrows + 0.6), layout="constrained")
    axs = fig.subplots(nrows, ncols, squeeze=False, sharex=True)
    n_win = len(result.windows)
    n_base = int(str(result.settings.get("baseline_windows", 0)))
    z_alarm = float(str(result.settings.get("z_alarm", 5.0)))
    for k, p in enumerate(parameters):
        ax = axs[k // ncols][k % ncols]
        idx, val, se = result.series(p)
        unit = next((w.params[p].unit for w in result.windows if p in w.params), "")
        if n_base and n_win:
            ax.axvspan(-0.5, min(n_base, n_win) - 0.5, color="0.92", zorder=0,
                       label="baseline period")
        b = result.baseline.get(p)
        if b is not None:
            ax.axhline(b.mean, color="tab:green", lw=1.0, label="baseline")
            for mult, alpha in ((2.0, 0.25), (z_alarm, 0.10)):
                ax.axhspan(b.mean - mult * b.band, b.mean + mult * b.band, color="tab:green",
                           alpha=alpha, lw=0, label=f"±{mult:g} σ" if mult == 2.0
                           else f"±{mult:g} σ (alarm)")
        if idx.size:
            ax.errorbar(idx, val, yerr=np.where(np.isfinite(se), se, 0.0), fmt="o", ms=3,
                        color="tab:blue", ecolor="tab:blue", elinewidth=0.8, capsize=2,
                        label="window ±1 s.e.")
        missing = [w.index for w in result.windows if p not in w.params]
        if missing:
            ax.plot(missing, np.zeros(len(missing)), "x", color="0.5",
                    transform=ax.get_xaxis_transform(), clip_on=False,
                    label="not identified")
        for a in result.alarms_for(p):
            ax.axvline(a.onset_index, color="tab:red", lw=1.0, ls="--")
            ax.annotate(f"{a.test} {100 * a.relative_change:+.0f} %", (a.window_index, 1.0),
                        xycoords=("data", "axes fraction"), va="top", ha="left", fontsize=7,
                        color="tab:red")
        ax.set_ylabel(f"{p} [{unit}]" if unit else p, fontsize=8)
        ax.tick_params(labelsize=7)
        if k == 0:
            ax.legend(fontsize=6, loc="best")
    for k in range(n, nrows * ncols):
        axs[k // ncols][k % ncols].set_visible(False)
    for c in range(ncols):
        axs[-1][c].set_xlabel("window", fontsize=8)
    fig.suptitle(f"{result.axis}: loop health over {n_win} windows "
                 f"({len(result.alarms)} alarm{'s' if len(result.alarms) != 1 else ''})",
                 fontsize=10)
    return fig
