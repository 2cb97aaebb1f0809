// Reads one dcobserver MCAP log with the TypeScript MCAP libraries that Foxglove uses and
// prints what a Foxglove user would see, as JSON: per topic the message count, the range of
// log times (one timeline?) and the first and last decoded messages; the metadata records.
// Usage: node check_log.mjs FILE.mcap
import { open } from "node:fs/promises";

import { McapIndexedReader } from "@mcap/core";
import { FileHandleReadable } from "@mcap/nodejs";
import { loadDecompressHandlers, protobufFromBinaryDescriptor } from "@mcap/support";

const handle = await open(process.argv[2], "r");
try {
  const reader = await McapIndexedReader.Initialize({
    readable: new FileHandleReadable(handle),
    decompressHandlers: await loadDecompressHandlers(),
  });
  const decoders = new Map();
  for (const [id, channel] of reader.channelsById) {
    const schema = reader.schemasById.get(channel.schemaId);
    if (channel.messageEncoding === "protobuf" && schema?.encoding === "protobuf") {
      // As Foxglove does: the message type comes from the FileDescriptorSet in the file.
      const type = protobufFromBinaryDescriptor(schema.data).lookupType(schema.name);
      decoders.set(id, (data) => type.toObject(type.decode(data), { longs: String }));
    } else if (channel.messageEncoding === "json") {
      const text = new TextDecoder();
      decoders.set(id, (data) => JSON.parse(text.decode(data)));
    } else {
      throw new Error(`channel ${channel.topic}: no decoder for ${channel.messageEncoding}`);
    }
  }
  const topics = {};
  for await (const message of reader.readMessages()) {
    const channel = reader.channelsById.get(message.channelId);
    const decoded = decoders.get(message.channelId)(message.data);
    const entry = (topics[channel.topic] ??= {
      schema: reader.schemasById.get(channel.schemaId)?.name,
      encoding: channel.messageEncoding,
      count: 0,
      minLogTime: message.logTime,
      maxLogTime: message.logTime,
      first: decoded,
    });
    entry.count += 1;
    if (message.logTime < entry.minLogTime) entry.minLogTime = message.logTime;
    if (message.logTime > entry.maxLogTime) entry.maxLogTime = message.logTime;
    entry.last = decoded;
  }
  const metadata = {};
  for await (const record of reader.readMetadata()) {
    metadata[record.name] = Object.fromEntries(record.metadata);
  }
  const stats = reader.statistics;
  const out = {
    library: reader.header.library,
    messageStartTime: stats?.messageStartTime,
    messageEndTime: stats?.messageEndTime,
    topics,
    metadata,
  };
  process.stdout.write(
    JSON.stringify(out, (_key, value) => (typeof value === "bigint" ? value.toString() : value)),
  );
} finally {
  await handle.close();
}
