// Independent check of an MCAP file with Foxglove's own TypeScript reader.
// usage: node check_mcap.mjs FILE.mcap [--stream-only]
// Indexed read (summary, chunk indexes, CRC validation) + decode of every message
// (protobuf via the schema's FileDescriptorSet, json via JSON.parse), then a streaming read
// with CRC validation.  Every message of a Foxglove schema ("foxglove.X") is decoded a second
// time against Foxglove's own published schema (@foxglove/schemas: the .proto it generates),
// and the fields both know must agree; a LocationFix must hold a latitude and longitude in
// range, a GeoJSON message parseable GeoJSON.  Prints one JSON object; exits 1 on any failure.
import { createRequire } from "node:module";
import { open, readFile } from "node:fs/promises";
import { McapIndexedReader, McapStreamReader } from "@mcap/core";
import { FileHandleReadable } from "@mcap/nodejs";
import { loadDecompressHandlers, protobufFromBinaryDescriptor } from "@mcap/support";
import protobuf from "protobufjs";

const require = createRequire(import.meta.url);
const foxgloveSchemas = require("@foxglove/schemas/internal");

const file = process.argv[2];
const streamOnly = process.argv.includes("--stream-only");
const decompressHandlers = await loadDecompressHandlers();
const out = { file };

// Foxglove's published message schemas, as one protobufjs root
function canonicalRoot() {
  const root = new protobuf.Root();
  for (const name of ["google/protobuf/timestamp.proto", "google/protobuf/duration.proto"]) {
    root.addJSON(protobuf.common[name].nested);
  }
  const enums = Object.values(foxgloveSchemas.foxgloveEnumSchemas);
  for (const sc of Object.values(foxgloveSchemas.foxgloveMessageSchemas)) {
    const nested = enums.filter((e) => e.parentSchemaName === sc.name);
    protobuf.parse(foxgloveSchemas.generateProto(sc, nested), root, { keepCase: true });
  }
  root.resolveAll();
  return root;
}
const CANON = canonicalRoot();
const OPTS = { defaults: true, longs: String, enums: Number, bytes: String };

function same(a, b) {
  return JSON.stringify(a) === JSON.stringify(b);
}

// a second decode against Foxglove's schema; the fields both decoders know must agree
function canonicalCheck(schema, channel, data, obj) {
  if (channel.messageEncoding !== "protobuf" || !schema.name.startsWith("foxglove.")) return false;
  const type = CANON.lookupType(schema.name);
  const canon = type.toObject(type.decode(data), OPTS);
  for (const [k, v] of Object.entries(obj)) {
    if (k in canon && !same(v, canon[k])) {
      throw new Error(`${channel.topic}: field ${k} is ${JSON.stringify(v).slice(0, 80)} by the log's schema, ${JSON.stringify(canon[k]).slice(0, 80)} by Foxglove's`);
    }
  }
  if (schema.name === "foxglove.LocationFix") {
    const ok = Math.abs(canon.latitude) <= 90 && Math.abs(canon.longitude) <= 180;
    if (!ok) throw new Error(`${channel.topic}: latitude/longitude out of range`);
  } else if (schema.name === "foxglove.GeoJSON") {
    const gj = JSON.parse(canon.geojson);
    if (!["FeatureCollection", "Feature"].includes(gj?.type)) {
      throw new Error(`${channel.topic}: GeoJSON of type ${gj?.type}`);
    }
  }
  return true;
}

function makeDecoder(schema, channel) {
  if (channel.messageEncoding === "protobuf") {
    const root = protobufFromBinaryDescriptor(schema.data);
    const type = root.lookupType(schema.name);
    return (data) => type.toObject(type.decode(data), OPTS);
  }
  if (channel.messageEncoding === "json") {
    const td = new TextDecoder();
    return (data) => JSON.parse(td.decode(data));
  }
  throw new Error(`unsupported encoding ${channel.messageEncoding} on ${channel.topic}`);
}

try {
  if (!streamOnly) {
    const handle = await open(file, "r");
    try {
      const reader = await McapIndexedReader.Initialize({
        readable: new FileHandleReadable(handle), decompressHandlers,
      });
      const decoders = new Map();
      const byTopic = {};
      const samples = {};
      const canonical = {};
      let n = 0;
      for await (const msg of reader.readMessages({ validateCrcs: true })) {
        const channel = reader.channelsById.get(msg.channelId);
        const schema = reader.schemasById.get(channel.schemaId);
        let dec = decoders.get(channel.id);
        if (!dec) { dec = makeDecoder(schema, channel); decoders.set(channel.id, dec); }
        const obj = dec(msg.data);
        if (obj === undefined || obj === null) throw new Error(`decode gave nothing: ${channel.topic}`);
        if (canonicalCheck(schema, channel, msg.data, obj)) {
          canonical[channel.topic] = (canonical[channel.topic] ?? 0) + 1;
        }
        if (!(channel.topic in samples)) samples[channel.topic] = Object.keys(obj);
        byTopic[channel.topic] = (byTopic[channel.topic] ?? 0) + 1;
        n += 1;
      }
      const stats = reader.statistics;
      const metadata = [];
      for await (const m of reader.readMetadata()) metadata.push(m.name);
      const attachments = [];
      for await (const a of reader.readAttachments({ validateCrcs: true })) attachments.push(a.name);
      out.indexed = {
        messages: n, decoded: n, statistics_messages: Number(stats?.messageCount ?? -1),
        chunks: reader.chunkIndexes.length, by_topic: byTopic, field_names: samples, canonical,
        metadata, attachments,
      };
      if (stats && Number(stats.messageCount) !== n) throw new Error(`statistics say ${stats.messageCount} messages, read ${n}`);
    } finally {
      await handle.close();
    }
  }
  const reader = new McapStreamReader({ decompressHandlers, validateCrcs: true });
  reader.append(await readFile(file));
  let n = 0;
  let footer = false;
  for (let rec; (rec = reader.nextRecord()); ) {
    if (rec.type === "Message") n += 1;
    if (rec.type === "Footer") footer = true;
  }
  out.stream = { messages: n, footer, done: reader.done() };
  out.ok = true;
  console.log(JSON.stringify(out));
} catch (err) {
  out.ok = false;
  out.error = String(err?.stack ?? err);
  console.log(JSON.stringify(out));
  process.exit(1);
}
