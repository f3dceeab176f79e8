"""The edge StoreSink writes the per-hole table of the store; its rows equal the batch
``cnctwin.usecases.holes.hole_records`` of the same recording.

Recording: the simulated 3-hole ``tool_wear_run`` of ``conftest.wear_run`` (thesis §5.1).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

import cnctwin.store
from cnctwin.edge import EdgeRuntime, HoleProcessor, ReplaySource, StoreSink, TorqueProcessor
from cnctwin.recording import Recording
from cnctwin.spindle import SpindleModel
from cnctwin.usecases.holes import hole_records


def _replay(rec: Recording, model: SpindleModel, store: Path) -> StoreSink:
    sink = StoreSink(store, machine="mill-1", block_cycles=2500)
    EdgeRuntime(ReplaySource(rec, chunk_cycles=50),
                [TorqueProcessor(model), HoleProcessor(model)], [sink]).run()
    return sink


def test_store_sink_hole_table_equals_batch(tmp_path: Path, wear_recording: Recording,
                                            spindle_model: SpindleModel) -> None:
    rec = wear_recording
    sink = _replay(rec, spindle_model, tmp_path / "store")
    assert sink.holes_written == 3
    batch = hole_records([rec], model=spindle_model)
    with cnctwin.store.open(tmp_path / "store") as st:
        got = st.holes(machine="mill-1")
        blocks = set(st.recordings(machine="mill-1")["recording_id"])
    assert len(got) == len(batch) == 3
    assert set(got["recording_id"]) <= blocks  # each hole under the block it completed in
    for col in batch.columns:
        b, s = batch[col], got[col]
        if pd.api.types.is_float_dtype(b):
            # the streamed row is hole_record on the same samples (test_replay): equal to
            # rounding; the store keeps float64 exactly
            np.testing.assert_allclose(s.to_numpy(dtype=float), b.to_numpy(), rtol=1e-12,
                                       atol=1e-12, equal_nan=True, err_msg=col)
        else:
            assert s.tolist() == b.tolist(), col  # ints, tool (Int64), text, start_time (ns)
    # a second replay of the same stream (a restarted runtime) stores every hole once
    _replay(rec, spindle_model, tmp_path / "store")
    with cnctwin.store.open(tmp_path / "store") as st:
        assert st.holes(machine="mill-1")["hole"].tolist() == [0, 1, 2]
