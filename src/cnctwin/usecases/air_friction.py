"""Spindle friction against the calibration, judged where no tool cuts.

The calibrated twin predicts the spindle current at constant speed without a cut
(``SpindleModel.predict_current_a(0, n)``, thesis Eq. 4.4: Coulomb and viscous friction over
Kt). Where the tool cannot be cutting (every feed axis still, the speed steady: the edge's
``air`` flag) the measured current must match it within what the twin cannot know: the bearing
friction drifts with temperature (~0.5 %/K, ~10 % over a warm-up) and the calibration has its
uncertainty. A friction rise (a bearing, a seal, lubrication) shows as a lasting offset there.
A learned detector cannot see a friction that was high from the start of its learning; this
check compares with the machine file, so it sees it in the first air seconds.

Below ``min_speed_rpm`` the check does not judge: there the low-speed (Stribeck) friction is
most of the air current, and its calibrated term (:meth:`cnctwin.spindle.SpindleModel.
stribeck_nm`) comes without a stated uncertainty.

Production leaves little time with every axis still and the spindle turning (none at all in
some drawn jobs: the spindle changes speed while the axes reposition). The NC program says
where the tool cannot cut while the axes move: a rapid traverse (``G0``, the interpolator's
motion group as the control reports it with each block, ``IpoGC``) outside a machining cycle
(a cycle's own feed moves do not show as blocks; a modal ``MCALL`` calls a cycle at every
position). :class:`RapidAir` marks those samples from the NC events; a cut in ``G0`` would be a
collision.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from cnctwin.analysis.segments import samples_since
from cnctwin.exceptions import ConfigError
from cnctwin.spindle import SpeedChangeFlags
from cnctwin.usecases.holes import modal_cycle_call

__all__ = ["AirFrictionCheck", "FrictionFinding", "RapidAir"]


@dataclass(frozen=True)
class FrictionFinding:
    """A window of air samples whose current departs from the calibrated twin.

    Attributes
    ----------
    cycle : int
        Last cycle of the window.
    residual_a : float
        Mean measured minus predicted current over the window [A].
    predicted_a : float
        Mean predicted current over the window [A].
    tolerance_a : float
        What the check allows [A].
    speed_rpm : float
        Mean speed of the window [rpm].
    """

    cycle: int
    residual_a: float
    predicted_a: float
    tolerance_a: float
    speed_rpm: float

    @property
    def message(self) -> str:
        """The finding in words."""
        word = "rose" if self.residual_a > 0 else "fell"
        return (f"spindle air current {self.predicted_a + self.residual_a:.2f} A at "
                f"{self.speed_rpm:.0f} rpm against {self.predicted_a:.2f} A of the calibrated "
                f"twin ({self.residual_a:+.2f} A, tolerance {self.tolerance_a:.2f} A): the "
                f"friction {word} (bearing, seal, lubrication) or the calibration is stale")


class AirFrictionCheck:
    """Mean air current over windows of ``window_s`` of air samples against the twin.

    Parameters
    ----------
    window_s : float, default 0.5
        Air samples (not necessarily consecutive) per judged window [s] (production leaves
        little air time with the spindle turning: 0.7 s in a 97 s draw; the mean of 250
        samples has a noise of ~0.02 A).
    rel_tol : float, default 0.25
        Allowed offset, a fraction of the predicted current (friction drift with temperature
        ~10 %, the calibration's uncertainty, the current sensor's offset) [-].
    abs_tol_a : float, default 0.1
        Allowed offset at least [A].
    min_speed_rpm : float, default 600
        Slower samples are not judged (the Stribeck friction dominates there).
    settle_s : float, default 0.3
        Samples after a speed change that are not judged [s] (the speed rule is
        :class:`cnctwin.spindle.SpeedChangeFlags`, as for the cutting torque).
    """

    def __init__(self, *, window_s: float = 0.5, rel_tol: float = 0.25, abs_tol_a: float = 0.1,
                 min_speed_rpm: float = 600.0, settle_s: float = 0.3) -> None:
        if window_s <= 0 or rel_tol < 0 or abs_tol_a < 0 or settle_s < 0:
            raise ConfigError("window_s must be > 0 and rel_tol, abs_tol_a, settle_s >= 0; got "
                              f"{window_s}, {rel_tol}, {abs_tol_a}, {settle_s}")
        self.window_s, self.rel_tol, self.abs_tol_a = window_s, rel_tol, abs_tol_a
        self.min_speed_rpm, self.settle_s = min_speed_rpm, settle_s
        self._sum = np.zeros(3)  # residual, predicted, speed
        self._n = 0
        self._flags: SpeedChangeFlags | None = None
        self.windows = 0
        self.departed = False

    def update(self, cycles: NDArray[np.int64], current_a: NDArray[np.float64],
               predicted_a: NDArray[np.float64], speed_rpm: NDArray[np.float64],
               air: NDArray[np.float64], *, cycle_time_s: float) -> list[FrictionFinding]:
        """Judge the next consecutive cycles; the findings of the windows they complete (a
        departure is reported once, again only after a window within the tolerance)."""
        n = np.asarray(speed_rpm, dtype=np.float64)
        if self._flags is None:  # the torque's own rule: a step > 1 rpm, settling, too slow
            self._flags = SpeedChangeFlags(fs_hz=1.0 / cycle_time_s, speed_step_rpm=1.0,
                                           settle_s=self.settle_s,
                                           min_speed_rpm=self.min_speed_rpm)
        steady = self._flags.update(n) == 0
        r = np.asarray(current_a, dtype=np.float64) - np.asarray(predicted_a, dtype=np.float64)
        ok = (np.asarray(air) == 1.0) & steady & np.isfinite(r)
        need = max(1, round(self.window_s / cycle_time_s))
        out: list[FrictionFinding] = []
        idx = np.flatnonzero(ok)
        pred_a = np.asarray(predicted_a, dtype=np.float64)
        k = 0
        while k < idx.size:  # one pass per window the chunk completes, not per sample
            take = idx[k:k + need - self._n]
            self._sum += (r[take].sum(), pred_a[take].sum(), np.abs(n[take]).sum())
            self._n += take.size
            k += take.size
            if self._n < need:
                break
            res, pred, spd = self._sum / self._n
            tol = max(self.abs_tol_a, self.rel_tol * abs(pred))
            self.windows += 1
            self._sum[:] = 0.0
            self._n = 0
            bad = bool(abs(res) > tol and math.isfinite(res))
            if bad and not self.departed:
                out.append(FrictionFinding(int(cycles[take[-1]]), float(res), float(pred),
                                           float(tol), float(spd)))
            self.departed = bad
        return out


class RapidAir:
    """Samples where the NC moves the tool in rapid traverse outside a machining cycle.

    Parameters
    ----------
    settle_s : float, default 0.1
        Samples after the end of a feed move, a cycle or an unknown state that are not marked
        [s] (the current loop and the chip leaving the tool).

    Notes
    -----
    State per NC event, in cycle order: a ``block`` event sets the motion from its ``ipo_gcode``
    (``G0``: rapid; any other or none: not) and the modal cycle call
    (:func:`~cnctwin.usecases.holes.modal_cycle_call`: ``MCALL CYCLE..`` on, a bare ``MCALL``
    or ``G80`` off, block numbers and comments allowed); a ``call`` event into a path naming a
    cycle (``CYCLE``) marks a cycle active until the next call event (the return into the
    caller). Before the first block event
    of a stream (or after a restart without the state) nothing is marked.
    """

    def __init__(self, *, settle_s: float = 0.1) -> None:
        if settle_s < 0:
            raise ConfigError(f"settle_s must be >= 0, not {settle_s}")
        self.settle_s = settle_s
        self._g0 = False
        self._mcall = False
        self._in_cycle = False
        self._since = 0  # samples since the state last was not rapid air

    @property
    def rapid(self) -> bool:
        """The state after the events seen so far: rapid traverse outside a cycle."""
        return self._g0 and not self._mcall and not self._in_cycle

    def _event(self, kind: object, gcode: object, ipo: object, path: object) -> None:
        kind = kind if isinstance(kind, str) else ""  # (pd.NA has no truth value)
        if kind == "block":
            self._g0 = isinstance(ipo, str) and ipo.strip().upper() in ("G0", "G00")
            call = modal_cycle_call(gcode) if isinstance(gcode, str) else None
            if call is not None:
                self._mcall = call
        elif kind == "call":
            self._in_cycle = isinstance(path, str) and "CYCLE" in path.upper()

    def update(self, cycles: NDArray[np.int64], events: pd.DataFrame,
               *, cycle_time_s: float) -> NDArray[np.bool_]:
        """Mark the next consecutive cycles.

        Parameters
        ----------
        cycles : numpy.ndarray of int64
            The chunk's cycles, increasing.
        events : pandas.DataFrame
            The chunk's NC events (``cycle``, ``kind``, ``gcode``, ``ipo_gcode``, ``path``;
            missing columns count as no value).
        cycle_time_s : float
            Sample period [s].

        Returns
        -------
        numpy.ndarray of bool
            True where the tool is in rapid traverse outside a cycle and has been for
            ``settle_s``.
        """
        n = int(np.asarray(cycles).size)
        state = np.zeros(n, dtype=bool)
        pos = 0
        if len(events):
            ec = events["cycle"].to_numpy(dtype=np.int64)
            order = (np.arange(ec.size) if ec.size < 2 or bool((ec[1:] >= ec[:-1]).all())
                     else np.argsort(ec, kind="stable"))  # chunks come sorted: no pandas sort
            # plain lists (a few rows per chunk: to_numpy with na_value costs more than them)
            col = [events[c].tolist() if c in events.columns else [None] * ec.size
                   for c in ("kind", "gcode", "ipo_gcode", "path")]
            at = np.searchsorted(cycles, ec, side="left")
            for j in order.tolist():
                k = min(int(at[j]), n)
                if k > pos:
                    state[pos:k] = self.rapid
                    pos = k
                self._event(col[0][j], col[1][j], col[2][j], col[3][j])
        state[pos:] = self.rapid
        need = round(self.settle_s / cycle_time_s)
        since = samples_since(~state, before=self._since)
        if n:
            self._since = int(since[-1])
        return state & (since > need)
