"""Wear-adaptive drilling monitor: limits that follow slow wear, from part 1 with physics.

A teach-in envelope (:class:`~cnctwin.usecases.anomaly.EnvelopeDetector`, the vendor baseline)
is taught on a new tool; as the flank wear grows the cutting torque rises (thesis §5.1,
+28 % over the life of the simulated drill) and the envelope alarms on every hole. The monitor
here keeps a *wear index* ``w``, the ratio of the measured cutting torque to a reference,
tracked **per hole from the holes themselves** with a **bounded rate** (``max_step`` per hole):
slow wear is followed, a sudden change (hardness change, breakage) is not absorbed, and a hole
that alarmed is never learned.

The reference is either

* the mean torque profile of the first holes (teach-in), or
* the **physics-predicted** torque of each sample (``expected``): the Kienzle drilling torque of
  the tool and chip load (:func:`drilling_torque_nm`, handbook constants, independent of the
  simulator's own fit), so monitoring starts with the first part and no teach-in. The first
  ``settle_holes`` holes use a wide band (``initial_tolerance``, the model's uncertainty) and
  calibrate the index freely; then the band narrows to ``tolerance``.

References
----------
.. [1] Kienzle, O., "Die Bestimmung von Kräften und Leistungen an spanenden Werkzeugen und
   Werkzeugmaschinen", VDI-Z 94 (1952) 299-305; drilling torque
   ``Mc = f kc D^2 sin(kappa) / 8000`` with ``kc = kc1.1 h^-mc``, ``h = (f/2) sin(kappa)``
   (ISCAR / Sandvik technical handbooks).
.. [2] VDI 3323 material groups; C45 (AISI 1045) annealed kc1.1 = 1500 N/mm^2, mc = 0.22;
   grey cast iron kc1.1 = 1150 N/mm^2, mc = 0.20 (ISCAR handbook tables).
.. [3] Komet Brinkhaus "WP1+X": breakage detection from the first part without teach-in
   (docs/reference docs/reference/peers.md §1.5, the baseline to beat).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray

from cnctwin.exceptions import ConfigError, SignalNotFoundError
from cnctwin.usecases.anomaly import (
    Detector,
    EnvelopeDetector,
    PhysicsResidualDetector,
    SpectralDetector,
    TappingDetector,
)

__all__ = [
    "DETECTORS",
    "KIENZLE_PARAMETERS",
    "WearAdaptiveDetector",
    "drilling_torque_nm",
    "expected_torque_stream",
]

KIENZLE_PARAMETERS: dict[str, dict[str, float]] = {
    "aisi1045": {"kc1_n_per_mm2": 1500.0, "mc": 0.22},
    "grey_cast_iron": {"kc1_n_per_mm2": 1150.0, "mc": 0.20},
}
"""Handbook Kienzle constants (kc1.1 [N/mm^2], mc [-]) by material, reference [2]."""


def drilling_torque_nm(
    feed_mm_per_rev: ArrayLike,
    *,
    diameter_mm: float = 8.5,
    point_angle_deg: float = 140.0,
    kc1_n_per_mm2: float = 1500.0,
    mc: float = 0.22,
    depth_mm: ArrayLike = math.inf,
) -> NDArray[np.float64]:
    """Kienzle drilling torque, with the engagement of the drill point [Nm].

    Parameters
    ----------
    feed_mm_per_rev : array-like
        Feed f [mm/rev].
    diameter_mm : float, default 8.5
        Drill diameter D [mm] (thesis §3.2.2: 8.5 mm TiAlN carbide drill).
    point_angle_deg : float, default 140
        Point angle sigma [deg], kappa = sigma / 2 (typical carbide drill).
    kc1_n_per_mm2, mc : float
        Kienzle constants (:data:`KIENZLE_PARAMETERS`) [N/mm^2], [-].
    depth_mm : array-like, default inf
        Depth of the drill tip below the surface [mm]; ``inf`` = full engagement.

    Returns
    -------
    numpy.ndarray
        Cutting torque [Nm].

    Notes
    -----
    ``Mc = f kc D^2 sin(kappa) / 8000`` with ``kc = kc1.1 h^-mc`` and ``h = (f/2) sin(kappa)``
    [1]. While the point enters (tip depth ``z`` below the point length
    ``L = (D/2) / tan(kappa)``) the engaged lip reaches the radius ``rho = D/2 z/L``; the torque
    of a lip cut at uniform force per length grows with ``rho^2``: ``Mc (z/L)^2``.

    Examples
    --------
    >>> round(float(drilling_torque_nm(400 / 2400)), 2)  # thesis §5.1 cut, C45 handbook values
    3.72
    """
    f = np.maximum(np.asarray(feed_mm_per_rev, dtype=np.float64), 1e-6)
    kappa = math.radians(point_angle_deg / 2.0)
    h = f / 2.0 * math.sin(kappa)
    kc = kc1_n_per_mm2 * np.maximum(h, 1e-3) ** (-mc)
    full = f * kc * diameter_mm**2 * math.sin(kappa) / 8000.0
    cone = diameter_mm / 2.0 / math.tan(kappa)
    eng = np.clip(np.asarray(depth_mm, dtype=np.float64) / cone, 0.0, 1.0) ** 2
    return np.asarray(full * eng, dtype=np.float64)


def expected_torque_stream(
    data: pd.DataFrame,
    holes: pd.DataFrame,
    *,
    material: str = "aisi1045",
    diameter_mm: float = 8.5,
    point_angle_deg: float = 140.0,
    full_engagement_only: bool = True,
) -> NDArray[np.float64]:
    """Physics-predicted cutting torque for each sample of a detector stream [Nm].

    Parameters
    ----------
    data : pandas.DataFrame
        Stream of :func:`~cnctwin.usecases.anomaly.signal_stream` with ``hole`` and
        ``progress`` (0..1 over the cut).
    holes : pandas.DataFrame
        Hole record of the same recordings (:func:`~cnctwin.usecases.holes.hole_record`): gives
        per hole the feed ``feed_mm_min``, the speed ``speed_rpm`` and the depth ``depth_mm``
        measured from the drive signals (the NC program's F and S words would do as well).
    material : str, default 'aisi1045'
        Key of :data:`KIENZLE_PARAMETERS`.
    diameter_mm, point_angle_deg : float
        Drill geometry, see :func:`drilling_torque_nm`.
    full_engagement_only : bool, default True
        NaN while the drill point enters (tip depth below the point length): the entry ramp
        depends on where the surface was detected, which the model cannot know to a sample;
        :class:`WearAdaptiveDetector` does not judge NaN samples.

    Returns
    -------
    numpy.ndarray
        Expected torque per row [Nm]; NaN outside the holes (``hole`` < 0).

    Notes
    -----
    The tip depth of a sample is ``progress x depth_mm`` (the feed is constant in the cut).
    """
    if material not in KIENZLE_PARAMETERS:
        raise ConfigError(f"material {material!r} unknown; KIENZLE_PARAMETERS has "
                          f"{sorted(KIENZLE_PARAMETERS)}")
    for c in ("hole", "progress"):
        if c not in data.columns:
            raise SignalNotFoundError(f"expected_torque_stream needs column {c!r} in data "
                                      "(signal_stream with a hole record)")
    per = holes.set_index("hole")[["feed_mm_min", "speed_rpm", "depth_mm"]]
    h = data["hole"].to_numpy()
    known = np.isin(h, per.index.to_numpy())
    out = np.full(len(data), np.nan)
    if known.any():
        rows = per.loc[h[known]]
        f = rows["feed_mm_min"].to_numpy(np.float64) / np.abs(rows["speed_rpm"].to_numpy(
            np.float64))
        depth = data["progress"].to_numpy(np.float64)[known] * rows["depth_mm"].to_numpy(
            np.float64)
        out[known] = drilling_torque_nm(f, diameter_mm=diameter_mm,
                                        point_angle_deg=point_angle_deg, depth_mm=depth,
                                        **KIENZLE_PARAMETERS[material])
        if full_engagement_only:
            cone = diameter_mm / 2.0 / math.tan(math.radians(point_angle_deg / 2.0))
            out[np.flatnonzero(known)[depth < cone]] = np.nan
    return out


class WearAdaptiveDetector(Detector):
    """Torque band around a reference scaled by a wear index tracked per hole, bounded rate.

    Parameters
    ----------
    signal : str, default 'torque_nm'
        Monitored value (cutting torque of the twin; the spindle current works too).
    progress : str, default 'progress'
        Position in the cut, 0..1.
    segment : str, default 'hole'
        Hole number; a change (or the progress going back) ends a hole. Values < 0 or a NaN
        progress are outside the cuts: not judged.
    expected : str or None, default None
        Key of the physics-predicted value (e.g. ``'expected_torque_nm'`` from
        :func:`expected_torque_stream`): monitoring from part 1, ``learn_one`` optional.
        ``None``: the reference is the mean profile over ``n_bins`` learned by ``learn_one``
        (teach-in).
    n_bins : int, default 50
        Bins over the progress (profile and shape correction).
    smoothing : float, default 50
        EWMA time constant of signal and reference [samples] (100 ms at 500 Hz); restarts per
        hole.
    tolerance : float, default 0.06
        Allowed rise above the reference, a fraction of it (harder material, a chipped edge,
        wear faster than ``max_step``) [-].
    tolerance_below : float, default 0.12
        Allowed drop below the reference [-]. Wider: a tool that cooled during a long break
        cuts ~5 % lower on its first hole (the simulated drill runs at ~500 degC, 1e-4 /K),
        while a breakage drops the torque by ~90 %.
    initial_tolerance : float, default 0.3
        The same while fewer than ``settle_holes`` holes have been tracked (physics mode: the
        uncertainty of the handbook constants and of the torque estimate) [-].
    settle_holes : int, default 3
        Holes over which the wear index is calibrated freely (mean of the hole ratios) before
        its rate is bounded; in teach-in mode the teach-in counts as settled.
    max_step : float, default 0.01
        Largest change of the wear index (and of each bin of the shape correction) per hole,
        relative [-]. The simulated drill wears by at most ~0.3 %/hole even with its whole
        life compressed into 300 holes; a hardness change of +10 % is 10 holes of steps.
    shape_gain : float, default 0.2
        Gain of the per-bin shape correction learned from good holes (depth effects the
        reference does not know) [-].
    min_engagement : float, default 0.8
        Samples whose reference is below this fraction of the hole's full-engagement
        reference (the point entering) are not judged [-].
    judge_until : float, default 0.99
        Samples later in the cut are not judged: the feed decelerates at the bottom and the
        torque falls to zero within ~6 samples (simulated wear run), which the constant-feed
        reference cannot follow [-].

    Notes
    -----
    Per sample: ``r = w c(b) e`` with ``e`` the base reference (expected value or learned bin
    mean) and ``c(b)`` the shape correction; score ``= |S(v) - S(r)| / (tol S(r)) - 1`` (tol:
    ``tolerance`` above, ``tolerance_below`` below the reference; S: the
    EWMA, started as a running mean), above 0 is anomalous; a sample is judged once the EWMA
    has run ``smoothing`` samples in the hole. At the end of a hole without an alarm,
    ``q(b)`` = mean of ``v / e`` per bin, ``rho`` = median of ``q(b) / c(b)``;
    ``w <- w + clip(rho - w, ±max_step w)``
    (unbounded running mean while settling) and ``c(b) <- c(b) + clip(g (q(b)/rho - c(b)),
    ±max_step)``. :meth:`acknowledge` accepts a new level after a real change (re-settles).
    """

    def __init__(
        self,
        *,
        signal: str = "torque_nm",
        progress: str = "progress",
        segment: str = "hole",
        expected: str | None = None,
        n_bins: int = 50,
        smoothing: float = 50.0,
        tolerance: float = 0.06,
        tolerance_below: float = 0.12,
        initial_tolerance: float = 0.3,
        settle_holes: int = 3,
        max_step: float = 0.01,
        shape_gain: float = 0.2,
        min_engagement: float = 0.8,
        judge_until: float = 0.99,
    ) -> None:
        if n_bins < 1 or smoothing < 1 or settle_holes < 1:
            raise ConfigError(f"n_bins, smoothing and settle_holes must be >= 1; got {n_bins}, "
                              f"{smoothing}, {settle_holes}")
        if not (tolerance > 0 and tolerance_below > 0 and initial_tolerance > 0
                and max_step >= 0):
            raise ConfigError("the tolerances must be > 0 and max_step >= 0")
        self.signal, self.progress, self.segment, self.expected = (
            signal, progress, segment, expected)
        self.n_bins, self.smoothing = n_bins, smoothing
        self.tolerance, self.initial_tolerance = tolerance, initial_tolerance
        self.tolerance_below = tolerance_below
        self.settle_holes, self.max_step = settle_holes, max_step
        self.shape_gain, self.min_engagement = shape_gain, min_engagement
        self.judge_until = judge_until
        self.inputs = (signal, progress, segment) + ((expected,) if expected else ())
        self.wear_index = 1.0
        """Measured / reference torque, tracked per hole [-]."""
        self.holes_tracked = 0
        self.wear_history: list[float] = []
        """``wear_index`` after every learned hole (trend for the report)."""
        self._teach_sum = np.zeros(n_bins)
        self._teach_n = np.zeros(n_bins)
        self._teach_full = math.nan
        self._shape = np.ones(n_bins)
        self._scoring = False
        self._reset_hole(None)

    def _params(self) -> dict[str, Any]:
        return {"signal": self.signal, "progress": self.progress, "segment": self.segment,
                "expected": self.expected, "n_bins": self.n_bins, "smoothing": self.smoothing,
                "tolerance": self.tolerance, "tolerance_below": self.tolerance_below,
                "initial_tolerance": self.initial_tolerance,
                "settle_holes": self.settle_holes, "max_step": self.max_step,
                "shape_gain": self.shape_gain, "min_engagement": self.min_engagement,
                "judge_until": self.judge_until}

    def _reset_hole(self, key: float | None) -> None:
        self._hole: float | None = key
        self._last_p = -math.inf
        self._sv: float | None = None
        self._sr = 0.0
        self._warm = 0
        self._full = 0.0
        self._q_sum = np.zeros(self.n_bins)
        self._q_n = np.zeros(self.n_bins)
        self._alarmed = False

    def _finish_hole(self, *, learn: bool) -> None:
        """End of a hole: learn the wear index and shape from it unless it alarmed."""
        ok = self._q_n > 0
        if learn and not self._alarmed and ok.any():
            q = self._q_sum[ok] / self._q_n[ok]
            rho = float(np.median(q / self._shape[ok]))
            if math.isfinite(rho) and rho > 0:
                if self.holes_tracked < self.settle_holes:  # calibration: running means
                    k = self.holes_tracked + 1
                    self.wear_index += (rho - self.wear_index) / k
                    self._shape[ok] += (q / rho - self._shape[ok]) / k
                else:
                    lim = self.max_step * self.wear_index
                    self.wear_index += float(np.clip(rho - self.wear_index, -lim, lim))
                    self._shape[ok] += np.clip(self.shape_gain * (q / rho - self._shape[ok]),
                                               -self.max_step, self.max_step)
                self.holes_tracked += 1
                self.wear_history.append(self.wear_index)

    def acknowledge(self) -> None:
        """Accept the present level (e.g. a new batch of harder material): re-settle."""
        self.holes_tracked = 0

    def _step(self, x: Mapping[str, float], *, teach: bool, learn: bool) -> float | None:
        """Shared per-sample update; returns the relative deviation or None (not judged)."""
        p = float(x[self.progress])
        key = float(x[self.segment])
        inside = math.isfinite(p) and key >= 0
        if self._hole is not None and (not inside or key != self._hole or p < self._last_p):
            self._finish_hole(learn=learn)
            self._reset_hole(None)
        if not inside:
            return None
        if self._hole is None:
            self._reset_hole(key)
        self._last_p = p
        b = min(max(int(p * self.n_bins), 0), self.n_bins - 1)
        v = float(x[self.signal])
        if teach:
            self._teach_sum[b] += v
            self._teach_n[b] += 1
            return None
        if self.expected is not None:
            e = float(x[self.expected])
        elif self._teach_n[b]:
            e = self._teach_sum[b] / self._teach_n[b]
        else:
            return None
        if not (math.isfinite(e) and math.isfinite(v)) or e <= 0:
            return None
        if self.expected is None:
            if not math.isfinite(self._teach_full):
                seen = self._teach_n > 0
                self._teach_full = float(np.max(self._teach_sum[seen] / self._teach_n[seen]))
            full = self._teach_full
        else:
            self._full = max(self._full, e)
            full = self._full
        r = self.wear_index * self._shape[b] * e
        if self._sv is None:
            self._sv, self._sr, self._warm = v, r, 1
        else:  # running mean over the first `smoothing` samples, then the EWMA
            self._warm += 1
            a = 1.0 / min(self._warm, self.smoothing)
            self._sv += a * (v - self._sv)
            self._sr += a * (r - self._sr)
        # not judged while the point enters (reference below min_engagement of the full
        # level), while the smoothed reference still lags the entry ramp, or during the
        # first `smoothing` samples of the EWMA (warm-up)
        if (e < self.min_engagement * full or self._sr < self.min_engagement * r
                or self._warm < self.smoothing or p > self.judge_until):
            return None
        self._q_sum[b] += v / e
        self._q_n[b] += 1
        return (self._sv - self._sr) / self._sr

    def learn_one(self, x: Mapping[str, float]) -> None:
        """Teach-in: learn the profile (or, with ``expected``, track the wear index)."""
        self._step(x, teach=self.expected is None, learn=True)

    def score_one(self, x: Mapping[str, float]) -> float:
        if not self._scoring:
            self._scoring = True
            if self.expected is None and self._teach_n.any():
                self.holes_tracked = self.settle_holes  # the teach-in is the calibration
        dev = self._step(x, teach=False, learn=True)
        if dev is None:
            return 0.0
        if self.holes_tracked < self.settle_holes:
            tol = self.initial_tolerance
        else:
            tol = self.tolerance if dev >= 0 else self.tolerance_below
        score = abs(dev) / tol - 1.0
        if score > 0:
            self._alarmed = True
        return score

    @classmethod
    def _unit_test_params(cls) -> dict[str, Any]:
        return {"signal": "current_a", "n_bins": 10, "smoothing": 5.0}


DETECTORS: tuple[type[Detector], ...] = (
    PhysicsResidualDetector, EnvelopeDetector, SpectralDetector, TappingDetector,
    WearAdaptiveDetector,
)
"""Every detector class (the conformance tests run on each)."""
