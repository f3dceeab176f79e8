"""Cutting tools: descriptions, flank-wear growth and the lumped tool-tip temperature.

* :class:`Drill`, :class:`EndMill`, :class:`Tap`: geometry of the thesis tools (the
  descriptions live in :mod:`cnctwin.machine.tools`; re-exported here).
* :func:`flank_wear_um`: three-phase flank-wear curve over the hole count (thesis §5.1:
  ~277 um after 2676 holes, TiAlN carbide drill in AISI 1045).
* :class:`ToolThermal` + :func:`tool_temperature`: first-order lumped tool-tip temperature driven
  by the cutting power (thesis Fig. 5.5: about +300 degC over 6 consecutive holes).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from cnctwin.exceptions import ConfigError
from cnctwin.machine.tools import Drill, EndMill, Tap

__all__ = [
    "Drill",
    "EndMill",
    "Tap",
    "ToolThermal",
    "WearCurve",
    "first_order_recursion",
    "flank_wear_um",
    "tool_temperature",
]


@dataclass(frozen=True)
class WearCurve:
    """Three-phase flank-wear curve VB(n) over the number of holes n.

    VB(n) = run_in (1 - exp(-n / run_in_holes)) + rate n + accel (n / n_end)^accel_exponent

    Defaults reach 277 um at hole 2676 (thesis §5.1): 60 um run-in, 147 um steady,
    70 um accelerating. [E] shape (Taylor-type three-phase wear), [T] end point.

    Attributes
    ----------
    run_in_um : float
        Wear gained in the run-in phase [um].
    run_in_holes : float
        Run-in length constant [holes].
    rate_um_per_hole : float
        Steady wear rate [um/hole].
    accel_um : float
        Wear added by the accelerating phase at ``n_end`` [um].
    accel_exponent : float
        Sharpness of the accelerating phase [-].
    n_end : float
        Hole count at which the accelerating term equals ``accel_um`` [holes].
    """

    run_in_um: float = 60.0
    run_in_holes: float = 40.0
    rate_um_per_hole: float = 147.0 / 2676.0
    accel_um: float = 70.0
    accel_exponent: float = 6.0
    n_end: float = 2676.0


def flank_wear_um(hole: ArrayLike, *, curve: WearCurve | None = None) -> NDArray[np.float64]:
    """Flank wear VB after ``hole`` holes [um].

    Parameters
    ----------
    hole : array-like of float
        Number of holes drilled (0 = new tool).
    curve : WearCurve, optional
        Curve parameters; default the thesis wear run.

    Returns
    -------
    numpy.ndarray
        Flank wear [um].

    Examples
    --------
    >>> round(float(flank_wear_um(2676)), 1)
    277.0
    """
    c = curve if curve is not None else WearCurve()
    n = np.maximum(np.asarray(hole, dtype=np.float64), 0.0)
    return np.asarray(
        c.run_in_um * (1.0 - np.exp(-n / c.run_in_holes))
        + c.rate_um_per_hole * n
        + c.accel_um * (n / c.n_end) ** c.accel_exponent,
        dtype=np.float64,
    )


@dataclass(frozen=True)
class ToolThermal:
    """Lumped (one-node) tool-tip temperature model.

    C dT/dt = eta P_cut - (T - T_amb) / R

    Attributes
    ----------
    heat_fraction : float
        Fraction eta of the cutting power entering the drill [-]. [E] 0.10 (5-15 %,
        docs/reference/physics-and-performance.md §3)
    heat_capacity_j_per_k : float
        Heat capacity of the tip region C [J/K]. [E] 3.3 (~16 g carbide)
    resistance_k_per_w : float
        Thermal resistance to the surroundings R [K/W]; R C ~ 24 s gives a time constant of
        about 4 hole cycles. [E] 7.3
    ambient_temperature_c : float
        Ambient [degC]. [T] 25 (reflected temperature set in the FLIR software, §5.2)
    """

    heat_fraction: float = 0.10
    heat_capacity_j_per_k: float = 3.3
    resistance_k_per_w: float = 7.3
    ambient_temperature_c: float = 25.0

    @property
    def time_constant_s(self) -> float:
        """R C [s]."""
        return self.resistance_k_per_w * self.heat_capacity_j_per_k


def tool_temperature(
    cutting_power_w: ArrayLike,
    *,
    dt_s: float,
    thermal: ToolThermal | None = None,
    initial_c: float | None = None,
) -> NDArray[np.float64]:
    """Tool-tip temperature under a sampled cutting power [degC].

    Parameters
    ----------
    cutting_power_w : array-like of float
        Cutting power M_c omega per sample [W] (held over each sample).
    dt_s : float
        Sample interval [s].
    thermal : ToolThermal, optional
        Model parameters.
    initial_c : float, optional
        Temperature before the first sample [degC]; default ambient.

    Returns
    -------
    numpy.ndarray
        Temperature at the end of each sample [degC].

    Notes
    -----
    Exact discretisation of the first-order model for piecewise-constant power:
    y[k] = a y[k-1] + (1 - a) eta R P[k], a = exp(-dt / (R C)), y = T - T_amb.
    """
    th = thermal if thermal is not None else ToolThermal()
    if dt_s <= 0:
        raise ConfigError(f"tool_temperature: dt_s must be > 0, got {dt_s}")
    p = np.asarray(cutting_power_w, dtype=np.float64)
    a = math.exp(-dt_s / th.time_constant_s)
    y0 = 0.0 if initial_c is None else initial_c - th.ambient_temperature_c
    u = (1.0 - a) * th.heat_fraction * th.resistance_k_per_w * np.maximum(p, 0.0)
    return first_order_recursion(u, a, b0=1.0, y_prev=y0) + th.ambient_temperature_c


@njit(cache=True)
def _first_order_kernel(x: NDArray[np.float64], a: float, b0: float,
                        y_prev: float) -> NDArray[np.float64]:  # pragma: no cover - compiled
    y = np.empty(x.size)
    z = a * y_prev
    for i in range(x.size):
        y[i] = b0 * x[i] + z
        z = a * y[i]
    return y


def first_order_recursion(x: ArrayLike, a: float, *, b0: float = 1.0,
                          y_prev: float = 0.0) -> NDArray[np.float64]:
    """y[k] = b0 x[k] + a y[k-1] from ``y[-1] = y_prev``: ``scipy.signal.lfilter([b0],
    [1, -a], x, zi=[a y_prev])`` with the same arithmetic (same bits), compiled, without
    importing scipy.signal (0.3 s of the simulator's start-up)."""
    return _first_order_kernel(np.ascontiguousarray(x, dtype=np.float64), float(a),
                               float(b0), float(y_prev))
