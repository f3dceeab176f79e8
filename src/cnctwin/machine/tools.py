"""Cutting-tool descriptions: the geometry of the thesis tools.

Descriptions, like the machine's (:mod:`cnctwin.machine.description`): the simulator cuts with
them (:mod:`cnctwin.sim.tool` adds the wear curve and the tool-tip temperature) and the
analyses read them (hole quality: the drill's stiffness and point geometry) without importing
the simulator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["Drill", "EndMill", "Tap"]


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
