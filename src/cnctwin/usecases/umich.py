"""Validation on the real University of Michigan CNC mill data (issue #6).

Two questions of thesis chapter 5 asked of real drive data (14 milling experiments on wax,
10 Hz, ``cnctwin.iotools.read_umich_dataset``):

1. **Worn or unworn?** From drive signals only, on an experiment never seen in training
   (leave-one-experiment-out), against the majority-class baseline.
2. **Anomaly**: four experiments were not finished (``machining_finalized == no``). Does a
   detector taught on finished runs flag them, how long before the run stops, and how often does
   it alarm on finished runs it did not learn?

Features per experiment (declared before looking at any result; valid rows of the cutting
phases ``Layer *`` only): mean spindle current and power, mean |current| of X and Y, mean
|following error| ``|ENC_POS - DES_POS|`` of X and Y. Cutting loads scale with the feed, and
feed and tool condition are not balanced in the data set, so each feature is replaced by its
residual from a straight line over the feedrate fitted on the training experiments of the fold.

References
----------
.. [1] University of Michigan SMART lab, "CNC Mill Tool Wear" data set (Kaggle, 2018).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from cnctwin.exceptions import ConfigError
from cnctwin.recording import Recording
from cnctwin.usecases.anomaly import Detector, EnvelopeDetector, backtest

__all__ = [
    "UMICH_FEATURES",
    "LoeoClassification",
    "cutting_rows",
    "feature_table",
    "loeo_classification",
    "unfinished_backtest",
]

UMICH_FEATURES: tuple[str, ...] = (
    "spindle_current_a",
    "spindle_power_w",
    "x_current_a",
    "y_current_a",
    "x_following_error_mm",
    "y_following_error_mm",
)
"""Per-experiment features (means over valid cutting rows)."""


def cutting_rows(rec: Recording, *, phase_prefix: str = "Layer") -> pd.DataFrame:
    """Valid HF rows of the cutting phases, with the phase name in column ``phase``.

    Parameters
    ----------
    rec : Recording
        One UMich experiment.
    phase_prefix : str, default 'Layer'
        Phases whose name starts with this are cutting (``Layer 1 Up`` ... ``Layer 3 Down``).

    Returns
    -------
    pandas.DataFrame
    """
    ev = rec.events[rec.events["kind"] == "block"].sort_values("cycle")
    if ev.empty or "VALID" not in rec.hf.columns:
        raise ConfigError("not a UMich recording: needs phase events and the VALID column")
    idx = np.searchsorted(ev["cycle"].to_numpy(), rec.cycles, side="right") - 1
    phase = np.where(idx >= 0, ev["gcode"].astype(str).to_numpy()[np.maximum(idx, 0)], "")
    keep = np.char.startswith(phase.astype(str), phase_prefix) & (
        rec.hf["VALID"].to_numpy() == 1.0)
    out = rec.hf.loc[keep].copy()
    out["phase"] = phase[keep]
    return out


def feature_table(recordings: Sequence[Recording]) -> pd.DataFrame:
    """One row per experiment: labels and :data:`UMICH_FEATURES`.

    Parameters
    ----------
    recordings : sequence
        The UMich experiments (:func:`cnctwin.iotools.read_umich_dataset`).

    Returns
    -------
    pandas.DataFrame
        ``experiment``, ``worn`` (bool), ``feedrate`` [mm/s], ``clamp_pressure`` [bar],
        ``finalized`` (bool), ``n_rows`` (valid cutting rows), then the features.
    """
    rows = []
    for r in recordings:
        lab = r.meta.attrs.get("labels")
        if lab is None:
            raise ConfigError(f"{r.meta.source_files}: no labels (experiments.csv) attached")
        d = cutting_rows(r)
        rows.append(
            {
                "experiment": r.meta.attrs.get("experiment"),
                "worn": lab["tool_condition"] == "worn",
                "feedrate": lab["feedrate"],
                "clamp_pressure": lab["clamp_pressure"],
                "finalized": bool(lab["machining_finalized"]),
                "n_rows": len(d),
                "spindle_current_a": float(d["CURRENT|SP1"].mean()),
                "spindle_power_w": float(d["POWER|SP1"].mean()),
                "x_current_a": float(d["CURRENT|X1"].abs().mean()),
                "y_current_a": float(d["CURRENT|Y1"].abs().mean()),
                "x_following_error_mm": float((d["ENC_POS|X1"] - d["DES_POS|X1"]).abs().mean()),
                "y_following_error_mm": float((d["ENC_POS|Y1"] - d["DES_POS|Y1"]).abs().mean()),
            }
        )
    return pd.DataFrame(rows)


@dataclass(frozen=True)
class LoeoClassification:
    """Leave-one-experiment-out worn/unworn classification.

    Attributes
    ----------
    per_experiment : pandas.DataFrame
        ``experiment``, ``worn``, ``predicted``, ``p_worn`` (logistic only; NaN otherwise),
        ``baseline`` (majority class of the training experiments).
    accuracy, balanced_accuracy : float
        Of the classifier [-].
    baseline_accuracy, baseline_balanced_accuracy : float
        Of the majority-class baseline [-].
    classifier : str
    features : list of str
    """

    per_experiment: pd.DataFrame
    accuracy: float
    balanced_accuracy: float
    baseline_accuracy: float
    baseline_balanced_accuracy: float
    classifier: str
    features: list[str]


def loeo_classification(
    table: pd.DataFrame,
    *,
    features: Sequence[str] = UMICH_FEATURES,
    classifier: str = "logistic",
    normalize_feed: bool = True,
    alpha: float = 1.0,
) -> LoeoClassification:
    """Leave-one-experiment-out accuracy of a worn/unworn classifier vs the majority baseline.

    Parameters
    ----------
    table : pandas.DataFrame
        :func:`feature_table` (optionally filtered, e.g. finalized experiments only).
    features : sequence of str
        Feature columns.
    classifier : {'logistic', 'centroid'}
        L2 logistic regression or nearest centroid (scikit-learn), both on features
        standardized with the training fold's mean and standard deviation.
    normalize_feed : bool, default True
        Replace each feature by its residual from a line over ``feedrate`` fitted on the
        training fold.
    alpha : float, default 1
        L2 penalty of the logistic regression.

    Returns
    -------
    LoeoClassification

    Notes
    -----
    Balanced accuracy = mean of the recall of the two classes; it is 0.5 for any constant
    prediction, so it is the fair score when the classes are unbalanced (8 worn, 6 unworn).
    """
    if classifier not in ("logistic", "centroid"):
        raise ConfigError(f"classifier must be 'logistic' or 'centroid', not {classifier!r}")
    try:
        from sklearn.linear_model import LogisticRegression
        from sklearn.neighbors import NearestCentroid
        from sklearn.pipeline import make_pipeline
        from sklearn.preprocessing import StandardScaler
    except ImportError as exc:  # pragma: no cover - the 'learn' extra is part of 'all'
        raise ConfigError("the worn/unworn classification needs scikit-learn: "
                          "pip install 'cnctwin[learn]'") from exc
    x_all = table[list(features)].to_numpy(dtype=np.float64)
    y_all = table["worn"].to_numpy(dtype=bool)
    f_all = table["feedrate"].to_numpy(dtype=np.float64)
    rows = []
    for k in range(len(table)):
        tr = np.arange(len(table)) != k
        xtr, xte = x_all[tr].copy(), x_all[k : k + 1].copy()
        if normalize_feed:
            for j in range(xtr.shape[1]):
                c = np.polyfit(f_all[tr], xtr[:, j], 1)
                xtr[:, j] -= np.polyval(c, f_all[tr])
                xte[:, j] -= np.polyval(c, f_all[k : k + 1])
        ytr = y_all[tr]
        p_worn = math.nan
        if classifier == "logistic":
            # scikit-learn minimizes C * sum(log-loss) + |w|^2 / 2 with the intercept not
            # penalized: C = 1 / alpha is the L2 penalty alpha * |w|^2 / 2 on the log-loss
            model = make_pipeline(StandardScaler(), LogisticRegression(C=1.0 / alpha))
            model.fit(xtr, ytr)
            p_worn = float(model.predict_proba(xte)[0, list(model.classes_).index(True)])
            pred = p_worn >= 0.5
        else:
            model = make_pipeline(StandardScaler(), NearestCentroid())
            pred = bool(model.fit(xtr, ytr).predict(xte)[0])
        base = bool(ytr.mean() > 0.5)
        rows.append({"experiment": table["experiment"].iloc[k], "worn": bool(y_all[k]),
                     "predicted": bool(pred), "p_worn": p_worn, "baseline": base})
    from sklearn.metrics import balanced_accuracy_score

    per = pd.DataFrame(rows)
    y = per["worn"].to_numpy(dtype=bool)
    p = per["predicted"].to_numpy(dtype=bool)
    bl = per["baseline"].to_numpy(dtype=bool)
    return LoeoClassification(
        per, float(np.mean(p == y)), float(balanced_accuracy_score(y, p)),
        float(np.mean(bl == y)), float(balanced_accuracy_score(y, bl)),
        classifier, list(features),
    )


def _stream(rec: Recording, signal: str, seq_max: float) -> pd.DataFrame:
    d = cutting_rows(rec)
    return pd.DataFrame({
        "value": d[signal].to_numpy(dtype=np.float64),
        "progress": np.clip(d["SEQUENCE_NUMBER"].to_numpy(dtype=np.float64) / seq_max, 0, 1),
    })


def unfinished_backtest(
    recordings: Sequence[Recording],
    *,
    signal: str = "CURRENT|SP1",
    detector: Detector | None = None,
    same_feedrate: bool = True,
) -> pd.DataFrame:
    """Replay each experiment against a detector taught on the other finished experiments.

    For every experiment, the detector learns the valid cutting rows of the *finished*
    experiments (other than itself; with ``same_feedrate`` only those at its feedrate), then
    scores its own rows through :func:`~cnctwin.usecases.anomaly.backtest`. On a finished
    experiment every alarm is false; on an unfinished one the first alarm is a detection and
    ``lead_s`` says how long before the end of the record (where machining stopped) it came.

    Parameters
    ----------
    recordings : sequence of Recording
        The UMich experiments (with labels).
    signal : str, default 'CURRENT|SP1'
        Monitored HF column.
    detector : Detector, optional
        Default :class:`EnvelopeDetector` of the signal over the NC-program progress
        (``SEQUENCE_NUMBER`` / largest sequence number), 20 bins, 10 % margin.
    same_feedrate : bool, default True
        Teach only on finished experiments at the same feedrate.

    Returns
    -------
    pandas.DataFrame
        ``experiment``, ``finalized``, ``feedrate``, ``taught_on`` (experiment numbers),
        ``scored_s`` (scored duration) [s], ``alarms``, ``first_alarm_s`` (from the start of
        the experiment's cutting rows) [s], ``lead_s`` (end of record minus first alarm) [s].
    """
    det = detector if detector is not None else EnvelopeDetector(
        signal="value", progress="progress", n_bins=20, margin=0.1, min_margin=0.05)
    labs = [r.meta.attrs["labels"] for r in recordings]
    seq_max = max(float(r.hf["SEQUENCE_NUMBER"].max()) for r, lab in
                  zip(recordings, labs, strict=True) if lab["machining_finalized"])
    dt = recordings[0].meta.cycle_time_s
    rows = []
    for k, rec in enumerate(recordings):
        teach = [j for j, (r, lab) in enumerate(zip(recordings, labs, strict=True))
                 if j != k and lab["machining_finalized"]
                 and (not same_feedrate or lab["feedrate"] == labs[k]["feedrate"])]
        exp = rec.meta.attrs.get("experiment")
        if not teach:
            rows.append({"experiment": exp, "finalized": bool(labs[k]["machining_finalized"]),
                         "feedrate": labs[k]["feedrate"], "taught_on": [], "scored_s": 0.0,
                         "alarms": -1, "first_alarm_s": math.nan, "lead_s": math.nan})
            continue
        parts = [_stream(recordings[j], signal, seq_max) for j in teach]
        learn = pd.concat(parts, ignore_index=True)
        test = _stream(rec, signal, seq_max)
        data = pd.concat([learn, test], ignore_index=True)
        t = np.arange(len(data)) * dt
        t_learn_end = len(learn) * dt
        res = backtest(det, data, time_s=t, learn_until_s=t_learn_end - dt / 2,
                       max_delay_s=0.0, refractory_s=1.0)
        first = (res.alarms_s[0] - t_learn_end) if res.alarms_s else math.nan
        rows.append({
            "experiment": exp, "finalized": bool(labs[k]["machining_finalized"]),
            "feedrate": labs[k]["feedrate"],
            "taught_on": [recordings[j].meta.attrs.get("experiment") for j in teach],
            "scored_s": len(test) * dt, "alarms": len(res.alarms_s),
            "first_alarm_s": first, "lead_s": len(test) * dt - first,
        })
    return pd.DataFrame(rows)
