"""Hole quality from servo positions: deviation paths, position error, straightness, flags.

Thesis chapter 5.3: while Z drills, the X and Y setpoints are constant, so any difference
between the desired (``DES_POS``) and the encoder (``ENC_POS``) positions of X and Y during the
cut shows the tool being pushed sideways (friction, walking drill, anomalies) and hints at a hole
that is off position or not straight. Figures 5.6-5.9 show these paths per hole in 3D and in the
X-Z, Y-Z and X-Y planes with the top of the hole at (0, 0, 0); :func:`deviation_paths` gives the
data and :mod:`cnctwin.usecases.figures` draws them.

Indicators (per hole, over the cut from the surface to the bottom):

* position error: ``|mean(ENC_xy - DES_xy)|``, the mean lateral offset from the programmed
  position [mm];
* straightness: ``max_k |d_xy(k) - mean(d_xy)|`` with ``d = ENC - DES``, the largest lateral
  excursion along the depth once the mean offset is removed [mm];
* out-of-tolerance flags against a tolerance [mm].

These are servo-side indicators: the encoder measures the axis, not the tool tip, so bending of
the drill itself is not seen. They flag holes to inspect; they do not replace a CMM.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from cnctwin.exceptions import ConfigError, SignalNotFoundError
from cnctwin.recording import Recording

__all__ = ["deviation_paths", "hole_quality"]


def _hole_rows(rec: Recording, holes: pd.DataFrame) -> pd.DataFrame:
    need = {"hole", "cut_start_cycle", "cut_end_cycle"}
    if not need <= set(holes.columns):
        raise ConfigError(f"hole table needs columns {sorted(need)}; run hole_record first")
    c0, c1 = int(rec.cycles[0]), int(rec.cycles[-1])
    inside = (holes["cut_start_cycle"] >= c0) & (holes["cut_end_cycle"] <= c1)
    return holes[inside]


def _axes_present(rec: Recording, axes: tuple[str, str, str]) -> None:
    for ax in axes:
        for code in ("DES_POS", "ENC_POS"):
            if not rec.has(code, ax):
                raise SignalNotFoundError(
                    f"hole quality needs {code}|{ax}; the recording has: {', '.join(rec.columns)}"
                )


def deviation_paths(
    rec: Recording,
    holes: pd.DataFrame,
    *,
    axes: tuple[str, str, str] = ("X1", "Y1", "Z1"),
) -> pd.DataFrame:
    """Desired and encoder positions of every hole, with the top of the hole at (0, 0, 0).

    Parameters
    ----------
    rec : Recording
        Recording with ``DES_POS`` and ``ENC_POS`` of the three axes.
    holes : pandas.DataFrame
        Hole record of this recording (:func:`~cnctwin.usecases.holes.hole_record`).
    axes : (str, str, str), default ('X1', 'Y1', 'Z1')
        Lateral X, lateral Y and drilling axis.

    Returns
    -------
    pandas.DataFrame
        Long form, one row per cycle of each cut: ``hole``, ``cycle``, ``t_s`` (from the cut
        start) [s], ``des_x_mm``, ``des_y_mm``, ``des_z_mm``, ``enc_x_mm``, ``enc_y_mm``,
        ``enc_z_mm`` [mm], all relative to the top of the hole: the programmed X/Y at the cut
        start and the surface Z (``surface_z_mm`` of the hole record).
    """
    _axes_present(rec, axes)
    rows = _hole_rows(rec, holes)
    cyc = rec.cycles
    parts = []
    for _, h in rows.iterrows():
        lo = int(np.searchsorted(cyc, int(h["cut_start_cycle"])))
        hi = int(np.searchsorted(cyc, int(h["cut_end_cycle"]), side="right"))
        sl = slice(lo, hi)
        top = [float(rec.hf[f"DES_POS|{axes[0]}"].iloc[lo]),
               float(rec.hf[f"DES_POS|{axes[1]}"].iloc[lo]),
               float(h["surface_z_mm"]) if "surface_z_mm" in h and math.isfinite(
                   float(h["surface_z_mm"])) else float(rec.hf[f"DES_POS|{axes[2]}"].iloc[lo])]
        d = {"hole": int(h["hole"]), "cycle": cyc[sl],
             "t_s": (cyc[sl] - cyc[lo]) * rec.meta.cycle_time_s}
        for k, (ax, tag) in enumerate(zip(axes, ("x", "y", "z"), strict=True)):
            d[f"des_{tag}_mm"] = rec.hf[f"DES_POS|{ax}"].to_numpy(dtype=np.float64)[sl] - top[k]
            d[f"enc_{tag}_mm"] = rec.hf[f"ENC_POS|{ax}"].to_numpy(dtype=np.float64)[sl] - top[k]
        parts.append(pd.DataFrame(d))
    cols = ["hole", "cycle", "t_s", "des_x_mm", "des_y_mm", "des_z_mm", "enc_x_mm", "enc_y_mm",
            "enc_z_mm"]
    if not parts:
        return pd.DataFrame(columns=cols)
    return pd.concat(parts, ignore_index=True)[cols]


def hole_quality(
    rec: Recording,
    holes: pd.DataFrame,
    *,
    tolerance_mm: float = 0.01,
    straightness_tolerance_mm: float | None = None,
    nominal_depth_mm: float | None = None,
    depth_tolerance_mm: float = 0.1,
    axes: tuple[str, str, str] = ("X1", "Y1", "Z1"),
) -> pd.DataFrame:
    """Position error, straightness and out-of-tolerance flags per hole.

    Parameters
    ----------
    rec : Recording
        Recording with ``DES_POS``/``ENC_POS`` of the three axes.
    holes : pandas.DataFrame
        Hole record of this recording.
    tolerance_mm : float, default 0.01
        Position tolerance (radius) [mm].
    straightness_tolerance_mm : float, optional
        Straightness tolerance [mm]; default ``tolerance_mm``.
    nominal_depth_mm : float, optional
        Programmed depth; with it ``depth_error_mm`` and ``depth_oot`` are filled [mm].
    depth_tolerance_mm : float, default 0.1
        Depth tolerance [mm].
    axes : (str, str, str)
        Lateral X, lateral Y and drilling axis.

    Returns
    -------
    pandas.DataFrame
        Per hole: ``hole``, ``position_error_x_mm``, ``position_error_y_mm``,
        ``position_error_mm``, ``straightness_mm``, ``depth_error_mm``, ``position_oot``,
        ``straightness_oot``, ``depth_oot``, ``out_of_tolerance`` (any flag).

    Notes
    -----
    With ``d = ENC - DES`` of X and Y over the cut: position error ``|mean(d)|``, straightness
    ``max |d - mean(d)|`` (both Euclidean in the XY plane).
    """
    if tolerance_mm <= 0:
        raise ConfigError(f"tolerance_mm must be > 0, not {tolerance_mm}")
    st_tol = tolerance_mm if straightness_tolerance_mm is None else straightness_tolerance_mm
    paths = deviation_paths(rec, holes, axes=axes)
    rows = []
    for hole, p in paths.groupby("hole", sort=True):
        dx = (p["enc_x_mm"] - p["des_x_mm"]).to_numpy()
        dy = (p["enc_y_mm"] - p["des_y_mm"]).to_numpy()
        mx, my = float(np.nanmean(dx)), float(np.nanmean(dy))
        straight = float(np.nanmax(np.hypot(dx - mx, dy - my))) if dx.size else math.nan
        rows.append({"hole": int(str(hole)), "position_error_x_mm": mx, "position_error_y_mm": my,
                     "position_error_mm": math.hypot(mx, my), "straightness_mm": straight})
    q = pd.DataFrame(rows, columns=["hole", "position_error_x_mm", "position_error_y_mm",
                                    "position_error_mm", "straightness_mm"])
    depth = holes.set_index("hole")["depth_mm"] if "depth_mm" in holes.columns else None
    if nominal_depth_mm is not None and depth is not None:
        q["depth_error_mm"] = q["hole"].map(depth).astype(float) - nominal_depth_mm
    else:
        q["depth_error_mm"] = math.nan
    q["position_oot"] = q["position_error_mm"] > tolerance_mm
    q["straightness_oot"] = q["straightness_mm"] > st_tol
    q["depth_oot"] = q["depth_error_mm"].abs() > depth_tolerance_mm
    q["out_of_tolerance"] = q["position_oot"] | q["straightness_oot"] | q["depth_oot"]
    q.attrs.update({"tolerance_mm": tolerance_mm, "straightness_tolerance_mm": st_tol,
                    "nominal_depth_mm": nominal_depth_mm,
                    "depth_tolerance_mm": depth_tolerance_mm})
    return q
