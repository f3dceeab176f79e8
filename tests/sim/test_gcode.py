"""Tests of the part-program parser (cnctwin.sim.gcode).

Cycle parameter semantics: Siemens, SINUMERIK 840D sl Cycles Programming Manual 04/2006
(CYCLE81, CYCLE83, CYCLE84); arc tolerance: MD21000/MD21010 (0.01 mm, 0.001 r).
"""

from __future__ import annotations

import math

import pytest

from cnctwin.exceptions import ConfigError, GCodeError
from cnctwin.sim.gcode import ISO_COARSE_PITCH_MM, parse_program


def test_modal_incremental_resolved_to_absolute() -> None:
    prog = parse_program("G90 G0 X10 Y20 Z5\nG91 G1 X5 Y-2.5 F400\nX1\nG90 X0\n")
    b = prog.blocks
    assert b[0].target == {"X": 10.0, "Y": 20.0, "Z": 5.0}
    assert b[1].target == {"X": 15.0, "Y": 17.5}
    assert b[2].target == {"X": 16.0}  # still G91
    assert b[3].target == {"X": 0.0}
    assert b[3].start["X"] == 16.0 and b[3].start["Y"] == 17.5
    assert [x.kind for x in b] == ["rapid", "linear", "linear", "linear"]
    assert b[1].feedrate_mm_min == 400.0 and b[3].feedrate_mm_min == 400.0  # modal F


def test_start_position_used_for_incremental() -> None:
    prog = parse_program("G91 G0 X5\n", start_position={"X": 100.0})
    assert prog.blocks[0].target == {"X": 105.0}


def test_comments_block_numbers_and_line_numbers() -> None:
    text = "; header\n\nN10 G0 X1 (go)\nN20 G1 Y2 F100 ; feed\n"
    prog = parse_program(text, name="demo")
    assert [b.line for b in prog.blocks] == [3, 4]
    assert prog.blocks[0].words["N"] == ("10",)
    assert prog.blocks[1].offset == text.index("N20")
    assert prog.call_path == "/_N_MPF_DIR/_N_DEMO_MPF"


def test_to_text_round_trip() -> None:
    text = "G0 X1 Y1\n; c\nS2400 M3\nG1 Z-1 F100\nG2 X3 Y1 I1 J0\nM30\n"
    prog = parse_program(text)
    again = parse_program(prog.to_text())
    assert [(b.kind, b.target, b.center) for b in again.blocks] == [
        (b.kind, b.target, b.center) for b in prog.blocks
    ]


def test_arc_center_and_radius_exact() -> None:
    prog = parse_program("G0 X10 Y0\nG3 X0 Y10 I-10 J0 F500\nG2 X10 Y0 CR=10\n")
    a1, a2 = prog.blocks[1], prog.blocks[2]
    assert a1.kind == "arc_ccw" and a1.center == (0.0, 0.0) and a1.radius_mm == 10.0
    assert a2.kind == "arc_cw"
    assert a2.center is not None
    # CR>0 short arc clockwise from (0,10) to (10,0): centre (0,0)
    assert a2.center == pytest.approx((0.0, 0.0), abs=1e-12)
    assert math.hypot(10 - a2.center[0], 0 - a2.center[1]) == pytest.approx(10.0, abs=1e-12)


def test_arc_negative_cr_takes_long_way() -> None:
    prog = parse_program("G0 X0 Y10\nG2 X10 Y0 CR=-10 F500\n")
    assert prog.blocks[1].center == pytest.approx((10.0, 10.0), abs=1e-12)


def test_arc_radius_inconsistent_raises_with_line() -> None:
    # end radius 10.05 vs start 10: beyond max(0.01, 0.001*10) = 0.01 mm (MD21000/MD21010)
    with pytest.raises(GCodeError) as exc:
        parse_program("G0 X10 Y0\nG3 X0 Y10.05 I-10 J0 F500\n")
    assert exc.value.line == 2 and "circle" in str(exc.value)
    # within tolerance (0.005 mm) is accepted
    parse_program("G0 X10 Y0\nG3 X0 Y10.005 I-10 J0 F500\n")


@pytest.mark.parametrize(
    ("text", "line", "fragment"),
    [
        ("G0 X1\nG18 X2\n", 2, "only G17 supported"),
        ("G0 X1\nG1 X2 F-5\n", 2, "positive"),
        ("G1 X2\n", 1, "feed"),
        ("G0 X1 W5\n", 1, "unknown word"),
        ("G0 X1\nM99\n", 2, "M99"),
        ("G0 X1\nG81 X0 Y0 R2 F100\n", 2, "Z"),
        ("S2400 M3\nF100\nCYCLE81(10, 0, 2)\n", 3, "depth"),
        ("S2400 M3\nF100\nCYCLE81(10, 0, 2, 5)\n", 3, "not below"),
        ("S30000 M3\n", 1, "exceeds"),
        ("G0 X1\nG4\n", 2, "G4"),
        ("G0 X1\nG0 X2 (open\n", 2, "parenthesis"),
        ("M30\nG0 X1\n", 2, "after program end"),
        ("S100 M3\nCYCLE84(10,0,2,-10)\n", 2, "pitch"),
        ("G0 X1\nCYCLE99(1,2)\n", 2, "CYCLE99"),
    ],
)
def test_errors_name_the_line(text: str, line: int, fragment: str) -> None:
    with pytest.raises(GCodeError) as exc:
        parse_program(text, max_speed_rpm=20000.0)
    assert exc.value.line == line
    assert fragment in str(exc.value)
    assert isinstance(exc.value, ConfigError)


def test_spindle_tool_dwell() -> None:
    prog = parse_program("T3\nM6\nS2400 M3\nG4 F1.5\nG4 S10\nM4\nM5\nM30\n")
    kinds = [b.kind for b in prog.blocks]
    assert kinds == ["set", "tool_change", "spindle", "dwell", "dwell", "spindle", "spindle",
                     "program_end"]  # fmt: skip
    assert prog.blocks[1].tool == 3 and prog.blocks[1].tool_change
    assert prog.blocks[2].speed_rpm == 2400.0 and prog.blocks[2].spindle_dir == 1
    assert prog.blocks[3].dwell_s == 1.5 and prog.blocks[4].dwell_rev == 10.0
    assert prog.blocks[3].speed_rpm == 2400.0  # G4 S does not change the spindle speed
    assert prog.blocks[5].spindle_dir == -1 and prog.blocks[6].spindle_dir == 0


def test_feed_per_rev_mode() -> None:
    prog = parse_program("S2400 M3\nG95 G1 Z-5 F0.16\n")
    b = prog.blocks[1]
    assert b.feed_mode == "G95" and b.feed_mm_per_rev == 0.16


def test_cycle81_planes() -> None:
    prog = parse_program("S2400 M3\nF400\nG0 X0 Y0 Z50\nCYCLE81(10, 0, 2, -20)\n"
                         "CYCLE81(10, 0, 2, -99, 15)\n")  # fmt: skip
    c = prog.blocks[3].cycle
    assert c is not None and prog.blocks[3].kind == "drill_cycle"
    assert (c.z_retract_mm, c.z_ref_mm, c.z_safety_mm, c.z_bottom_mm) == (10, 0, 2, -20)
    c2 = prog.blocks[4].cycle
    assert c2 is not None and c2.z_bottom_mm == -15.0  # DPR wins over DP (Siemens)
    assert c.call_path == "/_CYCLES_DIR/_CYCLE81"


def test_mcall_applies_at_following_positions() -> None:
    text = "S2400 M3\nF400\nG0 Z10\nMCALL CYCLE81(10, 0, 2, -20)\nX10 Y0\nX20\nMCALL\nX30\n"
    prog = parse_program(text)
    kinds = [b.kind for b in prog.blocks]
    assert kinds == ["spindle", "set", "rapid", "set", "drill_cycle", "drill_cycle", "set",
                     "rapid"]  # fmt: skip
    assert prog.blocks[5].target == {"X": 20.0}
    assert prog.blocks[5].start["Y"] == 0.0


def test_cycle83_parameters() -> None:
    prog = parse_program("S2400 M3\nF400\nCYCLE83(10, 0, 2, -30, , -10, , 3, 1, 0.5, 0.8, 1)\n")
    c = prog.blocks[2].cycle
    assert c is not None and c.kind == "peck"
    assert c.first_depth_mm == 10.0 and c.degression_mm == 3.0
    assert c.dwell_bottom_s == 1.0 and c.dwell_top_s == 0.5
    assert c.feed_factor_first == 0.8 and c.swarf_removal


def test_cycle84_pitch_from_mpit_and_pit() -> None:
    prog = parse_program(
        "S500 M3\nCYCLE84(10, 0, 2, -15, , 0, 3, 8, , 90, 400, 800)\n"
        "CYCLE84(10, 0, 2, -15, , 0, 4, , -1.0, 0, 400)\n"
    )
    c = prog.blocks[1].cycle
    assert c is not None and c.kind == "tap" and prog.blocks[1].kind == "tap_cycle"
    assert c.pitch_mm == ISO_COARSE_PITCH_MM[8] == 1.25  # ISO 261 M8 coarse
    assert (c.tap_speed_rpm, c.retract_speed_rpm, c.spindle_pos_deg) == (400, 800, 90)
    assert c.dir_after == 1
    c2 = prog.blocks[2].cycle
    assert c2 is not None and c2.pitch_mm == -1.0 and c2.retract_speed_rpm == 400.0
    assert c2.dir_after == -1


def test_iso_cycles_g98_g99_and_cancel() -> None:
    text = ("S1000 M3\nG0 X0 Y0 Z20\nG99 G81 X5 Y5 Z-10 R2 F300\nX10\nG98 G83 X20 Z-30 R2 Q5\n"
            "G80\nG0 Z20\nG95 G84 X40 Z-12 R3 F1.25\nG0 Z50\n")  # fmt: skip
    prog = parse_program(text)
    b = prog.blocks
    kinds = ["spindle", "rapid", "drill_cycle", "drill_cycle", "drill_cycle", "cycle_cancel",
             "rapid", "tap_cycle", "rapid"]  # fmt: skip
    assert [x.kind for x in b] == kinds
    c0, c1, c2, c3 = (x.cycle for x in (b[2], b[3], b[4], b[7]))
    assert c0 is not None and c0.z_retract_mm == 2.0 and c0.z_bottom_mm == -10.0  # G99 -> R
    assert c1 is not None and c1.z_bottom_mm == -10.0 and b[3].target == {"X": 10.0}
    assert c2 is not None and c2.kind == "peck" and c2.first_depth_mm == 5.0
    assert c2.z_retract_mm == 2.0  # G98: initial level = Z at the cycle start (R after G99)
    assert c3 is not None and c3.pitch_mm == 1.25 and c3.tap_speed_rpm == 1000.0
    assert b[2].feedrate_mm_min == 300.0


def test_iso_g91_cycle_is_relative() -> None:
    prog = parse_program("S1000 M3\nG0 X0 Y0 Z20\nG91 G81 X5 Z-12 R-18 F300\n")
    c = prog.blocks[2].cycle
    assert c is not None and c.z_ref_mm == 2.0 and c.z_bottom_mm == -10.0
    assert prog.blocks[2].target == {"X": 5.0}


def test_exact_stop_modal() -> None:
    prog = parse_program("G1 X1 F100\nG64 X2\nX3 G9\nG60 X4\n")
    assert [b.exact_stop for b in prog.blocks] == [True, False, True, True]
