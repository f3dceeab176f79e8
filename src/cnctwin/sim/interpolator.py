"""Path interpolation: part program -> fine-interpolated position commands (DES_POS) per cycle.

The NC of a SINUMERIK 840D sl plans the path velocity with jerk limitation and look-ahead and
the fine interpolator (FIPO) outputs one position set point per position-control cycle (2 ms on
the thesis machine, :doc:`physics-and-performance` section 1.1); that set point is the edge
signal DES_POS ("desired position, position command after the fine interpolator", thesis
Table 2.1). The jerk filter, dynamic response adaptation and the position loop act *after*
DES_POS and live in :mod:`cnctwin.sim.servo`.

Layers
------
* pure functions: :func:`acceleration_time_s`, :func:`transition_distance_mm`,
  :func:`scurve_profile` (one jerk-limited 7-phase profile),
* descriptions: :class:`AxisLimits`, :class:`SpindleLimits`,
* orchestration: :func:`interpolate_chunks` (streaming) and :func:`interpolate` (whole program),
  returning :class:`Trajectory`.

Notes
-----
Velocity profile per segment: the symmetric double-S ("7-phase S-curve") with zero
acceleration at both ends, Biagiotti & Melchiorri, *Trajectory Planning for Automatic Machines
and Robots*, Springer 2008, Sect. 3.4: accelerating by ``dv`` takes
``T = 2 sqrt(dv/j)`` if ``dv < a^2/j`` else ``T = dv/a + a/j`` and covers
``(v_start + v_end) T / 2``.

Look-ahead joins consecutive feed blocks in continuous-path mode (G64) with a junction
velocity limited by

* the axis velocity jump at a tangent discontinuity: ``v |du_i| <= k_ovl a_i T_ipo`` with the
  overload factor ``k_ovl`` of SINUMERIK MD32310 ``MAX_ACCEL_OVL_FACTOR`` (default 1.2 here),
* the path deviation of a rounded corner, ``v^2 = a delta sin(theta/2) / (1 - sin(theta/2))``
  (junction-deviation rule; ``delta`` = ``corner_tolerance_mm``),
* the axis acceleration jump at a curvature step (line -> arc): ``v^2 |d(kappa n)_i| <=
  j_i T_ipo`` (the role of MD32432 ``PATH_TRANS_JERK_LIM``),

then backward/forward passes make every junction reachable within the segment lengths, and a
junction can be no faster than a stop within the next ``lookahead_blocks`` segments allows.
On arcs the centripetal acceleration and its rate use the share ``curvature_share`` of the
axis limits (``v^2/r <= c a_max``, ``v^3/r^2 <= c j_max``; MD20602
``CURV_EFFECT_ON_PATH_ACCEL`` plays that role on the NC) and the tangential profile the rest.
G0 moves are linear interpolation with each axis within its own limits and stop exactly (G60
behaviour at rapid block ends); drilling cycles stop exactly at every point.

Rigid tapping interpolates the spindle as an axis with Z: spindle angle
``phi = POSS + (z_start - z) / pitch * 360 deg`` (reversing on the way out) and spindle speed
``n = -dz/dt / pitch * 60``; the path limits on the tapping segments are the tighter of Z and
spindle (``a_z <= accel_rpm_s / 60 * |pitch|``).
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field

import numba
import numpy as np
import pandas as pd
from numpy.typing import NDArray

from cnctwin.exceptions import ConfigError, GCodeError
from cnctwin.recording import EVENT_COLUMNS
from cnctwin.sim.gcode import Block, DrillCycle, Program

__all__ = [
    "HOLE_COLUMNS",
    "AxisLimits",
    "SpindleLimits",
    "Trajectory",
    "acceleration_time_s",
    "interpolate",
    "interpolate_chunks",
    "scurve_profile",
    "transition_distance_mm",
]

HOLE_COLUMNS: tuple[str, ...] = (
    "hole",
    "x_mm",
    "y_mm",
    "z_top_mm",
    "z_bottom_mm",
    "start_cycle",
    "end_cycle",
    "tool",
    "kind",
    "feed_mm_min",
    "speed_rpm",
    "pitch_mm",
    "block",
)
"""Columns of :attr:`Trajectory.holes`."""

_SEG_LINE, _SEG_ARC, _SEG_HOLD = 0, 1, 2
_JERK_SIGNS = (1.0, 0.0, -1.0, 0.0, -1.0, 0.0, 1.0)


@dataclass(frozen=True)
class AxisLimits:
    """Dynamic limits of one axis (SINUMERIK MD32000, MD32300, MD32431, MD32310).

    Attributes
    ----------
    max_velocity_mm_min : float
        Maximum axis velocity (rapid traverse) [mm/min] or [deg/min].
    max_accel_mm_s2 : float
        Maximum axis acceleration [mm/s^2] or [deg/s^2].
    max_jerk_mm_s3 : float
        Maximum axis jerk [mm/s^3] or [deg/s^3].
    overload_factor : float, default 1.2
        Allowed velocity jump at block transitions as a multiple of ``max_accel * T_ipo``
        (MD32310 ``MAX_ACCEL_OVL_FACTOR``).
    """

    max_velocity_mm_min: float
    max_accel_mm_s2: float
    max_jerk_mm_s3: float
    overload_factor: float = 1.2

    def __post_init__(self) -> None:
        for name in ("max_velocity_mm_min", "max_accel_mm_s2", "max_jerk_mm_s3"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"AxisLimits.{name} must be > 0, got {getattr(self, name)}")


@dataclass(frozen=True)
class SpindleLimits:
    """Spindle limits.

    Attributes
    ----------
    max_speed_rpm : float
        Maximum spindle speed [rpm].
    accel_rpm_s : float
        Speed ramp of the speed set point [rpm/s].
    jerk_time_s : float, default 0.02
        Time for the spindle acceleration to build up when it interpolates with Z (rigid
        tapping): jerk limit ``accel_rpm_s / jerk_time_s`` [s].
    """

    max_speed_rpm: float
    accel_rpm_s: float
    jerk_time_s: float = 0.02

    def __post_init__(self) -> None:
        if not (self.max_speed_rpm > 0 and self.accel_rpm_s > 0 and self.jerk_time_s > 0):
            raise ConfigError(
                "SpindleLimits: max_speed_rpm, accel_rpm_s and jerk_time_s must be > 0, got "
                f"{self.max_speed_rpm}, {self.accel_rpm_s}, {self.jerk_time_s}"
            )


@dataclass
class Trajectory:
    """Interpolated set points, one row per position-control cycle.

    Attributes
    ----------
    des_pos : dict
        Axis name -> DES_POS (position command after the fine interpolator) [mm] or [deg].
    path_velocity_mm_min : numpy.ndarray
        Path velocity [mm/min].
    spindle_speed_cmd_rpm : numpy.ndarray
        Signed spindle speed set point [rpm] (ramped; follows Z in rigid tapping).
    spindle_mode : numpy.ndarray of int8
        0 speed control, 1 position control (rigid tapping).
    spindle_pos_cmd_deg : numpy.ndarray
        Spindle angle set point [deg]: the coupled angle in mode 1 (not wrapped: POSS plus the
        turns of the thread); in mode 0 the integral of the speed set point, modulo 360.
    block_index : numpy.ndarray of int32
        Index into ``program.blocks`` of the block executing in each cycle.
    tool : numpy.ndarray of int32
        Active tool number (0: none).
    events : pandas.DataFrame
        NC events with :data:`cnctwin.recording.EVENT_COLUMNS`; ``cycle`` is the 0-based cycle
        offset from the program start (the caller adds the counter of the first cycle).
    holes : pandas.DataFrame
        Simulation truth, one row per drilled or tapped hole (:data:`HOLE_COLUMNS`):
        ``start_cycle`` is the first cycle with the tool tip at or below ``z_top_mm`` (the
        reference plane RFP, or R) going in, ``end_cycle`` the first cycle back at or above it.
    cycle_time_s : float
        Cycle time [s].
    duration_s : float
        Duration of the whole program [s].
    first_cycle : int
        Cycle offset of row 0 (non-zero for all but the first chunk of
        :func:`interpolate_chunks`).
    """

    des_pos: dict[str, NDArray[np.float64]]
    path_velocity_mm_min: NDArray[np.float64]
    spindle_speed_cmd_rpm: NDArray[np.float64]
    spindle_mode: NDArray[np.int8]
    spindle_pos_cmd_deg: NDArray[np.float64]
    block_index: NDArray[np.int32]
    tool: NDArray[np.int32]
    events: pd.DataFrame
    holes: pd.DataFrame
    cycle_time_s: float
    duration_s: float
    first_cycle: int = 0

    @property
    def n_cycles(self) -> int:
        """Number of cycles (rows) in this trajectory."""
        return int(self.path_velocity_mm_min.shape[0])

    @property
    def cycle(self) -> NDArray[np.int64]:
        """Cycle offsets of the rows."""
        return np.arange(self.first_cycle, self.first_cycle + self.n_cycles, dtype=np.int64)


# ----------------------------------------------------------------------------------------------
# pure functions: jerk-limited 7-phase profile


def acceleration_time_s(dv: float, a: float, j: float) -> float:
    """Time to change speed by ``dv`` with zero acceleration at both ends.

    Parameters
    ----------
    dv : float
        Speed change (magnitude) [mm/s].
    a : float
        Acceleration limit [mm/s^2].
    j : float
        Jerk limit [mm/s^3].

    Returns
    -------
    float
        Duration [s]: ``2 sqrt(dv/j)`` if ``dv < a^2/j`` (acceleration limit not reached),
        else ``dv/a + a/j`` (Biagiotti & Melchiorri 2008, Sect. 3.4).
    """
    dv = abs(dv)
    if dv * j < a * a:
        return 2.0 * math.sqrt(dv / j)
    return dv / a + a / j


def transition_distance_mm(v_start: float, v_end: float, a: float, j: float) -> float:
    """Path length needed to go from ``v_start`` to ``v_end`` [mm] (symmetric S-curve).

    Equals ``(v_start + v_end) / 2 * acceleration_time_s(v_end - v_start, a, j)``.

    Parameters
    ----------
    v_start : float
        Start velocity [mm/s].
    v_end : float
        End velocity [mm/s].
    a : float
        Acceleration limit [mm/s²].
    j : float
        Jerk limit [mm/s³].

    Returns
    -------
    float
        Path length [mm].
    """
    return 0.5 * (v_start + v_end) * acceleration_time_s(v_end - v_start, a, j)


def _max_reachable(v_from: float, length: float, a: float, j: float, v_max: float) -> float:
    """Largest speed reachable from (or stoppable to) ``v_from`` within ``length``."""
    if transition_distance_mm(v_from, v_max, a, j) <= length:
        return v_max
    lo, hi = v_from, v_max
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if transition_distance_mm(v_from, mid, a, j) <= length:
            lo = mid
        else:
            hi = mid
    return lo


def _accel_phases(dv: float, a: float, j: float) -> tuple[float, float]:
    """(jerk phase time, constant-acceleration phase time) for a speed change ``dv >= 0``."""
    if dv <= 0:
        return 0.0, 0.0
    if dv * j < a * a:
        return math.sqrt(dv / j), 0.0
    return a / j, dv / a - a / j


def scurve_profile(
    length_mm: float, v_start: float, v_end: float, v_max: float, a: float, j: float
) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Jerk-limited 7-phase velocity profile over a path segment.

    Parameters
    ----------
    length_mm : float
        Segment length [mm].
    v_start, v_end : float
        Path speed at the start and end [mm/s]; must be reachable within ``length_mm``.
    v_max : float
        Speed limit on the segment [mm/s].
    a, j : float
        Path acceleration [mm/s^2] and jerk [mm/s^3] limits.

    Returns
    -------
    durations : tuple of 7 float
        Phase durations [s]: jerk up, constant acceleration, jerk down, cruise, jerk down,
        constant deceleration, jerk up.
    jerks : tuple of 7 float
        Jerk in each phase [mm/s^3].

    Notes
    -----
    The peak speed is ``v_max`` if the acceleration and deceleration distances fit
    (cruise phase), else it is found by bisection so that they add up to ``length_mm``.
    """

    def dist(vp: float) -> float:
        return transition_distance_mm(v_start, vp, a, j) + transition_distance_mm(vp, v_end, a, j)

    lo = max(v_start, v_end)
    if dist(v_max) <= length_mm:
        vp = v_max
    elif dist(lo) >= length_mm:
        vp = lo
    else:
        hi = v_max
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            if dist(mid) <= length_mm:
                lo = mid
            else:
                hi = mid
        vp = lo
    tj1, ta1 = _accel_phases(vp - v_start, a, j)
    tj2, ta2 = _accel_phases(vp - v_end, a, j)
    rest = length_mm - dist(vp)
    tv = rest / vp if vp > 0 and rest > 0 else 0.0
    durations = (tj1, ta1, tj1, tv, tj2, ta2, tj2)
    return durations, tuple(s * j for s in _JERK_SIGNS)


# ----------------------------------------------------------------------------------------------
# program -> segments


@dataclass
class _Seg:
    kind: int
    p0: NDArray[np.float64]
    u: NDArray[np.float64]
    length: float = 0.0
    duration: float = 0.0  # holds only
    arc: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)  # cx, cy, r0, dr, th0, dth
    v_lim: float = 0.0
    a_lim: float = 1.0
    j_lim: float = 1.0
    continuous: bool = False  # may blend into the next segment (G64 feed motion)
    block: int = 0
    tool: int = 0
    sp_target: float = 0.0
    tap: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)  # flag, zref, ang0, k
    v0: float = 0.0
    v1: float = 0.0
    t0: float = 0.0
    phases_t: tuple[float, ...] = ()
    phases_j: tuple[float, ...] = ()


@dataclass
class _Hole:
    x: float
    y: float
    cycle: DrillCycle
    seg_in: int
    seg_out: int
    tool: int
    feed_mm_min: float
    speed_rpm: float
    block: int


@dataclass
class _Plan:
    segs: list[_Seg]
    axes: tuple[str, ...]
    block_events: list[tuple[int, int, int, int]] = field(default_factory=list)
    call_events: list[tuple[int, bool, str, int]] = field(default_factory=list)  # seg, at_end
    holes: list[_Hole] = field(default_factory=list)
    zi: int = -1


class _Builder:
    """Walks the blocks and emits motion primitives (segments) with their limits."""

    def __init__(
        self,
        program: Program,
        *,
        limits: Mapping[str, AxisLimits],
        spindle: SpindleLimits,
        axes: tuple[str, ...],
        axis_letters: Mapping[str, str],
        start: NDArray[np.float64],
        cycle_time_s: float,
        curvature_share: float,
        wait_for_spindle: bool,
        tool_change_s: float,
    ) -> None:
        self.program = program
        self.axes = axes
        self.idx = {ax: i for i, ax in enumerate(axes)}
        self.letters = dict(axis_letters)
        self.vmax = np.array([limits[a].max_velocity_mm_min / 60.0 for a in axes])
        self.amax = np.array([limits[a].max_accel_mm_s2 for a in axes])
        self.jmax = np.array([limits[a].max_jerk_mm_s3 for a in axes])
        self.ovl = np.array([limits[a].overload_factor for a in axes])
        self.spindle = spindle
        self.dt = cycle_time_s
        self.c_share = curvature_share
        self.wait_for_spindle = wait_for_spindle
        self.tool_change_s = tool_change_s
        self.pos = start.copy()
        self.segs: list[_Seg] = []
        self.plan = _Plan(segs=self.segs, axes=axes)
        self.block = 0
        self.active_tool = 0
        self.selected_tool = 0
        self.sp_target = 0.0  # signed rpm
        self.zi = self.idx.get(self.letters.get("Z", ""), -1)
        self.xi = self.idx.get(self.letters.get("X", ""), -1)
        self.yi = self.idx.get(self.letters.get("Y", ""), -1)
        self.plan.zi = self.zi

    # -- helpers --
    def _axis(self, letter: str, blk: Block) -> int:
        name = self.letters.get(letter)
        if name is None or name not in self.idx:
            raise ConfigError(
                f"line {blk.line}: axis {letter} is programmed but not mapped to an interpolated "
                f"axis (axis_letters={self.letters}, axes={self.axes})"
            )
        return self.idx[name]

    def _target(self, blk: Block) -> NDArray[np.float64]:
        p = self.pos.copy()
        for letter, v in blk.target.items():
            p[self._axis(letter, blk)] = v
        return p

    def _feed_mm_s(self, blk: Block) -> float:
        if blk.feed_mode == "G95":
            if blk.speed_rpm is None or blk.spindle_dir == 0 or blk.speed_rpm <= 0:
                raise GCodeError("feed per revolution (G95) with the spindle stopped",
                                 line=blk.line, text=blk.text)  # fmt: skip
            assert blk.feed_mm_per_rev is not None
            return blk.feed_mm_per_rev * blk.speed_rpm / 60.0
        if blk.feedrate_mm_min is None:
            raise GCodeError("no feed programmed", line=blk.line, text=blk.text)
        return blk.feedrate_mm_min / 60.0

    def _emit(self, seg: _Seg) -> int:
        seg.block = self.block
        seg.tool = self.active_tool
        seg.sp_target = self.sp_target
        self.segs.append(seg)
        return len(self.segs) - 1

    def _line(
        self,
        p1: NDArray[np.float64],
        *,
        rapid: bool,
        feed_mm_s: float = 0.0,
        continuous: bool = False,
        tap: tuple[float, float, float, float] | None = None,
        tap_limits: tuple[float, float, float] | None = None,
    ) -> int | None:
        d = p1 - self.pos
        length = float(np.sqrt(np.dot(d, d)))
        if length < 1e-9:
            self.pos = p1.copy()
            return None
        u = d / length
        au = np.abs(u)
        nz = au > 1e-12
        v_lim = float(np.min(self.vmax[nz] / au[nz]))
        a_lim = float(np.min(self.amax[nz] / au[nz]))
        j_lim = float(np.min(self.jmax[nz] / au[nz]))
        if not rapid:
            v_lim = min(v_lim, feed_mm_s)
        if tap_limits is not None:
            v_lim, a_lim, j_lim = (min(v_lim, tap_limits[0]), min(a_lim, tap_limits[1]),
                                   min(j_lim, tap_limits[2]))  # fmt: skip
        seg = _Seg(kind=_SEG_LINE, p0=self.pos.copy(), u=u, length=length, v_lim=v_lim,
                   a_lim=a_lim, j_lim=j_lim, continuous=continuous and not rapid)  # fmt: skip
        if tap is not None:
            seg.tap = tap
        self.pos = p1.copy()
        return self._emit(seg)

    def _hold(self, duration: float, tap: tuple[float, float, float, float] | None = None) -> None:
        if duration <= 0:
            return
        seg = _Seg(kind=_SEG_HOLD, p0=self.pos.copy(), u=np.zeros(len(self.axes)),
                   duration=duration)  # fmt: skip
        if tap is not None:
            seg.tap = tap
        self._emit(seg)

    def _spindle_to(self, target_rpm: float, blk: Block, *, wait: bool) -> None:
        if abs(target_rpm) > self.spindle.max_speed_rpm * (1 + 1e-12):
            raise GCodeError(f"spindle speed {abs(target_rpm):g} rpm exceeds the spindle maximum "
                             f"{self.spindle.max_speed_rpm:g} rpm", line=blk.line,
                             text=blk.text)  # fmt: skip
        dv = abs(target_rpm - self.sp_target)
        self.sp_target = target_rpm
        if wait and dv > 0:
            self._hold(dv / self.spindle.accel_rpm_s)

    # -- blocks --
    def run(self) -> _Plan:
        for bi, blk in enumerate(self.program.blocks):
            self.block = bi
            self.plan.block_events.append((len(self.segs), bi, self.selected_tool,
                                           self.active_tool))  # fmt: skip
            self._block(blk)
            # the selected tool may change inside the block; record what the event should show
            last = self.plan.block_events[-1]
            self.plan.block_events[-1] = (last[0], bi, self.selected_tool, self.active_tool)
        return self.plan

    def _block(self, blk: Block) -> None:
        if blk.tool is not None:
            self.selected_tool = blk.tool
        if blk.tool_change:
            # the change cycle stops the spindle (M5 before the gripper takes the tool; M3/M4
            # in the block restart it after the change); the program starts with its first
            # tool in the spindle (tool 0: none known), so only a real change takes the time
            if self.sp_target != 0.0:
                self._spindle_to(0.0, blk, wait=True)
            if self.active_tool not in (0, self.selected_tool):
                self._hold(self.tool_change_s)
            self.active_tool = self.selected_tool
        if blk.spindle_cmd:
            n = (blk.speed_rpm or 0.0) * blk.spindle_dir
            self._spindle_to(n, blk, wait=self.wait_for_spindle)
        kind = blk.kind
        if kind == "dwell":
            if blk.dwell_s is not None:
                self._hold(blk.dwell_s)
            elif blk.dwell_rev is not None:
                if self.sp_target == 0:
                    raise GCodeError("G4 S (dwell in revolutions) with the spindle stopped",
                                     line=blk.line, text=blk.text)  # fmt: skip
                self._hold(blk.dwell_rev / (abs(self.sp_target) / 60.0))
        elif kind == "rapid":
            self._line(self._target(blk), rapid=True)
        elif kind == "linear":
            self._line(self._target(blk), rapid=False, feed_mm_s=self._feed_mm_s(blk),
                       continuous=not blk.exact_stop)  # fmt: skip
        elif kind in ("arc_cw", "arc_ccw"):
            self._arc(blk)
        elif kind in ("drill_cycle", "tap_cycle"):
            self._cycle(blk)

    def _arc(self, blk: Block) -> None:
        assert blk.center is not None
        if self.xi < 0 or self.yi < 0:
            raise ConfigError(f"line {blk.line}: arcs need X and Y axes mapped")
        p1 = self._target(blk)
        cx, cy = blk.center
        x0, y0 = self.pos[self.xi], self.pos[self.yi]
        x1, y1 = p1[self.xi], p1[self.yi]
        r0, r1 = math.hypot(x0 - cx, y0 - cy), math.hypot(x1 - cx, y1 - cy)
        th0, th1 = math.atan2(y0 - cy, x0 - cx), math.atan2(y1 - cy, x1 - cx)
        two_pi = 2.0 * math.pi
        if blk.kind == "arc_ccw":
            dth = (th1 - th0) % two_pi
            if dth < 1e-12:
                dth = two_pi
        else:
            dth = -((th0 - th1) % two_pi)
            if dth > -1e-12:
                dth = -two_pi
        d_other = p1 - self.pos
        d_other[self.xi] = 0.0
        d_other[self.yi] = 0.0
        r_mean = 0.5 * (r0 + r1)
        planar = abs(dth) * r_mean
        length = math.sqrt(planar * planar + float(np.dot(d_other, d_other)))
        u = d_other / length  # linear rate of the non-plane axes per path mm
        a_xy = float(min(self.amax[self.xi], self.amax[self.yi]))
        j_xy = float(min(self.jmax[self.xi], self.jmax[self.yi]))
        v_xy = float(min(self.vmax[self.xi], self.vmax[self.yi]))
        # curvature of the path in the plane: kappa = r (dth/L)^2
        kappa = r_mean * (dth / length) ** 2
        c = self.c_share
        v_lim = min(self._feed_mm_s(blk), v_xy, math.sqrt(c * a_xy / kappa),
                    (c * j_xy / (kappa * kappa)) ** (1.0 / 3.0))  # fmt: skip
        nz = np.abs(u) > 1e-12
        # jerk vector on a circle: (j_t - v^3 k^2) t + 3 v a_t k n; keep
        # v^3 k^2 <= c j (above) and j_t + 3 v a_t k <= (1 - c) j
        a_lim = min((1 - c) * a_xy, (1 - c) * j_xy / (6.0 * v_lim * kappa))
        j_lim = (1 - c) * j_xy - 3.0 * v_lim * a_lim * kappa
        if np.any(nz):
            v_lim = min(v_lim, float(np.min(self.vmax[nz] / np.abs(u[nz]))))
            a_lim = min(a_lim, float(np.min(self.amax[nz] / np.abs(u[nz]))))
            j_lim = min(j_lim, float(np.min(self.jmax[nz] / np.abs(u[nz]))))
        seg = _Seg(kind=_SEG_ARC, p0=self.pos.copy(), u=u, length=length,
                   arc=(cx, cy, r0, r1 - r0, th0, dth), v_lim=v_lim, a_lim=a_lim, j_lim=j_lim,
                   continuous=not blk.exact_stop)  # fmt: skip
        self.pos = p1.copy()
        self._emit(seg)

    def _z_to(self, z: float, **kw: object) -> int | None:
        if self.zi < 0:
            raise ConfigError("drilling cycles need a Z axis mapped (axis_letters['Z'])")
        p = self.pos.copy()
        p[self.zi] = z
        return self._line(p, **kw)  # type: ignore[arg-type]

    def _cycle(self, blk: Block) -> None:
        cyc = blk.cycle
        assert cyc is not None
        # positioning to the hole with the active motion (G0 rapid, else G1 at feed)
        p = self._target(blk)
        if blk.motion == "G0" or (cyc.kind == "tap" and blk.feedrate_mm_min is None):
            self._line(p, rapid=True)
        else:
            self._line(p, rapid=False, feed_mm_s=self._feed_mm_s(blk))
        self.plan.call_events.append((len(self.segs), False, cyc.call_path, 2))
        x = float(self.pos[self.xi]) if self.xi >= 0 else 0.0
        y = float(self.pos[self.yi]) if self.yi >= 0 else 0.0
        self._z_to(cyc.z_safety_mm, rapid=True)
        hole = self._tap(blk, cyc, x, y) if cyc.kind == "tap" else self._drill(blk, cyc, x, y)
        self.plan.holes.append(hole)
        self.plan.call_events.append((len(self.segs) - 1, True, self.program.call_path, 1))

    def _dwell_cycle(self, s: float | None, rev: float | None, speed_rpm: float) -> None:
        if s is not None:
            self._hold(s)
        elif rev is not None and speed_rpm > 0:
            self._hold(rev / (speed_rpm / 60.0))

    def _drill(self, blk: Block, cyc: DrillCycle, x: float, y: float) -> _Hole:
        feed = self._feed_mm_s(blk)
        speed = abs(self.sp_target)
        if cyc.kind == "drill":
            seg_in = self._z_to(cyc.z_bottom_mm, rapid=False, feed_mm_s=feed)
            self._dwell_cycle(cyc.dwell_bottom_s, cyc.dwell_bottom_rev, speed)
            seg_out = self._z_to(cyc.z_retract_mm, rapid=True)
        else:
            seg_in, seg_out = self._peck(cyc, feed, speed)
        assert seg_in is not None and seg_out is not None
        return _Hole(x=x, y=y, cycle=cyc, seg_in=seg_in, seg_out=seg_out,
                     tool=self.active_tool, feed_mm_min=feed * 60.0, speed_rpm=speed,
                     block=self.block)  # fmt: skip

    def _peck(self, cyc: DrillCycle, feed: float, speed: float) -> tuple[int | None, int | None]:
        assert cyc.first_depth_mm is not None
        total = cyc.z_ref_mm - cyc.z_bottom_mm
        depths: list[float] = []
        infeed = cyc.first_depth_mm
        reached = 0.0
        while reached < total - 1e-9:
            reached = min(total, reached + infeed)
            depths.append(reached)
            if cyc.degression_mm > 0:
                infeed = max(infeed - cyc.degression_mm, cyc.min_infeed_mm)
        # anticipation distance (Siemens CYCLE83 automatic _DIS1): 0.6 mm up to 30 mm depth,
        # depth/50 above, at most 7 mm
        ant = 0.6 if total <= 30 else min(total / 50.0, 7.0)
        seg_in: int | None = None
        seg_out: int | None = None
        prev = 0.0
        for k, depth in enumerate(depths):
            z = cyc.z_ref_mm - depth
            f = feed * (cyc.feed_factor_first if k == 0 else 1.0)
            if k > 0:
                if cyc.swarf_removal:
                    self._z_to(cyc.z_ref_mm - prev + ant, rapid=True)
                else:
                    pass  # chip breaking: continue from 1 mm above the last depth
            s = self._z_to(z, rapid=False, feed_mm_s=f)
            if seg_in is None:
                seg_in = s
            if k < len(depths) - 1:
                if cyc.swarf_removal:
                    self._z_to(cyc.z_safety_mm, rapid=True)
                    self._dwell_cycle(cyc.dwell_top_s, cyc.dwell_top_rev, speed)
                else:
                    self._z_to(z + 1.0, rapid=False, feed_mm_s=feed)
            prev = depth
        self._dwell_cycle(cyc.dwell_bottom_s, cyc.dwell_bottom_rev, speed)
        seg_out = self._z_to(cyc.z_retract_mm, rapid=True)
        return seg_in, seg_out

    def _tap(self, blk: Block, cyc: DrillCycle, x: float, y: float) -> _Hole:
        assert cyc.pitch_mm is not None and cyc.tap_speed_rpm is not None
        pitch = cyc.pitch_mm
        sst = cyc.tap_speed_rpm
        sst1 = cyc.retract_speed_rpm or sst
        for n in (sst, sst1):
            if n > self.spindle.max_speed_rpm:
                raise GCodeError(f"{cyc.name}: tapping speed {n:g} rpm exceeds the spindle "
                                 f"maximum {self.spindle.max_speed_rpm:g} rpm", line=blk.line,
                                 text=blk.text)  # fmt: skip
        before = self.sp_target
        # oriented spindle stop (SPOS=POSS): ramp to 0, then position control
        self._spindle_to(0.0, blk, wait=True)
        z0 = float(self.pos[self.zi])
        tap = (1.0, z0, cyc.spindle_pos_deg, 360.0 / pitch)
        ap = abs(pitch)
        a_sp = self.spindle.accel_rpm_s / 60.0 * ap
        j_sp = self.spindle.accel_rpm_s / self.spindle.jerk_time_s / 60.0 * ap
        seg_in = self._z_to(cyc.z_bottom_mm, rapid=False, feed_mm_s=sst * ap / 60.0, tap=tap,
                            tap_limits=(sst * ap / 60.0, a_sp, j_sp))  # fmt: skip
        if cyc.dwell_bottom_s:
            self._hold(cyc.dwell_bottom_s, tap=tap)
        seg_back = self._z_to(z0, rapid=False, feed_mm_s=sst1 * ap / 60.0, tap=tap,
                              tap_limits=(sst1 * ap / 60.0, a_sp, j_sp))  # fmt: skip
        # spindle back to speed control: SDAC direction with the programmed S, else as before
        after = before if cyc.dir_after is None else cyc.dir_after * (blk.speed_rpm or abs(before))
        self.sp_target = after
        seg_out = self._z_to(cyc.z_retract_mm, rapid=True)
        if self.wait_for_spindle and after != 0:
            self._hold(abs(after) / self.spindle.accel_rpm_s)
        assert seg_in is not None and seg_back is not None
        del seg_out
        return _Hole(x=x, y=y, cycle=cyc, seg_in=seg_in, seg_out=seg_back,
                     tool=self.active_tool, feed_mm_min=sst * ap, speed_rpm=sst,
                     block=self.block)  # fmt: skip


# ----------------------------------------------------------------------------------------------
# velocity planning


def _tangent_curv(seg: _Seg, at_end: bool, xi: int, yi: int) -> tuple[NDArray[np.float64], ...]:
    """Unit tangent and curvature vector (kappa * n) of a segment at its start or end."""
    if seg.kind == _SEG_LINE:
        return seg.u, np.zeros_like(seg.u)
    _cx, _cy, r0, dr, th0, dth = seg.arc
    sig = 1.0 if at_end else 0.0
    th = th0 + dth * sig
    r = r0 + dr * sig
    w = dth / seg.length
    t = seg.u.copy()
    t[xi] = -r * math.sin(th) * w
    t[yi] = r * math.cos(th) * w
    k = np.zeros_like(seg.u)
    k[xi] = -r * math.cos(th) * w * w
    k[yi] = -r * math.sin(th) * w * w
    return t, k


def _plan_velocities(
    plan: _Plan,
    b: _Builder,
    *,
    corner_tolerance_mm: float,
    lookahead_blocks: int,
) -> float:
    segs = plan.segs
    n = len(segs)
    dt = b.dt
    # junction limits between segment k and k+1
    vj = np.zeros(n + 1)
    for k in range(n - 1):
        s1, s2 = segs[k], segs[k + 1]
        blend = (
            s1.continuous
            and s1.kind != _SEG_HOLD
            and s2.kind != _SEG_HOLD
            and s2.v_lim > 0
            and s1.tap[0] == 0
            and s2.tap[0] == 0
            and s1.sp_target == s2.sp_target
        )
        if not blend:
            continue
        t1, k1 = _tangent_curv(s1, True, b.xi, b.yi)
        t2, k2 = _tangent_curv(s2, False, b.xi, b.yi)
        v = min(s1.v_lim, s2.v_lim)
        du = np.abs(t2 - t1)
        if np.max(du) > 1e-9:
            nz = du > 1e-12
            v = min(v, float(np.min(b.ovl[nz] * b.amax[nz] * dt / du[nz])))
            cos_t = float(np.clip(-np.dot(t1, t2), -1.0, 1.0))
            sin_half = math.sqrt(max(0.5 * (1.0 - cos_t), 0.0))
            if sin_half < 1.0 - 1e-12:
                a_c = min(s1.a_lim, s2.a_lim)
                v = min(v, math.sqrt(a_c * corner_tolerance_mm * sin_half / (1.0 - sin_half)))
        dk = np.abs(k2 - k1)
        if np.max(dk) > 1e-12:
            nz = dk > 1e-15
            v = min(v, float(np.min(np.sqrt(b.jmax[nz] * dt / dk[nz]))))
        vj[k + 1] = max(v, 0.0)
    # look-ahead horizon: a junction must allow a stop within the next N segments
    lengths = np.array([s.length if s.kind != _SEG_HOLD else 0.0 for s in segs])
    for k in range(1, n):
        if vj[k] <= 0:
            continue
        horizon, m = 0.0, k
        a_h, j_h = math.inf, math.inf
        while m < n and m < k + lookahead_blocks:
            horizon += lengths[m]
            a_h, j_h = min(a_h, segs[m].a_lim), min(j_h, segs[m].j_lim)
            if vj[m + 1] <= 0:
                break
            m += 1
        vj[k] = min(vj[k], _max_reachable(0.0, horizon, a_h, j_h, vj[k]))
    # backward and forward passes
    for k in range(n - 1, -1, -1):
        s = segs[k]
        if s.kind == _SEG_HOLD:
            vj[k] = vj[k + 1] = 0.0
            continue
        if vj[k] > 0:
            vj[k] = min(vj[k], _max_reachable(vj[k + 1], s.length, s.a_lim, s.j_lim, vj[k]))
    for k in range(n):
        s = segs[k]
        if s.kind == _SEG_HOLD or vj[k + 1] <= 0:
            continue
        vj[k + 1] = min(vj[k + 1], _max_reachable(vj[k], s.length, s.a_lim, s.j_lim, vj[k + 1]))
    # profiles. Every motion that starts from standstill and every hold starts on the cycle
    # grid (the NC interpolates in whole IPO cycles), so exact-stop points appear in DES_POS
    # exactly; the standstill before it lasts < 1 cycle. Holds last whole cycles.
    t = 0.0
    cache: dict[tuple[float, ...], tuple[tuple[float, ...], tuple[float, ...]]] = {}
    for k, s in enumerate(segs):
        if s.kind == _SEG_HOLD or vj[k] <= 0:
            t = math.ceil(t / dt - 1e-9) * dt
        s.t0 = t
        if s.kind == _SEG_HOLD:
            s.duration = math.ceil(s.duration / dt - 1e-9) * dt
            s.phases_t = (s.duration, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
            s.phases_j = (0.0,) * 7
            t += s.duration
            continue
        s.v0, s.v1 = float(vj[k]), float(vj[k + 1])
        key = (s.length, s.v0, s.v1, s.v_lim, s.a_lim, s.j_lim)
        prof = cache.get(key)
        if prof is None:
            prof = scurve_profile(s.length, s.v0, s.v1, s.v_lim, s.a_lim, s.j_lim)
            cache[key] = prof
        s.phases_t, s.phases_j = prof
        s.duration = float(sum(s.phases_t))
        t += s.duration
    return math.ceil(t / dt - 1e-9) * dt


def _eval_profile(
    tau: float, v0: float, phases_t: Sequence[float], phases_j: Sequence[float]
) -> tuple[float, float]:
    """Path position and speed at local time ``tau`` (Python twin of the kernel)."""
    s, v, a = 0.0, v0, 0.0
    for d, jj in zip(phases_t, phases_j, strict=True):
        if tau <= d:
            return (
                s + v * tau + a * tau * tau / 2 + jj * tau**3 / 6,
                v + a * tau + jj * tau**2 / 2,
            )
        s += v * d + a * d * d / 2 + jj * d**3 / 6
        v += a * d + jj * d * d / 2
        a += jj * d
        tau -= d
    return s, v


def _time_at_s(seg: _Seg, s_target: float) -> float:
    """Local time at which the path position of ``seg`` reaches ``s_target`` (bisection)."""
    lo, hi = 0.0, seg.duration
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if _eval_profile(mid, seg.v0, seg.phases_t, seg.phases_j)[0] < s_target:
            lo = mid
        else:
            hi = mid
    return hi


# ----------------------------------------------------------------------------------------------
# sampling kernel


@numba.njit(cache=True)
def _sample_kernel(
    c0: int,
    c1: int,
    dt: float,
    t_end: float,
    kind: NDArray[np.int8],
    t0: NDArray[np.float64],
    v0: NDArray[np.float64],
    ph_t: NDArray[np.float64],
    ph_j: NDArray[np.float64],
    length: NDArray[np.float64],
    p0: NDArray[np.float64],
    u: NDArray[np.float64],
    arc: NDArray[np.float64],
    xi: int,
    yi: int,
    zi: int,
    tap: NDArray[np.float64],
    sp_target: NDArray[np.float64],
    acc_rpm_cycle: float,
    state: NDArray[np.float64],
    pos_out: NDArray[np.float64],
    vel_out: NDArray[np.float64],
    sp_out: NDArray[np.float64],
    mode_out: NDArray[np.int8],
    ang_out: NDArray[np.float64],
    seg_out: NDArray[np.int64],
) -> None:
    n_seg = kind.shape[0]
    n_ax = p0.shape[1]
    k = int(state[0])
    cur = state[1]
    ang = state[2]
    for c in range(c0, c1):
        i = c - c0
        t = c * dt
        while k < n_seg - 1 and t >= t0[k + 1]:
            k += 1
        tau = t - t0[k]
        # profile
        s = 0.0
        v = v0[k]
        a = 0.0
        rem = tau
        done = False
        for ph in range(7):
            d = ph_t[k, ph]
            jj = ph_j[k, ph]
            if rem <= d:
                s += v * rem + a * rem * rem / 2.0 + jj * rem * rem * rem / 6.0
                v += a * rem + jj * rem * rem / 2.0
                done = True
                break
            s += v * d + a * d * d / 2.0 + jj * d * d * d / 6.0
            v += a * d + jj * d * d / 2.0
            a += jj * d
            rem -= d
        if not done or t >= t_end:
            v = 0.0
        if kind[k] == 2:
            s = 0.0
            v = 0.0
        if s > length[k]:
            s = length[k]
        if s < 0.0:
            s = 0.0
        for ax in range(n_ax):
            pos_out[ax, i] = p0[k, ax] + u[k, ax] * s
        if kind[k] == 1:
            sig = s / length[k] if length[k] > 0 else 0.0
            th = arc[k, 4] + arc[k, 5] * sig
            r = arc[k, 2] + arc[k, 3] * sig
            pos_out[xi, i] = arc[k, 0] + r * np.cos(th)
            pos_out[yi, i] = arc[k, 1] + r * np.sin(th)
        vel_out[i] = v * 60.0
        seg_out[i] = k
        if tap[k, 0] > 0.0:
            z = pos_out[zi, i]
            ang = tap[k, 2] + (tap[k, 1] - z) * tap[k, 3]
            # deg/s -> rpm: /6; zero while holding (dwell at thread depth)
            cur = 0.0 if kind[k] == 2 else -u[k, zi] * v * tap[k, 3] / 6.0
            mode_out[i] = 1
            sp_out[i] = cur
            ang_out[i] = ang
        else:
            target = sp_target[k]
            diff = target - cur
            if diff > acc_rpm_cycle:
                diff = acc_rpm_cycle
            elif diff < -acc_rpm_cycle:
                diff = -acc_rpm_cycle
            cur += diff
            ang = (ang + cur * 6.0 * dt) % 360.0
            mode_out[i] = 0
            sp_out[i] = cur
            ang_out[i] = ang
    state[0] = k
    state[1] = cur
    state[2] = ang


# ----------------------------------------------------------------------------------------------
# orchestration


def _resolve_start(
    start_position: Mapping[str, float] | None,
    axes: tuple[str, ...],
    axis_letters: Mapping[str, str],
) -> NDArray[np.float64]:
    start = np.zeros(len(axes))
    if start_position:
        name_of = dict(axis_letters)
        for key, v in start_position.items():
            name = key if key in axes else name_of.get(key.upper(), key)
            if name not in axes:
                raise ConfigError(f"start_position: unknown axis {key!r}; axes are {axes}")
            start[axes.index(name)] = float(v)
    return start


def _events_frame(rows: list[dict[str, object]]) -> pd.DataFrame:
    df = pd.DataFrame(rows, columns=[*EVENT_COLUMNS, "_key"])
    df = df.sort_values(["cycle", "_key"], kind="stable").reset_index(drop=True)
    return df[list(EVENT_COLUMNS)].astype(
        {
            "cycle": "int64",
            "kind": "object",
            "channel": "Int64",
            "seek_offset": "Int64",
            "gcode": "object",
            "ipo_gcode": "object",
            "selected_tool": "Int64",
            "active_tool": "Int64",
            "path": "object",
            "call_stack_level": "Int64",
        }
    )


def _cycle_at(t: float, dt: float) -> int:
    """First cycle whose time is at or after ``t``."""
    return math.ceil(t / dt - 1e-9)


def interpolate_chunks(
    program: Program,
    *,
    limits: Mapping[str, AxisLimits],
    spindle: SpindleLimits,
    cycle_time_s: float = 0.002,
    lookahead_blocks: int = 16,
    axes: Sequence[str] = ("X1", "Y1", "Z1", "C1", "B1"),
    start_position: Mapping[str, float] | None = None,
    axis_letters: Mapping[str, str] | None = None,
    chunk_cycles: int = 500_000,
    corner_tolerance_mm: float = 0.01,
    curvature_share: float = 0.5,
    wait_for_spindle: bool = True,
    tool_change_s: float = 0.0,
) -> Iterator[Trajectory]:
    """Interpolate a program and yield the trajectory in chunks of ``chunk_cycles`` cycles.

    Parameters
    ----------
    program : Program
        Parsed part program (:func:`cnctwin.sim.gcode.parse_program`).
    limits : mapping
        Axis name -> :class:`AxisLimits` for every axis in ``axes``.
    spindle : SpindleLimits
        Spindle limits.
    cycle_time_s : float, default 0.002
        Position-control (fine interpolation) cycle [s].
    lookahead_blocks : int, default 16
        Look-ahead depth: a junction velocity must allow a stop within this many segments.
    axes : sequence of str
        Interpolated axes, in output order.
    start_position : mapping, optional
        Axis name or letter -> position before the first block (default 0).
    axis_letters : mapping, optional
        Program axis letter -> axis name (default ``{"X": "X1", "Y": "Y1", "Z": "Z1",
        "C": "C1", "B": "B1"}``).
    chunk_cycles : int, default 500000
        Cycles per yielded chunk.
    corner_tolerance_mm : float, default 0.01
        Path deviation allowed at G64 corners for the junction velocity [mm].
    curvature_share : float, default 0.5
        Share of the axis acceleration and jerk reserved for curvature on arcs (0..1).
    wait_for_spindle : bool, default True
        Hold the program after spindle commands until the speed set point has ramped.
    tool_change_s : float, default 0
        Time of an M6 tool change [s] (chip to chip; the spindle is stopped first, the first
        M6 of a program and an M6 of the tool in the spindle take no time).

    Yields
    ------
    Trajectory
        Consecutive chunks; ``first_cycle`` is the offset of row 0. Events and holes are
        split by cycle (a hole goes to the chunk containing its ``start_cycle``).

    Raises
    ------
    ConfigError
        Axis without limits, programmed axis not mapped, bad options.
    GCodeError
        Spindle speed above the limit, feed per revolution with a stopped spindle.
    """
    axes_t = tuple(axes)
    letters = dict(axis_letters or {"X": "X1", "Y": "Y1", "Z": "Z1", "C": "C1", "B": "B1"})
    missing = [a for a in axes_t if a not in limits]
    if missing:
        raise ConfigError(f"no AxisLimits for axes {missing}; limits given for {list(limits)}")
    if not cycle_time_s > 0:
        raise ConfigError(f"cycle_time_s must be > 0, got {cycle_time_s}")
    if chunk_cycles < 1 or lookahead_blocks < 1:
        raise ConfigError("chunk_cycles and lookahead_blocks must be >= 1")
    if not 0.0 < curvature_share < 1.0:
        raise ConfigError(f"curvature_share must be in (0, 1), got {curvature_share}")
    start = _resolve_start(start_position, axes_t, letters)
    builder = _Builder(program, limits=limits, spindle=spindle, axes=axes_t, axis_letters=letters,
                       start=start, cycle_time_s=cycle_time_s, curvature_share=curvature_share,
                       wait_for_spindle=wait_for_spindle, tool_change_s=tool_change_s)  # fmt: skip
    plan = builder.run()
    segs = plan.segs
    if not segs:  # program without motion or time: one sample at the start
        builder._hold(cycle_time_s * 0.5)
    duration = _plan_velocities(plan, builder, corner_tolerance_mm=corner_tolerance_mm,
                                lookahead_blocks=lookahead_blocks)  # fmt: skip
    dt = cycle_time_s
    n_total = _cycle_at(duration, dt) + 1
    n_ax = len(axes_t)
    n_seg = len(segs)
    seg_kind = np.array([s.kind for s in segs], dtype=np.int8)
    seg_t0 = np.array([s.t0 for s in segs])
    seg_v0 = np.array([s.v0 for s in segs])
    seg_pt = np.array([s.phases_t for s in segs], dtype=np.float64).reshape(n_seg, 7)
    seg_pj = np.array([s.phases_j for s in segs], dtype=np.float64).reshape(n_seg, 7)
    seg_len = np.array([s.length for s in segs])
    seg_p0 = np.array([s.p0 for s in segs], dtype=np.float64).reshape(n_seg, n_ax)
    seg_u = np.array([s.u for s in segs], dtype=np.float64).reshape(n_seg, n_ax)
    seg_arc = np.array([s.arc for s in segs], dtype=np.float64).reshape(n_seg, 6)
    seg_tap = np.array([s.tap for s in segs], dtype=np.float64).reshape(n_seg, 4)
    seg_sp = np.array([s.sp_target for s in segs])
    seg_block = np.array([s.block for s in segs], dtype=np.int32)
    seg_tool = np.array([s.tool for s in segs], dtype=np.int32)
    xi, yi, zi = max(builder.xi, 0), max(builder.yi, 0), max(builder.zi, 0)

    events, holes = _tables(program, plan, dt, n_total)
    state = np.zeros(3)
    acc_cycle = spindle.accel_rpm_s * dt
    for c0 in range(0, n_total, chunk_cycles):
        c1 = min(n_total, c0 + chunk_cycles)
        m = c1 - c0
        pos = np.empty((n_ax, m))
        vel = np.empty(m)
        sp = np.empty(m)
        mode = np.empty(m, dtype=np.int8)
        ang = np.empty(m)
        seg_idx = np.empty(m, dtype=np.int64)
        _sample_kernel(c0, c1, dt, duration, seg_kind, seg_t0, seg_v0, seg_pt, seg_pj, seg_len,
                       seg_p0, seg_u, seg_arc, xi, yi, zi, seg_tap, seg_sp, acc_cycle, state,
                       pos, vel, sp, mode, ang, seg_idx)  # fmt: skip
        ev = events[(events["cycle"] >= c0) & (events["cycle"] < c1)].reset_index(drop=True)
        ho = holes[(holes["start_cycle"] >= c0) & (holes["start_cycle"] < c1)]
        yield Trajectory(
            des_pos={ax: pos[i] for i, ax in enumerate(axes_t)},
            path_velocity_mm_min=vel,
            spindle_speed_cmd_rpm=sp,
            spindle_mode=mode,
            spindle_pos_cmd_deg=ang,
            block_index=seg_block[seg_idx],
            tool=seg_tool[seg_idx],
            events=ev,
            holes=ho.reset_index(drop=True),
            cycle_time_s=dt,
            duration_s=duration,
            first_cycle=c0,
        )


def _tables(program: Program, plan: _Plan, dt: float, n_total: int) -> tuple[pd.DataFrame, ...]:
    segs = plan.segs
    n_seg = len(segs)

    def seg_start_cycle(k: int) -> int:
        if k >= n_seg:
            return n_total - 1
        return min(_cycle_at(segs[k].t0, dt), n_total - 1)

    rows: list[dict[str, object]] = [
        {
            "cycle": 0,
            "kind": "call",
            "channel": 1,
            "seek_offset": 0,
            "gcode": None,
            "ipo_gcode": None,
            "selected_tool": None,
            "active_tool": None,
            "path": program.call_path,
            "call_stack_level": 1,
            "_key": -1.0,
        }
    ]
    blocks = program.blocks
    for seg_k, bi, sel, act in plan.block_events:
        blk = blocks[bi]
        ipo = {"rapid": "G0", "linear": "G1", "arc_cw": "G2", "arc_ccw": "G3"}.get(
            blk.kind, blk.motion
        )
        rows.append({"cycle": seg_start_cycle(seg_k), "kind": "block", "channel": 1,
                     "seek_offset": blk.offset, "gcode": blk.text.strip(), "ipo_gcode": ipo,
                     "selected_tool": sel, "active_tool": act, "path": None,
                     "call_stack_level": None, "_key": float(seg_k)})  # fmt: skip
    for seg_k, at_end, path, level in plan.call_events:
        if at_end:
            s = segs[seg_k]
            cyc = min(_cycle_at(s.t0 + s.duration, dt), n_total - 1)
        else:
            cyc = seg_start_cycle(seg_k)
        rows.append({"cycle": cyc, "kind": "call", "channel": 1, "seek_offset": 0,
                     "gcode": None, "ipo_gcode": None, "selected_tool": None,
                     "active_tool": None, "path": path, "call_stack_level": level,
                     "_key": seg_k + 0.75 if at_end else seg_k + 0.25})  # fmt: skip
    events = _events_frame(rows)

    hrows = []
    cache: dict[tuple[object, ...], float] = {}
    for i, h in enumerate(plan.holes):
        z_top = h.cycle.z_ref_mm
        times = []
        for k in (h.seg_in, h.seg_out):
            s = segs[k]
            z_start = float(s.p0[plan.zi])
            dz = abs(z_start - z_top)
            key = (s.phases_t, s.v0, round(dz, 12))
            tau = cache.get(key)
            if tau is None:
                tau = _time_at_s(s, dz)
                cache[key] = tau
            times.append(s.t0 + tau)
        pitch = h.cycle.pitch_mm
        hrows.append({"hole": i, "x_mm": h.x, "y_mm": h.y, "z_top_mm": z_top,
                      "z_bottom_mm": h.cycle.z_bottom_mm,
                      "start_cycle": _cycle_at(times[0], dt), "end_cycle": _cycle_at(times[1], dt),
                      "tool": h.tool, "kind": h.cycle.kind, "feed_mm_min": h.feed_mm_min,
                      "speed_rpm": h.speed_rpm,
                      "pitch_mm": float("nan") if pitch is None else pitch,
                      "block": h.block})  # fmt: skip
    holes = pd.DataFrame(hrows, columns=list(HOLE_COLUMNS))
    holes = holes.astype({"hole": "int64", "start_cycle": "int64", "end_cycle": "int64",
                          "tool": "int64", "block": "int64", "x_mm": "float64",
                          "y_mm": "float64", "z_top_mm": "float64", "z_bottom_mm": "float64",
                          "feed_mm_min": "float64", "speed_rpm": "float64",
                          "pitch_mm": "float64"})  # fmt: skip
    return events, holes


def interpolate(
    program: Program,
    *,
    limits: Mapping[str, AxisLimits],
    spindle: SpindleLimits,
    cycle_time_s: float = 0.002,
    lookahead_blocks: int = 16,
    axes: Sequence[str] = ("X1", "Y1", "Z1", "C1", "B1"),
    start_position: Mapping[str, float] | None = None,
    axis_letters: Mapping[str, str] | None = None,
    corner_tolerance_mm: float = 0.01,
    curvature_share: float = 0.5,
    wait_for_spindle: bool = True,
    tool_change_s: float = 0.0,
) -> Trajectory:
    """Interpolate a whole program (see :func:`interpolate_chunks` for the parameters).

    Parameters
    ----------
    program : Program
        Parsed part program (:func:`cnctwin.sim.gcode.parse_program`).
    limits : mapping
        Axis name -> :class:`AxisLimits` for every axis in ``axes``.
    spindle : SpindleLimits
        Spindle limits.
    cycle_time_s : float, default 0.002
        Position-control (fine interpolation) cycle [s].
    lookahead_blocks : int, default 16
        Look-ahead depth: a junction velocity must allow a stop within this many segments.
    axes : sequence of str
        Interpolated axes, in output order.
    start_position : mapping, optional
        Axis name or letter -> position before the first block (default 0).
    axis_letters : mapping, optional
        Program axis letter -> axis name (default X, Y, Z, C, B -> X1, Y1, Z1, C1, B1).
    corner_tolerance_mm : float, default 0.01
        Path deviation allowed at G64 corners for the junction velocity [mm].
    curvature_share : float, default 0.5
        Share of the axis acceleration and jerk reserved for curvature on arcs (0..1).
    wait_for_spindle : bool, default True
        Hold the program after spindle commands until the speed set point has ramped.
    tool_change_s : float, default 0
        Time of an M6 tool change [s] (chip to chip; the spindle is stopped first, the first
        M6 of a program and an M6 of the tool in the spindle take no time).

    Returns
    -------
    Trajectory
        All cycles of the program in one object (``first_cycle`` = 0). For long programs
        prefer :func:`interpolate_chunks` to bound memory (about 70 bytes per cycle for five
        axes).
    """
    chunks = list(
        interpolate_chunks(
            program, limits=limits, spindle=spindle, cycle_time_s=cycle_time_s,
            lookahead_blocks=lookahead_blocks, axes=axes, start_position=start_position,
            axis_letters=axis_letters, chunk_cycles=2**62, corner_tolerance_mm=corner_tolerance_mm,
            curvature_share=curvature_share, wait_for_spindle=wait_for_spindle,
            tool_change_s=tool_change_s,
        )
    )  # fmt: skip
    return chunks[0]
