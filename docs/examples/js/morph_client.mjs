// A MORPH application in JavaScript (deploy/missions/morph.yaml).
//
// zenoh-ts talks to a Zenoh router through its remote-api plugin over a WebSocket: run the
// surface router with the plugin enabled (plugins: { remote_api: { websocket_port: 10000 } })
// and connect the bridges to it. This script subscribes to every vehicle's navigation as the
// surface publishes it ("{src}/nav"), to the bridges' link states, and sends a mission command
// to the vehicles (the surface node's input key `command`).
//
//   npm install && node --experimental-wasm-modules morph_client.mjs ws/127.0.0.1:10000
//   (Deno and browsers load zenoh-ts's WebAssembly without the flag.)
import { Config, Encoding, Session } from "@eclipse-zenoh/zenoh-ts";
import { decode, encode } from "@msgpack/msgpack";

const locator = process.argv[2] ?? "ws/127.0.0.1:10000";

// The bridge publishes msgpack (encoding application/msgpack) or JSON, as the mission says.
function payloadOf(sample) {
  const bytes = sample.payload().toBytes();
  const encoding = sample.encoding().toString();
  if (encoding.startsWith("application/json")) {
    return JSON.parse(new TextDecoder().decode(bytes));
  }
  return decode(bytes);
}

const session = await Session.open(new Config(locator));

await session.declareSubscriber("*/nav", {
  handler: (sample) => {
    const nav = payloadOf(sample); // {x, y, depth}: see the key's payload schema
    console.log(`${sample.keyexpr().toString()}: x ${nav.x} m, y ${nav.y} m, depth ${nav.depth} m`);
  },
});

await session.declareSubscriber("@zab/morph/*/link/*", {
  handler: (sample) => {
    const link = payloadOf(sample); // {peer, state: up|degraded|down, last_heard, silent_s}
    console.log(`${sample.keyexpr().toString()}: ${link.peer} is ${link.state}`);
  },
});

// A command: msgpack map, field names and enum values exactly as the payload schema says.
await session.put("command", encode({ action: "start", leg: 2 }), {
  encoding: Encoding.fromString("application/msgpack"),
});
console.log("command sent; listening (Ctrl-C to stop)");
