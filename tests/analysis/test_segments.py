"""cnctwin.analysis.segments: Schmitt trigger, speed plateaus and cutting regions."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from cnctwin.analysis.segments import (
    centered_mean,
    cutting_regions,
    hysteresis_mask,
    runs,
    speed_plateaus,
    spindle_speed_rpm,
)
from cnctwin.exceptions import SignalNotFoundError
from cnctwin.recording import EVENT_COLUMNS, Recording

FS = 500.0


def test_hysteresis_ignores_chatter_between_thresholds() -> None:
    x = np.array([0, 0.6, 1.2, 0.6, 1.1, 0.3, 0.6, 0.9, 1.05, 0.2])
    m = hysteresis_mask(x, high=1.0, low=0.5)
    assert m.tolist() == [False, False, True, True, True, False, False, False, True, False]
    assert runs(m).tolist() == [[2, 4], [8, 8]]
    assert runs(np.zeros(0, bool)).shape == (0, 2)


def _steps(levels: list[float], seconds: float = 2.0, noise: float = 0.0) -> np.ndarray:
    rng = np.random.default_rng(0)
    parts = []
    prev = 0.0
    for lv in levels:
        parts.append(np.linspace(prev, lv, int(0.3 * FS), endpoint=False))  # run-up
        parts.append(np.full(int(seconds * FS), lv))
        prev = lv
    s = np.concatenate(parts)
    return s + rng.normal(0, noise, s.size) if noise else s


def test_speed_plateaus_excludes_ramps_and_splits_at_gaps() -> None:
    speed = _steps([1000.0, 2000.0, 2000.0 + 50.0, 0.0], seconds=3.0)
    cycles = np.arange(speed.size)
    cycles[2500:] += 100  # counter gap in the middle of the 2000 rpm plateau (1800-3300)
    rec = Recording.from_arrays(cycles, {"CMD_SPEED|SP1": speed})
    p = speed_plateaus(rec, min_duration_s=0.3)
    # 1000; 2000 split by the gap into two; 2050 (a jump of 50 rpm > tolerance); 0 dropped
    np.testing.assert_allclose(p["speed_rpm"], [1000, 2000, 2000, 2050])
    assert p.attrs["speed_source"] == "CMD_SPEED|SP1"
    # no plateau row contains a ramp sample
    for _, row in p.iterrows():
        seg = rec.hf.loc[row["start_cycle"]:row["end_cycle"], "CMD_SPEED|SP1"]
        assert seg.max() - seg.min() <= 5.0


def test_speed_from_lf_when_no_hf_speed() -> None:
    n = 3000
    rec = Recording.from_arrays(np.arange(n), {"CURRENT|SP1": np.ones(n)})
    lf_cycles = np.arange(0, n, 50)
    rec.lf = pd.DataFrame({
        "cycle": lf_cycles, "time": pd.NaT, "signal": "SPEED_SMOOTHED|SP1",
        "value": np.where(lf_cycles < 1500, 1200.0, 2400.0), "text": "",
    })
    speed, source = spindle_speed_rpm(rec)
    assert "LF" in source and speed[0] == 1200.0 and speed[-1] == 2400.0
    p = speed_plateaus(rec, min_duration_s=1.0)
    np.testing.assert_allclose(p["speed_rpm"], [1200.0, 2400.0])
    rec2 = Recording.from_arrays(np.arange(10), {"CURRENT|SP1": np.ones(10)})
    with pytest.raises(SignalNotFoundError, match="SPEED_SMOOTHED"):
        spindle_speed_rpm(rec2)


def _drilling(with_z: bool = True) -> tuple[Recording, list[tuple[float, float]]]:
    rng = np.random.default_rng(5)
    t = np.arange(0, 30.0, 1 / FS)
    speed = np.interp(t, [0, 1, 30], [0, 2400, 2400])  # run-up in the first second
    current = 0.53 + rng.normal(0, 0.05, t.size) + 0.02 * np.sin(2 * np.pi * 80 * t)
    current[t < 1.2] += 1.5  # inertia current during run-up: must not count as a cut
    holes = [(4.0, 7.0), (12.0, 15.5), (21.0, 24.0)]
    z = np.full(t.size, 2.0)
    for s, e in holes:
        m = (t >= s) & (t < e)
        current[m] += 3.8 * np.minimum(1, (t[m] - s) / 0.05)
        z[m] = -(t[m] - s) * 6.0
    # an air move with the spindle on and Z going down but no cut (no current rise)
    z[(t >= 26) & (t < 27)] = -np.linspace(0, 5, int(FS))
    signals = {"CMD_SPEED|SP1": speed, "CURRENT|SP1": current}
    if with_z:
        signals["ENC_POS|Z1"] = z
    rec = Recording.from_arrays(np.arange(t.size), signals)
    ev = pd.DataFrame({c: [None] * 3 for c in EVENT_COLUMNS})
    ev["cycle"] = [int(3.9 * FS), int(11.9 * FS), int(20.9 * FS)]
    ev["kind"] = "block"
    ev["gcode"] = ["N10 G1 Z-18", "N20 G1 Z-21", "N30 G1 Z-18"]
    rec.events = ev
    return rec, holes


def test_cutting_regions_match_the_holes() -> None:
    rec, holes = _drilling()
    reg = cutting_regions(rec)
    assert len(reg) == 3
    # 5 Hz smoothing + hysteresis: edges within 60 ms (start) / 100 ms (end)
    np.testing.assert_allclose(reg["start_s"], [h[0] for h in holes], atol=0.06)
    np.testing.assert_allclose(reg["end_s"], [h[1] for h in holes], atol=0.1)
    assert reg["block"].tolist() == ["N10 G1 Z-18", "N20 G1 Z-21", "N30 G1 Z-18"]
    np.testing.assert_allclose(reg["speed_rpm"], 2400.0)
    assert reg["baseline_a"].iloc[0] == pytest.approx(0.53, abs=0.05)
    assert reg.attrs["threshold_a"] > 0.2


def test_cutting_regions_without_z_and_fixed_threshold() -> None:
    rec, _ = _drilling(with_z=False)
    reg = cutting_regions(rec, current_threshold=1.0)
    assert len(reg) == 3
    assert reg["z_start_mm"].isna().all()
    # a threshold above the cut current finds nothing (and says so with an empty frame)
    assert cutting_regions(rec, current_threshold=10.0).empty


# ------------------------------------------------------------------ one simulated hole
@pytest.fixture(scope="module")
def cast_iron_hole() -> tuple[Recording, dict]:  # type: ignore[type-arg]
    """Thesis cuts 4 and 2 (cast iron, 3200 rpm 0.4 mm/rev and 2400 rpm 0.3 mm/rev, Fig. 4.5),
    simulated: one hole per recording, the drill in the material for more than half of the
    time at speed."""
    from cnctwin.sim import scenarios as sc

    res = sc.drilling_validation(seed=3, cuts=[("grey_cast_iron", 3200.0, 0.40),
                                               ("grey_cast_iron", 2400.0, 0.30)])
    return res.recordings, res.truth["cuts"]  # type: ignore[return-value]


@pytest.mark.parametrize("k", [0, 1])
@pytest.mark.parametrize("kwargs", [{}, {"z_axis": None}, {"air_from_z": False}])
def test_cutting_regions_on_one_cast_iron_hole(cast_iron_hole, k, kwargs) -> None:  # type: ignore[no-untyped-def]
    """Issue #4 item 2: before the fix the noise came from the lower half of the excess current,
    which in a one-hole recording is the cut itself, and no region was found."""
    recs, truth = cast_iron_hole
    rec, cut = recs[k], truth[k]
    reg = cutting_regions(rec, **kwargs)
    assert len(reg) == 1
    c0 = rec.cycles[0]
    first = (cut["cut_first_cycle"] - c0) * rec.meta.cycle_time_s
    full = (cut["full_engagement_first_cycle"] - c0) * rec.meta.cycle_time_s
    z = rec.hf["ENC_POS|Z1"].to_numpy()
    bottom = float(rec.time_s[int(np.argmin(z))])  # the drill stops feeding and retracts
    # the region starts during the drill-point entry (threshold at 30 % of the cut level) and
    # ends within 0.1 s of the hole bottom (5 Hz smoothing + hysteresis)
    assert first <= reg["start_s"].iloc[0] <= full + 0.05
    assert reg["end_s"].iloc[0] == pytest.approx(bottom, abs=0.1)
    # air level: the air-cut current at the cutting speed, well below the cut current
    assert 0.3 < reg["baseline_a"].iloc[0] < 0.8
    assert reg["mean_current_a"].iloc[0] > 4.0 * reg["baseline_a"].iloc[0]
    assert reg.attrs["noise_from"] in ("z_air", "rolling_std")
    assert reg.attrs["noise_sigma_a"] < 0.1 * reg.attrs["threshold_a"]


def test_cutting_regions_noise_from_z_air_in_multi_hole_recording() -> None:
    """With several holes there is air at the cutting speed between them: Z tells it apart."""
    rec, holes = _drilling()
    reg = cutting_regions(rec)
    assert reg.attrs["noise_from"] == "z_air"
    # the generator's noise is 0.05 A per sample; 5 Hz smoothing leaves about 0.05 *
    # sqrt(2 * 5 / 500) ~ 7 mA (plus the 80 Hz line, filtered out)
    assert 0.002 < reg.attrs["noise_sigma_a"] < 0.02
    assert len(reg) == len(holes)
    assert reg["baseline_a"].iloc[0] == pytest.approx(0.53, abs=0.02)


def test_spindle_actual_speed_from_a_wrapped_angle_with_a_gap() -> None:
    """ENC_POS of a spindle is modulo 360 deg: at 18 000 rpm it turns 216 deg per 2 ms cycle,
    more than half a turn, so only the command tells the increment's whole turns. A counter
    gap leaves its turns unknown (NaN there, nothing invented). Truth by construction."""
    import numpy as np

    from cnctwin.analysis.segments import spindle_actual_speed_rpm
    from cnctwin.recording import Recording

    n = 400
    speed = np.linspace(-3000.0, 18000.0, n)  # rpm, through zero and beyond 15 000
    angle = np.cumsum(speed * 6.0 * 0.002)  # deg
    cycles = np.arange(1000, 1000 + n)
    cycles[200:] += 5  # 5 cycles lost
    angle[200:] += speed[200] * 6.0 * 0.002 * 5
    rec = Recording.from_arrays(cycles, {"ENC_POS|SP1": np.mod(angle, 360.0),
                                         "CMD_SPEED|SP1": speed})
    v = spindle_actual_speed_rpm(rec)
    assert v is not None
    ok = np.isfinite(v)
    assert not ok[199] and not ok[200] and ok.sum() == n - 2
    # central differences of a linear ramp: exact up to the ramp's half-step
    step = speed[1] - speed[0]
    assert np.max(np.abs(v[ok][1:-1] - speed[ok][1:-1])) < step
    # without ENC_POS there is no actual speed
    assert spindle_actual_speed_rpm(Recording.from_arrays(cycles, {"CMD_SPEED|SP1": speed})) \
        is None


@pytest.mark.parametrize("w", [1, 3, 4, 10, 11])
@pytest.mark.parametrize("n", [1, 2, 9, 2300])
@pytest.mark.parametrize("nans", [False, True])
def test_centered_mean_is_pandas_centred_rolling_mean(w: int, n: int, nans: bool) -> None:
    """``centered_mean`` (the hole contact search's smoothing and ``_rolling``'s mean) gives
    pandas' centred rolling mean (min_periods=1), the one both used before (a reference
    computed by another library, to 1e-12); NaNs skipped, a window of only NaNs NaN."""
    a = np.random.default_rng(n + w).normal(8.0, 2.0, n)
    if nans:
        a[::3] = np.nan
        a[n // 2:n // 2 + 12] = np.nan
    ref = pd.Series(a).rolling(w, center=True, min_periods=1).mean().to_numpy()
    np.testing.assert_allclose(centered_mean(a, w), ref, rtol=1e-12, atol=1e-12)

