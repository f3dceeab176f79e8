"""Validation on the real Vicomtech turning tool-wear data (CNC-internal signals vs dynamometer).

Two questions the thesis asks of a drilling machine can be asked of this real turning data:

1. How well do the CNC spindle torque (``TV2.S``) and current (``CV3.S``) track the cutting force
   measured by the dynamometer (``F_c``), per tool? (Issue #4, item 8.)
2. How well do CNC-internal features predict flank wear ``Vb`` on a tool never seen in training,
   against plain baselines? (Issue #6, item 2.)
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd

from cnctwin.exceptions import ConfigError
from cnctwin.iotools.vicomtech import CNC_INTERNAL_SIGNALS
from cnctwin.usecases.wear import LogoResult, leave_one_group_out

__all__ = ["cnc_wear_features", "tracking_table", "wear_validation"]


def tracking_table(
    data: pd.DataFrame,
    *,
    reference: str = "F_c_MEAN",
    signals: Sequence[str] = ("TV2.S_MEAN", "CV3.S_MEAN", "TV50.S_MEAN"),
    group: str = "tool",
) -> pd.DataFrame:
    """Per group, how well each signal tracks the reference (linear fit).

    Parameters
    ----------
    data : pandas.DataFrame
        Vicomtech table (``cnctwin.iotools.read_vicomtech``).
    reference : str, default 'F_c_MEAN'
        Dynamometer feature (cutting force mean [N]).
    signals : sequence of str
        CNC-internal features to compare.
    group : str, default 'tool'
        Grouping column.

    Returns
    -------
    pandas.DataFrame
        One row per (group, signal): ``n``, Pearson ``r``, ``r2`` of the linear fit
        ``reference ~ a*signal + b``, and the normalized RMS error of that fit
        ``nrmse_pct`` = RMS residual / mean reference [%].
    """
    for col in (reference, group, *signals):
        if col not in data.columns:
            raise ConfigError(f"column {col!r} not in the data")
    rows = []
    for g, part in data.groupby(group, sort=True):
        y = part[reference].to_numpy(dtype=np.float64)
        for s in signals:
            x = part[s].to_numpy(dtype=np.float64)
            ok = np.isfinite(x) & np.isfinite(y)
            r = float(np.corrcoef(x[ok], y[ok])[0, 1]) if ok.sum() > 2 else float("nan")
            coef = np.polyfit(x[ok], y[ok], 1)
            resid = y[ok] - np.polyval(coef, x[ok])
            rows.append(
                {
                    group: g,
                    "signal": s,
                    "n": int(ok.sum()),
                    "r": r,
                    "r2": r * r,
                    "nrmse_pct": float(100 * np.sqrt(np.mean(resid**2)) / np.mean(y[ok])),
                }
            )
    return pd.DataFrame(rows)


def cnc_wear_features(
    data: pd.DataFrame, *, stats: Sequence[str] = ("MEAN", "RMS", "MAX")
) -> list[str]:
    """CNC-internal feature columns (what the control records; no dynamometer, no accelerometer).

    The programmed and encoder speeds/feeds (``CON.*``) are included.

    Parameters
    ----------
    data : pandas.DataFrame
        The Vicomtech table (:func:`cnctwin.iotools.read_vicomtech`).
    stats : sequence, default ('MEAN', 'RMS', 'MAX')
        Statistics to take per signal.

    Returns
    -------
    list of str
    """
    cols = [
        c for c in data.columns
        if any(c == f"{p}_{s}" for p in CNC_INTERNAL_SIGNALS for s in stats)
    ]
    cols += [c for c in data.columns if c.startswith("CON.")]
    return cols


def wear_validation(data: pd.DataFrame, *, alpha: float = 100.0) -> LogoResult:
    """Leave-one-tool-out flank-wear error from CNC-internal features vs plain baselines.

    Parameters
    ----------
    data : pandas.DataFrame
        The Vicomtech table.
    alpha : float, default 100.0
        Ridge penalty on standardized features.

    Returns
    -------
    LogoResult
    """
    return leave_one_group_out(
        data, features=cnc_wear_features(data), target="Vb", group="tool", usage="segment",
        alpha=alpha,
    )
