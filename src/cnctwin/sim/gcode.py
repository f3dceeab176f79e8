"""Part programs: a G-code subset of SINUMERIK 840D sl (and its ISO dialect) parsed into blocks.

:func:`parse_program` turns program text into a :class:`Program` of :class:`Block` objects with
all modal state resolved: absolute target positions (G90/G91), arc centres, the active feed
(G94 mm/min or G95 mm/rev), spindle speed and direction, the selected tool, and drilling /
tapping cycles expanded into a :class:`DrillCycle` description (retraction plane, reference
plane, safety plane, final depth, pecks, pitch). The interpolator
(:mod:`cnctwin.sim.interpolator`) turns the blocks into motion.

Supported words
---------------
``N`` (block number, ignored), ``G0 G1 G2 G3 G4 G9 G17 G40 G49 G53 G54..G59 G500 G60 G64 G641
G642 G71 G710 G80 G81 G83 G84 G90 G91 G94 G95 G98 G99``, ``M2 M3 M4 M5 M6 M8 M9 M17 M30``,
``T D S F``, axes ``X Y Z A B C``, arc centre ``I J`` (incremental from the start point, the
SINUMERIK default), arc radius ``CR=`` (``R`` in ISO style), ISO cycle words ``R Q P``, the
SINUMERIK cycles ``CYCLE81 CYCLE83 CYCLE84`` (direct or modal via ``MCALL``), comments ``;...``
and ``(...)``. ``G18``/``G19`` and anything else raise :class:`~cnctwin.exceptions.GCodeError`
naming the line.

Notes
-----
SINUMERIK cycle parameters are positional, after Siemens, *SINUMERIK 840D sl/840D/840Di sl/
840Di/810D Cycles, Programming Manual* 04/2006 ("Drilling, centering - CYCLE81", "Deep-hole
drilling - CYCLE83", "Rigid tapping - CYCLE84"):

* ``CYCLE81(RTP, RFP, SDIS, DP, DPR)``: retraction plane (abs.), reference plane (abs.),
  safety clearance (no sign), final depth (abs.), final depth relative to RFP (no sign). If both
  DP and DPR are given, DPR wins. Sequence: G0 to RFP+SDIS, G1 to depth with the F of the
  calling program, G0 to RTP.
* ``CYCLE83(RTP, RFP, SDIS, DP, DPR, FDEP, FDPR, DAM, DTB, DTS, FRF, VARI, ...)``: first depth
  (abs. or relative), degression DAM, dwell at depth DTB and at the start point DTS (> 0 s,
  < 0 revolutions), feed factor of the first infeed FRF (0.001..1), VARI 0 chip breaking
  (retract 1 mm with G1) or 1 swarf removal (G0 to RFP+SDIS, G0 back to the last depth minus an
  anticipation distance of 0.6 mm up to 30 mm depth, depth/50 above, at most 7 mm).
  Parameter list also summarised at http://doc.i5cnc.com/article.php?id=512.
* ``CYCLE84(RTP, RFP, SDIS, DP, DPR, DTB, SDAC, MPIT, PIT, POSS, SST, SST1, ...)``: dwell at
  thread depth DTB, spindle direction after the cycle SDAC (3, 4, 5), thread size MPIT (3..48
  for M3..M48, ISO 261 coarse pitch) or pitch PIT [mm] (sign = hand), spindle position for the
  oriented stop POSS [deg], tapping speed SST and retraction speed SST1 [rpm] (0: SST). Rigid
  tapping interpolates the spindle with Z; no F is programmed.

ISO cycles (Fanuc-style, available on SINUMERIK in ISO dialect mode): ``G81 X Y Z R F``,
``G83 ... Q`` (peck increment, full retract to R), ``G84 ... F`` (F is the pitch under G95,
the feed under G94 so pitch = F/S), return to the initial level (G98, default) or R (G99),
cancelled by ``G80`` or any of G0..G3. Under G91, R is relative to the initial level and Z
relative to R.

Arc radius consistency tolerance follows SINUMERIK MD21000 ``CIRCLE_ERROR_CONST`` (0.01 mm) and
MD21010 ``CIRCLE_ERROR_FACTOR`` (0.001): ``|r_end - r_start| <= max(0.01, 0.001 r)``.
Spindle programming: ``G4 F..`` dwells seconds, ``G4 S..`` spindle revolutions (SINUMERIK
Fundamentals, "Dwell time (G4)"). The exact-stop mode defaults to G60 (the SINUMERIK reset
value); program ``G64`` for continuous-path mode with look-ahead.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from cnctwin.exceptions import GCodeError

__all__ = [
    "BLOCK_KINDS",
    "ISO_COARSE_PITCH_MM",
    "Block",
    "DrillCycle",
    "Program",
    "parse_program",
]

BLOCK_KINDS: frozenset[str] = frozenset(
    {
        "rapid",
        "linear",
        "arc_cw",
        "arc_ccw",
        "dwell",
        "spindle",
        "tool_change",
        "drill_cycle",
        "tap_cycle",
        "cycle_cancel",
        "program_end",
        "set",
    }
)
"""Values of :attr:`Block.kind`."""

ISO_COARSE_PITCH_MM: dict[int, float] = {
    3: 0.5,
    4: 0.7,
    5: 0.8,
    6: 1.0,
    8: 1.25,
    10: 1.5,
    12: 1.75,
    14: 2.0,
    16: 2.0,
    18: 2.5,
    20: 2.5,
    22: 2.5,
    24: 3.0,
    27: 3.0,
    30: 3.5,
    33: 3.5,
    36: 4.0,
    39: 4.0,
    42: 4.5,
    45: 4.5,
    48: 5.0,
}
"""ISO 261 metric coarse thread pitch [mm] by nominal diameter [mm] (CYCLE84 ``MPIT``)."""

AXIS_LETTERS = ("X", "Y", "Z", "A", "B", "C")
_ADDRESSES = frozenset({"N", "G", "M", "T", "D", "S", "F", "I", "J", "K", "R", "Q", "P", "CR"})
_ADDRESSES_ALL = _ADDRESSES | frozenset(AXIS_LETTERS)
_G_NOOP = frozenset({"40", "49", "53", "54", "55", "56", "57", "58", "59", "500", "71", "710"})
_G_KNOWN = _G_NOOP | frozenset(
    {"0", "1", "2", "3", "4", "9", "17", "18", "19", "60", "64", "641", "642", "80", "81", "83",
     "84", "90", "91", "94", "95", "98", "99"}
)  # fmt: skip
_M_KNOWN = frozenset({"2", "3", "4", "5", "6", "8", "9", "17", "30"})
_CYCLE_ARGS = {
    "CYCLE81": ("RTP", "RFP", "SDIS", "DP", "DPR"),
    "CYCLE83": ("RTP", "RFP", "SDIS", "DP", "DPR", "FDEP", "FDPR", "DAM", "DTB", "DTS", "FRF",
                "VARI", "_AXN", "_MDEP", "_VRT", "_DTD", "_DIS1"),
    "CYCLE84": ("RTP", "RFP", "SDIS", "DP", "DPR", "DTB", "SDAC", "MPIT", "PIT", "POSS", "SST",
                "SST1", "_AXN", "_PTAB", "_TECHNO", "_VARI", "_DAM", "_VRT"),
}  # fmt: skip
_CYCLE_RE = re.compile(r"\b(CYCLE\d+)\s*\(([^()]*)\)")
_COMMENT_RE = re.compile(r"\([^()]*\)")
_WORD_RE = re.compile(r"\s*([A-Z]+)\s*(=?)\s*([-+]?(?:\d+\.?\d*|\.\d+))")
_KEYWORD_RE = re.compile(r"\s*(MCALL|@CYCLE)\b")
_NUM_RE = re.compile(r"^[-+]?(?:\d+\.?\d*|\.\d+)(?:E[-+]?\d+)?$")


@dataclass(frozen=True)
class DrillCycle:
    """A drilling or tapping cycle resolved to planes and depths (all absolute, machine Z) [mm].

    Attributes
    ----------
    name : str
        ``"CYCLE81"``, ``"CYCLE83"``, ``"CYCLE84"``, ``"G81"``, ``"G83"`` or ``"G84"``.
    kind : str
        ``"drill"``, ``"peck"`` or ``"tap"``.
    z_retract_mm : float
        Retraction plane: RTP, or the ISO return level (initial level under G98, R under G99).
    z_ref_mm : float
        Reference plane (workpiece surface): RFP, or R for ISO cycles.
    z_safety_mm : float
        Plane where feed starts: RFP + SDIS, or R for ISO cycles.
    z_bottom_mm : float
        Final drilling / thread depth.
    first_depth_mm : float or None
        Peck drilling: depth of the first infeed below the reference plane (relative, > 0).
    degression_mm : float
        Peck drilling: CYCLE83 ``DAM``, or the constant ISO ``Q`` increment.
    min_infeed_mm : float
        Peck drilling: smallest infeed (CYCLE83: ``DAM``; ISO: ``Q``).
    feed_factor_first : float
        Feed factor of the first infeed (CYCLE83 ``FRF``), 1 otherwise.
    swarf_removal : bool
        Peck drilling: True for a full retract after each infeed (VARI=1, ISO G83), False for
        chip breaking (VARI=0: 1 mm retract).
    dwell_bottom_s, dwell_bottom_rev : float or None
        Dwell at final depth in seconds or spindle revolutions.
    dwell_top_s, dwell_top_rev : float or None
        Dwell at the safety plane between pecks (CYCLE83 ``DTS``).
    pitch_mm : float or None
        Tapping: thread pitch [mm/rev], positive for a right-hand thread (spindle M3 going in).
    tap_speed_rpm, retract_speed_rpm : float or None
        Tapping: spindle speed going in and coming out [rpm] (magnitudes).
    spindle_pos_deg : float
        Tapping: oriented-stop position before tapping (CYCLE84 ``POSS``) [deg].
    dir_after : int or None
        Tapping: spindle direction after the cycle (+1 M3, -1 M4, 0 M5; None = as before).
    args : tuple
        Raw positional arguments (SINUMERIK) or ISO words, for reference.
    """

    name: str
    kind: str
    z_retract_mm: float
    z_ref_mm: float
    z_safety_mm: float
    z_bottom_mm: float
    first_depth_mm: float | None = None
    degression_mm: float = 0.0
    min_infeed_mm: float = 0.0
    feed_factor_first: float = 1.0
    swarf_removal: bool = True
    dwell_bottom_s: float | None = None
    dwell_bottom_rev: float | None = None
    dwell_top_s: float | None = None
    dwell_top_rev: float | None = None
    pitch_mm: float | None = None
    tap_speed_rpm: float | None = None
    retract_speed_rpm: float | None = None
    spindle_pos_deg: float = 0.0
    dir_after: int | None = None
    args: tuple[float | None, ...] = ()

    @property
    def call_path(self) -> str:
        """Path of the cycle as the edge device reports it (``/_CYCLES_DIR/_CYCLE81``)."""
        name = {"G81": "CYCLE81", "G83": "CYCLE83", "G84": "CYCLE84"}.get(self.name, self.name)
        return f"/_CYCLES_DIR/_{name}"


@dataclass(frozen=True)
class Block:
    """One executable program line with its modal state resolved.

    Attributes
    ----------
    line : int
        1-based line number in the program text.
    text : str
        The source line as written.
    kind : str
        One of :data:`BLOCK_KINDS`. A block that moves is a motion kind even if it also sets the
        spindle or feed; blocks that execute a drilling cycle are ``drill_cycle``/``tap_cycle``.
    words : dict
        Raw words, address -> values as written (``{"G": ("0", "90"), "X": ("10",)}``).
    target : dict
        Absolute end position of the axes programmed in this block, axis letter -> [mm]/[deg].
        For cycle blocks, the hole position (X, Y) where the cycle runs.
    start : dict
        Absolute position of every axis known to the parser before the block [mm]/[deg].
    center : tuple of float or None
        Arc centre (X, Y), absolute [mm].
    radius_mm : float or None
        Arc radius [mm].
    plane : str
        Working plane, always ``"G17"``.
    motion : str
        Active motion group G code (``"G0"``..``"G3"``): the IPO G code for events.
    feed_mode : str
        ``"G94"`` (mm/min) or ``"G95"`` (mm/rev).
    feedrate_mm_min : float or None
        Active path feed under G94 [mm/min].
    feed_mm_per_rev : float or None
        Active feed per revolution under G95 [mm/rev] (converted with ``speed_rpm``).
    speed_rpm : float or None
        Programmed spindle speed S (magnitude) [rpm].
    spindle_dir : int
        Programmed spindle direction: +1 (M3), -1 (M4), 0 (M5 / not started).
    spindle_cmd : bool
        True when the block programs the spindle (S, M3, M4 or M5).
    tool : int or None
        Selected tool (T), modal.
    tool_change : bool
        True when the block contains M6 (the selected tool becomes active).
    dwell_s, dwell_rev : float or None
        Dwell in seconds (``G4 F``) or spindle revolutions (``G4 S``).
    cycle : DrillCycle or None
        Cycle executed by this block at ``target``.
    exact_stop : bool
        True when the path must stop at the end of this block (G60 modal or G9).
    offset : int
        Character offset of the line in the program text (SeekOffset of events).
    """

    line: int
    text: str
    kind: str
    words: dict[str, tuple[str, ...]] = field(default_factory=dict, compare=False)
    target: dict[str, float] = field(default_factory=dict)
    start: dict[str, float] = field(default_factory=dict)
    center: tuple[float, float] | None = None
    radius_mm: float | None = None
    plane: str = "G17"
    motion: str = "G0"
    feed_mode: str = "G94"
    feedrate_mm_min: float | None = None
    feed_mm_per_rev: float | None = None
    speed_rpm: float | None = None
    spindle_dir: int = 0
    spindle_cmd: bool = False
    tool: int | None = None
    tool_change: bool = False
    dwell_s: float | None = None
    dwell_rev: float | None = None
    cycle: DrillCycle | None = None
    exact_stop: bool = True
    offset: int = 0


@dataclass
class Program:
    """A parsed part program.

    Attributes
    ----------
    blocks : list of Block
        Executable blocks in program order (blank and comment-only lines are not blocks).
    name : str
        Program name (used for the main-program call path of events).
    text : str
        The source text.
    """

    blocks: list[Block]
    name: str = "program"
    text: str = ""

    def to_text(self) -> str:
        """Program text rebuilt from the blocks (comment-only and blank lines dropped).

        Returns
        -------
        str
            One line per block, in order, ending with a newline; :func:`parse_program` accepts
            it and yields blocks with the same content (line numbers renumbered).
        """
        return "".join(b.text.rstrip("\n") + "\n" for b in self.blocks)

    @property
    def call_path(self) -> str:
        """Main-program path as the edge device reports it (``/_N_MPF_DIR/_N_<NAME>_MPF``)."""
        safe = re.sub(r"[^A-Za-z0-9_]", "_", self.name).upper()
        return f"/_N_MPF_DIR/_N_{safe}_MPF"


@dataclass
class _State:
    position: dict[str, float]
    motion: str = "G0"
    absolute: bool = True
    feed_mode: str = "G94"
    feedrate_mm_min: float | None = None
    feed_mm_per_rev: float | None = None
    speed_rpm: float | None = None
    spindle_dir: int = 0
    tool: int | None = None
    exact_stop: bool = True
    return_initial: bool = True  # G98
    iso_cycle: str | None = None  # "G81" / "G83" / "G84"
    iso_words: dict[str, float] = field(default_factory=dict)
    mcall: tuple[str, tuple[float | None, ...]] | None = None


def _err(msg: str, line: int, text: str) -> GCodeError:
    return GCodeError(msg, line=line, text=text)


def _split_words(code: str, line: int, text: str) -> list[tuple[str, str]]:
    """Tokenise an upper-case, comment-free line into (address, value) pairs."""
    words: list[tuple[str, str]] = []
    pos = 0
    n = len(code)
    while pos < n:
        if code[pos].isspace():
            pos += 1
            continue
        kw = _KEYWORD_RE.match(code, pos)
        if kw:
            words.append((kw.group(1), ""))
            pos = kw.end()
            continue
        m = _WORD_RE.match(code, pos)
        if not m:
            bad = code[pos:].split()[0] if code[pos:].split() else code[pos:]
            raise _err(
                f"cannot read {bad!r}: expected words like X10.5, F400, CR=5, CYCLE81(...) "
                "(supported subset: see cnctwin.sim.gcode)",
                line,
                text,
            )
        addr = m.group(1)
        if addr not in _ADDRESSES_ALL:
            raise _err(
                f"unknown word {addr}{m.group(3)!s}: supported addresses are "
                f"{', '.join(sorted(_ADDRESSES_ALL))}",
                line,
                text,
            )
        words.append((addr, m.group(3)))
        pos = m.end()
    return words


def _parse_args(raw: str, name: str, line: int, text: str) -> tuple[float | None, ...]:
    vals: list[float | None] = []
    if raw.strip() == "":
        return ()
    for item in raw.split(","):
        s = item.strip()
        if s == "":
            vals.append(None)
        elif _NUM_RE.match(s):
            vals.append(float(s))
        else:
            raise _err(f"{name} argument {s!r} is not a number (variables are not supported)",
                       line, text)  # fmt: skip
    n_max = len(_CYCLE_ARGS[name])
    if len(vals) > n_max:
        raise _err(f"{name} takes at most {n_max} arguments, got {len(vals)}", line, text)
    return tuple(vals)


def _arg(args: tuple[float | None, ...], name: str, key: str) -> float | None:
    idx = _CYCLE_ARGS[name].index(key)
    return args[idx] if idx < len(args) else None


def _dwell(v: float | None) -> tuple[float | None, float | None]:
    """SINUMERIK cycle dwell: > 0 seconds, < 0 revolutions."""
    if v is None or v == 0:
        return None, None
    return (v, None) if v > 0 else (None, -v)


def _siemens_cycle(
    name: str, args: tuple[float | None, ...], st: _State, line: int, text: str
) -> DrillCycle:
    rtp, rfp = _arg(args, name, "RTP"), _arg(args, name, "RFP")
    sdis = _arg(args, name, "SDIS") or 0.0
    dp, dpr = _arg(args, name, "DP"), _arg(args, name, "DPR")
    if rtp is None or rfp is None:
        raise _err(f"{name}: RTP (retraction plane) and RFP (reference plane) are required",
                   line, text)  # fmt: skip
    if sdis < 0:
        raise _err(f"{name}: SDIS must be given without sign (>= 0), got {sdis}", line, text)
    if dpr is not None and dpr != 0:
        if dpr < 0:
            raise _err(f"{name}: DPR must be given without sign (> 0), got {dpr}", line, text)
        bottom = rfp - dpr
    elif dp is not None:
        bottom = dp
    else:
        raise _err(f"{name}: final depth missing: give DP (absolute Z) or DPR (relative)",
                   line, text)  # fmt: skip
    safety = rfp + sdis
    if bottom >= rfp:
        raise _err(f"{name}: final depth Z={bottom:g} is not below the reference plane "
                   f"RFP={rfp:g}", line, text)  # fmt: skip
    if rtp < safety:
        raise _err(f"{name}: retraction plane RTP={rtp:g} is below RFP+SDIS={safety:g}",
                   line, text)  # fmt: skip
    common = {"z_retract_mm": rtp, "z_ref_mm": rfp, "z_safety_mm": safety,
              "z_bottom_mm": bottom, "args": args}  # fmt: skip
    if name == "CYCLE81":
        return DrillCycle(name=name, kind="drill", **common)  # type: ignore[arg-type]
    if name == "CYCLE83":
        fdep, fdpr = _arg(args, name, "FDEP"), _arg(args, name, "FDPR")
        if fdpr is not None and fdpr != 0:
            first = fdpr
        elif fdep is not None:
            first = rfp - fdep
        else:
            raise _err("CYCLE83: first drilling depth missing: give FDEP (abs.) or FDPR (rel.)",
                       line, text)  # fmt: skip
        if first <= 0:
            raise _err(f"CYCLE83: first drilling depth must be below RFP, got {first:g} mm",
                       line, text)  # fmt: skip
        dam = _arg(args, name, "DAM") or 0.0
        if dam < 0:
            raise _err("CYCLE83: DAM < 0 (degression in percent) is not supported", line, text)
        frf = _arg(args, name, "FRF")
        frf = 1.0 if frf is None or frf == 0 else frf
        if not 0.001 <= frf <= 1.0:
            raise _err(f"CYCLE83: FRF must be in 0.001..1, got {frf}", line, text)
        vari = _arg(args, name, "VARI") or 0.0
        if vari not in (0.0, 1.0):
            raise _err(f"CYCLE83: VARI must be 0 (chip breaking) or 1 (swarf removal), got "
                       f"{vari:g}", line, text)  # fmt: skip
        dtb_s, dtb_r = _dwell(_arg(args, name, "DTB"))
        dts_s, dts_r = _dwell(_arg(args, name, "DTS"))
        return DrillCycle(
            name=name, kind="peck", first_depth_mm=first, degression_mm=dam,
            min_infeed_mm=dam if dam > 0 else first, feed_factor_first=frf,
            swarf_removal=vari == 1.0, dwell_bottom_s=dtb_s, dwell_bottom_rev=dtb_r,
            dwell_top_s=dts_s, dwell_top_rev=dts_r, **common,  # type: ignore[arg-type]
        )  # fmt: skip
    # CYCLE84
    pit, mpit = _arg(args, name, "PIT"), _arg(args, name, "MPIT")
    if pit is not None and pit != 0:
        if not 0.001 <= abs(pit) <= 2000:
            raise _err(f"CYCLE84: PIT must be 0.001..2000 mm, got {pit}", line, text)
        pitch = pit
    elif mpit is not None and mpit != 0:
        size = round(abs(mpit))
        if size not in ISO_COARSE_PITCH_MM or abs(abs(mpit) - size) > 1e-9:
            sizes = ", ".join(str(k) for k in ISO_COARSE_PITCH_MM)
            raise _err(f"CYCLE84: MPIT {mpit:g} is not a metric coarse thread size ({sizes})",
                       line, text)  # fmt: skip
        pitch = math.copysign(ISO_COARSE_PITCH_MM[size], mpit)
    else:
        raise _err("CYCLE84: thread pitch missing: give PIT (mm) or MPIT (thread size)",
                   line, text)  # fmt: skip
    sst = _arg(args, name, "SST") or st.speed_rpm
    if sst is None or sst <= 0:
        raise _err("CYCLE84: tapping speed SST missing and no spindle speed S programmed",
                   line, text)  # fmt: skip
    sst1 = _arg(args, name, "SST1") or sst
    if sst1 < 0:
        raise _err(f"CYCLE84: SST1 must be >= 0, got {sst1}", line, text)
    sdac = _arg(args, name, "SDAC")
    dir_after: int | None
    if sdac is None or sdac == 0:
        dir_after = None
    elif sdac in (3.0, 4.0, 5.0):
        dir_after = {3.0: 1, 4.0: -1, 5.0: 0}[sdac]
    else:
        raise _err(f"CYCLE84: SDAC must be 3, 4 or 5, got {sdac:g}", line, text)
    dtb_s, dtb_r = _dwell(_arg(args, name, "DTB"))
    return DrillCycle(
        name=name, kind="tap", pitch_mm=pitch, tap_speed_rpm=sst, retract_speed_rpm=sst1,
        spindle_pos_deg=_arg(args, name, "POSS") or 0.0, dir_after=dir_after,
        dwell_bottom_s=dtb_s, dwell_bottom_rev=dtb_r, **common,  # type: ignore[arg-type]
    )  # fmt: skip


def _iso_cycle(name: str, st: _State, z_initial: float, line: int, text: str) -> DrillCycle:
    w = st.iso_words
    if "Z" not in w:
        raise _err(f"{name}: Z (hole bottom) missing in the cycle", line, text)
    if "R" not in w:
        raise _err(f"{name}: R (reference plane) missing in the cycle", line, text)
    if st.absolute:
        r_level, bottom = w["R"], w["Z"]
    else:  # Fanuc G91: R from the initial level, Z from R
        r_level = z_initial + w["R"]
        bottom = r_level + w["Z"]
    if bottom >= r_level:
        raise _err(f"{name}: hole bottom Z={bottom:g} is not below R={r_level:g}", line, text)
    if r_level > z_initial + 1e-9:
        raise _err(f"{name}: R={r_level:g} is above the initial level Z={z_initial:g}; "
                   "move Z above R before the cycle", line, text)  # fmt: skip
    ret = z_initial if st.return_initial else r_level
    args = tuple(w.get(k) for k in ("Z", "R", "Q", "P", "F"))
    common = {"z_retract_mm": ret, "z_ref_mm": r_level, "z_safety_mm": r_level,
              "z_bottom_mm": bottom, "args": args}  # fmt: skip
    dwell_s = w["P"] / 1000.0 if w.get("P") else None  # Fanuc P in ms
    if name == "G81":
        return DrillCycle(name=name, kind="drill", dwell_bottom_s=dwell_s, **common)  # type: ignore[arg-type]
    if name == "G83":
        q = w.get("Q")
        if q is None or q <= 0:
            raise _err("G83: peck increment Q missing or not positive", line, text)
        return DrillCycle(name=name, kind="peck", first_depth_mm=q, degression_mm=0.0,
                          min_infeed_mm=q, swarf_removal=True, dwell_bottom_s=dwell_s,
                          **common)  # type: ignore[arg-type]  # fmt: skip
    # G84 rigid tapping
    if st.speed_rpm is None or st.speed_rpm <= 0:
        raise _err("G84: spindle speed S must be programmed before rigid tapping", line, text)
    if "F" not in w:
        raise _err("G84: F missing (pitch under G95, feed under G94)", line, text)
    pitch = w["F"] if st.feed_mode == "G95" else w["F"] / st.speed_rpm
    hand = -1.0 if st.spindle_dir < 0 else 1.0
    return DrillCycle(name=name, kind="tap", pitch_mm=hand * pitch, tap_speed_rpm=st.speed_rpm,
                      retract_speed_rpm=st.speed_rpm, dwell_bottom_s=dwell_s, dir_after=None,
                      **common)  # type: ignore[arg-type]  # fmt: skip


def parse_program(
    text: str,
    *,
    name: str = "program",
    start_position: Mapping[str, float] | None = None,
    max_speed_rpm: float | None = None,
) -> Program:
    """Parse a part program (SINUMERIK subset, see the module docstring).

    Parameters
    ----------
    text : str
        Program text, one block per line.
    name : str, default "program"
        Program name.
    start_position : mapping, optional
        Axis letter -> position before the first block [mm]/[deg]; missing axes start at 0.
        Incremental (G91) moves and arcs are resolved from it.
    max_speed_rpm : float, optional
        Machine maximum spindle speed [rpm]; larger S words raise :class:`GCodeError`.

    Returns
    -------
    Program
        The blocks with modal state resolved to absolute coordinates.

    Raises
    ------
    GCodeError
        For unknown words, unsupported G/M codes, G18/G19, negative or zero feed, spindle speed
        above ``max_speed_rpm``, cycles without depth, arcs whose end point is not on the
        circle, motion or feed blocks without a feed. The error names the line.
    """
    pos0 = {ax: 0.0 for ax in AXIS_LETTERS}
    if start_position:
        for k, v in start_position.items():
            pos0[k.upper()] = float(v)
    st = _State(position=pos0)
    blocks: list[Block] = []
    offset = 0
    ended = False
    for lineno, raw_line in enumerate(text.splitlines(keepends=True), start=1):
        line_offset = offset
        offset += len(raw_line)
        src = raw_line.rstrip("\r\n")
        code = src.split(";", 1)[0].upper()
        cycles = _CYCLE_RE.findall(code)
        code = _CYCLE_RE.sub(" @CYCLE ", code)
        code = _COMMENT_RE.sub(" ", code)
        if "(" in code or ")" in code:
            raise _err("unbalanced parenthesis (comments are '( ... )' on one line)",
                       lineno, src)  # fmt: skip
        if not code.strip():
            continue
        if ended:
            raise _err("block after program end (M30/M2/M17)", lineno, src)
        words = _split_words(code, lineno, src)
        blk = _parse_block(words, cycles, st, lineno, src, line_offset, max_speed_rpm)
        if blk is None:
            continue
        blocks.append(blk)
        if blk.kind == "program_end":
            ended = True
    return Program(blocks=blocks, name=name, text=text)


def _num(value: str, addr: str, line: int, text: str) -> float:
    try:
        return float(value)
    except ValueError:  # pragma: no cover - regex guarantees a number
        raise _err(f"{addr}: {value!r} is not a number", line, text) from None


def _parse_block(
    words: list[tuple[str, str]],
    cycles: list[tuple[str, str]],
    st: _State,
    line: int,
    text: str,
    offset: int,
    max_speed_rpm: float | None,
) -> Block | None:
    raw: dict[str, list[str]] = {}
    for a, v in words:
        raw.setdefault(a, []).append(v)
    gcodes = [str(int(float(v))) if _NUM_RE.match(v) else v for v in raw.get("G", [])]
    mcodes = [str(int(float(v))) for v in raw.get("M", [])]
    for g in gcodes:
        if g in ("18", "19"):
            raise _err(f"G{g}: only G17 supported (XY working plane)", line, text)
        if g not in _G_KNOWN:
            raise _err(f"G{g} is not supported", line, text)
    for m in mcodes:
        if m not in _M_KNOWN:
            raise _err(f"M{m} is not supported (supported: M2 M3 M4 M5 M6 M8 M9 M17 M30)",
                       line, text)  # fmt: skip
    for addr, vals in raw.items():
        if addr not in ("G", "M", "@CYCLE") and len(vals) > 1:
            raise _err(f"address {addr} appears {len(vals)} times in one block", line, text)
    if "70" in gcodes:  # pragma: no cover - 70 not in _G_KNOWN
        raise _err("G70 (inch) is not supported; program in mm (G71)", line, text)

    def val(addr: str) -> float | None:
        v = raw.get(addr)
        return _num(v[0], addr, line, text) if v else None

    start = dict(st.position)
    # --- modal settings ---
    for g in gcodes:
        if g == "90":
            st.absolute = True
        elif g == "91":
            st.absolute = False
        elif g == "94":
            st.feed_mode = "G94"
        elif g == "95":
            st.feed_mode = "G95"
        elif g == "60":
            st.exact_stop = True
        elif g in ("64", "641", "642"):
            st.exact_stop = False
        elif g == "98":
            st.return_initial = True
        elif g == "99":
            st.return_initial = False
    f = val("F")
    is_dwell = "4" in gcodes
    iso_cycle_words = {"81", "83", "84"} & set(gcodes)
    if f is not None and not is_dwell:
        if f <= 0:
            raise _err(f"feed F must be positive, got {f:g}", line, text)
        if st.feed_mode == "G94":
            st.feedrate_mm_min = f
        else:
            st.feed_mm_per_rev = f
    s = val("S")
    spindle_cmd = False
    if s is not None and not is_dwell:
        if s < 0:
            raise _err(f"spindle speed S must not be negative, got {s:g}", line, text)
        if max_speed_rpm is not None and s > max_speed_rpm:
            raise _err(f"spindle speed S{s:g} exceeds the machine maximum {max_speed_rpm:g} rpm",
                       line, text)  # fmt: skip
        st.speed_rpm = s
        spindle_cmd = True
    if "6" in mcodes:  # the tool change stops the spindle; M3/M4 of the block restart it
        st.spindle_dir = 0
    for m in mcodes:
        if m == "3":
            st.spindle_dir, spindle_cmd = 1, True
        elif m == "4":
            st.spindle_dir, spindle_cmd = -1, True
        elif m == "5":
            st.spindle_dir, spindle_cmd = 0, True
    t = val("T")
    if t is not None:
        if t < 0 or t != int(t):
            raise _err(f"tool number T must be a non-negative integer, got {t:g}", line, text)
        st.tool = int(t)
    tool_change = "6" in mcodes
    if tool_change and st.tool is None:
        raise _err("M6 without a selected tool: program T<n> first", line, text)

    # --- motion group and cycles ---
    motion_g = [g for g in gcodes if g in ("0", "1", "2", "3")]
    if len(motion_g) > 1:
        raise _err(f"more than one motion G code in a block: {motion_g}", line, text)
    if motion_g:
        st.motion = "G" + motion_g[0]
        st.iso_cycle = None  # group-01 codes cancel ISO canned cycles
    cancel = "80" in gcodes
    if cancel:
        st.iso_cycle = None
    if len(iso_cycle_words) > 1:
        raise _err("more than one drilling cycle G code in a block", line, text)
    if iso_cycle_words:
        st.iso_cycle = "G" + iso_cycle_words.pop()
        st.iso_words = {}
    if st.iso_cycle is not None:
        for k in ("Z", "R", "Q", "P", "F"):
            iv = val(k)
            if iv is not None:
                st.iso_words[k] = iv
    is_mcall = "MCALL" in raw
    if is_mcall:
        if cycles:
            st.mcall = (cycles[0][0], _parse_args(cycles[0][1], _check_cycle(cycles[0][0], line,
                        text), line, text))  # fmt: skip
            cycles = []
        else:
            st.mcall = None
    if len(cycles) > 1:
        raise _err("more than one cycle call in a block", line, text)

    # --- axis targets ---
    target: dict[str, float] = {}
    axis_words = {ax: val(ax) for ax in AXIS_LETTERS if ax in raw}
    in_iso = st.iso_cycle is not None and not motion_g
    for ax, av in axis_words.items():
        assert av is not None
        if in_iso and ax == "Z":
            continue  # Z of an ISO cycle is the hole bottom, not a move
        target[ax] = av if st.absolute else st.position[ax] + av
    common = {"line": line, "text": text, "words": {k: tuple(v) for k, v in raw.items()},
              "start": start, "motion": st.motion, "feed_mode": st.feed_mode,
              "feedrate_mm_min": st.feedrate_mm_min, "feed_mm_per_rev": st.feed_mm_per_rev,
              "speed_rpm": st.speed_rpm, "spindle_dir": st.spindle_dir,
              "spindle_cmd": spindle_cmd, "tool": st.tool, "tool_change": tool_change,
              "offset": offset}  # fmt: skip

    def finish(kind: str, **kw: object) -> Block:
        exact = st.exact_stop or "9" in gcodes
        st.position.update(target)
        return Block(kind=kind, target=target, exact_stop=exact, **common, **kw)  # type: ignore[arg-type]

    if any(m in mcodes for m in ("2", "30", "17")):
        if target or cycles:
            raise _err("program end (M2/M30/M17) must be in a block without motion", line, text)
        return finish("program_end")
    if is_dwell:
        if target or cycles:
            raise _err("G4 (dwell) must be programmed in its own block", line, text)
        fv, sv = val("F"), val("S")
        if (fv is None) == (sv is None):
            raise _err("G4 needs exactly one of F (seconds) or S (spindle revolutions)",
                       line, text)  # fmt: skip
        if (fv is not None and fv < 0) or (sv is not None and sv < 0):
            raise _err("G4 dwell must not be negative", line, text)
        return finish("dwell", dwell_s=fv, dwell_rev=sv)

    # cycle execution: direct call, MCALL at a position, or ISO cycle
    cyc: DrillCycle | None = None
    if cycles:
        cname = _check_cycle(cycles[0][0], line, text)
        cyc = _siemens_cycle(cname, _parse_args(cycles[0][1], cname, line, text), st, line, text)
    elif st.mcall is not None and not is_mcall and target and not motion_g:
        pass  # handled below (MCALL applies after positioning with the modal G0/G1)
    elif in_iso and (target or iso_cycle_words or "Z" in axis_words or "R" in raw):
        z_init = st.position["Z"]
        cyc = _iso_cycle(st.iso_cycle or "", st, z_init, line, text)
    if cyc is None and st.mcall is not None and not is_mcall and target:
        cname, cargs = st.mcall
        cyc = _siemens_cycle(_check_cycle(cname, line, text), cargs, st, line, text)
        if "Z" in target:
            raise _err("Z must not be programmed in a block that calls a modal cycle (MCALL)",
                       line, text)  # fmt: skip
    if cyc is not None:
        if any(ax in target for ax in ("A", "B", "C")):
            raise _err("rotary axes cannot move in a cycle block", line, text)
        if cyc.kind != "tap" and _feed_missing(st):
            raise _err(f"{cyc.name}: no feed programmed (F under {st.feed_mode})", line, text)
        if cyc.kind != "tap" and st.spindle_dir == 0:
            raise _err(f"{cyc.name}: spindle not started (M3/M4) before drilling", line, text)
        kind = "tap_cycle" if cyc.kind == "tap" else "drill_cycle"
        blk = finish(kind, cycle=cyc)
        st.position["Z"] = cyc.z_retract_mm
        return blk

    if cancel and not target:
        return finish("cycle_cancel")
    if target:
        if st.motion in ("G2", "G3"):
            return _arc_block(st, start, target, val, finish, line, text)
        if st.motion == "G1" and _feed_missing(st):
            raise _err("G1 without feed: program F (mm/min under G94, mm/rev under G95)",
                       line, text)  # fmt: skip
        return finish("rapid" if st.motion == "G0" else "linear")
    if any(k in raw for k in ("I", "J", "K", "CR")):
        raise _err("arc words (I, J, CR) without an end point", line, text)
    if tool_change:
        return finish("tool_change")
    if spindle_cmd:
        return finish("spindle")
    if cancel:
        return finish("cycle_cancel")
    return finish("set")


def _check_cycle(name: str, line: int, text: str) -> str:
    if name not in _CYCLE_ARGS:
        raise _err(f"{name} is not supported (supported: {', '.join(_CYCLE_ARGS)})", line, text)
    return name


def _feed_missing(st: _State) -> bool:
    return (st.feed_mode == "G94" and st.feedrate_mm_min is None) or (
        st.feed_mode == "G95" and st.feed_mm_per_rev is None
    )


def _arc_block(
    st: _State,
    start: dict[str, float],
    target: dict[str, float],
    val: Callable[[str], float | None],
    finish: Callable[..., Block],
    line: int,
    text: str,
) -> Block:
    if _feed_missing(st):
        raise _err(f"{st.motion} without feed: program F", line, text)
    x0, y0 = start["X"], start["Y"]
    x1, y1 = target.get("X", x0), target.get("Y", y0)
    i, j, cr = val("I"), val("J"), val("CR")
    r_iso = val("R")
    if cr is None and r_iso is not None:
        cr = r_iso
    if val("K") is not None:
        raise _err("K is not allowed in G17 (arc centre in XY is given by I and J)", line, text)
    if any(ax in target for ax in ("A", "B", "C")):
        raise _err("rotary axes cannot move in an arc block", line, text)
    cw = st.motion == "G2"
    if i is not None or j is not None:
        if cr is not None:
            raise _err("give either I/J (centre) or CR= (radius), not both", line, text)
        cx, cy = x0 + (i or 0.0), y0 + (j or 0.0)
        r0 = math.hypot(x0 - cx, y0 - cy)
        r1 = math.hypot(x1 - cx, y1 - cy)
        if r0 <= 0:
            raise _err("arc radius is zero (I and J both 0)", line, text)
        tol = max(0.01, 0.001 * r0)  # MD21000 CIRCLE_ERROR_CONST, MD21010 CIRCLE_ERROR_FACTOR
        if abs(r1 - r0) > tol:
            raise _err(f"arc end point is not on the circle: start radius {r0:.4f} mm, end radius"
                       f" {r1:.4f} mm (tolerance {tol:.4f} mm)", line, text)  # fmt: skip
        radius = r0
    elif cr is not None:
        chord = math.hypot(x1 - x0, y1 - y0)
        radius = abs(cr)
        if chord == 0:
            raise _err("a full circle cannot be programmed with CR=; use I/J", line, text)
        if chord > 2 * radius + max(0.01, 0.001 * radius):
            raise _err(f"arc radius {radius:g} mm too small for chord {chord:.4f} mm", line, text)
        h = math.sqrt(max(radius * radius - chord * chord / 4.0, 0.0))
        mx, my = (x0 + x1) / 2.0, (y0 + y1) / 2.0
        ux, uy = (x1 - x0) / chord, (y1 - y0) / chord
        # centre on the left of the chord for G3 short arcs, right for G2 short arcs
        side = 1.0 if (not cw) else -1.0
        if cr < 0:  # more than a semicircle
            side = -side
        cx, cy = mx - side * uy * h, my + side * ux * h
    else:
        raise _err(f"{st.motion} needs the centre (I, J) or the radius (CR=)", line, text)
    kind = "arc_cw" if cw else "arc_ccw"
    return finish(kind, center=(cx, cy), radius_mm=radius)
