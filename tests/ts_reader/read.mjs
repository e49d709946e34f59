// Read an MCAP file with the official TypeScript reader (@mcap/core) and print what it found as JSON:
// {"reader", "library", "complete", "topics": {topic: {"schema", "count"}}, "metadata": [...], "attachments": [...],
//  "warnings": [...]}.
// Every message is decoded with JSON.parse, which rejects NaN and other non-strict JSON. Warnings name what
// a JavaScript reader such as Foxglove would get wrong or could not use: a number beyond 2^53 (silently
// rounded), a payload that is not a JSON object, a channel whose encoding is not json or whose schema is
// not a parseable jsonschema object, and anything the library itself logs with console.warn/error.
// Usage: node read.mjs FILE.mcap [--stream]   (--stream: McapStreamReader over the bytes, for unfinished files)
import { open, readFile } from "node:fs/promises";
import { McapIndexedReader, McapStreamReader } from "@mcap/core";
import * as zstd from "@foxglove/wasm-zstd";

const [file, mode] = process.argv.slice(2);
if (!file) {
  console.error("usage: node read.mjs FILE.mcap [--stream]");
  process.exit(2);
}
await zstd.isLoaded;
const decompressHandlers = { zstd: (data, size) => zstd.decompress(data, Number(size)) };
const utf8 = new TextDecoder("utf-8", { fatal: true });

const warningCounts = new Map(); // warning text -> occurrences
function warn(text) {
  warningCounts.set(text, (warningCounts.get(text) ?? 0) + 1);
}
for (const level of ["warn", "error"]) {
  console[level] = (...args) => warn(`console.${level}: ${args.map(String).join(" ")}`);
}

const checkedChannels = new Set();
function checkChannel(channel, schema) {
  if (checkedChannels.has(channel.id)) return;
  checkedChannels.add(channel.id);
  if (channel.messageEncoding !== "json") warn(`${channel.topic}: message encoding ${channel.messageEncoding}, not json`);
  if (!schema) return warn(`${channel.topic}: no schema`);
  if (schema.encoding !== "jsonschema") return warn(`${channel.topic}: schema encoding ${schema.encoding}, not jsonschema`);
  try {
    const parsed = JSON.parse(utf8.decode(schema.data));
    if (parsed?.type !== "object") warn(`${channel.topic}: schema ${schema.name} is not of type object`);
  } catch (error) {
    warn(`${channel.topic}: schema ${schema.name} does not parse (${error.message})`);
  }
}

function countMessage(topics, channel, schema, message) {
  checkChannel(channel, schema);
  const payload = JSON.parse(utf8.decode(message.data), (key, value) => {
    if (typeof value === "number" && Number.isInteger(value) && !Number.isSafeInteger(value)) {
      warn(`${channel.topic}: ${key} holds a number beyond 2^53 (not exact in JavaScript)`);
    }
    return value;
  });
  if (payload === null || typeof payload !== "object" || Array.isArray(payload)) {
    warn(`${channel.topic}: a payload is not a JSON object`);
  }
  const entry = (topics[channel.topic] ??= { schema: schema?.name ?? "", count: 0 });
  entry.count += 1;
}

function warnings() {
  return [...warningCounts].map(([text, count]) => (count > 1 ? `${text} (${count} times)` : text));
}

async function readIndexed() {
  const handle = await open(file, "r");
  try {
    const readable = {
      size: async () => BigInt((await handle.stat()).size),
      read: async (offset, size) => {
        const buffer = new Uint8Array(Number(size));
        const { bytesRead } = await handle.read(buffer, 0, Number(size), Number(offset));
        if (bytesRead !== Number(size)) throw new Error(`short read at ${offset}`);
        return buffer;
      },
    };
    const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers });
    const topics = {};
    for await (const message of reader.readMessages({ validateCrcs: true })) {
      const channel = reader.channelsById.get(message.channelId);
      const schema = reader.schemasById.get(channel.schemaId);
      countMessage(topics, channel, schema, message);
    }
    const metadata = [];
    for await (const record of reader.readMetadata()) metadata.push(record.name);
    const attachments = [];
    for await (const record of reader.readAttachments({ validateCrcs: true })) attachments.push(record.name);
    return {
      reader: "McapIndexedReader",
      library: reader.header.library,
      complete: true,
      topics,
      metadata,
      attachments,
      warnings: warnings(),
    };
  } finally {
    await handle.close();
  }
}

async function readStream() {
  const reader = new McapStreamReader({ decompressHandlers, validateCrcs: true });
  reader.append(await readFile(file));
  const schemas = new Map();
  const channels = new Map();
  const topics = {};
  const metadata = [];
  const attachments = [];
  let library = "";
  for (let record; (record = reader.nextRecord()); ) {
    if (record.type === "Header") library = record.library;
    else if (record.type === "Schema") schemas.set(record.id, record);
    else if (record.type === "Channel") channels.set(record.id, record);
    else if (record.type === "Message") {
      const channel = channels.get(record.channelId);
      countMessage(topics, channel, schemas.get(channel.schemaId), record);
    } else if (record.type === "Metadata") metadata.push(record.name);
    else if (record.type === "Attachment") attachments.push(record.name);
  }
  return {
    reader: "McapStreamReader",
    library,
    complete: reader.done(),
    topics,
    metadata,
    attachments,
    warnings: warnings(),
  };
}

const result = mode === "--stream" ? await readStream() : await readIndexed();
process.stdout.write(JSON.stringify(result) + "\n");
