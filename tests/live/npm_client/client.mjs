// A Foxglove WebSocket client nobody here wrote: @foxglove/ws-protocol's FoxgloveClient over the
// `ws` package, decoding every message with protobufjs from the schemas the server advertises.
//
//   node client.mjs URL SUBPROTOCOL [TIMEOUT_S]
//
// Subscribes to every channel advertised and, when the server closes the connection, prints one
// JSON summary on stdout: the subprotocol agreed, the close code, each topic's schema, the log
// times of its messages and, for foxglove.Grid, each grid's cell count and value range. Exits 1
// where the connection failed or the server did not close it within TIMEOUT_S (default 30).
import { createRequire } from "node:module";

const require = createRequire(import.meta.url);
const { FoxgloveClient } = require("@foxglove/ws-protocol");
const protobuf = require("protobufjs");
const descriptor = require("protobufjs/ext/descriptor");
const WebSocket = require("ws");

const [url, subprotocol, timeoutS = "30"] = process.argv.slice(2);
if (!url || !subprotocol) {
  console.error("usage: node client.mjs URL SUBPROTOCOL [TIMEOUT_S]");
  process.exit(2);
}

const summary = { subprotocol: null, closeCode: null, server: null, topics: {}, errors: [] };
const channels = new Map(); // subscription id -> { topic, type }

function decoderOf(channel) {
  if (channel.encoding !== "protobuf" || channel.schemaEncoding !== "protobuf") {
    throw new Error(`${channel.topic}: not protobuf (${channel.encoding})`);
  }
  const bytes = Buffer.from(channel.schema, "base64");
  const root = protobuf.Root.fromDescriptor(descriptor.FileDescriptorSet.decode(bytes));
  return root.lookupType(channel.schemaName);
}

function gridSummary(grid) {
  const cells = new Int8Array(grid.data.buffer, grid.data.byteOffset, grid.data.byteLength);
  let min = 127;
  let max = -128;
  for (const v of cells) {
    if (v < min) min = v;
    if (v > max) max = v;
  }
  const rows = grid.rowStride > 0 ? cells.length / grid.rowStride : 0;
  return { columns: grid.columnCount, rows, cells: cells.length, min, max };
}

const ws = new WebSocket(url, [subprotocol]);
const client = new FoxgloveClient({ ws });
const timer = setTimeout(() => finish(1, `no close from the server within ${timeoutS} s`),
  Number(timeoutS) * 1000);

function finish(code, error) {
  clearTimeout(timer);
  if (error) summary.errors.push(error);
  process.stdout.write(JSON.stringify(summary) + "\n", () => process.exit(code));
}

client.on("open", () => { summary.subprotocol = ws.protocol; });
client.on("serverInfo", (info) => { summary.server = info.name; });
client.on("error", (err) => summary.errors.push(String(err?.message ?? err)));
client.on("advertise", (advertised) => {
  for (const channel of advertised) {
    try {
      const type = decoderOf(channel);
      const id = client.subscribe(channel.id);
      channels.set(id, { topic: channel.topic, type });
      summary.topics[channel.topic] = { schema: channel.schemaName, logTimes: [], grids: [] };
    } catch (err) {
      summary.errors.push(String(err.message));
    }
  }
});
client.on("message", ({ subscriptionId, timestamp, data }) => {
  const channel = channels.get(subscriptionId);
  const topic = summary.topics[channel.topic];
  const message = channel.type.decode(new Uint8Array(data.buffer, data.byteOffset, data.byteLength));
  topic.logTimes.push(timestamp.toString()); // uint64 nanoseconds: a string, JSON has no int64
  if (topic.schema === "foxglove.Grid") topic.grids.push(gridSummary(message));
});
client.on("close", (event) => {
  summary.closeCode = event.code;
  finish(summary.subprotocol === null ? 1 : 0, summary.subprotocol === null
    ? `could not connect (close ${event.code})` : null);
});
