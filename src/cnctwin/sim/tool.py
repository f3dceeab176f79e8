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
    "free_cooling",
    "tool_temperature",
    "tool_temperatures",
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
    """Tool-tip temperature model: one node (the default), or the tip and its holder.

    One node: ``C dT/dt = eta P_cut - (T - T_amb) / R``. With a holder node
    (``holder_heat_capacity_j_per_k > 0``) the tip also conducts into the shank and holder,
    which warm slowly over many holes and cool slowly in the pauses:

    ``C dT/dt = eta P - (T - T_amb) / R - (T - T_h) / R_th``,
    ``C_h dT_h/dt = (T - T_h) / R_th - (T_h - T_amb) / R_h``.

    The soft sensor of :mod:`cnctwin.usecases.thermal` assumes one node; a simulated tool
    with a holder node shows it the model error a real tool would (issue 13).

    Attributes
    ----------
    heat_fraction : float
        Fraction eta of the cutting power entering the drill [-]. [E] 0.10 (5-15 %,
        docs/reference/physics-and-performance.md §3)
    heat_capacity_j_per_k : float
        Heat capacity of the tip region C [J/K]. [E] 3.3 (~16 g carbide)
    resistance_k_per_w : float
        Thermal resistance of the tip to the surroundings R [K/W]; R C ~ 24 s gives a time
        constant of about 4 hole cycles. [E] 7.3
    ambient_temperature_c : float
        Ambient [degC]. [T] 25 (reflected temperature set in the FLIR software, §5.2)
    holder_heat_capacity_j_per_k : float
        Heat capacity C_h of the shank and holder [J/K]; 0 = one node. [E] 40-120 for a
        shrink-fit holder's steel near the tool (0.1-0.3 kg x 460 J/(kg K)), when used
    tip_to_holder_k_per_w : float
        Conduction resistance R_th from the tip into the holder [K/W]. [E] 10
    holder_to_ambient_k_per_w : float
        Resistance R_h of the holder to the surroundings [K/W]. [E] 2
    """

    heat_fraction: float = 0.10
    heat_capacity_j_per_k: float = 3.3
    resistance_k_per_w: float = 7.3
    ambient_temperature_c: float = 25.0
    holder_heat_capacity_j_per_k: float = 0.0
    tip_to_holder_k_per_w: float = 10.0
    holder_to_ambient_k_per_w: float = 2.0

    @property
    def time_constant_s(self) -> float:
        """R C [s] (of the tip alone)."""
        return self.resistance_k_per_w * self.heat_capacity_j_per_k

    @property
    def two_node(self) -> bool:
        """True when the holder node is on."""
        return self.holder_heat_capacity_j_per_k > 0.0

    def state_matrices(self, dt_s: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Exact zero-order-hold discretisation of the two-node model over ``dt_s``.

        Parameters
        ----------
        dt_s : float
            Step [s].

        Returns
        -------
        ad : numpy.ndarray
            2 x 2 state transition of (tip, holder) temperature rises over ambient [-].
        bd : numpy.ndarray
            Rise per watt of cutting power held over the step, shape (2,) [K/W].
        """
        from scipy.linalg import expm

        c1, c2 = self.heat_capacity_j_per_k, self.holder_heat_capacity_j_per_k
        g1, g12, g2 = (1.0 / self.resistance_k_per_w, 1.0 / self.tip_to_holder_k_per_w,
                       1.0 / self.holder_to_ambient_k_per_w)
        a = np.array([[-(g1 + g12) / c1, g12 / c1], [g12 / c2, -(g12 + g2) / c2]])
        b = np.array([self.heat_fraction / c1, 0.0])
        m = np.zeros((3, 3))
        m[:2, :2] = a * dt_s
        m[:2, 2] = b * dt_s
        e = expm(m)
        return np.ascontiguousarray(e[:2, :2]), np.ascontiguousarray(e[:2, 2])


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
    importing scipy.signal (0.3 s of the simulator's start-up).

    Parameters
    ----------
    x : array-like
        Input samples.
    a : float
        Pole (0 < a < 1).
    b0 : float, default 1.0
        Input gain.
    y_prev : float, default 0.0
        Output before the first sample.

    Returns
    -------
    numpy.ndarray
        ``y``.
    """
    return _first_order_kernel(np.ascontiguousarray(x, dtype=np.float64), float(a),
                               float(b0), float(y_prev))


@njit(cache=True)
def _two_node_kernel(p: NDArray[np.float64], ad: NDArray[np.float64], bd: NDArray[np.float64],
                     y1: float, y2: float) -> tuple[NDArray[np.float64],
                                                    NDArray[np.float64]]:  # pragma: no cover
    tip = np.empty(p.size)
    holder = np.empty(p.size)
    for i in range(p.size):
        n1 = ad[0, 0] * y1 + ad[0, 1] * y2 + bd[0] * p[i]
        n2 = ad[1, 0] * y1 + ad[1, 1] * y2 + bd[1] * p[i]
        y1, y2 = n1, n2
        tip[i] = y1
        holder[i] = y2
    return tip, holder


def tool_temperatures(
    cutting_power_w: ArrayLike,
    *,
    dt_s: float,
    thermal: ToolThermal | None = None,
    initial_c: float | None = None,
    initial_holder_c: float | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Tip and holder temperatures under a sampled cutting power [degC].

    Parameters
    ----------
    cutting_power_w : array-like of float
        Cutting power M_c omega per sample [W] (held over each sample).
    dt_s : float
        Sample interval [s].
    thermal : ToolThermal, optional
        Model parameters; with one node this is :func:`tool_temperature` (same bits) and the
        holder stays at ambient.
    initial_c, initial_holder_c : float, optional
        Temperatures before the first sample [degC]; default ambient.

    Returns
    -------
    tip, holder : numpy.ndarray
        Temperatures at the end of each sample [degC].
    """
    th = thermal if thermal is not None else ToolThermal()
    amb = th.ambient_temperature_c
    if not th.two_node:
        tip = tool_temperature(cutting_power_w, dt_s=dt_s, thermal=th, initial_c=initial_c)
        return tip, np.full(tip.shape, amb)
    if dt_s <= 0:
        raise ConfigError(f"tool_temperatures: dt_s must be > 0, got {dt_s}")
    p = np.maximum(np.ascontiguousarray(cutting_power_w, dtype=np.float64), 0.0)
    ad, bd = th.state_matrices(dt_s)
    y1 = 0.0 if initial_c is None else initial_c - amb
    y2 = 0.0 if initial_holder_c is None else initial_holder_c - amb
    tip, holder = _two_node_kernel(p, ad, bd, float(y1), float(y2))
    return tip + amb, holder + amb


def free_cooling(tip_c: float, holder_c: float, seconds: float,
                 thermal: ToolThermal) -> float:
    """Tip temperature ``seconds`` after the cut ends (no power) [degC].

    Parameters
    ----------
    tip_c, holder_c : float
        Tip and holder temperatures at the start [degC] (``holder_c`` unused with one node).
    seconds : float
        Cooling time [s].
    thermal : ToolThermal
        Model parameters.

    Returns
    -------
    float
        ``T_amb + (T - T_amb) exp(-t / RC)`` with one node; the two-node solution otherwise.
    """
    amb = thermal.ambient_temperature_c
    if not thermal.two_node:
        return amb + (tip_c - amb) * math.exp(-seconds / thermal.time_constant_s)
    ad, _ = thermal.state_matrices(seconds)
    return amb + float(ad[0, 0] * (tip_c - amb) + ad[0, 1] * (holder_c - amb))
