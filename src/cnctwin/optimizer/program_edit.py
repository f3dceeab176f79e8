"""Write the optimized program: new F words, split blocks, every other word kept.

Only F changes. A motion block whose feed changes gets an explicit F (its old F word, if any,
is replaced); a block split where the engagement changes becomes several G1 blocks: the
inserted pieces carry only ``G1``, the coordinates of the split point and F, and a comment
``; cnctwin: line L piece k/m``; the original line, with its new F, is the last piece (its
target and every other word unchanged). Blocks whose feed the optimizer did not change but
which relied on a modal F (a drilling cycle after a milled contour) get their old F back
explicitly, so their feed is what it was.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from cnctwin.sim.gcode import Block, Program, parse_program

__all__ = ["Piece", "rewrite_program"]

_F_RE = re.compile(r"\bF\s*=?\s*[-+]?(?:\d+\.?\d*|\.\d+)", re.IGNORECASE)
_FEED_KINDS = ("linear", "arc_cw", "arc_ccw", "drill_cycle")


@dataclass(frozen=True)
class Piece:
    """One piece of a block with its feed.

    Attributes
    ----------
    end : dict or None
        Axis letter -> absolute end point [mm] of an inserted piece; None for the block's
        own (last) piece.
    feed : float
        Feed in the block's mode (mm/min under G94, mm/rev under G95).
    """

    end: Mapping[str, float] | None
    feed: float


def _fmt(v: float, decimals: int) -> str:
    s = f"{v:.{decimals}f}".rstrip("0").rstrip(".")
    return "0" if s in ("", "-0") else s


def _split_comment(text: str) -> tuple[str, str]:
    i = text.find(";")
    return (text, "") if i < 0 else (text[:i].rstrip(), text[i:])


def _with_feed(text: str, feed_word: str) -> str:
    code, comment = _split_comment(text.rstrip("\n"))
    code = _F_RE.sub("", code).rstrip()
    code = re.sub(r"\s{2,}", " ", code)
    return f"{code} {feed_word}" + (f" {comment}" if comment else "")


def _feed_word(blk: Block, feed: float) -> str:
    return f"F{_fmt(feed, 4 if blk.feed_mode == 'G95' else 1)}"


def _effective_feed(blk: Block) -> tuple[str, float | None]:
    if blk.feed_mode == "G95":
        return "G95", blk.feed_mm_per_rev
    return "G94", blk.feedrate_mm_min


def rewrite_program(program: Program, plan: Mapping[int, Sequence[Piece]]) -> str:
    """The program text with the planned feeds.

    Parameters
    ----------
    program : Program
        The parsed original (its ``text`` is rewritten line by line).
    plan : mapping
        Block index -> its pieces in order (one piece: only the F changes).

    Returns
    -------
    str
        Program text; :func:`~cnctwin.sim.gcode.parse_program` reads it.
    """
    lines = program.text.splitlines()
    by_line: dict[int, list[str]] = {}
    for bi, pieces in plan.items():
        blk = program.blocks[bi]
        out = []
        m = len(pieces)
        for k, p in enumerate(pieces, start=1):
            if p.end is None:
                out.append(_with_feed(lines[blk.line - 1], _feed_word(blk, p.feed)))
            else:
                coords = " ".join(f"{a}{_fmt(v, 4)}" for a, v in p.end.items())
                out.append(f"G1 {coords} {_feed_word(blk, p.feed)} ; cnctwin: line {blk.line} "
                           f"piece {k}/{m}")
        by_line[blk.line] = out
    restore: dict[int, str] = {}
    for _ in range(4):  # restore the modal F of blocks the plan does not change
        text = _assemble(lines, by_line, restore)
        new = parse_program(text, name=program.name)
        changed = _modal_mismatches(program, new, plan)
        if not changed:
            return text
        for blk in changed:
            restore[blk.line] = _feed_word(blk, _effective_feed(blk)[1] or 0.0)
    return _assemble(lines, by_line, restore)


def _assemble(lines: list[str], by_line: Mapping[int, list[str]],
              restore: Mapping[int, str]) -> str:
    out = []
    for i, text in enumerate(lines, start=1):
        if i in by_line:
            out.extend(by_line[i])
        elif i in restore:
            out.append(_with_feed(text, restore[i]))
        else:
            out.append(text)
    return "\n".join(out) + "\n"


def _modal_mismatches(old: Program, new: Program, plan: Mapping[int, Sequence[Piece]]
                      ) -> list[Block]:
    """Original blocks the plan leaves alone whose effective feed changed in the new text."""
    planned_lines = {old.blocks[bi].line for bi in plan}
    new_by_text: dict[int, Block] = {}
    # map new blocks back to old lines: inserted pieces carry "cnctwin: line"; the rest keep
    # their order
    old_iter = iter(old.blocks)
    for nb in new.blocks:
        if "; cnctwin: line" in nb.text:
            continue
        prev = next(old_iter, None)
        if prev is None:
            break
        new_by_text[prev.line] = nb
    out = []
    for ob in old.blocks:
        if ob.line in planned_lines or ob.kind not in _FEED_KINDS:
            continue
        match = new_by_text.get(ob.line)
        if match is None:
            continue
        a, b = _effective_feed(ob), _effective_feed(match)
        if a[0] != b[0] or (a[1] is None) != (b[1] is None) or (
                a[1] is not None and b[1] is not None and not math.isclose(a[1], b[1],
                                                                           rel_tol=1e-9)):
            out.append(ob)
    return out
