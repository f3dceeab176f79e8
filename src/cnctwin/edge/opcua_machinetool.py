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

__all__ = ["MACHINE_TOOL_NS", "NODESET_FILES", "add_machine_tool"]

MACHINE_TOOL_NS = "http://opcfoundation.org/UA/MachineTool/"
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
_MACHINES_FOLDER = 1001  # Machinery


async def add_machine_tool(server: Any, machine: str, own_idx: int) -> dict[str, Any]:
    """Load the NodeSets and create the machine's ``MachineToolType`` object.

    Parameters
    ----------
    server : asyncua.Server
        The server (initialized, not yet started).
    machine : str
        Machine name: the object's browse name and serial number.
    own_idx : int
        Namespace index of cnctwin's own variables.

    Returns
    -------
    dict
        Key -> node id of the values cnctwin writes: ``IsRotating``, ``ActualSpeed``,
        ``CuttingTorque``, ``ProgramName``, ``HoleCount``, ``AlarmActive``, ``AlarmMessage``.
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
    out: dict[str, Any] = {}

    async def own_var(parent: Any, name: str, value: Any, vt: Any) -> Any:
        node = await parent.add_variable(ua.NodeId(f"{machine}.MT.{name}", own_idx),
                                         ua.QualifiedName(name, own_idx), value, varianttype=vt)
        out[name] = node.nodeid
        return node

    # Identification is DI's (the MachineTool NodeSet names it DI:Identification)
    ident = await obj.get_child([f"{di}:Identification"])
    for name, value, vt in (("Manufacturer", ua.LocalizedText("unknown"),
                             ua.VariantType.LocalizedText),
                            ("SerialNumber", machine, ua.VariantType.String),
                            ("ProductInstanceUri", f"urn:cnctwin:machine:{machine}",
                             ua.VariantType.String)):
        for ns in (di, mach, mt):
            try:
                child = await ident.get_child([f"{ns}:{name}"])
            except ua.UaStatusCodeError:
                continue
            await child.write_value(ua.DataValue(ua.Variant(value, vt)))
            break
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
    production = await obj.get_child([f"{mt}:Production"])
    active = await production.get_child([f"{mt}:ActiveProgram"])
    try:
        prog = await active.get_child([f"{mt}:Name"])
        out["ProgramName"] = prog.nodeid
        await prog.write_value("")
    except ua.UaStatusCodeError:
        await own_var(active, "ProgramName", "", ua.VariantType.String)
    await own_var(active, "HoleCount", 0, ua.VariantType.Int64)
    notification = await obj.get_child([f"{mt}:Notification"])
    messages = await notification.add_object(ua.NodeId(f"{machine}.MT.Messages", own_idx),
                                             ua.QualifiedName("Messages", mt),
                                             objecttype=ua.NodeId(38, mt),
                                             instantiate_optional=False)
    await own_var(messages, "AlarmActive", False, ua.VariantType.Boolean)
    await own_var(messages, "AlarmMessage", "", ua.VariantType.String)
    return out
