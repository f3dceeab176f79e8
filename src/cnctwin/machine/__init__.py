"""The machine description layer: what a machine is, and the one file that keeps it.

Below the analyses and the simulator: :mod:`cnctwin.machine.description` holds the
description types (:class:`Machine`, :class:`FeedAxis`, :class:`SpindleMotor`),
:mod:`cnctwin.machine.file` the machine file (:func:`load_machine`, :func:`save_machine`)
that ``cnctwin calibrate`` writes and every other part reads.
"""

from cnctwin.machine.description import (
    KV_UNIT_PER_S,
    FeedAxis,
    Machine,
    SpindleMotor,
    dynamic_response_adaptation_times,
)
from cnctwin.machine.file import (
    SCHEMA,
    SCHEMA_VERSION,
    MachineFile,
    ParameterRecord,
    Provenance,
    load_machine,
    parameter_unit,
    save_machine,
)
from cnctwin.machine.tools import Drill, EndMill, Tap
from cnctwin.machine.tooltable import (
    TOOL_KINDS,
    ToolSpec,
    ToolTable,
    read_toml,
    read_tool_table,
)

__all__ = [
    "KV_UNIT_PER_S",
    "SCHEMA",
    "SCHEMA_VERSION",
    "TOOL_KINDS",
    "Drill",
    "EndMill",
    "FeedAxis",
    "Machine",
    "MachineFile",
    "ParameterRecord",
    "Provenance",
    "SpindleMotor",
    "Tap",
    "ToolSpec",
    "ToolTable",
    "dynamic_response_adaptation_times",
    "load_machine",
    "parameter_unit",
    "read_toml",
    "read_tool_table",
    "save_machine",
]
