"""The signal catalog: SINUMERIK high-frequency (HF) codes and low-frequency (LF) drive values.

One entry per signal with description, unit for linear and rotary axes, the name the thesis uses
(Tables 2.1 and 2.2), the long-name aliases seen in real files, and, for LF values, the SINAMICS
parameter and OPC UA path where known. Columns of a :class:`~cnctwin.recording.Recording` are
named ``CODE|AXIS`` (``CURRENT|SP1``, ``ENC_POS|Z1``); :func:`parse_column` splits them.

Sources
-------
.. [1] Siemens, SINUMERIK Connector FAQ "Which HF data can be collected via SINUMERIK Connector?",
   docs.industrial-operations-x.siemens.cloud (codes CYCLE ... CMD_SPEED).
.. [2] Thesis "CNC Machine Tool Digital Twin Applications with Advancements of Edge Computing",
   Koç University, Tables 2.1 and 2.2.
.. [3] SINAMICS S120 parameter list: r0035 motor temperature, r0063 actual speed smoothed,
   r0068 absolute actual current smoothed, r0078 actual Iq, r0081 torque utilization.
.. [4] Real-file long names: KIT CNC milling dataset header.csv (DOI 10.35097/hvvwn1kfwf7qt48z) and
   lukasmundorf/I40Infrastruktur SynchronizeMatlabEdgeDataDockerContainer.m.

Run ``python -m cnctwin.signals --glossary docs/glossary.md`` to regenerate the glossary page.
"""

from __future__ import annotations

import argparse
import re
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from cnctwin.exceptions import SignalNotFoundError

__all__ = [
    "CATALOG",
    "DEFAULT_AXIS_MAP",
    "HF_CODES",
    "LF_CODES",
    "SignalSpec",
    "axis_kind",
    "column",
    "glossary_markdown",
    "lookup",
    "parse_column",
    "unit",
]

AxisKind = Literal["linear", "rotary", "spindle"]


@dataclass(frozen=True)
class SignalSpec:
    """Catalog entry of one signal.

    Attributes
    ----------
    code : str
        Catalog code, the SINUMERIK HF address code for HF signals (``"CURRENT"``).
    kind : {'hf', 'lf'}
        ``'hf'``: one sample per position-control cycle (500 Hz at 2 ms);
        ``'lf'``: low-frequency drive value (typically 100-500 ms).
    description : str
        What the signal is.
    unit_linear : str
        Unit on a linear feed axis.
    unit_rotary : str
        Unit on a rotary axis or spindle.
    unit_spindle : str
        Unit on a spindle where it differs from ``unit_rotary`` ("" = same).
    thesis_name : str
        Name in the thesis' Tables 2.1 / 2.2 ("" when the thesis does not list it).
    aliases : tuple of str
        Long names seen in real files (``"ActualAxisPosition"``) and other common names.
    sinamics_parameter : str
        SINAMICS parameter the value comes from, where known (LF values).
    opcua_path : str
        OPC UA node path (``ns=2;s=...``), where known.
    note : str
        Caveats seen on real data.
    """

    code: str
    kind: Literal["hf", "lf"]
    description: str
    unit_linear: str
    unit_rotary: str
    thesis_name: str = ""
    aliases: tuple[str, ...] = ()
    sinamics_parameter: str = ""
    opcua_path: str = ""
    note: str = ""
    dtype: str = "float64"
    unit_spindle: str = ""

    def unit_for(self, axis: str | None) -> str:
        """Unit of this signal on ``axis`` (linear axes get ``unit_linear``)."""
        if axis is None:
            return self.unit_linear
        kind = axis_kind(axis)
        if kind == "spindle" and self.unit_spindle:
            return self.unit_spindle
        return self.unit_linear if kind == "linear" else self.unit_rotary


_HF: tuple[SignalSpec, ...] = (
    SignalSpec(
        "CYCLE", "hf", "Position-control cycle counter, 0..2147483647, +1 per cycle (2 ms).",
        "-", "-", "time base", ("Cycle", "HFProbeCounter"), dtype="int64",
        note="Wraps around at 2**31; real files have gaps (one of 3860 cycles in the C4A sample).",
    ),
    SignalSpec(
        "ENC_POS", "hf", "Actual position of the active encoder.", "mm", "deg",
        "Encoder position", ("ActualAxisPosition", "ActualPosition", "EncoderPosition"),
    ),
    SignalSpec(
        "ENC1_POS", "hf", "Actual position of encoder 1 (motor measuring system).", "mm", "deg",
        "", ("Encoder1Position",),
    ),
    SignalSpec(
        "ENC2_POS", "hf", "Actual position of encoder 2 (direct measuring system).", "mm", "deg",
        "", ("Encoder2Position",),
    ),
    SignalSpec(
        "DES_POS", "hf",
        "Position command after the fine interpolator (OPI cmdContrPos without filter and "
        "compensation).", "mm", "deg", "Desired position",
        ("CommandedAxisPosition", "CommandedPosition", "DesiredPosition"),
    ),
    SignalSpec(
        "CTRL_POS", "hf",
        "Position at the position-controller input, after jerk filter, dynamic response "
        "adaptation and feedforward balancing.", "mm", "deg", "Controller input position",
        ("ControlPos", "ControllerPosition"),
    ),
    SignalSpec(
        "CTRL_DIFF", "hf",
        "Position-controller input difference including DSC compensation (OPI trackErrContr).",
        "mm", "deg", "", ("ControlDiff", "ControlDifference"),
    ),
    SignalSpec(
        "CTRL_DIFF2", "hf",
        "Position-controller input difference without DSC compensation (CTRL_POS - ENC_POS).",
        "mm", "deg", "Position controller difference", ("ControlDiff2",),
    ),
    SignalSpec(
        "CONT_DEV", "hf",
        "Contour deviation: following error minus the lag the NC's model expects "
        "(OPI trackErrDiff).", "mm", "deg", "Contour deviation",
        ("CountourDeviation", "ContourDeviation"),
    ),
    SignalSpec(
        "VEL_FFW", "hf", "Velocity feedforward added to the position-controller output.",
        "mm/s", "deg/s", "Velocity feedforward", ("VelocityFeedForward", "VelocityFeedforward"),
        unit_spindle="rpm",
        note="Per second, as Siemens documents and the real C4A file shows: VEL_FFW equals "
        "d(DES_POS)/dt in mm/s (deg/s) with ratio 1.000 on X1, Y1, C1 "
        "(docs/real-data-servo.md); the simulator writes these units. Spindle: rpm (the "
        "simulated spindle in speed control and the spindle analyses use rpm; the real file's "
        "SP1, positioning, shows deg/s). cnctwin.servo reads the unit from the data.",
    ),
    SignalSpec(
        "TORQUE_FFW", "hf", "Torque (force) feedforward value sent from the NC to the drive.",
        "N", "Nm", "Torque feedforward", ("TorqueFeedForward", "TorqueFeedforward"),
        note="Zero on axes where torque feedforward is off (FFW_MODE 0/1/3).",
    ),
    SignalSpec(
        "CMD_SPEED", "hf", "Speed command sent from the NC to the drive (controller output + "
        "velocity feedforward).", "mm/s", "deg/s", "Speed command",
        ("CommandedSpeed", "SpeedCommand"), unit_spindle="rpm",
        note="Same unit convention as VEL_FFW (per second; spindle rpm).",
    ),
    SignalSpec(
        "CURRENT", "hf", "Actual torque-generating drive current (Iq), signed.", "A", "A",
        "Actual current", ("Current", "ActualCurrent"),
        note="Likely $AA_CURR = r0078 (not stated by Siemens for HF).",
    ),
    SignalSpec(
        "TORQUE", "hf", "Torque setpoint sent to the current setpoint filter.", "N", "Nm",
        "Torque setpoint", ("Torque", "TorqueSetpoint"),
        note="Likely $AA_TORQUE = r0079.",
    ),
    SignalSpec(
        "LOAD", "hf", "Drive load as a percentage of the rated torque.", "%", "%", "Load",
        ("Load",), note="Likely $AA_LOAD = r0081.",
    ),
    SignalSpec(
        "POWER", "hf", "Actual active power of the drive.", "W", "W", "Power", ("Power",),
        note="Likely $AA_POWER = r0082; pysiedge notes a wrong declared type in some headers.",
    ),
)

_LF: tuple[SignalSpec, ...] = (
    SignalSpec(
        "SPEED_SMOOTHED", "lf", "Smoothed actual motor speed (100 ms smoothing).", "mm/min", "rpm",
        "Actual speed smoothed", ("ActualSpeedSmoothed", "r0063"), sinamics_parameter="r0063",
        opcua_path="ns=2;s=/DriveVsa/Drive/r0063[u<DO>]",
    ),
    SignalSpec(
        "CURRENT_ABS_SMOOTHED", "lf", "Smoothed absolute actual current sqrt(Id^2 + Iq^2).",
        "A rms", "A rms", "Smoothed absolute current", ("AbsoluteCurrentSmoothed", "r0068"),
        sinamics_parameter="r0068", opcua_path="ns=2;s=/DriveVsa/Drive/r0068[u<DO>]",
    ),
    SignalSpec(
        "MOTOR_TEMP", "lf", "Actual motor temperature.", "degC", "degC", "Temperature",
        ("MotorTemperature", "r0035"), sinamics_parameter="r0035",
        opcua_path="ns=2;s=/DriveVsa/Drive/r0035[u<DO>]",
    ),
    SignalSpec(
        "IQ_ACT", "lf", "Actual torque-generating (quadrature-axis) current, smoothed.", "A rms",
        "A rms", "Actual quadrature-axis current", ("ActualIq", "r0078"),
        sinamics_parameter="r0078", opcua_path="ns=2;s=/DriveVsa/Drive/r0078[u<DO>]",
    ),
    SignalSpec(
        "TORQUE_UTIL", "lf", "Torque utilization as a percentage of the available torque.", "%",
        "%", "Torque utilization", ("TorqueUtilization", "r0081"), sinamics_parameter="r0081",
        opcua_path="ns=2;s=/DriveVsa/Drive/r0081[u<DO>]",
    ),
)

CATALOG: dict[str, SignalSpec] = {s.code: s for s in (*_HF, *_LF)}
"""All catalog entries by code."""

HF_CODES: tuple[str, ...] = tuple(s.code for s in _HF)
"""HF codes of the SINUMERIK Connector, in catalog order."""

LF_CODES: tuple[str, ...] = tuple(s.code for s in _LF)
"""Low-frequency drive values of thesis Table 2.2."""

DEFAULT_AXIS_MAP: dict[int, str] = {1: "X1", 2: "Y1", 3: "Z1", 4: "C1", 5: "B1", 6: "SP1"}
"""Axis number -> axis name of the thesis' 5-axis machine (and the DMU80 map in pysiedge)."""

_ALIASES: dict[str, str] = {}
for _spec in CATALOG.values():
    _ALIASES[_spec.code.lower()] = _spec.code
    for _alias in _spec.aliases:
        _ALIASES[_alias.lower()] = _spec.code
    if _spec.thesis_name and _spec.thesis_name != "time base":
        _ALIASES[_spec.thesis_name.lower()] = _spec.code



def axis_kind(axis: str) -> AxisKind:
    """Classify an axis name: ``SP1``/``S1`` spindle, ``A``/``B``/``C`` rotary, else linear.

    Parameters
    ----------
    axis : str
        Machine axis name (``"X1"``, ``"SP1"``, ``"C1"``).

    Returns
    -------
    {'linear', 'rotary', 'spindle'}
    """
    name = axis.strip().upper()
    if name.startswith("SP") or re.fullmatch(r"S\d*", name):
        return "spindle"
    if re.fullmatch(r"[ABC]\d*", name):
        return "rotary"
    return "linear"


def lookup(name: str) -> SignalSpec:
    """Find a catalog entry by code, alias, thesis name or column name.

    Parameters
    ----------
    name : str
        ``"CURRENT"``, ``"ActualAxisPosition"``, ``"Encoder position"`` or ``"CURRENT|SP1"``;
        a ``|axis`` suffix is ignored.

    Returns
    -------
    SignalSpec

    Raises
    ------
    SignalNotFoundError
        If the name is unknown; the message lists the known codes.
    """
    base = name.split("|", 1)[0].strip()
    code = _ALIASES.get(base.lower())
    if code is None:
        raise SignalNotFoundError(
            f"unknown signal {name!r}; known codes: {', '.join(CATALOG)}"
        )
    return CATALOG[code]


def column(code: str, axis: str) -> str:
    """Column name ``CODE|AXIS`` of a signal on an axis (``column('CURRENT', 'SP1')``).

    Parameters
    ----------
    code : str
        Signal code (``CURRENT``).
    axis : str
        Axis name (``SP1``).

    Returns
    -------
    str
        ``CODE|AXIS``.
    """
    return f"{code}|{axis}"


def parse_column(name: str) -> tuple[str, str | None]:
    """Split ``"CURRENT|SP1"`` into ``("CURRENT", "SP1")``; ``"CYCLE"`` -> ``("CYCLE", None)``.

    Parameters
    ----------
    name : str
        Column name (``CURRENT|SP1``, ``time``).

    Returns
    -------
    tuple
        (code, axis or None).
    """
    if "|" in name:
        code, axis = name.split("|", 1)
        return code, axis
    return name, None


def unit(name: str) -> str:
    """Unit of a column ``CODE|AXIS`` from the catalog; ``""`` for codes not in the catalog.

    Parameters
    ----------
    name : str
        Column name or signal code.

    Returns
    -------
    str
        The catalog unit (``''`` when unknown).
    """
    code, axis = parse_column(name)
    spec = CATALOG.get(code)
    return spec.unit_for(axis) if spec else ""


def glossary_markdown(specs: Iterable[SignalSpec] | None = None) -> str:
    """The signal glossary as a Markdown page (generated from :data:`CATALOG`).

    Parameters
    ----------
    specs : iterable, optional
        Signal specs; default the whole catalog.

    Returns
    -------
    str
        A Markdown table.
    """
    specs = list(CATALOG.values()) if specs is None else list(specs)
    lines = [
        "# Signal glossary",
        "",
        "Generated from `cnctwin.signals.CATALOG` by `python -m cnctwin.signals --glossary`.",
        "Do not edit by hand. Columns of a recording are named `CODE|AXIS`, e.g. `CURRENT|SP1`.",
        "",
    ]
    for kind, title in (("hf", "High-frequency signals (one per 2 ms position-control cycle)"),
                        ("lf", "Low-frequency drive values (thesis Table 2.2)")):
        lines += [f"## {title}", "",
                  "| code | description | unit (linear) | unit (rotary/spindle) | thesis name | "
                  "aliases | SINAMICS | note |",
                  "|---|---|---|---|---|---|---|---|"]
        for s in specs:
            if s.kind != kind:
                continue
            lines.append(
                f"| `{s.code}` | {s.description} | {s.unit_linear} | {s.unit_rotary}"
                f"{f' (spindle: {s.unit_spindle})' if s.unit_spindle else ''} | "
                f"{s.thesis_name} | {', '.join(s.aliases)} | {s.sinamics_parameter} | {s.note} |"
            )
        lines.append("")
    return "\n".join(lines)


def _main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m cnctwin.signals")
    parser.add_argument("--glossary", type=Path, help="write the glossary Markdown page here")
    args = parser.parse_args(argv)
    text = glossary_markdown()
    if args.glossary:
        args.glossary.parent.mkdir(parents=True, exist_ok=True)
        args.glossary.write_text(text, encoding="utf-8")
    else:
        print(text)



if __name__ == "__main__":
    _main()
