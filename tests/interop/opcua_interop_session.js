// The session both node-opcua interop clients open to `cnctwin edge run --opcua`:
// Basic256Sha256 SignAndEncrypt, the client's certificate in PKI_DIR (created on first use),
// a user from CNCTWIN_OPCUA_USER / CNCTWIN_OPCUA_PASSWORD, and the server's namespace array.
"use strict";
const {
  OPCUAClient, MessageSecurityMode, SecurityPolicy, UserTokenType, AttributeIds,
} = require("node-opcua-client");
// a dependency of node-opcua-client (its certificate store)
const { OPCUACertificateManager } = require("node-opcua-certificate-manager");

// Connect and open the session: {client, session, ns, nsArray} with ns(uri) the namespace
// index.
async function openSession(url, pki, applicationName) {
  const certificateManager = new OPCUACertificateManager({
    rootFolder: pki, automaticallyAcceptUnknownCertificate: true });
  await certificateManager.initialize();
  const client = OPCUAClient.create({
    applicationName,
    securityMode: MessageSecurityMode.SignAndEncrypt,
    securityPolicy: SecurityPolicy.Basic256Sha256,
    endpointMustExist: false,
    clientCertificateManager: certificateManager,
    connectionStrategy: { maxRetry: 0, initialDelay: 100, maxDelay: 200 },
  });
  await client.connect(url);
  const session = await client.createSession({
    type: UserTokenType.UserName, userName: process.env.CNCTWIN_OPCUA_USER,
    password: process.env.CNCTWIN_OPCUA_PASSWORD });
  const nsArray = (await session.read({ nodeId: "i=2255", attributeId: AttributeIds.Value }))
    .value.value;
  return { client, session, ns: (uri) => nsArray.indexOf(uri), nsArray };
}

module.exports = { openSession };
