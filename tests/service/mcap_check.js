// Independent check of an MCAP file terrastride wrote, with @mcap/core (service/report's Node
// toolchain): the file is read twice, once indexed (footer, summary, chunk indexes, message
// indexes) and once as a stream (every record in order, CRCs of chunks, data section and summary
// validated), every message decoded as JSON and checked against its channel's schema (the
// published Foxglove JSON schema the file carries), and the counts per topic compared.
// The frames: every scene entity, grid and point cloud is in `map` or in a frame /tf defines, and
// /tf's frames form a tree (one parent each). It also counts what the terrain topics hold (cubes,
// triangles, points) and finds the largest message.
//   node tests/service/mcap_check.js FILE.mcap ['{"topic": count, ...}']
// Prints one JSON line: {ok, errors, topics: {topic: count}, statistics, chunks, compression,
// largest: {bytes, topic}, cubes: {topic: n}, triangles: {topic: n}, points: {topic: n},
// robot_spheres: {topic: [[x, y, z, diameter]]} (the first message of each .../robot topic, its
// spheres placed in map through /tf at that time), numbers: {path: [min, max]}, logs,
// grids: {topic: {field: [min, max]}} (FLOAT32 fields, NaN left out), point_boxes: {topic:
// [min x, y, z, max x, y, z]} of the point clouds (x y z FLOAT32 first),
// frames: [child frames of /tf], schemas: {topic: schema name}}.
'use strict';
const fs = require('fs');
const path = require('path');
const modules = path.join(__dirname, '..', '..', 'service', 'report', 'node_modules');
const { McapIndexedReader, McapStreamReader } = require(path.join(modules, '@mcap', 'core'));
const zstd = require(path.join(modules, '@foxglove', 'wasm-zstd'));

// A JSON-schema subset validator: the keywords the Foxglove schemas use.
function validate(schema, value, where, errors) {
  if (errors.length > 20) return;
  if (schema.oneOf) {
    if (!schema.oneOf.some((s) => s.const === undefined || s.const === value))
      errors.push(where + ': ' + JSON.stringify(value) + ' is none of ' + schema.title);
    return;
  }
  switch (schema.type) {
    case 'object':
      if (value === null || typeof value !== 'object' || Array.isArray(value)) {
        errors.push(where + ': not an object'); return;
      }
      for (const k of schema.required || [])
        if (!(k in value)) errors.push(where + ': missing ' + k);
      for (const [k, s] of Object.entries(schema.properties || {}))
        if (k in value) validate(s, value[k], where + '.' + k, errors);
      return;
    case 'array':
      if (!Array.isArray(value)) { errors.push(where + ': not an array'); return; }
      value.forEach((v, i) => validate(schema.items || {}, v, where + '[' + i + ']', errors));
      return;
    case 'number':
      if (typeof value !== 'number' || !isFinite(value)) errors.push(where + ': not a finite number');
      return;
    case 'integer':
      if (!Number.isInteger(value)) errors.push(where + ': not an integer');
      else if (schema.minimum !== undefined && value < schema.minimum) errors.push(where + ': below minimum');
      return;
    case 'string':
      if (typeof value !== 'string') errors.push(where + ': not a string');
      else if (schema.contentEncoding === 'base64' && !/^[A-Za-z0-9+/]*={0,2}$/.test(value))
        errors.push(where + ': not base64');
      return;
    case 'boolean':
      if (typeof value !== 'boolean') errors.push(where + ': not a boolean');
      return;
  }
}

// The range of every numeric field of a message of our own schemas, by path
// ("/plan/joints.LF.kfe.torque": [min, max]), as Foxglove's Plot panel addresses them.
function collectNumbers(prefix, value, out) {
  for (const [k, v] of Object.entries(value)) {
    if (k === 'timestamp') continue;
    const p = prefix + '.' + k;
    if (typeof v === 'number') out[p] = out[p] ? [Math.min(out[p][0], v), Math.max(out[p][1], v)] : [v, v];
    else if (v && typeof v === 'object') collectNumbers(p, v, out);
  }
}

// Rotates v by the unit quaternion q.
function rotate(q, v) {
  const { x, y, z, w } = q;
  const tx = 2 * (y * v.z - z * v.y), ty = 2 * (z * v.x - x * v.z), tz = 2 * (x * v.y - y * v.x);
  return { x: v.x + w * tx + (y * tz - z * ty), y: v.y + w * ty + (z * tx - x * tz), z: v.z + w * tz + (x * ty - y * tx) };
}
// A point of `frame` in map, through the transforms of one /tf message (child -> transform).
function toMap(transforms, frame, p) {
  for (let steps = 0; frame !== 'map' && steps < 20; steps++) {
    const t = transforms[frame];
    if (!t) return null;
    const r = rotate(t.rotation, p);
    p = { x: r.x + t.translation.x, y: r.y + t.translation.y, z: r.z + t.translation.z };
    frame = t.parent_frame_id;
  }
  return frame === 'map' ? p : null;
}

async function main() {
  const file = process.argv[2];
  const expected = process.argv[3] ? JSON.parse(process.argv[3]) : null;
  const bytes = fs.readFileSync(file);
  await zstd.isLoaded;
  const decompressHandlers = { zstd: (buf, size) => zstd.decompress(buf, Number(size)) };
  const errors = [];

  // 1. Indexed reading: summary, statistics, chunk and message indexes.
  const readable = {
    size: async () => BigInt(bytes.length),
    read: async (offset, length) => bytes.subarray(Number(offset), Number(offset + length)),
  };
  const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers });
  const topics = {};
  const schemaOf = {};
  for (const [id, ch] of reader.channelsById) {
    const schema = reader.schemasById.get(ch.schemaId);
    if (!schema || schema.encoding !== 'jsonschema' || ch.messageEncoding !== 'json')
      errors.push(ch.topic + ': not a jsonschema/json channel');
    schemaOf[id] = JSON.parse(new TextDecoder().decode(schema.data));
    topics[ch.topic] = 0;
  }
  let messages = 0;
  const largest = { bytes: 0, topic: '' };
  const cubes = {}, triangles = {}, points = {}, schemas = {};
  const parentOf = {}, framesUsed = new Set();
  const numbers = {}, logs = [], grids = {}, pointBoxes = {};
  // The first message of each robot topic, its spheres placed in map by /tf at its time.
  const tfAt = new Map(), firstRobot = {};
  for (const [, ch] of reader.channelsById) schemas[ch.topic] = reader.schemasById.get(ch.schemaId).name;
  for await (const m of reader.readMessages()) {
    const ch = reader.channelsById.get(m.channelId);
    topics[ch.topic]++;
    messages++;
    let value;
    try {
      value = JSON.parse(new TextDecoder().decode(m.data));
    } catch (e) {
      errors.push(ch.topic + ': message ' + m.sequence + ' is not JSON'); continue;
    }
    const errs = [];
    validate(schemaOf[m.channelId], value, ch.topic + '#' + m.sequence, errs);
    errors.push(...errs.slice(0, 3));
    if (m.data.length > largest.bytes) { largest.bytes = m.data.length; largest.topic = ch.topic; }
    const schemaName = schemas[ch.topic];
    if (schemaName === 'foxglove.SceneUpdate' && ch.topic.endsWith('/robot') && !firstRobot[ch.topic])
      firstRobot[ch.topic] = { t: m.logTime, value };
    if (schemaName === 'foxglove.SceneUpdate') {
      for (const e of value.entities || []) {
        framesUsed.add(e.frame_id);
        cubes[ch.topic] = (cubes[ch.topic] || 0) + (e.cubes || []).length;
        for (const t of e.triangles || [])
          triangles[ch.topic] = (triangles[ch.topic] || 0) + (t.indices.length || t.points.length) / 3;
      }
    } else if (schemaName.startsWith('terrastride.')) {
      collectNumbers(ch.topic, value, numbers);
    } else if (schemaName === 'foxglove.Log') {
      logs.push({ level: value.level, message: value.message, t: value.timestamp.sec + 1e-9 * value.timestamp.nsec });
    } else if (schemaName === 'foxglove.PointCloud') {
      framesUsed.add(value.frame_id);
      const data = Buffer.from(value.data, 'base64');
      points[ch.topic] = (points[ch.topic] || 0) + data.length / value.point_stride;
      const box = pointBoxes[ch.topic] = pointBoxes[ch.topic] || [Infinity, Infinity, Infinity, -Infinity, -Infinity, -Infinity];
      for (let o = 0; o + 12 <= data.length; o += value.point_stride)
        for (let a = 0; a < 3; a++) {
          const x = data.readFloatLE(o + 4 * a);
          box[a] = Math.min(box[a], x);
          box[a + 3] = Math.max(box[a + 3], x);
        }
    } else if (schemaName === 'foxglove.Grid') {
      framesUsed.add(value.frame_id);
      const data = Buffer.from(value.data, 'base64');
      const g = grids[ch.topic] = grids[ch.topic] || {};
      for (const f of value.fields) {
        if (f.type !== 7) continue;  // FLOAT32
        for (let o = f.offset; o + 4 <= data.length; o += value.cell_stride) {
          const x = data.readFloatLE(o);
          if (!Number.isFinite(x)) continue;
          g[f.name] = g[f.name] ? [Math.min(g[f.name][0], x), Math.max(g[f.name][1], x)] : [x, x];
        }
      }
    } else if (schemaName === 'foxglove.FrameTransforms') {
      for (const t of value.transforms || []) {
        if (parentOf[t.child_frame_id] !== undefined && parentOf[t.child_frame_id] !== t.parent_frame_id)
          errors.push('/tf: frame ' + t.child_frame_id + ' has two parents');
        parentOf[t.child_frame_id] = t.parent_frame_id;
        if (!tfAt.has(m.logTime)) tfAt.set(m.logTime, {});
        tfAt.get(m.logTime)[t.child_frame_id] = t;
        const q = t.rotation, n = Math.hypot(q.x, q.y, q.z, q.w);
        if (Math.abs(n - 1) > 1e-3) errors.push('/tf: rotation of ' + t.child_frame_id + ' is not a unit quaternion');
      }
    }
  }
  const robotSpheres = {};
  for (const [topic, { t, value }] of Object.entries(firstRobot)) {
    const transforms = tfAt.get(t) || {};
    robotSpheres[topic] = [];
    for (const e of value.entities)
      for (const sp of e.spheres) {
        const p = toMap(transforms, e.frame_id, sp.pose.position);
        if (p) robotSpheres[topic].push([p.x, p.y, p.z, sp.size.x]);
        else errors.push(topic + ': entity ' + e.id + ' in frame ' + e.frame_id + ' has no /tf at its time');
      }
  }
  for (const f of framesUsed)
    if (f !== 'map' && parentOf[f] === undefined) errors.push('frame ' + f + ' is used but /tf never defines it');
  for (const f of Object.keys(parentOf)) {  // every frame reaches map without a cycle
    let g = f, steps = 0;
    while (g !== 'map' && parentOf[g] !== undefined && steps++ < 100) g = parentOf[g];
    if (g !== 'map') { errors.push('frame ' + f + ' does not reach map'); break; }
  }
  const stats = reader.statistics;
  if (!stats) errors.push('no statistics record');
  else {
    if (Number(stats.messageCount) !== messages)
      errors.push('statistics say ' + stats.messageCount + ' messages, read ' + messages);
    for (const [id, n] of stats.channelMessageCounts) {
      const topic = reader.channelsById.get(id).topic;
      if (Number(n) !== topics[topic]) errors.push(topic + ': statistics ' + n + ', read ' + topics[topic]);
    }
  }

  // 2. Streaming every record (validates the chunk, data-section and summary CRCs).
  const stream = new McapStreamReader({ validateCrcs: true, decompressHandlers });
  stream.append(bytes);
  let streamed = 0, footer = false, compression = new Set();
  for (let r; (r = stream.nextRecord()); ) {
    if (r.type === 'Message') streamed++;
    if (r.type === 'Footer') footer = true;
    if (r.type === 'ChunkIndex') compression.add(r.compression || 'none');
  }
  if (!stream.done()) errors.push('the stream reader did not reach the end magic');
  if (!footer) errors.push('no footer');
  if (streamed !== messages) errors.push('streamed ' + streamed + ' messages, indexed ' + messages);

  if (expected)
    for (const [topic, n] of Object.entries(expected))
      if (topics[topic] !== n) errors.push(topic + ': ' + topics[topic] + ' messages, expected ' + n);
  console.log(JSON.stringify({
    ok: errors.length === 0, errors, topics, messages,
    chunks: reader.chunkIndexes.length, compression: [...compression],
    largest, cubes, triangles, points, frames: Object.keys(parentOf).sort(), schemas, numbers, logs, grids, point_boxes: pointBoxes, robot_spheres: robotSpheres,
    start_ns: stats ? String(stats.messageStartTime) : null, end_ns: stats ? String(stats.messageEndTime) : null,
    statistics: stats ? { messageCount: Number(stats.messageCount), channelCount: stats.channelCount } : null,
  }));
  process.exit(errors.length === 0 ? 0 : 1);
}
main().catch((e) => { console.log(JSON.stringify({ ok: false, errors: [String(e.stack || e)] })); process.exit(1); });
