"""The compiled setpoint chain equals the NumPy/SciPy filters, number for number.

``fit_setpoint_chain`` evaluates the chain (jerk filter -> two interpolated delays -> two PT1)
thousands of times per axis; it runs the compiled :func:`setpoint_chain_segments`, which
repeats the operations of :func:`jerk_filter_average`, :func:`delay` (``numpy.interp``),
:func:`pt1` and :func:`pt2` (``scipy.signal.lfilter``) in their order. The truth here is the
reference implementation, :func:`apply_setpoint_chain`, run run by run.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from cnctwin.servo._common import JERK_CODES, setpoint_chain_segments
from cnctwin.servo.identify import apply_setpoint_chain


def _reference(des: np.ndarray, starts: np.ndarray, jt: str, p: np.ndarray) -> np.ndarray:
    nj = {"none": 0, "moving_average": 1}.get(jt, 2)
    return np.concatenate([
        apply_setpoint_chain(des[a:b], jerk_type=jt, jerk_cycles=tuple(p[:nj]),
                             delay_cycles=p[nj], pt1_cycles=p[nj + 1], pt1b_cycles=p[nj + 2],
                             delay2_cycles=p[nj + 3])
        for a, b in itertools.pairwise(starts)])


@pytest.mark.parametrize("jt", list(JERK_CODES))
def test_compiled_chain_equals_the_reference_filters(jt: str) -> None:
    rng = np.random.default_rng(7)
    nj = {"none": 0, "moving_average": 1}.get(jt, 2)
    for trial in range(60):
        lens = rng.integers(3, 400, size=rng.integers(1, 6))
        des = np.concatenate([np.cumsum(rng.normal(size=n)) * 0.3 + rng.normal() * 100
                              for n in lens])
        starts = np.r_[0, np.cumsum(lens)].astype(np.int64)
        p = rng.uniform(0.0, 12.0, nj + 4)
        if jt == "pt2":
            p[1] = rng.uniform(0.0, 2.0)  # below the 0.05 clamp too
        if trial % 4 == 0:  # whole-cycle windows and delays (the interpolation's exact points)
            p = np.floor(p)
        if trial % 5 == 0:  # filters switched off
            p[nj + 1 :] = 0.0
        got = setpoint_chain_segments(des, starts, jt, p)
        np.testing.assert_array_equal(got, _reference(des, starts, jt, p))


def test_each_run_starts_settled_on_its_own() -> None:
    # two runs of a constant: each filter starts at its first sample, so the output is that
    # constant everywhere (a chain run across the boundary would ramp from 1 to 5)
    des = np.r_[np.full(50, 1.0), np.full(50, 5.0)]
    out = setpoint_chain_segments(des, np.array([0, 50, 100]), "moving_average",
                                  np.array([8.0, 2.5, 3.0, 1.0, 0.5]))
    np.testing.assert_array_equal(out, des)
