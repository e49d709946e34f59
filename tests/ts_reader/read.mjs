// Read an MCAP file with the official TypeScript reader (@mcap/core) and print what it found as JSON:
// {"reader", "library", "complete", "topics": {topic: {"schema", "count"}}, "metadata": [...], "attachments": [...]}.
// Every message is decoded with JSON.parse, which rejects NaN and other non-strict JSON.
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

function countMessage(topics, channel, schemaName, message) {
  JSON.parse(utf8.decode(message.data));
  const entry = (topics[channel.topic] ??= { schema: schemaName, count: 0 });
  entry.count += 1;
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
      countMessage(topics, channel, schema?.name ?? "", message);
    }
    const metadata = [];
    for await (const record of reader.readMetadata()) metadata.push(record.name);
    const attachments = [];
    for await (const record of reader.readAttachments({ validateCrcs: true })) attachments.push(record.name);
    return { reader: "McapIndexedReader", library: reader.header.library, complete: true, topics, metadata, attachments };
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
      countMessage(topics, channel, schemas.get(channel.schemaId)?.name ?? "", record);
    } else if (record.type === "Metadata") metadata.push(record.name);
    else if (record.type === "Attachment") attachments.push(record.name);
  }
  return { reader: "McapStreamReader", library, complete: reader.done(), topics, metadata, attachments };
}

const result = mode === "--stream" ? await readStream() : await readIndexed();
process.stdout.write(JSON.stringify(result) + "\n");
