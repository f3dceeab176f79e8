"""MTConnect out: a device model, a sequence-numbered circular buffer, the agent's documents
(``probe``, ``current``, ``sample``) and an SHDR adapter.

MTConnect 2.3 (namespaces ``urn:mtconnect.org:MTConnect{Devices,Streams,Error}:2.3``; the
documents validate against the official XSD files, tests/data/mtconnect/). The device model
(:func:`machine_tool_device`):

=====================  ==========================  =================================================
component              data item (id)              MTConnect type, units
=====================  ==========================  =================================================
Device                 ``avail``                   EVENT AVAILABILITY
Axes / Linear X, Y, Z  ``<axis>_pos``              SAMPLE POSITION ACTUAL, MILLIMETER
                       ``<axis>_load``             SAMPLE LOAD, PERCENT
Axes / Rotary C        ``<sp>_speed``              SAMPLE ROTARY_VELOCITY ACTUAL, REVOLUTION/MINUTE
(the spindle)          ``<sp>_load``               SAMPLE LOAD, PERCENT
                       ``<sp>_power``              SAMPLE WATTAGE, WATT
                       ``<sp>_cut_torque``         SAMPLE TORQUE, NEWTON_METER (cnctwin: cutting
                                                   torque from the drive current)
                       ``<sp>_hole_torque``        SAMPLE TORQUE, NEWTON_METER (cnctwin: mean
                                                   cutting torque of the last hole)
                       ``<sp>_cond``               CONDITION LOAD (cnctwin alarms)
Controller / Path      ``program``                 EVENT PROGRAM
                       ``tool``                    EVENT TOOL_NUMBER
                       ``holes``                   EVENT CYCLE_COUNT (cnctwin: holes drilled)
                       ``hole_record``             EVENT MESSAGE (cnctwin: the per-hole record)
                       ``wear``                    EVENT MESSAGE (cnctwin: wear index)
                       ``system``                  CONDITION SYSTEM (runtime overload)
Device                 ``asset_chg``               EVENT ASSET_CHANGED (a tool's asset updated)
=====================  ==========================  =================================================

Assets (``/assets``, ``/asset/ID``; :func:`assets_document`, namespace
``urn:mtconnect.org:MTConnectAssets:2.3``): one ``CuttingTool`` per tool of the tool table
(:func:`cutting_tool`), its ``CuttingToolLifeCycle`` carrying cnctwin's tool life: the
``CutterStatus`` (NEW, USED, EXPIRED, BROKEN), ``ToolLife`` ``PART_COUNT`` counting up (holes
drilled, ``limit`` the planned life), ``PART_COUNT`` counting down (the remaining-life
forecast, its 90 % interval in the ``Description``) and ``WEAR`` (the flank-wear estimate
[µm] against its limit), and the ``ProgramToolNumber``.

The buffer (:class:`ObservationBuffer`) numbers every observation; ``sample?from=&count=``
returns the observations ``from .. from+count-1`` still in the buffer and ``nextSequence``
(the one to ask for next), so a client that follows ``nextSequence`` sees every observation
once; asking for one that has left the buffer is an ``OUT_OF_RANGE`` error document (never a
silent skip).

References
----------
MTConnect Standard Part 1-4, version 2.3; cppagent's schemas/ (Apache 2.0).
"""

from __future__ import annotations

import math
import threading
import time
import uuid as uuidlib
import xml.etree.ElementTree as ET
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

from cnctwin.exceptions import ConfigError

__all__ = [
    "MTCONNECT_VERSION",
    "NS_ASSETS",
    "NS_DEVICES",
    "NS_ERROR",
    "NS_STREAMS",
    "AssetStore",
    "Component",
    "CuttingToolAsset",
    "DataItem",
    "DeviceModel",
    "Observation",
    "ObservationBuffer",
    "OutOfRangeError",
    "assets_document",
    "cutting_tool",
    "error_document",
    "iso_timestamp",
    "item_key",
    "machine_tool_device",
    "path_items",
    "probe_document",
    "streams_document",
]

MTCONNECT_VERSION = "2.3"
NS_DEVICES = f"urn:mtconnect.org:MTConnectDevices:{MTCONNECT_VERSION}"
NS_STREAMS = f"urn:mtconnect.org:MTConnectStreams:{MTCONNECT_VERSION}"
NS_ERROR = f"urn:mtconnect.org:MTConnectError:{MTCONNECT_VERSION}"
NS_ASSETS = f"urn:mtconnect.org:MTConnectAssets:{MTCONNECT_VERSION}"
UNAVAILABLE = "UNAVAILABLE"


@dataclass(frozen=True)
class DataItem:
    """One MTConnect data item.

    Attributes
    ----------
    id : str
        Unique id (the SHDR key too).
    category : {'SAMPLE', 'EVENT', 'CONDITION'}
        Category.
    type : str
        MTConnect type (``POSITION``, ``ROTARY_VELOCITY``, ...).
    component : str
        Id of the component it belongs to.
    units : str, optional
        MTConnect units (samples).
    sub_type : str, optional
        ``ACTUAL``, ``COMMANDED``, ...
    name : str, optional
        Name.
    """

    id: str
    category: str
    type: str
    component: str
    units: str | None = None
    sub_type: str | None = None
    name: str | None = None

    @property
    def element(self) -> str:
        """The observation's element name in a Streams document (``ROTARY_VELOCITY`` ->
        ``RotaryVelocity``)."""
        return "".join(p.capitalize() for p in self.type.split("_"))


@dataclass(frozen=True)
class Component:
    """A component of the device: ``kind`` is its element name (``Axes``, ``Linear``, ...)."""

    id: str
    kind: str
    name: str | None = None
    parent: str | None = None


@dataclass(frozen=True)
class DeviceModel:
    """A device: its components (parents first) and data items."""

    id: str
    name: str
    uuid: str
    components: tuple[Component, ...]
    data_items: tuple[DataItem, ...]

    def item(self, item_id: str) -> DataItem:
        """The data item with this id."""
        for d in self.data_items:
            if d.id == item_id:
                return d
        raise KeyError(item_id)

    def component(self, component_id: str) -> Component | None:
        """The component with this id (None for the device itself)."""
        for c in self.components:
            if c.id == component_id:
                return c
        return None


def item_key(name: str) -> str:
    """The data-item id prefix of an axis or spindle name (``"X1"`` -> ``"x1"``).

    Parameters
    ----------
    name : str
        Axis or spindle name (``X1``, ``SP1``).

    Returns
    -------
    str
        The lower-case prefix of its data items' ids.
    """
    return "".join(ch if ch.isalnum() else "_" for ch in name).lower()


def machine_tool_device(
    machine: str, *, axes: Sequence[str] = ("X1", "Y1", "Z1"), spindle: str = "SP1",
) -> DeviceModel:
    """The device model of a SINUMERIK machine tool as cnctwin sees it (module table).

    Parameters
    ----------
    machine : str
        Machine name (the device's ``name``; its ``uuid`` derives from it).
    axes : sequence of str, default ('X1', 'Y1', 'Z1')
        Linear axes (their MTConnect names are the letters: ``X1`` -> ``X``).
    spindle : str, default 'SP1'
        The spindle (a Rotary component named ``C`` in rotary-velocity mode).

    Returns
    -------
    DeviceModel
    """
    dev = item_key(machine) or "machine"
    comps: list[Component] = [Component("axes", "Axes"), Component("ctrl", "Controller"),
                              Component("path", "Path", parent="ctrl")]
    items: list[DataItem] = [DataItem("avail", "EVENT", "AVAILABILITY", dev),
                             DataItem("asset_chg", "EVENT", "ASSET_CHANGED", dev)]
    for ax in axes:
        k = item_key(ax)
        comps.append(Component(k, "Linear", name=ax.rstrip("0123456789") or ax, parent="axes"))
        items += [DataItem(f"{k}_pos", "SAMPLE", "POSITION", k, "MILLIMETER", "ACTUAL",
                           f"{ax}_actual"),
                  DataItem(f"{k}_load", "SAMPLE", "LOAD", k, "PERCENT", name=f"{ax}_load")]
    sp = item_key(spindle)
    comps.append(Component(sp, "Rotary", name="C", parent="axes"))
    items += [
        DataItem(f"{sp}_speed", "SAMPLE", "ROTARY_VELOCITY", sp, "REVOLUTION/MINUTE", "ACTUAL",
                 f"{spindle}_speed"),
        DataItem(f"{sp}_load", "SAMPLE", "LOAD", sp, "PERCENT", name=f"{spindle}_load"),
        DataItem(f"{sp}_power", "SAMPLE", "WATTAGE", sp, "WATT", name=f"{spindle}_power"),
        DataItem(f"{sp}_cut_torque", "SAMPLE", "TORQUE", sp, "NEWTON_METER",
                 name="cutting_torque"),
        DataItem(f"{sp}_hole_torque", "SAMPLE", "TORQUE", sp, "NEWTON_METER",
                 name="hole_mean_cutting_torque"),
        DataItem(f"{sp}_cond", "CONDITION", "LOAD", sp, name="cnctwin_alarm"),
        DataItem("program", "EVENT", "PROGRAM", "path"),
        DataItem("tool", "EVENT", "TOOL_NUMBER", "path"),
        DataItem("holes", "EVENT", "CYCLE_COUNT", "path", name="holes"),
        DataItem("hole_record", "EVENT", "MESSAGE", "path", name="hole_record"),
        DataItem("wear", "EVENT", "MESSAGE", "path", name="wear_index"),
        DataItem("system", "CONDITION", "SYSTEM", "path", name="runtime"),
    ]
    return DeviceModel(dev, machine, str(uuidlib.uuid5(uuidlib.NAMESPACE_URL,
                                                         f"cnctwin:{machine}")),
                       tuple(comps), tuple(items))


# ---------------------------------------------------------------------------- buffer
@dataclass(frozen=True)
class Observation:
    """One observation: sequence number, data item, time and value.

    For a condition, ``value`` is the level (``NORMAL``, ``WARNING``, ``FAULT``,
    ``UNAVAILABLE``) and ``native_code``/``message`` describe it.
    """

    sequence: int
    item_id: str
    timestamp_ns: int
    value: Any
    native_code: str | None = None
    message: str | None = None


class OutOfRangeError(ConfigError):
    """A ``sample`` request for sequence numbers the buffer no longer (or not yet) holds."""


@dataclass
class ObservationBuffer:
    """A sequence-numbered circular buffer of observations (thread-safe).

    Parameters
    ----------
    size : int, default 131072
        Observations kept (MTConnect ``bufferSize``).
    """

    size: int = 131_072
    instance_id: int = field(default_factory=lambda: int(time.time()))
    _obs: deque[Observation] = field(init=False, repr=False)
    _latest: dict[str, Observation] = field(init=False, repr=False, default_factory=dict)
    _next: int = field(init=False, default=1)
    _lock: threading.Lock = field(init=False, repr=False, default_factory=threading.Lock)

    def __post_init__(self) -> None:
        if not isinstance(self.size, int) or self.size < 1:
            raise ConfigError(f"the MTConnect buffer size must be a positive integer, not "
                              f"{self.size!r}")
        self._obs = deque(maxlen=self.size)

    def add(self, item_id: str, timestamp_ns: int, value: Any, *,
            native_code: str | None = None, message: str | None = None) -> int:
        """Append one observation; returns its sequence number."""
        with self._lock:
            seq = self._next
            ob = Observation(seq, item_id, int(timestamp_ns), value, native_code, message)
            self._obs.append(ob)
            self._latest[item_id] = ob
            self._next += 1
            return seq

    @property
    def next_sequence(self) -> int:
        """The sequence number the next observation will get."""
        return self._next

    @property
    def first_sequence(self) -> int:
        """The oldest sequence number still in the buffer (= next when empty)."""
        with self._lock:
            return self._obs[0].sequence if self._obs else self._next

    def current(self) -> tuple[list[Observation], int, int]:
        """The newest observation of every data item, ``firstSequence``, ``nextSequence``."""
        with self._lock:
            first = self._obs[0].sequence if self._obs else self._next
            return sorted(self._latest.values(), key=lambda o: o.sequence), first, self._next

    def sample(self, start: int | None = None, count: int = 100, *,
               to: int | None = None, items: set[str] | None = None) -> tuple[
            list[Observation], int, int, int]:
        """Observations from ``start`` (at most ``count``, before ``to``) that are in the
        buffer, of the data items ``items`` (all without it).

        Parameters
        ----------
        start : int, optional
            First sequence number; default the oldest in the buffer (with a negative
            ``count``: not allowed, the window ends at ``to``).
        count : int, default 100
            Most observations returned (1 ... buffer size); negative: the last ``-count``
            before ``to`` (MTConnect 1.7 ``count=-n``).
        to : int, optional
            Sequence number to stop before (default: the next).
        items : set of str, optional
            Data item ids to return (the agent's ``path=`` filter).

        Returns
        -------
        observations, first_sequence, next_sequence, last_sequence
            ``next_sequence`` is the one after the last returned (the one to ask for next).

        Raises
        ------
        OutOfRangeError
            ``start`` or ``to`` outside the buffer, ``count`` 0 or beyond the buffer size.
        """
        if not isinstance(count, int) or count == 0 or abs(count) > self.size:
            raise OutOfRangeError(f"count must be 1 ... {self.size} or -1 ... -{self.size} "
                                  f"(the buffer size), not {count!r}")
        with self._lock:
            first = self._obs[0].sequence if self._obs else self._next
            last = self._next - 1
            end = self._next if to is None else int(to)
            if end < first or end > self._next:
                raise OutOfRangeError(f"'to' must be {first} ... {self._next} (the buffer "
                                      f"holds {first} ... {last}), not {end}")

            def keep(o: Observation) -> bool:
                return items is None or o.item_id in items

            if count < 0:
                if start is not None:
                    raise OutOfRangeError("a negative count takes no 'from': it counts back "
                                          "from 'to' (or the newest)")
                out: list[Observation] = []
                for j in range(end - first - 1, -1, -1):
                    if keep(self._obs[j]):
                        out.append(self._obs[j])
                        if len(out) == -count:
                            break
                out.reverse()
                return out, first, (out[-1].sequence + 1 if out else end), last
            s = first if start is None else int(start)
            if s < first or s > self._next:
                raise OutOfRangeError(
                    f"'from' must be {first} ... {self._next} (the buffer holds {first} ... "
                    f"{last}); {s} has {'left' if s < first else 'not reached'} the buffer")
            out = []
            j = s - first
            stop = max(end - first, j)
            while j < stop and len(out) < count:
                if keep(self._obs[j]):
                    out.append(self._obs[j])
                j += 1
            # the next request starts after what was scanned (the filter's gaps included)
            nxt = first + j if out and len(out) == count else max(first + j, s)
            return out, first, nxt, last


# ---------------------------------------------------------------------------- documents
def path_items(model: DeviceModel, buffer: ObservationBuffer, path: str) -> set[str]:
    """The data item ids an MTConnect ``path=`` XPath selects in the device model.

    The XPath is evaluated on the ``/probe`` document without its namespace (clients write
    ``//Axes//DataItem[@type="POSITION"]``); a matched ``DataItem`` counts itself, any other
    matched element every ``DataItem`` below it.

    Parameters
    ----------
    model : DeviceModel
        The device.
    buffer : ObservationBuffer
        The agent's buffer (the probe document's header).
    path : str
        XPath 1.0.

    Returns
    -------
    set of str

    Raises
    ------
    ConfigError
        Not a valid XPath (the agent answers ``INVALID_PATH``).
    """
    from lxml import etree

    doc = etree.fromstring(probe_document(model, buffer))
    for el in doc.iter():
        if isinstance(el.tag, str) and "}" in el.tag:
            el.tag = el.tag.split("}", 1)[1]
    etree.cleanup_namespaces(doc)
    try:
        found = doc.xpath(path)
    except etree.XPathError as exc:
        raise ConfigError(f"path {path!r} is not a valid XPath: {exc}") from None
    ids: set[str] = set()
    for el in found if isinstance(found, list) else []:
        if not isinstance(el, etree._Element):
            continue
        if el.tag == "DataItem":
            ids.add(str(el.get("id")))
        ids.update(str(d.get("id")) for d in el.iter("DataItem"))
    return ids


def iso_timestamp(t_ns: int) -> str:
    """MTConnect/SHDR timestamp of ``t_ns`` [ns since the epoch], UTC, microseconds.

    Parameters
    ----------
    t_ns : int
        Time [ns since the epoch, UTC].

    Returns
    -------
    str
        ISO 8601 with microseconds and ``Z``.
    """
    s, ns = divmod(int(t_ns), 1_000_000_000)
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(s)) + f".{ns // 1000:06d}Z"


def _header(root: ET.Element, tag: str, *, sender: str, instance_id: int,
            buffer_size: int | None, extra: dict[str, str], model_time: bool = True
            ) -> ET.Element:
    h = ET.SubElement(root, tag)
    h.set("creationTime", iso_timestamp(time.time_ns()).split(".")[0] + "Z")
    h.set("sender", sender)
    h.set("instanceId", str(instance_id))
    h.set("version", f"{MTCONNECT_VERSION}.0")
    if buffer_size is not None:  # an assets header has none
        h.set("bufferSize", str(buffer_size))
    if model_time:
        h.set("deviceModelChangeTime", iso_timestamp(instance_id * 1_000_000_000))
    for k, v in extra.items():
        h.set(k, v)
    return h


def _doc(root: ET.Element) -> bytes:
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="utf-8")


def probe_document(model: DeviceModel, buffer: ObservationBuffer, *,
                   sender: str = "cnctwin", asset_count: int = 0,
                   asset_buffer_size: int = 1024) -> bytes:
    """The ``/probe`` document (MTConnectDevices): the device model.

    Parameters
    ----------
    model : DeviceModel
        The device model.
    buffer : ObservationBuffer
        The agent's observation buffer (for the header).
    sender : str, default 'cnctwin'
        Agent host name in the header.
    asset_count, asset_buffer_size : int
        Assets held and the most the agent keeps (header).

    Returns
    -------
    bytes
        An ``MTConnectDevices`` XML document.
    """
    root = ET.Element("MTConnectDevices", {"xmlns": NS_DEVICES})
    _header(root, "Header", sender=sender, instance_id=buffer.instance_id,
            buffer_size=buffer.size, extra={"assetBufferSize": str(asset_buffer_size),
                                            "assetCount": str(asset_count)})
    devices = ET.SubElement(root, "Devices")
    dev = ET.SubElement(devices, "Device", {"id": model.id, "name": model.name,
                                            "uuid": model.uuid})
    ET.SubElement(dev, "Description", {"manufacturer": "cnctwin"}).text = (
        f"{model.name}: SINUMERIK drive signals and cnctwin's digital-twin results")
    elements: dict[str | None, ET.Element] = {None: dev}
    holders: dict[str | None, ET.Element] = {}

    def items_of(cid: str | None, parent: ET.Element) -> None:
        mine = [d for d in model.data_items if d.component == (cid or model.id)]
        if not mine:
            return
        box = ET.SubElement(parent, "DataItems")
        for d in mine:
            attrs = {"id": d.id, "category": d.category, "type": d.type}
            if d.sub_type:
                attrs["subType"] = d.sub_type
            if d.units:
                attrs["units"] = d.units
            if d.name:
                attrs["name"] = d.name
            ET.SubElement(box, "DataItem", attrs)

    items_of(None, dev)
    for c in model.components:
        parent = elements[c.parent]
        if c.parent not in holders:
            holders[c.parent] = ET.SubElement(parent, "Components")
        attrs = {"id": c.id}
        if c.name:
            attrs["name"] = c.name
        el = ET.SubElement(holders[c.parent], c.kind, attrs)
        elements[c.id] = el
        items_of(c.id, el)
    return _doc(root)


def streams_document(
    model: DeviceModel, observations: Iterable[Observation], *, buffer: ObservationBuffer,
    first_sequence: int, next_sequence: int, last_sequence: int, sender: str = "cnctwin",
) -> bytes:
    """A ``/current`` or ``/sample`` document (MTConnectStreams).

    Parameters
    ----------
    model : DeviceModel
        The device model.
    observations : iterable
        Observations to include, in sequence order.
    buffer : ObservationBuffer
        The agent's observation buffer.
    first_sequence : int
        First sequence number the buffer holds.
    next_sequence : int
        Sequence number of the next observation.
    last_sequence : int
        Last sequence number the buffer holds.
    sender : str, default 'cnctwin'
        Agent host name in the header.

    Returns
    -------
    bytes
        An ``MTConnectStreams`` XML document.
    """
    root = ET.Element("MTConnectStreams", {"xmlns": NS_STREAMS})
    _header(root, "Header", sender=sender, instance_id=buffer.instance_id,
            buffer_size=buffer.size,
            extra={"firstSequence": str(first_sequence), "nextSequence": str(next_sequence),
                   "lastSequence": str(last_sequence)})
    streams = ET.SubElement(root, "Streams")
    ds = ET.SubElement(streams, "DeviceStream", {"name": model.name, "uuid": model.uuid})
    by_comp: dict[str, list[Observation]] = {}
    for ob in sorted(observations, key=lambda o: o.sequence):
        by_comp.setdefault(model.item(ob.item_id).component, []).append(ob)
    order = [model.id, *[c.id for c in model.components]]
    for cid in order:
        obs = by_comp.get(cid)
        if not obs:
            continue
        comp = model.component(cid)
        attrs = {"component": comp.kind if comp else "Device", "componentId": cid}
        if comp is not None and comp.name:
            attrs["name"] = comp.name
        if comp is None:
            attrs["name"] = model.name
        cs = ET.SubElement(ds, "ComponentStream", attrs)
        for cat, tag in (("SAMPLE", "Samples"), ("EVENT", "Events"), ("CONDITION", "Condition")):
            group = [o for o in obs if model.item(o.item_id).category == cat]
            if not group:
                continue
            box = ET.SubElement(cs, tag)
            for o in group:
                _observation(box, model.item(o.item_id), o)
    return _doc(root)


def _observation(box: ET.Element, d: DataItem, o: Observation) -> None:
    attrs = {"dataItemId": d.id, "timestamp": iso_timestamp(o.timestamp_ns),
             "sequence": str(o.sequence)}
    if d.name:
        attrs["name"] = d.name
    if d.sub_type:
        attrs["subType"] = d.sub_type
    if d.category == "CONDITION":
        level = str(o.value).upper()
        tag = {"NORMAL": "Normal", "WARNING": "Warning", "FAULT": "Fault"}.get(level,
                                                                              "Unavailable")
        attrs["type"] = d.type
        if tag in ("Warning", "Fault"):
            attrs["conditionId"] = o.native_code or d.id
        if o.native_code:
            attrs["nativeCode"] = o.native_code
        el = ET.SubElement(box, tag, attrs)
        if o.message:
            el.text = o.message
        return
    if d.type == "ASSET_CHANGED":
        attrs["assetType"] = "CuttingTool" if o.value is not None else "UNAVAILABLE"
    el = ET.SubElement(box, d.element, attrs)
    v = o.value
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        el.text = UNAVAILABLE
    elif isinstance(v, float):
        el.text = f"{v:.6g}"
    else:
        el.text = str(v)


def error_document(code: str, message: str, *, buffer: ObservationBuffer,
                   sender: str = "cnctwin") -> bytes:
    """An MTConnectError document (``OUT_OF_RANGE``, ``INVALID_REQUEST``, ...).

    Parameters
    ----------
    code : str
        MTConnect error code (``INVALID_REQUEST``, ``OUT_OF_RANGE``, ...).
    message : str
        What went wrong, for the client.
    buffer : ObservationBuffer
        The agent's observation buffer (for the header).
    sender : str, default 'cnctwin'
        Agent host name in the header.

    Returns
    -------
    bytes
        An ``MTConnectError`` XML document.
    """
    root = ET.Element("MTConnectError", {"xmlns": NS_ERROR})
    _header(root, "Header", sender=sender, instance_id=buffer.instance_id,
            buffer_size=buffer.size, extra={}, model_time=False)
    errors = ET.SubElement(root, "Errors")
    ET.SubElement(errors, "Error", {"errorCode": code}).text = message
    return _doc(root)


# ---------------------------------------------------------------------------- assets
@dataclass(frozen=True)
class CuttingToolAsset:
    """One ``CuttingTool`` asset (MTConnect Part 4, Cutting Tools).

    Attributes
    ----------
    asset_id : str
        Unique asset id (``<device>.T<n>``).
    tool_id : str
        The tool's id (``T<n>``).
    serial_number : str
        Serial number of the physical tool (cnctwin: the tool table's name).
    timestamp_ns : int
        Time of the last change [ns since the epoch].
    status : tuple of str
        ``CutterStatus`` values (``NEW``, ``USED``, ``EXPIRED``, ``BROKEN``, ...).
    life : tuple
        ``ToolLife`` entries: (type, countDirection, value, limit or None, initial or None),
        at most three (``PART_COUNT``, ``MINUTES``, ``WEAR``).
    program_tool_number : int
        The T number of the program.
    description : str
        Free text (the remaining-life forecast with its interval and basis).
    """

    asset_id: str
    tool_id: str
    serial_number: str
    timestamp_ns: int
    status: tuple[str, ...] = ("NEW",)
    life: tuple[tuple[str, str, float, float | None, float | None], ...] = ()
    program_tool_number: int = 0
    description: str = ""


def cutting_tool(device: str, number: int, spec: dict[str, Any],
                 life: dict[str, Any] | None = None, *, timestamp_ns: int,
                 broken: bool = False) -> CuttingToolAsset:
    """The ``CuttingTool`` asset of a tool-table entry and its latest ``tool_life`` result.

    Parameters
    ----------
    device : str
        The device id (prefix of the asset id).
    number : int
        T number.
    spec : dict
        The tool table's entry (``name``, ``kind``, ``diameter_mm``, ``life_holes``,
        ``wear_limit_um``).
    life : dict, optional
        The latest ``tool_life`` payload of the tool (None: not used yet).
    timestamp_ns : int
        Time of the change [ns since the epoch].
    broken : bool, default False
        A breakage alarm of this tool: status ``BROKEN``.

    Returns
    -------
    CuttingToolAsset
    """
    used = int((life or {}).get("used_holes") or 0)
    entries: list[tuple[str, str, float, float | None, float | None]] = []
    limit = spec.get("life_holes")
    entries.append(("PART_COUNT", "UP", float(used),
                    None if limit is None else float(limit), 0.0))
    text = [f"T{number} {spec.get('kind', 'tool')} D{spec.get('diameter_mm', '?')} mm"]
    remaining = (life or {}).get("remaining_holes")
    status = ["NEW"] if used == 0 else ["USED"]
    if life is not None and (remaining is not None or life.get("never_reaches_limit")):
        rem = math.inf if remaining is None else float(remaining)
        lo, hi = life.get("remaining_low"), life.get("remaining_high")
        if math.isfinite(rem):
            entries.append(("PART_COUNT", "DOWN", rem, 0.0, None))
        text.append(f"remaining life {rem:.0f} holes (90 %: {_fmt(lo)} - {_fmt(hi)}), "
                    f"basis {life.get('basis', '')}")
        if math.isfinite(rem) and rem <= 0.0:
            status = ["EXPIRED"]
    elif life is not None and life.get("reason"):
        text.append(f"remaining life unknown: {life['reason']}")
    wear = (life or {}).get("wear_um")
    if wear is not None and spec.get("wear_limit_um") is not None:
        entries.append(("WEAR", "UP", float(wear), float(spec["wear_limit_um"]), 0.0))
    if broken:
        status = ["BROKEN"]
    return CuttingToolAsset(asset_id=f"{device}.T{number}", tool_id=f"T{number}",
                            serial_number=str(spec.get("name") or f"T{number}"),
                            timestamp_ns=int(timestamp_ns), status=tuple(status),
                            life=tuple(entries), program_tool_number=int(number),
                            description="; ".join(text))


def _fmt(v: Any) -> str:
    return "inf" if v is None else f"{float(v):.0f}"


def assets_document(model: DeviceModel, assets: Iterable[CuttingToolAsset], *,
                    buffer: ObservationBuffer, asset_buffer_size: int = 1024,
                    asset_count: int | None = None, sender: str = "cnctwin") -> bytes:
    """An ``/assets`` or ``/asset/ID`` document (MTConnectAssets).

    Parameters
    ----------
    model : DeviceModel
        The device (``deviceUuid`` of the assets).
    assets : iterable of CuttingToolAsset
        The assets to include.
    buffer : ObservationBuffer
        The agent's observation buffer (for the header).
    asset_buffer_size : int, default 1024
        The most assets the agent keeps.
    asset_count : int, optional
        Assets the agent holds (default: those given).
    sender : str, default 'cnctwin'
        Agent host name in the header.

    Returns
    -------
    bytes
        An ``MTConnectAssets`` XML document.
    """
    items = list(assets)
    root = ET.Element("MTConnectAssets", {"xmlns": NS_ASSETS})
    _header(root, "Header", sender=sender, instance_id=buffer.instance_id,
            buffer_size=None,
            extra={"assetBufferSize": str(asset_buffer_size),
                   "assetCount": str(len(items) if asset_count is None else asset_count)})
    box = ET.SubElement(root, "Assets")
    for a in items:
        el = ET.SubElement(box, "CuttingTool", {
            "assetId": a.asset_id, "timestamp": iso_timestamp(a.timestamp_ns),
            "deviceUuid": model.uuid, "serialNumber": a.serial_number, "toolId": a.tool_id})
        if a.description:
            ET.SubElement(el, "Description").text = a.description
        cycle = ET.SubElement(el, "CuttingToolLifeCycle")
        st = ET.SubElement(cycle, "CutterStatus")
        for v in a.status:
            ET.SubElement(st, "Status").text = v
        for kind, direction, value, limit, initial in a.life[:3]:
            attrs = {"type": kind, "countDirection": direction}
            if limit is not None:
                attrs["limit"] = f"{limit:.6g}"
            if initial is not None:
                attrs["initial"] = f"{initial:.6g}"
            ET.SubElement(cycle, "ToolLife", attrs).text = f"{value:.6g}"
        ET.SubElement(cycle, "ProgramToolNumber").text = str(a.program_tool_number)
    return _doc(root)


class AssetStore:
    """The agent's assets, newest change last, at most ``size`` (the oldest leave first).

    Parameters
    ----------
    size : int, default 1024
        Most assets kept (the header's ``assetBufferSize``).
    """

    def __init__(self, size: int = 1024) -> None:
        if size < 1:
            raise ConfigError(f"the asset buffer needs room for at least 1 asset, not {size}")
        self.size = size
        self._assets: dict[str, CuttingToolAsset] = {}
        self._lock = threading.Lock()
        self.changes = 0

    def put(self, asset: CuttingToolAsset) -> None:
        """Add or replace an asset (it becomes the newest)."""
        with self._lock:
            self._assets.pop(asset.asset_id, None)
            self._assets[asset.asset_id] = asset
            while len(self._assets) > self.size:
                self._assets.pop(next(iter(self._assets)))
            self.changes += 1

    def get(self, asset_id: str) -> CuttingToolAsset | None:
        """The asset with this id (None: not held)."""
        with self._lock:
            return self._assets.get(asset_id)

    def all(self, *, count: int | None = None) -> list[CuttingToolAsset]:
        """The assets, newest first, at most ``count``."""
        with self._lock:
            out = list(reversed(self._assets.values()))
        return out if count is None else out[:count]

    def __len__(self) -> int:
        with self._lock:
            return len(self._assets)
