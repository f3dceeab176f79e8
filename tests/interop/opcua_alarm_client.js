// An OPC UA client cnctwin did not write (node-opcua, npm registry) watching the OPC 40501
// machine object of `cnctwin edge run --opcua` the way plant software does: subscribe to the
// alarm events of Notification/Messages (Alarms & Conditions fields), acknowledge the first
// active alarm through AcknowledgeableConditionType.Acknowledge, and monitor values (a tool's
// ToolLife, the program state, the parts produced) while holes are drilled.
// Usage: node opcua_alarm_client.js URL MACHINE PKI_DIR SECONDS < watch.json
//   (user from CNCTWIN_OPCUA_USER, password from CNCTWIN_OPCUA_PASSWORD; watch.json: a JSON
//    list of browse paths below the machine object, each a list of [namespace URI, name])
// Prints one JSON document: {"events": [...], "values": {path: [[value, status], ...]},
//   "ack": {status}} once SECONDS have passed or the server has gone.
"use strict";
const {
  AttributeIds, makeBrowsePath, ClientSubscription, ClientMonitoredItem, TimestampsToReturn,
  constructEventFilter, DataType,
} = require("node-opcua-client");
const { openSession } = require("./opcua_interop_session.js");

const FIELDS = ["EventId", "EventType", "SourceName", "Message", "Severity", "Time",
  "ActiveState", "ActiveState.Id", "AckedState", "AckedState.Id", "Retain", "ConditionName",
  "ConditionId"];

function plain(v) {
  if (v === null || v === undefined) { return null; }
  if (typeof v === "bigint") { return Number(v); }
  if (Buffer.isBuffer(v)) { return v.toString("hex"); }
  if (v instanceof Date) { return v.toISOString(); }
  if (typeof v === "object" && "text" in v) { return v.text; }
  if (typeof v === "object" && typeof v.toString === "function" && v.namespace !== undefined) {
    return v.toString();
  }
  return v;
}

async function main() {
  const [url, machine, pki, seconds] = process.argv.slice(2);
  const paths = JSON.parse(require("fs").readFileSync(0, "utf8"));
  const out = { events: [], values: {}, ack: null, ended: "timeout" };
  let closed = false;
  const { client, session, ns } = await openSession(url, pki,
    "cnctwin-interop-node-opcua-alarms");
  client.on("connection_lost", () => { closed = true; });
  client.on("close", () => { closed = true; });
  const mt = ns("http://opcfoundation.org/UA/MachineTool/");
  const machinery = ns("http://opcfoundation.org/UA/Machinery/");
  const resolve = async (rel) => {
    const r = await session.translateBrowsePath(makeBrowsePath("i=85", rel));
    if (!r.targets || r.targets.length === 0) { throw new Error(`no node ${rel}`); }
    return r.targets[0].targetId;
  };
  const base = `/${machinery}:Machines/${mt}:${machine}`;
  const messages = await resolve(`${base}/${mt}:Notification/${mt}:Messages`);
  const sub = ClientSubscription.create(session, {
    requestedPublishingInterval: 100, requestedLifetimeCount: 600,
    requestedMaxKeepAliveCount: 20, maxNotificationsPerPublish: 1000,
    publishingEnabled: true, priority: 10 });
  const events = ClientMonitoredItem.create(sub,
    { nodeId: messages, attributeId: AttributeIds.EventNotifier },
    { samplingInterval: 0, discardOldest: false, queueSize: 100,
      filter: constructEventFilter(FIELDS) }, TimestampsToReturn.Neither);
  let acking = false;
  events.on("changed", async (fields) => {
    const ev = {};
    FIELDS.forEach((name, k) => { ev[name] = plain(fields[k].value); });
    out.events.push(ev);
    if (!acking && ev["ActiveState.Id"] === true && ev["AckedState.Id"] === false) {
      acking = true;  // the operator acknowledges the first alarm it sees
      try {
        const res = await session.call({
          objectId: fields[FIELDS.indexOf("ConditionId")].value,
          methodId: "i=9111",
          inputArguments: [
            { dataType: DataType.ByteString, value: fields[0].value },
            { dataType: DataType.LocalizedText, value: { text: "seen by node-opcua" } }] });
        out.ack = { status: res.statusCode.name, condition: ev.ConditionName };
      } catch (err) {
        out.ack = { error: String(err.message || err) };
      }
    }
  });
  for (const p of paths) {
    const key = p.map((e) => e[1]).join("/");
    const rel = base + p.map((e) => `/${ns(e[0])}:${e[1]}`).join("");
    out.values[key] = [];
    let id;
    try { id = await resolve(rel); } catch (err) {
      out.values[key].push([null, String(err.message || err)]);
      continue;
    }
    const item = ClientMonitoredItem.create(sub, { nodeId: id, attributeId: AttributeIds.Value },
      { samplingInterval: 50, discardOldest: true, queueSize: 100 },
      TimestampsToReturn.Both);
    item.on("changed", (dv) => { out.values[key].push([plain(dv.value.value),
      dv.statusCode.name]); });
  }
  const deadline = Date.now() + 1000 * Number(seconds);
  while (Date.now() < deadline && !closed) {
    await new Promise((r) => setTimeout(r, 100));
  }
  if (closed) { out.ended = "server gone"; }
  process.stdout.write(JSON.stringify(out) + "\n");
  try { await sub.terminate(); await session.close(); } catch (err) { /* server gone */ }
  try { await client.disconnect(); } catch (err) { /* server gone */ }
}

main().catch((err) => {
  process.stderr.write(`node-opcua client: ${err.message || err}\n`);
  process.exit(3);
});
