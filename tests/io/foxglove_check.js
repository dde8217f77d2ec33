// Independent client of the Foxglove WebSocket protocol (@foxglove/ws-protocol, what Foxglove
// itself speaks) against `rtsid run --foxglove`: connect, list the advertised channels with
// their schemas, subscribe to every one and collect N messages of TOPIC.
// Usage: NODE_PATH=<dir with node_modules> node foxglove_check.js ws://127.0.0.1:PORT TOPIC N
//   -> JSON on stdout: {channels: [{topic, encoding, schemaName, schemaEncoding, schema}],
//                       counts: {topic: n}, messages: [decoded JSON of TOPIC]}
const { FoxgloveClient } = require("@foxglove/ws-protocol");
const WebSocket = require("ws");

const [url, topic, wanted] = [process.argv[2], process.argv[3], Number(process.argv[4] || 5)];
// foxglove-sdk's server negotiates the protocol as "foxglove.sdk.v1" (the same messages as the
// published spec, foxglove.websocket.v1, which this client library implements); offer both.
const ws = new WebSocket(url, ["foxglove.sdk.v1", FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
const client = new FoxgloveClient({ ws });
const channels = new Map();
const bySubscription = new Map();
const counts = {};
const messages = [];
const timer = setTimeout(() => {
  console.error(`timeout: ${messages.length} of ${wanted} messages on ${topic}`);
  process.exit(1);
}, 20000);

client.on("error", (err) => {
  console.error(String(err && err.message ? err.message : err));
  process.exit(1);
});
client.on("advertise", (advertised) => {
  for (const channel of advertised) {
    channels.set(channel.id, channel);
    bySubscription.set(client.subscribe(channel.id), channel);
  }
});
client.on("message", ({ subscriptionId, data }) => {
  const channel = bySubscription.get(subscriptionId);
  const name = channel ? channel.topic : String(subscriptionId);
  counts[name] = (counts[name] || 0) + 1;
  if (name === topic && messages.length < wanted) {
    messages.push(JSON.parse(new TextDecoder().decode(data)));
    if (messages.length === wanted) {
      clearTimeout(timer);
      const out = [...channels.values()].map((c) => ({
        topic: c.topic,
        encoding: c.encoding,
        schemaName: c.schemaName,
        schemaEncoding: c.schemaEncoding,
        schema: c.schema,
      }));
      console.log(JSON.stringify({ channels: out, counts, messages }));
      client.close();
      process.exit(0);
    }
  }
});
