"""Fault injection for the cutting hook: loose tool, tool breakage, chatter, hardness change.

Each fault is a frozen dataclass; :func:`apply_faults` modifies a
:class:`~cnctwin.sim.cutting.CuttingLoad` for one chunk and reports per fault whether (and from
which sample) it was active, so scenarios can write the *true* onset times into ``truth.json``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cnctwin.sim.cutting import CuttingLoad

__all__ = [
    "Chatter",
    "Fault",
    "HardnessChange",
    "LooseTool",
    "ToolBreakage",
    "apply_faults",
    "fault_to_dict",
    "hardness_factor",
]


@dataclass(frozen=True)
class LooseTool:
    """Tool loosening in the collet (thesis §5.4, Fig. 5.10: loose tap on extraction).

    From ``start_hole`` (or ``start_s``) on, while the spindle turns backwards
    (``on_extraction_only``) and the tool is engaged, torque and axial force fluctuate: the
    tool slips and re-grips in the collet.

    Attributes
    ----------
    start_hole : int or None
        First hole (0-based) with a loose tool.
    start_s : float or None
        Or: time from which the tool is loose [s].
    torque_amplitude_nm : float
        Amplitude of the torque fluctuation [Nm]. [E] 1.0
    axial_force_amplitude_n : float
        Amplitude of the axial (Z) force fluctuation [N] -> Z ENC_POS fluctuation. [E] 300
    freq_hz : float
        Main slip-stick frequency [Hz]. [E] 37
    on_extraction_only : bool
        Only while the spindle turns backwards (speed < 0). Default True.
    """

    start_hole: int | None = None
    start_s: float | None = None
    torque_amplitude_nm: float = 1.0
    axial_force_amplitude_n: float = 300.0
    freq_hz: float = 37.0
    on_extraction_only: bool = True


@dataclass(frozen=True)
class ToolBreakage:
    """Drill breaks in ``hole`` at ``depth_fraction`` of the engaged time.

    At the break a short torque spike (``spike_factor`` x load for ``spike_s``), afterwards no
    cutting torque/thrust (the broken stub rubs: ``residual_ratio``).
    """

    hole: int
    depth_fraction: float = 0.5
    spike_factor: float = 2.5
    spike_s: float = 0.01
    residual_ratio: float = 0.1


@dataclass(frozen=True)
class Chatter:
    """Regenerative chatter from ``start_s``: a sinusoidal modulation of the cutting load.

    Attributes
    ----------
    start_s : float
        Onset [s] (recording time).
    freq_hz : float
        Chatter frequency [Hz] (folds about 250 Hz in the 500 Hz recording).
    amplitude : float
        Relative amplitude of the torque/force modulation [-].
    growth_s : float
        Time constant of the amplitude build-up [s]. [E] 0.2
    """

    start_s: float
    freq_hz: float = 180.0
    amplitude: float = 0.3
    growth_s: float = 0.2


@dataclass(frozen=True)
class HardnessChange:
    """Workpiece hardness (kc) multiplied by ``factor`` from ``hole`` on."""

    hole: int
    factor: float = 1.15


Fault = LooseTool | ToolBreakage | Chatter | HardnessChange


def fault_to_dict(fault: Fault) -> dict[str, object]:
    """Plain dict with a ``type`` key (for truth.json)."""
    return {"type": type(fault).__name__, **dataclasses.asdict(fault)}


def hardness_factor(faults: Sequence[Fault], hole: ArrayLike) -> NDArray[np.float64]:
    """Product of all :class:`HardnessChange` factors active at ``hole`` (0-based)."""
    h = np.asarray(hole, dtype=np.float64)
    out = np.ones(h.shape)
    for f in faults:
        if isinstance(f, HardnessChange):
            out = np.where(h >= f.hole, out * f.factor, out)
    return out


def apply_faults(
    faults: Sequence[Fault],
    load: CuttingLoad,
    *,
    time_s: ArrayLike,
    hole: ArrayLike,
    speed_rpm: ArrayLike,
    hole_progress: ArrayLike | None = None,
    rng: np.random.Generator | None = None,
) -> tuple[CuttingLoad, list[float | None]]:
    """Apply faults to one chunk of cutting load.

    Parameters
    ----------
    faults : sequence of Fault
        Faults to inject (:class:`HardnessChange` acts through :func:`hardness_factor`).
    load : CuttingLoad
        Fault-free load of the chunk.
    time_s : array-like
        Recording time per sample [s].
    hole : array-like of int
        Current hole index per sample (0-based; -1 before the first hole).
    speed_rpm : array-like
        Spindle speed per sample [rpm].
    hole_progress : array-like, optional
        Fraction 0..1 of the engaged part of the current hole (for :class:`ToolBreakage`).
    rng : numpy.random.Generator, optional
        Randomness of the loose-tool slips.

    Returns
    -------
    load : CuttingLoad
        Modified load.
    onsets : list of float or None
        Per fault, the first time [s] in this chunk where it changed the load (else None).
    """
    t = np.asarray(time_s, dtype=np.float64)
    n = t.size
    hole_a = np.broadcast_to(np.asarray(hole, dtype=np.float64), (n,))
    spd = np.broadcast_to(np.asarray(speed_rpm, dtype=np.float64), (n,))
    prog = (
        np.zeros(n)
        if hole_progress is None
        else np.broadcast_to(np.asarray(hole_progress, dtype=np.float64), (n,))
    )
    torque = load.torque_nm.copy()
    thrust = load.thrust_n.copy()
    fx, fy = load.fx_n.copy(), load.fy_n.copy()
    engaged = load.engagement > 0.0
    onsets: list[float | None] = []
    for f in faults:
        active = np.zeros(n, dtype=bool)
        if isinstance(f, LooseTool):
            started = np.ones(n, dtype=bool)
            if f.start_hole is not None:
                started &= hole_a >= f.start_hole
            if f.start_s is not None:
                started &= t >= f.start_s
            active = started & engaged
            if f.on_extraction_only:
                active &= spd < 0.0
            if active.any():
                jitter = rng.standard_normal(n) if rng is not None else np.zeros(n)
                phase = 2.0 * math.pi * f.freq_hz * t
                slip = np.sin(phase) + 0.5 * np.sin(2.7 * phase + 1.0) + 0.5 * jitter
                torque = np.where(active, torque + f.torque_amplitude_nm * slip, torque)
                thrust = np.where(active, thrust + f.axial_force_amplitude_n * slip, thrust)
        elif isinstance(f, ToolBreakage):
            in_hole = hole_a == f.hole
            after = (hole_a > f.hole) | (in_hole & (prog >= f.depth_fraction))
            active = after & engaged
            if active.any():
                first = int(np.argmax(active))
                spike = active & (t < t[first] + f.spike_s)
                torque = np.where(
                    spike,
                    torque * f.spike_factor,
                    np.where(active, torque * f.residual_ratio, torque),
                )
                thrust = np.where(active & ~spike, thrust * f.residual_ratio, thrust)
        elif isinstance(f, Chatter):
            active = (t >= f.start_s) & engaged
            if active.any():
                env = 1.0 - np.exp(-np.maximum(t - f.start_s, 0.0) / f.growth_s)
                mod = 1.0 + f.amplitude * env * np.sin(2.0 * math.pi * f.freq_hz * t)
                torque = np.where(active, torque * mod, torque)
                thrust = np.where(active, thrust * mod, thrust)
                fx = np.where(active, fx * mod, fx)
                fy = np.where(active, fy * mod, fy)
        elif isinstance(f, HardnessChange):
            active = (hole_a >= f.hole) & engaged
        onsets.append(float(t[int(np.argmax(active))]) if active.any() else None)
    return CuttingLoad(torque, thrust, fx, fy, load.engagement.copy()), onsets
