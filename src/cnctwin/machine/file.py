"""The machine file: one TOML description of a machine, with what was identified and how.

``cnctwin calibrate`` writes it; the simulator (``cnctwin simulate --machine``), the edge
runtime, the dashboard and the fleet jobs read it, all through :func:`load_machine`. One
schema, one loader, one validator.

Format (schema ``cnctwin.machine``, version 1)::

    schema = "cnctwin.machine"
    schema_version = 1
    name = "dmc60h-cell3"

    [spindle]
    pole_count = 4                       # a plain number: given by the user
    kt_nm_per_a = { value = 1.021, uncertainty = 0.0031, unit = "Nm/A",
                    provenance = { method = "...", recordings = ["..."], date = "..." },
                    valid_range = [600.0, 4200.0], valid_quantity = "speed_rpm" }
    viscous_friction_nm_per_rpm = { value = 8.42e-5, identified = false,
                                    reason = "only 1 plateau between 500 and 7000 rpm" }

    [axes.X1]
    kv_m_min_per_mm = { value = 2.48, uncertainty = 0.02, unit = "(m/min)/mm", ... }

Keys are the simulator's own parameter names (:class:`~cnctwin.machine.description.Machine`,
``FeedAxis``, ``SpindleMotor``). A value is a number (or bool/int/string where the field is
one) or a table with at least ``value``; ``uncertainty`` is the standard uncertainty (1 sigma)
in the value's unit. A parameter that is not in the file takes the documented default of
:class:`~cnctwin.machine.description.Machine` (the thesis machine); a parameter the
calibration could not identify is written with ``identified = false`` and the reason, and its
value is that default.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import json
import math
import os
import tempfile
import tomllib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

from cnctwin.exceptions import ConfigError
from cnctwin.machine.description import FeedAxis, Machine, SpindleMotor

__all__ = [
    "SCHEMA",
    "SCHEMA_VERSION",
    "MachineFile",
    "ParameterRecord",
    "Provenance",
    "load_machine",
    "parameter_unit",
    "save_machine",
]

SCHEMA = "cnctwin.machine"
"""Value of the ``schema`` key of a machine file."""

SCHEMA_VERSION = 1
"""Current schema version; files of a newer version are refused with what to do."""

# unit of a parameter from the ending of its name (longest ending first)
_UNIT_BY_SUFFIX: tuple[tuple[str, str], ...] = (
    ("_m_min_per_mm", "(m/min)/mm"),
    ("_nm_s_per_rad", "Nm s/rad"),
    ("_nm_per_rpm", "Nm/rpm"),
    ("_n_per_mm_s", "N/(mm/s)"),
    ("_nm_per_a", "Nm/A"),
    ("_k_per_w", "K/W"),
    ("_j_per_k", "J/K"),
    ("_per_k", "1/K"),
    ("_per_s", "1/s"),
    ("_rev_s2", "rev/s^2"),
    ("_mm_min", "mm/min"),
    ("_mm_s2", "mm/s^2"),
    ("_mm_s3", "mm/s^3"),
    ("_mm_s", "mm/s"),
    ("_kg_m2", "kg m^2"),
    ("_kgm2", "kg m^2"),
    ("_rpm", "rpm"),
    ("_ohm", "Ohm"),
    ("_vs", "Vs"),
    ("_kg", "kg"),
    ("_mm", "mm"),
    ("_nm", "Nm"),
    ("_hz", "Hz"),
    ("_s", "s"),
    ("_n", "N"),
    ("_a", "A"),
    ("_v", "V"),
    ("_h", "H"),
    ("_c", "degC"),
    ("_w", "W"),
)
_ROTARY_UNITS = {"N": "Nm", "N/(mm/s)": "Nm/(deg/s)", "mm/s": "deg/s", "mm/min": "deg/min",
                 "mm/s^2": "deg/s^2", "mm/s^3": "deg/s^3", "mm": "deg"}
_RECORD_KEYS = {"value", "uncertainty", "unit", "provenance", "identified", "reason",
                "valid_range", "valid_quantity"}
_TOP_KEYS = {"schema", "schema_version", "name", "cycle_time_s", "inner_steps", "spindle_name",
             "tool_change_s", "axis_map", "axes", "spindle", "materials", "identification"}
IDENTIFICATION_KEYS = {"manufacturer": str, "model": str, "serial_number": str,
                       "year_of_construction": int, "software_revision": str,
                       "product_instance_uri": str}
"""``[identification]`` of a machine file, as the user gives them (the OPC 40501
Identification the edge's OPC UA server publishes)."""


def parameter_unit(key: str, *, rotary: bool = False) -> str:
    """The unit of a machine parameter from its dotted key (``-`` for dimensionless).

    Parameters
    ----------
    key : str
        Dotted key (``spindle.kt_nm_per_a``, ``axes.X1.coulomb_n``).
    rotary : bool, default False
        The axis is rotary: lengths are degrees and forces load torques.

    Returns
    -------
    str

    Examples
    --------
    >>> parameter_unit("spindle.viscous_friction_nm_per_rpm")
    'Nm/rpm'
    >>> parameter_unit("axes.C1.coulomb_n", rotary=True)
    'Nm'
    """
    name = key.rsplit(".", 1)[-1]
    for suffix, unit in _UNIT_BY_SUFFIX:
        if name.endswith(suffix):
            return _ROTARY_UNITS.get(unit, unit) if rotary else unit
    return "-"


@dataclass(frozen=True)
class Provenance:
    """Where an identified value comes from.

    Attributes
    ----------
    method : str
        Identification method (e.g. ``"improved air-cut friction + Kt (thesis ch. 4)"``).
    recordings : tuple of str
        The recordings it was identified from (paths or names as given).
    date : str
        When (ISO 8601, UTC).
    """

    method: str
    recordings: tuple[str, ...] = ()
    date: str = ""

    @classmethod
    def now(cls, method: str, recordings: Iterable[str | PathLike[str]]) -> Provenance:
        """A provenance stamped with the current UTC time."""
        stamp = _dt.datetime.now(_dt.UTC).replace(microsecond=0).isoformat()
        return cls(method, tuple(str(r) for r in recordings), stamp)


@dataclass(frozen=True)
class ParameterRecord:
    """What the file says about one parameter beyond its value.

    Attributes
    ----------
    value : float
        The value [the parameter's unit, :func:`parameter_unit`].
    uncertainty : float or None
        Standard uncertainty (1 sigma) [same unit]; None where not stated.
    provenance : Provenance or None
        Where the value comes from.
    identified : bool
        False: the calibration tried and could not identify it; ``value`` is the default.
    reason : str
        Why it was not identified (and what to record to identify it).
    valid_range : tuple of float or None
        Range of ``valid_quantity`` the value was identified over; an estimate outside it is
        an extrapolation and is flagged by the code that uses it.
    valid_quantity : str
        The quantity of ``valid_range`` (e.g. ``"speed_rpm"``).
    """

    value: float
    uncertainty: float | None = None
    provenance: Provenance | None = None
    identified: bool = True
    reason: str = ""
    valid_range: tuple[float, float] | None = None
    valid_quantity: str = ""

    def interval95(self) -> tuple[float, float] | None:
        """The 95 % interval ``value +- 1.96 uncertainty`` (None without an uncertainty)."""
        if self.uncertainty is None:
            return None
        return (self.value - 1.96 * self.uncertainty, self.value + 1.96 * self.uncertainty)


@dataclass(frozen=True)
class MachineFile:
    """A machine description with a record per identified (or refused) parameter.

    Attributes
    ----------
    machine : Machine
        The description every value is in (defaults where the file is silent).
    records : dict
        Dotted key -> :class:`ParameterRecord` for the values the file states as a table.
    path : Path or None
        The file it was read from.
    materials : dict
        Workpiece materials calibrated on this machine (``cnctwin calibrate material``):
        name -> table with ``milling`` (coefficient -> record table ``value``,
        ``uncertainty``, ``unit``, ``provenance``); read by
        :func:`cnctwin.sim.materials.resolve_material`.
    identification : dict
        ``[identification]``: manufacturer, model, serial_number, year_of_construction,
        software_revision, product_instance_uri (:data:`IDENTIFICATION_KEYS`).
    """

    machine: Machine = field(default_factory=Machine.thesis_default)
    records: Mapping[str, ParameterRecord] = field(default_factory=dict)
    path: Path | None = None
    materials: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    identification: Mapping[str, Any] = field(default_factory=dict)

    def value(self, key: str) -> Any:
        """The value of a dotted key (``spindle.kt_nm_per_a``, ``axes.X1.kv_m_min_per_mm``)."""
        return _get(self.machine, key)

    def record(self, key: str) -> ParameterRecord | None:
        """The record of a dotted key, or None if the file states a plain value/nothing."""
        return self.records.get(key)

    def is_identified(self, key: str) -> bool:
        """True if the key was identified from recordings (has a provenance)."""
        r = self.records.get(key)
        return r is not None and r.identified and r.provenance is not None

    def with_records(self, records: Mapping[str, ParameterRecord]) -> MachineFile:
        """A copy with the values and records of ``records`` set (identified or not)."""
        values = {k: r.value for k, r in records.items()}
        for key, value in values.items():
            _check_type(self.machine, key, value, source="update")
        machine = self.machine.with_overrides(
            {k: _coerce(self.machine, k, v) for k, v in values.items()})
        merged = {**self.records, **records}
        return dataclasses.replace(self, machine=machine, records=merged)

    # ------------------------------------------------------------------ dict
    def to_dict(self) -> dict[str, Any]:
        """The TOML document: values that differ from the defaults, and every record."""
        default = Machine.thesis_default()
        m = self.machine
        doc: dict[str, Any] = {"schema": SCHEMA, "schema_version": SCHEMA_VERSION,
                               "name": m.name}
        for k in ("cycle_time_s", "inner_steps", "spindle_name", "tool_change_s"):
            if getattr(m, k) != getattr(default, k):
                doc[k] = getattr(m, k)
        if m.axis_map != default.axis_map:
            doc["axis_map"] = {str(k): v for k, v in sorted(m.axis_map.items())}
        spindle: dict[str, Any] = {}
        for f in dataclasses.fields(SpindleMotor):
            key = f"spindle.{f.name}"
            v = getattr(m.spindle, f.name)
            if key in self.records:
                spindle[f.name] = _record_dict(self.records[key], parameter_unit(key))
            elif v != getattr(default.spindle, f.name):
                spindle[f.name] = v
        doc["spindle"] = spindle
        axes: dict[str, Any] = {}
        default_axes = {ax.name: ax for ax in default.axes}
        for ax in m.axes:
            base = default_axes.get(ax.name, FeedAxis(ax.name))
            table: dict[str, Any] = {}
            for f in dataclasses.fields(FeedAxis):
                if f.name == "name":
                    continue
                key = f"axes.{ax.name}.{f.name}"
                v = getattr(ax, f.name)
                if key in self.records:
                    table[f.name] = _record_dict(self.records[key],
                                                 parameter_unit(key, rotary=ax.rotary))
                elif v != getattr(base, f.name):
                    table[f.name] = v
            axes[ax.name] = table
        doc["axes"] = axes
        if self.materials:
            doc["materials"] = {k: dict(v) for k, v in self.materials.items()}
        if self.identification:
            doc["identification"] = dict(self.identification)
        return doc

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], *, source: str = "machine file",
                  path: Path | None = None) -> MachineFile:
        """Validate and build from a parsed document; every error names the key.

        Raises
        ------
        ConfigError
            Unknown keys, a wrong schema or version, a wrong unit, a value that is not a
            number or is out of range (the message gives the allowed range).
        """
        if not isinstance(data, Mapping):
            raise ConfigError(f"{source}: the top level must be a table")
        schema = data.get("schema", SCHEMA)
        if schema != SCHEMA:
            raise ConfigError(f"{source}: schema = {schema!r} is not a machine file "
                              f"(expected {SCHEMA!r})")
        version = data.get("schema_version", SCHEMA_VERSION)
        if not isinstance(version, int) or isinstance(version, bool):
            raise ConfigError(f"{source}: schema_version must be an integer, not {version!r}")
        if version > SCHEMA_VERSION:
            raise ConfigError(f"{source}: schema_version {version} is newer than this cnctwin "
                              f"reads ({SCHEMA_VERSION}); update cnctwin")
        unknown = sorted(set(data) - _TOP_KEYS)
        if unknown:
            raise ConfigError(f"{source}: unknown keys {unknown}; valid top-level keys: "
                              f"{sorted(_TOP_KEYS)}")
        default = Machine.thesis_default()
        records: dict[str, ParameterRecord] = {}
        plain: dict[str, Any] = {}
        for k in ("name", "cycle_time_s", "inner_steps", "spindle_name", "tool_change_s"):
            if k in data:
                plain[k] = data[k]
        kw: dict[str, Any] = {}
        if "axis_map" in data:
            kw["axis_map"] = data["axis_map"]
        spindle_tab = data.get("spindle", {})
        if not isinstance(spindle_tab, Mapping):
            raise ConfigError(f"{source}: spindle must be a table ([spindle])")
        spindle_fields = {f.name for f in dataclasses.fields(SpindleMotor)}
        spindle_values = _parse_table("spindle", spindle_tab, spindle_fields, records, source,
                                      rotary=False, what="spindle")
        axes_tab = data.get("axes")
        axis_fields = {f.name for f in dataclasses.fields(FeedAxis)} - {"name"}
        default_axes = {ax.name: ax for ax in default.axes}
        axes: list[FeedAxis] | None = None
        if axes_tab is not None:
            if not isinstance(axes_tab, Mapping):
                raise ConfigError(f"{source}: axes must be tables ([axes.X1], ...)")
            axes = []
            for ax_name, tab in axes_tab.items():
                if not isinstance(tab, Mapping):
                    raise ConfigError(f"{source}: axes.{ax_name} must be a table")
                base = default_axes.get(ax_name, FeedAxis(str(ax_name)))
                rotary = bool(tab.get("rotary", base.rotary))
                vals = _parse_table(f"axes.{ax_name}", tab, axis_fields, records, source,
                                    rotary=rotary, what="axis")
                for name, v in vals.items():
                    _check_type(base, name, v, source=source, key=f"axes.{ax_name}.{name}")
                try:
                    axes.append(dataclasses.replace(
                        base, **{k: _coerce_field(base, k, v) for k, v in vals.items()}))
                except (TypeError, ValueError) as exc:
                    raise ConfigError(f"{source}: axes.{ax_name}: {exc}") from None
        for name, v in spindle_values.items():
            _check_type(default.spindle, name, v, source=source, key=f"spindle.{name}")
        try:
            spindle = dataclasses.replace(
                default.spindle,
                **{k: _coerce_field(default.spindle, k, v) for k, v in spindle_values.items()})
            if "axis_map" in kw:
                kw["axis_map"] = {int(k): str(v) for k, v in kw["axis_map"].items()}
            for k, v in plain.items():
                _check_type(default, k, v, source=source, key=k)
                kw[k] = _coerce_field(default, k, v)
            if axes is not None:
                kw["axes"] = tuple(axes)
                # an axis the map does not number gets the next free number
                amap = dict(kw.get("axis_map", default.axis_map))
                for ax in axes:
                    if ax.name not in amap.values():
                        amap[max(amap, default=0) + 1] = ax.name
                kw["axis_map"] = amap
            machine = dataclasses.replace(default, spindle=spindle, **kw)
        except ConfigError as exc:
            raise ConfigError(f"{source}: {exc}") from None
        except (TypeError, ValueError, AttributeError) as exc:
            raise ConfigError(f"{source}: {exc}") from None
        _validate_spindle(machine.spindle, source)
        return cls(machine=machine, records=records, path=path,
                   materials=_materials(data.get("materials", {}), source),
                   identification=_identification(data.get("identification", {}), source))


def _get(machine: Machine, key: str) -> Any:
    parts = key.split(".")
    if parts[0] == "spindle" and len(parts) == 2:
        return getattr(machine.spindle, parts[1])
    if parts[0] == "axes" and len(parts) == 3:
        return getattr(machine.axis(parts[1]), parts[2])
    if len(parts) == 1:
        return getattr(machine, key)
    raise ConfigError(f"{key!r} is not a machine parameter key")


def _coerce(machine: Machine, key: str, value: Any) -> Any:
    current = _get(machine, key)
    if isinstance(current, int) and not isinstance(current, bool) and isinstance(value, float):
        return round(value)
    return value


def _coerce_field(obj: Any, name: str, value: Any) -> Any:
    current = getattr(obj, name)
    if isinstance(current, float) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


def _check_type(obj: Any, name: str, value: Any, *, source: str, key: str | None = None) -> None:
    key = key or name
    try:
        current = _get(obj, name) if isinstance(obj, Machine) and "." in name \
            else getattr(obj, name.rsplit(".", 1)[-1])
    except (AttributeError, ConfigError):
        return
    if isinstance(current, bool):
        ok = isinstance(value, bool)
        want = "true or false"
    elif isinstance(current, int | float):
        ok = isinstance(value, int | float) and not isinstance(value, bool)
        want = "a number"
        if ok and not math.isfinite(float(value)):
            raise ConfigError(f"{source}: {key} = {value!r} is not finite; give a number")
    elif isinstance(current, str):
        ok = isinstance(value, str)
        want = "a string"
    else:
        return
    if not ok:
        raise ConfigError(f"{source}: {key} must be {want}, not {value!r}")


def _parse_table(prefix: str, tab: Mapping[str, Any], fields: set[str],
                 records: dict[str, ParameterRecord], source: str, *, rotary: bool,
                 what: str) -> dict[str, Any]:
    """The values of one table (``[spindle]``, ``[axes.X1]``); unknown keys are errors."""
    values: dict[str, Any] = {}
    for name, raw in tab.items():
        key = f"{prefix}.{name}"
        if name not in fields:
            raise ConfigError(f"{source}: unknown key {key}; valid {what} keys: "
                              f"{', '.join(sorted(fields))}")
        values[name] = _parse_value(key, raw, records, source, rotary=rotary)
    return values


def _parse_value(key: str, raw: Any, records: dict[str, ParameterRecord], source: str, *,
                 rotary: bool) -> Any:
    if not isinstance(raw, Mapping):
        return raw
    bad = sorted(set(raw) - _RECORD_KEYS)
    if bad:
        raise ConfigError(f"{source}: {key} has unknown fields {bad}; a parameter table has "
                          f"{sorted(_RECORD_KEYS)}")
    if "value" not in raw:
        raise ConfigError(f"{source}: {key} is a table without 'value'; write "
                          f"{key.rsplit('.', 1)[-1]} = {{ value = ... }}")
    value = raw["value"]
    if isinstance(value, bool) or not isinstance(value, int | float) \
            or not math.isfinite(float(value)):
        raise ConfigError(f"{source}: {key}.value must be a finite number, not {value!r}")
    unit = raw.get("unit")
    expected = parameter_unit(key, rotary=rotary)
    if unit is not None and unit != expected:
        raise ConfigError(f"{source}: {key} is in {unit!r}, but this key is in {expected!r}; "
                          "convert the value or use the key for that unit")
    unc = raw.get("uncertainty")
    if unc is not None and (isinstance(unc, bool) or not isinstance(unc, int | float)
                            or not (math.isfinite(float(unc)) and unc >= 0)):
        raise ConfigError(f"{source}: {key}.uncertainty must be a number >= 0 (standard "
                          f"uncertainty in {expected}), not {unc!r}")
    prov = raw.get("provenance")
    provenance = None
    if prov is not None:
        if not isinstance(prov, Mapping) or not isinstance(prov.get("method", ""), str):
            raise ConfigError(f"{source}: {key}.provenance must be a table with method, "
                              "recordings, date")
        unknown = sorted(set(prov) - {"method", "recordings", "date"})
        if unknown:
            raise ConfigError(f"{source}: {key}.provenance has unknown fields {unknown}")
        recs = prov.get("recordings", [])
        if isinstance(recs, str) or not all(isinstance(r, str) for r in recs):
            raise ConfigError(f"{source}: {key}.provenance.recordings must be a list of "
                              "strings")
        provenance = Provenance(str(prov.get("method", "")), tuple(recs),
                                str(prov.get("date", "")))
    identified = raw.get("identified", True)
    if not isinstance(identified, bool):
        raise ConfigError(f"{source}: {key}.identified must be true or false")
    vr = raw.get("valid_range")
    valid_range = None
    if vr is not None:
        if (not isinstance(vr, list) or len(vr) != 2
                or not all(isinstance(x, int | float) and not isinstance(x, bool) for x in vr)
                or not vr[0] <= vr[1]):
            raise ConfigError(f"{source}: {key}.valid_range must be [low, high], not {vr!r}")
        valid_range = (float(vr[0]), float(vr[1]))
    records[key] = ParameterRecord(
        value=float(value) if isinstance(value, float) else value,
        uncertainty=None if unc is None else float(unc), provenance=provenance,
        identified=identified, reason=str(raw.get("reason", "")), valid_range=valid_range,
        valid_quantity=str(raw.get("valid_quantity", "")))
    return value


def _sig(x: float, digits: int) -> float:
    return float(f"{x:.{digits}g}")


def _record_dict(rec: ParameterRecord, unit: str) -> dict[str, Any]:
    d: dict[str, Any] = {"value": _sig(rec.value, 7) if isinstance(rec.value, float)
                         else rec.value}
    if rec.uncertainty is not None:
        d["uncertainty"] = _sig(rec.uncertainty, 3)
    d["unit"] = unit
    if not rec.identified:
        d["identified"] = False
    if rec.reason:
        d["reason"] = rec.reason
    if rec.valid_range is not None:
        d["valid_range"] = [_sig(x, 6) for x in rec.valid_range]
        if rec.valid_quantity:
            d["valid_quantity"] = rec.valid_quantity
    if rec.provenance is not None:
        d["provenance"] = {"method": rec.provenance.method,
                           "recordings": list(rec.provenance.recordings),
                           "date": rec.provenance.date}
    return d


# ranges of the spindle parameters (the feed axes are checked by FeedAxis.validate)
_SPINDLE_RANGES: dict[str, tuple[float, float]] = {
    "max_speed_rpm": (100.0, 200_000.0),
    "base_speed_rpm": (10.0, 200_000.0),
    "kt_nm_per_a": (1e-3, 100.0),
    "kt_ref_temperature_c": (-40.0, 200.0),
    "magnet_temp_coeff_per_k": (-0.01, 0.0),
    "viscous_friction_nm_per_rpm": (0.0, 0.1),
    "coulomb_friction_nm": (0.0, 1000.0),
    "friction_ref_temperature_c": (-40.0, 200.0),
    "stribeck_torque_nm": (0.0, 1000.0),
    "stribeck_speed_rpm": (1.0, 100_000.0),
    "current_limit_a": (0.1, 10_000.0),
    "rated_current_a": (0.1, 10_000.0),
    "rated_torque_nm": (1e-3, 100_000.0),
    "inertia_kg_m2": (1e-6, 1000.0),
    "dc_link_v": (10.0, 2000.0),
    "stator_resistance_ohm": (0.0, 100.0),
    "d_inductance_h": (1e-6, 10.0),
    "q_inductance_h": (1e-6, 10.0),
    "lf_smoothing_time_s": (1e-3, 10.0),
}


def _validate_spindle(sp: SpindleMotor, source: str) -> None:
    if not isinstance(sp.pole_count, int) or sp.pole_count < 2 or sp.pole_count % 2:
        raise ConfigError(f"{source}: spindle.pole_count = {sp.pole_count!r} is out of range; "
                          "allowed: an even integer >= 2")
    for name, (lo, hi) in _SPINDLE_RANGES.items():
        v = getattr(sp, name)
        if not lo <= v <= hi:
            raise ConfigError(f"{source}: spindle.{name} = {v!r} is out of range; allowed "
                              f"{lo:g} ... {hi:g} {parameter_unit('spindle.' + name)}")


def _literal(v: Any) -> str:
    """A TOML literal for a scalar, list or inline table."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_literal(x) for x in v) + "]"
    if isinstance(v, Mapping):
        return "{ " + ", ".join(f"{k} = {_literal(x)}" for k, x in v.items()) + " }"
    raise ConfigError(f"cannot write {v!r} to a machine file")


def _materials(data: Any, source: str) -> dict[str, dict[str, Any]]:
    """The ``[materials.NAME]`` tables, checked for shape (the values: resolve_material)."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{source}: materials must be a table of [materials.NAME] tables")
    out: dict[str, dict[str, Any]] = {}
    for name, table in data.items():
        if not isinstance(table, Mapping) or not isinstance(table.get("milling"), Mapping):
            raise ConfigError(f"{source}: materials.{name} needs a [materials.{name}.milling] "
                              "table of coefficients")
        out[str(name)] = dict(table)
    return out


def _identification(data: Any, source: str) -> dict[str, Any]:
    """The ``[identification]`` table: known keys of the right type (the message names the
    key and lists the known ones)."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{source}: identification must be a table")
    out: dict[str, Any] = {}
    for k, v in data.items():
        want = IDENTIFICATION_KEYS.get(str(k))
        if want is None:
            raise ConfigError(f"{source}: identification.{k} is not a key; keys: "
                              f"{', '.join(sorted(IDENTIFICATION_KEYS))}")
        if not isinstance(v, want) or isinstance(v, bool):
            raise ConfigError(f"{source}: identification.{k} must be a "
                              f"{'whole number' if want is int else 'text'}, got {v!r}")
        out[str(k)] = v
    return out


def _dumps(doc: Mapping[str, Any]) -> str:
    """The document as TOML, one line per parameter (records as inline tables)."""
    lines = []
    for k, v in doc.items():
        if not isinstance(v, Mapping) or k == "axis_map":
            lines.append(f"{k} = {_literal(v)}" if k != "axis_map" else "")
    if "axis_map" in doc:
        lines.append("\n[axis_map]")
        lines += [f"{json.dumps(k)} = {_literal(v)}" for k, v in doc["axis_map"].items()]
    lines.append("\n[spindle]")
    lines += [f"{k} = {_literal(v)}" for k, v in doc.get("spindle", {}).items()]
    for name, table in doc.get("axes", {}).items():
        lines.append(f"\n[axes.{name}]")
        lines += [f"{k} = {_literal(v)}" for k, v in table.items()]
    if doc.get("identification"):
        lines.append("\n[identification]")
        lines += [f"{k} = {_literal(v)}" for k, v in doc["identification"].items()]
    for name, table in doc.get("materials", {}).items():
        lines.append(f"\n[materials.{name}]")
        lines += [f"{k} = {_literal(v)}" for k, v in table.items() if k != "milling"]
        lines.append(f"\n[materials.{name}.milling]")
        lines += [f"{k} = {_literal(v)}" for k, v in table["milling"].items()]
    return "\n".join(x for x in lines if x != "") + "\n"


def load_machine(path: str | PathLike[str]) -> MachineFile:
    """Read and validate a machine file.

    Parameters
    ----------
    path : str or path-like
        The TOML file (written by :func:`save_machine`, ``cnctwin calibrate`` or by hand).

    Returns
    -------
    MachineFile

    Raises
    ------
    ConfigError
        File missing or unreadable, not TOML (with the line), or any invalid key or value
        (named, with the allowed range).
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{p}: machine file not found; create it with 'cnctwin calibrate "
                          "spindle ... --machine FILE'") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: cannot read the machine file: {exc}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: not valid TOML ({exc}); fix the line or restore the file "
                          "from its backup") from None
    return MachineFile.from_dict(data, source=str(p), path=p)


def _umask() -> int:
    """The process umask, read without changing it (Linux ``/proc``; else the usual 022)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    return 0o022


def save_machine(machine_file: MachineFile, path: str | PathLike[str]) -> Path:
    """Write a machine file atomically (a crash leaves the old file or the new, never half).

    Parameters
    ----------
    machine_file : MachineFile
        The description to write (validated before anything is written).
    path : str or path-like
        Target file (``.toml``); its folder must exist.

    Returns
    -------
    pathlib.Path
    """
    p = Path(path)
    text = ("# cnctwin machine description (schema cnctwin.machine). Values not listed take\n"
            "# the documented defaults of cnctwin.machine.Machine; see docs/machine-file.md.\n"
            + _dumps(machine_file.to_dict()))
    # check that what is written reads back before it replaces anything
    MachineFile.from_dict(tomllib.loads(text), source=str(p))
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", dir=p.parent)
    try:
        # mkstemp makes the file 0600; the machine file is a normal output: it keeps the
        # mode of the file it replaces, a new one gets the user's umask
        os.fchmod(fd, p.stat().st_mode & 0o777 if p.exists() else 0o666 & ~_umask())
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return p
