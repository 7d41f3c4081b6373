// An independent Foxglove WebSocket client for the live-view tests and benchmark.
//
//   node live_client.mjs --url ws://127.0.0.1:8765 [--timeout-s 60] [--expect T1,T2,...]
//                        [--min-count N] [--after-s S] [--image-data-every K] [--quiet]
//
// Connects with Foxglove's own client library (@foxglove/ws-protocol), subscribes to every
// channel the server advertises (also those advertised later), and decodes each message the way
// the Foxglove app does: protobuf channels through protobufjs from the FileDescriptorSet in the
// advertisement, JSON channels with JSON.parse. Prints one JSON object per line on stdout:
//   {"event":"serverInfo", ...}, {"event":"advertise","channels":[...]},
//   {"event":"message","topic","schemaName","encoding","logTimeNs","receivedMs","bytes","decoded"}
//   (CompressedImage: "data" replaced by its length "dataBytes", and the base64 image every K-th
//   message as "dataBase64"), and last {"event":"summary","counts","ratesHz","elapsedS",...}.
// Stops when the server closes the connection, at --timeout-s, or (with --expect) once every
// expected topic got --min-count messages and --after-s seconds have passed since the first.
// Exit status: 0 when every expected topic was advertised and got --min-count messages, else 1
// (2 for bad arguments, 3 when no connection could be made).
import protobufjs from "protobufjs";
import descriptor from "protobufjs/ext/descriptor/index.js";
import wsProtocol from "@foxglove/ws-protocol";
import WebSocket from "ws";

const { FoxgloveClient } = wsProtocol;

function parseArgs(argv) {
  const opts = { url: "", timeoutS: 60, expect: [], minCount: 1, afterS: null, imageDataEvery: 0,
                 quiet: false, waitUntilClose: false };
  for (let i = 0; i < argv.length; i++) {
    const a = argv[i];
    const next = () => {
      if (i + 1 >= argv.length) { throw new Error(`${a}: missing value`); }
      return argv[++i];
    };
    if (a === "--url") opts.url = next();
    else if (a === "--timeout-s") opts.timeoutS = Number(next());
    else if (a === "--expect") opts.expect = next().split(",").filter((s) => s.length > 0);
    else if (a === "--min-count") opts.minCount = Number(next());
    else if (a === "--after-s") opts.afterS = Number(next());
    else if (a === "--image-data-every") opts.imageDataEvery = Number(next());
    else if (a === "--quiet") opts.quiet = true;
    else throw new Error(`unknown option ${a}`);
  }
  if (!opts.url.startsWith("ws://")) throw new Error("--url: expected ws://HOST:PORT");
  if (!(opts.timeoutS > 0)) throw new Error("--timeout-s: expected a positive number");
  return opts;
}

let opts;
try {
  opts = parseArgs(process.argv.slice(2));
} catch (err) {
  process.stderr.write(`live_client: ${err.message}\n`);
  process.exit(2);
}

const out = (obj) => process.stdout.write(JSON.stringify(obj) + "\n");
const t0 = Date.now();
const channels = new Map();      // channel id -> {topic, encoding, schemaName, decode}
const subscriptions = new Map(); // subscription id -> channel id
const counts = {};
const firstMs = {};
const lastMs = {};
const bytes = {};
let imageMessages = 0;
let connected = false;
let finished = false;
let client = null;

function decoderFor(channel) {
  if (channel.encoding === "json") {
    const text = new TextDecoder();
    return (data) => JSON.parse(text.decode(data));
  }
  if (channel.encoding === "protobuf") {
    const set = descriptor.FileDescriptorSet.decode(Buffer.from(channel.schema, "base64"));
    const root = protobufjs.Root.fromDescriptor(set);
    root.resolveAll();
    const type = root.lookupType(channel.schemaName);
    return (data) => type.toObject(type.decode(data), { longs: Number, enums: String, bytes: Buffer,
                                                        defaults: true, arrays: true });
  }
  return null;   // other encodings: counted, not decoded
}

function summary() {
  const ratesHz = {};
  for (const [topic, n] of Object.entries(counts)) {
    const span = (lastMs[topic] - firstMs[topic]) / 1000;
    ratesHz[topic] = n > 1 && span > 0 ? (n - 1) / span : 0;
  }
  return { event: "summary", counts, ratesHz, bytes, elapsedS: (Date.now() - t0) / 1000,
           advertised: [...channels.values()].map((c) => c.topic) };
}

function satisfied() {
  const topics = new Set([...channels.values()].map((c) => c.topic));
  return opts.expect.every((t) => topics.has(t) && (counts[t] ?? 0) >= opts.minCount);
}

function finish(reason) {
  if (finished) return;
  finished = true;
  out({ ...summary(), reason });
  try { client?.close(); } catch { /* already closed */ }
  const ok = connected && satisfied();
  process.exitCode = connected ? (ok ? 0 : 1) : 3;
  setTimeout(() => process.exit(process.exitCode), 50);
}

function onMessage({ subscriptionId, timestamp, data }) {
  const chanId = subscriptions.get(subscriptionId);
  const chan = channels.get(chanId);
  if (chan === undefined || finished) return;
  const now = Date.now();
  const topic = chan.topic;
  counts[topic] = (counts[topic] ?? 0) + 1;
  firstMs[topic] ??= now;
  lastMs[topic] = now;
  bytes[topic] = (bytes[topic] ?? 0) + data.byteLength;
  let decoded = null;
  let error = null;
  if (chan.decode !== null) {
    try {
      decoded = chan.decode(new Uint8Array(data.buffer, data.byteOffset, data.byteLength));
    } catch (err) {
      error = String(err);
    }
  }
  if (decoded !== null && chan.schemaName === "foxglove.CompressedImage") {
    const raw = decoded.data;
    decoded.dataBytes = raw.length;
    delete decoded.data;
    imageMessages += 1;
    if (opts.imageDataEvery > 0 && (imageMessages - 1) % opts.imageDataEvery === 0) {
      decoded.dataBase64 = Buffer.from(raw).toString("base64");
    }
  }
  if (!opts.quiet) {
    out({ event: "message", topic, schemaName: chan.schemaName, encoding: chan.encoding,
          logTimeNs: Number(timestamp), receivedMs: now - t0, bytes: data.byteLength, decoded, error });
  }
  if (opts.expect.length > 0 && opts.afterS !== null && satisfied()) {
    const first = Math.min(...opts.expect.map((t) => firstMs[t]));
    if (now - first >= opts.afterS * 1000) finish("satisfied");
  }
}

function connect() {
  // the Foxglove SDK's server speaks the ws-protocol spec as "foxglove.sdk.v1" (older servers:
  // "foxglove.websocket.v1", the library's own name for it); offer both, as the Foxglove app does
  const ws = new WebSocket(opts.url, ["foxglove.sdk.v1", FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
  client = new FoxgloveClient({ ws });
  client.on("open", () => { connected = true; out({ event: "open", url: opts.url }); });
  client.on("error", (err) => {
    if (!connected) return;   // before the connection: retried below
    out({ event: "error", error: String(err) });
  });
  client.on("close", () => {
    if (!connected) {          // the server is not up yet: try again until the timeout
      if (!finished) setTimeout(connect, 200);
      return;
    }
    finish("closed by the server");
  });
  client.on("serverInfo", (info) => out({ event: "serverInfo", ...info }));
  client.on("time", (t) => { lastTime = Number(t.timestamp); });
  client.on("advertise", (list) => {
    for (const c of list) {
      let decode = null;
      let error = null;
      try { decode = decoderFor(c); } catch (err) { error = String(err); }
      channels.set(c.id, { topic: c.topic, encoding: c.encoding, schemaName: c.schemaName, decode });
      subscriptions.set(client.subscribe(c.id), c.id);
      out({ event: "advertise", channel: { id: c.id, topic: c.topic, encoding: c.encoding,
                                           schemaName: c.schemaName, schemaEncoding: c.schemaEncoding },
            error });
    }
  });
  client.on("unadvertise", (ids) => out({ event: "unadvertise", ids }));
  client.on("message", onMessage);
}

let lastTime = null;
setTimeout(() => finish("timeout"), opts.timeoutS * 1000);
connect();
