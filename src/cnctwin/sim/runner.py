"""Running a scenario: sinks, truth files, seeds and the program file beside the recording."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from cnctwin.exceptions import ConfigError
from cnctwin.recording import Recording
from cnctwin.sim.config import (
    START_CYCLE,
    START_TIME,
    ScenarioConfig,
    ScenarioResult,
)
from cnctwin.sim.faults import Fault
from cnctwin.sim.gcode import Program
from cnctwin.sim.processes import _DynamometerDAQ, _TruthParquet
from cnctwin.sim.recorder import Capture4AnalysisSink, ParquetChunkSink, RecordingSink
from cnctwin.sim.simulation import SimulationResult, simulate

__all__: list[str] = []

_FORMATS = ("c4a", "parquet")


# ----------------------------------------------------------------------------- running
class _EventTee:
    """Forward chunks to a sink and keep the (small) NC event table."""

    def __init__(self, sink: RecordingSink) -> None:
        self.sink = sink
        self.events: list[pd.DataFrame] = []
        # the tee keeps only each chunk's (fresh) events frame: buffer reuse stays safe
        self.keeps_chunks = getattr(sink, "keeps_chunks", True)

    def open(self, columns: list[str], meta: Any) -> None:
        self.sink.open(columns, meta)

    def write(self, chunk: Any) -> None:
        if len(chunk.events):
            self.events.append(chunk.events)
        self.sink.write(chunk)

    def close(self, meta: Any) -> Recording | None:
        return self.sink.close(meta)

    def event_table(self) -> pd.DataFrame:
        return pd.concat(self.events, ignore_index=True) if self.events else pd.DataFrame()


def _make_sink(out: Path | None, stem: str, fmt: str,
               max_file_mb: float | None) -> tuple[RecordingSink | None, Path | None]:
    if fmt not in _FORMATS:
        raise ConfigError(f"fmt must be one of {_FORMATS}, not {fmt!r}")
    if out is None:
        return None, None
    if fmt == "c4a":
        path = out / f"{stem}.json"
        return Capture4AnalysisSink(path, max_file_mb=max_file_mb), path
    path = out / stem
    return ParquetChunkSink(path), path


def _sink_files(sink: Any, path: Path | None) -> list[Path]:
    if sink is None:
        return []
    inner = sink.sink if isinstance(sink, _EventTee) else sink
    files = list(getattr(inner, "files", []))
    if isinstance(inner, ParquetChunkSink) and path is not None:
        return [path]
    return files


def _collect(res: ScenarioResult, sim: Any, sink: Any, path: Path | None,
             daq: _DynamometerDAQ | None, tp: _TruthParquet | None) -> None:
    """Keep a finished simulation in ``res``: the in-memory recording with its first
    dynamometer session attached and its per-cycle truth, or the files written."""
    if sim.recording is not None:
        rec = sim.recording
        if daq is not None and daq.channels:
            rec.external["dynamometer"] = daq.channels[0]
        res.recordings.append(rec)
        res.per_cycle.append(sim.truth["per_cycle"])
    if path is not None:
        res.recording_paths.append(path)
        res.paths += _sink_files(sink, path) + (daq.paths if daq is not None else [])
        if tp is not None and tp.close() is not None:
            res.paths.append(tp.path)


def _sim_seed(seed: int, *key: int) -> int:
    return int(np.random.SeedSequence([seed, *key]).generate_state(1)[0])


def _simulate(program: Program, cfg: ScenarioConfig, *, seed: int, hook: Any,
              sink: Any, chunk_cycles: int) -> SimulationResult:
    return simulate(program, cfg.machine, seed=seed, start_cycle=START_CYCLE,
                    start_time=START_TIME, cutting=hook, sink=sink, chunk_cycles=chunk_cycles)


def _prepare(out: str | Path | None) -> Path | None:
    if out is None:
        return None
    p = Path(out)
    p.mkdir(parents=True, exist_ok=True)
    return p


def _write_program(out: Path | None, name: str, text: str, paths: list[Path]) -> None:
    if out is not None:
        p = out / name
        p.write_text(text, encoding="utf-8")
        paths.append(p)


def _json_default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    if isinstance(o, pd.Timestamp):
        return o.isoformat()
    if isinstance(o, pd.DataFrame):
        return o.to_dict("records")
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def _write_truth(out: Path | None, truth: dict[str, Any], paths: list[Path]) -> None:
    if out is None:
        return
    p = out / "truth.json"
    p.write_text(json.dumps(truth, indent=1, default=_json_default), encoding="utf-8")
    paths.append(p)


def _base_truth(name: str, seed: int, overrides: Mapping[str, Any] | None,
                cfg: ScenarioConfig) -> dict[str, Any]:
    return {"scenario": name, "seed": seed, "overrides": dict(overrides or {}),
            "start_cycle": START_CYCLE, "start_time": START_TIME.isoformat(),
            "cycle_time_s": cfg.machine.cycle_time_s, **cfg.to_dict()}


def _faults_from(faults: Sequence[Fault | Mapping[str, Any]]) -> tuple[Fault, ...]:
    """Faults given as objects or as dicts with a ``type`` key (CLI / JSON)."""
    from cnctwin.sim import faults as fmod

    out: list[Fault] = []
    for f in faults:
        if isinstance(f, Mapping):
            d = dict(f)
            kind = d.pop("type", None)
            cls = getattr(fmod, str(kind), None)
            known = ("LooseTool", "ToolBreakage", "Chatter", "HardnessChange")
            if kind not in known or cls is None:
                raise ConfigError(f"fault {f!r}: 'type' must be LooseTool, ToolBreakage, "
                                  "Chatter or HardnessChange")
            try:
                out.append(cls(**d))
            except TypeError as exc:
                raise ConfigError(f"fault {f!r}: {exc}") from exc
        else:
            out.append(f)
    return tuple(out)


def _rec_time_s(cycle: int, cfg: ScenarioConfig) -> float:
    return (cycle - START_CYCLE) * cfg.machine.cycle_time_s


def _write_recording(rec: Recording, out: Path, stem: str, fmt: str,
                     max_file_mb: float | None, paths: list[Path]) -> Path:
    """Write an in-memory recording as C4A (chained) or a Parquet chunk directory."""
    if fmt not in _FORMATS:
        raise ConfigError(f"fmt must be one of {_FORMATS}, not {fmt!r}")
    if fmt == "c4a":
        from cnctwin.iotools.capture4analysis import write_capture4analysis

        path = out / f"{stem}.json"
        paths += list(write_capture4analysis(rec, path, max_file_mb=max_file_mb))
        return path
    from cnctwin.sim.recorder import RecordedChunk

    path = out / stem
    sink = ParquetChunkSink(path)
    cols = [c for c in rec.hf.columns if c != "time"]
    sink.open(cols, rec.meta)
    step = 50_000
    cyc = rec.cycles
    for a in range(0, cyc.size, step):
        part = rec.hf.iloc[a:a + step]
        lf = rec.lf if a == 0 and rec.lf is not None else pd.DataFrame(columns=["cycle"])
        ev = rec.events if a == 0 and rec.events is not None else pd.DataFrame(columns=["kind"])
        sink.write(RecordedChunk(cycles=cyc[a:a + step],
                                 hf={c: part[c].to_numpy() for c in cols}, lf=lf, events=ev))
    sink.close(rec.meta)
    paths.append(path)
    return path


