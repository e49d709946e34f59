// Validate every foxglove.* message of an MCAP file against Foxglove's published JSON Schemas
// (@foxglove/schemas/jsonschema) with Ajv, and compare the schema each channel carries with the official one.
// Prints one JSON object: {"topics": {topic: {"schema", "messages", "invalid", "errors"}},
//  "schema_gaps": {topic: [paths the official schema requires and the channel's schema does not]},
//  "unknown_schemas": [foxglove.* schema names @foxglove/schemas does not publish]}.
// Usage: node foxglove_check.mjs FILE.mcap
import { createRequire } from "node:module";
import { open } from "node:fs/promises";
import { McapIndexedReader } from "@mcap/core";
import * as zstd from "@foxglove/wasm-zstd";
import Ajv from "ajv";

const require = createRequire(import.meta.url);
const official = require("@foxglove/schemas/jsonschema.js");

const [file] = process.argv.slice(2);
if (!file) {
  console.error("usage: node foxglove_check.mjs FILE.mcap");
  process.exit(2);
}
await zstd.isLoaded;
const decompressHandlers = { zstd: (data, size) => zstd.decompress(data, Number(size)) };
const utf8 = new TextDecoder("utf-8", { fatal: true });
const ajv = new Ajv({ allErrors: true, strict: false });

// Paths below `path` where `theirs` requires a property that `ours` does not (or does not declare).
function gaps(ours, theirs, path, out) {
  if (!theirs || typeof theirs !== "object") return out;
  if (theirs.type === "object" && theirs.properties) {
    const required = new Set(ours?.required ?? []);
    for (const name of theirs.required ?? []) {
      if (!required.has(name)) out.push(`${path}.${name}`);
    }
    for (const [name, sub] of Object.entries(theirs.properties)) {
      gaps(ours?.properties?.[name], sub, `${path}.${name}`, out);
    }
  } else if (theirs.type === "array" && theirs.items) {
    gaps(ours?.items, theirs.items, `${path}[]`, out);
  }
  return out;
}

const handle = await open(file, "r");
const readable = {
  size: async () => BigInt((await handle.stat()).size),
  read: async (offset, size) => {
    const buffer = new Uint8Array(Number(size));
    await handle.read(buffer, 0, Number(size), Number(offset));
    return buffer;
  },
};
const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers });
const topics = {};
const schemaGaps = {};
const unknown = new Set();
const validators = new Map(); // channel id -> Ajv validate function, or null when not foxglove.*
for await (const message of reader.readMessages()) {
  const channel = reader.channelsById.get(message.channelId);
  const schema = reader.schemasById.get(channel.schemaId);
  if (!validators.has(channel.id)) {
    const name = schema?.name ?? "";
    const theirs = name.startsWith("foxglove.") ? official[name.slice("foxglove.".length)] : undefined;
    if (name.startsWith("foxglove.") && !theirs) unknown.add(name);
    validators.set(channel.id, theirs ? ajv.compile(theirs) : null);
    if (theirs) {
      const ours = JSON.parse(utf8.decode(schema.data));
      schemaGaps[channel.topic] = gaps(ours, theirs, "", []);
      topics[channel.topic] = { schema: name, messages: 0, invalid: 0, errors: [] };
    }
  }
  const validate = validators.get(channel.id);
  if (!validate) continue;
  const entry = topics[channel.topic];
  entry.messages += 1;
  if (!validate(JSON.parse(utf8.decode(message.data)))) {
    entry.invalid += 1;
    if (entry.errors.length < 3) entry.errors.push(ajv.errorsText(validate.errors));
  }
}
await handle.close();
process.stdout.write(JSON.stringify({ topics, schema_gaps: schemaGaps, unknown_schemas: [...unknown] }) + "\n");
