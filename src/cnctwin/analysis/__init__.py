"""Signal processing on Recordings: filters, alignment, segments, spectra, correlation.

Pure functions on arrays (frequencies in Hz with an explicit ``fs_hz``, scipy.signal SOS
idioms) plus thin helpers that read a :class:`~cnctwin.recording.Recording`.
"""

from __future__ import annotations

from cnctwin.analysis.align import (
    Alignment,
    AlignmentWarning,
    align,
    align_external,
    external_on_hf,
)
from cnctwin.analysis.correlation import correlation_matrix, plot_correlation_heatmaps
from cnctwin.analysis.filters import (
    CausalFilter,
    FilterWarning,
    bandpass,
    bandstop,
    extract_stator_component,
    fold_frequency,
    highpass,
    lowpass,
    remove_stator_component,
    stator_frequency_hz,
)
from cnctwin.analysis.segments import (
    cutting_regions,
    hysteresis_mask,
    speed_plateaus,
    spindle_speed_rpm,
)
from cnctwin.analysis.spectra import (
    DominantLine,
    Spectrum,
    amplitude_spectrum,
    dominant_frequency,
    dominant_line,
)

__all__ = [
    "Alignment",
    "AlignmentWarning",
    "CausalFilter",
    "DominantLine",
    "FilterWarning",
    "Spectrum",
    "align",
    "align_external",
    "amplitude_spectrum",
    "bandpass",
    "bandstop",
    "correlation_matrix",
    "cutting_regions",
    "dominant_frequency",
    "dominant_line",
    "external_on_hf",
    "extract_stator_component",
    "fold_frequency",
    "highpass",
    "hysteresis_mask",
    "lowpass",
    "plot_correlation_heatmaps",
    "remove_stator_component",
    "speed_plateaus",
    "spindle_speed_rpm",
    "stator_frequency_hz",
]
