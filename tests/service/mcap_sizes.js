// What the JSON encoding of an export costs against a binary (protobuf) one, per topic: the JSON
// bytes, and an estimate of the protobuf bytes the same messages would take (every number a
// double of 8 bytes plus a one-byte field tag, integers as varints, strings and nested messages
// length-prefixed, base64 `data` fields as their raw bytes), each raw and after zstd in ~1 MiB
// groups as the writer's chunks compress them. An estimate for a decision, not an encoder.
//   node tests/service/mcap_sizes.js FILE.mcap
'use strict';
const fs = require('fs');
const path = require('path');
const modules = path.join(__dirname, '..', '..', 'service', 'report', 'node_modules');
const { McapIndexedReader } = require(path.join(modules, '@mcap', 'core'));
const zstd = require(path.join(modules, '@foxglove', 'wasm-zstd'));

function varintSize(n) {
  let s = 1;
  while (n >= 128) { n = Math.floor(n / 128); s++; }
  return s;
}
// Bytes of a protobuf-shaped encoding of `value` (without its own tag), appended to `out`.
function binary(value, key, out) {
  if (typeof value === 'number') {
    if (Number.isInteger(value) && value >= 0) { out.push(Buffer.alloc(varintSize(value), value & 127)); return; }
    const b = Buffer.alloc(8); b.writeDoubleLE(value); out.push(b); return;
  }
  if (typeof value === 'boolean') { out.push(Buffer.from([value ? 1 : 0])); return; }
  if (typeof value === 'string') {
    const b = key === 'data' ? Buffer.from(value, 'base64') : Buffer.from(value, 'utf8');
    out.push(Buffer.alloc(varintSize(b.length)), b); return;
  }
  const parts = [];
  const items = Array.isArray(value) ? value.map((v) => [key, v]) : Object.entries(value);
  for (const [k, v] of items) {
    if (Array.isArray(v) && v.length === 0) continue;
    parts.push(Buffer.from([1]));  // the field tag
    const inner = [];
    binary(v, k, inner);
    const b = Buffer.concat(inner);
    if (v !== null && typeof v === 'object') parts.push(Buffer.alloc(varintSize(b.length)));
    parts.push(b);
  }
  out.push(Buffer.concat(parts));
}

async function main() {
  const bytes = fs.readFileSync(process.argv[2]);
  await zstd.isLoaded;
  const readable = {
    size: async () => BigInt(bytes.length),
    read: async (offset, length) => bytes.subarray(Number(offset), Number(offset + length)),
  };
  const reader = await McapIndexedReader.Initialize({
    readable, decompressHandlers: { zstd: (buf, size) => zstd.decompress(buf, Number(size)) } });
  const topics = {};
  for await (const m of reader.readMessages()) {
    const topic = reader.channelsById.get(m.channelId).topic;
    const t = topics[topic] || (topics[topic] = { json: [], pb: [], base64: 0, raw: 0 });
    const value = JSON.parse(Buffer.from(m.data).toString('utf8'));
    const out = [];
    binary(value, '', out);
    t.json.push(Buffer.from(m.data));
    t.pb.push(Buffer.concat(out));
    if (typeof value.data === 'string') { t.base64 += value.data.length; t.raw += Buffer.from(value.data, 'base64').length; }
  }
  const compressed = (buffers) => {  // ~1 MiB groups, as the writer's chunks
    let total = 0, group = [], size = 0;
    const flush = () => { if (group.length) total += zstd.compress(Buffer.concat(group), 3).length; group = []; size = 0; };
    for (const b of buffers) { group.push(b); size += b.length; if (size > (1 << 20)) flush(); }
    flush();
    return total;
  };
  const sum = (buffers) => buffers.reduce((a, b) => a + b.length, 0);
  const result = { file_bytes: bytes.length, topics: {}, total: { json: 0, json_zstd: 0, pb: 0, pb_zstd: 0, base64: 0, raw: 0 } };
  for (const [topic, t] of Object.entries(topics)) {
    const r = { json: sum(t.json), json_zstd: compressed(t.json), pb: sum(t.pb), pb_zstd: compressed(t.pb), base64: t.base64, raw: t.raw };
    result.topics[topic] = r;
    for (const k of Object.keys(r)) result.total[k] += r[k];
  }
  console.log(JSON.stringify(result));
}
main().catch((e) => { console.error(e); process.exit(1); });
