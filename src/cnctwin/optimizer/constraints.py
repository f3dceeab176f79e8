"""The limits a feed must respect, and the highest feed per control cycle that respects them.

Every limit comes from the machine file (the calibrated spindle law and the drives' ratings),
the tool table (chip thickness, torque, force per tooth) or the material (the milling
coefficients). Predicted loads (torque, power, force) carry a margin ``base + k u`` where
``u`` is the relative standard uncertainty of the prediction (material coefficient and torque
constant, combined in quadrature; a library material without a calibration counts
:data:`LIBRARY_MATERIAL_UNCERTAINTY`) and ``k = 2``; the chip thickness, which the feed and
the speed set, carries :data:`CHIP_MARGIN` only.

Per cycle with engagement (entry phi_st, exit phi_ex, axial depth a) at spindle speed n and
z teeth, the feed per tooth c = f / (n z) enters the loads linearly
(:func:`cnctwin.sim.cutting.mean_milling_load`): mean torque A + B c, peak torque P + Q c
(k_max teeth engaged at once, each at its largest chip), chip c sin(phi)_max, force per
tooth a |(Ktc h + Kte, Krc h + Kre)| at h = c sin(phi)_max. Each limit gives a largest c;
the cycle's feed is the smallest, and the name of the limit that gave it binds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from cnctwin.machine import MachineFile, ToolSpec
from cnctwin.sim.cutting import MillingCoefficients, max_chip_factor
from cnctwin.spindle import SpindleModel

__all__ = [
    "CONSTRAINTS",
    "LIBRARY_MATERIAL_UNCERTAINTY",
    "MODEL_MARGIN",
    "Limits",
    "feed_limits",
    "limits_from_machine",
]

MODEL_MARGIN = 0.05
"""Base margin on every predicted load for what the zero-helix model leaves out [-]."""

LIBRARY_MATERIAL_UNCERTAINTY = 0.15
"""Relative standard uncertainty of a library material's coefficients (derived, not
calibrated on this machine) [-]; ``cnctwin calibrate material`` replaces it by the fit's."""

CHIP_MARGIN = 0.02
"""Margin on the chip thickness [-]: it is set by the feed and the speed, not by the material,
so only the drives' feed overshoot is covered."""

COVERAGE_K = 2.0
"""Coverage factor on the combined standard uncertainty [-]."""

CONSTRAINTS: tuple[str, ...] = (
    "spindle S1 torque", "spindle S1 power", "spindle peak torque", "tool torque",
    "chip thickness", "force per tooth", "axis current", "machine feed", "programmed feed",
)
"""Names of the limits a line's feed can be bound by."""


@dataclass(frozen=True)
class Limits:
    """The machine's and the tool's limits with the margin applied to predicted loads.

    Attributes
    ----------
    spindle : SpindleModel
        Calibrated spindle law (friction B n + tau_f, torque constant across speed).
    rated_torque_nm : float
        Spindle S1 torque [Nm].
    s1_power_w : float
        Spindle S1 power, rated torque x base speed [W].
    peak_torque_nm : float
        Spindle torque at the current limit and the calibrated Kt [Nm].
    margin : float
        Relative margin on predicted loads [-].
    margin_parts : dict
        ``base``, ``material_u``, ``kt_u``, ``k``: how the margin was made.
    axis_force_n : float
        Largest continuous cutting force the weakest linear feed axis takes (its S1 torque
        through the screw, minus its Coulomb friction) [N].
    path_max_mm_min : float
        Largest path feed of the linear axes [mm/min].
    """

    spindle: SpindleModel
    rated_torque_nm: float
    s1_power_w: float
    peak_torque_nm: float
    margin: float
    margin_parts: dict[str, float]
    axis_force_n: float
    path_max_mm_min: float

    def s1_torque_nm(self, speed_rpm: NDArray[np.float64]) -> NDArray[np.float64]:
        """S1 torque across speed: rated torque up to base speed, constant power above [Nm]."""
        w = np.maximum(np.abs(speed_rpm), 1.0) * 2.0 * math.pi / 60.0
        return np.minimum(self.rated_torque_nm, self.s1_power_w / w)


def limits_from_machine(mfile: MachineFile, *, material_uncertainty: float) -> Limits:
    """The limits of a machine file with the margin from the uncertainties.

    Parameters
    ----------
    mfile : MachineFile
        The (calibrated) machine.
    material_uncertainty : float
        Relative standard uncertainty of the material's cutting coefficient Ktc [-].

    Returns
    -------
    Limits
    """
    m = mfile.machine
    sp = m.spindle
    model = SpindleModel.from_machine(mfile)
    rec = mfile.record("spindle.kt_nm_per_a")
    kt_u = 0.0
    if rec is not None and rec.uncertainty is not None and rec.value:
        kt_u = abs(float(rec.uncertainty) / float(rec.value))
    u = math.hypot(material_uncertainty, kt_u)
    margin = MODEL_MARGIN + COVERAGE_K * u
    linear = [ax for ax in m.axes if not ax.rotary]
    forces = [ax.rated_torque_nm * 2.0 * math.pi / (ax.screw_pitch_mm / 1000.0) - ax.coulomb_n
              for ax in linear] or [math.inf]
    vmax = min((ax.max_velocity_mm_min for ax in linear), default=10000.0)
    return Limits(
        spindle=model, rated_torque_nm=sp.rated_torque_nm,
        s1_power_w=sp.rated_torque_nm * sp.base_speed_rpm * 2.0 * math.pi / 60.0,
        peak_torque_nm=sp.current_limit_a * model.kt_nm_per_a, margin=margin,
        margin_parts={"base": MODEL_MARGIN, "material_u": material_uncertainty, "kt_u": kt_u,
                      "k": COVERAGE_K},
        axis_force_n=float(min(forces)), path_max_mm_min=float(vmax))


@dataclass(frozen=True)
class FeedLimits:
    """Highest feed per cycle and the limit that binds (what :func:`feed_limits` returns).

    Attributes
    ----------
    feed_mm_min : numpy.ndarray
        Highest path feed [mm/min] (``inf`` where no cutting limit applies: air).
    binding : numpy.ndarray of int
        Index into :data:`CONSTRAINTS` of the binding limit (-1: none).
    torque_a_nm, torque_b_nm_per_mm : numpy.ndarray
        The predicted mean cutting torque A + B c at a feed per tooth c [mm] (nominal, no
        margin; 0 where not cutting): what the adaptive feed holds (docs/adaptive.md).
    """

    feed_mm_min: NDArray[np.float64]
    binding: NDArray[np.int64]
    torque_a_nm: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    torque_b_nm_per_mm: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))


def _positive_root(a2: NDArray[np.float64], a1: NDArray[np.float64],
                   a0: NDArray[np.float64]) -> NDArray[np.float64]:
    """Largest root of a2 u^2 + a1 u + a0 = 0 (a2 > 0), NaN without a real root."""
    disc = a1 * a1 - 4.0 * a2 * a0
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(disc >= 0.0, (-a1 + np.sqrt(np.maximum(disc, 0.0))) / (2.0 * a2),
                        np.nan)


def feed_limits(entry_rad: NDArray[np.float64], exit_rad: NDArray[np.float64],
                axial_depth_mm: NDArray[np.float64], speed_rpm: NDArray[np.float64], *,
                tool: ToolSpec, coefficients: MillingCoefficients,
                limits: Limits) -> FeedLimits:
    """Highest feed per cycle within every cutting limit.

    Parameters
    ----------
    entry_rad, exit_rad : numpy.ndarray
        Immersion per cycle [rad] (NaN: not cutting).
    axial_depth_mm : numpy.ndarray
        Axial depth per cycle [mm].
    speed_rpm : numpy.ndarray
        Commanded spindle speed per cycle [rpm].
    tool : ToolSpec
        The end mill (diameter, flutes, chip and torque limits).
    coefficients : MillingCoefficients
        The material's milling coefficients.
    limits : Limits
        Machine limits and margin.

    Returns
    -------
    FeedLimits
    """
    z = tool.flutes
    r = tool.diameter_mm / 2.0
    k = coefficients
    n = np.abs(np.asarray(speed_rpm, dtype=np.float64))
    on = np.isfinite(entry_rad) & np.isfinite(exit_rad) & (axial_depth_mm > 0.0) & (n > 1.0)
    p0 = np.where(on, entry_rad, 0.0)
    p1 = np.where(on, exit_rad, 0.0)
    a = np.where(on, axial_depth_mm, 0.0)
    sn = np.cos(p0) - np.cos(p1)
    span = p1 - p0
    g = 1.0 + limits.margin
    # mean torque A + B c, peak P + Q c [Nm]
    big_a = z * a * r / (2.0 * math.pi) * k.kte_n_per_mm * span / 1000.0 * g
    big_b = z * a * r / (2.0 * math.pi) * k.ktc_n_per_mm2 * sn / 1000.0 * g
    smax = max_chip_factor(p0, p1)
    kmax = np.ceil(span * z / (2.0 * math.pi) - 1e-9)
    peak_p = kmax * a * r * k.kte_n_per_mm / 1000.0 * g
    peak_q = kmax * a * r * k.ktc_n_per_mm2 * smax / 1000.0 * g
    fric = np.abs(limits.spindle.friction_torque_nm(n))
    w = n * 2.0 * math.pi / 60.0
    cands: list[NDArray[np.float64]] = []
    with np.errstate(divide="ignore", invalid="ignore"):
        cands.append((limits.s1_torque_nm(n) - fric - big_a) / big_b)
        cands.append((limits.s1_power_w / np.maximum(w, 1e-9) - fric - big_a) / big_b)
        cands.append((limits.peak_torque_nm - fric - peak_p) / peak_q)
        cands.append((tool.max_torque_nm - peak_p) / peak_q if tool.max_torque_nm is not None
                     else np.full(n.size, np.inf))
        cands.append(tool.max_chip_mm / (smax * (1.0 + CHIP_MARGIN))
                     if tool.max_chip_mm is not None
                     else np.full(n.size, np.inf))
        if tool.max_force_per_tooth_n is not None:
            f = tool.max_force_per_tooth_n / (np.maximum(a, 1e-12) * g)
            a2 = k.ktc_n_per_mm2**2 + k.krc_n_per_mm2**2
            a1 = 2.0 * (k.ktc_n_per_mm2 * k.kte_n_per_mm + k.krc_n_per_mm2 * k.kre_n_per_mm)
            a0 = k.kte_n_per_mm**2 + k.kre_n_per_mm**2 - f * f
            cands.append(_positive_root(np.full(n.size, a2), np.full(n.size, a1), a0) / smax)
        else:
            cands.append(np.full(n.size, np.inf))
        # axis: mean cutting force bound |F| <= z a / (2 pi) (|..| of each term) <= force limit
        fa0 = z * a / (2.0 * math.pi) * (k.kte_n_per_mm + k.kre_n_per_mm) * span * g
        fa1 = z * a / (2.0 * math.pi) * (k.ktc_n_per_mm2 + k.krc_n_per_mm2) * span * g
        cands.append((limits.axis_force_n - fa0) / fa1)
    c_all = np.vstack(cands)
    c_all = np.where(np.isnan(c_all) | (c_all < 0.0), 0.0, c_all)
    c_all[:, ~on] = np.inf
    idx = np.argmin(c_all, axis=0)
    c_best = c_all[idx, np.arange(n.size)]
    feed = c_best * n * z
    binding = np.where(np.isfinite(feed), idx, -1)
    return FeedLimits(feed_mm_min=feed, binding=binding.astype(np.int64),
                      torque_a_nm=big_a / g, torque_b_nm_per_mm=big_b / g)
