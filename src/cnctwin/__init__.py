"""cnctwin: an open-source edge digital twin for CNC machine tools (SINUMERIK 840D sl class).

Layers, as in pvlib:

* functions in physics-named modules (:mod:`cnctwin.spindle`, :mod:`cnctwin.servo`,
  :mod:`cnctwin.analysis`, :mod:`cnctwin.usecases`), tested on values;
* description objects (:class:`cnctwin.sim.Machine`, :class:`cnctwin.spindle.SpindleModel`);
* one orchestrator (:class:`cnctwin.twin.TwinChain`).

Data flows one way: readers in :mod:`cnctwin.iotools` (or the simulator in :mod:`cnctwin.sim`)
produce a :class:`Recording`; analyses read only the Recording.
"""

from __future__ import annotations

from cnctwin.exceptions import (
    CnctwinError,
    CnctwinWarning,
    ConfigError,
    FormatError,
    GCodeError,
    IdentificationError,
    SignalNotFoundError,
    StoreError,
    TruncatedFileError,
)
from cnctwin.iotools import read_recording
from cnctwin.recording import CounterGap, ExternalChannel, Recording, RecordingMeta

__version__ = "0.1.0"

__all__ = [
    "CnctwinError",
    "CnctwinWarning",
    "ConfigError",
    "CounterGap",
    "ExternalChannel",
    "FormatError",
    "GCodeError",
    "IdentificationError",
    "Recording",
    "RecordingMeta",
    "SignalNotFoundError",
    "StoreError",
    "TruncatedFileError",
    "__version__",
    "read_recording",
]
