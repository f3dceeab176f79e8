"""Adaptive feed: hold the cutting torque at a target by the feed override (issue 26).

The edge proposes a feed override from the spindle's cutting torque (the calibrated soft
sensor: Kt I - B n - tau_f - J dOmega/dt); the control applies it within its bounds. The
controller is model-based: in the linear edge-force model (``mean_milling_load``) the mean
cutting torque at a fixed engagement is T = A + B c, with the feed per tooth c proportional
to the override, so T(o) = T_e + (T_now - T_e) o / o_now, T_e the edge share (the torque at
zero chip). The override that gives the target is therefore

    o_new = o_now (T_target - T_e) / (T_now - T_e),

moved by a fraction ``gain`` of the way per update (0 < gain <= 1: 1 is a dead-beat step of
the model; less damps the measurement noise and the engagement changes the model does not
see). ``edge_share`` (T_e / T_target, default 0.25: the edge force's share of the tangential
force at a typical chip, docs/optimizer.md) sets T_e; the loop is stable for any share in
0..1 with gain <= 1 because the update is monotone in T_now.

Samples while the spindle's speed command changes, and for the settling time after
(:class:`cnctwin.spindle.SpeedChangeFlags`: the current then accelerates the rotor, ~20 Nm on a
run-up against ~2.6 Nm of the cut, known only as well as J and a derivative that a chunk of
one OPC UA value cannot give), and a standing spindle, carry no cutting torque: they are
left out of every mean below (the torque processor flags the same samples).

Air (torque below ``air_nm``): the override goes to its maximum (cutting air costs time).
Overload (torque above ``overload_nm`` for ``overload_s``): the override goes to its minimum
and ``state.overload`` asks for a feed hold. Breakage (the torque falls to the air level in
the middle of a cut that ran for ``min_cut_s`` where the engagement model still expects a
cut, also within the last fifth of an update's samples, so the request comes with the update
in which it happened): ``state.breakage`` asks for a stop and the override goes to its minimum.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cnctwin.exceptions import ConfigError
from cnctwin.spindle import SpeedChangeFlags, SpindleModel

__all__ = ["AdaptiveFeedController", "AdaptiveState"]


@dataclass
class AdaptiveState:
    """What the controller decided at its last update.

    Attributes
    ----------
    override_pct : float
        Requested feed override [%].
    torque_nm : float
        Mean cutting torque of the last update's samples [Nm] (NaN: no usable sample).
    cutting : bool
        The tool cut (torque above the air level).
    overload : bool
        The torque stayed above the overload limit: feed hold requested.
    breakage : bool
        The cut's torque collapsed to air in the middle of a cut: stop requested.
    history : list of tuple
        (override, torque, cutting) per update.
    """

    override_pct: float = 100.0
    torque_nm: float = math.nan
    cutting: bool = False
    overload: bool = False
    breakage: bool = False
    history: list[tuple[float, float, bool]] = field(default_factory=list)


class AdaptiveFeedController:
    """Feed override from the spindle's cutting torque (model-based, see module docstring).

    Parameters
    ----------
    model : SpindleModel
        The calibrated spindle (the soft sensor).
    target_nm : float
        Cutting torque to hold [Nm].
    min_pct, max_pct : float, default 50 and 120
        Override bounds [%].
    air_nm : float, default 0.15 x target
        Below: air [Nm].
    overload_nm : float, default 1.5 x target
        Above for ``overload_s``: overload [Nm].
    overload_s : float, default 0.2
        [s].
    gain : float, default 0.5
        Share of the model's step taken per update (0 < gain <= 1).
    edge_share : float, default 0.25
        Edge-force share of the target torque [-].
    fs_hz : float, default 500
        Sample rate of the signals [Hz].
    min_cut_s : float, default 0.5
        Cutting time before a collapse counts as a breakage [s].
    update_s : float, optional
        Samples gathered per override update [s] (e.g. 0.1 when the signals arrive every
        20 ms over OPC UA: the override moves on a 100 ms mean, breakage is judged on every
        call); None: every call updates.
    settle_s : float, default 0.3
        Samples for this long after a change of the speed command, and at the start (the
        speed before the first sample is not known: a live stream may join a run-up), carry
        no cutting torque (:class:`cnctwin.spindle.SpeedChangeFlags`) [s]; 0: only the
        changing samples themselves.
    """

    def __init__(self, model: SpindleModel, *, target_nm: float, min_pct: float = 50.0,
                 max_pct: float = 120.0, air_nm: float | None = None,
                 overload_nm: float | None = None, overload_s: float = 0.2, gain: float = 0.5,
                 edge_share: float = 0.25, fs_hz: float = 500.0, min_cut_s: float = 0.5,
                 update_s: float | None = None, settle_s: float = 0.3) -> None:
        if not (math.isfinite(target_nm) and target_nm > 0):
            raise ConfigError(f"target_nm must be a positive torque, got {target_nm!r}")
        if not (0.0 < min_pct <= max_pct):
            raise ConfigError(f"override bounds {min_pct}..{max_pct} %: give 0 < min <= max")
        if not (0.0 < gain <= 1.0):
            raise ConfigError(f"gain must be in (0, 1], got {gain}")
        if not (0.0 <= edge_share < 1.0):
            raise ConfigError(f"edge_share must be in [0, 1), got {edge_share}")
        self.model = model
        self.target_nm = float(target_nm)
        self.min_pct, self.max_pct = float(min_pct), float(max_pct)
        self.air_nm = 0.15 * target_nm if air_nm is None else float(air_nm)
        self.overload_nm = 1.5 * target_nm if overload_nm is None else float(overload_nm)
        self.overload_s = float(overload_s)
        self.gain = float(gain)
        self.edge_nm = edge_share * target_nm
        self.fs_hz = float(fs_hz)
        self.min_cut_s = float(min_cut_s)
        self.state = AdaptiveState(override_pct=100.0)
        self._over_s = 0.0
        self._cut_s = 0.0
        if update_s is not None and not (math.isfinite(update_s) and update_s > 0):
            raise ConfigError(f"update_s must be a positive time [s], got {update_s!r}")
        self.update_s = update_s
        self._buf_tau: list[NDArray[np.float64]] = []
        self._buf_s = 0.0
        if not (math.isfinite(settle_s) and settle_s >= 0):
            raise ConfigError(f"settle_s must be >= 0 [s], got {settle_s!r}")
        self._flags = SpeedChangeFlags(fs_hz=self.fs_hz, settle_s=settle_s,
                                       settled_at_start=False)

    def set_target(self, target_nm: float) -> None:
        """Hold a new torque (a power target at a new speed: P / omega); the air, overload and
        edge levels keep their ratio to the target.

        Parameters
        ----------
        target_nm : float
            Cutting torque to hold [Nm].
        """
        if not (math.isfinite(target_nm) and target_nm > 0):
            raise ConfigError(f"target_nm must be a positive torque, got {target_nm!r}")
        k = float(target_nm) / self.target_nm
        self.target_nm = float(target_nm)
        self.air_nm *= k
        self.overload_nm *= k
        self.edge_nm *= k

    def update(self, current_a: ArrayLike, speed_rpm: ArrayLike, *,
               expect_cut: bool | None = None, edge_nm: float | None = None) -> AdaptiveState:
        """One step from the samples since the last call.

        Breakage is judged on every call (the stop request comes with the samples in which
        the torque collapsed); the override is updated once at least ``update_s`` of samples
        have arrived (every call without ``update_s``), from their mean torque.

        Parameters
        ----------
        current_a, speed_rpm : array-like
            Spindle current [A] and speed [rpm] of the samples since the last call.
        expect_cut : bool, optional
            The engagement model (the program through the stock, ``cnctwin.engagement``)
            expects the tool in the material at the end of these samples: a collapse of the
            torque then is a breakage, not the end of a cut. None (not known): breakage is
            not judged (a tool leaving the part looks the same).
        edge_nm : float, optional
            The edge (rubbing) torque at the present engagement [Nm], from the engagement
            model and the material's edge coefficients scaled by the measured-to-model ratio
            (:class:`cnctwin.edge.adaptive.AdaptiveProcessor`); replaces the fixed
            ``edge_share`` of the target from now on.

        Returns
        -------
        AdaptiveState
        """
        if edge_nm is not None and math.isfinite(edge_nm) and edge_nm >= 0.0:
            self.edge_nm = float(edge_nm)
        i = np.asarray(current_a, dtype=np.float64)
        n = np.asarray(speed_rpm, dtype=np.float64)
        st = self.state
        if i.size == 0:
            return st
        with np.errstate(invalid="ignore"):
            tau = self.model.cutting_torque(i, n, fs_hz=self.fs_hz) * np.sign(n)
        # steady speed only: a run-up's or braking's current is the rotor's, not the cut's
        ok = np.isfinite(tau) & (np.abs(n) > 50.0) & (self._flags.update(n) == 0)
        t_new = float(np.mean(tau[ok])) if ok.any() else math.nan
        # a collapse inside these samples: their last fifth already at the air level (the
        # stop request then comes with them, not with the next call)
        tail = slice(min(int(0.8 * i.size), i.size - 1), None)
        ok_t = ok[tail]
        t_tail = float(np.mean(tau[tail][ok_t])) if ok_t.any() else math.nan
        dt = i.size / self.fs_hz
        cut_before = self._cut_s
        if math.isfinite(t_new) and t_new > self.air_nm:
            self._cut_s += dt
        if (expect_cut and cut_before >= self.min_cut_s and math.isfinite(t_tail)
                and t_tail < self.air_nm):
            st.breakage = True
        if st.breakage:
            st.override_pct = self.min_pct  # stop requested: no faster feed into a broken tool
            st.torque_nm = t_new
            st.history.append((st.override_pct, t_new, False))
            return st
        self._buf_tau.append(tau[ok])
        self._buf_s += dt
        if self.update_s is not None and self._buf_s < self.update_s - 1e-9:
            return st
        both = np.concatenate(self._buf_tau) if self._buf_tau else np.zeros(0)
        t_now = float(np.mean(both)) if both.size else math.nan
        span = self._buf_s
        self._buf_tau, self._buf_s = [], 0.0
        st.torque_nm = t_now
        st.cutting = bool(math.isfinite(t_now) and t_now > self.air_nm)
        o = st.override_pct
        if not st.cutting:
            self._cut_s = 0.0
            self._over_s = 0.0
            o_new = self.max_pct
        else:
            self._over_s = self._over_s + span if t_now > self.overload_nm else 0.0
            if self._over_s >= self.overload_s:
                st.overload = True
                o_new = self.min_pct
            else:
                # the linear edge-force model: T(o) = T_e + (T_now - T_e) o / o_now
                denom = max(t_now - self.edge_nm, 1e-3 * self.target_nm)
                o_model = o * (self.target_nm - self.edge_nm) / denom
                o_new = o + self.gain * (o_model - o)
        st.override_pct = float(min(max(o_new, self.min_pct), self.max_pct))
        st.history.append((st.override_pct, t_now, st.cutting))
        return st
