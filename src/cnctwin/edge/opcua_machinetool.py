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

from importlib import resources
from typing import Any

__all__ = ["MACHINE_TOOL_NS", "NODESET_FILES", "PROGRAM_STATES", "add_machine_tool",
           "program_state"]

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
                           identification: dict[str, Any] | None = None) -> dict[str, Any]:
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

    Returns
    -------
    dict
        Key -> node id of the values cnctwin writes: ``IsRotating``, ``ActualSpeed``,
        ``CuttingTorque``, ``ProgramName``, ``HoleCount``, ``AlarmActive``, ``AlarmMessage``,
        ``OperationMode``, ``PowerOnDuration``, ``ChannelState``, ``ChannelMode``, ``Name``,
        ``FeedOverride``, ``Light.Green``, ``Light.Yellow``, ``Light.Red`` (``SignalOn``).
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
    out: dict[str, Any] = {"mt_ns": mt}

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
    await units.write_value(ua.EUInformation(
        NamespaceUri="http://www.opcfoundation.org/UA/units/un/cefact", UnitId=20529,
        DisplayName=ua.LocalizedText("%"), Description=ua.LocalizedText("percent")))
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
    notification = await obj.get_child([f"{mt}:Notification"])
    messages = await notification.add_object(ua.NodeId(f"{machine}.MT.Messages", own_idx),
                                             ua.QualifiedName("Messages", mt),
                                             objecttype=ua.NodeId(38, mt),
                                             instantiate_optional=False)
    await own_var(messages, "AlarmActive", False, ua.VariantType.Boolean)
    await own_var(messages, "AlarmMessage", "", ua.VariantType.String)
    return out
