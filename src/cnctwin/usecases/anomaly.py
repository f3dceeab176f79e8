"""Anomaly detectors with one interface for batch and streaming, and a backtest.

Every detector follows river's anomaly API [1]: ``learn_one(x)`` updates it with one sample
(a dict of floats), ``score_one(x)`` returns a float where HIGH means anomalous. ``learn_many`` and
``score_many`` take a DataFrame and give the same numbers as the one-sample calls in order (a
conformance test checks it for every detector through ``_unit_test_params``).

Detectors
---------
``PhysicsResidualDetector``
    The twin's job: score the residual between a measured signal and the value the twin
    predicts (e.g. spindle current against the calibrated model), normalized by the residual
    spread learned on good data.
``EnvelopeDetector``
    The vendor teach-in baseline (ToolScope, TNC7 process monitoring): a min/max envelope of a
    signal over the progress of a repeated operation, learned from good parts.
``SpectralDetector``
    Chatter: power in a frequency band over a sliding window, relative to the learned level.
``TappingDetector``
    The loose tap of thesis Figure 5.10: fluctuation of spindle current and Z following error
    while the spindle runs in reverse (extraction), relative to the learned level.
``WearAdaptiveDetector`` (:mod:`cnctwin.usecases.monitoring`, which also lists every detector
class in ``DETECTORS``)
    Torque band around a teach-in profile or the physics-predicted torque, scaled by a wear
    index tracked per hole at a bounded rate (no false alarms over a tool life, from part 1).

References
----------
.. [1] Montiel et al., "River: machine learning for streaming data in Python", JMLR 22 (2021);
   river/anomaly/base.py: "A high score is indicative of an anomaly".
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray

from cnctwin._jit import lazy_njit
from cnctwin.exceptions import ConfigError, SignalNotFoundError

if TYPE_CHECKING:
    from cnctwin.recording import Recording
    from cnctwin.spindle import SpindleModel

__all__ = [
    "BacktestResult",
    "Detector",
    "EnvelopeDetector",
    "PhysicsResidualDetector",
    "SpectralDetector",
    "TappingDetector",
    "backtest",
    "signal_stream",
]


class _Welford:
    """Running mean and variance (Welford's algorithm)."""

    __slots__ = ("m2", "mean", "n")

    def __init__(self) -> None:
        self.n = 0
        self.mean = 0.0
        self.m2 = 0.0

    def update(self, x: float) -> None:
        self.n += 1
        d = x - self.mean
        self.mean += d / self.n
        self.m2 += d * (x - self.mean)

    def update_many(self, x: NDArray[np.float64]) -> None:
        """Add many values at once (Chan et al.'s pairwise combination; equal to repeated
        :meth:`update` up to rounding)."""
        nb = int(x.size)
        if nb == 0:
            return
        mb = float(x.mean())
        m2b = float(((x - mb) ** 2).sum())
        n = self.n + nb
        d = mb - self.mean
        self.m2 += m2b + d * d * self.n * nb / n
        self.mean += d * nb / n
        self.n = n

    @property
    def std(self) -> float:
        return math.sqrt(self.m2 / (self.n - 1)) if self.n > 1 else float("nan")


class Detector:
    """Base class: one-sample learning and scoring, with batch helpers.

    Subclasses implement ``learn_one`` and ``score_one`` and list their input keys in
    ``inputs`` (required) and ``optional_inputs`` (used when the data has them);
    ``_unit_test_params`` gives parameters for the conformance tests.
    """

    inputs: tuple[str, ...] = ()
    optional_inputs: tuple[str, ...] = ()

    def learn_one(self, x: Mapping[str, float]) -> None:
        """Update the detector with one good (normal) sample."""
        raise NotImplementedError

    def score_one(self, x: Mapping[str, float]) -> float:
        """Anomaly score of one sample: high means anomalous; 0 or below means normal."""
        raise NotImplementedError

    def learn_chunk(self, x: Mapping[str, NDArray[np.float64]]) -> None:
        """Learn consecutive samples given as equal-length arrays, in order.

        The same as ``learn_one`` on each sample; detectors override it with array code (the
        edge runtime calls it once per chunk of cycles).
        """
        keys = list(x)
        for row in zip(*(np.asarray(x[k]).tolist() for k in keys), strict=True):
            self.learn_one(dict(zip(keys, row, strict=True)))

    def score_chunk(self, x: Mapping[str, NDArray[np.float64]]) -> NDArray[np.float64]:
        """Scores of consecutive samples given as equal-length arrays, in order.

        The same as ``score_one`` on each sample (see :meth:`learn_chunk`).
        """
        keys = list(x)
        rows = zip(*(np.asarray(x[k]).tolist() for k in keys), strict=True)
        return np.array([self.score_one(dict(zip(keys, row, strict=True))) for row in rows],
                        dtype=np.float64)

    def learn_many(self, df: pd.DataFrame) -> None:
        """Learn every row of ``df`` in order (same as repeated ``learn_one``)."""
        keys = self._keys(df)
        for row in df[keys].itertuples(index=False):
            self.learn_one(dict(zip(keys, row, strict=True)))

    def score_many(self, df: pd.DataFrame) -> NDArray[np.float64]:
        """Score every row of ``df`` in order (same as repeated ``score_one``)."""
        keys = self._keys(df)
        out = np.empty(len(df))
        for i, row in enumerate(df[keys].itertuples(index=False)):
            out[i] = self.score_one(dict(zip(keys, row, strict=True)))
        return out

    def prepare(self) -> None:
        """Compile what the chunk calls use (numba), so that a live stream's first chunk
        does not wait for it; the detector's state is not touched. Nothing by default."""

    def clone(self) -> Detector:
        """A fresh, unlearned copy with the same parameters."""
        return type(self)(**self._params())

    def _params(self) -> dict[str, Any]:
        raise NotImplementedError

    def _keys(self, df: pd.DataFrame) -> list[str]:
        """Required input columns (error if one is missing) and the optional ones present."""
        missing = [c for c in self.inputs if c not in df.columns]
        if missing:
            raise ConfigError(
                f"{type(self).__name__} needs columns {list(self.inputs)}; missing {missing}"
            )
        return [*self.inputs, *(c for c in self.optional_inputs if c in df.columns)]

    @classmethod
    def _unit_test_params(cls) -> dict[str, Any]:
        return {}

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self._params().items())
        return f"{type(self).__name__}({args})"


class PhysicsResidualDetector(Detector):
    """Residual between a measured and a twin-predicted signal, in learned standard deviations.

    Score: ``|EWMA(residual) - mean_learned| / std_learned - threshold_sigma`` where the EWMA
    (time constant ``smoothing`` samples) suppresses sample noise. Above 0 is anomalous.

    Parameters
    ----------
    measured : str, default 'current_a'
        Key of the measured value.
    predicted : str, default 'predicted_current_a'
        Key of the twin's prediction.
    smoothing : float, default 25
        EWMA time constant [samples] (25 samples = 50 ms at 500 Hz).
    threshold_sigma : float, default 5
        Learned standard deviations that count as normal.
    speed : str or None, default 'speed_rpm'
        Key of the spindle speed. The twin's prediction is the current at constant speed
        (thesis Eq. 4.4 at zero cutting torque); while the speed changes (run-up, braking,
        a new S word) the current also accelerates the rotor (J dw/dt / Kt, tens of amperes
        when braking) and the drive's speed loop settles, so those samples are neither learned
        nor judged (score NaN). None: every sample counts (the earlier behaviour).
    settle_samples : int, default 150
        Samples after the last speed change that are still not judged (150 = 0.3 s at 500 Hz:
        the speed loop and the current filter settle).
    speed_tol_rpm : float, default 1
        A speed change is a step of more than ``speed_tol_rpm`` from one sample to the next
        (a commanded ramp of 500 rpm/s or more moves 1 rpm per 2 ms cycle), or a drift of more
        than ``max(10 speed_tol_rpm, 1 % of the speed)`` from the speed at the last change
        [rpm]. The speed command (``CMD_SPEED``) is noise-free; on a noisy actual speed fewer
        samples are judged.
    gate : str or None, default None
        Key of an air indicator (1: the tool cannot be cutting, e.g. every feed axis has
        stood still for a while; :class:`cnctwin.edge.AnomalyProcessor` gives ``air``):
        other samples are neither learned nor judged. The twin's prediction is the current
        *without* a cut, so a cut is no departure from it; without a gate every cut is one.
    rel_floor : float, default 0
        Lower bound of the standard deviation, a fraction of ``|predicted|`` [-]: what the
        twin cannot know (friction drifts with the bearing temperature by ~0.5 %/K, 10 %
        over a warm-up), so that a learned spread of a few quiet seconds does not make
        every later speed an alarm.
    abs_floor : float, default 0
        Further lower bound of the standard deviation, in the unit of ``measured`` (the
        calibration's uncertainty of the prediction and the sensor's noise).
    """

    def __init__(
        self,
        *,
        measured: str = "current_a",
        predicted: str = "predicted_current_a",
        smoothing: float = 25.0,
        threshold_sigma: float = 5.0,
        speed: str | None = "speed_rpm",
        settle_samples: int = 150,
        speed_tol_rpm: float = 1.0,
        gate: str | None = None,
        rel_floor: float = 0.0,
        abs_floor: float = 0.0,
    ) -> None:
        if rel_floor < 0 or abs_floor < 0:
            raise ConfigError(f"rel_floor ({rel_floor}) and abs_floor ({abs_floor}) must be "
                              ">= 0")
        self.gate, self.rel_floor, self.abs_floor = gate, rel_floor, abs_floor
        if smoothing < 1:
            raise ConfigError(f"smoothing must be >= 1 sample, not {smoothing}")
        if settle_samples < 0 or speed_tol_rpm < 0:
            raise ConfigError(f"settle_samples ({settle_samples}) and speed_tol_rpm "
                              f"({speed_tol_rpm}) must be >= 0")
        self.measured = measured
        self.predicted = predicted
        self.smoothing = smoothing
        self.threshold_sigma = threshold_sigma
        self.speed = speed
        self.settle_samples = settle_samples
        self.speed_tol_rpm = speed_tol_rpm
        keys = (measured, predicted) if speed is None else (measured, predicted, speed)
        self.inputs = keys if gate is None else (*keys, gate)
        self._alpha = 1.0 / smoothing
        self._ewma: float | None = None
        self._stats = _Welford()
        self._n_ref: float | None = None
        self._n_prev: float | None = None
        self._since_change = 0

    def _params(self) -> dict[str, Any]:
        return {"measured": self.measured, "predicted": self.predicted,
                "smoothing": self.smoothing, "threshold_sigma": self.threshold_sigma,
                "speed": self.speed, "settle_samples": self.settle_samples,
                "speed_tol_rpm": self.speed_tol_rpm, "gate": self.gate,
                "rel_floor": self.rel_floor, "abs_floor": self.abs_floor}

    def _smooth(self, x: Mapping[str, float]) -> float:
        r = float(x[self.measured]) - float(x[self.predicted])
        self._ewma = r if self._ewma is None else self._ewma + self._alpha * (r - self._ewma)
        return self._ewma

    def _steady(self, x: Mapping[str, float]) -> bool:
        """Track speed changes; True once the speed has been steady for settle_samples."""
        if self.speed is None:
            return True
        n = float(x[self.speed])
        if not math.isfinite(n):
            return True  # no speed signal: judged as before (signal_stream flags it)
        prev, self._n_prev = self._n_prev, n
        if (self._n_ref is None or prev is None or abs(n - prev) > self.speed_tol_rpm
                or abs(n - self._n_ref) > max(10.0 * self.speed_tol_rpm,
                                              0.01 * abs(self._n_ref))):
            self._n_ref = n
            self._since_change = 0
            return False
        self._since_change += 1
        return self._since_change > self.settle_samples

    def _open(self, x: Mapping[str, float]) -> bool:
        return self.gate is None or float(x[self.gate]) == 1.0

    def _std(self, predicted: NDArray[np.float64]) -> NDArray[np.float64]:
        """Standard deviation of each sample: the learned one, at least the floor."""
        std = self._stats.std
        floor = self.rel_floor * np.abs(predicted) + self.abs_floor
        return np.fmax(floor, std if math.isfinite(std) else 0.0)

    def learn_one(self, x: Mapping[str, float]) -> None:
        s = self._smooth(x)
        if self._steady(x) and self._open(x):
            self._stats.update(s)

    def score_one(self, x: Mapping[str, float]) -> float:
        s = self._smooth(x)
        if not (self._steady(x) and self._open(x)):
            return math.nan  # speed changing or maybe cutting: the twin does not apply
        std = float(self._std(np.array([float(x[self.predicted])]))[0])
        if not math.isfinite(std) or std == 0.0:
            return 0.0
        mean = self._stats.mean if self._stats.n else 0.0
        return abs(s - mean) / std - self.threshold_sigma

    # ------------------------------------------------------------ chunks (compiled loop)
    def _chunk_steps(self, x: Mapping[str, NDArray[np.float64]]
                     ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
        """The EWMA of the residual and whether each sample counts (speed steady, gate
        open): :meth:`_smooth`, :meth:`_steady` and :meth:`_open` of each sample, in one
        compiled loop (the edge runs it on every chunk)."""
        meas = np.ascontiguousarray(x[self.measured], dtype=np.float64)
        pred = np.ascontiguousarray(x[self.predicted], dtype=np.float64)
        k = meas.size
        speed = _NONE if self.speed is None else np.ascontiguousarray(x[self.speed],
                                                                      dtype=np.float64)
        gate = _NONE if self.gate is None else np.ascontiguousarray(x[self.gate],
                                                                    dtype=np.float64)
        s = np.empty(k)
        ok = np.empty(k, dtype=np.bool_)
        ewma, ref, prev = self._ewma, self._n_ref, self._n_prev
        got = _residual_steps(meas, pred, speed, gate, self._alpha,
                              ewma is not None, 0.0 if ewma is None else ewma,
                              ref is not None, 0.0 if ref is None else ref,
                              prev is not None, 0.0 if prev is None else prev,
                              self._since_change, float(self.speed_tol_rpm),
                              int(self.settle_samples), s, ok)
        if k:
            self._ewma = float(got[0])
        self._n_ref = float(got[2]) if got[1] else None
        self._n_prev = float(got[4]) if got[3] else None
        self._since_change = int(got[5])
        return s, ok

    def prepare(self) -> None:
        one, flag = np.ones(1), np.empty(1, dtype=np.bool_)
        _residual_steps(one, one, one, one, self._alpha, False, 0.0, False, 0.0, False, 0.0,
                        0, 1.0, 0, np.empty(1), flag)

    def learn_chunk(self, x: Mapping[str, NDArray[np.float64]]) -> None:
        s, ok = self._chunk_steps(x)
        self._stats.update_many(s[ok])

    def score_chunk(self, x: Mapping[str, NDArray[np.float64]]) -> NDArray[np.float64]:
        s, steady = self._chunk_steps(x)
        std = self._std(np.asarray(x[self.predicted], dtype=np.float64))
        mean = self._stats.mean if self._stats.n else 0.0
        with np.errstate(invalid="ignore", divide="ignore"):
            out = np.where(std > 0, np.abs(s - mean) / std - self.threshold_sigma, 0.0)
        out[~steady] = np.nan
        return out

    @classmethod
    def _unit_test_params(cls) -> dict[str, Any]:
        return {"smoothing": 5.0}


_NONE = np.empty(0)  # no speed or gate key


def _residual_steps_py(meas: NDArray[np.float64], pred: NDArray[np.float64],
                       speed: NDArray[np.float64], gate: NDArray[np.float64], alpha: float,
                       has_ewma: bool, ewma: float, has_ref: bool, ref: float,
                       has_prev: bool, prev: float, since: int, tol: float, settle: int,
                       s_out: NDArray[np.float64], ok_out: NDArray[np.bool_]
                       ) -> tuple[float, bool, float, bool, float, int]:
    """:meth:`PhysicsResidualDetector._smooth`, ``_steady`` and ``_open`` of each sample
    (an empty ``speed``/``gate``: no such key). The EWMA is computed as ``scipy.signal.lfilter``
    computed it before (``a r + (1 - a) e``; the first sample of a stream starts it).
    Returns the state after the samples: ewma, has_ref, ref, has_prev, prev, since."""
    c = 1.0 - alpha
    use_speed = speed.size > 0
    use_gate = gate.size > 0
    for k in range(meas.size):
        r = meas[k] - pred[k]
        if has_ewma:
            ewma = alpha * r + c * ewma
        else:
            ewma = r
            has_ewma = True
        s_out[k] = ewma
        steady = True
        if use_speed:
            n = speed[k]
            if math.isfinite(n):
                p, has_p = prev, has_prev
                prev, has_prev = n, True
                if (not has_ref or not has_p or abs(n - p) > tol
                        or abs(n - ref) > max(10.0 * tol, 0.01 * abs(ref))):
                    ref, has_ref = n, True
                    since = 0
                    steady = False
                else:
                    since += 1
                    steady = since > settle
        ok_out[k] = steady and (not use_gate or gate[k] == 1.0)
    return ewma, has_ref, ref, has_prev, prev, since


_residual_steps = lazy_njit(_residual_steps_py)


class EnvelopeDetector(Detector):
    """Learned min/max envelope over the progress of a repeated operation (vendor teach-in).

    Parameters
    ----------
    signal : str, default 'current_a'
        Monitored value.
    progress : str, default 'progress'
        Position within the operation, in [0, 1] (e.g. depth / hole depth, or samples since the
        block start / expected duration).
    n_bins : int, default 50
        Bins over the progress.
    margin : float, default 0.1
        Extra margin as a fraction of the learned band width (and at least ``min_margin``).
    min_margin : float, default 0.05
        Minimum absolute margin [unit of ``signal``].
    smoothing : float, default 1
        EWMA time constant applied to the signal first [samples]; 1 = none. The EWMA restarts
        when the progress goes backwards (a new pass of the operation).

    Notes
    -----
    Score = distance outside ``[min - m, max + m]`` divided by ``m`` (m = margin); 0 inside.
    Anything above 0 leaves the envelope; bins never seen in teach-in score 0 (no evidence).
    """

    def __init__(
        self,
        *,
        signal: str = "current_a",
        progress: str = "progress",
        n_bins: int = 50,
        margin: float = 0.1,
        min_margin: float = 0.05,
        smoothing: float = 1.0,
    ) -> None:
        if n_bins < 1:
            raise ConfigError(f"n_bins must be >= 1, not {n_bins}")
        if smoothing < 1:
            raise ConfigError(f"smoothing must be >= 1 sample, not {smoothing}")
        self.signal = signal
        self.progress = progress
        self.n_bins = n_bins
        self.margin = margin
        self.min_margin = min_margin
        self.smoothing = smoothing
        self._ewma: float | None = None
        self._last_p = -math.inf
        self.inputs = (signal, progress)
        self._lo = np.full(n_bins, np.inf)
        self._hi = np.full(n_bins, -np.inf)

    def _params(self) -> dict[str, Any]:
        return {"signal": self.signal, "progress": self.progress, "n_bins": self.n_bins,
                "margin": self.margin, "min_margin": self.min_margin,
                "smoothing": self.smoothing}

    def _bin(self, p: float) -> int:
        return min(max(int(p * self.n_bins), 0), self.n_bins - 1)

    def _value(self, x: Mapping[str, float]) -> float:
        v, p = float(x[self.signal]), float(x[self.progress])
        if self._ewma is None or p < self._last_p or not math.isfinite(self._ewma):
            self._ewma = v
        else:
            self._ewma += (v - self._ewma) / self.smoothing
        self._last_p = p
        return self._ewma

    def learn_one(self, x: Mapping[str, float]) -> None:
        b = self._bin(float(x[self.progress]))
        v = self._value(x)
        self._lo[b] = min(self._lo[b], v)
        self._hi[b] = max(self._hi[b], v)

    def score_one(self, x: Mapping[str, float]) -> float:
        b = self._bin(float(x[self.progress]))
        v = self._value(x)
        lo, hi = self._lo[b], self._hi[b]
        if not np.isfinite(lo):
            return 0.0
        m = max(self.margin * (hi - lo), self.min_margin)
        return float(max(lo - m - v, v - hi - m, 0.0) / m)

    @classmethod
    def _unit_test_params(cls) -> dict[str, Any]:
        return {"n_bins": 10, "smoothing": 3.0}


class SpectralDetector(Detector):
    """Chatter: the largest line in a band of a steady-cutting spectrum against the learned level.

    Every ``hop`` samples the last ``window`` samples are detrended (least-squares line), Hann
    tapered and transformed; the largest power in ``band_hz`` outside the notches of the known
    lines is compared in dB with the level learned on good data at the same spindle speed.

    Parameters
    ----------
    signal : str, default 'current_a'
        Monitored value (spindle current, a feed-axis current, or CONT_DEV).
    fs_hz : float, default 500
        Sample rate [Hz].
    band_hz : (float, float), default (20, 240)
        Band searched for a chatter line [Hz].
    window : int, default 128
        Window length [samples].
    hop : int, default 16
        The spectrum is recomputed every ``hop`` samples; scores in between repeat it.
    threshold_db : float, default 10
        Rise of the band line over the learned level that counts as normal [dB].
    speed : str or None, default 'speed_rpm'
        Optional key of the spindle speed [rpm]. When present: the known spindle-rotation
        lines are notched out, windows during a speed change are not judged, and the level is
        learned per speed class. ``None`` or a missing/NaN value: none of these.
    segment : str or None, default 'hole'
        Optional key of a segment number (the hole of :func:`signal_stream`). When it changes
        the window restarts: a spectrum never spans two cuts (the cut-only stream joins the end
        of one hole, ~4 A, to the entry of the next, ~0.5 A; that step is broadband).
    max_harmonic : int, default 6
        Rotation harmonics ``k · n/60``, k = 1..max_harmonic, candidates for a notch, with
        their aliases folded about ``fs/2`` (see ``line_db``). This covers tooth passing
        (``z · n/60``, z <= max_harmonic teeth) and the stator frequency ``p · n/60`` of a
        motor with p <= max_harmonic pole pairs (:mod:`cnctwin.spindle`).
    notch_hz : float, optional
        Half width of each notch [Hz]; default 1.5 bins, ``1.5 fs_hz / window`` (a forced line
        between two bins leaks into the neighbours; at 1 bin a rising 150 Hz tooth-passing
        line still alarms in the test).
    speed_tolerance : float, default 0.02
        Windows whose speed range exceeds this fraction of the mean speed (and 5 rpm) are speed
        transients (run-up, reversal, speed change) and are neither learned nor scored.
    persistence : int, default 3
        The score is the smallest of the last ``persistence`` spectra: an alarm needs that many
        consecutive spectra above the threshold, ``(persistence - 1) · hop`` samples of delay.
    speed_step_rpm : float, default 100
        Width of the speed classes of the learned level [rpm]; an unlearned class uses the
        level over all speeds.
    line_db : float, default 6
        A rotation harmonic is a known line (notched) if it stands this much above the band
        median of the mean spectrum learned at that speed [dB]: forced lines present in the
        teach-in may grow (wear) without an alarm, while chatter next to a harmonic that the
        teach-in did not show stays visible.

    Notes
    -----
    Raw score of a spectrum: ``10·log10(P_max) - L(n) - threshold_db`` with ``L(n)`` the mean
    of the learned ``10·log10(P_max)`` in the speed class of ``n``. Score = min of the last
    ``persistence`` raw scores (fewer after a restart: min with 0). No evidence (window not
    full, speed transient, NaN in the window, nothing learned) scores 0. Chatter is a
    self-excited vibration near, not at, a structural mode, distinct from the forced lines
    at the tooth-passing harmonics (Altintas, *Manufacturing Automation*, 2nd ed., ch. 3.4),
    hence the notches.
    """

    def __init__(
        self,
        *,
        signal: str = "current_a",
        fs_hz: float = 500.0,
        band_hz: tuple[float, float] = (20.0, 240.0),
        window: int = 128,
        hop: int = 16,
        threshold_db: float = 10.0,
        speed: str | None = "speed_rpm",
        segment: str | None = "hole",
        max_harmonic: int = 6,
        notch_hz: float | None = None,
        speed_tolerance: float = 0.02,
        persistence: int = 3,
        speed_step_rpm: float = 100.0,
        line_db: float = 6.0,
    ) -> None:
        if not 0 <= band_hz[0] < band_hz[1] <= fs_hz / 2:
            raise ConfigError(f"band_hz must lie in [0, {fs_hz / 2}] Hz, got {band_hz}")
        if window < 8 or hop < 1:
            raise ConfigError("window must be >= 8 samples and hop >= 1")
        if persistence < 1 or max_harmonic < 0 or speed_step_rpm <= 0:
            raise ConfigError(
                "persistence must be >= 1, max_harmonic >= 0 and speed_step_rpm > 0; got "
                f"{persistence}, {max_harmonic}, {speed_step_rpm}"
            )
        self.signal = signal
        self.fs_hz = fs_hz
        self.band_hz = band_hz
        self.window = window
        self.hop = hop
        self.threshold_db = threshold_db
        self.speed = speed
        self.segment = segment
        self.max_harmonic = max_harmonic
        self.notch_hz = notch_hz
        self.speed_tolerance = speed_tolerance
        self.persistence = persistence
        self.speed_step_rpm = speed_step_rpm
        self.line_db = line_db
        self.inputs = (signal,)
        self.optional_inputs = tuple(k for k in (speed, segment) if k is not None)
        self._freqs = np.fft.rfftfreq(window, 1.0 / fs_hz)
        self._band = (self._freqs >= band_hz[0]) & (self._freqs <= band_hz[1])
        self._notch = 1.5 * fs_hz / window if notch_hz is None else notch_hz
        self._taper = np.hanning(window)
        self._ramp = np.arange(window) - (window - 1) / 2.0
        self._ramp_ss = float(self._ramp @ self._ramp)
        self._buf: deque[float] = deque(maxlen=window)
        self._spd: deque[float] = deque(maxlen=window)
        self._seg: float | None = None
        self._count = 0
        self._last = 0.0
        self._hist: deque[float] = deque(maxlen=persistence)
        self._level: dict[int | None, _Welford] = {}
        self._spec = np.zeros(self._freqs.size)
        self._spec_sum: dict[int, list[Any]] = {}
        self._all = _Welford()

    def _params(self) -> dict[str, Any]:
        return {"signal": self.signal, "fs_hz": self.fs_hz, "band_hz": self.band_hz,
                "window": self.window, "hop": self.hop, "threshold_db": self.threshold_db,
                "speed": self.speed, "segment": self.segment,
                "max_harmonic": self.max_harmonic, "notch_hz": self.notch_hz,
                "speed_tolerance": self.speed_tolerance, "persistence": self.persistence,
                "speed_step_rpm": self.speed_step_rpm, "line_db": self.line_db}

    def line_mask(self, speed_rpm: float) -> NDArray[np.bool_]:
        """Bins of the band searched at this spindle speed [-].

        Notched out: the rotation harmonics ``k · n/60`` (k = 1..max_harmonic, aliases folded
        about ``fs/2``) that stand ``line_db`` above the median of the band in the mean
        spectrum learned at this speed class; all of them if the class was not learned.
        """
        mask = self._band.copy()
        if not math.isfinite(speed_rpm) or speed_rpm == 0.0:
            return mask
        learned = self._spec_sum.get(round(speed_rpm / self.speed_step_rpm))
        mean = None
        if learned is not None:
            mean = learned[0] / learned[1]
            floor = float(np.median(mean[self._band]))
        f_rot = abs(speed_rpm) / 60.0
        for k in range(1, self.max_harmonic + 1):
            f = math.fmod(k * f_rot, self.fs_hz)
            f = self.fs_hz - f if f > self.fs_hz / 2 else f  # aliased line
            near = np.abs(self._freqs - f) <= self._notch
            if mean is not None and not (
                near.any() and float(mean[near].max()) > floor * 10 ** (self.line_db / 10)
            ):
                continue  # no such line in the teach-in
            mask &= ~near
        return mask

    def _spectrum(self, x: Mapping[str, float]) -> tuple[float, int | None] | bool | None:
        """(dB, speed class) of a new spectrum; None between hops; False: no evidence."""
        if self.segment is not None and self.segment in x:
            seg = float(x[self.segment])
            if self._seg is not None and seg != self._seg:
                self._buf.clear()
                self._spd.clear()
                self._hist.clear()
            self._seg = seg
        self._buf.append(float(x[self.signal]))
        self._spd.append(float(x[self.speed]) if self.speed and self.speed in x else math.nan)
        self._count += 1
        if self._count % self.hop:
            return None
        if len(self._buf) < self.window:
            return False
        w = np.asarray(self._buf)
        n = np.asarray(self._spd)
        cls: int | None = None
        n_mean = math.nan
        if np.all(np.isfinite(n)):
            n_mean = float(n.mean())
            if float(n.max() - n.min()) > max(self.speed_tolerance * abs(n_mean), 5.0):
                return False  # speed transient: run-up, reversal, speed change
            cls = round(n_mean / self.speed_step_rpm)
        w = w - w.mean()
        w = w - (self._ramp @ w / self._ramp_ss) * self._ramp
        spec = np.abs(np.fft.rfft(w * self._taper)) ** 2
        if not np.all(np.isfinite(spec)):
            return False
        self._spec = spec
        mask = self.line_mask(n_mean)
        if not mask.any():
            return False
        return 10.0 * math.log10(max(float(spec[mask].max()), 1e-300)), cls

    def learn_one(self, x: Mapping[str, float]) -> None:
        s = self._spectrum(x)
        if isinstance(s, tuple):
            self._level.setdefault(s[1], _Welford()).update(s[0])
            self._all.update(s[0])
            if s[1] is not None:
                acc = self._spec_sum.setdefault(s[1], [np.zeros_like(self._spec), 0])
                acc[0] = acc[0] + self._spec
                acc[1] += 1

    def score_one(self, x: Mapping[str, float]) -> float:
        s = self._spectrum(x)
        if s is None:
            return self._last
        if s is False or not self._all.n:
            self._hist.clear()
            self._last = 0.0
            return 0.0
        assert isinstance(s, tuple)
        lev = self._level.get(s[1])
        ref = lev.mean if lev is not None and lev.n >= 5 else self._all.mean
        self._hist.append(s[0] - ref - self.threshold_db)
        low = min(self._hist)
        self._last = low if len(self._hist) == self.persistence else min(low, 0.0)
        return self._last

    @classmethod
    def _unit_test_params(cls) -> dict[str, Any]:
        return {"window": 32, "hop": 4}


class TappingDetector(Detector):
    """Loose tap on extraction: fluctuation while the spindle runs in reverse.

    Thesis Figure 5.10: when the loose tap is extracted (spindle reversed), the dynamometer
    torque, the spindle current and the Z encoder position fluctuate. The detector tracks the
    rolling standard deviation of the sample-to-sample change of ``current_a`` and of
    ``z_error_mm`` (following error of Z) while ``speed_rpm`` has the reverse sign, and scores
    their ratio to the level learned on good extractions *at the same time since the reversal*
    (bins of ``bin_samples``), so the reversal and stop transients of a healthy tap are not
    alarms.

    Parameters
    ----------
    window : int, default 50
        Rolling window [samples] (100 ms at 500 Hz).
    direction : int, default -1
        Sign of the spindle speed during extraction (M3 tapping reverses to M4: -1).
    threshold_ratio : float, default 3
        Ratio to the learned fluctuation that counts as normal.
    bin_samples : int, default 5
        Width of the reference bins over the time since the reversal [samples].
    n_bins : int, default 800
        Reference bins (800 x 5 samples = 8 s at 500 Hz); later windows use the last bin.
    tolerance_bins : int, default 2
        The reference of bin ``b`` is the largest learned level in ``b - tol .. b + tol``, which
        tolerates a jitter of the transients of ``tol x bin_samples`` samples.
    min_current_a : float, default 0.01
        Floor of the learned current fluctuation [A] (quantization of CURRENT).
    min_z_mm : float, default 2e-5
        Floor of the learned Z fluctuation [mm] (encoder resolution order).

    Notes
    -----
    Score = ``max(s_I / ref_I(b), s_z / ref_z(b)) - threshold_ratio`` with ``s`` the rolling
    standard deviation of first differences and ``ref(b)`` the largest learned mean of ``s``
    within ``tolerance_bins`` of bin ``b`` = (samples since the reversal - window) //
    ``bin_samples``, floored by the ``min_*`` values. Bins never learned fall back to the
    nearest earlier learned bin.
    """

    inputs = ("current_a", "z_error_mm", "speed_rpm")

    def __init__(
        self,
        *,
        window: int = 50,
        direction: int = -1,
        threshold_ratio: float = 3.0,
        bin_samples: int = 5,
        n_bins: int = 800,
        tolerance_bins: int = 2,
        min_current_a: float = 0.01,
        min_z_mm: float = 2e-5,
    ) -> None:
        if direction not in (-1, 1):
            raise ConfigError(f"direction must be -1 or +1, not {direction}")
        if window < 2 or n_bins < 1 or bin_samples < 1 or tolerance_bins < 0:
            raise ConfigError(
                "window must be >= 2, n_bins and bin_samples >= 1, tolerance_bins >= 0; got "
                f"{window}, {n_bins}, {bin_samples}, {tolerance_bins}"
            )
        self.window = window
        self.direction = direction
        self.threshold_ratio = threshold_ratio
        self.bin_samples = bin_samples
        self.n_bins = n_bins
        self.tolerance_bins = tolerance_bins
        self.min_current_a = min_current_a
        self.min_z_mm = min_z_mm
        self._prev: tuple[float, float] | None = None
        self._since = 0
        self._dc: deque[float] = deque(maxlen=window)
        self._dz: deque[float] = deque(maxlen=window)
        self._ref_c = [_Welford() for _ in range(n_bins)]
        self._ref_z = [_Welford() for _ in range(n_bins)]

    def _params(self) -> dict[str, Any]:
        return {"window": self.window, "direction": self.direction,
                "threshold_ratio": self.threshold_ratio, "bin_samples": self.bin_samples,
                "n_bins": self.n_bins, "tolerance_bins": self.tolerance_bins,
                "min_current_a": self.min_current_a, "min_z_mm": self.min_z_mm}

    def _update(self, x: Mapping[str, float]) -> tuple[int, float, float] | None:
        c, z, n = float(x["current_a"]), float(x["z_error_mm"]), float(x["speed_rpm"])
        reverse = n * self.direction > 1.0
        prev, self._prev = self._prev, (c, z)
        if not reverse or prev is None:
            self._dc.clear()
            self._dz.clear()
            self._since = 0
            return None
        self._since += 1
        self._dc.append(c - prev[0])
        self._dz.append(z - prev[1])
        if len(self._dc) < self.window:
            return None
        b = min((self._since - self.window) // self.bin_samples, self.n_bins - 1)
        return b, float(np.std(self._dc)), float(np.std(self._dz))

    def _ref(self, refs: list[_Welford], b: int, floor: float) -> float:
        lo, hi = max(b - self.tolerance_bins, 0), min(b + self.tolerance_bins, self.n_bins - 1)
        near = [r.mean for r in refs[lo:hi + 1] if r.n]
        if near:
            return max(max(near), floor)
        for k in range(lo - 1, -1, -1):  # never learned: the nearest earlier learned bin
            if refs[k].n:
                return max(refs[k].mean, floor)
        return float("nan")

    def learn_one(self, x: Mapping[str, float]) -> None:
        f = self._update(x)
        if f is not None:
            self._ref_c[f[0]].update(f[1])
            self._ref_z[f[0]].update(f[2])

    def score_one(self, x: Mapping[str, float]) -> float:
        f = self._update(x)
        if f is None:
            return 0.0
        rc = self._ref(self._ref_c, f[0], self.min_current_a)
        rz = self._ref(self._ref_z, f[0], self.min_z_mm)
        if not math.isfinite(rc):
            return 0.0
        return max(f[1] / rc, f[2] / rz) - self.threshold_ratio

    def _forward_chunk(self, x: Mapping[str, NDArray[np.float64]]) -> bool:
        """True (and the state advanced) when no sample of the chunk is in extraction: then
        every sample only resets the window, as :meth:`_update` would one by one."""
        n = np.asarray(x["speed_rpm"], dtype=np.float64)
        if n.size == 0 or bool((n * self.direction > 1.0).any()):
            return False
        self._prev = (float(np.asarray(x["current_a"])[-1]),
                      float(np.asarray(x["z_error_mm"])[-1]))
        self._dc.clear()
        self._dz.clear()
        self._since = 0
        return True

    def learn_chunk(self, x: Mapping[str, NDArray[np.float64]]) -> None:
        if not self._forward_chunk(x):  # extraction in the chunk: sample by sample
            super().learn_chunk(x)

    def score_chunk(self, x: Mapping[str, NDArray[np.float64]]) -> NDArray[np.float64]:
        if self._forward_chunk(x):  # no extraction: nothing to judge (score 0, as one by one)
            return np.zeros(len(np.asarray(x["speed_rpm"])))
        return super().score_chunk(x)

    @classmethod
    def _unit_test_params(cls) -> dict[str, Any]:
        return {"window": 10, "n_bins": 50}


@dataclass(frozen=True)
class BacktestResult:
    """Detections of a detector replayed over recordings with known fault onsets.

    Attributes
    ----------
    alarms_s : list of float
        Times at which the score crossed the threshold upward [s].
    delays_s : list of float
        Per fault onset, the delay to the first alarm within ``max_delay_s``; NaN if missed [s].
    misses : int
        Faults with no alarm within ``max_delay_s``.
    false_alarms : int
        Alarms not within ``max_delay_s`` after any fault onset (with ``persistent`` faults:
        alarms before the first onset).
    false_alarms_per_hour : float
        ``false_alarms`` per hour of fault-free monitored time (``healthy_s``) [1/h].
    monitored_s : float
        Scored duration [s].
    healthy_s : float
        Scored duration in which an alarm counts as false [s]: ``monitored_s``, or with
        ``persistent`` faults the scored time before the first onset.
    """

    alarms_s: list[float]
    delays_s: list[float]
    misses: int
    false_alarms: int
    false_alarms_per_hour: float
    monitored_s: float
    healthy_s: float = float("nan")


def backtest(
    detector: Detector,
    data: pd.DataFrame,
    *,
    time_s: ArrayLike,
    learn_until_s: float,
    fault_onsets_s: Sequence[float] = (),
    threshold: float = 0.0,
    max_delay_s: float = 2.0,
    refractory_s: float = 1.0,
    persistent: bool = False,
) -> BacktestResult:
    """Replay a stream: learn on the first part, score the rest, compare alarms with faults.

    Parameters
    ----------
    detector : Detector
        A fresh detector (it is cloned, the argument is not changed).
    data : pandas.DataFrame
        Samples with the detector's input columns, in time order.
    time_s : array-like
        Time of each row [s].
    learn_until_s : float
        Rows before this time are learned (teach-in on good data), the rest scored [s].
    fault_onsets_s : sequence of float
        True fault onset times [s].
    threshold : float, default 0
        Score above which an alarm is raised.
    max_delay_s : float, default 2
        An alarm within this time after an onset counts as a detection [s].
    refractory_s : float, default 1
        After an alarm, further crossings within this time are not new alarms [s].
    persistent : bool, default False
        The fault stays once it has started (a loose tool stays loose, a broken drill stays
        broken): alarms after the first onset are never false, and the false-alarm rate is per
        hour of scored time before it.

    Returns
    -------
    BacktestResult
    """
    t = np.asarray(time_s, dtype=np.float64)
    if t.size != len(data):
        raise ConfigError(f"time_s has {t.size} values, data {len(data)} rows")
    det = detector.clone()
    learn = t < learn_until_s
    det.learn_many(data.loc[learn])
    scores = det.score_many(data.loc[~learn])
    ts = t[~learn]
    alarms: list[float] = []
    above_prev = False
    for ti, s in zip(ts, scores, strict=True):
        above = bool(s > threshold)
        if above and not above_prev and (not alarms or ti - alarms[-1] >= refractory_s):
            alarms.append(float(ti))
        above_prev = above
    onsets = sorted(float(o) for o in fault_onsets_s)
    delays: list[float] = []
    matched: set[int] = set()
    for o in onsets:
        hits = [i for i, a in enumerate(alarms) if o <= a <= o + max_delay_s]
        delays.append(alarms[hits[0]] - o if hits else float("nan"))
        matched.update(hits)
    monitored = float(ts[-1] - ts[0]) if ts.size > 1 else 0.0
    healthy = monitored
    if persistent and onsets:
        matched.update(i for i, a in enumerate(alarms) if a >= onsets[0])
        healthy = float(np.clip(onsets[0] - ts[0], 0.0, monitored)) if ts.size else 0.0
    false = len(alarms) - len(matched)
    return BacktestResult(
        alarms, delays, int(np.isnan(delays).sum()) if delays else 0, false,
        false / (healthy / 3600.0) if healthy > 0 else float("nan"), monitored, healthy,
    )


def signal_stream(
    recordings: Sequence[Recording],
    holes: pd.DataFrame | None = None,
    *,
    cutting_only: bool = False,
    model: SpindleModel | None = None,
) -> pd.DataFrame:
    """Detector inputs, one row per HF sample, from recordings in time order.

    Parameters
    ----------
    recordings : sequence of Recording
        Recordings with ``CURRENT|SP1`` (and ``DES_POS|Z1``/``ENC_POS|Z1`` for the Z error).
    holes : pandas.DataFrame, optional
        Hole record (:func:`cnctwin.usecases.holes.hole_records`): gives ``progress`` (0..1 over
        each cut) and ``hole``; without it both are NaN / -1.
    cutting_only : bool, default False
        Keep only the samples inside a cut (envelope, physics and spectral detectors).
    model : SpindleModel, optional
        The calibrated spindle of this machine (``SpindleModel.from_machine``); without it
        the thesis machine's parameters, and ``attrs["issues"]`` says the prediction is not
        calibrated to this machine.

    Returns
    -------
    pandas.DataFrame
        ``time_s`` (from the first sample of the first recording) [s], ``current_a`` [A],
        ``speed_rpm`` (actual spindle speed) [rpm], ``predicted_current_a`` (spindle twin with
        the thesis parameters at zero cutting torque) [A], ``torque_nm`` (cutting torque of the
        same twin, thesis Eq. 3.1) [Nm], ``z_error_mm`` (DES_POS - ENC_POS of
        Z1, 0 if absent) [mm], ``progress`` [-], ``hole`` [-]. Without a spindle speed
        signal the speed (and the prediction) is NaN and ``attrs["issues"]`` says so.
    """
    from cnctwin.analysis.segments import spindle_speed_rpm
    from cnctwin.spindle import SpindleModel

    if not recordings:
        raise ConfigError("signal_stream needs at least one recording")
    issues: list[str] = []
    if model is None:
        model = SpindleModel.from_parameters("thesis_spinner_840dsl")
        issues.append("the predicted current and torque use the thesis machine's spindle "
                      "(thesis_spinner_840dsl), not calibrated to this machine: give the "
                      "machine file (--machine FILE) of a 'cnctwin calibrate spindle'")
    origin = pd.Timestamp(recordings[0].hf["time"].iloc[0])
    parts = []
    for r in recordings:
        t = ((pd.DatetimeIndex(r.hf["time"]) - origin) / pd.Timedelta(seconds=1)).to_numpy()
        cur = r.hf["CURRENT|SP1"].to_numpy(dtype=np.float64)
        try:
            speed, _ = spindle_speed_rpm(r, "SP1")
        except SignalNotFoundError as exc:  # e.g. UMich: no CMD_SPEED; keep, flag
            speed = np.full(len(cur), np.nan)
            issues.append(f"{r.meta.source_files[:1]}: spindle speed NaN ({exc})")
        with np.errstate(invalid="ignore"):
            torque = model.cutting_torque(cur, speed, fs_hz=r.fs_hz)
        d = pd.DataFrame({"time_s": t, "current_a": cur, "speed_rpm": speed,
                          "predicted_current_a": model.predict_current_a(0.0, speed),
                          "torque_nm": torque})
        if r.has("DES_POS|Z1") and r.has("ENC_POS|Z1"):
            d["z_error_mm"] = (r.hf["DES_POS|Z1"] - r.hf["ENC_POS|Z1"]).to_numpy()
        else:
            d["z_error_mm"] = 0.0
        prog = np.full(len(d), np.nan)
        hole = np.full(len(d), -1)
        cyc = r.cycles
        if holes is not None:
            hv = holes[["hole", "cut_start_cycle", "cut_end_cycle"]].to_numpy(dtype=np.int64)
            for h_no, c0, c1 in hv:
                lo = int(np.searchsorted(cyc, c0))
                hi = int(np.searchsorted(cyc, c1, side="right"))
                if hi > lo:
                    prog[lo:hi] = np.linspace(0.0, 1.0, hi - lo)
                    hole[lo:hi] = int(h_no)
        d["progress"] = prog
        d["hole"] = hole
        parts.append(d)
    data = pd.concat(parts, ignore_index=True)
    if cutting_only:
        data = data[data["hole"] >= 0].reset_index(drop=True)
    data.attrs["issues"] = issues
    return data
