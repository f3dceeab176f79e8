"""Min/max decimation keeps every bucket's extremes and the ends (cnctwin.web.decimate).

Checked against a direct per-bucket ``min``/``max`` written out in the test (a loop over the
buckets), not against the vectorised implementation."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from cnctwin.exceptions import ConfigError
from cnctwin.web.decimate import bucket_starts, envelope_decimate


def _check_buckets(x: np.ndarray, y: np.ndarray, px: int) -> None:
    env = envelope_decimate(x, y, px=px)
    assert not env.exact
    assert env.n_points <= 2 * px + 2
    starts = bucket_starts(y.size, px)
    assert np.array_equal(env.bucket_starts, starts)
    kept = set(env.index.tolist())
    for a, b in itertools.pairwise(starts):
        seg = y[a:b]
        good = seg[np.isfinite(seg)]
        if good.size == 0:
            continue
        in_bucket = env.y[(env.index >= a) & (env.index < b)]
        # the exact extreme values of the bucket are among the kept samples of that bucket
        assert np.nanmin(in_bucket) == good.min()
        assert np.nanmax(in_bucket) == good.max()
    assert 0 in kept and y.size - 1 in kept  # first and last sample
    assert np.array_equal(env.x, x[env.index]) and np.array_equal(env.y, y[env.index],
                                                                   equal_nan=True)
    assert np.all(np.diff(env.index) > 0)


@pytest.mark.parametrize(("n", "px"), [(100_003, 997), (50_000, 1000), (4001, 2000),
                                       (10_007, 3)])
def test_every_bucket_keeps_min_and_max(n: int, px: int) -> None:
    rng = np.random.default_rng(n)
    y = np.cumsum(rng.standard_normal(n))
    y[rng.integers(0, n, 20)] += rng.choice([-50.0, 50.0], 20)  # isolated spikes
    _check_buckets(np.arange(n) * 0.002, y, px)


def test_single_sample_spike_survives() -> None:
    # one 2 ms spike in 1 M samples: a mean/resample would flatten it, the envelope keeps it
    y = np.zeros(1_000_000)
    y[654_321] = 7.5
    y[123] = -2.0
    env = envelope_decimate(np.arange(y.size, dtype=float), y, px=800)
    assert env.y.max() == 7.5 and env.y.min() == -2.0
    assert 654_321 in env.index and 123 in env.index


def test_nan_samples_skipped_and_all_nan_bucket_empty() -> None:
    n, px = 10_000, 100
    y = np.sin(np.arange(n) / 50.0)
    y[::7] = np.nan
    y[2000:2100] = np.nan  # exactly bucket 20 (100 samples per bucket)
    _check_buckets(np.arange(n, dtype=float), y, px)
    env = envelope_decimate(np.arange(n, dtype=float), y, px=px)
    assert not np.any((env.index >= 2000) & (env.index < 2100))


def test_small_input_is_kept_whole() -> None:
    y = np.array([1.0, np.nan, 3.0, -1.0])
    env = envelope_decimate(np.arange(4.0), y, px=2)
    assert env.exact and env.n_points == 4
    assert np.array_equal(env.y, y, equal_nan=True)


def test_bucket_sizes_differ_by_at_most_one() -> None:
    s = bucket_starts(10_000_019, 2000)
    sizes = np.diff(s)
    assert s[0] == 0 and s[-1] == 10_000_019 and sizes.max() - sizes.min() <= 1


def test_bad_arguments() -> None:
    with pytest.raises(ConfigError, match="px"):
        envelope_decimate(np.arange(3.0), np.arange(3.0), px=0)
    with pytest.raises(ConfigError, match="1-D of one length"):
        envelope_decimate(np.arange(3.0), np.arange(4.0), px=10)
