"""Synthetic Capture4Analysis files for the IO benchmark.

The file mimics the real recording in ``tests/data/real/capture4analysis``: 61 columns (CYCLE +
10 codes x 6 axes), HF chunks of 1..101 rows, values with 6 decimals and many exact zeros
(the real file averages 8.6 bytes per value), one ``HFTimestamp`` per chunk, a block event
every ~40 cycles, a call event every ~150 cycles and five LF values every 250 cycles. It is
written with the project's streaming :class:`~cnctwin.iotools.Capture4AnalysisWriter`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from cnctwin.iotools import Capture4AnalysisWriter

CODES = ("CMD_SPEED", "CONT_DEV", "VEL_FFW", "TORQUE_FFW", "TORQUE", "POWER", "CURRENT", "LOAD",
         "ENC_POS", "DES_POS")
AXES = {1: "X1", 2: "Y1", 3: "Z1", 4: "C1", 5: "B1", 6: "SP1"}
BYTES_PER_ROW = 520  # measured on generated data (61 values per row)


def _values(rng: np.random.Generator, cycles: np.ndarray, n_cols: int) -> np.ndarray:
    t = cycles.astype(np.float64) * 0.002
    scale = np.geomspace(1e-3, 7e4, n_cols)
    phase = np.arange(n_cols, dtype=np.float64)
    v = np.sin(t[:, None] * (0.3 + phase * 0.05) + phase) * scale
    v += rng.standard_normal(v.shape) * scale * 1e-3
    v[:, ::3] = 0.0  # many exact zeros, as in the real file (idle axes, feed-forward off)
    return np.round(v, 6)


def generate_c4a(path: str | Path, *, mb: float = 100.0, seed: int = 7,
                 zip: bool = False) -> Path:
    """Write a synthetic recording of about ``mb`` megabytes; returns the file."""
    rng = np.random.default_rng(seed)
    cols = [f"{code}|{ax}" for code in CODES for ax in AXES.values()]
    n_rows = int(mb * 1e6 / BYTES_PER_ROW)
    start = 5_558_098
    t0 = pd.Timestamp("2023-12-22T14:26:01.108Z")
    writer = Capture4AnalysisWriter(
        path, columns=cols, axis_map=AXES, machine="sinumerik_adapter_840Dsl",
        initial=(start, t0), zip=zip, chunk_rows=101,
        lf_signals=[f"/Channel/State/{s}" for s in ("actToolIdent", "actTNumber",
                                                   "actToolLength1", "actToolLength2",
                                                   "actToolRadius")],
    )
    done = 0
    with writer:
        while done < n_rows:
            size = min(int(rng.integers(1, 102)), n_rows - done)
            c = np.arange(start + done, start + done + size)
            writer.write_hf(c, _values(rng, c, len(cols)))
            last = int(c[-1])
            writer.write_timestamp(last, t0 + pd.Timedelta(milliseconds=2 * (last - start)))
            for cyc in c[c % 40 == 0]:
                writer.write_block_event(int(cyc), seek_offset=int(cyc % 977), selected_tool=6,
                                         active_tool=6, gcode=f"N{cyc % 1000} G1 X[aXX]=1.5",
                                         ipo_gcode="G1", la_buf=1)
            for cyc in c[c % 150 == 0]:
                writer.write_call_event(int(cyc), seek_offset=12, call_stack_level=2,
                                        path="/_CUTTING")
            for cyc in c[c % 250 == 0]:
                writer.write_lf([{"cycle": int(cyc), "signal": f"/Channel/State/{s}",
                                  "value": v, "time": "2023-12-22T13:23:41.392226Z"}
                                 for s, v in (("actToolIdent", "182437"), ("actTNumber", "6"),
                                              ("actToolLength1", "0.0"),
                                              ("actToolLength2", "75.316999999999993"),
                                              ("actToolRadius", "48.959000000000003"))])
            done += size
    return writer.files[0]
