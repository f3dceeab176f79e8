"""Tests of the fine interpolator (cnctwin.sim.interpolator).

Limits are checked on finite differences of DES_POS at the 2 ms cycle: the k-th difference
divided by T^k is a kernel-weighted average of the k-th derivative over k cycles, so it cannot
exceed the derivative's bound (tolerance below only covers float round-off).
References: double-S profile, Biagiotti & Melchiorri, Trajectory Planning for Automatic
Machines and Robots (2008) Sect. 3.4; corner velocity jump <= MD32310 overload factor x a_max x T.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from cnctwin.exceptions import ConfigError, GCodeError
from cnctwin.sim.gcode import parse_program
from cnctwin.sim.interpolator import (
    AxisLimits,
    SpindleLimits,
    Trajectory,
    interpolate,
    interpolate_chunks,
)

T = 0.002
V_MAX = {"X1": 30000.0, "Y1": 30000.0, "Z1": 20000.0}  # mm/min
A_MAX = {"X1": 3000.0, "Y1": 2500.0, "Z1": 2000.0}  # mm/s^2
J_MAX = {"X1": 50000.0, "Y1": 40000.0, "Z1": 30000.0}  # mm/s^3
LIMITS = {ax: AxisLimits(V_MAX[ax], A_MAX[ax], J_MAX[ax]) for ax in V_MAX}
LIMITS["C1"] = LIMITS["B1"] = AxisLimits(7200.0, 1000.0, 20000.0)
SPINDLE = SpindleLimits(max_speed_rpm=20000.0, accel_rpm_s=4000.0)


def run(text: str, **kw: object) -> Trajectory:
    return interpolate(parse_program(text), limits=LIMITS, spindle=SPINDLE, **kw)  # type: ignore[arg-type]


def diffs(x: np.ndarray, order: int) -> np.ndarray:
    return np.diff(x, n=order) / T**order


def check_limits(tr: Trajectory, *, skip_jerk: np.ndarray | None = None, ovl: float = 1.0) -> None:
    for ax in ("X1", "Y1", "Z1"):
        x = tr.des_pos[ax]
        v = np.abs(diffs(x, 1)) * 60.0
        a = np.abs(diffs(x, 2))
        j = np.abs(diffs(x, 3))
        assert v.max() <= V_MAX[ax] * (1 + 1e-9) + 1e-6, ax
        assert a.max() <= ovl * A_MAX[ax] * (1 + 1e-6) + 1e-3, (ax, a.max())
        if skip_jerk is not None:
            j = j[~skip_jerk[: j.size]]
        assert j.max() <= J_MAX[ax] * (1 + 1e-6) + 1.0, (ax, j.max())


def test_linear_feed_plateau_and_endpoint() -> None:
    tr = run("G0 X0 Y0 Z0\nG1 X100 F400\n")
    x = tr.des_pos["X1"]
    step = np.diff(x)
    # 400 mm/min at 2 ms: 400/60*0.002 = 0.013333 mm per cycle
    plateau = step[np.abs(step - 400 / 60 * T) < 1e-6]
    assert plateau.size > 0.9 * 100 / (400 / 60) / T
    np.testing.assert_allclose(plateau, 0.0133333333, rtol=1e-6)
    assert x[-1] == pytest.approx(100.0, abs=1e-9)
    np.testing.assert_allclose(tr.path_velocity_mm_min.max(), 400.0, rtol=1e-9)
    assert tr.path_velocity_mm_min[-1] == 0.0
    check_limits(tr)


def test_rapid_respects_per_axis_limits() -> None:
    tr = run("G0 X300 Y-200 Z-150\nG0 X0 Y0 Z0\n")
    check_limits(tr)
    for ax, end in (("X1", 0.0), ("Y1", 0.0), ("Z1", 0.0)):
        assert tr.des_pos[ax][-1] == pytest.approx(end, abs=1e-9)
    # the rapid reaches the velocity of its limiting axis: path 403.1 mm, Y is limiting
    # because its acceleration is the lowest relative to its share; at least one axis must
    # get within 1 % of its velocity limit on a 400 mm move
    peaks = [np.abs(np.diff(tr.des_pos[ax])).max() / T * 60 / V_MAX[ax] for ax in V_MAX]
    assert max(peaks) == pytest.approx(1.0, rel=0.01)


def test_g91_and_feed_per_rev() -> None:
    tr = run("S2400 M3\nG91 G95 G1 X10 F0.16\nX10\n")
    # G95: 0.16 mm/rev x 2400 rpm = 384 mm/min
    assert tr.path_velocity_mm_min.max() == pytest.approx(384.0, rel=1e-9)
    assert tr.des_pos["X1"][-1] == pytest.approx(20.0, abs=1e-9)


SQUARE = "G0 X0 Y0 Z0\n{mode} G1 X50 F2000\nY50\nX0\nY0\n"


def test_square_corners_slow_down_with_lookahead() -> None:
    tr = run(SQUARE.format(mode="G64"))
    v = tr.path_velocity_mm_min
    x, y = tr.des_pos["X1"], tr.des_pos["Y1"]
    # at the three inner corners the path velocity drops to the velocity-jump limit:
    # 90 deg corner, |du| = 1 on each axis -> v <= 1.2 * a_min * T = 1.2*2500*0.002 = 6 mm/s
    v_corner = 1.2 * 2500.0 * T * 60.0  # 360 mm/min
    for cx, cy in ((50, 0), (50, 50), (0, 50)):
        near = np.hypot(x - cx, y - cy) < 0.05
        assert near.any()
        vmin = v[near].min()
        # sampled within one cycle of the corner: at most one cycle of acceleration above
        assert 0.999 * v_corner <= vmin <= v_corner * 1.02, (cx, cy, vmin)
    assert v.max() == pytest.approx(2000.0, rel=1e-9)  # plateau between corners = F
    corners = v < 1.05 * v_corner
    near_corner = np.convolve(corners, np.ones(7), mode="same") > 0
    check_limits(tr, skip_jerk=near_corner, ovl=1.2)
    # exact stop mode (G60) stops at every corner
    tr60 = run(SQUARE.format(mode="G60"))
    x60, y60 = tr60.des_pos["X1"], tr60.des_pos["Y1"]
    at = np.hypot(x60 - 50, y60 - 50) < 1e-9
    assert tr60.path_velocity_mm_min[at].min() == 0.0
    assert tr60.duration_s > tr.duration_s
    check_limits(tr60)


@pytest.mark.parametrize("radius", [2.0, 20.0])
def test_circle_exact_and_centripetal_limit(radius: float) -> None:
    text = f"G0 X{radius} Y0 Z0\nG3 X{radius} Y0 I{-radius} J0 F6000\n"
    tr = run(text)
    arc = tr.block_index == 1
    x, y = tr.des_pos["X1"][arc], tr.des_pos["Y1"][arc]
    np.testing.assert_allclose(np.hypot(x, y), radius, atol=1e-9)  # on the circle
    v = tr.path_velocity_mm_min[arc] / 60.0
    a_xy, j_xy = 2500.0, 40000.0
    # centripetal share 0.5: v <= sqrt(0.5 a r) and v^3/r^2 <= 0.5 j
    expected = min(100.0, math.sqrt(0.5 * a_xy * radius), (0.5 * j_xy * radius**2) ** (1 / 3))
    assert v.max() <= expected * (1 + 1e-9)
    if radius == 20.0:  # F-limited: the plateau is the programmed feed
        assert v.max() == pytest.approx(100.0, rel=1e-9)
    else:  # curvature-limited (jerk term); the short circle nearly reaches it
        assert v.max() >= 0.95 * expected
    assert v.max() <= math.sqrt(a_xy * radius)
    # full circle swept: angle unwraps by 2 pi
    ang = np.unwrap(np.arctan2(tr.des_pos["Y1"][arc.argmax() :], tr.des_pos["X1"][arc.argmax() :]))
    assert ang[-1] - ang[0] == pytest.approx(2 * math.pi, abs=1e-9)
    check_limits(tr)


def test_arc_endpoint_exact_and_line_to_arc_blend() -> None:
    tr = run("G0 X0 Y0 Z0\nG64 G1 X20 F1200\nG3 X30 Y10 CR=10\nG1 Y40\n")
    assert tr.des_pos["X1"][-1] == pytest.approx(30.0, abs=1e-9)
    assert tr.des_pos["Y1"][-1] == pytest.approx(40.0, abs=1e-9)
    v = tr.path_velocity_mm_min
    # tangent transitions line->arc->line do not stop the path
    inner = (tr.des_pos["X1"] > 1) & (tr.des_pos["Y1"] < 39)
    assert v[inner].min() > 0.0
    check_limits(tr)


def drill_program(cycle: str) -> str:
    return (
        "G90 G17 G94\nT1 M6\nS2400 M3 F400\nG0 X0 Y0 Z10\n"
        f"MCALL {cycle}\nX10 Y0\nX10 Y12\nX10 Y24\nMCALL\nG0 Z50\nM5\nM30\n"
    )


def test_cycle81_hole_table_and_events() -> None:
    tr = run(drill_program("CYCLE81(10, 0, 2, -20)"))
    h = tr.holes
    assert len(h) == 3
    assert (h["kind"] == "drill").all() and (h["z_top_mm"] == 0.0).all()
    assert (h["z_bottom_mm"] == -20.0).all() and (h["tool"] == 1).all()
    np.testing.assert_array_equal(h["y_mm"], [0.0, 12.0, 24.0])
    z = tr.des_pos["Z1"]
    for _, row in h.iterrows():
        s, e = int(row.start_cycle), int(row.end_cycle)
        assert z[s] <= 0.0 < z[s - 1]  # first cycle at/below the surface going in
        assert z[e] >= 0.0 > z[e - 1]  # first cycle back at/above the surface
        assert z[s:e].min() == pytest.approx(-20.0, abs=1e-9)
        assert tr.des_pos["X1"][s] == 10.0 and tr.des_pos["Y1"][s] == row.y_mm
        # feed 400 mm/min inside the hole
        steps = -np.diff(z[s:e])
        assert steps.max() == pytest.approx(400 / 60 * T, rel=1e-6)
        # cutting time at least depth/feed = 20 mm / 400 mm/min = 3 s
        assert (e - s) * T >= 3.0
    ev = tr.events
    blocks = ev[ev["kind"] == "block"]
    assert len(blocks) == 12
    assert list(blocks["gcode"].iloc[:2]) == ["G90 G17 G94", "T1 M6"]
    calls = ev[(ev["kind"] == "call") & (ev["path"] == "/_CYCLES_DIR/_CYCLE81")]
    assert len(calls) == 3 and (calls["call_stack_level"] == 2).all()
    assert (calls["cycle"].to_numpy() < h["start_cycle"].to_numpy()).all()
    assert ev["cycle"].is_monotonic_increasing
    assert set(blocks["ipo_gcode"]) <= {"G0", "G1", "G2", "G3"}
    assert (tr.tool[h["start_cycle"]] == 1).all()
    # spindle at speed when cutting (waited for the ramp after M3)
    np.testing.assert_allclose(tr.spindle_speed_cmd_rpm[h["start_cycle"]], 2400.0)
    check_limits(tr)


def test_cycle83_peck_depths() -> None:
    # first depth 10 (FDPR), DAM 3: infeeds 10, 7, 4, 3, 3, 3 -> depths 10 17 21 24 27 30
    tr = run(drill_program("CYCLE83(10, 0, 2, , 30, , 10, 3, 0, 0, 1, 1)"))
    h = tr.holes
    assert len(h) == 3 and (h["kind"] == "peck").all()
    z = tr.des_pos["Z1"]
    s, e = int(h.start_cycle[0]), int(h.end_cycle[0])
    seg = z[s - 1 : e + 1]
    is_min = (seg[1:-1] < seg[:-2]) & (seg[1:-1] <= seg[2:])
    np.testing.assert_allclose(seg[1:-1][is_min], [-10, -17, -21, -24, -27, -30], atol=1e-9)
    check_limits(tr)


def test_iso_g81_and_chunks_equal_whole() -> None:
    text = "S2400 M3\nG0 X0 Y0 Z20\nG99 G81 X5 Y5 Z-10 R2 F300\nX15\nG80\nG0 Z20\nM30\n"
    whole = run(text)
    prog = parse_program(text)
    chunks = list(interpolate_chunks(prog, limits=LIMITS, spindle=SPINDLE, chunk_cycles=777))
    assert len(chunks) > 2
    for ax in whole.des_pos:
        np.testing.assert_array_equal(np.concatenate([c.des_pos[ax] for c in chunks]),
                                      whole.des_pos[ax])  # fmt: skip
    np.testing.assert_array_equal(
        np.concatenate([c.spindle_speed_cmd_rpm for c in chunks]), whole.spindle_speed_cmd_rpm
    )
    assert sum(len(c.holes) for c in chunks) == len(whole.holes) == 2
    assert sum(len(c.events) for c in chunks) == len(whole.events)
    assert chunks[1].first_cycle == 777
    assert (whole.holes["z_top_mm"] == 2.0).all()  # R plane for ISO cycles


def test_rigid_tapping_spindle_follows_z() -> None:
    text = ("G0 X0 Y0 Z10\nS500 M3\nCYCLE84(10, 0, 2, -15, , 0, 3, 8, , 30, 400, 800)\n"
            "G0 Z50\nM30\n")  # fmt: skip
    tr = run(text)
    mode = tr.spindle_mode
    assert mode.any()
    idx = np.flatnonzero(mode == 1)
    ang = tr.spindle_pos_cmd_deg[idx]
    pitch = 1.25  # M8 coarse, ISO 261
    # angle travelled = thread length / pitch * 360 deg: from RFP+SDIS = 2 to -15 = 17 mm
    assert ang.max() - ang.min() == pytest.approx(17.0 / pitch * 360.0, rel=1e-9)
    assert ang[0] == pytest.approx(30.0, abs=1e-9)  # POSS oriented stop
    # back to the start angle on retract (last position-mode sample is < 1 cycle before the
    # top, where the speed is ~0)
    assert ang[-1] == pytest.approx(30.0, abs=0.01)
    # spindle speed = -dz/dt / pitch * 60 (finite differences of DES_POS Z)
    vz = np.diff(tr.des_pos["Z1"]) / T
    sp = tr.spindle_speed_cmd_rpm
    inner = idx[1:-1]
    np.testing.assert_allclose(
        0.5 * (sp[inner] + sp[inner - 1]), -vz[inner - 1] / pitch * 60.0, atol=2.0
    )
    assert sp[idx].max() == pytest.approx(400.0, rel=1e-9)  # SST going in
    assert sp[idx].min() == pytest.approx(-800.0, rel=1e-9)  # SST1, reversed, coming out
    h = tr.holes
    assert len(h) == 1 and h["kind"][0] == "tap" and h["pitch_mm"][0] == pitch
    assert h["feed_mm_min"][0] == pytest.approx(400 * pitch)
    # after the cycle, speed control again and back to M3 S500 (SDAC = 3)
    assert mode[-1] == 0 and tr.spindle_speed_cmd_rpm[-1] == pytest.approx(500.0)


def test_spindle_ramp_and_dwell() -> None:
    tr = run("S3000 M3\nG4 F1\nM4\nG4 S10\nM5\nM30\n")
    sp = tr.spindle_speed_cmd_rpm
    ramp = np.abs(np.diff(sp)) / T
    assert ramp.max() <= 4000.0 * (1 + 1e-9)
    assert sp.max() == pytest.approx(3000.0) and sp.min() == pytest.approx(-3000.0)
    # waits: 0.75 s up, 1 s dwell, 1.5 s reversal, 10 rev at 3000 rpm = 0.2 s, 0.75 s down
    assert tr.duration_s == pytest.approx(0.75 + 1.0 + 1.5 + 0.2 + 0.75, abs=1e-9)
    assert sp[-1] == 0.0


def test_errors() -> None:
    with pytest.raises(ConfigError, match="AxisLimits"):
        interpolate(parse_program("G0 X1\n"), limits={"X1": LIMITS["X1"]}, spindle=SPINDLE)
    with pytest.raises(GCodeError) as exc:
        run("S25000 M3\n")
    assert exc.value.line == 1
    with pytest.raises(ConfigError, match="not mapped"):
        interpolate(parse_program("G0 A5\n"), limits=LIMITS, spindle=SPINDLE)
