"""Cutting process models: drilling (Kienzle), end milling (mechanistic), rigid tapping.

Pure functions of the kinematics; each returns a :class:`CuttingLoad` (spindle load torque and
the forces on the tool). Material constants are data (:data:`MATERIALS`); the drilling constants
are *fitted* to the thesis dynamometer means (Table 4.1 and §4.3) with :func:`fit_kienzle`.

Sign conventions
----------------
* ``torque_nm``: load torque on the spindle, positive brakes positive (M3) rotation.
* ``thrust_n``: axial force of the workpiece on the tool, positive pushes the tool up (+Z).
* ``fx_n``, ``fy_n``: lateral force of the workpiece on the tool in machine X/Y [N].
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cnctwin.exceptions import ConfigError
from cnctwin.sim.tool import Drill, EndMill, Tap, first_order_recursion

__all__ = [
    "MATERIALS",
    "MILLING_CHIP_RANGE_MM",
    "THESIS_DRILLING_CUTS",
    "CuttingLoad",
    "DrillingModel",
    "KienzleFit",
    "Material",
    "MeanMillingLoad",
    "MillingCoefficients",
    "arc_integrals",
    "cycle_mean_milling_load",
    "drill_thrust_n",
    "drill_torque_nm",
    "drilling_load",
    "fit_kienzle",
    "get_material",
    "kienzle_kc",
    "lip_height_difference_um",
    "max_chip_factor",
    "mean_milling_load",
    "milling_from_kienzle",
    "milling_load",
    "rotating_force_n",
    "tapping_load",
    "wear_factor",
]


@dataclass(frozen=True)
class MillingCoefficients:
    """Mechanistic milling coefficients (linear edge-force model, Altintas).

    Attributes
    ----------
    ktc_n_per_mm2, krc_n_per_mm2, kac_n_per_mm2 : float
        Cutting coefficients, tangential / radial / axial [N/mm^2].
    kte_n_per_mm, kre_n_per_mm, kae_n_per_mm : float
        Edge (rubbing) coefficients [N/mm].
    """

    ktc_n_per_mm2: float
    krc_n_per_mm2: float
    kac_n_per_mm2: float
    kte_n_per_mm: float
    kre_n_per_mm: float
    kae_n_per_mm: float


@dataclass(frozen=True)
class Material:
    """Workpiece material.

    Attributes
    ----------
    name : str
        Key in :data:`MATERIALS`.
    kc1_n_per_mm2 : float
        Kienzle specific cutting force for h = b = 1 mm, kc1.1 [N/mm^2].
    mc : float
        Kienzle exponent [-].
    speed_exponent : float
        Cutting-speed correction kc x (v_ref / vc)^z [-]. [E] 0.1 (carbide)
    ref_speed_m_per_min : float
        v_ref of the speed correction [m/min]. [E] 100
    thrust_factor : float
        kf in the feed-force formula Ff = 0.63 (D/2) f kc sin(kappa) kf [-]. [S] 1 (ISCAR)
    hardness_hb : float
        Brinell hardness [HB] (documentation; hardness changes scale kc).
    milling : MillingCoefficients or None
        Coefficients for :func:`milling_load`.
    """

    name: str
    kc1_n_per_mm2: float
    mc: float
    speed_exponent: float = 0.1
    ref_speed_m_per_min: float = 100.0
    thrust_factor: float = 1.0
    hardness_hb: float = 200.0
    milling: MillingCoefficients | None = None


THESIS_DRILLING_CUTS: tuple[tuple[str, float, float, float], ...] = (
    ("aisi1045", 2400.0, 0.16, 3.97),
    ("grey_cast_iron", 2400.0, 0.30, 3.99),
    ("aisi1045", 2800.0, 0.14, 3.37),
    ("grey_cast_iron", 3200.0, 0.40, 4.83),
    ("aisi1045", 3200.0, 0.125, 3.18),
)
"""Thesis dynamometer means (material, speed [rpm], feed [mm/rev], mean torque [Nm]), 8.5 mm
TiAlN carbide drill: §4.3 (steel 2400/0.16) and Table 4.1 (the other four)."""

_AL7050_MILLING = MillingCoefficients(2172.0, 850.0, 726.0, 17.3, 7.8, 6.7)

MATERIALS: dict[str, Material] = {
    # kc1/mc: minimax fit (fit_kienzle) to the three steel cuts of THESIS_DRILLING_CUTS, with
    # z = 0.1; the handbook start value is C45 annealed 1500 / 0.22 (ISCAR, VDI 3323).
    # milling: linear coefficients derived from the Kienzle law (see _MILLING_FROM_KIENZLE)
    "aisi1045": Material("aisi1045", kc1_n_per_mm2=1556.9, mc=0.21771, hardness_hb=190.0,
                         milling=MillingCoefficients(1931.0, 755.7, 645.4, 56.58, 25.51, 21.91)),
    # exact fit to the two cast-iron cuts; handbook GG ferritic/pearlitic 1150 / 0.20.
    "grey_cast_iron": Material(
        "grey_cast_iron",
        kc1_n_per_mm2=944.23,
        mc=0.23588,
        hardness_hb=180.0,
        thrust_factor=0.9,
        milling=MillingCoefficients(1189.3, 465.4, 397.5, 38.68, 17.44, 14.98),
    ),
    # Al7050-T7451: Kienzle pair [E] (wrought Al ~ 700 / 0.25); milling coefficients as
    # commonly quoted from Altintas, Manufacturing Automation (2nd ed.) for Al7050 [E: not
    # re-verified against the book in this project].
    "al7050": Material(
        "al7050",
        kc1_n_per_mm2=700.0,
        mc=0.25,
        hardness_hb=140.0,
        speed_exponent=0.0,
        milling=_AL7050_MILLING,
    ),
}
"""Workpiece materials by key.

The milling coefficients of ``aisi1045`` and ``grey_cast_iron`` are derived [D], not measured:
Ktc and Kte are the least-squares line through the material's Kienzle law kc1 h^(1 - mc) for
chip thicknesses 0.02-0.25 mm (the tangential force per unit width is Ktc h + Kte), and
Krc, Kac, Kre, Kae keep the ratios to Ktc and Kte of the Al7050 set (Krc/Ktc 0.39, Kac/Ktc
0.33, Kre/Kte 0.45, Kae/Kte 0.39). :func:`milling_from_kienzle` reproduces them. They are a
start: ``cnctwin calibrate material`` fits the user's own from their cuts.
"""

MILLING_CHIP_RANGE_MM: tuple[float, float] = (0.02, 0.25)
"""Chip-thickness range over which :func:`milling_from_kienzle` fits the line [mm]."""


def milling_from_kienzle(kc1_n_per_mm2: float, mc: float, *,
                         ratios_from: MillingCoefficients | None = None) -> MillingCoefficients:
    """Linear edge-force milling coefficients equivalent to a Kienzle law.

    Parameters
    ----------
    kc1_n_per_mm2 : float
        Kienzle kc1.1 [N/mm^2].
    mc : float
        Kienzle exponent [-].
    ratios_from : MillingCoefficients, optional
        Set whose radial and axial ratios (Krc/Ktc, Kac/Ktc, Kre/Kte, Kae/Kte) are kept;
        default the Al7050 set.

    Returns
    -------
    MillingCoefficients

    Notes
    -----
    Tangential force per unit width Ft/b = kc1 h^(1-mc) (Kienzle) is replaced by its
    least-squares line Ktc h + Kte over :data:`MILLING_CHIP_RANGE_MM` (100 points).
    """
    r = ratios_from if ratios_from is not None else _AL7050_MILLING
    h = np.linspace(*MILLING_CHIP_RANGE_MM, 100)
    ft = kc1_n_per_mm2 * h ** (1.0 - mc)
    ktc, kte = np.linalg.lstsq(np.c_[h, np.ones_like(h)], ft, rcond=None)[0]
    return MillingCoefficients(
        float(ktc), float(ktc * r.krc_n_per_mm2 / r.ktc_n_per_mm2),
        float(ktc * r.kac_n_per_mm2 / r.ktc_n_per_mm2), float(kte),
        float(kte * r.kre_n_per_mm / r.kte_n_per_mm), float(kte * r.kae_n_per_mm / r.kte_n_per_mm))


def get_material(material: str | Material) -> Material:
    """Look up a material by key (or pass a :class:`Material` through).

    Parameters
    ----------
    material : str or Material
        A name in :data:`MATERIALS` or a :class:`Material` (returned as is).

    Returns
    -------
    Material
    """
    if isinstance(material, Material):
        return material
    try:
        return MATERIALS[material.lower()]
    except KeyError:
        raise ConfigError(
            f"unknown material {material!r}; known: {sorted(MATERIALS)} "
            "(or pass a cnctwin.sim.cutting.Material)"
        ) from None


def kienzle_kc(h_mm: ArrayLike, *, kc1_n_per_mm2: float, mc: float) -> NDArray[np.float64]:
    """Kienzle specific cutting force kc = kc1.1 h^-mc [N/mm^2] (h clipped at 1 um).

    Parameters
    ----------
    h_mm : array-like
        Uncut chip thickness h [mm] (clipped at 1 µm).
    kc1_n_per_mm2 : float
        Specific cutting force at h = 1 mm [N/mm²].
    mc : float
        Kienzle exponent [-].

    Returns
    -------
    numpy.ndarray
        kc [N/mm²].
    """
    h = np.maximum(np.asarray(h_mm, dtype=np.float64), 1e-3)
    return np.asarray(kc1_n_per_mm2 * h ** (-mc), dtype=np.float64)


def _kc_drill(
    feed_mm_per_rev: NDArray[np.float64], speed_rpm: NDArray[np.float64], drill: Drill, m: Material
) -> NDArray[np.float64]:
    s = math.sin(drill.kappa_rad)
    h = feed_mm_per_rev / 2.0 * s
    kc = kienzle_kc(h, kc1_n_per_mm2=m.kc1_n_per_mm2, mc=m.mc)
    vc = np.maximum(math.pi * drill.diameter_mm * np.abs(speed_rpm) / 1000.0, 1.0)
    return np.asarray(kc * (m.ref_speed_m_per_min / vc) ** m.speed_exponent, dtype=np.float64)


def wear_factor(
    feed_mm_per_rev: ArrayLike,
    wear_um: ArrayLike,
    *,
    edge_radius_mm: float = 0.01,
    gain: float = 1.0,
) -> NDArray[np.float64]:
    """Torque/thrust multiplier for flank wear, Subramanian & Cook shape.

    M = 0.125 HB d^2 f + 0.289 HB d^2 r + 0.0487 HB d^2 w, so
    M(w)/M(0) = 1 + gain 0.0487 w / (0.125 f + 0.289 r)  (w, f, r in mm).

    Parameters
    ----------
    feed_mm_per_rev : array-like
        Feed f [mm/rev].
    wear_um : array-like
        Average flank wear w [um].
    edge_radius_mm : float, default 0.01
        Edge radius r [mm].
    gain : float, default 1
        Calibration of the magnitude (1 = HSS/cast-iron values of the 1977 paper).

    Returns
    -------
    numpy.ndarray
        M(w) / M(0) [-].
    """
    f = np.maximum(np.asarray(feed_mm_per_rev, dtype=np.float64), 1e-3)
    w = np.maximum(np.asarray(wear_um, dtype=np.float64), 0.0) / 1000.0
    return np.asarray(1.0 + gain * 0.0487 * w / (0.125 * f + 0.289 * edge_radius_mm))


@dataclass(frozen=True)
class DrillingModel:
    """Secondary drilling effects (all [E] unless stated).

    Attributes
    ----------
    torque_wear_gain, thrust_wear_gain : float
        ``gain`` of :func:`wear_factor` for torque and thrust; carbide/TiAlN is less sensitive
        than the HSS tools of Subramanian & Cook: torque x1.28, thrust x1.57 at 277 um, f 0.167.
    chip_evacuation_per_diameter : float
        Relative torque growth per drill diameter of depth beyond 1 D (chip packing). 0.02
    margin_torque_nm : float
        Margin rubbing torque while the body is in the hole and not cutting (dwell,
        retract) [Nm]. 0.05
    fluctuation : float
        Relative std of the random torque/thrust fluctuation (AR(1), ~5 ms correlation). 0.03
    lip_ripple : float
        Relative amplitude of the lip-pass (flutes x rotation) ripple. 0.02
    walk_force_ratio_new, walk_force_ratio_worn : float
        Static lateral force / thrust for a new tool and at ``walk_wear_ref_um`` (lip
        asymmetry grows with wear -> straightness error, thesis §5.3).
        0.01, 0.06
    lip_height_difference_um : float
        Axial lip-height difference delta of the new (reground) drill [um]; with two lips
        the chip thicknesses are f/2 + delta and f/2 - delta (derivation in Notes of
        :func:`rotating_force_n`). [E] 8 (precision carbide drills: a few um to ~20 um)
    wear_asymmetry : float
        Fraction of the flank wear VB by which one lip wears more than the other [-];
        the edge recedes by VB tan(alpha) along the feed, so delta grows by
        ``wear_asymmetry`` VB tan(alpha). [E] 0.2
    clearance_angle_deg : float
        Lip clearance angle alpha [deg]. [E] 8 (typical carbide twist drill 6-12)
    lip_thrust_share : float
        Share of the thrust produced by the two lips (the rest by the chisel edge) [-].
        [S] the chisel edge gives roughly half of the drilling thrust (Shaw & Oxford 1957;
        Stephenson & Agapiou, Metal Cutting Theory and Practice, ch. 8); 0.5
    entry_force_ratio : float
        Peak lateral force / full-engagement thrust while the chisel edge skids on the
        surface before the point is centred (0 < z < point length), new tool [-]; it grows
        like the walk with wear (x (1 + ``entry_wear_gain`` VB/``walk_wear_ref_um``)) and
        acts in a random direction per hole. [E] 0.03
    entry_wear_gain : float
        Growth of the entry force with wear (chisel-edge wear) [-]. [E] 1.0
    walk_wear_ref_um : float
        Wear at which ``walk_force_ratio_worn`` applies [um]. 277
    tool_temp_torque_coeff_per_k : float
        Relative torque change per kelvin of tool-tip temperature rise above 25 degC (margin
        friction with the hot tool: thesis §5.1 sees the current rise at the end of each set of
        6). 1e-4
    """

    torque_wear_gain: float = 0.5
    thrust_wear_gain: float = 1.0
    chip_evacuation_per_diameter: float = 0.02
    margin_torque_nm: float = 0.05
    fluctuation: float = 0.03
    lip_ripple: float = 0.02
    walk_force_ratio_new: float = 0.01
    walk_force_ratio_worn: float = 0.06
    lip_height_difference_um: float = 8.0
    wear_asymmetry: float = 0.2
    clearance_angle_deg: float = 8.0
    lip_thrust_share: float = 0.5
    entry_force_ratio: float = 0.03
    entry_wear_gain: float = 1.0
    walk_wear_ref_um: float = 277.0
    tool_temp_torque_coeff_per_k: float = 1e-4


def drill_torque_nm(
    feed_mm_per_rev: ArrayLike,
    speed_rpm: ArrayLike,
    *,
    drill: Drill | None = None,
    material: str | Material = "aisi1045",
    wear_um: ArrayLike = 0.0,
    hardness_factor: ArrayLike = 1.0,
    model: DrillingModel | None = None,
) -> NDArray[np.float64]:
    """Mean drilling torque at full engagement [Nm].

    Parameters
    ----------
    feed_mm_per_rev : array-like
        Feed f [mm/rev].
    speed_rpm : array-like
        Spindle speed [rpm] (speed correction of kc).
    drill : Drill, optional
        Tool geometry; default :class:`Drill`.
    material : str or Material, default 'aisi1045'
        Workpiece material (name in :data:`MATERIALS` or a :class:`Material`).
    wear_um : array-like, default 0.0
        Flank wear VB [µm].
    hardness_factor : array-like, default 1.0
        Multiplier on kc (a harder batch).
    model : DrillingModel, optional
        Drilling model constants; default :class:`DrillingModel`.

    Returns
    -------
    numpy.ndarray
        Mean cutting torque at full engagement [Nm].

    Notes
    -----
    Mc = f kc D^2 sin(kappa) / 8000 (ISCAR), kc = kc1.1 h^-mc (v_ref/vc)^z, h = (f/2) sin(kappa)
    (docs/reference/physics-and-performance.md §3), times :func:`wear_factor` and
    ``hardness_factor``.
    """
    d = drill if drill is not None else Drill()
    m = get_material(material)
    mdl = model if model is not None else DrillingModel()
    f = np.maximum(np.asarray(feed_mm_per_rev, dtype=np.float64), 0.0)
    n = np.asarray(speed_rpm, dtype=np.float64)
    kc = _kc_drill(np.maximum(f, 1e-3), n, d, m)
    mc = f * kc * d.diameter_mm**2 * math.sin(d.kappa_rad) / 8000.0
    wf = wear_factor(f, wear_um, edge_radius_mm=d.edge_radius_mm, gain=mdl.torque_wear_gain)
    return np.asarray(mc * wf * np.asarray(hardness_factor, dtype=np.float64))


def drill_thrust_n(
    feed_mm_per_rev: ArrayLike,
    speed_rpm: ArrayLike,
    *,
    drill: Drill | None = None,
    material: str | Material = "aisi1045",
    wear_um: ArrayLike = 0.0,
    hardness_factor: ArrayLike = 1.0,
    model: DrillingModel | None = None,
) -> NDArray[np.float64]:
    """Mean drilling thrust (feed force) at full engagement [N].

    Parameters
    ----------
    feed_mm_per_rev : array-like
        Feed f [mm/rev].
    speed_rpm : array-like
        Spindle speed [rpm] (speed correction of kc).
    drill : Drill, optional
        Tool geometry; default :class:`Drill`.
    material : str or Material, default 'aisi1045'
        Workpiece material (name in :data:`MATERIALS` or a :class:`Material`).
    wear_um : array-like, default 0.0
        Flank wear VB [µm].
    hardness_factor : array-like, default 1.0
        Multiplier on kc (a harder batch).
    model : DrillingModel, optional
        Drilling model constants; default :class:`DrillingModel`.

    Returns
    -------
    numpy.ndarray
        Mean thrust at full engagement [N].

    Notes
    -----
    Ff = 0.63 (D/2) f kc sin(kappa) kf (ISCAR), same kc as :func:`drill_torque_nm`; the chisel
    edge contribution is included in the 0.63 factor of the handbook formula.
    """
    d = drill if drill is not None else Drill()
    m = get_material(material)
    mdl = model if model is not None else DrillingModel()
    f = np.maximum(np.asarray(feed_mm_per_rev, dtype=np.float64), 0.0)
    n = np.asarray(speed_rpm, dtype=np.float64)
    kc = _kc_drill(np.maximum(f, 1e-3), n, d, m)
    ff = 0.63 * (d.diameter_mm / 2.0) * f * kc * math.sin(d.kappa_rad) * m.thrust_factor
    wf = wear_factor(f, wear_um, edge_radius_mm=d.edge_radius_mm, gain=mdl.thrust_wear_gain)
    return np.asarray(ff * wf * np.asarray(hardness_factor, dtype=np.float64))


def lip_height_difference_um(
    wear_um: ArrayLike, *, model: DrillingModel | None = None
) -> NDArray[np.float64]:
    """Effective axial lip-height difference delta of a drill with flank wear VB [um].

    Parameters
    ----------
    wear_um : array-like
        Flank wear VB [µm].
    model : DrillingModel, optional
        Drilling model constants (new-drill difference, wear asymmetry, clearance angle).

    Returns
    -------
    numpy.ndarray
        Lip-height difference [µm].

    Notes
    -----
    delta = delta_0 + q VB tan(alpha): the lip that wears more by q VB (``wear_asymmetry``)
    loses VB tan(alpha) of height along the feed (alpha = clearance angle).
    """
    mdl = model if model is not None else DrillingModel()
    w = np.maximum(np.asarray(wear_um, dtype=np.float64), 0.0)
    return np.asarray(mdl.lip_height_difference_um + mdl.wear_asymmetry * w
                      * math.tan(math.radians(mdl.clearance_angle_deg)), dtype=np.float64)


def rotating_force_n(
    thrust_n: ArrayLike,
    feed_mm_per_rev: ArrayLike,
    wear_um: ArrayLike = 0.0,
    *,
    drill: Drill | None = None,
    model: DrillingModel | None = None,
) -> NDArray[np.float64]:
    """Amplitude of the lateral force rotating with the spindle (unequal lips) [N].

    Parameters
    ----------
    thrust_n : array-like
        Drilling thrust [N].
    feed_mm_per_rev : array-like
        Feed per revolution f [mm/rev].
    wear_um : array-like, default 0
        Flank wear VB [um] (:func:`lip_height_difference_um`).
    drill : Drill, optional
        Point angle (kappa = point angle / 2).
    model : DrillingModel, optional
        Lip-height difference, wear asymmetry, lip share of the thrust.

    Returns
    -------
    numpy.ndarray
        Force amplitude [N].

    Notes
    -----
    Two lips, lip 1 ahead by delta: chip thicknesses h1 = f/2 + delta, h2 = f/2 - delta
    (h1 - h2 = 2 delta, clipped at f: one lip cuts alone). The force normal to a lip in the
    axial plane has the axial part N sin(kappa) and the radial part N cos(kappa); the axial
    parts add up to the lip thrust s F_z (s = ``lip_thrust_share``), the radial parts cancel
    but for the chip-thickness difference:

        F_rot = s F_z cot(kappa) (h1 - h2) / (h1 + h2) = s F_z cot(kappa) min(2 delta / f, 1)

    It is fixed to the tool, so in the machine frame it turns at the spindle frequency.
    Example: F_z = 1000 N, f = 0.167 mm, kappa = 70 deg, delta = 8 um: F_rot = 17 N; at
    VB = 277 um (delta 15.8 um, thrust x1.57): 54 N.
    """
    d = drill if drill is not None else Drill()
    mdl = model if model is not None else DrillingModel()
    fz = np.abs(np.asarray(thrust_n, dtype=np.float64))
    f = np.maximum(np.asarray(feed_mm_per_rev, dtype=np.float64), 1e-6)
    delta_mm = lip_height_difference_um(wear_um, model=mdl) / 1000.0
    ratio = np.minimum(2.0 * delta_mm / f, 1.0)
    return np.asarray(mdl.lip_thrust_share * fz * ratio / math.tan(d.kappa_rad),
                      dtype=np.float64)


@dataclass(frozen=True)
class CuttingLoad:
    """Process load per sample (signs: module docstring).

    Attributes
    ----------
    torque_nm : numpy.ndarray
        Spindle load torque [Nm].
    thrust_n : numpy.ndarray
        Axial force on the tool, + pushes the tool up [N].
    fx_n, fy_n : numpy.ndarray
        Lateral forces on the tool in machine X and Y [N].
    engagement : numpy.ndarray
        Fraction of the cutting edges engaged (0..1) [-].
    """

    torque_nm: NDArray[np.float64]
    thrust_n: NDArray[np.float64]
    fx_n: NDArray[np.float64]
    fy_n: NDArray[np.float64]
    engagement: NDArray[np.float64]

    @staticmethod
    def zeros(n: int) -> CuttingLoad:
        """No load for ``n`` samples."""
        return CuttingLoad(*(np.zeros(n) for _ in range(5)))


def _ar1(noise: NDArray[np.float64], a: float) -> NDArray[np.float64]:
    """Unit-variance AR(1) filter of white noise (no state across calls)."""
    return first_order_recursion(noise, a, b0=math.sqrt(1.0 - a * a))


def drilling_load(
    tip_depth_mm: ArrayLike,
    speed_rpm: ArrayLike,
    feed_mm_per_rev: ArrayLike,
    *,
    drill: Drill | None = None,
    material: str | Material = "aisi1045",
    wear_um: ArrayLike = 0.0,
    hardness_factor: ArrayLike = 1.0,
    exit_depth_mm: float | None = None,
    spindle_angle_rad: ArrayLike | None = None,
    tool_temperature_c: ArrayLike | None = None,
    walk_direction_rad: float = 0.0,
    entry_direction_rad: ArrayLike = 0.0,
    model: DrillingModel | None = None,
    rng: np.random.Generator | None = None,
    dt_s: float = 0.002,
) -> CuttingLoad:
    """Drilling load per sample from the tip depth and the kinematics.

    Parameters
    ----------
    tip_depth_mm : array-like
        Depth of the drill tip below the entry surface (<= 0: outside the workpiece) [mm].
    speed_rpm : array-like
        Spindle speed [rpm].
    feed_mm_per_rev : array-like
        Instantaneous feed per revolution, positive into the workpiece [mm/rev]; <= 0 (dwell,
        peck retract, withdrawal) cuts nothing, only the margins rub.
    drill : Drill, optional
        Tool; default the thesis 8.5 mm drill.
    material : str or Material, default 'aisi1045'
        Workpiece material.
    wear_um : array-like, default 0
        Flank wear [um].
    hardness_factor : array-like, default 1
        Multiplier on kc (hardness variation, :class:`~cnctwin.sim.faults.HardnessChange`).
    exit_depth_mm : float, optional
        Plate thickness for through holes: beyond it the point breaks out; default blind hole.
    spindle_angle_rad : array-like, optional
        Spindle angle for the lip-pass ripple and the rotating lateral force.
    tool_temperature_c : array-like, optional
        Tool-tip temperature (see :class:`DrillingModel`) [degC].
    walk_direction_rad : float, default 0
        Direction of the static lateral (walk) force in the XY plane [rad].
    entry_direction_rad : array-like, default 0
        Direction of the chisel-edge entry force per sample (one value per hole) [rad].
    model : DrillingModel, optional
        Secondary effects.
    rng : numpy.random.Generator, optional
        Source of the random fluctuation; ``None`` = no fluctuation.
    dt_s : float, default 0.002
        Sample interval (for the fluctuation correlation time) [s].

    Returns
    -------
    CuttingLoad

    Notes
    -----
    Entry: over the point length L = (D/2)/tan(kappa) the engaged radius is r = z tan(kappa);
    torque scales with (r/R)^2 (moment of a uniform lip load), thrust with r/R. Break-out (through
    holes) removes the inner part the same way. Mean torque and thrust at full engagement come
    from :func:`drill_torque_nm` / :func:`drill_thrust_n`.

    Lateral forces on the tool (machine X/Y): (1) the force rotating with the spindle from the
    lip-height difference, :func:`rotating_force_n` (1x spindle frequency, 40 Hz at 2400 rpm);
    (2) the chisel-edge entry force F_e = ratio (1 + g VB/VB_ref) F_full 4 u (1 - u),
    u = z / L_point, in ``entry_direction_rad`` (skidding until the point is centred);
    (3) the static walk ratio(VB) x thrust in ``walk_direction_rad``.
    """
    d = drill if drill is not None else Drill()
    m = get_material(material)
    mdl = model if model is not None else DrillingModel()
    z = np.atleast_1d(np.asarray(tip_depth_mm, dtype=np.float64))
    nsz = z.size
    n = np.broadcast_to(np.asarray(speed_rpm, dtype=np.float64), (nsz,))
    f = np.broadcast_to(np.asarray(feed_mm_per_rev, dtype=np.float64), (nsz,))
    wear = np.broadcast_to(np.asarray(wear_um, dtype=np.float64), (nsz,))
    hard = np.broadcast_to(np.asarray(hardness_factor, dtype=np.float64), (nsz,))
    radius = d.diameter_mm / 2.0
    tan_k = math.tan(d.kappa_rad)
    r_out = np.clip(z * tan_k, 0.0, radius) / radius
    if exit_depth_mm is not None:
        r_in = np.clip((z - exit_depth_mm) * tan_k, 0.0, radius) / radius
    else:
        r_in = np.zeros(nsz)
    eng_torque = r_out**2 - r_in**2
    eng_thrust = r_out - r_in
    cutting = f > 0.0
    m_full = drill_torque_nm(
        f, n, drill=d, material=m, wear_um=wear, hardness_factor=hard, model=mdl
    )
    f_full = drill_thrust_n(
        f, n, drill=d, material=m, wear_um=wear, hardness_factor=hard, model=mdl
    )
    depth_beyond = np.maximum(z - d.diameter_mm, 0.0) / d.diameter_mm
    chip = 1.0 + mdl.chip_evacuation_per_diameter * depth_beyond
    if tool_temperature_c is not None:
        tt = np.broadcast_to(np.asarray(tool_temperature_c, dtype=np.float64), (nsz,))
        chip = chip * (1.0 + mdl.tool_temp_torque_coeff_per_k * np.maximum(tt - 25.0, 0.0))
    fluct = np.ones(nsz)
    fluct_f = np.ones(nsz)
    if rng is not None and mdl.fluctuation > 0:
        a = math.exp(-dt_s / 0.005)
        w = rng.standard_normal((nsz, 2))
        fluct = 1.0 + mdl.fluctuation * _ar1(w[:, 0], a)
        fluct_f = 1.0 + mdl.fluctuation * _ar1(w[:, 1], a)
    ang = None
    if spindle_angle_rad is not None:
        ang = np.broadcast_to(np.asarray(spindle_angle_rad, dtype=np.float64), (nsz,))
        fluct = fluct + mdl.lip_ripple * np.sin(d.flutes * ang)
    inside = z > 0.0
    torque = np.where(cutting, m_full * eng_torque * chip * fluct, 0.0)
    # margin rubbing is part of the fitted cutting torque; alone it shows while not cutting
    rub = inside & ~cutting & (z > d.cone_length_mm)
    torque = torque + np.where(rub, mdl.margin_torque_nm, 0.0)
    torque = torque * np.sign(np.where(n == 0.0, 1.0, n))
    thrust = np.where(cutting, f_full * eng_thrust * fluct_f, 0.0)
    wear_rel = np.clip(wear / mdl.walk_wear_ref_um, 0.0, 2.0)
    walk = mdl.walk_force_ratio_new + (mdl.walk_force_ratio_worn - mdl.walk_force_ratio_new) * (
        wear_rel
    )
    # static walk, rising with the thrust while the point enters
    lat = walk * thrust
    fx = lat * math.cos(walk_direction_rad)
    fy = lat * math.sin(walk_direction_rad)
    # chisel-edge skid at entry: bump over the point length, random direction per hole
    cone = d.cone_length_mm
    zc = np.clip(z / cone, 0.0, 1.0)
    bump = np.where(cutting & (z > 0.0) & (z < cone), 4.0 * zc * (1.0 - zc), 0.0)
    ent = (mdl.entry_force_ratio * (1.0 + mdl.entry_wear_gain * wear_rel) * f_full * bump
           * (1.0 - r_in))
    edir = np.broadcast_to(np.asarray(entry_direction_rad, dtype=np.float64), (nsz,))
    fx = fx + ent * np.cos(edir)
    fy = fy + ent * np.sin(edir)
    if ang is not None:
        rot = rotating_force_n(thrust, f, wear, drill=d, model=mdl)
        fx = fx + rot * np.cos(ang)
        fy = fy + rot * np.sin(ang)
    return CuttingLoad(
        torque_nm=np.asarray(torque, dtype=np.float64),
        thrust_n=np.asarray(thrust, dtype=np.float64),
        fx_n=np.asarray(fx, dtype=np.float64),
        fy_n=np.asarray(fy, dtype=np.float64),
        engagement=np.where(cutting | inside, eng_torque, 0.0).astype(np.float64),
    )


def milling_load(
    spindle_angle_rad: ArrayLike,
    feed_per_tooth_mm: ArrayLike,
    axial_depth_mm: ArrayLike,
    feed_direction_rad: ArrayLike,
    *,
    tool: EndMill | None = None,
    material: str | Material = "al7050",
    entry_angle_rad: ArrayLike = 0.0,
    exit_angle_rad: ArrayLike = math.pi,
    hardness_factor: ArrayLike = 1.0,
) -> CuttingLoad:
    """End-milling forces from the tool engagement (zero-helix mechanistic model).

    Parameters
    ----------
    spindle_angle_rad : array-like
        Angle of tooth 1 measured clockwise from the +y axis of the feed frame [rad].
    feed_per_tooth_mm : array-like
        Instantaneous feed per tooth v_f / (n z) [mm]; 0 = not cutting.
    axial_depth_mm : array-like
        Axial depth of cut a [mm]; 0 = out of the workpiece.
    feed_direction_rad : array-like
        Direction of the feed in machine XY (atan2(vy, vx)) [rad].
    tool : EndMill, optional
        Default 16 mm, 2 flutes.
    material : str or Material, default 'al7050'
        Needs ``milling`` coefficients.
    entry_angle_rad, exit_angle_rad : array-like
        Immersion [rad], scalars or one per sample (the Z-map's
        :class:`~cnctwin.engagement.Engagement`); 0 .. pi is a full slot, NaN cuts nothing.
    hardness_factor : array-like, default 1
        Multiplier on all coefficients.

    Returns
    -------
    CuttingLoad
        ``thrust_n`` is the axial force.

    Notes
    -----
    Per engaged tooth (Altintas, Manufacturing Automation, ch. 2): h = c sin(phi),
    Ft = a (Ktc h + Kte), Fr = a (Krc h + Kre), Fa = a (Kac h + Kae);
    feed frame Fx = -Ft cos(phi) - Fr sin(phi), Fy = Ft sin(phi) - Fr cos(phi);
    spindle torque T = sum Ft D/2.
    """
    t = tool if tool is not None else EndMill()
    m = get_material(material)
    if m.milling is None:
        raise ConfigError(
            f"material {m.name!r} has no milling coefficients; use 'al7050' or "
            "give Material(milling=MillingCoefficients(...))"
        )
    k = m.milling
    ang = np.atleast_1d(np.asarray(spindle_angle_rad, dtype=np.float64))
    nsz = ang.size
    c = np.broadcast_to(np.asarray(feed_per_tooth_mm, dtype=np.float64), (nsz,))
    a = np.broadcast_to(np.asarray(axial_depth_mm, dtype=np.float64), (nsz,))
    th = np.broadcast_to(np.asarray(feed_direction_rad, dtype=np.float64), (nsz,))
    hard = np.broadcast_to(np.asarray(hardness_factor, dtype=np.float64), (nsz,))
    p_in = np.broadcast_to(np.asarray(entry_angle_rad, dtype=np.float64), (nsz,))
    p_out = np.broadcast_to(np.asarray(exit_angle_rad, dtype=np.float64), (nsz,))
    active = (c > 0.0) & (a > 0.0)
    fx = np.zeros(nsz)
    fy = np.zeros(nsz)
    fa = np.zeros(nsz)
    torque = np.zeros(nsz)
    eng = np.zeros(nsz)
    for j in range(t.flutes):
        phi = np.mod(ang + 2.0 * math.pi * j / t.flutes, 2.0 * math.pi)
        inside = active & (phi >= p_in) & (phi <= p_out)
        h = np.where(inside, c * np.sin(phi), 0.0)
        on = inside.astype(np.float64)
        ft = a * (k.ktc_n_per_mm2 * h + k.kte_n_per_mm * on) * hard
        fr = a * (k.krc_n_per_mm2 * h + k.kre_n_per_mm * on) * hard
        fa = fa + a * (k.kac_n_per_mm2 * h + k.kae_n_per_mm * on) * hard
        fx = fx - ft * np.cos(phi) - fr * np.sin(phi)
        fy = fy + ft * np.sin(phi) - fr * np.cos(phi)
        torque = torque + ft * t.diameter_mm / 2000.0
        eng = eng + on / t.flutes
    cos_t, sin_t = np.cos(th), np.sin(th)
    return CuttingLoad(
        torque_nm=torque,
        thrust_n=fa,
        fx_n=fx * cos_t - fy * sin_t,
        fy_n=fx * sin_t + fy * cos_t,
        engagement=eng,
    )


def arc_integrals(start_rad: ArrayLike, end_rad: ArrayLike
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64],
                             NDArray[np.float64], NDArray[np.float64]]:
    """The integrals of the tooth-angle functions of the edge-force model over u..v.

    Parameters
    ----------
    start_rad, end_rad : array-like
        The arc u..v of tooth angles [rad].

    Returns
    -------
    tuple of numpy.ndarray
        ``(v - u, int sin, int cos, int sin^2, int sin cos)`` =
        ``(v - u, cos u - cos v, sin v - sin u, (v - u)/2 - (sin 2v - sin 2u)/4,
        (sin^2 v - sin^2 u)/2)``.
    """
    u = np.asarray(start_rad, dtype=np.float64)
    v = np.asarray(end_rad, dtype=np.float64)
    return (v - u, np.cos(u) - np.cos(v), np.sin(v) - np.sin(u),
            (v - u) / 2.0 - (np.sin(2.0 * v) - np.sin(2.0 * u)) / 4.0,
            (np.sin(v) ** 2 - np.sin(u) ** 2) / 2.0)


def cycle_mean_milling_load(
    spindle_angle_rad: ArrayLike,
    angle_step_rad: ArrayLike,
    feed_per_tooth_mm: ArrayLike,
    axial_depth_mm: ArrayLike,
    feed_direction_rad: ArrayLike,
    *,
    tool: EndMill | None = None,
    material: str | Material = "al7050",
    entry_angle_rad: ArrayLike = 0.0,
    exit_angle_rad: ArrayLike = math.pi,
    hardness_factor: ArrayLike = 1.0,
) -> CuttingLoad:
    """:func:`milling_load` integrated over each control cycle's rotation, in closed form.

    A two-flute cutter at 3000 rpm turns 36 deg per 2 ms cycle, in step with the cycle:
    evaluated at the cycle's end angle, the interrupted cut is seen at five fixed tooth
    phases only, and the mean of a partial immersion is off by up to tens of percent. The
    drive integrates the load over the cycle; so does this function, exactly (the integrals
    of sin, cos, sin^2 and sin cos of the tooth angle over the part of the cycle's rotation
    that lies in the engagement), for a feed per tooth, depth and immersion constant within
    the cycle.

    Parameters
    ----------
    spindle_angle_rad : array-like
        Angle of tooth 1 at the end of each cycle (convention of :func:`milling_load`) [rad].
    angle_step_rad : array-like
        Rotation during the cycle, |n| 2 pi dt / 60 [rad] (0: the instantaneous load).
    feed_per_tooth_mm, axial_depth_mm, feed_direction_rad : array-like
        As in :func:`milling_load`.
    tool : EndMill, optional
        Default 16 mm, 2 flutes.
    material : str or Material, default 'al7050'
        Needs ``milling`` coefficients.
    entry_angle_rad, exit_angle_rad : array-like
        Immersion per cycle [rad] (NaN: not engaged).
    hardness_factor : array-like, default 1
        Multiplier on all coefficients.

    Returns
    -------
    CuttingLoad
        The cycle means; ``engagement`` is the mean fraction of the teeth engaged.
    """
    t = tool if tool is not None else EndMill()
    m = get_material(material)
    if m.milling is None:
        raise ConfigError(f"material {m.name!r} has no milling coefficients; give "
                          "Material(milling=MillingCoefficients(...))")
    k = m.milling
    end = np.atleast_1d(np.asarray(spindle_angle_rad, dtype=np.float64))
    nsz = end.size

    def arr(x: ArrayLike) -> NDArray[np.float64]:
        return np.broadcast_to(np.asarray(x, dtype=np.float64), (nsz,))

    step, c, a, th = arr(angle_step_rad), arr(feed_per_tooth_mm), arr(axial_depth_mm), arr(
        feed_direction_rad)
    hard = arr(hardness_factor)
    p0, p1 = arr(entry_angle_rad), arr(exit_angle_rad)
    active = (c > 0.0) & (a > 0.0) & np.isfinite(p0) & np.isfinite(p1) & (p1 > p0)
    inst = step <= 1e-12
    if inst.any():  # no rotation: the instantaneous load
        li = milling_load(end[inst], c[inst], a[inst], th[inst], tool=t, material=m,
                          entry_angle_rad=p0[inst], exit_angle_rad=p1[inst],
                          hardness_factor=hard[inst])
    p0 = np.where(active, p0, 0.0)
    p1 = np.where(active, p1, 0.0)
    st = np.where(inst, 1.0, step)
    two_pi = 2.0 * math.pi
    i1 = np.zeros(nsz)
    isn = np.zeros(nsz)
    ics = np.zeros(nsz)
    is2 = np.zeros(nsz)
    isc = np.zeros(nsz)
    for j in range(t.flutes):
        e = np.mod(end + two_pi * j / t.flutes, two_pi)
        s = e - st  # the tooth swept s..e during the cycle (s may be < 0)
        for shift in (-two_pi, 0.0, two_pi):
            u = np.maximum(s, p0 + shift)
            v = np.minimum(e, p1 + shift)
            ok = active & (v > u)
            u = np.where(ok, u - shift, 0.0)
            v = np.where(ok, v - shift, 0.0)
            d1, dsn, dcs, ds2, dsc = arc_integrals(u, v)
            i1 += d1
            isn += dsn
            ics += dcs
            is2 += ds2
            isc += dsc
    g = a * hard / st
    torque = g * (k.ktc_n_per_mm2 * c * isn + k.kte_n_per_mm * i1) * t.diameter_mm / 2000.0
    fxf = -g * (k.ktc_n_per_mm2 * c * isc + k.kte_n_per_mm * ics
                + k.krc_n_per_mm2 * c * is2 + k.kre_n_per_mm * isn)
    fyf = g * (k.ktc_n_per_mm2 * c * is2 + k.kte_n_per_mm * isn
               - k.krc_n_per_mm2 * c * isc - k.kre_n_per_mm * ics)
    fa = g * (k.kac_n_per_mm2 * c * isn + k.kae_n_per_mm * i1)
    eng = i1 / st / t.flutes
    cos_t, sin_t = np.cos(th), np.sin(th)
    out = CuttingLoad(torque_nm=torque, thrust_n=fa, fx_n=fxf * cos_t - fyf * sin_t,
                      fy_n=fxf * sin_t + fyf * cos_t, engagement=eng)
    if inst.any():
        for name in ("torque_nm", "thrust_n", "fx_n", "fy_n", "engagement"):
            getattr(out, name)[inst] = getattr(li, name)
    return out


def max_chip_factor(entry_angle_rad: ArrayLike, exit_angle_rad: ArrayLike
                    ) -> NDArray[np.float64]:
    """Largest sin(phi) over the immersion ``entry..exit`` (chip thickness = c x this) [-].

    Parameters
    ----------
    entry_angle_rad, exit_angle_rad : array-like
        Immersion in the feed frame [rad] (0..pi; NaN gives NaN).

    Returns
    -------
    numpy.ndarray
        1 where the immersion contains pi/2, else the larger of sin(entry), sin(exit).
    """
    p0 = np.asarray(entry_angle_rad, dtype=np.float64)
    p1 = np.asarray(exit_angle_rad, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        return np.where((p0 <= math.pi / 2) & (p1 >= math.pi / 2), 1.0,
                        np.maximum(np.sin(p0), np.sin(p1)))


@dataclass(frozen=True)
class MeanMillingLoad:
    """Milling load averaged over a spindle revolution (what :func:`mean_milling_load` returns).

    Attributes
    ----------
    torque_nm : numpy.ndarray
        Mean spindle load torque [Nm].
    fx_n, fy_n : numpy.ndarray
        Mean force on the tool in machine X and Y [N].
    axial_n : numpy.ndarray
        Mean axial force on the tool (+ pushes the tool up) [N].
    peak_chip_mm : numpy.ndarray
        Largest uncut chip thickness c sin(phi) over the engaged arc [mm].
    """

    torque_nm: NDArray[np.float64]
    fx_n: NDArray[np.float64]
    fy_n: NDArray[np.float64]
    axial_n: NDArray[np.float64]
    peak_chip_mm: NDArray[np.float64]


def mean_milling_load(
    feed_per_tooth_mm: ArrayLike,
    axial_depth_mm: ArrayLike,
    entry_angle_rad: ArrayLike,
    exit_angle_rad: ArrayLike,
    *,
    feed_direction_rad: ArrayLike = 0.0,
    diameter_mm: float,
    flutes: int,
    coefficients: MillingCoefficients,
    hardness_factor: ArrayLike = 1.0,
) -> MeanMillingLoad:
    """Per-revolution mean of :func:`milling_load` in closed form (the tooth-passing average).

    Parameters
    ----------
    feed_per_tooth_mm : array-like
        Feed per tooth c [mm].
    axial_depth_mm : array-like
        Axial depth a [mm].
    entry_angle_rad, exit_angle_rad : array-like
        Immersion in the feed frame [rad] (0..pi full slot; NaN: not engaged, load 0).
    feed_direction_rad : array-like, default 0
        Direction of the feed in machine XY [rad].
    diameter_mm : float
        Tool diameter D [mm].
    flutes : int
        Teeth z.
    coefficients : MillingCoefficients
        Linear edge-force coefficients.
    hardness_factor : array-like, default 1
        Multiplier on all coefficients.

    Returns
    -------
    MeanMillingLoad

    Notes
    -----
    With the conventions of :func:`milling_load` and the integrals over phi_st..phi_ex of
    sin, cos, sin^2 and sin cos (Altintas, *Manufacturing Automation*, 2nd ed., eq. 2.47):
    T = z a R / (2 pi) [Ktc c (cos phi_st - cos phi_ex) + Kte (phi_ex - phi_st)],
    Fx_f = z a / (2 pi) [-Ktc c S2 - Kte Sc - Krc c Ss - Kre Sn],
    Fy_f = z a / (2 pi) [Ktc c Ss + Kte Sn - Krc c S2 - Kre Sc],
    Fa = z a / (2 pi) [Kac c Sn + Kae (phi_ex - phi_st)], with Sn = cos phi_st - cos phi_ex,
    Sc = sin phi_ex - sin phi_st, Ss = int sin^2, S2 = int sin cos. The mean is exact when
    the immersion is constant over the revolution.
    """
    c = np.asarray(feed_per_tooth_mm, dtype=np.float64)
    a = np.asarray(axial_depth_mm, dtype=np.float64)
    p0 = np.asarray(entry_angle_rad, dtype=np.float64)
    p1 = np.asarray(exit_angle_rad, dtype=np.float64)
    c, a, p0, p1, th, hard = np.broadcast_arrays(
        c, a, p0, p1, np.asarray(feed_direction_rad, dtype=np.float64),
        np.asarray(hardness_factor, dtype=np.float64))
    on = np.isfinite(p0) & np.isfinite(p1) & (p1 > p0) & (a > 0.0)
    p0 = np.where(on, p0, 0.0)
    p1 = np.where(on, p1, 0.0)
    a = np.where(on, a, 0.0)
    k = coefficients
    _, sn, sc, ss, s2 = arc_integrals(p0, p1)
    g = flutes * a * hard / (2.0 * math.pi)
    torque = g * (diameter_mm / 2000.0) * (k.ktc_n_per_mm2 * c * sn + k.kte_n_per_mm * (p1 - p0))
    fxf = g * (-k.ktc_n_per_mm2 * c * s2 - k.kte_n_per_mm * sc - k.krc_n_per_mm2 * c * ss
               - k.kre_n_per_mm * sn)
    fyf = g * (k.ktc_n_per_mm2 * c * ss + k.kte_n_per_mm * sn - k.krc_n_per_mm2 * c * s2
               - k.kre_n_per_mm * sc)
    fa = g * (k.kac_n_per_mm2 * c * sn + k.kae_n_per_mm * (p1 - p0))
    smax = max_chip_factor(p0, p1)
    ct, st = np.cos(th), np.sin(th)
    return MeanMillingLoad(
        torque_nm=torque, fx_n=fxf * ct - fyf * st, fy_n=fxf * st + fyf * ct, axial_n=fa,
        peak_chip_mm=np.where(on, c * smax, 0.0))


def tapping_load(
    tip_depth_mm: ArrayLike,
    speed_rpm: ArrayLike,
    *,
    tap: Tap | None = None,
    material: str | Material = "aisi1045",
    hardness_factor: ArrayLike = 1.0,
) -> CuttingLoad:
    """Rigid-tapping torque with reversal on extraction.

    Parameters
    ----------
    tip_depth_mm : array-like
        Depth of the tap tip below the surface [mm].
    speed_rpm : array-like
        Signed spindle speed: > 0 cutting (M3 into the hole), < 0 extraction [rpm].
    tap : Tap, optional
        Default M8x1.25.
    material : str or Material, default 'aisi1045'
        Workpiece.
    hardness_factor : array-like, default 1
        Multiplier on kc.

    Returns
    -------
    CuttingLoad
        Spindle torque [Nm] (its sign reverses on extraction), thrust [N] and engagement
        per sample.

    Notes
    -----
    Md = kc1.1 P^2 D / 8000 [Nm] (tap-maker rule with kc in N/mm^2, P and D in mm); the chamfer
    (``chamfer_threads`` x P) ramps the engagement in; on extraction the torque changes sign
    (reverse rotation) with ``reverse_torque_ratio`` of the cutting torque while any thread is
    engaged.
    """
    tp = tap if tap is not None else Tap()
    m = get_material(material)
    z = np.atleast_1d(np.asarray(tip_depth_mm, dtype=np.float64))
    nsz = z.size
    n = np.broadcast_to(np.asarray(speed_rpm, dtype=np.float64), (nsz,))
    hard = np.broadcast_to(np.asarray(hardness_factor, dtype=np.float64), (nsz,))
    md = m.kc1_n_per_mm2 * tp.pitch_mm**2 * tp.diameter_mm / 8000.0 * hard
    eng = np.clip(z / (tp.chamfer_threads * tp.pitch_mm), 0.0, 1.0)
    fwd = n > 0.0
    torque = np.where(fwd, md * eng, -tp.reverse_torque_ratio * md * eng)
    torque = np.where(z > 0.0, torque, 0.0)
    return CuttingLoad(
        torque_nm=np.asarray(torque, dtype=np.float64),
        thrust_n=np.zeros(nsz),
        fx_n=np.zeros(nsz),
        fy_n=np.zeros(nsz),
        engagement=eng.astype(np.float64),
    )


@dataclass(frozen=True)
class KienzleFit:
    """Result of :func:`fit_kienzle`.

    Attributes
    ----------
    kc1_n_per_mm2, mc : float
        Fitted constants.
    residuals_pct : numpy.ndarray
        Model / measured - 1 per point [%].
    """

    kc1_n_per_mm2: float
    mc: float
    residuals_pct: NDArray[np.float64]


def fit_kienzle(
    cuts: Sequence[tuple[float, float, float]],
    *,
    drill: Drill | None = None,
    speed_exponent: float = 0.1,
    ref_speed_m_per_min: float = 100.0,
    start: tuple[float, float] = (1500.0, 0.22),
) -> KienzleFit:
    """Fit kc1.1 and mc to measured mean drilling torques (minimax relative error).

    Parameters
    ----------
    cuts : sequence of (speed_rpm, feed_mm_per_rev, torque_nm)
        Measured mean torques.
    drill : Drill, optional
        Tool geometry.
    speed_exponent, ref_speed_m_per_min : float
        Fixed speed correction.
    start : (float, float)
        Start values (handbook constants).

    Returns
    -------
    KienzleFit
    """
    d = drill if drill is not None else Drill()
    pts = np.asarray(cuts, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] < 2:
        raise ConfigError("fit_kienzle needs at least two (speed_rpm, feed, torque) rows")

    def model(x: NDArray[np.float64]) -> NDArray[np.float64]:
        mat = Material(
            "fit",
            kc1_n_per_mm2=x[0] * 1000.0,
            mc=x[1],
            speed_exponent=speed_exponent,
            ref_speed_m_per_min=ref_speed_m_per_min,
        )
        return drill_torque_nm(pts[:, 1], pts[:, 0], drill=d, material=mat)

    def objective(x: NDArray[np.float64]) -> float:
        return float(np.max(np.abs(model(x) / pts[:, 2] - 1.0)))

    from scipy.optimize import minimize  # here: 0.3 s of import the simulator does not need

    res = minimize(
        objective,
        np.array([start[0] / 1000.0, start[1]]),
        method="Nelder-Mead",
        options={"xatol": 1e-9, "fatol": 1e-12, "maxiter": 5000},
    )
    x = np.asarray(res.x, dtype=np.float64)
    return KienzleFit(float(x[0] * 1000.0), float(x[1]), 100.0 * (model(x) / pts[:, 2] - 1.0))
