"""Live tool life per tool: holes used, the wear model's remaining life and its interval.

The edge runtime feeds each completed hole to a :class:`ToolLifeTracker`, which keeps per T
number the holes drilled and their mean cutting torque, and answers with a
:class:`ToolLifeState`:

* **usage**: holes drilled with the tool, against the planned ``life_holes`` of the tool
  table (what the control's tool management counts);
* **wear**: the flank wear ``VB = wear_offset_um + wear_um_per_increase * increase`` from
  the relative increase of the hole's mean cutting torque over the tool's first
  ``wear_baseline_holes`` (Subramanian & Cook [1]: the drilling torque grows linearly with
  the average flank wear; :class:`~cnctwin.usecases.wear.WearEstimator`), set means removing
  the within-set heating pattern (:func:`~cnctwin.usecases.wear.relative_increase`);
* **remaining life**: the holes until ``VB`` reaches ``wear_limit_um``, extrapolating the
  wear trend with its 90 % residual-bootstrap interval
  (:func:`~cnctwin.usecases.wear.forecast_remaining_life`) over the tool's last
  ``window_holes`` and over the most recent fifth of them (the nearer forecast, the union
  of the intervals, widened by the wear estimate's own uncertainty ``wear_std_um``);
  without a wear calibration the remaining usages ``life_holes - used`` (exact, no
  interval); the nearer of the two when both are given (the first limit reached).

The remaining holes become a time with the tool's recent hole period (median time between its
holes on the recording's clock): the predicted tool change of OPC 40501's
``ToolChangePrognosis`` and the ``ToolLife`` of MTConnect's ``CuttingTool`` asset.

References
----------
.. [1] K. Subramanian, N. H. Cook, "Sensing of drill wear and prediction of drill life",
   J. Eng. Ind. 99 (1977) 295-301.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from cnctwin.exceptions import ConfigError, IdentificationError
from cnctwin.usecases.wear import forecast_remaining_life, relative_increase

__all__ = ["ToolLifeLimits", "ToolLifeState", "ToolLifeTracker"]

_Z90 = 1.6449
"""Two-sided 90 % normal quantile (the interval of the bootstrap)."""


@dataclass(frozen=True)
class ToolLifeLimits:
    """What the tool table says about one tool's life.

    Attributes
    ----------
    name : str
        The tool's name (catalogue number) or ``"T<n>"``.
    life_holes : int or None
        Planned life in holes (usages).
    wear_limit_um : float or None
        Flank wear at which the tool is changed [µm].
    wear_um_per_increase : float or None
        Flank wear per unit relative torque increase [µm].
    wear_offset_um : float
        Flank wear at the baseline holes [µm].
    wear_std_um : float
        Standard uncertainty of a wear estimate [µm].
    baseline_holes : int
        The tool's first holes whose mean torque is the new-tool reference (the
        ``--baseline`` of ``cnctwin wear`` that gave ``wear_um_per_increase``).
    """

    name: str = ""
    life_holes: int | None = None
    wear_limit_um: float | None = None
    wear_um_per_increase: float | None = None
    wear_offset_um: float = 0.0
    wear_std_um: float = 0.0
    baseline_holes: int = 30

    @classmethod
    def from_tool(cls, spec: Any) -> ToolLifeLimits:
        """From a :class:`cnctwin.machine.ToolSpec` (the tool table's entry)."""
        return cls(name=spec.name or f"T{spec.number}", life_holes=spec.life_holes,
                   wear_limit_um=spec.wear_limit_um,
                   wear_um_per_increase=spec.wear_um_per_increase,
                   wear_offset_um=spec.wear_offset_um, wear_std_um=spec.wear_std_um,
                   baseline_holes=spec.wear_baseline_holes)

    @property
    def wear_model(self) -> bool:
        """The tool has a wear calibration and a wear limit."""
        return self.wear_limit_um is not None and self.wear_um_per_increase is not None


@dataclass(frozen=True)
class ToolLifeState:
    """One tool's life after a hole.

    Attributes
    ----------
    tool : int
        T number.
    name : str
        Tool name.
    used_holes : int
        Holes drilled with the tool so far.
    life_holes : int or None
        Planned life in holes (tool table).
    torque_increase : float
        Relative increase of the mean cutting torque over the baseline holes [-] (NaN while
        the baseline is being drilled).
    wear_um : float
        Flank-wear estimate [µm] (NaN without a wear calibration or during the baseline).
    wear_limit_um : float or None
        Wear limit [µm].
    remaining_holes : float
        Holes left until the first limit (NaN: unknown; ``inf``: the wear trend does not reach
        its limit within ten times the holes seen).
    remaining_low, remaining_high : float
        90 % interval of ``remaining_holes`` [holes] (equal to it for the usage limit).
    basis : str
        ``"wear"``, ``"usage"`` or ``"none"``: which limit ``remaining_holes`` comes from.
    reason : str
        Why the remaining life is unknown (empty when it is known).
    hole_period_s : float
        Median time between the tool's recent holes [s] (NaN before its second hole).
    remaining_s, remaining_low_s, remaining_high_s : float
        ``remaining_*`` times ``hole_period_s`` [s]: the time to the tool change.
    time_s : float
        Time of the hole on the recording's clock [s].
    """

    tool: int
    name: str
    used_holes: int
    life_holes: int | None
    torque_increase: float
    wear_um: float
    wear_limit_um: float | None
    remaining_holes: float
    remaining_low: float
    remaining_high: float
    basis: str
    reason: str
    hole_period_s: float
    remaining_s: float
    remaining_low_s: float
    remaining_high_s: float
    time_s: float

    def as_payload(self) -> dict[str, Any]:
        """The state as a ``tool_life`` result payload (JSON values, units in the keys)."""
        out = {k: (None if isinstance(v, float) and math.isnan(v) else v)
               for k, v in asdict(self).items()}
        # JSON has no infinity: a trend that never reaches the limit is said so
        inf = [k for k, v in out.items() if isinstance(v, float) and math.isinf(v)]
        for k in inf:
            out[k] = None
        out["never_reaches_limit"] = bool(inf)
        out["units"] = {"wear_um": "um", "wear_limit_um": "um", "hole_period_s": "s",
                        "remaining_s": "s", "remaining_low_s": "s", "remaining_high_s": "s",
                        "time_s": "s", "remaining_holes": "holes", "torque_increase": "-"}
        return out


@dataclass
class _Tool:
    torque_nm: list[float] = field(default_factory=list)
    time_s: list[float] = field(default_factory=list)
    forecast: tuple[int, float, float, float] | None = None  # (at used, rem, lo, hi)


class ToolLifeTracker:
    """Per-tool life from the completed holes (see the module text).

    Parameters
    ----------
    limits : mapping
        T number -> :class:`ToolLifeLimits` (the tool table's tools, each with its baseline
        holes); a hole with a tool not in it is counted under its T number without limits.
    set_size : int or None, default 6
        Holes per set for the set means of :func:`~cnctwin.usecases.wear.relative_increase`
        (None: per hole).
    window_holes : int, default 300
        The wear trend is fitted on the tool's last ``window_holes`` holes.
    forecast_every : int, default 6
        Holes between two forecasts (a bootstrap of ``n_boot`` fits); in between the last
        forecast counts down by the holes drilled since.
    min_trend_holes : int, default 24
        Holes after the baseline before a wear trend is extrapolated.
    n_boot : int, default 100
        Bootstrap draws of the interval.
    period_holes : int, default 20
        Recent holes whose median period converts holes into time.

    Raises
    ------
    ConfigError
        A bad option.
    """

    def __init__(self, limits: Mapping[int, ToolLifeLimits], *,
                 set_size: int | None = 6, window_holes: int = 300, forecast_every: int = 6,
                 min_trend_holes: int = 24, n_boot: int = 100, period_holes: int = 20) -> None:
        for name, v, lo in (("window_holes", window_holes, 8),
                            ("forecast_every", forecast_every, 1),
                            ("min_trend_holes", min_trend_holes, 4), ("n_boot", n_boot, 20),
                            ("period_holes", period_holes, 2)):
            if isinstance(v, bool) or not isinstance(v, int) or v < lo:
                raise ConfigError(f"ToolLifeTracker: {name} must be a whole number >= {lo}, "
                                  f"not {v!r}")
        if set_size is not None and (not isinstance(set_size, int) or set_size < 1):
            raise ConfigError(f"ToolLifeTracker: set_size must be None or >= 1, not {set_size!r}")
        self.limits = dict(limits)
        self.set_size = set_size
        self.window_holes, self.forecast_every = window_holes, forecast_every
        self.min_trend_holes, self.n_boot, self.period_holes = (min_trend_holes, n_boot,
                                                                period_holes)
        self._tools: dict[int, _Tool] = {}

    def tools(self) -> list[int]:
        """T numbers known (tool table and tools seen), sorted."""
        return sorted({*self.limits, *self._tools})

    def update(self, tool: int, torque_mean_nm: float, time_s: float) -> ToolLifeState:
        """Add a completed hole of ``tool`` and return the tool's life after it.

        Parameters
        ----------
        tool : int
            T number of the hole.
        torque_mean_nm : float
            The hole's mean cutting torque [Nm] (NaN: counted, not used for the wear).
        time_s : float
            End of the hole on the recording's clock [s].

        Returns
        -------
        ToolLifeState
        """
        t = self._tools.setdefault(int(tool), _Tool())
        t.torque_nm.append(float(torque_mean_nm))
        t.time_s.append(float(time_s))
        return self.state(int(tool))

    def state(self, tool: int) -> ToolLifeState:
        """The tool's life now (no hole added).

        Parameters
        ----------
        tool : int
            T number.

        Returns
        -------
        ToolLifeState
        """
        lim = self.limits.get(tool, ToolLifeLimits(name=f"T{tool}"))
        t = self._tools.get(tool, _Tool())
        used = len(t.torque_nm)
        nan = float("nan")
        inc_now, wear_now = nan, nan
        wear_rem: tuple[float, float, float] | None = None
        reason = ""
        base = lim.baseline_holes
        if used > base:
            try:
                inc = relative_increase(t.torque_nm, baseline=base,
                                        set_size=self.set_size)
                inc_now = float(inc[-1])
            except (ConfigError, IdentificationError) as exc:
                inc, reason = None, f"no torque reference: {exc}"
            if inc is not None and lim.wear_model:
                slope = float(lim.wear_um_per_increase)  # type: ignore[arg-type]
                wear = lim.wear_offset_um + slope * inc
                wear_now = float(wear[-1])
                wear_rem = self._wear_forecast(t, used, wear, lim, base)
                if wear_rem is None:
                    reason = (f"the wear trend needs {self.min_trend_holes} holes after the "
                              f"{base} baseline holes ({used} drilled)")
        elif lim.wear_model:
            reason = f"drilling the {base} baseline holes ({used} so far)"
        candidates: list[tuple[float, float, float, str]] = []
        if wear_rem is not None:
            candidates.append((*wear_rem, "wear"))
        if lim.life_holes is not None:
            left = float(max(lim.life_holes - used, 0))
            candidates.append((left, left, left, "usage"))
        if candidates:
            rem, lo, hi, basis = min(candidates, key=lambda c: c[0])
            reason = ""
        else:
            rem = lo = hi = nan
            basis = "none"
            if not reason:
                reason = ("the tool table gives neither life_holes nor wear_limit_um with "
                          "wear_um_per_increase for this tool")
        period = self._period(t)
        return ToolLifeState(
            tool=tool, name=lim.name or f"T{tool}", used_holes=used, life_holes=lim.life_holes,
            torque_increase=inc_now, wear_um=wear_now, wear_limit_um=lim.wear_limit_um,
            remaining_holes=rem, remaining_low=lo, remaining_high=hi, basis=basis,
            reason=reason, hole_period_s=period, remaining_s=rem * period,
            remaining_low_s=lo * period, remaining_high_s=hi * period,
            time_s=t.time_s[-1] if t.time_s else nan)

    def _period(self, t: _Tool) -> float:
        if len(t.time_s) < 2:
            return float("nan")
        d = np.diff(np.asarray(t.time_s[-(self.period_holes + 1):], dtype=np.float64))
        d = d[np.isfinite(d) & (d > 0)]
        return float(np.median(d)) if d.size else float("nan")

    def _trend_points(self, wear: Any, used: int, base: int) -> tuple[Any, Any]:
        """The wear trend's points after the baseline: one per set at its centre (a set
        mean belongs to the set's middle hole, not to its last: fitted at the last hole
        the trend would lag half a set), or one per hole without sets."""
        k = self.set_size or 1
        if k == 1:
            return np.arange(base, used, dtype=np.float64), wear[base:]
        starts = np.arange(0, used, k)
        ends = np.minimum(starts + k, used)
        centres = (starts + ends - 1) / 2.0
        keep = starts >= base
        if keep.sum() < 4:  # too few sets yet: the holes after the baseline
            return np.arange(base, used, dtype=np.float64), wear[base:]
        return centres[keep], wear[starts[keep]]

    def _wear_forecast(self, t: _Tool, used: int, wear: Any, lim: ToolLifeLimits,
                       base: int) -> tuple[float, float, float] | None:
        limit_um = float(lim.wear_limit_um or 0.0)
        band = _Z90 * lim.wear_std_um  # the estimate's own error, as a band on the limit
        if wear[-1] >= limit_um + band:
            t.forecast = (used, 0.0, 0.0, 0.0)
            return 0.0, 0.0, 0.0
        if used < base + self.min_trend_holes:
            return None
        last = t.forecast
        if last is None or used - last[0] >= self.forecast_every:
            idx, w = self._trend_points(np.asarray(wear, dtype=np.float64), used, base)
            ahead = float(used - 1) - float(idx[-1])  # holes since the last point's centre
            rem, lo, hi = math.inf, math.inf, 0.0
            # the whole trend and the recent one (wear accelerates towards the end of life:
            # the recent trend sees it first); the nearer forecast, the union of intervals
            per = float(self.set_size or 1)  # holes per trend point
            for window in (max(int(self.window_holes / per), 4),
                           max(int(max(self.min_trend_holes, self.window_holes // 5) / per),
                               4)):
                kw: dict[str, Any] = {"window": window, "degree": 2, "n_boot": self.n_boot,
                                      "seed": used}
                fc = forecast_remaining_life(idx, w, limit_um=limit_um, **kw)
                rem, lo, hi = (min(rem, fc.remaining), min(lo, fc.remaining_low),
                               max(hi, fc.remaining_high))
                if band > 0.0:  # the true wear may reach the limit while the estimate is lower
                    lo = min(lo, forecast_remaining_life(idx, w, limit_um=limit_um - band,
                                                         **kw).remaining_low)
                    hi = max(hi, forecast_remaining_life(idx, w, limit_um=limit_um + band,
                                                         **kw).remaining_high)
            t.forecast = last = (used, rem - ahead, lo - ahead, hi - ahead)
        since = float(used - last[0])
        return (max(last[1] - since, 0.0), max(last[2] - since, 0.0),
                max(last[3] - since, 0.0))
