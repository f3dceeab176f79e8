"""Readers and writers, one module per source (pvlib.iotools style).

``read_recording(path)`` detects the format; format-specific readers are importable by name
(``read_capture4analysis``, ...); ``parse_capture4analysis(data)`` parses a document held in
memory. Every reader returns a :class:`~cnctwin.recording.Recording`.
"""

from __future__ import annotations

from cnctwin.iotools._detect import read_recording
from cnctwin.iotools.capture4analysis import (
    Capture4AnalysisWriter,
    parse_capture4analysis,
    read_capture4analysis,
    write_capture4analysis,
)
from cnctwin.iotools.csv_export import write_csv
from cnctwin.iotools.databus import DatabusDecoder, DatabusValue
from cnctwin.iotools.dynamometer import (
    attach_external,
    read_dynamometer_csv,
    read_dynamometer_tdms,
)
from cnctwin.iotools.edge_dataobject import (
    EdgeDataobjectAssembler,
    parse_edge_dataobject,
    read_edge_dataobject,
)
from cnctwin.iotools.flat_csv import read_flat_csv
from cnctwin.iotools.mqtt import MqttRecorder, subscribe_data_recorder, subscribe_databus
from cnctwin.iotools.parquet import read_parquet, write_parquet
from cnctwin.iotools.sinumerik_trace import read_sinumerik_trace
from cnctwin.iotools.thermal import read_thermal_camera_csv
from cnctwin.iotools.umich import read_umich, read_umich_dataset, read_umich_labels

__all__ = ["read_recording"]
__all__ += [  # Capture4Analysis / Data Recorder, Parquet and CSV export
    "Capture4AnalysisWriter",
    "parse_capture4analysis",
    "read_capture4analysis",
    "read_parquet",
    "write_capture4analysis",
    "write_csv",
    "write_parquet",
]
__all__ += [  # readers of the non-Capture4Analysis sources
    "DatabusDecoder",
    "DatabusValue",
    "EdgeDataobjectAssembler",
    "MqttRecorder",
    "attach_external",
    "parse_edge_dataobject",
    "read_dynamometer_csv",
    "read_dynamometer_tdms",
    "read_edge_dataobject",
    "read_flat_csv",
    "read_sinumerik_trace",
    "read_thermal_camera_csv",
    "read_umich",
    "read_umich_dataset",
    "read_umich_labels",
    "subscribe_data_recorder",
    "subscribe_databus",
]
