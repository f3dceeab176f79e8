"""Calibrate the twin of one's own machine from its recordings (``cnctwin calibrate``).

An orchestration layer above the analyses (:mod:`cnctwin.twin`, :mod:`cnctwin.servo`): each
function turns recordings into machine-file records (value, standard uncertainty,
provenance, valid range) for :mod:`cnctwin.machine.file`.
"""

from cnctwin.calibration.spindle import (
    METHODS,
    SpindleCalibration,
    calibrate_spindle,
    check_air_cut_plateaus,
)

__all__ = ["METHODS", "SpindleCalibration", "calibrate_spindle", "check_air_cut_plateaus"]
