"""Position-control twin: signal relations, loop identification, geometry, prediction.

Analyses read only :class:`~cnctwin.recording.Recording` objects (never simulator internals), so
they run unchanged on real Capture4Analysis files and servo traces.

* :mod:`~cnctwin.servo.relations`: :func:`check_relations` (following error, CTRL_DIFF2,
  CONT_DEV, VEL_FFW, CMD_SPEED relations with residual statistics).
* :mod:`~cnctwin.servo.identify`: :func:`identify_axis` (Kv, feedforward, jerk filter, delays,
  speed loop, friction) with uncertainties.
* :mod:`~cnctwin.servo.geometry`: :func:`contour_error`, :func:`circle_test` (ISO 230-4).
* :mod:`~cnctwin.servo.predict`: :class:`AxisLoopModel`, :class:`DriftMonitor`.
* :mod:`~cnctwin.servo.figures`: thesis Fig. 3.2/3.3 style figures.
"""

from __future__ import annotations

from cnctwin.servo._common import moving_axes
from cnctwin.servo.geometry import CircleResult, ContourErrorResult, circle_test, contour_error
from cnctwin.servo.identify import (
    JERK_FILTER_TYPES,
    KV_PER_S_PER_M_MIN_MM,
    AxisIdentification,
    Estimate,
    identify_axis,
)
from cnctwin.servo.predict import (
    AxisLoopModel,
    DriftAlarm,
    DriftMonitor,
    Prediction,
    prediction_residual,
)
from cnctwin.servo.relations import Relation, RelationReport, check_relations

__all__ = [
    "JERK_FILTER_TYPES",
    "KV_PER_S_PER_M_MIN_MM",
    "AxisIdentification",
    "AxisLoopModel",
    "CircleResult",
    "ContourErrorResult",
    "DriftAlarm",
    "DriftMonitor",
    "Estimate",
    "Prediction",
    "Relation",
    "RelationReport",
    "check_relations",
    "circle_test",
    "contour_error",
    "identify_axis",
    "moving_axes",
    "prediction_residual",
]
