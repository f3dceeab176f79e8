"""Save and load a calibrated :class:`~cnctwin.spindle.SpindleModel` as JSON or TOML.

The edge runtime is given the spindle twin as a small file that the calibration (e.g.
``TwinChain.improved_method().calibrate(...)``) writes once::

    {"kind": "cnctwin.SpindleModel", "version": 1,
     "parameters": {"kt_nm_per_a": 1.04, "b_nm_per_rpm": 8.42e-05, "tau_f_nm": 0.35,
                    "j_kgm2": 0.0, ...},
     "units": {"kt_nm_per_a": "Nm/A", ...}, "source": "..."}

The same document in TOML (``.toml`` suffix) has the tables ``[parameters]`` and ``[units]``.
A bare parameter mapping (``{"kt_nm_per_a": ..., ...}``, what ``SpindleModel.to_dict()``
gives) is accepted on reading too.
"""

from __future__ import annotations

import dataclasses
import json
import math
import tomllib
from os import PathLike
from pathlib import Path
from typing import Any

from cnctwin.exceptions import ConfigError, FormatError
from cnctwin.spindle import SpindleModel

__all__ = ["MODEL_UNITS", "load_spindle_model", "save_spindle_model"]

MODEL_UNITS: dict[str, str] = {
    "kt_nm_per_a": "Nm/A",
    "b_nm_per_rpm": "Nm/rpm",
    "tau_f_nm": "Nm",
    "j_kgm2": "kg m^2",
    "kt_temp_coeff_per_k": "1/K",
    "b_temp_coeff_per_k": "1/K",
    "tau_f_temp_coeff_per_k": "1/K",
    "reference_temperature_c": "degC",
    "flux_base_speed_rpm": "rpm",
    "flux_exponent": "-",
    "kt_valid_speed_rpm": "rpm",
    "stribeck_torque_nm": "Nm",
    "stribeck_speed_rpm": "rpm",
}
"""Units of the :class:`~cnctwin.spindle.SpindleModel` fields."""

_KIND = "cnctwin.SpindleModel"


def save_spindle_model(model: SpindleModel, path: str | PathLike[str], *,
                       source: str = "") -> Path:
    """Write ``model`` to ``path`` (``.toml`` -> TOML, anything else -> JSON).

    Parameters
    ----------
    model : SpindleModel
        Calibrated model.
    path : str or path-like
        Target file.
    source : str, optional
        Free text stored with the model (which recordings it was calibrated from).

    Returns
    -------
    pathlib.Path
    """
    p = Path(path)
    params = {k: v for k, v in model.to_dict().items() if v is not None}
    if not model.stribeck_torque_nm:  # no low-speed term: the file as earlier versions read it
        params.pop("stribeck_torque_nm", None)
        params.pop("stribeck_speed_rpm", None)
    doc: dict[str, Any] = {"kind": _KIND, "version": 1, "source": source,
                           "parameters": params,
                           "units": {k: MODEL_UNITS[k] for k in params}}
    if p.suffix.lower() == ".toml":
        import tomli_w

        p.write_text(tomli_w.dumps(doc), encoding="utf-8")
    else:
        p.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
    return p


def load_spindle_model(path: str | PathLike[str]) -> SpindleModel:
    """Read a model written by :func:`save_spindle_model` (or a bare parameter mapping).

    Parameters
    ----------
    path : str or path-like
        A JSON or TOML file.

    Returns
    -------
    SpindleModel
        The model.

    Raises
    ------
    FormatError
        If the file is not JSON/TOML or a value is not a finite number; names file and field.
    ConfigError
        If a required parameter is missing or an unknown one is present.
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"cannot read the spindle model file {p}: {exc}") from None
    try:
        doc = tomllib.loads(text) if p.suffix.lower() == ".toml" else json.loads(text)
    except (json.JSONDecodeError, tomllib.TOMLDecodeError) as exc:
        raise FormatError(f"not a JSON/TOML spindle model: {exc}", path=str(p)) from None
    if not isinstance(doc, dict):
        raise FormatError("top level is not an object", path=str(p))
    params = doc.get("parameters", doc) if doc.get("kind", _KIND) == _KIND else None
    if not isinstance(params, dict):
        raise FormatError(f"kind {doc.get('kind')!r} is not {_KIND!r}", path=str(p),
                          field="kind")
    fields = {f.name for f in dataclasses.fields(SpindleModel)}
    unknown = sorted(set(params) - fields - {"kind", "version", "source", "units"})
    if unknown:
        raise ConfigError(f"{p}: unknown spindle model parameters {unknown}; valid: "
                          f"{sorted(fields)}")
    values: dict[str, float | None] = {}
    ranges: dict[str, tuple[float, float]] = {}
    for k in fields & set(params):
        v = params[k]
        if v is None and k in ("reference_temperature_c", "kt_valid_speed_rpm"):
            values[k] = None
            continue
        if k == "kt_valid_speed_rpm":
            if (not isinstance(v, list | tuple) or len(v) != 2
                    or not all(isinstance(x, int | float) and math.isfinite(x) for x in v)):
                raise FormatError(f"parameter {k} = {v!r} is not [low, high] in rpm",
                                  path=str(p), field=k)
            ranges[k] = (float(v[0]), float(v[1]))
            continue
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise FormatError(f"parameter {k} = {v!r} is not a finite number", path=str(p),
                              field=k)
        values[k] = float(v)
    missing = [k for k in ("kt_nm_per_a", "b_nm_per_rpm", "tau_f_nm") if k not in values]
    if missing:
        raise ConfigError(f"{p}: spindle model lacks {missing} (write it with "
                          "cnctwin.edge.save_spindle_model)")
    return SpindleModel(**values, **ranges)  # type: ignore[arg-type]
