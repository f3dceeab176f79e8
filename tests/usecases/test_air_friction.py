"""AirFrictionCheck: the spindle's air current against the calibrated twin (issue 24, the
friction-rise fault), on synthetic streams with a known offset, both sides of the tolerance;
RapidAir: which samples the NC events show as rapid traverse outside a machining cycle."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from cnctwin.exceptions import ConfigError
from cnctwin.usecases.air_friction import AirFrictionCheck, RapidAir

CT = 0.002


def _stream(offset_a: float, *, n: int = 2000, speed: float = 2400.0, air: float = 1.0,
            noise_a: float = 0.3, seed: int = 1) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    pred = np.full(n, 0.6)  # the twin's air current at this speed [A]
    cur = pred + offset_a + rng.normal(0.0, noise_a, n)
    return (np.arange(n, dtype=np.int64), cur, pred, np.full(n, speed), np.full(n, air))


def _run(check: AirFrictionCheck, s: tuple[np.ndarray, ...], chunk: int = 50) -> list:
    out = []
    for k in range(0, s[0].size, chunk):
        sl = slice(k, k + chunk)
        out += check.update(*(a[sl] for a in s), cycle_time_s=CT)
    return out


def test_tolerance_is_the_larger_of_the_absolute_and_relative_bound() -> None:
    # 0.6 A predicted: 25 % = 0.15 A > 0.1 A. 0.10 A passes, 0.20 A is found (noise of the
    # 250-sample mean: 0.3 / sqrt(250) = 0.019 A: each 2.6 sigma from the bound)
    assert _run(AirFrictionCheck(), _stream(0.10)) == []
    found = _run(AirFrictionCheck(), _stream(0.20))
    assert len(found) == 1  # once, not every window
    f = found[0]
    assert f.residual_a == pytest.approx(0.20, abs=0.06) and f.tolerance_a == pytest.approx(0.15)
    # a larger relative tolerance wins over the absolute one where the twin predicts more
    assert _run(AirFrictionCheck(rel_tol=0.5), _stream(0.20)) == []
    assert "friction rose" in f.message and f.speed_rpm == pytest.approx(2400.0)
    drop = _run(AirFrictionCheck(), _stream(-0.2))
    assert len(drop) == 1 and "fell" in drop[0].message


def test_only_air_steady_fast_samples_are_judged() -> None:
    assert _run(AirFrictionCheck(), _stream(0.5, air=0.0)) == []  # cutting: not air
    assert _run(AirFrictionCheck(), _stream(0.5, speed=400.0)) == []  # Stribeck region
    s = _stream(0.5)
    s[3][::100] += 50.0  # a speed change every 0.2 s: never 0.3 s steady
    assert _run(AirFrictionCheck(), s) == []


def test_a_departure_that_returns_is_reported_again() -> None:
    c = AirFrictionCheck()
    found = (_run(c, _stream(0.4, n=1000)) + _run(c, _stream(0.0, n=1000, seed=2))
             + _run(c, _stream(0.4, n=1000, seed=3)))
    assert len(found) == 2 and c.departed  # found again after a window within tolerance


def test_bad_options() -> None:
    with pytest.raises(ConfigError):
        AirFrictionCheck(window_s=0)


def _events(rows: list[tuple[int, str, str | None, str | None, str | None]]) -> pd.DataFrame:
    return pd.DataFrame(rows, columns=["cycle", "kind", "gcode", "ipo_gcode", "path"])


def _marks(tracker: RapidAir, events: pd.DataFrame, n: int, chunk: int) -> np.ndarray:
    cyc = np.arange(n, dtype=np.int64)
    return np.concatenate([
        tracker.update(cyc[k:k + chunk], events[(events.cycle >= k) & (events.cycle < k + chunk)],
                       cycle_time_s=CT) for k in range(0, n, chunk)])


def test_rapid_air_marks_g0_outside_cycles_after_settling() -> None:
    """A job as the simulator and the control report it (IpoGC with each block, a call event
    into the cycle and back): G0 repositioning is marked from 0.1 s (50 cycles) after it starts;
    G1 feed, the positions of a modal MCALL and a called cycle are not; chunking does not
    change the marks."""
    ev = _events([
        (0, "block", "G0 X10 Y10 Z10", "G0", None),        # 0..199 rapid
        (200, "block", "G1 Z-2 F100", "G1", None),          # 200..399 feed
        (400, "block", "G0 Z10", "G0", None),               # 400..599 rapid
        (600, "block", "MCALL CYCLE81(10, 0, 2, -8)", "G0", None),
        (600, "block", "X12 Y180", "G0", None),             # 600..799 modal cycle call
        (610, "call", None, None, "/_CYCLES_DIR/_CYCLE81"),
        (790, "call", None, None, "/_N_MPF_DIR/_N_PROGRAM_MPF"),
        (800, "block", "MCALL", "G0", None),                # 800..899 rapid again
        (900, "call", None, None, "/_CYCLES_DIR/_CYCLE83"),  # 900..999 a cycle called once
    ])
    expect = np.zeros(1000, dtype=bool)
    expect[50:200] = True
    expect[450:600] = True
    expect[850:900] = True
    for chunk in (1000, 37, 1):
        got = _marks(RapidAir(), ev, 1000, chunk)
        assert np.array_equal(got, expect), (chunk, np.flatnonzero(got != expect)[:5])


def test_rapid_air_knows_nothing_before_a_block_or_without_ipo_gcode() -> None:
    # a stream that starts mid-program (a restart without state): no block yet, nothing marked
    assert not _marks(RapidAir(), _events([]), 500, 100).any()
    # a source that does not report the interpolator's motion group: never rapid
    ev = _events([(0, "block", "G0 X10", None, None)])
    assert not _marks(RapidAir(), ev, 500, 100).any()
    with pytest.raises(ConfigError):
        RapidAir(settle_s=-1.0)


def test_rapid_air_reads_missing_values_and_unsorted_events() -> None:
    """Event tables as readers give them: pandas' missing values (NA, NaN) in any column and,
    from a merged source, rows out of cycle order; the marks equal those of the clean table."""
    clean = _events([(0, "block", "G0 X10", "G0", None), (100, "block", "G1 X20", "G1", None),
                     (200, "block", "G0 Z10", "G0", None)])
    messy = clean.iloc[[2, 0, 1]].astype(object).reset_index(drop=True)
    messy.loc[0, "path"] = pd.NA
    messy.loc[1, "path"] = float("nan")
    messy = pd.concat([messy, pd.DataFrame({"cycle": [150], "kind": [pd.NA], "gcode": [None],
                                            "ipo_gcode": [pd.NA], "path": [pd.NA]})])
    a = _marks(RapidAir(), clean, 300, 300)
    b = _marks(RapidAir(), messy, 300, 300)
    assert a.sum() == 50 + 50 and np.array_equal(a, b)


@pytest.mark.parametrize(("block", "effect"), [
    ("MCALL CYCLE81(10, 0, 2, -20)", True),
    ("N100 MCALL CYCLE82(10, 0, 2, -20, , 0.5)", True),
    ("MCALL", False),
    ("N120 MCALL", False),
    ("N120 MCALL ; end of the pattern", False),
    ("/1 N120 MCALL", False),
    (":10 MCALL", False),
    ("G80", False),
    ("N130 G0 X10 ; MCALL and G80 in a comment", None),
    ("CYCLE81(10, 0, 2, -20)", None),  # a single call, not modal
    ("N140 G1 X20 F500", None),
])
def test_every_recogniser_reads_a_blocks_modal_cycle_call_alike(block: str,
                                                                 effect: bool | None) -> None:
    """The three readers of the modal cycle call (rapid air, the live cut tracker, the hole
    table's cycle name) share one rule: SINUMERIK's ``MCALL`` (Programming Manual Job
    Planning) with block numbers, skip levels and comments as the control records them."""
    from cnctwin.usecases.holes import modal_cycle_call

    assert modal_cycle_call(block) is effect
