"""Part programs of the thesis experiments, generated as SINUMERIK program text.

Every function returns program text that :func:`cnctwin.sim.gcode.parse_program` accepts
(``parse_program(hole_pattern(2676))``).

* :func:`hole_pattern`: the tool-wear drilling run, holes in sets of 6 (thesis Sect. 5.1: 2676
  holes, 20 mm deep, 2400 rpm, 400 mm/min, TiAlN carbide drill 8.5 mm, AISI 1045).
* :func:`drilling_validation_program`: drilling at a given speed and feed per revolution
  (thesis Table 4.1: 2400 rpm 0.3 mm/rev, 3200 rpm 0.4, 2800 rpm 0.14, 3200 rpm 0.125; the
  calibration hole 2400 rpm 0.16 mm/rev).
* :func:`square_path`, :func:`circle_path`: the milling experiment of thesis Sect. 3.1.2
  (Al7050-T7451, 16 mm two-flute carbide end mill, 0.5 mm axial depth, 0.167 mm/tooth).
* :func:`air_cut_sweep_program`: the spindle run at 126 speeds up to 18000 rpm (thesis Sect. 3.2.2).
* :func:`warm_up_program`: constant-speed run (thesis Sect. 4.2: 5000 and 7000 rpm for > 20 min).
* :func:`tapping_program`: rigid tapping (thesis Sect. 5.4), M8 x 1.25 by default.
* :func:`axis_test_program`: each feed axis back and forth in air at several feeds, for the
  identification of its position loop and friction (``cnctwin calibrate axes``).
* :data:`ADAPTIVE_SLOT`: the adaptive feed's closed-loop part (docs/adaptive.md).

Values the thesis does not give are marked as assumptions in the parameter descriptions.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from cnctwin.exceptions import ConfigError
from cnctwin.sim.gcode import ISO_COARSE_PITCH_MM

__all__ = [
    "ADAPTIVE_SLOT",
    "AIR_CUT_SPEEDS_RPM",
    "PRODUCTION_STOCK",
    "PRODUCTION_TOOLS",
    "ProductionProgram",
    "air_cut_sweep_program",
    "axis_test_program",
    "circle_path",
    "drilling_validation_program",
    "hole_pattern",
    "hole_positions",
    "production_program",
    "square_path",
    "tapping_program",
    "warm_up_program",
]

AIR_CUT_SPEEDS_RPM: tuple[float, ...] = tuple(
    float(v) for v in np.round(np.linspace(18000.0 / 126.0, 18000.0, 126), 0)
)
"""126 spindle speeds up to 18000 rpm (thesis Sect. 3.2.2 gives the count and the maximum
only; equal spacing of ~143 rpm is an assumption)."""

_CYCLES = ("CYCLE81", "CYCLE83", "G81", "G83")


def _fmt(v: float) -> str:
    s = f"{v:.4f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def _check_positive(**kw: float) -> None:
    for k, v in kw.items():
        if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
            raise ConfigError(f"{k} must be a positive number, got {v!r}")


def hole_positions(
    n_holes: int,
    *,
    set_size: int = 6,
    pitch_mm: float = 12.0,
    set_spacing_mm: float = 15.0,
    sets_per_row: int = 20,
    row_spacing_mm: float | None = None,
    start_xy: tuple[float, float] = (10.0, 10.0),
) -> list[tuple[float, float]]:
    """XY positions of holes in sets: each set is a column of ``set_size`` holes along Y.

    Parameters
    ----------
    n_holes : int
        Number of holes.
    set_size : int, default 6
        Holes per set (thesis: 6 consecutive holes placed vertically).
    pitch_mm : float, default 12
        Distance between holes of a set along Y [mm] (assumption; drill 8.5 mm).
    set_spacing_mm : float, default 15
        Distance between sets along X [mm] (assumption).
    sets_per_row : int, default 20
        Sets side by side before starting the next row of sets (assumption).
    row_spacing_mm : float, optional
        Y distance between rows of sets [mm]; default ``set_size * pitch_mm + pitch_mm``.
    start_xy : tuple, default (10, 10)
        Position of the first hole [mm].

    Returns
    -------
    list of (x, y)
        Hole positions in drilling order [mm].
    """
    if n_holes < 1 or set_size < 1 or sets_per_row < 1:
        raise ConfigError("n_holes, set_size and sets_per_row must be >= 1")
    _check_positive(pitch_mm=pitch_mm, set_spacing_mm=set_spacing_mm)
    row_dy = row_spacing_mm if row_spacing_mm is not None else (set_size + 1) * pitch_mm
    out = []
    for h in range(n_holes):
        s, i = divmod(h, set_size)
        row, col = divmod(s, sets_per_row)
        out.append((start_xy[0] + col * set_spacing_mm, start_xy[1] + row * row_dy + i * pitch_mm))
    return out


def hole_pattern(
    n_holes: int,
    *,
    set_size: int = 6,
    pitch_mm: float = 12.0,
    set_spacing_mm: float = 15.0,
    sets_per_row: int = 20,
    depth_mm: float = 20.0,
    speed_rpm: float = 2400.0,
    feedrate_mm_min: float = 400.0,
    cycle: str = "CYCLE81",
    tool: int = 1,
    start_xy: tuple[float, float] = (10.0, 10.0),
    surface_z_mm: float = 0.0,
    retract_mm: float = 10.0,
    safety_mm: float = 2.0,
    peck_mm: float = 5.0,
    name: str = "HOLES",
) -> str:
    """Drilling program for ``n_holes`` holes in sets (the thesis tool-wear run).

    Parameters
    ----------
    n_holes : int
        Number of holes (thesis Sect. 5.1: 2676).
    set_size, pitch_mm, set_spacing_mm, sets_per_row, start_xy
        Layout, see :func:`hole_positions`.
    depth_mm : float, default 20
        Hole depth below the surface [mm] (thesis: 20 mm).
    speed_rpm : float, default 2400
        Spindle speed [rpm] (thesis).
    feedrate_mm_min : float, default 400
        Feed [mm/min] (thesis; 0.167 mm/rev at 2400 rpm).
    cycle : {"CYCLE81", "CYCLE83", "G81", "G83"}
        Drilling cycle: SINUMERIK cycles called modally with ``MCALL``, or ISO canned cycles.
    tool : int, default 1
        Tool number.
    surface_z_mm : float, default 0
        Workpiece surface (reference plane RFP / R) [mm].
    retract_mm : float, default 10
        Retraction plane above the surface (RTP - RFP; ISO: initial level) [mm] (assumption).
    safety_mm : float, default 2
        Safety clearance SDIS [mm] (assumption; ISO cycles use R = surface + safety).
    peck_mm : float, default 5
        Peck depth for CYCLE83 (FDPR, no degression) and G83 (Q) [mm].
    name : str
        Program name, written as a comment.

    Returns
    -------
    str
        Program text.
    """
    if cycle not in _CYCLES:
        raise ConfigError(f"cycle must be one of {_CYCLES}, got {cycle!r}")
    _check_positive(depth_mm=depth_mm, speed_rpm=speed_rpm, feedrate_mm_min=feedrate_mm_min,
                    retract_mm=retract_mm, peck_mm=peck_mm)  # fmt: skip
    if safety_mm < 0 or safety_mm > retract_mm:
        raise ConfigError(f"safety_mm must be in 0..retract_mm, got {safety_mm}")
    pos = hole_positions(n_holes, set_size=set_size, pitch_mm=pitch_mm,
                         set_spacing_mm=set_spacing_mm, sets_per_row=sets_per_row,
                         start_xy=start_xy)  # fmt: skip
    rfp, rtp = surface_z_mm, surface_z_mm + retract_mm
    bottom = surface_z_mm - depth_mm
    lines = [
        f"; {name}: {n_holes} holes in sets of {set_size}, {_fmt(depth_mm)} mm deep, "
        f"{_fmt(speed_rpm)} rpm, {_fmt(feedrate_mm_min)} mm/min ({cycle})",
        "G90 G17 G94 G60",
        f"T{tool} M6",
        f"S{_fmt(speed_rpm)} M3 M8",
        f"G0 X{_fmt(pos[0][0])} Y{_fmt(pos[0][1])} Z{_fmt(rtp)} F{_fmt(feedrate_mm_min)}",
    ]
    if cycle == "CYCLE81":
        lines.append(f"MCALL CYCLE81({_fmt(rtp)}, {_fmt(rfp)}, {_fmt(safety_mm)}, {_fmt(bottom)})")
    elif cycle == "CYCLE83":
        lines.append(
            f"MCALL CYCLE83({_fmt(rtp)}, {_fmt(rfp)}, {_fmt(safety_mm)}, {_fmt(bottom)}, , , "
            f"{_fmt(peck_mm)}, 0, 0, 0, 1, 1)"
        )
    for k, (x, y) in enumerate(pos):
        if k % set_size == 0:
            lines.append(f"; set {k // set_size + 1}")
        if cycle in ("G81", "G83") and k == 0:
            q = f" Q{_fmt(peck_mm)}" if cycle == "G83" else ""
            lines.append(f"G98 {cycle} X{_fmt(x)} Y{_fmt(y)} Z{_fmt(bottom)} "
                         f"R{_fmt(rfp + safety_mm)}{q} F{_fmt(feedrate_mm_min)}")  # fmt: skip
        else:
            lines.append(f"X{_fmt(x)} Y{_fmt(y)}")
    lines += ["MCALL" if cycle.startswith("CYCLE") else "G80", "G0 Z50", "M5 M9", "M30"]
    return "\n".join(lines) + "\n"


def drilling_validation_program(
    speed_rpm: float,
    feed_mm_per_rev: float,
    depth_mm: float,
    *,
    n_holes: int = 1,
    spacing_mm: float = 20.0,
    tool: int = 1,
    start_xy: tuple[float, float] = (20.0, 20.0),
    retract_mm: float = 10.0,
    safety_mm: float = 2.0,
    cycle: str = "CYCLE81",
) -> str:
    """Drilling with feed per revolution (G95), one row of holes along X.

    Parameters
    ----------
    speed_rpm : float
        Spindle speed [rpm].
    feed_mm_per_rev : float
        Feed per revolution [mm/rev].
    depth_mm : float
        Hole depth [mm] (not given in the thesis for Table 4.1).
    n_holes : int, default 1
        Holes in the row.
    spacing_mm : float, default 20
        Distance between holes [mm].
    tool, start_xy, retract_mm, safety_mm
        As in :func:`hole_pattern`.
    cycle : {"CYCLE81", "G81"}
        Drilling cycle.

    Returns
    -------
    str
        Program text.
    """
    if cycle not in ("CYCLE81", "G81"):
        raise ConfigError(f"cycle must be 'CYCLE81' or 'G81', got {cycle!r}")
    _check_positive(speed_rpm=speed_rpm, feed_mm_per_rev=feed_mm_per_rev, depth_mm=depth_mm)
    rtp, bottom = retract_mm, -depth_mm
    lines = [
        f"; drilling {_fmt(speed_rpm)} rpm {_fmt(feed_mm_per_rev)} mm/rev {_fmt(depth_mm)} mm",
        "G90 G17 G95 G60",
        f"T{tool} M6",
        f"S{_fmt(speed_rpm)} M3 M8",
        f"G0 X{_fmt(start_xy[0])} Y{_fmt(start_xy[1])} Z{_fmt(rtp)} F{_fmt(feed_mm_per_rev)}",
    ]
    if cycle == "CYCLE81":
        lines.append(f"MCALL CYCLE81({_fmt(rtp)}, 0, {_fmt(safety_mm)}, {_fmt(bottom)})")
    for k in range(n_holes):
        x, y = start_xy[0] + k * spacing_mm, start_xy[1]
        if cycle == "G81" and k == 0:
            lines.append(f"G98 G81 X{_fmt(x)} Y{_fmt(y)} Z{_fmt(bottom)} R{_fmt(safety_mm)} "
                         f"F{_fmt(feed_mm_per_rev)}")  # fmt: skip
        else:
            lines.append(f"X{_fmt(x)} Y{_fmt(y)}")
    lines += ["MCALL" if cycle == "CYCLE81" else "G80", "G0 Z50", "M5 M9", "M30"]
    return "\n".join(lines) + "\n"


def _milling_header(
    speed_rpm: float, feed_per_tooth_mm: float, n_flutes: int, tool: int
) -> tuple[list[str], float]:
    _check_positive(speed_rpm=speed_rpm, feed_per_tooth_mm=feed_per_tooth_mm)
    if n_flutes < 1:
        raise ConfigError(f"n_flutes must be >= 1, got {n_flutes}")
    feed = feed_per_tooth_mm * n_flutes * speed_rpm  # f = fz * z * n [mm/min]
    return ["G90 G17 G94", f"T{tool} M6", f"S{_fmt(speed_rpm)} M3 M8"], feed


def square_path(
    side_mm: float,
    *,
    speed_rpm: float = 6000.0,
    feed_per_tooth_mm: float = 0.167,
    n_flutes: int = 2,
    depth_mm: float = 0.5,
    start_xy: tuple[float, float] = (0.0, 0.0),
    safe_z_mm: float = 5.0,
    tool: int = 1,
    continuous: bool = True,
) -> str:
    """Mill a square (thesis Sect. 3.1.2 milling experiment), counter-clockwise.

    Parameters
    ----------
    side_mm : float
        Side length of the tool-centre square [mm].
    speed_rpm : float, default 6000
        Spindle speed [rpm] (not given in the thesis; assumption ~300 m/min for a 16 mm mill
        in aluminium).
    feed_per_tooth_mm : float, default 0.167
        Feed per tooth [mm] (thesis).
    n_flutes : int, default 2
        Number of flutes (thesis: two-flute end mill). Feed F = fz * z * n [mm/min].
    depth_mm : float, default 0.5
        Axial depth of cut [mm] (thesis).
    start_xy : tuple, default (0, 0)
        First corner [mm].
    safe_z_mm : float, default 5
        Clearance height [mm].
    tool : int, default 1
        Tool number.
    continuous : bool, default True
        G64 continuous-path mode (corners slowed by look-ahead); False: G60 exact stop.

    Returns
    -------
    str
        Program text.
    """
    _check_positive(side_mm=side_mm, depth_mm=depth_mm)
    head, feed = _milling_header(speed_rpm, feed_per_tooth_mm, n_flutes, tool)
    x0, y0 = start_xy
    x1, y1 = x0 + side_mm, y0 + side_mm
    mode = "G64" if continuous else "G60"
    return "\n".join([
        f"; square {_fmt(side_mm)} mm, F{_fmt(feed)} mm/min ({_fmt(feed_per_tooth_mm)} mm/tooth)",
        *head,
        f"G0 X{_fmt(x0)} Y{_fmt(y0)} Z{_fmt(safe_z_mm)}",
        f"G1 Z{_fmt(-depth_mm)} F{_fmt(feed)}",
        f"{mode} X{_fmt(x1)}",
        f"Y{_fmt(y1)}",
        f"X{_fmt(x0)}",
        f"Y{_fmt(y0)}",
        "G60 G0 Z" + _fmt(safe_z_mm),
        "M5 M9",
        "M30",
    ]) + "\n"  # fmt: skip


def circle_path(
    radius_mm: float,
    *,
    center_xy: tuple[float, float] = (0.0, 0.0),
    speed_rpm: float = 6000.0,
    feed_per_tooth_mm: float = 0.167,
    n_flutes: int = 2,
    depth_mm: float = 0.5,
    safe_z_mm: float = 5.0,
    tool: int = 1,
    clockwise: bool = False,
) -> str:
    """Mill a full circle (thesis Sect. 3.1.2), starting at the +X point of the circle.

    Parameters
    ----------
    radius_mm : float
        Radius of the tool-centre circle [mm].
    center_xy : tuple, default (0, 0)
        Centre [mm].
    speed_rpm, feed_per_tooth_mm, n_flutes, depth_mm, safe_z_mm, tool
        As in :func:`square_path`.
    clockwise : bool, default False
        G2 (climb/conventional depends on the side) instead of G3.

    Returns
    -------
    str
        Program text.
    """
    _check_positive(radius_mm=radius_mm, depth_mm=depth_mm)
    head, feed = _milling_header(speed_rpm, feed_per_tooth_mm, n_flutes, tool)
    cx, cy = center_xy
    g = "G2" if clockwise else "G3"
    return "\n".join([
        f"; circle r={_fmt(radius_mm)} mm, F{_fmt(feed)} mm/min",
        *head,
        f"G0 X{_fmt(cx + radius_mm)} Y{_fmt(cy)} Z{_fmt(safe_z_mm)}",
        f"G1 Z{_fmt(-depth_mm)} F{_fmt(feed)}",
        f"{g} X{_fmt(cx + radius_mm)} Y{_fmt(cy)} I{_fmt(-radius_mm)} J0",
        f"G0 Z{_fmt(safe_z_mm)}",
        "M5 M9",
        "M30",
    ]) + "\n"  # fmt: skip


def air_cut_sweep_program(
    speeds_rpm: Sequence[float] = AIR_CUT_SPEEDS_RPM,
    *,
    dwell_s: float = 5.0,
    max_speed_rpm: float | None = None,
) -> str:
    """Spindle-only program stepping through speeds with a dwell at each (air cut).

    Parameters
    ----------
    speeds_rpm : sequence of float, default :data:`AIR_CUT_SPEEDS_RPM`
        Spindle speeds in order [rpm] (thesis: 126 speeds up to 18000 rpm).
    dwell_s : float, default 5
        Dwell at each speed after it is reached [s] (assumption).
    max_speed_rpm : float, optional
        Reject speeds above this [rpm].

    Returns
    -------
    str
        Program text.
    """
    _check_positive(dwell_s=dwell_s)
    if len(speeds_rpm) == 0:
        raise ConfigError("speeds_rpm is empty")
    lines = [f"; air cut: {len(speeds_rpm)} speeds, {_fmt(dwell_s)} s each", "G90 G17 G94"]
    for n in speeds_rpm:
        _check_positive(speed_rpm=float(n))
        if max_speed_rpm is not None and n > max_speed_rpm:
            raise ConfigError(f"speed {n} rpm above max_speed_rpm {max_speed_rpm}")
        lines += [f"S{_fmt(float(n))} M3", f"G4 F{_fmt(dwell_s)}"]
    lines += ["M5", "M30"]
    return "\n".join(lines) + "\n"


def axis_test_program(
    axes: Sequence[str] = ("X1", "Y1", "Z1"),
    *,
    stroke_mm: float = 60.0,
    feeds_mm_min: Sequence[float] = (500.0, 1000.0, 2000.0, 4000.0, 8000.0),
    dwell_s: float = 0.3,
    words: dict[str, str] | None = None,
) -> str:
    """Air moves of each feed axis back and forth at several feeds (no cutting).

    A program a user can run on the machine to calibrate the feed axes: each stroke has a
    long constant-velocity stretch in both directions at every feed (friction, Kv from the
    steady following error), and starts and stops with the jerk-limited setpoint (jerk
    filter, speed loop).

    Parameters
    ----------
    axes : sequence of str, default ('X1', 'Y1', 'Z1')
        Machine axes to move; the program word is the axis name's letter (X1 -> X).
    stroke_mm : float, default 60
        Stroke from the start position [mm] (moves between 0 and ``stroke_mm``).
    feeds_mm_min : sequence of float
        Feeds [mm/min], each run once forward and once back.
    dwell_s : float, default 0.3
        Dwell at each end (G4) [s].
    words : dict, optional
        Axis name -> program word, where it is not the first letter.

    Returns
    -------
    str
        Program text (G90 G94 G60 exact stop, G1 moves).
    """
    _check_positive(stroke_mm=stroke_mm, dwell_s=dwell_s)
    if not feeds_mm_min or min(feeds_mm_min) <= 0:
        raise ConfigError(f"feeds_mm_min must be positive feeds, not {feeds_mm_min!r}")
    lines = [f"; axis test: {', '.join(axes)} back and forth over {_fmt(stroke_mm)} mm at "
             f"F{', F'.join(_fmt(f) for f in feeds_mm_min)} mm/min", "G90 G94 G60"]
    for ax in axes:
        w = (words or {}).get(ax, ax[0])
        lines.append(f"G0 {w}0")
        for f in feeds_mm_min:
            lines += [f"G1 {w}{_fmt(stroke_mm)} F{_fmt(f)}", f"G4 F{_fmt(dwell_s)}",
                      f"G1 {w}0 F{_fmt(f)}", f"G4 F{_fmt(dwell_s)}"]
    lines.append("M30")
    return "\n".join(lines) + "\n"


def warm_up_program(speed_rpm: float, *, minutes: float) -> str:
    """Run the spindle at constant speed (thesis Sect. 4.2: > 20 min at 5000 and 7000 rpm).

    Parameters
    ----------
    speed_rpm : float
        Spindle speed [rpm].
    minutes : float
        Time at speed [min].

    Returns
    -------
    str
        Program text.
    """
    _check_positive(speed_rpm=speed_rpm, minutes=minutes)
    return (
        f"; warm-up {_fmt(speed_rpm)} rpm for {_fmt(minutes)} min\n"
        f"S{_fmt(speed_rpm)} M3\nG4 F{_fmt(minutes * 60.0)}\nM5\nM30\n"
    )


def tapping_program(
    n_holes: int = 6,
    *,
    thread: str = "M8",
    pitch_mm: float | None = None,
    depth_mm: float = 15.0,
    speed_rpm: float = 400.0,
    retract_speed_rpm: float | None = None,
    cycle: str = "CYCLE84",
    spindle_pos_deg: float = 0.0,
    tool: int = 2,
    pitch_between_mm: float = 12.0,
    start_xy: tuple[float, float] = (10.0, 10.0),
    retract_mm: float = 10.0,
    safety_mm: float = 2.0,
) -> str:
    """Rigid tapping of a column of holes (CYCLE84 via MCALL, or ISO G84 under G95).

    Parameters
    ----------
    n_holes : int, default 6
        Holes.
    thread : str, default "M8"
        Metric coarse thread; sets the pitch from ISO 261 (M8: 1.25 mm).
    pitch_mm : float, optional
        Pitch [mm], overrides ``thread``.
    depth_mm : float, default 15
        Thread depth below the surface [mm].
    speed_rpm : float, default 400
        Tapping speed SST [rpm] (assumption).
    retract_speed_rpm : float, optional
        Retraction speed SST1 [rpm]; default ``speed_rpm``.
    cycle : {"CYCLE84", "G84"}
        Cycle.
    spindle_pos_deg : float, default 0
        Oriented-stop position POSS [deg].
    tool, pitch_between_mm, start_xy, retract_mm, safety_mm
        Layout and planes as in :func:`hole_pattern` (holes along Y).

    Returns
    -------
    str
        Program text.
    """
    if cycle not in ("CYCLE84", "G84"):
        raise ConfigError(f"cycle must be 'CYCLE84' or 'G84', got {cycle!r}")
    if pitch_mm is None:
        size = thread.upper().lstrip("M")
        if not size.isdigit() or int(size) not in ISO_COARSE_PITCH_MM:
            raise ConfigError(f"thread {thread!r} is not a metric coarse thread "
                              f"(M{', M'.join(str(k) for k in ISO_COARSE_PITCH_MM)})")  # fmt: skip
        pitch_mm = ISO_COARSE_PITCH_MM[int(size)]
    _check_positive(pitch_mm=pitch_mm, depth_mm=depth_mm, speed_rpm=speed_rpm)
    sst1 = retract_speed_rpm or speed_rpm
    rtp, bottom = retract_mm, -depth_mm
    lines = [
        f"; rigid tapping {thread} pitch {_fmt(pitch_mm)} mm, {_fmt(depth_mm)} mm, "
        f"{_fmt(speed_rpm)} rpm",
        "G90 G17 G94 G60",
        f"T{tool} M6",
        f"S{_fmt(speed_rpm)} M3 M8",
        f"G0 X{_fmt(start_xy[0])} Y{_fmt(start_xy[1])} Z{_fmt(rtp)}",
    ]
    if cycle == "CYCLE84":
        lines.append(
            f"MCALL CYCLE84({_fmt(rtp)}, 0, {_fmt(safety_mm)}, {_fmt(bottom)}, , 0, 3, , "
            f"{_fmt(pitch_mm)}, {_fmt(spindle_pos_deg)}, {_fmt(speed_rpm)}, {_fmt(sst1)})"
        )
    for k in range(n_holes):
        x, y = start_xy[0], start_xy[1] + k * pitch_between_mm
        if cycle == "G84" and k == 0:
            lines.append(f"G95 G98 G84 X{_fmt(x)} Y{_fmt(y)} Z{_fmt(bottom)} "
                         f"R{_fmt(safety_mm)} F{_fmt(pitch_mm)}")  # fmt: skip
        else:
            lines.append(f"X{_fmt(x)} Y{_fmt(y)}")
    lines += ["MCALL" if cycle == "CYCLE84" else "G80", "G0 Z50", "M5 M9", "M30"]
    return "\n".join(lines) + "\n"


PRODUCTION_TOOLS = """[tools.1]
kind = "drill"
diameter_mm = 8.5

[tools.2]
kind = "tap"
diameter_mm = 8
pitch_mm = 1.25

[tools.3]
kind = "end_mill"
diameter_mm = 10
flutes = 2
helix_deg = 30
max_chip_mm = 0.1

[tools.4]
kind = "drill"
diameter_mm = 8.5
"""
"""Tool table (TOML, docs/machine-file.md) of :func:`production_program` with ``end_mill=3``:
T1 and T4 drills of 8.5 mm, T2 an M8 x 1.25 tap, T3 a 10 mm 2-flute end mill."""

PRODUCTION_STOCK = "0,0,-40,210,210,0"
"""Stock (``--stock``: x0, y0, z0, x1, y1, z1 [mm]) of :func:`production_program`'s 16 x 16
grid of 12 mm, its top at Z 0."""


@dataclass(frozen=True)
class ProductionProgram:
    """A randomly drawn production program and what it must give (the truth of a soak).

    Attributes
    ----------
    text : str
        Program text.
    holes : int
        Drilling- and tapping-cycle calls: the holes a correct hole count finds [-].
    operations : tuple of str
        The operations in order (``drill CYCLE81 4 x 12 mm``, ``mill pocket``, ...).
    surface_z_mm : float
        Workpiece surface; the tool cannot cut while its tip is above it [mm].
    """

    text: str
    holes: int
    operations: tuple[str, ...]
    surface_z_mm: float = 0.0


def production_program(seed: int, *, operations: int = 8, tapping: bool = True,
                       end_mill: int | None = None) -> ProductionProgram:
    """Varied production from a seed: drilling, peck drilling, tapping, milling entries and
    contours, tool changes, speed changes, dwells and air moves, in random order.

    Parameters
    ----------
    seed : int
        Seed of every choice; the same seed gives the same program.
    operations : int, default 8
        Number of operations [-].
    tapping : bool, default True
        Include rigid tapping (CYCLE84) among the choices.
    end_mill : int, optional
        T number of an end mill: the milling operations change to it (``T.. M6``, 3000 rpm,
        0.05 mm per tooth of a 2-flute cutter: 300 mm/min) and back to the drilling tool
        after, and a tool change alternates between two drills (T1, T4; T2 stays the tap);
        simulate with a tool table and a stock so they cut (``--tools``,
        ``--stock 0,0,-40,210,210,0``). Without it the drill makes the milling moves (the
        drilling model gives them no milling load: the original soak).

    Returns
    -------
    ProductionProgram

    Notes
    -----
    Every hole is drilled at a fresh X/Y of a 12 mm grid (no hole twice); milling enters with
    a straight plunge (``G1 Z``), a ramp or a helix and then follows a contour at depth, which
    no correct hole count takes for a hole. Speeds 1200-3200 rpm, feeds 0.08-0.2 mm/rev,
    hole depths 4-20 mm, tapping M6-M10 at 300-500 rpm.
    """
    if operations < 1:
        raise ConfigError(f"operations must be >= 1, not {operations}")
    rng = np.random.default_rng(seed)
    cells = [(12.0 * (i + 1), 12.0 * (j + 1)) for i in range(16) for j in range(16)]
    order = rng.permutation(len(cells))
    free = [cells[k] for k in order.tolist()]
    lines = [f"; production draw {seed}", "G90 G17 G94 G60", "T1 M6"]
    speed = float(rng.choice([1600.0, 2000.0, 2400.0, 2800.0]))
    lines.append(f"S{_fmt(speed)} M3 M8")
    ops: list[str] = []
    holes = 0
    tool = 1
    kinds = ["drill", "peck", "mill", "ramp", "helix", "speed", "tool", "air"]
    if tapping:
        kinds.append("tap")
    for k_op in range(operations):
        # production drills: the first operation drills (the simulator's drilling model
        # also carries the milling passes as air cuts, see docs/simulator.md)
        kind = "drill" if k_op == 0 else str(rng.choice(kinds))
        if kind in ("drill", "peck") and len(free) >= 6:
            n = int(rng.integers(2, 6))
            depth = float(rng.choice([4.0, 8.0, 12.0, 16.0, 20.0]))
            speed = float(rng.choice([1200.0, 1800.0, 2400.0, 3200.0]))
            feed = round(speed * float(rng.uniform(0.08, 0.2)), 0)
            pos = [free.pop() for _ in range(n)]
            lines += [f"S{_fmt(speed)} M3", f"F{_fmt(feed)}",
                      f"G0 X{_fmt(pos[0][0])} Y{_fmt(pos[0][1])} Z10"]
            if kind == "drill":
                lines.append(f"MCALL CYCLE81(10, 0, 2, {_fmt(-depth)})")
            else:
                lines.append(f"MCALL CYCLE83(10, 0, 2, {_fmt(-depth)}, , , "
                             f"{_fmt(max(depth / 3, 2.0))}, 0, 0, 0, 1, 1)")
            lines += [f"X{_fmt(x)} Y{_fmt(y)}" for x, y in pos]
            lines += ["MCALL", "G0 Z10"]
            holes += n
            ops.append(f"{kind} {'CYCLE81' if kind == 'drill' else 'CYCLE83'} {n} x "
                       f"{_fmt(depth)} mm at {_fmt(speed)} rpm")
        elif kind == "tap" and len(free) >= 4:
            n = int(rng.integers(1, 4))
            size = int(rng.choice([6, 8, 10]))
            sst = float(rng.choice([300.0, 400.0, 500.0]))
            pos = [free.pop() for _ in range(n)]
            lines += ["T2 M6", f"S{_fmt(sst)} M3",
                      f"G0 X{_fmt(pos[0][0])} Y{_fmt(pos[0][1])} Z10",
                      f"MCALL CYCLE84(10, 0, 2, -12, , 0, 3, , "
                      f"{_fmt(ISO_COARSE_PITCH_MM[size])}, 0, {_fmt(sst)}, {_fmt(sst)})"]
            lines += [f"X{_fmt(x)} Y{_fmt(y)}" for x, y in pos]
            lines += ["MCALL", "G0 Z10", "T1 M6", f"S{_fmt(speed)} M3"]
            tool = 1
            holes += n
            ops.append(f"tap M{size} {n} x 12 mm at {_fmt(sst)} rpm")
        elif kind in ("mill", "ramp", "helix"):
            x0, y0 = float(rng.uniform(20, 150)), float(rng.uniform(20, 150))
            w, h = float(rng.uniform(10, 40)), float(rng.uniform(10, 40))
            d = float(rng.choice([0.5, 1.0, 2.0]))
            f = float(rng.choice([200.0, 400.0, 800.0]))
            if end_mill is not None:
                f = {200.0: 200.0, 400.0: 300.0, 800.0: 400.0}[f]  # no extra random draw
                lines += ["G0 Z50", f"T{end_mill} M6", "S3000 M3"]
            lines.append(f"G0 X{_fmt(x0)} Y{_fmt(y0)} Z2")
            if kind == "mill":  # straight plunge, then the contour at depth
                lines.append(f"G1 Z{_fmt(-d)} F100")
            elif kind == "ramp":
                lines.append(f"G1 X{_fmt(x0 + w)} Z{_fmt(-d)} F{_fmt(f)}")
                lines.append(f"G1 X{_fmt(x0)} F{_fmt(f)}")
            else:  # one helical turn of radius 3 mm down to the depth
                lines.append(f"G1 X{_fmt(x0 + 3)} F{_fmt(f)}")
                lines.append(f"G2 X{_fmt(x0 + 3)} Y{_fmt(y0)} Z{_fmt(-d)} I-3 J0")
                lines.append(f"G1 X{_fmt(x0)} Y{_fmt(y0)}")
            lines += [f"G1 X{_fmt(x0 + w)} F{_fmt(f)}", f"G1 Y{_fmt(y0 + h)}",
                      f"G1 X{_fmt(x0)}", f"G1 Y{_fmt(y0)}", "G0 Z10"]
            if end_mill is not None:  # back to the drilling tool at its speed
                lines += ["G0 Z50", f"T{tool} M6", f"S{_fmt(speed)} M3"]
            ops.append(f"{kind} contour {_fmt(w)} x {_fmt(h)} mm at {_fmt(d)} mm")
        elif kind == "speed":
            speed = float(rng.choice([800.0, 1600.0, 2400.0, 3600.0, 4800.0]))
            lines += [f"S{_fmt(speed)} M3", f"G4 F{_fmt(float(rng.uniform(0.5, 2.0)))}"]
            ops.append(f"speed {_fmt(speed)} rpm")
        elif kind == "tool":
            if end_mill is None:
                tool = 3 - tool if tool in (1, 2) else 1
            else:  # a second drill (T4): T2 is the tap, the end mill has its own number
                tool = 5 - tool if tool in (1, 4) else 1
            lines += ["G0 Z50", "M5", f"T{tool} M6", f"S{_fmt(speed)} M3", "G4 F1"]
            ops.append(f"tool change T{tool}")
        else:
            lines.append(f"G0 X{_fmt(float(rng.uniform(0, 200)))} "
                         f"Y{_fmt(float(rng.uniform(0, 200)))} Z{_fmt(float(rng.uniform(5, 50)))}")
            ops.append("air move")
    lines += ["G0 Z50", "M5 M9", "M30"]
    return ProductionProgram("\n".join(lines) + "\n", holes, tuple(ops))


@dataclass(frozen=True)
class _AdaptiveSlot:
    """The adaptive feed's closed-loop part: program, tool table, stock, hidden hardness."""

    program: str
    tools: str
    stock: str
    hardness_along_x: tuple[tuple[float, float], ...]
    target_nm: float


ADAPTIVE_SLOT = _AdaptiveSlot(
    program="""G90 G17 G94 G64
T2 M6
S3000 M3
G0 X-12 Y20 Z5
G0 Z-2
G1 X110 F450
G0 Z20
G0 X0 Y0
M30
""",
    tools=('[tools.2]\nkind = "end_mill"\ndiameter_mm = 16\nflutes = 2\nhelix_deg = 30\n'
           'max_chip_mm = 0.2\n'),
    stock="0,0,-30,150,40,0",
    hardness_along_x=((-100.0, 1.0), (40.0, 1.15), (80.0, 0.95)),
    target_nm=2.6)
"""A 16 mm slot 2 mm deep in AISI 1045 at a conservative F450 (3000 rpm, 0.075 mm/tooth:
2.38 Nm by the closed form at hardness 1, Altintas eq. 2.47), hidden hardness x 1.0 / 1.15 /
0.95 along X, target 2.6 Nm: the adaptive feed's closed-loop test and benchmark
(tests/usecases/test_adaptive_closed_loop.py, benchmarks/bench_adaptive_loop.py)."""
