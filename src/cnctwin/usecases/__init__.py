"""Use-cases of thesis chapter 5: per-hole record, tool wear, tool temperature, hole quality,
anomaly detection."""

from __future__ import annotations

from cnctwin.usecases.wear import (
    LifeForecast,
    LogoResult,
    SetPattern,
    WearEstimator,
    forecast_remaining_life,
    leave_one_group_out,
    moving_average,
    relative_increase,
    set_pattern,
)

__all__ = [
    "LifeForecast",
    "LogoResult",
    "SetPattern",
    "WearEstimator",
    "forecast_remaining_life",
    "leave_one_group_out",
    "moving_average",
    "relative_increase",
    "set_pattern",
]

from cnctwin.usecases.holes import hole_record, hole_records
from cnctwin.usecases.quality import deviation_paths, hole_quality
from cnctwin.usecases.thermal import ToolThermalModel, merge_camera

__all__ += [
    "ToolThermalModel",
    "deviation_paths",
    "hole_quality",
    "hole_record",
    "hole_records",
    "merge_camera",
]
