"""Per-hole load judge: a broken drill, a load that rose, a hole cut without load.

A drilling cycle repeats the same cut: the same tool, cycle, depth, speed and feed give the
same cutting torque to about 1 % (the material and the drill are the same; the flank wear of a
few holes adds less than 1 %, thesis §5.1: +28 % over 2676 holes). The judge keeps, for every
such **cut condition**, the reference of its first ``teach_holes`` holes (as Heidenhain AFC's
teach-in cut, per tool and cut) and judges each later hole of the same condition against it:

* ``breakage``: the torque over the last ``window_s`` of the cut (the drill fully engaged)
  falls below ``breakage_ratio`` of the reference: the drill broke in the hole (the cutting
  torque of a broken stub is ~10 % of the load; thesis simulator ``ToolBreakage``);
* ``no_load``: the whole cut is below ``breakage_ratio`` of the reference (a drill broken
  before the hole, a missing tool);
* ``load_rise``: the mean torque of the cut exceeds the reference by more than ``rise`` (a
  worn or chipped drill, harder material): ``rise`` 0.25 lies far above the healthy scatter
  and slow wear between holes, and below the rise of a worn-out drill;
* ``load_drop``: the mean torque is lower by more than ``drop`` (softer material, a wrong
  tool) where it is not a breakage;
* ``loose_tool``: a tap's current fluctuates while it is extracted (spindle reversed) more
  than ``loose_ratio`` times its reference (thesis §5.4, Fig. 5.10: a tap loose in its
  collet stick-slips on the way out; the simulator's ``LooseTool``: 1.7x at 500 rpm to 3x at
  300 rpm on the calibrated soak machine, where the healthy level itself grows with the speed;
  healthy taps of one condition scatter by ~5 %).

A load rise or drop is raised once, not at every hole (alarm management, ANSI/ISA-18.2: no
repeating alarm for one standing condition): the same condition's next holes alarm again
only if the load moves a further ``rise`` (``drop``) beyond the last alarm's, e.g. +25 % then
+50 % for a drill wearing out; the alarm re-arms when the load is back within half the
threshold. A hole that alarmed is not learned.

A condition is one (tool, cycle) with the depth within 0.5 mm, the speed within 1 % + 5 rpm
and the feed within 2 % + 2 mm/min of the first hole's (measured values scatter: a tapping
depth reads 11.7 or 11.8 mm): a change beyond that is a new cut and is taught anew.
The first hole of a condition is never judged against a reference (there is none), except:

* a drilling or tapping-cycle hole whose torque at the end of the cut (the drill or tap
  fully engaged, where it is at least the cut's mean: the entry cone or the tap's chamfer
  lowers the mean) falls below ``breakage_ratio`` of the cut's own mean broke in that hole;
* a drilling-cycle hole whose cutting torque stays below ``min_load_nm`` over the whole cut
  cut nothing;
* after a breakage of tool T, the rubbing of its stub is known (the torque of the holes after
  the break): a new cut condition of T whose first hole stays below ``1 / breakage_ratio``
  times that level is still the broken tool, not a new reference. A hole of T that cuts
  above it shows the tool was replaced: T is whole again.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from cnctwin.exceptions import ConfigError

__all__ = ["HoleLoadJudge", "HoleLoadVerdict"]


@dataclass(frozen=True)
class HoleLoadVerdict:
    """The judge's finding on one hole.

    Attributes
    ----------
    kind : str
        ``breakage``, ``no_load``, ``load_rise`` or ``load_drop``.
    hole : int
        Hole number.
    ratio : float
        Torque of the hole over the reference of its cut condition [-] (the last window's for
        ``breakage``, the cut's mean otherwise).
    reference_nm : float
        The reference torque [Nm].
    message : str
        What was found, in words.
    """

    kind: str
    hole: int
    ratio: float
    reference_nm: float
    message: str


@dataclass
class HoleLoadJudge:
    """Judge each hole row (:func:`cnctwin.usecases.holes.hole_records`) against its cut
    condition's taught reference.

    Parameters
    ----------
    teach_holes : int, default 1
        Holes of a new cut condition whose mean is its reference.
    breakage_ratio : float, default 0.4
        Below this fraction of the reference: breakage (last window) or no load (whole cut).
    rise, drop : float, default 0.25
        Relative rise / drop of the mean torque that alarms.
    min_load_nm : float, default 0.25
        A drilling-cycle hole below this mean cutting torque cut nothing [Nm].
    loose_ratio : float, default 1.5
        A tap's extraction fluctuation above this multiple of its reference: loose.
    """

    teach_holes: int = 1
    breakage_ratio: float = 0.4
    rise: float = 0.25
    drop: float = 0.25
    min_load_nm: float = 0.25
    loose_ratio: float = 1.5
    references: dict[tuple[Any, ...], list[tuple[float, float, float]]] = field(
        default_factory=dict)
    broken: dict[Any, float] = field(default_factory=dict)
    """Tool -> torque of its broken stub [Nm] (after a breakage, until it cuts again)."""
    raised: dict[tuple[Any, ...], float] = field(default_factory=dict)
    """(condition, kind) -> ratio of the last load_rise/load_drop alarm, until it re-arms."""

    def __post_init__(self) -> None:
        if self.teach_holes < 1:
            raise ConfigError(f"teach_holes must be >= 1, not {self.teach_holes}")
        if not 0 < self.breakage_ratio < 1 or self.rise <= 0 or not 0 < self.drop < 1:
            raise ConfigError("breakage_ratio and drop must lie in (0, 1) and rise above 0; "
                              f"got {self.breakage_ratio}, {self.drop}, {self.rise}")

    @staticmethod
    def condition(row: Mapping[str, Any]) -> tuple[Any, ...]:
        """The cut condition of a hole row: ``(tool, cycle, depth [mm], speed [rpm], feed
        [mm/min])`` as measured (NaN where unknown)."""
        def v(key: str) -> float:
            f = _finite(row.get(key))
            return math.nan if f is None else f

        return (row.get("tool"), row.get("cycle"), v("depth_mm"), v("speed_rpm"),
                v("feed_mm_min"))

    @staticmethod
    def same_condition(a: tuple[Any, ...], b: tuple[Any, ...]) -> bool:
        """Two conditions are one cut: the same tool and cycle, depth within 0.5 mm, speed
        within 1 % + 5 rpm, feed within 2 % + 2 mm/min (NaN matches NaN)."""
        if a[:2] != b[:2]:
            return False

        def close(x: float, y: float, rel: float, tol: float) -> bool:
            if math.isnan(x) or math.isnan(y):
                return math.isnan(x) and math.isnan(y)
            return abs(x - y) <= rel * max(abs(x), abs(y)) + tol

        return (close(a[2], b[2], 0.0, 0.5) and close(a[3], b[3], 0.01, 5.0)
                and close(a[4], b[4], 0.02, 2.0))

    def _key(self, row: Mapping[str, Any]) -> tuple[Any, ...]:
        """The taught condition this row belongs to (or its own, new)."""
        cond = self.condition(row)
        return next((k for k in self.references if self.same_condition(k, cond)), cond)

    def judge(self, row: Mapping[str, Any]) -> HoleLoadVerdict | None:
        """The finding on one hole (None: normal, or taught), learning it when normal.

        Parameters
        ----------
        row : mapping
            A hole row with ``hole``, ``cycle``, ``tool``, ``depth_mm``, ``speed_rpm``,
            ``feed_mm_min``, ``torque_mean_nm`` and ``torque_last_nm``.

        Returns
        -------
        HoleLoadVerdict or None
        """
        hole = int(row.get("hole", -1))
        mean = _finite(row.get("torque_mean_nm"))
        last = _finite(row.get("torque_last_nm"))
        fluct = _finite(row.get("reverse_current_fluct_a"))
        if mean is None:
            return None  # no torque estimate (flagged samples only): nothing to judge
        cyc_name = str(row.get("cycle", "")).upper()
        cutting = cyc_name.startswith("CYCLE8")  # drilling and tapping cycles
        drilling = cutting and cyc_name != "CYCLE84"
        what = "tap" if cyc_name == "CYCLE84" else "drill"
        key = self._key(row)
        refs = self.references.get(key, [])
        tool = row.get("tool")
        stub = self.broken.get(tool)
        if stub is not None:
            if mean * self.breakage_ratio <= stub:
                self.broken[tool] = min(stub, mean)
                return HoleLoadVerdict(
                    "no_load", hole, mean / refs[0][0] if refs else math.nan,
                    refs[0][0] if refs else math.nan,
                    f"hole {hole}: {mean:.2f} Nm, the level of the broken tool {tool} "
                    f"({stub:.2f} Nm since its breakage): still no cutting load")
            del self.broken[tool]  # it cuts: the tool was replaced
        if len(refs) < self.teach_holes:
            if cutting and last is not None and mean >= self.min_load_nm and \
                    last < self.breakage_ratio * mean:
                # no reference yet, but a drill or a tap is fully engaged at the end of its
                # infeed: its torque there is at least the cut's mean (the entry cone or the
                # tap's chamfer lowers the mean; healthy taps of the soak: last/mean
                # 1.13-1.16, a tap broken half-way: 0.24)
                self.broken[tool] = last
                return HoleLoadVerdict(
                    "breakage", hole, last / mean, mean,
                    f"hole {hole}: the torque fell to {last:.2f} Nm at the end of the cut, "
                    f"{100 * last / mean:.0f} % of the cut's mean {mean:.2f} Nm (first hole "
                    f"of its cut condition): the {what} broke in this hole")
            if drilling and mean < self.min_load_nm:
                return HoleLoadVerdict(
                    "no_load", hole, math.nan, math.nan,
                    f"hole {hole}: drilling cycle cut with {mean:.2f} Nm (< "
                    f"{self.min_load_nm:g} Nm): no cutting load, a broken or missing drill")
            self.references.setdefault(key, []).append(
                (mean, last if last is not None else mean,
                 fluct if fluct is not None else math.nan))
            return None
        ref_mean = sum(r[0] for r in refs) / len(refs)
        ref_last = sum(r[1] for r in refs) / len(refs)
        ref_fluct = sum(r[2] for r in refs) / len(refs)
        if fluct is not None and ref_fluct > 0 and fluct > self.loose_ratio * ref_fluct:
            return HoleLoadVerdict(
                "loose_tool", hole, fluct / ref_fluct, ref_fluct,
                f"hole {hole}: the spindle current fluctuates {fluct:.3f} A while the tap is "
                f"extracted, {fluct / ref_fluct:.1f}x the {ref_fluct:.3f} A taught: the tap "
                "is loose in its holder (stick-slip on reversal)")
        if ref_mean <= 0 or ref_last <= 0:
            return None
        if mean < self.breakage_ratio * ref_mean:
            self.broken[tool] = mean
            return HoleLoadVerdict(
                "no_load", hole, mean / ref_mean, ref_mean,
                f"hole {hole}: {mean:.2f} Nm over the whole cut, {100 * mean / ref_mean:.0f} % "
                f"of the {ref_mean:.2f} Nm of its cut condition: no cutting load (a broken "
                f"{what}?)")
        if last is not None and last < self.breakage_ratio * ref_last:
            self.broken[tool] = last
            return HoleLoadVerdict(
                "breakage", hole, last / ref_last, ref_last,
                f"hole {hole}: the torque fell to {last:.2f} Nm at the end of the cut, "
                f"{100 * last / ref_last:.0f} % of the {ref_last:.2f} Nm taught: the {what} "
                "broke in this hole")
        ratio = mean / ref_mean
        up, down = (*key, "load_rise"), (*key, "load_drop")
        if ratio <= 1 + self.rise / 2:  # back to normal: re-armed
            self.raised.pop(up, None)
        if ratio >= 1 - self.drop / 2:
            self.raised.pop(down, None)
        if ratio > 1 + self.rise:
            last_up = self.raised.get(up)
            if last_up is not None and ratio < last_up + self.rise:
                return None  # the standing rise, already raised
            self.raised[up] = ratio
            further = "" if last_up is None else (
                f", up from {100 * (last_up - 1):+.0f} % at the last alarm")
            return HoleLoadVerdict(
                "load_rise", hole, ratio, ref_mean,
                f"hole {hole}: {mean:.2f} Nm, {100 * (ratio - 1):+.0f} % over the "
                f"{ref_mean:.2f} Nm taught{further} (worn or chipped {what}, harder "
                "material)")
        if ratio < 1 - self.drop:
            last_down = self.raised.get(down)
            if last_down is not None and ratio > last_down - self.drop:
                return None
            self.raised[down] = ratio
            return HoleLoadVerdict(
                "load_drop", hole, ratio, ref_mean,
                f"hole {hole}: {mean:.2f} Nm, {100 * (ratio - 1):+.0f} % under the "
                f"{ref_mean:.2f} Nm taught (softer material, another tool?)")
        return None


def _finite(v: Any) -> float | None:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None
