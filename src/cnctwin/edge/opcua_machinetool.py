"""The OPC 40501 (Machine Tools, "umati") structure on the edge runtime's OPC UA server.

The official NodeSets (``cnctwin/data/nodesets``: DI, IA, Machinery, ISA95-JOBCONTROL_V2,
Machinery/Jobs, MachineTool; OPC Foundation MIT licence) are loaded into the asyncua server,
and one object of the companion specification's ``MachineToolType`` is created in Machinery's
``Machines`` folder, with its mandatory children and what cnctwin knows:

=====================================================  =========================================
browse path (namespace ``http://opcfoundation.org/      value
UA/MachineTool/`` unless marked)
=====================================================  =========================================
``<machine>/DI:Identification`` (``DI:Manufacturer``,     ``cnctwin``-given identification (machine
``DI:SerialNumber``, ``Machinery:ProductInstanceUri``)  name; manufacturer "unknown" unless set)
``<machine>/Monitoring/Spindle`` (SpindleMonitoring-   ``IsRotating`` (speed above 1 rpm),
Type)                                                  ``Name``; cnctwin's own ``ActualSpeed``
                                                       [rpm] and ``CuttingTorque`` [Nm]
``<machine>/Production/ActiveProgram``                 ``Name`` (program of the NC call), and
                                                       cnctwin's ``HoleCount``
``<machine>/Notification/Messages`` (event notifier)   cnctwin's ``AlarmActive``,
                                                       ``AlarmMessage``
=====================================================  =========================================

cnctwin's own variables (namespace ``urn:cnctwin:edge``) sit beside the specification's
children; the specification's structure and browse names are unchanged.
"""

from __future__ import annotations

from collections.abc import Mapping
from datetime import UTC, datetime
from importlib import resources
from typing import Any

__all__ = ["EU_CODES", "EU_NAMESPACE", "MACHINE_TOOL_NS", "NODESET_FILES", "PROGRAM_STATES",
           "add_machine_tool", "eu_information", "eu_unit_id", "program_state"]

EU_NAMESPACE = "http://www.opcfoundation.org/UA/units/un/cefact"
"""``NamespaceUri`` of UNECE units in OPC UA ``EUInformation`` (Part 8 §5.6.3)."""

EU_CODES: dict[str, str] = {
    "rpm": "RPM", "Nm": "NU", "um": "4H", "degC": "CEL", "mm": "MMT", "J": "JOU", "s": "SEC",
    "A": "AMP", "mm/min": "H81", "%": "P1", "one": "C62",
}
"""UNECE Recommendation 20 common codes of the units used (OPC UA Part 8, EUInformation)."""


def eu_unit_id(code: str) -> int:
    """``UnitId`` of an UNECE common code (OPC UA Part 8 §5.6.3: the code's bytes, big end).

    >>> eu_unit_id("CEL")
    4408652

    Parameters
    ----------
    code : str
        UNECE common code (``CEL``, ``AMP``, ``RPM``; at most 4 characters).

    Returns
    -------
    int
        The ``UnitId`` of OPC UA ``EUInformation``.
    """
    uid = 0
    for ch in code.upper()[:4]:
        uid = (uid << 8) | ord(ch)
    return uid


def eu_information(unit: str, description: str = "") -> Any:
    """OPC UA ``EUInformation`` of a unit of :data:`EU_CODES`.

    Parameters
    ----------
    unit : str
        A key of :data:`EU_CODES` (``"Nm"``, ``"um"``, ``"%"``, ``"one"``).
    description : str
        Its description (default: the unit).

    Returns
    -------
    asyncua.ua.EUInformation
    """
    from asyncua import ua

    return ua.EUInformation(NamespaceUri=EU_NAMESPACE, UnitId=eu_unit_id(EU_CODES[unit]),
                            DisplayName=ua.LocalizedText(unit),
                            Description=ua.LocalizedText(description or unit))

MACHINE_TOOL_NS = "http://opcfoundation.org/UA/MachineTool/"
IA_NS = "http://opcfoundation.org/UA/IA/"
MACHINERY_NS = "http://opcfoundation.org/UA/Machinery/"
DI_NS = "http://opcfoundation.org/UA/DI/"

NODESET_FILES = (
    "Opc.Ua.Di.NodeSet2.xml",
    "Opc.Ua.IA.NodeSet2.xml",
    "Opc.Ua.Machinery.NodeSet2.xml",
    "opc.ua.isa95-jobcontrol.nodeset2.xml",
    "Opc.Ua.Machinery.Jobs.Nodeset2.xml",
    "Opc.Ua.MachineTool.NodeSet2.xml",
)
"""The NodeSets in load order (each needs the ones before it)."""

# node ids in the MachineTool NodeSet (its own namespace): OPC 40501-1 v1.02
_MACHINE_TOOL_TYPE = 13
_SPINDLE_MONITORING_TYPE = 22
_CHANNEL_MONITORING_TYPE = 16
_BASIC_STACKLIGHT_TYPE = 1002  # IA
_STACK_ELEMENT_LIGHT_TYPE = 1006  # IA
LIGHTS = (("Green", 2), ("Yellow", 4), ("Red", 1))
"""The stack light's elements from the base up: name and IA ``SignalColor`` (Green 2, Yellow
4, Red 1): green while the machine runs without an alarm, yellow on a feed hold or overload
request of the adaptive feed, red while an alarm is active."""
_MACHINES_FOLDER = 1001  # Machinery
_PRODUCTION_STATISTICS_TYPE = 20
_TOOL_LIST_TYPE = 44
_TOOL_TYPE = 50
_TOOL_LIFE_TYPE = 61
_PROGNOSIS_LIST_TYPE = 2
_TOOL_CHANGE_PROGNOSIS_TYPE = 45
_EPOCH_DT = datetime(1970, 1, 1, tzinfo=UTC)


async def _child(parent: Any, name: str, namespaces: tuple[int, ...]) -> Any:
    """The child ``name`` in the first of ``namespaces`` that has it (None: none)."""
    from asyncua import ua

    for ns in namespaces:
        try:
            return await parent.get_child([f"{ns}:{name}"])
        except ua.UaStatusCodeError:
            continue
    return None


PROGRAM_STATES = {"Initializing": (0, 135), "Running": (1, 138), "Ended": (2, 140),
                  "Interrupted": (3, 139), "Aborted": (4, 141)}
"""ProductionStateMachineType's states: StateNumber and the state's node id in the MachineTool
NodeSet (OPC 40501-1 v1.02, 11.3)."""


def program_state(name: str, mt: int) -> dict[str, Any]:
    """``CurrentState`` (text), ``CurrentState.Id`` (the state's node) and
    ``CurrentState.Number`` of the active program's state machine, as data values.

    Parameters
    ----------
    name : str
        One of :data:`PROGRAM_STATES`.
    mt : int
        Namespace index of the MachineTool NodeSet.

    Returns
    -------
    dict
    """
    from asyncua import ua

    number, node = PROGRAM_STATES[name]
    return {"CurrentState": ua.DataValue(ua.Variant(ua.LocalizedText(name),
                                                    ua.VariantType.LocalizedText)),
            "CurrentState.Id": ua.DataValue(ua.Variant(ua.NodeId(node, mt),
                                                       ua.VariantType.NodeId)),
            "CurrentState.Number": ua.DataValue(ua.Variant(number, ua.VariantType.UInt32))}


async def add_machine_tool(server: Any, machine: str, own_idx: int, *,
                           identification: dict[str, Any] | None = None,
                           tools: Mapping[int, Mapping[str, Any]] | None = None
                           ) -> dict[str, Any]:
    """Load the NodeSets and create the machine's ``MachineToolType`` object.

    Parameters
    ----------
    server : asyncua.Server
        The server (initialized, not yet started).
    machine : str
        Machine name: the object's browse name and serial number.
    own_idx : int
        Namespace index of cnctwin's own variables.
    identification : dict, optional
        The machine file's ``[identification]`` (manufacturer, model, serial_number,
        year_of_construction, software_revision, product_instance_uri); without a value the
        serial number is the machine name and the manufacturer "unknown".
    tools : mapping, optional
        T number -> the tool table's entry (``name``, ``life_holes``, ``wear_limit_um``):
        ``Equipment/Tools`` with one ``ToolType`` per tool and its ``ToolLife``, and
        ``Notification/Prognoses`` with its ``ToolChangePrognosis`` (:func:`add_tools`).

    Returns
    -------
    dict
        Key -> node id of the values cnctwin writes: ``IsRotating``, ``ActualSpeed``,
        ``CuttingTorque``, ``ProgramName``, ``HoleCount``, ``AlarmActive``, ``AlarmMessage``,
        ``OperationMode``, ``PowerOnDuration``, ``ChannelState``, ``ChannelMode``, ``Name``,
        ``FeedOverride``, ``Light.Green``, ``Light.Yellow``, ``Light.Red`` (``SignalOn``),
        ``PartsProduced``, ``Messages`` (the event notifier) and those of :func:`add_tools`.
    """
    from asyncua import ua

    pkg = resources.files("cnctwin") / "data" / "nodesets"
    for name in NODESET_FILES:
        with resources.as_file(pkg / name) as path:
            # structures are not compiled to Python classes (asyncua 1.1 cannot compile the
            # OptionSet fields of Machinery/Jobs); the address space is complete
            await server.import_xml(str(path), auto_load_definitions=False)
    nsa = await server.get_namespace_array()
    mt, mach, di = nsa.index(MACHINE_TOOL_NS), nsa.index(MACHINERY_NS), nsa.index(DI_NS)
    machines = server.get_node(ua.NodeId(_MACHINES_FOLDER, mach))
    obj = await machines.add_object(ua.NodeId(f"{machine}.MachineTool", own_idx),
                                    ua.QualifiedName(machine, mt),
                                    objecttype=ua.NodeId(_MACHINE_TOOL_TYPE, mt),
                                    instantiate_optional=False)
    out: dict[str, Any] = {"mt_ns": mt, "Machine": obj.nodeid}

    async def own_var(parent: Any, name: str, value: Any, vt: Any) -> Any:
        node = await parent.add_variable(ua.NodeId(f"{machine}.MT.{name}", own_idx),
                                         ua.QualifiedName(name, own_idx), value, varianttype=vt)
        out[name] = node.nodeid
        return node

    # Identification is DI's (the MachineTool NodeSet names it DI:Identification)
    ident = await obj.get_child([f"{di}:Identification"])
    given = dict(identification or {})
    lt, st = ua.VariantType.LocalizedText, ua.VariantType.String
    fields: list[tuple[str, Any, Any, int]] = [
        ("Manufacturer", ua.LocalizedText(str(given.get("manufacturer", "unknown"))), lt, di),
        ("SerialNumber", str(given.get("serial_number", machine)), st, di),
        ("ProductInstanceUri", str(given.get("product_instance_uri",
                                             f"urn:cnctwin:machine:{machine}")), st, di)]
    if "model" in given:
        fields.append(("Model", ua.LocalizedText(str(given["model"])), lt, di))
    if "software_revision" in given:
        fields.append(("SoftwareRevision", str(given["software_revision"]), st, di))
    if "year_of_construction" in given:
        fields.append(("YearOfConstruction", int(given["year_of_construction"]),
                       ua.VariantType.UInt16, mach))
    for name, value, vt, home in fields:
        child = await _child(ident, name, (di, mach, mt))
        if child is None:  # an optional property: added with the specification's name
            child = await ident.add_property(ua.NodeId(f"{machine}.MT.Ident.{name}", own_idx),
                                             ua.QualifiedName(name, home), value,
                                             varianttype=vt)
        await child.write_value(ua.DataValue(ua.Variant(value, vt)))
    monitoring = await obj.get_child([f"{mt}:Monitoring"])
    spindle = await monitoring.add_object(ua.NodeId(f"{machine}.MT.Spindle", own_idx),
                                          ua.QualifiedName("Spindle", mt),
                                          objecttype=ua.NodeId(_SPINDLE_MONITORING_TYPE, mt),
                                          instantiate_optional=False)
    out["IsRotating"] = (await spindle.get_child([f"{mt}:IsRotating"])).nodeid
    await (await spindle.get_child([f"{mt}:IsRotating"])).write_value(False)
    try:
        name_node = await spindle.get_child([f"{mt}:Name"])
        await name_node.write_value("SP1")
    except ua.UaStatusCodeError:
        pass
    # Override (AnalogUnitRangeType, optional): the commanded over the programmed speed,
    # published while the spindle turns at a constant command (BadWaitingForInitialData
    # before: the recording has no override signal of its own)
    override = await spindle.add_variable(ua.NodeId(f"{machine}.MT.SpindleOverride", own_idx),
                                          ua.QualifiedName("Override", mt), 100.0,
                                          varianttype=ua.VariantType.Double)
    await override.add_property(ua.NodeId(f"{machine}.MT.SpindleOverride.EURange", own_idx),
                                ua.QualifiedName("EURange", 0), ua.Range(Low=0.0, High=200.0))
    await override.add_property(ua.NodeId(f"{machine}.MT.SpindleOverride.EU", own_idx),
                                ua.QualifiedName("EngineeringUnits", 0),
                                eu_information("%", "percent"))
    await server.write_attribute_value(override.nodeid, _waiting())
    out["SpindleOverride"] = override.nodeid
    await own_var(spindle, "ActualSpeed", float("nan"), ua.VariantType.Double)
    await own_var(spindle, "CuttingTorque", float("nan"), ua.VariantType.Double)
    ia = nsa.index(IA_NS)
    # MachineTool: PowerOnDuration [h] (optional in MachineToolMonitoringType)
    mtm = await monitoring.get_child([f"{mt}:MachineTool"])
    out["OperationMode"] = (await mtm.get_child([f"{mt}:OperationMode"])).nodeid
    await server.write_attribute_value(out["OperationMode"], ua.DataValue(
        ua.Variant(2, ua.VariantType.Int32)))  # MachineOperationMode: 2 Automatic
    pod = await mtm.add_variable(ua.NodeId(f"{machine}.MT.PowerOnDuration", own_idx),
                                 ua.QualifiedName("PowerOnDuration", mt), 0,
                                 varianttype=ua.VariantType.UInt32)
    out["PowerOnDuration"] = pod.nodeid
    # Channel 1 (ChannelMonitoringType): state, mode, the feed override the control applies
    chan = await monitoring.add_object(ua.NodeId(f"{machine}.MT.Channel1", own_idx),
                                       ua.QualifiedName("Channel 1", mt),
                                       objecttype=ua.NodeId(_CHANNEL_MONITORING_TYPE, mt),
                                       instantiate_optional=False)
    for name, value, vt in (("ChannelState", 1, ua.VariantType.Int32),  # Interrupted: no data
                            ("ChannelMode", 0, ua.VariantType.Int32),  # Automatic
                            ("Name", "Channel 1", ua.VariantType.String)):
        node = await chan.get_child([f"{mt}:{name}"])
        await server.write_attribute_value(node.nodeid, ua.DataValue(ua.Variant(value, vt)))
        out[name] = node.nodeid
    feed = await chan.get_child([f"{mt}:FeedOverride"])
    out["FeedOverride"] = feed.nodeid
    await server.write_attribute_value(feed.nodeid, ua.DataValue(ua.Variant(100.0,
                                                                            ua.VariantType.Double)))
    eur = await feed.get_child(["0:EURange"])
    await eur.write_value(ua.Range(Low=0.0, High=200.0))
    units = await feed.get_child(["0:EngineeringUnits"])
    await units.write_value(eu_information("%", "percent"))
    # the IA stack light: three lights from the base up
    stack = await monitoring.add_object(ua.NodeId(f"{machine}.MT.Stacklight", own_idx),
                                        ua.QualifiedName("Stacklight", mt),
                                        objecttype=ua.NodeId(_BASIC_STACKLIGHT_TYPE, ia),
                                        instantiate_optional=False)
    mode = await stack.get_child([f"{ia}:StacklightMode"])
    await server.write_attribute_value(mode.nodeid, ua.DataValue(
        ua.Variant(0, ua.VariantType.Int32)))  # StacklightOperationMode: 0 Segmented
    await stack.add_property(ua.NodeId(f"{machine}.MT.Stacklight.NodeVersion", own_idx),
                             ua.QualifiedName("NodeVersion", 0), "1",
                             varianttype=ua.VariantType.String)
    for k, (name, color) in enumerate(LIGHTS):
        light = await stack.add_object(ua.NodeId(f"{machine}.MT.Light{k}", own_idx),
                                       ua.QualifiedName(f"Light {k}", ia),
                                       objecttype=ua.NodeId(_STACK_ELEMENT_LIGHT_TYPE, ia),
                                       instantiate_optional=False)
        for child, value, vt in (("SignalOn", False, ua.VariantType.Boolean),
                                 ("SignalColor", color, ua.VariantType.Int32),
                                 ("SignalMode", 0, ua.VariantType.Int32),  # Continuous
                                 ("IsPartOfBase", False, ua.VariantType.Boolean),
                                 ("NumberInList", k, ua.VariantType.UInt16)):
            node = await _child(light, child, (ia, 0))  # IA's, or Part 5's NumberInList
            if node is None:  # an optional child: added with the specification's name
                node = await light.add_variable(
                    ua.NodeId(f"{machine}.MT.Light{k}.{child}.v", own_idx),
                    ua.QualifiedName(child, 0 if child == "NumberInList" else ia), value,
                    varianttype=vt)
            await server.write_attribute_value(node.nodeid, ua.DataValue(ua.Variant(value, vt)))
            if child == "SignalOn":
                out[f"Light.{name}"] = node.nodeid
    production = await obj.get_child([f"{mt}:Production"])
    active = await production.get_child([f"{mt}:ActiveProgram"])
    try:
        prog = await active.get_child([f"{mt}:Name"])
        out["ProgramName"] = prog.nodeid
        await prog.write_value("")
    except ua.UaStatusCodeError:
        await own_var(active, "ProgramName", "", ua.VariantType.String)
    await own_var(active, "HoleCount", 0, ua.VariantType.Int64)
    number = await active.get_child(["0:NumberInList"])
    await server.write_attribute_value(number.nodeid, ua.DataValue(
        ua.Variant(0, ua.VariantType.UInt16)))  # the one program the channel runs
    state = await (await active.get_child([f"{mt}:State"])).get_child(["0:CurrentState"])
    out["CurrentState"] = state.nodeid
    out["CurrentState.Id"] = (await state.get_child(["0:Id"])).nodeid
    out["CurrentState.Number"] = (await state.get_child(["0:Number"])).nodeid
    for key, value in program_state("Initializing", mt).items():
        await server.write_attribute_value(out[key], value)
    # Production/Statistics: parts produced (program ends, M30/M2)
    stats = await production.add_object(ua.NodeId(f"{machine}.MT.Statistics", own_idx),
                                         ua.QualifiedName("Statistics", mt),
                                         objecttype=ua.NodeId(_PRODUCTION_STATISTICS_TYPE, mt),
                                         instantiate_optional=False)
    parts = await stats.add_variable(ua.NodeId(f"{machine}.MT.PartsProduced", own_idx),
                                     ua.QualifiedName("PartsProducedInLifetime", mt), 0,
                                     varianttype=ua.VariantType.UInt32)
    out["PartsProduced"] = parts.nodeid
    notification = await obj.get_child([f"{mt}:Notification"])
    messages = await notification.add_object(ua.NodeId(f"{machine}.MT.Messages", own_idx),
                                             ua.QualifiedName("Messages", mt),
                                             objecttype=ua.NodeId(38, mt),
                                             instantiate_optional=False)
    await server.write_attribute_value(messages.nodeid, ua.DataValue(
        ua.Variant(1, ua.VariantType.Byte)), ua.AttributeIds.EventNotifier)
    out["Messages"] = messages.nodeid
    await own_var(messages, "AlarmActive", False, ua.VariantType.Boolean)
    await own_var(messages, "AlarmMessage", "", ua.VariantType.String)
    if tools:
        equipment = await obj.get_child([f"{mt}:Equipment"])
        out.update(await add_tools(server, machine, own_idx, mt, equipment, notification,
                                   tools))
    return out


def _waiting() -> Any:
    """The value of a node that has none yet (``BadWaitingForInitialData``)."""
    from asyncua import ua

    return ua.DataValue(StatusCode_=ua.StatusCode(ua.StatusCodes.BadWaitingForInitialData))


async def add_tools(server: Any, machine: str, own_idx: int, mt: int, equipment: Any,
                    notification: Any, tools: Mapping[int, Mapping[str, Any]]
                    ) -> dict[str, Any]:
    """``Equipment/Tools`` and ``Notification/Prognoses`` of the tool table's tools.

    Per tool ``T<n>`` (``ToolType``, OPC 40501-1 v1.02 §8.5.4): ``ControlIdentifier1`` = n,
    ``ControlIdentifierInterpretation`` NumberBased, ``Locked`` false, ``Name``,
    ``Identifier``, ``LastUsage``, and ``ToolLife`` (§11.1, ``ToolLifeType`` entries):

    ``Usages``
        holes drilled, counting up (Indication NumberOfUsages, unit "one"); ``LimitValue`` the
        tool table's ``life_holes``.
    ``RemainingUsages``
        cnctwin's remaining-life forecast in holes, counting down to ``LimitValue`` 0, with
        cnctwin's ``LowerBound``/``UpperBound`` (90 % interval) and ``Basis`` (wear, usage).
    ``FlankWear``
        with a wear calibration: the flank-wear estimate VB [µm] (Indication Other: VB is not
        an abraded length), ``LimitValue`` the tool table's ``wear_limit_um``.

    Per tool a ``ToolChangePrognosisType`` ``ToolChange T<n>`` in ``Notification/Prognoses``
    (§9.6): ``PredictedTime`` (the forecast tool change), ``Location`` (the spindle),
    ``ToolIdentifier``, ``ToolName``, ``ToolNodeId``, and cnctwin's ``PredictedTimeEarliest``,
    ``PredictedTimeLatest``, ``RemainingHoles``. Values without an estimate are
    ``BadWaitingForInitialData``.

    Returns
    -------
    dict
        ``Tool.<n>.<name>`` -> node id of ``Usages``, ``RemainingUsages``,
        ``RemainingUsages.LowerBound``, ``RemainingUsages.UpperBound``,
        ``RemainingUsages.Basis``, ``FlankWear`` (with a wear limit), ``LastUsage``,
        ``PredictedTime``, ``PredictedTimeEarliest``, ``PredictedTimeLatest``,
        ``RemainingHoles``.
    """
    import logging

    from asyncua import ua
    from asyncua.common.instantiate_util import instantiate

    # instantiating a variable type logs each attribute the type node does not have
    logging.getLogger("asyncua.common.copy_node_util").setLevel(logging.ERROR)
    out: dict[str, Any] = {}
    waiting = _waiting()
    D = ua.VariantType.Double

    async def put(node: Any, value: Any, vt: Any) -> None:
        await server.write_attribute_value(node.nodeid, ua.DataValue(ua.Variant(value, vt)))

    async def child(parent: Any, name: str, value: Any, vt: Any, *, key: str,
                    ns: int | None = None, prop: bool = True) -> Any:
        node = await _child(parent, name, (mt, 0))
        if node is None:
            nid = ua.NodeId(f"{machine}.MT.{key}", own_idx)
            qn = ua.QualifiedName(name, mt if ns is None else ns)
            node = await (parent.add_property(nid, qn, value, varianttype=vt) if prop
                          else parent.add_variable(nid, qn, value, varianttype=vt))
        await put(node, value, vt)
        return node

    async def node_list(parent: Any, name: str, type_id: int) -> Any:
        """A list object (ToolListType, PrognosisListType) with its NodeVersion."""
        obj = await parent.add_object(ua.NodeId(f"{machine}.MT.{name}", own_idx),
                                      ua.QualifiedName(name, mt),
                                      objecttype=ua.NodeId(type_id, mt),
                                      instantiate_optional=False)
        await obj.add_property(ua.NodeId(f"{machine}.MT.{name}.NodeVersion", own_idx),
                               ua.QualifiedName("NodeVersion", 0), "1",
                               varianttype=ua.VariantType.String)
        return obj

    tool_list = await node_list(equipment, "Tools", _TOOL_LIST_TYPE)
    prognoses = await node_list(notification, "Prognoses", _PROGNOSIS_LIST_TYPE)
    for n in sorted(tools):
        spec = tools[n]
        name = str(spec.get("name") or f"T{n}")
        k = f"Tool.{n}"
        tool = await tool_list.add_object(ua.NodeId(f"{machine}.MT.Tool{n}", own_idx),
                                          ua.QualifiedName(f"T{n}", mt),
                                          objecttype=ua.NodeId(_TOOL_TYPE, mt),
                                          instantiate_optional=False)
        await child(tool, "ControlIdentifier1", n, ua.VariantType.UInt32, key=f"{k}.CI1",
                    prop=False)
        await child(tool, "ControlIdentifierInterpretation", 0, ua.VariantType.Int32,
                    key=f"{k}.CII", prop=False)  # ToolManagement: NumberBased
        locked = await child(tool, "Locked", False, ua.VariantType.Boolean, key=f"{k}.Locked",
                             prop=False)
        await child(locked, "ReasonForLocking", 5, ua.VariantType.Int32,
                    key=f"{k}.ReasonForLocking")  # ToolLocked: Other (not locked)
        await child(tool, "Name", name, ua.VariantType.String, key=f"{k}.Name")
        await child(tool, "Identifier", f"T{n}", ua.VariantType.String, key=f"{k}.Identifier")
        last = await child(tool, "LastUsage", _EPOCH_DT, ua.VariantType.DateTime,
                           key=f"{k}.LastUsage", prop=False)
        await server.write_attribute_value(last.nodeid, waiting)
        out[f"{k}.LastUsage"] = last.nodeid
        life = await tool.add_object(ua.NodeId(f"{machine}.MT.Tool{n}.ToolLife", own_idx),
                                     ua.QualifiedName("ToolLife", mt))
        entries: list[tuple[str, int, bool, str, float | None]] = [
            ("Usages", 2, True, "one", spec.get("life_holes")),
            ("RemainingUsages", 2, False, "one", 0.0)]
        if spec.get("wear_limit_um") is not None and spec.get("wear_um_per_increase"):
            entries.append(("FlankWear", 7, True, "um", spec.get("wear_limit_um")))
        for entry, indication, up, unit, limit in entries:
            # a ToolLifeType variable with its mandatory properties
            node = (await instantiate(
                life, server.get_node(ua.NodeId(_TOOL_LIFE_TYPE, mt)),
                nodeid=ua.NodeId(f"{machine}.MT.Tool{n}.{entry}", own_idx),
                bname=ua.QualifiedName(entry, mt), instantiate_optional=False))[0]
            out[f"{k}.{entry}"] = node.nodeid
            pk = f"{k}.{entry}"
            await child(node, "EngineeringUnits", eu_information(unit), None,
                        key=f"{pk}.EU")
            await child(node, "Indication", indication, ua.VariantType.Int32,
                        key=f"{pk}.Indication")
            await child(node, "IsCountingUp", up, ua.VariantType.Boolean, key=f"{pk}.Up")
            await child(node, "StartValue", 0.0, D, key=f"{pk}.Start")
            if limit is not None:
                await child(node, "LimitValue", float(limit), D, key=f"{pk}.Limit")
            if entry == "Usages":
                await put(node, 0.0, D)
                continue
            await server.write_attribute_value(node.nodeid, waiting)
            if entry == "RemainingUsages":
                for extra, value, vt in (("LowerBound", 0.0, D), ("UpperBound", 0.0, D),
                                         ("Basis", "", ua.VariantType.String)):
                    b = await node.add_property(
                        ua.NodeId(f"{machine}.MT.Tool{n}.{entry}.{extra}", own_idx),
                        ua.QualifiedName(extra, own_idx), value, varianttype=vt)
                    await server.write_attribute_value(b.nodeid, waiting)
                    out[f"{k}.{entry}.{extra}"] = b.nodeid
        prog = await prognoses.add_object(
            ua.NodeId(f"{machine}.MT.Prognosis.Tool{n}", own_idx),
            ua.QualifiedName(f"ToolChange T{n}", mt),
            objecttype=ua.NodeId(_TOOL_CHANGE_PROGNOSIS_TYPE, mt), instantiate_optional=False)
        pt = await prog.get_child([f"{mt}:PredictedTime"])
        await server.write_attribute_value(pt.nodeid, waiting)
        out[f"{k}.PredictedTime"] = pt.nodeid
        await child(prog, "Location", ua.LocalizedText("Spindle"),
                    ua.VariantType.LocalizedText, key=f"{k}.Prog.Location", prop=False)
        await child(prog, "ToolIdentifier", f"T{n}", ua.VariantType.String,
                    key=f"{k}.Prog.ToolIdentifier", prop=False)
        await child(prog, "ToolName", name, ua.VariantType.String, key=f"{k}.Prog.ToolName",
                    prop=False)
        await child(prog, "ToolNodeId", tool.nodeid, ua.VariantType.NodeId,
                    key=f"{k}.Prog.ToolNodeId", prop=False)
        for extra, vt in (("PredictedTimeEarliest", ua.VariantType.DateTime),
                          ("PredictedTimeLatest", ua.VariantType.DateTime),
                          ("RemainingHoles", D)):
            v = await prog.add_variable(ua.NodeId(f"{machine}.MT.Prognosis.Tool{n}.{extra}",
                                                  own_idx),
                                        ua.QualifiedName(extra, own_idx),
                                        0.0 if vt == D else _EPOCH_DT, varianttype=vt)
            await server.write_attribute_value(v.nodeid, waiting)
            out[f"{k}.{extra}"] = v.nodeid
    return out
