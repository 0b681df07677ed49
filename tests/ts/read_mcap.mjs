// Reads an MCAP file with Foxglove's TypeScript reader (@mcap/core) and prints what it saw as JSON:
//   node read_mcap.mjs FILE
// stream: McapStreamReader over the whole file (what Foxglove uses for files without chunk indexes);
// indexed: McapIndexedReader (random access), or the reason it cannot read the file.
// Per topic: the message count and, for CAN topics (schema lde_msgs/msg/CanFrame), every message as
// [log_time, payload hex] in log-time order.
import { readFileSync } from "node:fs";
import { McapIndexedReader, McapStreamReader } from "@mcap/core";
import { decompress as zstdDecompress } from "fzstd";
import lz4 from "lz4js";

const decompressHandlers = {
  zstd: (buf, size) => zstdDecompress(buf, new Uint8Array(Number(size))),
  lz4: (buf, size) => Uint8Array.from(lz4.decompress(buf, Number(size))),
};
const hex = (u8) => Buffer.from(u8).toString("hex");

function collect(schemas, channels, messages) {
  const out = {};
  for (const m of messages) {
    const ch = channels.get(m.channelId);
    const sch = schemas.get(ch.schemaId);
    const t = (out[ch.topic] ??= { count: 0, schema: sch ? sch.name : "", frames: [] });
    t.count += 1;
    if (t.schema === "lde_msgs/msg/CanFrame") t.frames.push([m.logTime.toString(), hex(m.data)]);
  }
  for (const t of Object.values(out)) {
    t.frames.sort((a, b) => (BigInt(a[0]) < BigInt(b[0]) ? -1 : BigInt(a[0]) > BigInt(b[0]) ? 1 : 0));
  }
  return out;
}

const data = new Uint8Array(readFileSync(process.argv[2]));
const result = {};

// the stream reader: every record in file order
{
  const reader = new McapStreamReader({ decompressHandlers, validateCrcs: true });
  reader.append(data);
  const schemas = new Map();
  const channels = new Map();
  const messages = [];
  const metadata = {};
  let rec;
  while ((rec = reader.nextRecord())) {
    if (rec.type === "Schema") schemas.set(rec.id, rec);
    else if (rec.type === "Channel") channels.set(rec.id, rec);
    else if (rec.type === "Message") messages.push(rec);
    else if (rec.type === "Metadata") metadata[rec.name] = Object.fromEntries(rec.metadata);
  }
  result.stream = { done: reader.done(), topics: collect(schemas, channels, messages), metadata };
}

// the indexed reader
try {
  const readable = {
    size: async () => BigInt(data.length),
    read: async (offset, length) => data.subarray(Number(offset), Number(offset + length)),
  };
  const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers });
  if (reader.chunkIndexes.length === 0) {
    result.indexed = { error: "no chunk indexes (Foxglove reads such files with the stream reader)" };
  } else {
    const messages = [];
    for await (const m of reader.readMessages()) messages.push(m);
    result.indexed = { topics: collect(reader.schemasById, reader.channelsById, messages) };
  }
} catch (e) {
  result.indexed = { error: String(e) };
}
process.stdout.write(JSON.stringify(result));
