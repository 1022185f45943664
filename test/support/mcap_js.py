"""The TypeScript @mcap/core reader's script (the mcap_js fixture of test/conftest.py)."""

import pytest

pytest.importorskip('rclpy')

_JS = r'''
import { readFileSync } from 'node:fs';
import { McapStreamReader, McapIndexedReader } from '@mcap/core';
import { decompress } from 'fzstd';
const handlers = { zstd: (buf, size) => decompress(buf, new Uint8Array(Number(size))) };
const results = {};
for (const file of process.argv.slice(2)) {
  const bytes = new Uint8Array(readFileSync(file));
  const out = { stream: {}, indexed: {} };
  try {
    const reader = new McapStreamReader({ validateCrcs: true, decompressHandlers: handlers });
    reader.append(bytes);
    const topics = new Map(); const counts = {}; const metadata = []; let profile = null;
    for (let r; (r = reader.nextRecord()); ) {
      if (r.type === 'Header') profile = r.profile;
      if (r.type === 'Channel') topics.set(r.id, r.topic);
      if (r.type === 'Metadata') metadata.push(r.name);
      if (r.type === 'Message') {
        const t = topics.get(r.channelId); counts[t] = (counts[t] ?? 0) + 1;
      }
    }
    Object.assign(out.stream, { profile, counts, metadata, done: reader.done() });
  } catch (e) { out.stream.error = String(e); }
  try {
    const readable = { size: async () => BigInt(bytes.length),
      read: async (offset, size) => bytes.subarray(Number(offset), Number(offset + size)) };
    const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers: handlers });
    const counts = {};
    for await (const m of reader.readMessages()) {
      const t = reader.channelsById.get(m.channelId).topic; counts[t] = (counts[t] ?? 0) + 1;
    }
    const metadata = {};
    for await (const m of reader.readMetadata()) metadata[m.name] = Object.fromEntries(m.metadata);
    Object.assign(out.indexed, { counts, metadata,
      statisticsMessageCount: Number(reader.statistics?.messageCount ?? -1),
      compression: [...new Set(reader.chunkIndexes.map((c) => c.compression))] });
  } catch (e) { out.indexed.error = String(e); }
  results[file] = out;
}
console.log(JSON.stringify(results));
'''
