// Independent check of an MCAP file with Foxglove's own TypeScript reader.
// usage: node check_mcap.mjs FILE.mcap [--stream-only]
// Indexed read (summary, chunk indexes, CRC validation) + decode of every message
// (protobuf via the schema's FileDescriptorSet, json via JSON.parse), then a streaming read
// with CRC validation.  Prints one JSON object; exits 1 on any failure.
import { open, readFile } from "node:fs/promises";
import { McapIndexedReader, McapStreamReader } from "@mcap/core";
import { FileHandleReadable } from "@mcap/nodejs";
import { loadDecompressHandlers, protobufFromBinaryDescriptor } from "@mcap/support";

const file = process.argv[2];
const streamOnly = process.argv.includes("--stream-only");
const decompressHandlers = await loadDecompressHandlers();
const out = { file };

function makeDecoder(schema, channel) {
  if (channel.messageEncoding === "protobuf") {
    const root = protobufFromBinaryDescriptor(schema.data);
    const type = root.lookupType(schema.name);
    return (data) => type.toObject(type.decode(data), { defaults: true });
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
      let n = 0;
      for await (const msg of reader.readMessages({ validateCrcs: true })) {
        const channel = reader.channelsById.get(msg.channelId);
        const schema = reader.schemasById.get(channel.schemaId);
        let dec = decoders.get(channel.id);
        if (!dec) { dec = makeDecoder(schema, channel); decoders.set(channel.id, dec); }
        const obj = dec(msg.data);
        if (obj === undefined || obj === null) throw new Error(`decode gave nothing: ${channel.topic}`);
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
        chunks: reader.chunkIndexes.length, by_topic: byTopic, field_names: samples,
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
