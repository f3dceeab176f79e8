"""Helpers of the live-source tests: a recording's drive signals as Industrial Edge Databus
``bulk`` messages (the documented payload, the SINUMERIK cycle counter as the ``CYCLE``
datapoint ``"1"``), and the results file read back."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import orjson
import pandas as pd

from cnctwin.recording import Recording


def bulk_messages(rec: Recording, columns: list[str], per_msg: int) -> list[bytes]:
    """``per_msg`` cycles per message; datapoint ids ``"1"`` (CYCLE), then ``"2"``, ... in the
    order of ``columns``."""
    t_ms = rec.hf["time"].astype("int64").to_numpy() // 1_000_000
    data = {c: rec.hf[c].to_numpy(dtype=np.float64) for c in columns}
    cyc = rec.cycles
    out = []
    for j, k in enumerate(range(0, cyc.size, per_msg)):
        vals: list[dict[str, Any]] = []
        for r in range(k, min(k + per_msg, cyc.size)):
            ts = pd.Timestamp(int(t_ms[r]), unit="ms").strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z"
            vals.append({"id": "1", "qc": 3, "ts": ts, "val": int(cyc[r])})
            vals += [{"id": str(i + 2), "qc": 3, "ts": ts, "val": float(data[c][r])}
                     for i, c in enumerate(columns)]
        out.append(orjson.dumps({"seq": j + 1, "vals": vals}))
    return out


def read_results(path: Path) -> list[dict[str, Any]]:
    """The messages of a ``results.jsonl`` (a line a SIGKILL cut short is left out)."""
    msgs = []
    for line in path.read_text(encoding="utf-8").splitlines():
        try:
            msgs.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return msgs


def torque_of(msgs: list[dict[str, Any]]) -> tuple[np.ndarray, np.ndarray]:
    """Cycles and cutting torque [Nm] of the ``torque`` messages, in order."""
    t = [m for m in msgs if m["kind"] == "torque"]
    if not t:
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    return (np.concatenate([np.arange(m["first_cycle"], m["first_cycle"] + m["n"]) for m in t]),
            np.concatenate([np.asarray(m["torque_nm"], dtype=float) for m in t]))
