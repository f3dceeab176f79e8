"""Edge streaming runtime: live Databus/MQTT or replayed recordings in, results out.

Layers (pure pieces first, orchestration last):

* :mod:`~cnctwin.edge.cycles`: the CYCLE time base of a stream (unwrap, gaps, late rows).
* :mod:`~cnctwin.edge.model_file`: the calibrated spindle model as a JSON/TOML file.
* :mod:`~cnctwin.edge.pipeline`: ``Chunk``, ``Result`` and the Source/Processor/Sink protocols.
* :mod:`~cnctwin.edge.sources`: replay of any recording file, live Databus over MQTT.
* :mod:`~cnctwin.edge.cut`: the live hole context (hole number, tip depth, progress) per cycle.
* :mod:`~cnctwin.edge.processors`: cutting torque, per-hole record, anomaly detectors.
* :mod:`~cnctwin.edge.forward_log`: the bounded on-disk queue of store-and-forward (an
  append-only log; :mod:`~cnctwin.edge.forward`: the SQLite queue of earlier versions).
* :mod:`~cnctwin.edge.sinks`: MQTT (store-and-forward), the store, JSON lines.
* :mod:`~cnctwin.edge.opcua`: an OPC UA server sink (extra ``opcua``; import it from there).
* :mod:`~cnctwin.edge.runtime`: :class:`EdgeRuntime`, the loop and its status.
* :mod:`~cnctwin.edge.plant`: many machines in one process group (the plant file, worker
  processes, restarts).

See docs/edge.md.
"""

from cnctwin.edge.cycles import CycleTracker
from cnctwin.edge.forward import ForwardQueue
from cnctwin.edge.forward_log import ForwardLog
from cnctwin.edge.model_file import load_spindle_model, save_spindle_model
from cnctwin.edge.pipeline import Chunk, Result
from cnctwin.edge.processors import AnomalyProcessor, HoleProcessor, TorqueProcessor
from cnctwin.edge.runtime import EdgeRuntime, last_emitted_cycle, read_status
from cnctwin.edge.sinks import JsonLinesSink, MqttSink, StoreSink
from cnctwin.edge.sources import (
    DatabusSource,
    ReplaySource,
    parse_mqtt_url,
    session_client_id,
)

__all__ = [
    "AnomalyProcessor",
    "Chunk",
    "CycleTracker",
    "DatabusSource",
    "EdgeRuntime",
    "ForwardLog",
    "ForwardQueue",
    "HoleProcessor",
    "JsonLinesSink",
    "MqttSink",
    "ReplaySource",
    "Result",
    "StoreSink",
    "TorqueProcessor",
    "last_emitted_cycle",
    "load_spindle_model",
    "parse_mqtt_url",
    "read_status",
    "save_spindle_model",
    "session_client_id",
]
