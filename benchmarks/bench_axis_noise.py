"""Feed-axis noise: the simulator's standing axes beside the real recordings (issue 29, pt 1).

Per axis, over the cycles where the setpoint stands still (``DES_POS`` unchanged): the
cycle-to-cycle noise (std of the first difference / sqrt 2) of ``CURRENT``, ``TORQUE``,
``CMD_SPEED`` and ``ENC_POS``; the lag-1 correlation of the ``ENC_POS`` increments (white
measuring noise gives -0.5, a random walk of real motion 0); the share of the ``CURRENT``
noise power above 50 Hz (a white spectrum has 80 % of 0-250 Hz there); ``TORQUE`` against
Kt x ``CURRENT`` (slope and residual). Real files: the Capture4Analysis recording (X1, Y1,
C1; SINUMERIK 840D sl) and the servo trace (AX7, SINUMERIK Solution Line, positions in the
trace's own unit), both in ``tests/data/real/``; simulated: ``cnctwin simulate axis_test``
with two seeds. Prints one table; docs/simulator.md §1b records it.

Run: ``.venv/bin/python benchmarks/bench_axis_noise.py``
"""

from __future__ import annotations

import contextlib
import io
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

from cnctwin.cli import main
from cnctwin.iotools import read_recording
from cnctwin.recording import Recording

ROOT = Path(__file__).resolve().parents[1]
C4A = (ROOT / "tests/data/real/capture4analysis"
       / "example_data_ff429d74-6482-4d4f-80e1-31419d9bd56c.json")
TRACE = ROOT / "tests/data/real/sinumerik-trace/Tav23362_2140_frenata_15_4_26_EmgTest.xml"


def _col(rec: Recording, code: str, ax: str) -> np.ndarray | None:
    c = f"{code}|{ax}"
    return rec.hf[c].to_numpy(dtype=np.float64) if c in rec.hf.columns else None


def stats(rec: Recording, ax: str, enc_code: str = "ENC_POS") -> dict[str, float]:
    des = _col(rec, "DES_POS", ax)
    assert des is not None
    still = np.r_[False, np.diff(des) == 0.0]
    pair = still[1:] & still[:-1]
    out: dict[str, float] = {"cycles": float(pair.sum())}
    for code in ("CURRENT", "TORQUE", "CMD_SPEED", enc_code):
        x = _col(rec, code, ax)
        if x is None:
            continue
        d = np.diff(x)[pair & np.isfinite(np.diff(x))]
        out[code] = float(np.std(d) / math.sqrt(2.0))
        if code == enc_code and d.size > 2:
            out["enc_lag1"] = float(np.corrcoef(d[1:], d[:-1])[0, 1])
    cur, tq = _col(rec, "CURRENT", ax), _col(rec, "TORQUE", ax)
    if cur is not None:
        # share of the noise power above 50 Hz: the longest standing stretch, detrended
        edges = np.flatnonzero(np.diff(np.r_[0, still.astype(np.int8), 0]))
        runs = sorted(zip(edges[::2], edges[1::2], strict=True), key=lambda r: r[0] - r[1])
        a, b = runs[0]
        seg = cur[a:b] - np.polyval(np.polyfit(np.arange(b - a), cur[a:b], 1), np.arange(b - a))
        if seg.size >= 128:
            p = np.abs(np.fft.rfft(seg * np.hanning(seg.size))) ** 2
            f = np.fft.rfftfreq(seg.size, rec.meta.cycle_time_s)
            out["hf_share"] = float(p[f > 50.0].sum() / p[f > 0.5].sum())
    if cur is not None and tq is not None:
        k = np.polyfit(cur[still], tq[still], 1)
        out["torque_per_a"] = float(k[0])
        out["torque_resid"] = float(np.std(tq[still] - np.polyval(k, cur[still])))
    return out


def simulated(d: Path, seed: int) -> Recording:
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        rc = main(["simulate", "axis_test", "--out", str(d / f"s{seed}"), "--seed", str(seed)])
    if rc:
        raise SystemExit(f"simulate axis_test exited {rc}")
    return read_recording(d / f"s{seed}" / "axis_test.json")


def row(name: str, s: dict[str, float]) -> str:
    def g(k: str, fmt: str = ".3g") -> str:
        return format(s[k], fmt) if k in s and math.isfinite(s[k]) else "-"
    enc = s.get("ENC_POS", s.get("ENC1_POS", math.nan))
    return (f"| {name} | {int(s['cycles'])} | {g('CURRENT')} | {g('TORQUE')} | "
            f"{g('CMD_SPEED')} | {format(enc * 1000.0, '.3g') if math.isfinite(enc) else '-'} | "
            f"{g('enc_lag1', '.2f')} | {g('hf_share', '.2f')} | {g('torque_per_a', '.4g')} | "
            f"{g('torque_resid')} |")


if __name__ == "__main__":
    print("| recording, axis | standing cycle pairs | CURRENT [A] | TORQUE | CMD_SPEED [/s] | "
          "ENC_POS [um or mdeg] | ENC increments lag-1 | CURRENT power > 50 Hz | "
          "TORQUE per A | TORQUE - k CURRENT, std |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    real = read_recording(C4A)
    for ax in ("X1", "Y1", "C1"):
        print(row(f"real C4A {ax}", stats(real, ax)))
    trace = read_recording(TRACE)
    print(row("real servo trace AX7", stats(trace, "AX7", enc_code="ENC1_POS")))
    with tempfile.TemporaryDirectory() as tmp:
        for seed in (0, 2):
            rec = simulated(Path(tmp), seed)
            for ax in ("X1", "Y1"):
                print(row(f"simulated seed {seed} {ax}", stats(rec, ax)))
    sys.stdout.flush()
