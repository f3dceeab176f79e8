"""A feed override the simulated control obeys while the program runs (issue 26, point 3).

The interpolator plans the program at 100 %. :class:`OverridePlayer` plays that plan at a
feed override that may change from one control cycle to the next, as a control does: the
path parameter (seconds of the 100 % plan) advances by ``dt x override`` per cycle on feed
moves (G1/G2/G3 outside rigid tapping), by ``dt`` elsewhere (rapid moves, dwells, spindle
ramps and tapping are not feed-overridden); the applied override follows the requested one
at a limited rate (the control's override ramp) and stays within its bounds. Positions,
spindle commands, blocks and tools are read from the plan at the path parameter (linear
interpolation between its cycles); an NC event is emitted in the cycle in which the path
passes it. :func:`cnctwin.sim.simulate` takes the player's chunks (an iterator), so a
controller that reads each chunk's recording can set the override of the next: a closed loop
in one process.

Time scaling keeps the path; velocities scale with the override, accelerations with its
square and jerks with its cube (plus the ramp's own terms). The NC's plan at 100 % is within
the axes' limits; above 100 % the player caps the override where the plan is near them
(``axis_limits``: per plan cycle the largest override with v o, a o^2 and j o^3 within the
limits, anticipated at the ramp rate), as a control's look-ahead does; below 100 % every
term shrinks.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from cnctwin.exceptions import ConfigError
from cnctwin.sim.gcode import Program

__all__ = ["OverrideChunk", "OverridePlayer", "plan_of"]

FEED_KINDS = frozenset({"linear", "arc_cw", "arc_ccw"})


@dataclass
class OverrideChunk:
    """One chunk the player produced (the trajectory interface :func:`simulate` reads).

    Attributes
    ----------
    des_pos, spindle_speed_cmd_rpm, spindle_mode, spindle_pos_cmd_deg, block_index, tool
        Per executed cycle, as in :class:`cnctwin.sim.interpolator.Trajectory`.
    events : pandas.DataFrame
        NC events, ``cycle`` = executed cycle offset from the program start.
    holes : pandas.DataFrame
        Empty (the plan's hole table counts plan cycles).
    cycle_time_s : float
        Control cycle [s].
    override_pct : numpy.ndarray
        Applied feed override per cycle [%] (100 where the cycle is not a feed move).
    plan_time_s : numpy.ndarray
        Path parameter at the end of each cycle: seconds of the 100 % plan [s].
    """

    des_pos: dict[str, NDArray[np.float64]]
    spindle_speed_cmd_rpm: NDArray[np.float64]
    spindle_mode: NDArray[Any]
    spindle_pos_cmd_deg: NDArray[np.float64]
    block_index: NDArray[Any]
    tool: NDArray[Any]
    events: pd.DataFrame
    holes: pd.DataFrame
    cycle_time_s: float
    override_pct: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    plan_time_s: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))


class OverridePlayer:
    """Play a planned trajectory at a changing feed override.

    Parameters
    ----------
    plan : Trajectory
        The whole program interpolated at 100 % (:func:`cnctwin.sim.interpolator.interpolate`).
    program : Program
        The parsed program (which blocks are feed moves).
    min_pct, max_pct : float, default 0 and 120
        Bounds of the applied override [%] (SINUMERIK's feed override switch: 0-120 %).
    rate_pct_per_s : float, default 200
        Largest change of the applied override per second [%/s] (the control's ramp).
    axis_limits : dict, optional
        Axis name -> (max velocity [mm/min], max acceleration [mm/s^2], max jerk [mm/s^3]):
        the override above 100 % is capped where the plan runs near them.

    Attributes
    ----------
    cycle : int
        Executed cycles so far.
    applied_pct : float
        The override applied in the last cycle [%].
    """

    def __init__(self, plan: Any, program: Program, *, min_pct: float = 0.0,
                 max_pct: float = 120.0, rate_pct_per_s: float = 200.0,
                 axis_limits: dict[str, tuple[float, float, float]] | None = None) -> None:
        if not (0.0 <= min_pct <= max_pct):
            raise ConfigError(f"override bounds {min_pct}..{max_pct} %: give 0 <= min <= max")
        if not rate_pct_per_s > 0:
            raise ConfigError(f"rate_pct_per_s must be positive, got {rate_pct_per_s}")
        self.plan = plan
        self.min_pct, self.max_pct = float(min_pct), float(max_pct)
        self.rate_pct_per_s = float(rate_pct_per_s)
        self.dt = float(plan.cycle_time_s)
        n = int(np.asarray(plan.spindle_speed_cmd_rpm).size)
        self.n_plan = n
        kinds = np.array([b.kind in FEED_KINDS for b in program.blocks] + [False])
        bi = np.asarray(plan.block_index, dtype=np.int64)
        mode = np.asarray(plan.spindle_mode)
        self._feed = kinds[np.clip(bi, 0, len(kinds) - 1)] & (mode == 0)
        self._cap = self._override_cap(axis_limits or {})
        self._tau = 0.0  # plan cycles (fractional)
        self.cycle = 0
        self.applied_pct = 100.0
        ev = plan.events
        self._events = ev.sort_values("cycle", kind="stable").reset_index(drop=True) \
            if len(ev) else ev
        self._ev_next = 0

    def _override_cap(self, limits: dict[str, tuple[float, float, float]]
                      ) -> NDArray[np.float64]:
        """Per plan cycle the largest override [%] within the axes' limits (>= 100: the
        plan itself is the NC's, within them), anticipated backwards at the ramp rate."""
        cap = np.full(self.n_plan, np.inf)
        dt = self.dt
        for ax, (v_max, a_max, j_max) in limits.items():
            if ax not in self.plan.des_pos:
                continue
            x = np.asarray(self.plan.des_pos[ax], dtype=np.float64)
            if x.size < 4:
                continue
            v = np.abs(np.gradient(x, dt)) * 60.0  # [mm/min]
            a = np.abs(np.gradient(np.gradient(x, dt), dt))
            j = np.abs(np.gradient(np.gradient(np.gradient(x, dt), dt), dt))
            with np.errstate(divide="ignore"):
                c = np.minimum.reduce([v_max / v, np.sqrt(a_max / a), np.cbrt(j_max / j)])
            cap = np.minimum(cap, 100.0 * c)
        cap = np.maximum(cap, 100.0)
        # the applied override falls at most rate x dt per cycle: reach a cap in time
        step = self.rate_pct_per_s * dt
        out = cap.copy()
        for i in range(out.size - 2, -1, -1):
            out[i] = min(out[i], out[i + 1] + step)
        return out

    @property
    def done(self) -> bool:
        """True once the whole plan has been played."""
        return self._tau >= self.n_plan - 1

    def step(self, n_cycles: int, requested_pct: float) -> OverrideChunk:
        """Play the next ``n_cycles`` cycles with the requested override.

        Parameters
        ----------
        n_cycles : int
            Cycles to play (fewer at the end of the plan).
        requested_pct : float
            Requested feed override [%]; the applied one ramps to it within the bounds.

        Returns
        -------
        OverrideChunk
        """
        target = min(max(float(requested_pct), self.min_pct), self.max_pct)
        d_max = self.rate_pct_per_s * self.dt
        taus = []
        ovr = []
        last = self.n_plan - 1
        for _ in range(int(n_cycles)):
            if self._tau >= last:
                break
            i = min(int(self._tau), last)
            if self._feed[i]:
                goal = min(target, float(self._cap[i]))
                self.applied_pct += min(max(goal - self.applied_pct, -d_max), d_max)
                rate = self.applied_pct / 100.0
                ovr.append(self.applied_pct)
            else:
                rate = 1.0
                ovr.append(100.0)
            self._tau = min(self._tau + rate, float(last))
            taus.append(self._tau)
        tau = np.asarray(taus, dtype=np.float64)
        lo = np.floor(tau).astype(np.int64)
        hi = np.minimum(lo + 1, last)
        w = tau - lo
        p = self.plan

        def lerp(x: Any) -> NDArray[np.float64]:
            a = np.asarray(x, dtype=np.float64)
            return a[lo] * (1.0 - w) + a[hi] * w

        def pick(x: Any) -> NDArray[Any]:
            return np.asarray(x)[np.where(w < 0.5, lo, hi)]

        first = self.cycle
        self.cycle += tau.size
        events = self._emit(tau, first)
        return OverrideChunk(
            des_pos={k: lerp(v) for k, v in p.des_pos.items()},
            spindle_speed_cmd_rpm=lerp(p.spindle_speed_cmd_rpm),
            spindle_mode=pick(p.spindle_mode), spindle_pos_cmd_deg=lerp(p.spindle_pos_cmd_deg),
            block_index=pick(p.block_index), tool=pick(p.tool), events=events,
            holes=p.holes.iloc[0:0] if isinstance(p.holes, pd.DataFrame) else pd.DataFrame(),
            cycle_time_s=self.dt, override_pct=np.asarray(ovr, dtype=np.float64),
            plan_time_s=tau * self.dt)

    def _emit(self, tau: NDArray[np.float64], first: int) -> pd.DataFrame:
        ev = self._events
        if not len(ev) or tau.size == 0:
            return ev.iloc[0:0] if len(ev) else pd.DataFrame(columns=getattr(ev, "columns", []))
        plan_c = ev["cycle"].to_numpy(dtype=np.float64)
        j0 = self._ev_next
        j1 = int(np.searchsorted(plan_c, tau[-1], side="right"))
        self._ev_next = j1
        out = ev.iloc[j0:j1].copy()
        if len(out):
            k = np.searchsorted(tau, plan_c[j0:j1], side="left")
            out["cycle"] = (first + np.minimum(k, tau.size - 1)).astype(np.int64)
        return out

    def chunks(self, controller: Any, *, chunk_cycles: int = 50) -> Iterator[OverrideChunk]:
        """Chunks until the plan ends, each at the override ``controller()`` returns then.

        Parameters
        ----------
        controller : callable
            ``controller() -> float``: the requested override [%], asked before each chunk
            (a closed loop updates it from the recording of the previous chunk).
        chunk_cycles : int, default 50
            Cycles per chunk (50 = 100 ms at 2 ms).

        Yields
        ------
        OverrideChunk
        """
        while not self.done:
            c = self.step(chunk_cycles, float(controller()))
            if c.block_index.size == 0:
                return
            yield c


def plan_of(program: Program, machine: Any) -> Any:
    """The program interpolated at 100 % on a machine (one whole trajectory).

    Parameters
    ----------
    program : Program
        Parsed program.
    machine : Machine
        Its limits.

    Returns
    -------
    Trajectory
    """
    from cnctwin.sim.simulation import iter_chunks

    parts = list(iter_chunks(program, machine, 10_000_000))
    if len(parts) != 1:
        raise ConfigError("the plan must be one trajectory")
    return parts[0]
