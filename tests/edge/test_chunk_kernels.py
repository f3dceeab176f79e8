"""The per-chunk steps compiled as loops (cnctwin._jit) against their NumPy formulations.

``samples_since``, ``SpeedChangeFlags.update`` and the anomaly processor's ``air`` input
were NumPy expressions (up to session 24); they are one compiled loop each now because the
calls, not the arithmetic, cost the edge's time (BENCHMARKS.md, session 25). The NumPy
expressions are kept here as the reference: random streams (steps, ramps, NaN), cut into
random chunks, must give the same values, and the chunked stream the same as one call.
"""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np
import pandas as pd
from hypothesis import given, settings
from hypothesis import strategies as st

from cnctwin.analysis.segments import samples_since
from cnctwin.edge.pipeline import Chunk
from cnctwin.edge.processors import AnomalyProcessor
from cnctwin.spindle import SpeedChangeFlags


def _since_numpy(mask: np.ndarray, before: int) -> np.ndarray:
    m = np.asarray(mask, dtype=bool)
    idx = np.arange(m.size, dtype=np.int64)
    last = np.maximum.accumulate(np.where(m, idx, -1))
    return np.where(last >= 0, idx - last, before + idx + 1)


def _flags_numpy(nv: np.ndarray, *, tol: float = 1.0, settle: int = 150,
                 min_speed: float = 10.0) -> np.ndarray:
    """The whole stream at once, as SpeedChangeFlags.update computed it."""
    prev = np.concatenate([[nv[0]], nv[:-1]])
    nxt = np.concatenate([nv[1:], [nv[-1]]])
    with np.errstate(invalid="ignore"):
        changed = ~((np.abs(nv - prev) <= tol) & (np.abs(nxt - nv) <= tol))
    since = _since_numpy(changed, 1 << 40)
    flags = np.zeros(nv.size, dtype=np.int8)
    flags[since <= settle] = 1
    with np.errstate(invalid="ignore"):
        flags[~(np.abs(nv) >= min_speed)] = 2
    return flags


def _air_numpy(x: np.ndarray, y: np.ndarray, z: np.ndarray, *, step: float, still: int,
               after: int) -> np.ndarray:
    pos = np.vstack([x, y, z])
    d = np.diff(np.hstack([pos[:, :1], pos]), axis=1)
    with np.errstate(invalid="ignore"):
        moving = ~(np.abs(d) <= step).all(axis=0)
        zdown = d[-1] < -step
    # the processor starts with both counts at 0: no air before still / after samples
    return ((_since_numpy(moving, 0) >= still)
            & (_since_numpy(zdown, 0) >= after)).astype(np.float64)


def _cuts(n: int, data: st.DataObject) -> list[int]:
    k = data.draw(st.integers(0, 6))
    return sorted(set(data.draw(st.lists(st.integers(1, max(n - 1, 1)), min_size=k,
                                         max_size=k)))) if n > 1 else []


@settings(max_examples=60, deadline=None)
@given(st.lists(st.booleans(), max_size=400), st.integers(0, 1 << 40), st.data())
def test_samples_since_as_the_numpy_expression(mask: list[bool], before: int,
                                               data: st.DataObject) -> None:
    m = np.array(mask, dtype=bool)
    assert samples_since(m, before=before).tolist() == _since_numpy(m, before).tolist()
    # carried across blocks
    out, b = [], before
    for part in np.split(m, _cuts(m.size, data)):
        got = samples_since(part, before=b)
        out += got.tolist()
        b = int(got[-1]) if got.size else b
    assert out == _since_numpy(m, before).tolist()


def _speed_stream(data: st.DataObject) -> np.ndarray:
    """Plateaus, ramps, single steps, standstill and NaN: what a spindle command does."""
    parts = []
    for _ in range(data.draw(st.integers(1, 6))):
        kind = data.draw(st.sampled_from(["plateau", "ramp", "stand", "nan", "noise"]))
        n = data.draw(st.integers(1, 300))
        level = data.draw(st.floats(-6000, 6000))
        if kind == "plateau":
            parts.append(np.full(n, level))
        elif kind == "ramp":
            parts.append(np.linspace(level, level + data.draw(st.floats(-800, 800)), n))
        elif kind == "stand":
            parts.append(np.zeros(n))
        elif kind == "nan":
            parts.append(np.full(n, np.nan))
        else:
            rng = np.random.default_rng(data.draw(st.integers(0, 2**32 - 1)))
            parts.append(level + rng.normal(0.0, 0.8, n))
    return np.concatenate(parts)


@settings(max_examples=60, deadline=None)
@given(st.data())
def test_speed_change_flags_as_the_numpy_expression(data: st.DataObject) -> None:
    nv = _speed_stream(data)
    want = _flags_numpy(nv)
    assert SpeedChangeFlags().update(nv).tolist() == want.tolist()
    # chunked: the next chunk's first command is known to the last sample of a chunk
    f = SpeedChangeFlags()
    cuts = [0, *_cuts(nv.size, data), nv.size]
    got = []
    for a, b in itertools.pairwise(cuts):
        got += f.update(nv[a:b], float(nv[b]) if b < nv.size else None).tolist()
    assert got == want.tolist()


@settings(max_examples=40, deadline=None)
@given(st.data())
def test_anomaly_air_input_as_the_numpy_expression(data: st.DataObject) -> None:
    """The ``air`` input: every setpoint still for 0.3 s and Z not down for 1 s."""
    n = data.draw(st.integers(1, 2500))
    rng = np.random.default_rng(data.draw(st.integers(0, 2**32 - 1)))
    axes = []
    for _ in range(3):  # held, moving in runs, now and then NaN
        moves = rng.random(n) < data.draw(st.sampled_from([0.0, 0.002, 0.02, 0.3]))
        v = np.cumsum(np.where(moves, rng.normal(0.0, 0.5, n), 0.0))
        v[rng.random(n) < data.draw(st.sampled_from([0.0, 0.001]))] = np.nan
        axes.append(v)
    x, y, z = axes
    p = AnomalyProcessor(learn_s=0.0)
    cuts = [0, *_cuts(n, data), n]
    got = []
    for a, b in itertools.pairwise(cuts):
        ch = Chunk(np.arange(a, b, dtype=np.int64), np.arange(a, b, dtype=np.int64) * 2_000_000,
                   {"DES_POS|X1": x[a:b], "DES_POS|Y1": y[a:b], "DES_POS|Z1": z[a:b]},
                   events=pd.DataFrame())
        got += p._air(ch).tolist()
    want = _air_numpy(x, y, z, step=0.05 * 0.002, still=150, after=500)
    assert got == want.tolist()


class _FormerPhysicsChunks:
    """PhysicsResidualDetector's chunk path as NumPy/SciPy code (up to session 24)."""

    def __init__(self, det: Any) -> None:
        self.d = det

    def smooth(self, x: dict[str, np.ndarray]) -> np.ndarray:
        from scipy.signal import lfilter

        d = self.d
        r = x[d.measured] - x[d.predicted]
        a = d._alpha
        out = np.empty_like(r)
        if d._ewma is None:
            out[0] = prev = float(r[0])
            start = 1
        else:
            start, prev = 0, d._ewma
        if r.size > start:
            out[start:] = lfilter([a], [1.0, -(1.0 - a)], r[start:], zi=[(1.0 - a) * prev])[0]
        d._ewma = float(out[-1])
        return out

    def steady(self, x: dict[str, np.ndarray]) -> np.ndarray:
        d = self.d
        return np.array([d._steady({d.speed: v}) for v in x[d.speed].tolist()], dtype=bool)

    def score(self, x: dict[str, np.ndarray]) -> np.ndarray:
        d = self.d
        s = self.smooth(x)
        ok = self.steady(x) & (x[d.gate] == 1.0)
        std = d._std(x[d.predicted])
        mean = d._stats.mean if d._stats.n else 0.0
        with np.errstate(invalid="ignore", divide="ignore"):
            out = np.where(std > 0, np.abs(s - mean) / std - d.threshold_sigma, 0.0)
        out[~ok] = np.nan
        return out


@settings(max_examples=40, deadline=None)
@given(st.data())
def test_physics_detector_chunks_as_the_former_numpy_code(data: st.DataObject) -> None:
    """The edge's detector (current against the twin, gated on air) scored chunk by chunk:
    the compiled loop gives the scores of the former lfilter/NumPy code (to 1e-12 of the
    score: the same operations in the same order, the EWMA as lfilter computes it)."""
    from cnctwin.usecases.anomaly import PhysicsResidualDetector

    speed = _speed_stream(data)
    n = speed.size
    rng = np.random.default_rng(data.draw(st.integers(0, 2**32 - 1)))
    pred = 3.0 + 1e-4 * np.abs(np.nan_to_num(speed))
    x = {"current_a": pred + rng.normal(0.0, 0.05, n), "predicted_current_a": pred,
         "speed_rpm": speed, "air": (rng.random(n) < 0.7).astype(np.float64)}
    make = lambda: PhysicsResidualDetector(gate="air", rel_floor=0.1,  # noqa: E731
                                           abs_floor=0.05)
    det, old = make(), make()
    old._stats.update_many(np.array([0.01, -0.02, 0.03]))  # something learned, in both
    det._stats.update_many(np.array([0.01, -0.02, 0.03]))
    former = _FormerPhysicsChunks(old)
    cuts = [0, *_cuts(n, data), n]
    for a, b in itertools.pairwise(cuts):
        part = {k: v[a:b] for k, v in x.items()}
        got, want = det.score_chunk(part), former.score(part)
        np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
        assert (det._n_ref, det._n_prev, det._since_change) == (
            old._n_ref, old._n_prev, old._since_change)


def test_prepare_compiles_the_loops_and_leaves_the_state() -> None:
    """A live runtime calls ``prepare()`` of its processors before the first message: after
    it every compiled loop of the chunk path is compiled, and a processor's pickled state
    (what a checkpoint keeps) is what it was."""
    import pickle

    from cnctwin.analysis import segments
    from cnctwin.edge import processors
    from cnctwin.edge.processors import TorqueProcessor
    from cnctwin.spindle import SpindleModel
    from cnctwin.spindle import _speed_flags as flags_kernel
    from cnctwin.usecases import anomaly
    from cnctwin.usecases.air_friction import AirFrictionCheck

    model = SpindleModel(1.04, 8.42e-5, 0.35, j_kgm2=0.0045)
    procs = [TorqueProcessor(model),
             AnomalyProcessor(anomaly.PhysicsResidualDetector(gate="air"), model=model,
                              friction_check=AirFrictionCheck())]
    kernels = (segments._since, flags_kernel, processors._air_samples,
               anomaly._residual_steps)
    for kernel in kernels:  # as in a fresh process (numba's disk cache loads them again)
        kernel._fn = None
    before = [pickle.dumps(p) for p in procs]
    for p in procs:
        p.prepare()
    assert [pickle.dumps(p) for p in procs] == before
    for kernel in kernels:
        assert kernel._fn is not None, kernel.py.__name__


def test_prepare_kernels_compiles_every_loop() -> None:
    """``cnctwin edge run`` with a live source compiles the loops before it connects."""
    from cnctwin.analysis import segments
    from cnctwin.edge import processors
    from cnctwin.spindle import _speed_flags as flags_kernel
    from cnctwin.usecases import anomaly

    kernels = (segments._since, flags_kernel, processors._air_samples,
               anomaly._residual_steps)
    for kernel in kernels:
        kernel._fn = None
    processors.prepare_kernels()
    assert all(kernel._fn is not None for kernel in kernels)
