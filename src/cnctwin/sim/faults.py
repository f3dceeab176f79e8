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
    "loose_tool_signature",
]


@dataclass(frozen=True)
class LooseTool:
    """Tool loosening in the collet (thesis §5.4, Fig. 5.10: loose tap on extraction).

    From ``start_hole`` (or ``start_s``) on, while the spindle turns backwards
    (``on_extraction_only``) and the tool is engaged, the tool sticks and slips in the collet:
    the collet clamps for one direction of rotation only (thesis §5.4: "dynamometer collet is not
    providing changing on rotation"), so on reversal the reverse torque winds the holder up until
    the clamping friction gives, the tap slips back, and the cycle repeats (stick-slip).

    Signature (see :func:`loose_tool_signature`):

    * torque: a sawtooth at the slip frequency, rising during the stick phase and dropping at
      each slip, with a slip-to-slip amplitude spread and sample jitter -> dynamometer torque and,
      through the spindle position loop, the spindle current;
    * axial force: at each slip the tap lags in rotation while the Z axis keeps retracting at the
      pitch; the thread held in the workpiece pulls the tap (and the Z axis) back into the hole
      with a force pulse that decays as the tension-compression float of the holder takes it up
      -> fluctuation of the Z encoder position (following error).

    Both scale with the engaged fraction of the thread.

    Attributes
    ----------
    start_hole : int or None
        First hole (0-based) with a loose tool.
    start_s : float or None
        Or: time from which the tool is loose [s].
    torque_amplitude_nm : float
        Half range of the stick-slip torque sawtooth [Nm]. [E] 1.0 (of the order of the
        reverse torque of an M8 tap in steel, ~0.85 Nm)
    axial_force_amplitude_n : float
        Peak of the axial pull per slip [N] -> Z ENC_POS fluctuation. [E] 300
    freq_hz : float
        Mean slip frequency [Hz]. [E] 37
    amplitude_spread : float
        Relative spread of the slip amplitude from slip to slip (uniform +-) [-]. [E] 0.4
    axial_decay_s : float
        Decay time of the axial pull after a slip [s]. [E] 0.006
    on_extraction_only : bool
        Only while the spindle turns backwards (speed < 0). Default True.
    """

    start_hole: int | None = None
    start_s: float | None = None
    torque_amplitude_nm: float = 1.0
    axial_force_amplitude_n: float = 300.0
    freq_hz: float = 37.0
    amplitude_spread: float = 0.4
    axial_decay_s: float = 0.006
    on_extraction_only: bool = True


def loose_tool_signature(
    fault: LooseTool, time_s: ArrayLike, *, jitter: ArrayLike | None = None
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Stick-slip torque and axial-force fluctuation of a loose tool (per unit engagement).

    Parameters
    ----------
    fault : LooseTool
        Amplitudes, slip frequency, spread and decay.
    time_s : array-like
        Recording time per sample [s].
    jitter : array-like, optional
        Standard-normal noise per sample (slip randomness within a slip) [-].

    Returns
    -------
    torque_nm : numpy.ndarray
        Torque fluctuation [Nm], sign as a load opposing reverse rotation adds to (negative).
    axial_n : numpy.ndarray
        Axial force [N], negative = pulls the tool down into the hole.

    Notes
    -----
    Slip k occupies ``k <= f t < k + 1``; ``u = f t - k`` is the phase within it. Torque
    ``-A_T a_k (2u - 1)`` (wind-up, then release at the slip), axial force
    ``-A_F a_k exp(-u / (f tau))`` (pull after the slip, decaying with ``tau``). The slip
    amplitude ``a_k = 1 + s (2 r_k - 1)`` uses a hash ``r_k`` of the slip number, so the
    signature does not depend on how the simulation is cut into chunks.
    """
    t = np.asarray(time_s, dtype=np.float64)
    ft = fault.freq_hz * t
    k = np.floor(ft)
    u = ft - k
    r = np.sin(k * 12.9898 + 78.233) * 43758.5453
    r -= np.floor(r)
    a = 1.0 + fault.amplitude_spread * (2.0 * r - 1.0)
    if jitter is not None:
        a = a * (1.0 + 0.15 * np.asarray(jitter, dtype=np.float64))
    torque = -fault.torque_amplitude_nm * a * (2.0 * u - 1.0)
    decay = max(fault.freq_hz * fault.axial_decay_s, 1e-6)
    axial = -fault.axial_force_amplitude_n * a * np.exp(-u / decay)
    return torque, axial


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
    """Plain dict with a ``type`` key (for truth.json).

    Parameters
    ----------
    fault : Fault
        A fault object.

    Returns
    -------
    dict
        ``kind`` and the fault's fields (what ``truth.json`` stores).
    """
    return {"type": type(fault).__name__, **dataclasses.asdict(fault)}


def hardness_factor(faults: Sequence[Fault], hole: ArrayLike) -> NDArray[np.float64]:
    """Product of all :class:`HardnessChange` factors active at ``hole`` (0-based).

    Parameters
    ----------
    faults : sequence
        The faults of a run.
    hole : array-like
        Hole numbers (0-based).

    Returns
    -------
    numpy.ndarray
        Factor on kc per hole [-].
    """
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
                jitter = rng.standard_normal(n) if rng is not None else None
                dt, da = loose_tool_signature(f, t, jitter=jitter)
                w = np.clip(load.engagement, 0.0, 1.0)
                torque = np.where(active, torque + w * dt, torque)
                thrust = np.where(active, thrust + w * da, thrust)
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
