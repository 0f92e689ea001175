// An independent OPC UA client (node-opcua, not heliocal's code) for the OPC UA server tests.
// usage: node client.js ENDPOINT USER PASSWORD SECURITY STEP...
//   SECURITY: none | sign-encrypt (Basic256Sha256); STEPs run in order, each printing one JSON line:
//   browse                 the children of Objects/Heliocal and of Heliocal/Heliostats
//   read:PATH              the value at Objects/Heliocal/PATH (e.g. Heliostats/H02/State)
//   watch:PATH:UNTIL:S     subscribe to PATH; print every change ("subscribed" first) until the value
//                          equals UNTIL or S seconds pass
//   call:PATH              call the method at Objects/Heliocal/PATH with no arguments (its status code)
"use strict";
const opcua = require("node-opcua-client");
const {OPCUACertificateManager} = require("node-opcua-certificate-manager");
const path = require("path");

const [endpoint, user, password, security, ...steps] = process.argv.slice(2);
const out = (obj) => process.stdout.write(JSON.stringify(obj) + "\n");

async function nodeIdOf(session, ns, rel) {
  const browsePath = ["Heliocal", ...rel.split("/")].map((name) => `/${ns}:${name}`).join("");
  const r = await session.translateBrowsePath(opcua.makeBrowsePath("ObjectsFolder", browsePath));
  if (!r.targets || !r.targets.length) throw new Error(`no node at Heliocal/${rel}: ${r.statusCode.name}`);
  return r.targets[0].targetId;
}

async function main() {
  const secure = security === "sign-encrypt";
  const client = opcua.OPCUAClient.create({
    endpointMustExist: false,
    securityMode: secure ? opcua.MessageSecurityMode.SignAndEncrypt : opcua.MessageSecurityMode.None,
    securityPolicy: secure ? opcua.SecurityPolicy.Basic256Sha256 : opcua.SecurityPolicy.None,
    clientCertificateManager: new OPCUACertificateManager({rootFolder: process.env.CLIENT_PKI || "./pki",
                                                                 automaticallyAcceptUnknownCertificate: true}),
    connectionStrategy: {maxRetry: 2, initialDelay: 200, maxDelay: 1000},
  });
  await client.connect(endpoint);
  const session = await client.createSession({type: opcua.UserTokenType.UserName, userName: user, password});
  const ns = (await session.readNamespaceArray()).indexOf("urn:heliocal");
  try {
    for (const step of steps) {
      const [kind, rel, until, seconds] = step.split(":");
      if (kind === "browse") {
        const top = await session.browse(`ns=${ns};s=Heliocal`);
        const hs = await session.browse(await nodeIdOf(session, ns, "Heliostats"));
        out({step: kind, heliocal: top.references.map((r) => r.browseName.name),
             heliostats: hs.references.map((r) => r.browseName.name)});
      } else if (kind === "read") {
        const dv = await session.read({nodeId: await nodeIdOf(session, ns, rel), attributeId: opcua.AttributeIds.Value});
        out({step: kind, path: rel, status: dv.statusCode.name, value: dv.value.value});
      } else if (kind === "watch") {
        const sub = await session.createSubscription2({requestedPublishingInterval: 100, publishingEnabled: true,
                                                       requestedLifetimeCount: 600, requestedMaxKeepAliveCount: 10});
        const item = await sub.monitor({nodeId: await nodeIdOf(session, ns, rel), attributeId: opcua.AttributeIds.Value},
                                       {samplingInterval: 100, queueSize: 100, discardOldest: true},
                                       opcua.TimestampsToReturn.Both);
        await new Promise((resolve) => {
          const timer = setTimeout(resolve, 1000 * Number(seconds));
          item.on("changed", (dv) => {
            out({step: kind, path: rel, value: dv.value.value});
            if (String(dv.value.value) === until) { clearTimeout(timer); resolve(); }
          });
          out({step: kind, path: rel, subscribed: true});
        });
        await sub.terminate();
      } else if (kind === "call") {
        const r = await session.call({objectId: await nodeIdOf(session, ns, path.posix.dirname(rel)),
                                      methodId: await nodeIdOf(session, ns, rel), inputArguments: []});
        out({step: kind, path: rel, status: r.statusCode.name});
      } else {
        throw new Error(`unknown step ${step}`);
      }
    }
  } finally {
    await session.close();
    await client.disconnect();
  }
}

main().then(() => process.exit(0), (err) => { out({error: String(err && err.message || err)}); process.exit(1); });
