"""Replay recordings through a named anomaly detector: teach on the first part, score the rest.

The one replay behind ``cnctwin anomalies`` and the dashboard's anomaly view:
:func:`~cnctwin.usecases.anomaly.signal_stream` (only the cuts where the detector judges cuts),
the detector by name, :func:`~cnctwin.usecases.anomaly.backtest`, the hole of each alarm and,
on request, the scores of a clone taught on the same rows.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from cnctwin.exceptions import ConfigError, NotScoredError
from cnctwin.recording import Recording
from cnctwin.spindle import SpindleModel
from cnctwin.usecases.anomaly import (
    BacktestResult,
    Detector,
    EnvelopeDetector,
    PhysicsResidualDetector,
    SpectralDetector,
    TappingDetector,
    backtest,
    signal_stream,
)

__all__ = ["DETECTOR_NAMES", "DetectorReplay", "make_detector", "replay_detector"]

DETECTOR_NAMES: tuple[str, ...] = ("envelope", "adaptive", "physics-torque", "physics",
                                   "spectral", "tapping")
"""Detectors by the names the CLI and the dashboard use."""

_NEEDS_HOLES = ("envelope", "adaptive", "physics-torque")
"""Detectors that judge each cut by its progress: they need the hole record."""

_CUTS_ONLY = ("envelope", "adaptive", "physics-torque", "physics", "spectral")
"""Detectors scored on the cutting samples only (when there are holes)."""


def make_detector(name: str, *, fs_hz: float) -> Detector:
    """A fresh detector by name (:data:`DETECTOR_NAMES`).

    ``spectral``: the default band 20-240 Hz at 500 Hz, scaled with the sampling rate
    ``fs_hz`` [Hz] (UMich: 10 Hz). ``physics-torque``: the wear-adaptive monitor around the
    Kienzle-predicted torque (column ``expected_torque_nm``).

    Parameters
    ----------
    name : str
        Detector name.
    fs_hz : float
        Sample rate of the stream [Hz].

    Returns
    -------
    Detector
    """
    from cnctwin.usecases.monitoring import WearAdaptiveDetector

    makers: dict[str, Callable[[], Detector]] = {
        "envelope": EnvelopeDetector,
        "adaptive": WearAdaptiveDetector,
        "physics-torque": lambda: WearAdaptiveDetector(expected="expected_torque_nm"),
        "physics": PhysicsResidualDetector,
        "spectral": lambda: SpectralDetector(fs_hz=fs_hz, band_hz=(0.04 * fs_hz, 0.48 * fs_hz)),
        "tapping": TappingDetector,
    }
    if name not in makers:
        raise ConfigError(f"detector {name!r} is not known; use one of "
                          f"{', '.join(DETECTOR_NAMES)}")
    return makers[name]()


@dataclass(frozen=True)
class DetectorReplay:
    """What :func:`replay_detector` found.

    Attributes
    ----------
    detector : Detector
        The detector as taught and run by the backtest.
    learn_until_s : float
        End of the teach-in [s] (recording time of the stream).
    result : BacktestResult
        Alarms and scored duration.
    alarm_holes : list of int
        Hole number at each alarm.
    score_time_s, score : numpy.ndarray
        Scores of a clone taught on the same rows, for the samples after the teach-in
        (empty unless asked for) [s], [-].
    issues : list of str
        Notes of the signal stream (what it could not use).
    """

    detector: Detector
    learn_until_s: float
    result: BacktestResult
    alarm_holes: list[int]
    score_time_s: NDArray[np.float64] = field(default_factory=lambda: np.empty(0))
    score: NDArray[np.float64] = field(default_factory=lambda: np.empty(0))
    issues: list[str] = field(default_factory=list)


_INPUT_SOURCES: dict[str, str] = {
    "current_a": "the spindle current CURRENT|SP1",
    "speed_rpm": "the spindle speed (CMD_SPEED|SP1 or the actual speed)",
    "predicted_current_a": "the twin's air current, which needs the spindle speed",
    "torque_nm": "the cutting torque of the twin, which needs the spindle speed",
    "z_error_mm": "the Z following error (DES_POS|Z1 - ENC_POS|Z1)",
    "progress": "the progress through each cut (the hole record)",
    "expected_torque_nm": "the predicted cutting torque (the hole record and the feed)",
}


def _check_inputs(det: Detector, name: str, data: pd.DataFrame) -> None:
    """Refuse to score where a needed input is missing or never finite.

    A detector fed NaN returns a score of 0 on every sample, which reads as "no alarm"; the
    stream says instead that it was not scored and why.
    """
    notes = [str(i).split("; HF columns")[0] for i in data.attrs.get("issues", [])]
    issues = "; ".join(n if len(n) <= 240 else n[:237] + "..." for n in notes)
    for col in det.inputs:
        vals = data[col].to_numpy(dtype=np.float64) if col in data.columns else np.empty(0)
        n_ok = int(np.isfinite(vals).sum())
        if n_ok == 0:
            what = _INPUT_SOURCES.get(col, col)
            raise NotScoredError(
                f"not scored: the {name} detector needs {what} ({col}), and the recording "
                f"has {'none' if col not in data.columns or vals.size == 0 else 'no finite value'}"
                + (f" ({issues})" if issues else "") + "; choose a detector whose inputs the "
                "recording has, or record the missing signal")


def replay_detector(
    recordings: Sequence[Recording],
    holes: pd.DataFrame | None,
    *,
    detector: str,
    learn_until_s: float | None = None,
    threshold: float = 0.0,
    material: str = "aisi1045",
    drill_mm: float = 8.5,
    scores: bool = False,
    model: SpindleModel | None = None,
) -> DetectorReplay:
    """Replay recordings through the detector ``detector``: teach, then score.

    Parameters
    ----------
    recordings : sequence of Recording
        The recordings in time order.
    holes : pandas.DataFrame or None
        Their hole record (:func:`~cnctwin.usecases.holes.hole_records`); ``None`` or empty
        when there is none (then every sample is scored).
    detector : str
        One of :data:`DETECTOR_NAMES`.
    learn_until_s : float, optional
        End of the teach-in [s]; default the first third of the stream (``physics-torque``:
        none, it needs no teach-in).
    threshold : float, default 0
        Alarm threshold on the detector score.
    material : str, default 'aisi1045'
        Workpiece material of the ``physics-torque`` prediction.
    drill_mm : float, default 8.5
        Drill diameter of the ``physics-torque`` prediction [mm].
    scores : bool, default False
        Also score a clone taught on the same rows (for a figure).
    model : SpindleModel, optional
        The machine's calibrated spindle for the predicted current and torque (default the
        thesis machine's, said so in ``issues``).

    Returns
    -------
    DetectorReplay

    Raises
    ------
    ConfigError
        Unknown detector, a detector that needs holes without them, nothing to score.
    NotScoredError
        A needed input is missing or never finite (e.g. no spindle speed for ``physics``).
    """
    if detector not in DETECTOR_NAMES:
        raise ConfigError(f"detector {detector!r} is not known; use one of "
                          f"{', '.join(DETECTOR_NAMES)}")
    have_holes = holes is not None and not holes.empty
    if detector in _NEEDS_HOLES and not have_holes:
        raise ConfigError(f"the {detector} detector needs holes (progress through each cut); "
                          "this recording has none: use detector=physics")
    data = signal_stream(list(recordings), holes if have_holes else None,
                         cutting_only=have_holes and detector in _CUTS_ONLY, model=model)
    if data.empty:
        raise ConfigError("nothing to score: no cutting samples in the recordings")
    if detector == "physics-torque":
        from cnctwin.usecases.monitoring import expected_torque_stream

        assert holes is not None
        data["expected_torque_nm"] = expected_torque_stream(data, holes, material=material,
                                                            diameter_mm=drill_mm)
    det = make_detector(detector, fs_hz=recordings[0].fs_hz)
    _check_inputs(det, detector, data)
    t = data["time_s"].to_numpy(dtype=np.float64)
    learn = learn_until_s if learn_until_s is not None else (
        t[0] - 1.0 if detector == "physics-torque" else t[0] + (t[-1] - t[0]) / 3.0)
    res = backtest(det, data, time_s=t, learn_until_s=learn, threshold=threshold)
    hole_at = (np.interp(res.alarms_s, t, data["hole"].to_numpy(dtype=np.float64))
               if res.alarms_s else np.empty(0))
    score_t, score = np.empty(0), np.empty(0)
    if scores:
        clone = det.clone()
        taught = t < learn
        clone.learn_many(data.loc[taught])
        score_t = t[~taught]
        score = np.asarray(clone.score_many(data.loc[~taught]), dtype=np.float64)
    return DetectorReplay(detector=det, learn_until_s=float(learn), result=res,
                          alarm_holes=np.round(hole_at).astype(int).tolist(),
                          score_time_s=score_t, score=score,
                          issues=list(data.attrs.get("issues", [])))
