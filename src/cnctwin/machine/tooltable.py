"""The tool table: per T number the tool's kind, geometry and limits (a TOML file).

The simulator cuts with it (engagement diameter, flutes), the optimizer respects its limits
(chip thickness, torque, force per tooth) and the edge knows what each T number is::

    [tools.1]
    kind = "drill"
    diameter_mm = 8.5

    [tools.2]
    kind = "end_mill"
    diameter_mm = 16
    flutes = 2
    helix_deg = 30
    max_chip_mm = 0.2
    max_torque_nm = 40        # optional
    max_force_per_tooth_n = 900   # optional
    stick_out_mm = 50         # optional
    corner_radius_mm = 0      # optional (flat end mill)

    [tools.4]
    kind = "drill"
    diameter_mm = 20
    life_holes = 3000             # optional: the planned life (the control's usage limit)
    wear_limit_um = 300           # optional: flank wear VB at which the tool is changed
    wear_um_per_increase = 1000   # optional: VB per unit relative torque increase
    wear_offset_um = 20           #   (cnctwin wear --measured ...: its slope, offset
    wear_std_um = 8               #    its uncertainty, and the new-tool holes the increase
    wear_baseline_holes = 30      #    is relative to)

    [tools.3]
    kind = "tap"
    diameter_mm = 8
    pitch_mm = 1.25

Every error names the file, the tool and the key.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cnctwin.exceptions import ConfigError
from cnctwin.machine.tools import Drill, EndMill, Tap

__all__ = ["TOOL_KINDS", "ToolSpec", "ToolTable", "read_toml", "read_tool_table"]

TOOL_KINDS: tuple[str, ...] = ("end_mill", "drill", "tap")
"""Values of ``kind``."""

_REQUIRED: dict[str, tuple[str, ...]] = {
    "end_mill": ("kind", "diameter_mm", "flutes", "helix_deg", "max_chip_mm"),
    "drill": ("kind", "diameter_mm"),
    "tap": ("kind", "diameter_mm", "pitch_mm"),
}
_OPTIONAL = ("flutes", "helix_deg", "max_chip_mm", "max_torque_nm", "max_force_per_tooth_n",
             "stick_out_mm", "corner_radius_mm", "pitch_mm", "point_angle_deg", "name",
             "life_holes", "wear_limit_um", "wear_um_per_increase", "wear_offset_um",
             "wear_std_um", "wear_baseline_holes")
_UNIT_HINTS = {"diameter": "diameter_mm", "d": "diameter_mm", "dia": "diameter_mm",
               "diameter_in": "diameter_mm", "max_chip": "max_chip_mm", "helix": "helix_deg",
               "max_torque": "max_torque_nm", "stick_out": "stick_out_mm",
               "corner_radius": "corner_radius_mm", "pitch": "pitch_mm",
               "z": "flutes", "teeth": "flutes"}


@dataclass(frozen=True)
class ToolSpec:
    """One tool of the table.

    Attributes
    ----------
    number : int
        T number.
    kind : str
        ``"end_mill"``, ``"drill"`` or ``"tap"``.
    diameter_mm : float
        Diameter [mm].
    flutes : int
        Teeth (end mill) or lips (drill) [-].
    helix_deg : float
        Helix angle [deg] (documented; the zero-helix force model does not use it).
    max_chip_mm : float or None
        Largest uncut chip thickness the tool takes [mm] (end mill; the maker's fz max).
    max_torque_nm : float or None
        Torque the tool (shank, clamping) takes [Nm].
    max_force_per_tooth_n : float or None
        Resultant force per tooth the edge takes [N].
    stick_out_mm : float or None
        Length from the holder [mm].
    corner_radius_mm : float
        Corner radius [mm] (0: flat end mill).
    pitch_mm : float or None
        Thread pitch of a tap [mm].
    point_angle_deg : float
        Point angle of a drill [deg].
    name : str
        Free text (catalogue number).
    life_holes : int or None
        Planned life in holes (usages), as the control's tool management counts it.
    wear_limit_um : float or None
        Average flank wear VB at which the tool is due for a change [µm].
    wear_um_per_increase : float or None
        Flank wear per unit relative increase of the hole's mean cutting torque [µm] (the
        slope of :class:`cnctwin.usecases.wear.WearEstimator`, from ``cnctwin wear
        --measured``); with ``wear_limit_um`` the edge forecasts the remaining life.
    wear_offset_um : float
        Flank wear of the tool when its baseline holes were drilled [µm].
    wear_std_um : float
        Standard uncertainty of a wear estimate [µm] (``cnctwin wear --measured`` prints
        it); widens the remaining-life interval.
    wear_baseline_holes : int
        The tool's first holes whose mean torque the increase is relative to (as
        ``cnctwin wear --baseline``).
    """

    number: int
    kind: str
    diameter_mm: float
    flutes: int = 2
    helix_deg: float = 30.0
    max_chip_mm: float | None = None
    max_torque_nm: float | None = None
    max_force_per_tooth_n: float | None = None
    stick_out_mm: float | None = None
    corner_radius_mm: float = 0.0
    pitch_mm: float | None = None
    point_angle_deg: float = 140.0
    name: str = ""
    life_holes: int | None = None
    wear_limit_um: float | None = None
    wear_um_per_increase: float | None = None
    wear_offset_um: float = 0.0
    wear_std_um: float = 0.0
    wear_baseline_holes: int = 30

    def end_mill(self) -> EndMill:
        """The :class:`~cnctwin.machine.tools.EndMill` description of this tool."""
        return EndMill(diameter_mm=self.diameter_mm, flutes=self.flutes,
                       helix_deg=self.helix_deg, tool_number=self.number)

    def drill(self, base: Drill | None = None) -> Drill:
        """The :class:`~cnctwin.machine.tools.Drill` with this diameter, point and lips.

        Parameters
        ----------
        base : Drill, optional
            Values the table does not give (stiffness, run-out); default the thesis drill.
        """
        import dataclasses

        b = base if base is not None else Drill()
        kw: dict[str, Any] = {"diameter_mm": self.diameter_mm, "flutes": self.flutes,
                              "point_angle_deg": self.point_angle_deg,
                              "tool_number": self.number}
        if self.stick_out_mm is not None:
            kw["overhang_mm"] = self.stick_out_mm
        return dataclasses.replace(b, **kw)

    def tap(self, base: Tap | None = None) -> Tap:
        """The :class:`~cnctwin.machine.tools.Tap` with this diameter and pitch."""
        import dataclasses

        b = base if base is not None else Tap()
        return dataclasses.replace(b, diameter_mm=self.diameter_mm,
                                   pitch_mm=self.pitch_mm or b.pitch_mm, tool_number=self.number)


@dataclass(frozen=True)
class ToolTable:
    """Tools by T number (what :func:`read_tool_table` returns).

    Attributes
    ----------
    tools : dict
        T number -> :class:`ToolSpec`.
    source : str
        The file it came from (for messages).
    """

    tools: Mapping[int, ToolSpec] = field(default_factory=dict)
    source: str = "tool table"

    def __contains__(self, number: object) -> bool:
        return number in self.tools

    def __iter__(self) -> Iterator[int]:
        return iter(sorted(self.tools))

    def __len__(self) -> int:
        return len(self.tools)

    def get(self, number: int, *, line: int | None = None, text: str = "") -> ToolSpec:
        """The tool T ``number``; :class:`ConfigError` names the table and the known tools.

        Parameters
        ----------
        number : int
            T number.
        line : int, optional
            Program line that selects it (for the message).
        text : str
            That line's text.
        """
        if number in self.tools:
            return self.tools[number]
        where = f"line {line}: {text.strip()!r}: " if line is not None else ""
        raise ConfigError(f"{where}T{number} is not in the tool table {self.source}; it has "
                          f"T{', T'.join(str(k) for k in self)}: add [tools.{number}] with "
                          "kind and diameter_mm")


_INTEGER = ("flutes", "life_holes", "wear_baseline_holes")


def _number(src: str, t: str, key: str, v: Any, *, lo: float = 0.0,
            integer: bool = False) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise ConfigError(f"{src}: tools.{t}.{key} must be a number, got {v!r}")
    if v <= lo and key not in ("corner_radius_mm", "helix_deg", "wear_offset_um"):
        bound = ">= 0" if -1e-9 < lo < 0 else f"> {lo:g}"
        raise ConfigError(f"{src}: tools.{t}.{key} must be {bound}, got {v!r}")
    if integer and v != int(v):
        raise ConfigError(f"{src}: tools.{t}.{key} must be a whole number, got {v!r}")
    return float(v)


def _tool(src: str, t: str, entry: Any) -> ToolSpec:
    if not isinstance(entry, Mapping):
        raise ConfigError(f"{src}: [tools.{t}] must be a table with kind, diameter_mm, ...")
    try:
        num = int(t)
    except ValueError:
        raise ConfigError(f"{src}: [tools.{t}]: the key is the T number, a whole number "
                          "(e.g. [tools.2])") from None
    if num < 0:
        raise ConfigError(f"{src}: [tools.{t}]: T numbers are >= 0")
    kind = entry.get("kind")
    if kind not in TOOL_KINDS:
        raise ConfigError(f"{src}: tools.{t}.kind must be one of {', '.join(TOOL_KINDS)}, got "
                          f"{kind!r}")
    for k in entry:
        if k not in _REQUIRED[kind] and k not in _OPTIONAL:
            hint = _UNIT_HINTS.get(k.lower())
            raise ConfigError(f"{src}: tools.{t}.{k} is not a tool key" + (
                f"; did you mean {hint!r} (units are in the key name)?" if hint else
                f"; keys: {', '.join(sorted({*_REQUIRED[kind], *_OPTIONAL}))}"))
    missing = [k for k in _REQUIRED[kind] if k not in entry]
    if missing:
        raise ConfigError(f"{src}: tools.{t} ({kind}) lacks {', '.join(missing)}")
    kw: dict[str, Any] = {"number": num, "kind": kind}
    for k, v in entry.items():
        if k in ("kind", "name"):
            if k == "name":
                kw[k] = str(v)
            continue
        kw[k] = _number(src, t, k, v, integer=k in _INTEGER,
                        lo=-1e-12 if k in ("corner_radius_mm", "wear_std_um") else 0.0)
        if k in _INTEGER:
            kw[k] = int(v)
    if kind == "end_mill" and kw.get("corner_radius_mm", 0.0) > kw["diameter_mm"] / 2.0:
        raise ConfigError(f"{src}: tools.{t}.corner_radius_mm exceeds the radius")
    if ("wear_limit_um" in kw) != ("wear_um_per_increase" in kw):
        given, lacking = (("wear_limit_um", "wear_um_per_increase") if "wear_limit_um" in kw
                          else ("wear_um_per_increase", "wear_limit_um"))
        raise ConfigError(f"{src}: tools.{t}.{given} needs {lacking} too (the wear forecast "
                          "maps the torque increase to flank wear and compares it with the "
                          "limit); 'cnctwin wear --measured HOLE:UM,...' gives the "
                          "slope")
    return ToolSpec(**kw)


def read_toml(path: str | Path, *, what: str) -> dict[str, Any]:
    """A TOML file as a dict, or one :class:`ConfigError` naming the file and what it is.

    Parameters
    ----------
    path : str or path
        The file.
    what : str
        What the file should be (``"tool table"``), for the message.

    Returns
    -------
    dict
    """
    p = Path(path)
    try:
        return tomllib.loads(p.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read the {what}: {exc.strerror or exc}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: not a TOML {what}: {exc}") from None


def read_tool_table(path: str | Path) -> ToolTable:
    """Read a tool table (TOML, ``[tools.N]`` per T number).

    Parameters
    ----------
    path : str or path
        The file.

    Returns
    -------
    ToolTable

    Raises
    ------
    ConfigError
        Unreadable file, TOML syntax, no ``[tools]``, a wrong kind, a missing field or a key
        without its unit (``diameter`` instead of ``diameter_mm``); the message names the file,
        the tool and the key.
    """
    src = str(path)
    data = read_toml(path, what="tool table")
    tools = data.get("tools")
    if not isinstance(tools, Mapping) or not tools:
        raise ConfigError(f"{src}: no [tools.N] tables; give one per T number with kind and "
                          "diameter_mm")
    extra = sorted(set(data) - {"tools"})
    if extra:
        raise ConfigError(f"{src}: unknown top-level keys {extra}; the table has [tools.N] only")
    specs = [_tool(src, str(k), v) for k, v in tools.items()]
    return ToolTable({t.number: t for t in specs}, source=src)
