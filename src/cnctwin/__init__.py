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

import typing

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

if typing.TYPE_CHECKING:  # imported on first use (below): `cnctwin --help` needs neither
    from cnctwin.iotools import read_recording
    from cnctwin.recording import CounterGap, ExternalChannel, Recording, RecordingMeta

__version__ = "0.1.0"

_LAZY = {"read_recording": "cnctwin.iotools", "CounterGap": "cnctwin.recording",
         "ExternalChannel": "cnctwin.recording", "Recording": "cnctwin.recording",
         "RecordingMeta": "cnctwin.recording"}


def __getattr__(name: str) -> object:
    # the readers pull in pandas and scipy (~0.3 s): loaded when first asked for, so the
    # command line starts fast and a subcommand imports only what it uses
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'cnctwin' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})

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
