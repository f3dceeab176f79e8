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
