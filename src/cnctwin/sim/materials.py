"""Workpiece materials by name or file: the library, a material file, the machine file's own.

``--material`` takes a library name (:data:`cnctwin.sim.cutting.MATERIALS`), a TOML file, or
the name of a material that ``cnctwin calibrate material`` wrote into the machine file (that
one wins over the library's). A material file::

    name = "s355"                 # optional; default the file name
    source = "fitted from my cuts, 2026-11"   # where the numbers come from
    [milling]
    ktc_n_per_mm2 = 1900
    krc_n_per_mm2 = 750
    kac_n_per_mm2 = 640
    kte_n_per_mm = 55
    kre_n_per_mm = 25
    kae_n_per_mm = 22
    [kienzle]                     # optional: drilling (default derived from the milling set)
    kc1_n_per_mm2 = 1550
    mc = 0.22
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from cnctwin.exceptions import ConfigError
from cnctwin.machine.tooltable import read_toml
from cnctwin.sim.cutting import MATERIALS, Material, MillingCoefficients

__all__ = ["MILLING_KEYS", "MaterialSource", "material_from_mapping", "resolve_material"]

MILLING_KEYS: tuple[str, ...] = tuple(f.name for f in fields(MillingCoefficients))
"""The six keys of a ``[milling]`` table, with their units in the names."""


@dataclass(frozen=True)
class MaterialSource:
    """A resolved material and where it came from (what :func:`resolve_material` returns).

    Attributes
    ----------
    material : Material
        The coefficients.
    origin : str
        ``"library"``, ``"file"`` or ``"machine file"``.
    where : str
        The library key, file path or machine file path.
    uncertainty : dict
        Milling key -> standard uncertainty [same unit] where known (calibrated materials).
    """

    material: Material
    origin: str
    where: str
    uncertainty: Mapping[str, float]


def _num(src: str, key: str, v: Any) -> float:
    if isinstance(v, Mapping):  # a machine-file record {value = .., uncertainty = ..}
        v = v.get("value")
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v < 0:
        raise ConfigError(f"{src}: {key} must be a non-negative number, got {v!r}")
    return float(v)


def material_from_mapping(data: Mapping[str, Any], *, name: str, source: str) -> Material:
    """Build a :class:`Material` from a material table (file or machine-file entry).

    Parameters
    ----------
    data : mapping
        ``milling`` table with :data:`MILLING_KEYS` (plain numbers or ``{value, uncertainty}``
        records), optional ``kienzle`` table (``kc1_n_per_mm2``, ``mc``), ``hardness_hb``.
    name : str
        Material name.
    source : str
        For messages (file path, ``machine file materials.NAME``).

    Returns
    -------
    Material

    Raises
    ------
    ConfigError
        No ``[milling]`` table, a missing key (named), a key without its unit, a bad value.
    """
    mill = data.get("milling")
    if not isinstance(mill, Mapping):
        raise ConfigError(f"{source}: no [milling] table; give {', '.join(MILLING_KEYS)}")
    bad = sorted(set(mill) - set(MILLING_KEYS))
    if bad:
        raise ConfigError(f"{source}: milling.{bad[0]} is not a milling coefficient; keys are "
                          f"{', '.join(MILLING_KEYS)} (units in the names)")
    missing = [k for k in MILLING_KEYS if k not in mill]
    if missing:
        raise ConfigError(f"{source}: milling lacks {', '.join(missing)}")
    coef = MillingCoefficients(**{k: _num(source, f"milling.{k}", mill[k]) for k in MILLING_KEYS})
    kien = data.get("kienzle", {})
    if not isinstance(kien, Mapping):
        raise ConfigError(f"{source}: [kienzle] must be a table (kc1_n_per_mm2, mc)")
    base = MATERIALS.get(name.lower())
    if "kc1_n_per_mm2" in kien or "mc" in kien:
        kc1 = _num(source, "kienzle.kc1_n_per_mm2", kien.get("kc1_n_per_mm2"))
        mc = _num(source, "kienzle.mc", kien.get("mc"))
    elif base is not None:
        kc1, mc = base.kc1_n_per_mm2, base.mc
    else:  # Kienzle law through the milling line at h = 0.1 mm with the steel exponent
        mc = 0.22
        kc1 = (coef.ktc_n_per_mm2 * 0.1 + coef.kte_n_per_mm) / 0.1 ** (1.0 - mc)
    hb = _num(source, "hardness_hb", data.get("hardness_hb", 200.0))
    return Material(name=name, kc1_n_per_mm2=kc1, mc=mc, hardness_hb=hb, milling=coef)


def _uncertainty(data: Mapping[str, Any]) -> dict[str, float]:
    mill = data.get("milling", {})
    out: dict[str, float] = {}
    if isinstance(mill, Mapping):
        for k, v in mill.items():
            if isinstance(v, Mapping) and isinstance(v.get("uncertainty"), int | float):
                out[k] = float(v["uncertainty"])
    return out


def resolve_material(spec: str, *, machine_materials: Mapping[str, Any] | None = None,
                     machine_source: str = "machine file") -> MaterialSource:
    """Find a material: a file path, the machine file's calibrated one, or the library's.

    Parameters
    ----------
    spec : str
        A ``.toml`` path, or a name.
    machine_materials : mapping, optional
        The machine file's ``materials`` tables (name -> table), which win over the library.
    machine_source : str
        The machine file's path (for messages).

    Returns
    -------
    MaterialSource

    Raises
    ------
    ConfigError
        Unknown name (the message lists the library and the machine file's), an unreadable or
        malformed file.
    """
    s = str(spec)
    if s.lower().endswith(".toml") or Path(s).is_file():
        p = Path(s)
        data = read_toml(p, what="material file")
        name = str(data.get("name", p.stem))
        return MaterialSource(material_from_mapping(data, name=name, source=str(p)),
                              origin="file", where=str(p), uncertainty=_uncertainty(data))
    own = dict(machine_materials or {})
    if s in own:
        src = f"{machine_source}: materials.{s}"
        return MaterialSource(material_from_mapping(own[s], name=s, source=src),
                              origin="machine file", where=machine_source,
                              uncertainty=_uncertainty(own[s]))
    if s.lower() in MATERIALS:
        return MaterialSource(MATERIALS[s.lower()], origin="library", where=s.lower(),
                              uncertainty={})
    known = sorted({*MATERIALS, *own})
    raise ConfigError(f"unknown material {s!r}; known: {', '.join(known)}, or give a material "
                      "file (.toml with a [milling] table)")
