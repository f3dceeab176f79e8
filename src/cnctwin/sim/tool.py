"""Cutting tools: descriptions, flank-wear growth and the lumped tool-tip temperature.

* :class:`Drill`, :class:`EndMill`, :class:`Tap`: geometry of the thesis tools.
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
class Drill:
    """Twist drill.

    Attributes
    ----------
    diameter_mm : float
        Diameter D [mm]. [T] 8.5 (thesis §3.2.2, TiAlN-coated carbide)
    point_angle_deg : float
        Point angle sigma [deg]; kappa = sigma/2. [E] 140 (carbide drills)
    flutes : int
        Number of cutting lips. [E] 2
    edge_radius_mm : float
        Cutting-edge radius r [mm] (Subramanian & Cook torque term). [S] ~0.01
    tool_number : int
        T number in the NC program. [E] 1
    youngs_modulus_gpa : float
        Young's modulus of the drill [GPa]. [S] cemented carbide WC-Co 550-650 (e.g.
        Sandvik/ISO hardmetal data); 600
    overhang_mm : float
        Free length from the holder to the tip [mm]. [E] 50 (5xD drill for 20 mm holes)
    effective_diameter_ratio : float
        Diameter of the solid rod with the bending stiffness of the fluted body / D [-].
        [E] 0.8 (I_fluted ~ 0.4 I_solid)
    spindle_stiffness_n_per_um : float
        Static radial stiffness of spindle + holder at the gauge line [N/um]. [E] 30
        (motor spindles of machining centres: ~20-50 N/um)
    radial_runout_um : float
        Radial run-out of the tip (TIR / 2) [um]; the hole is 2 x this oversize. [E] 3
    guided_stiffness_gain : float
        Stiffening of the tip once the margins are in the hole (the hole wall guides the
        drill) relative to the free cantilever [-]. [E] 10
    """

    diameter_mm: float = 8.5
    point_angle_deg: float = 140.0
    flutes: int = 2
    edge_radius_mm: float = 0.01
    tool_number: int = 1
    youngs_modulus_gpa: float = 600.0
    overhang_mm: float = 50.0
    effective_diameter_ratio: float = 0.8
    spindle_stiffness_n_per_um: float = 30.0
    radial_runout_um: float = 3.0
    guided_stiffness_gain: float = 10.0

    @property
    def tip_stiffness_n_per_um(self) -> float:
        """Lateral stiffness at the free tip: drill cantilever in series with the spindle [N/um].

        Notes
        -----
        k_drill = 3 E I / L^3 with I = pi (c D)^4 / 64; 1/k = 1/k_drill + 1/k_spindle.
        Defaults: I = 105 mm^4, k_drill = 3 x 600e3 x 105 / 50^3 = 1512 N/mm = 1.51 N/um,
        with 30 N/um in series: 1.44 N/um.
        """
        i_mm4 = math.pi * (self.effective_diameter_ratio * self.diameter_mm) ** 4 / 64.0
        k_drill = 3.0 * self.youngs_modulus_gpa * 1e3 * i_mm4 / self.overhang_mm**3 / 1000.0
        return 1.0 / (1.0 / k_drill + 1.0 / self.spindle_stiffness_n_per_um)

    @property
    def kappa_rad(self) -> float:
        """Tool cutting-edge angle kappa = point angle / 2 [rad]."""
        return math.radians(self.point_angle_deg / 2.0)

    @property
    def cone_length_mm(self) -> float:
        """Axial length of the drill point, (D/2) / tan(kappa) [mm]."""
        return (self.diameter_mm / 2.0) / math.tan(self.kappa_rad)


@dataclass(frozen=True)
class EndMill:
    """Flat end mill.

    Attributes
    ----------
    diameter_mm : float
        Diameter [mm]. [T-brief] 16
    flutes : int
        Number of teeth. [T-brief] 2
    helix_deg : float
        Helix angle [deg] (not used by the zero-helix force model; documented). [E] 30
    tool_number : int
        T number. [E] 2
    """

    diameter_mm: float = 16.0
    flutes: int = 2
    helix_deg: float = 30.0
    tool_number: int = 2


@dataclass(frozen=True)
class Tap:
    """Machine tap for rigid tapping.

    Attributes
    ----------
    diameter_mm : float
        Nominal diameter [mm]. [E] 8 (M8)
    pitch_mm : float
        Thread pitch [mm]. [S] 1.25 (ISO M8 coarse)
    chamfer_threads : float
        Threads in the chamfer (entry ramp length = chamfer_threads x pitch). [E] 3
    reverse_torque_ratio : float
        Torque on extraction (reverse rotation: chip root shearing and flank friction) relative
        to the cutting torque [-]. [E] 0.3
    tool_number : int
        T number. [E] 3
    """

    diameter_mm: float = 8.0
    pitch_mm: float = 1.25
    chamfer_threads: float = 3.0
    reverse_torque_ratio: float = 0.3
    tool_number: int = 3


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
        physics-and-performance.md §3)
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
