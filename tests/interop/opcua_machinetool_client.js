// An OPC UA client cnctwin did not write (node-opcua, npm registry) reading the OPC 40501
// machine-tool structure of `cnctwin edge run --opcua` the way the umati dashboard does:
// browse Objects/Machines, find the machine, read the nodes of its BaseMachineTool schema.
// Usage: node opcua_machinetool_client.js URL MACHINE PKI_DIR < paths.json
//   (user from CNCTWIN_OPCUA_USER, password from CNCTWIN_OPCUA_PASSWORD;
//    paths.json: a JSON list of browse paths below the machine object, each a list of
//    [namespace URI, browse name] pairs)
// Prints one JSON document: {"machines": [...], "components": {name: {typeNamespace, typeId}},
//   "values": {path: value or {"error": ...}}}.
"use strict";
const {
  AttributeIds, makeBrowsePath, BrowseDirection, NodeClassMask,
} = require("node-opcua-client");
const { openSession } = require("./opcua_interop_session.js");

async function main() {
  const [url, machine, pki] = process.argv.slice(2);
  const paths = JSON.parse(require("fs").readFileSync(0, "utf8"));
  const out = { machines: [], values: {} };
  const { client, session, ns, nsArray } = await openSession(url, pki,
    "cnctwin-interop-node-opcua");
  try {
    const machinery = ns("http://opcfoundation.org/UA/Machinery/");
    // Objects/Machines (Machinery), its children are the machines
    const found = await session.translateBrowsePath(
      makeBrowsePath("i=85", `/${machinery}:Machines`));
    const machinesId = found.targets[0].targetId;
    const browsed = await session.browse({
      nodeId: machinesId, browseDirection: BrowseDirection.Forward,
      includeSubtypes: true, nodeClassMask: NodeClassMask.Object, resultMask: 63 });
    let machineId = null;
    for (const ref of browsed.references) {
      out.machines.push(ref.browseName.name);
      if (ref.browseName.name === machine) { machineId = ref.nodeId; }
    }
    if (machineId === null) { throw new Error(`no machine ${machine} in Objects/Machines`); }
    // the machine's components and their types, as the umati observer finds the
    // identification (a HasComponent, subtypes included, of the namespace's identification type)
    out.components = {};
    const comps = await session.browse({
      nodeId: machineId, referenceTypeId: "HasComponent", includeSubtypes: true,
      browseDirection: BrowseDirection.Forward, nodeClassMask: NodeClassMask.Object,
      resultMask: 63 });
    for (const ref of comps.references) {
      out.components[ref.browseName.name] = {
        typeNamespace: nsArray[ref.typeDefinition.namespace], typeId: ref.typeDefinition.value };
    }
    for (const p of paths) {
      const key = p.map((e) => e[1]).join("/");
      const rel = p.map((e) => `/${ns(e[0])}:${e[1]}`).join("");
      try {
        const r = await session.translateBrowsePath(makeBrowsePath(machineId, rel));
        if (!r.targets || r.targets.length === 0) {
          out.values[key] = { error: r.statusCode.name };
          continue;
        }
        const id = r.targets[0].targetId;
        const cls = await session.read({ nodeId: id, attributeId: AttributeIds.NodeClass });
        if (cls.value.value !== 2) {  // not a variable: it exists
          out.values[key] = { exists: true };
          continue;
        }
        const dv = await session.read({ nodeId: id, attributeId: AttributeIds.Value });
        let v = dv.value.value;
        if (v && typeof v === "object" && "text" in v) { v = v.text; }
        if (typeof v === "bigint") { v = Number(v); }
        if (v && typeof v === "object" && v.low !== undefined && v.high !== undefined) {
          v = { low: v.low, high: v.high };
        }
        out.values[key] = { value: v === undefined ? null : v, status: dv.statusCode.name };
      } catch (err) {
        out.values[key] = { error: String(err.message || err) };
      }
    }
    await session.close();
  } finally {
    await client.disconnect();
  }
  process.stdout.write(JSON.stringify(out) + "\n");
}

main().catch((err) => {
  process.stderr.write(`node-opcua client: ${err.message || err}\n`);
  process.exit(3);
});
