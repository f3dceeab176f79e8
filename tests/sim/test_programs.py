"""Tests of the thesis program generators (cnctwin.sim.programs).

Thesis numbers: Sect. 5.1 (2676 holes in sets of 6, 20 mm, 2400 rpm, 400 mm/min), Sect. 3.1.2
(16 mm two-flute end mill, 0.5 mm depth, 0.167 mm/tooth), Sect. 3.2.2 (126 air-cut speeds up
to 18000 rpm), Sect. 4.2 (warm-up at 5000/7000 rpm). Rest-to-rest move times: closed-form
double-S, Biagiotti & Melchiorri (2008) Sect. 3.4.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from cnctwin.exceptions import ConfigError
from cnctwin.sim.gcode import parse_program
from cnctwin.sim.interpolator import AxisLimits, SpindleLimits, interpolate, interpolate_chunks
from cnctwin.sim.programs import (
    AIR_CUT_SPEEDS_RPM,
    air_cut_sweep_program,
    circle_path,
    drilling_validation_program,
    hole_pattern,
    hole_positions,
    square_path,
    tapping_program,
    warm_up_program,
)

LIMITS = {
    "X1": AxisLimits(30000.0, 3000.0, 50000.0),
    "Y1": AxisLimits(30000.0, 2500.0, 40000.0),
    "Z1": AxisLimits(20000.0, 2000.0, 30000.0),
    "C1": AxisLimits(7200.0, 1000.0, 20000.0),
    "B1": AxisLimits(7200.0, 1000.0, 20000.0),
}
SPINDLE = SpindleLimits(max_speed_rpm=20000.0, accel_rpm_s=4000.0)
T = 0.002


def rest_to_rest_s(length: float, v: float, a: float, j: float) -> float:
    """Closed-form duration of a rest-to-rest double-S move (zero end accelerations)."""
    if v * j >= a * a:
        if length >= v * (v / a + a / j):
            return length / v + v / a + a / j
    elif length >= 2 * v * math.sqrt(v / j):
        return length / v + 2 * math.sqrt(v / j)
    # peak speed not reached
    tj = (length / (2 * j)) ** (1 / 3)
    if j * tj <= a:
        return 4 * tj
    vp = (-(a * a) / j + math.sqrt((a * a / j) ** 2 + 4 * a * length)) / 2
    return 2 * (vp / a + a / j)


def line_limits(dx: float, dy: float, dz: float) -> tuple[float, float, float, float]:
    d = np.array([dx, dy, dz])
    length = float(np.linalg.norm(d))
    u = np.abs(d / length)
    names = ("X1", "Y1", "Z1")
    nz = u > 0
    v = min(
        LIMITS[n].max_velocity_mm_min / 60 / ui for n, ui, k in zip(names, u, nz, strict=True) if k
    )
    a = min(LIMITS[n].max_accel_mm_s2 / ui for n, ui, k in zip(names, u, nz, strict=True) if k)
    j = min(LIMITS[n].max_jerk_mm_s3 / ui for n, ui, k in zip(names, u, nz, strict=True) if k)
    return length, v, a, j


def test_all_programs_parse() -> None:
    texts = [
        hole_pattern(12), hole_pattern(7, cycle="CYCLE83"), hole_pattern(7, cycle="G81"),
        hole_pattern(7, cycle="G83"), drilling_validation_program(2400, 0.16, 10, n_holes=2),
        drilling_validation_program(3200, 0.4, 10, cycle="G81"), square_path(40.0),
        circle_path(20.0), air_cut_sweep_program(), warm_up_program(5000, minutes=1),
        tapping_program(),
        tapping_program(2, cycle="G84"),
    ]  # fmt: skip
    for text in texts:
        prog = parse_program(text, max_speed_rpm=20000)
        assert prog.blocks[-1].kind == "program_end"


def test_hole_positions_sets_of_six() -> None:
    pos = hole_positions(13, pitch_mm=12.0, set_spacing_mm=15.0, sets_per_row=2)
    assert pos[0] == (10.0, 10.0) and pos[5] == (10.0, 70.0)  # set 1 along Y
    assert pos[6] == (25.0, 10.0)  # set 2 next to it
    assert pos[12] == (10.0, 10.0 + 7 * 12.0)  # set 3 starts the next row
    with pytest.raises(ConfigError):
        hole_positions(0)


@pytest.mark.slow
def test_thesis_wear_run_duration_and_holes() -> None:
    n = 2676
    text = hole_pattern(n)
    prog = parse_program(text)
    n_cycles = 0
    holes = []
    duration = 0.0
    for tr in interpolate_chunks(prog, limits=LIMITS, spindle=SPINDLE, chunk_cycles=2_000_000):
        n_cycles += tr.n_cycles
        holes.append(tr.holes)
        duration = tr.duration_s
        assert tr.des_pos["Z1"].min() >= -20.0 - 1e-9
    assert n_cycles == round(duration / T) + 1
    h = np.concatenate([x["z_bottom_mm"].to_numpy() for x in holes])
    assert h.size == n and np.all(h == -20.0)
    starts = np.concatenate([x["start_cycle"].to_numpy() for x in holes])
    assert np.all(np.diff(starts) > 0)
    # expected machine time, per hole: XY rapid from the previous hole at RTP, G0 Z 10 -> 2,
    # G1 Z 2 -> -20 at 400 mm/min, G0 Z -20 -> 10; plus the start (spindle ramp 2400/4000 s,
    # first positioning) and the end (G0 Z50, spindle stop 0.6 s)
    pos = hole_positions(n)
    expected = 2400 / 4000 + 2400 / 4000
    expected += rest_to_rest_s(*line_limits(pos[0][0], pos[0][1], 10.0))
    for k in range(n):
        if k > 0:
            expected += rest_to_rest_s(*line_limits(pos[k][0] - pos[k - 1][0],
                                                     pos[k][1] - pos[k - 1][1], 0.0))  # fmt: skip
        expected += rest_to_rest_s(*line_limits(0, 0, 8.0))
        expected += rest_to_rest_s(22.0, 400 / 60, 2000.0, 30000.0)
        expected += rest_to_rest_s(*line_limits(0, 0, 30.0))
    expected += rest_to_rest_s(*line_limits(0, 0, 40.0))
    # feed time alone: 2676 * 22 mm / (400 mm/min) = 8830.8 s (2.45 h)
    assert expected > 2676 * 22 / (400 / 60)
    # each standstill-to-motion start waits for the next 2 ms cycle: at most 4 * 2 ms per hole
    assert duration == pytest.approx(expected, rel=0.01)
    assert duration - expected < 4 * T * n + 1.0


def test_drilling_validation_feed_per_rev() -> None:
    # thesis Table 4.1 row: cast iron, 3200 rpm, 0.4 mm/rev -> 1280 mm/min
    tr = interpolate(parse_program(drilling_validation_program(3200, 0.4, 10.0)),
                     limits=LIMITS, spindle=SPINDLE)  # fmt: skip
    assert len(tr.holes) == 1
    assert tr.holes["feed_mm_min"][0] == pytest.approx(1280.0)
    z = tr.des_pos["Z1"]
    s, e = int(tr.holes["start_cycle"][0]), int(tr.holes["end_cycle"][0])
    bottom = s + int(np.argmin(z[s:e]))
    assert (-np.diff(z[s:bottom])).max() == pytest.approx(1280 / 60 * T, rel=1e-9)


def test_square_and_circle_feed_from_feed_per_tooth() -> None:
    # F = fz * z * n = 0.167 * 2 * 6000 = 2004 mm/min
    tr = interpolate(parse_program(square_path(40.0)), limits=LIMITS, spindle=SPINDLE)
    cutting = tr.des_pos["Z1"] < -0.499
    assert tr.path_velocity_mm_min[cutting].max() == pytest.approx(2004.0, rel=1e-9)
    assert tr.des_pos["Z1"].min() == pytest.approx(-0.5, abs=1e-12)
    x, y = tr.des_pos["X1"], tr.des_pos["Y1"]
    assert (x.min(), x.max(), y.min(), y.max()) == pytest.approx((0.0, 40.0, 0.0, 40.0))
    tr_c = interpolate(parse_program(circle_path(20.0, center_xy=(50.0, 50.0))), limits=LIMITS,
                       spindle=SPINDLE)  # fmt: skip
    cut = tr_c.des_pos["Z1"] < -0.499
    r = np.hypot(tr_c.des_pos["X1"][cut] - 50.0, tr_c.des_pos["Y1"][cut] - 50.0)
    np.testing.assert_allclose(r, 20.0, atol=1e-9)
    assert tr_c.path_velocity_mm_min[cut].max() == pytest.approx(2004.0, rel=1e-9)


def test_air_cut_sweep_speeds() -> None:
    assert len(AIR_CUT_SPEEDS_RPM) == 126 and max(AIR_CUT_SPEEDS_RPM) == 18000.0
    tr = interpolate(parse_program(air_cut_sweep_program(AIR_CUT_SPEEDS_RPM[-5:], dwell_s=1.0)),
                     limits=LIMITS, spindle=SPINDLE)  # fmt: skip
    sp = tr.spindle_speed_cmd_rpm
    for n in AIR_CUT_SPEEDS_RPM[-5:]:
        at = np.isclose(sp, n)
        assert at.sum() * T >= 1.0  # dwell at each speed after reaching it
    with pytest.raises(ConfigError):
        air_cut_sweep_program([1000, 30000], max_speed_rpm=20000)


def test_warm_up_duration() -> None:
    tr = interpolate(parse_program(warm_up_program(5000, minutes=0.5)), limits=LIMITS,
                     spindle=SPINDLE)
    # 5000/4000 s up + 30 s + 5000/4000 s down
    assert tr.duration_s == pytest.approx(1.25 + 30.0 + 1.25, abs=T)


@pytest.mark.parametrize("cycle", ["CYCLE84", "G84"])
def test_tapping_program_m8(cycle: str) -> None:
    tr = interpolate(parse_program(tapping_program(2, cycle=cycle)), limits=LIMITS,
                     spindle=SPINDLE)  # fmt: skip
    h = tr.holes
    assert len(h) == 2 and (h["kind"] == "tap").all()
    assert (h["pitch_mm"] == 1.25).all()  # ISO 261 M8 coarse
    assert (h["z_bottom_mm"] == -15.0).all()
    assert tr.spindle_speed_cmd_rpm.max() == pytest.approx(400.0)
    assert tr.spindle_speed_cmd_rpm.min() == pytest.approx(-400.0)
    with pytest.raises(ConfigError):
        tapping_program(thread="M7")


def test_production_with_an_end_mill_changes_to_it_for_the_milling() -> None:
    """end_mill=3: every milling operation runs with T3 (changed to and back), the drawn
    tool changes alternate between two drills (T1, T4), the holes are those of the plain
    draw (the same random choices)."""
    from cnctwin.sim.gcode import parse_program
    from cnctwin.sim.programs import production_program

    for seed in range(2000, 2010):
        plain = production_program(seed, operations=12)
        mill = production_program(seed, operations=12, end_mill=3)
        assert mill.holes == plain.holes
        prog = parse_program(mill.text)
        active = 0
        for b in prog.blocks:
            if b.tool_change and b.tool is not None:
                active = int(b.tool)
            if b.kind in ("linear", "arc_cw", "arc_ccw") and b.target.get("Z", 1.0) < 0:
                assert active == 3, (seed, b.line, b.text)
            if b.kind == "drill_cycle":
                assert active in (1, 4), (seed, b.line, b.text)
            if b.kind == "tap_cycle":
                assert active == 2, (seed, b.line, b.text)
