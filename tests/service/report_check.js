#!/usr/bin/env node
// Opens a terrastride HTML report in headless Chromium through the DevTools protocol (over
// --remote-debugging-pipe, no extra packages) and checks it the way a person would see it:
//   - no console error, no uncaught exception, no browser log error;
//   - no network request at all (only the report file itself is loaded);
//   - every chart drew data (the page's own self-check, cross-checked here on the Plotly divs);
//   - which problems the summary flags (printed so tests can compare them with report.json).
// Optionally saves a screenshot of each view (elements with data-shot="NAME") into a folder.
//
// usage: node report_check.js REPORT.html [--screenshots DIR] [--chromium PATH] [--timeout S]
// Prints one JSON object on stdout; exit code 0 when the report passed, 1 when it failed,
// 2 on a usage or start-up error.
'use strict';
const { spawn } = require('child_process');
const fs = require('fs');
const os = require('os');
const path = require('path');
const { pathToFileURL } = require('url');

function usage(message) {
  process.stderr.write(`report_check: ${message}\n` +
    'usage: node report_check.js REPORT.html [--screenshots DIR] [--chromium PATH] [--timeout S] [--allow-no-charts]\n');
  process.exit(2);
}

const args = process.argv.slice(2);
let reportPath = null;
let shotDir = null;
let chromium = process.env.CHROMIUM || 'chromium';
let timeoutS = 90;
for (let i = 0; i < args.length; ++i) {
  const a = args[i];
  if (a === '--screenshots') shotDir = args[++i];
  else if (a === '--chromium') chromium = args[++i];
  else if (a === '--timeout') timeoutS = Number(args[++i]);
  else if (a === '--allow-no-charts') continue;
  else if (a.startsWith('--')) usage(`unknown option '${a}'`);
  else if (reportPath === null) reportPath = a;
  else usage(`unexpected argument '${a}'`);
}
if (!reportPath) usage('no report given');
if (!fs.existsSync(reportPath)) usage(`${reportPath}: no such file`);
if (!(timeoutS > 0)) usage('--timeout must be a positive number of seconds');
const reportUrl = pathToFileURL(path.resolve(reportPath)).href;

const profile = fs.mkdtempSync(path.join(os.tmpdir(), 'terrastride-report-check-'));
const browser = spawn(chromium, [
  '--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
  '--disable-background-networking', '--disable-component-update', '--disable-sync',
  '--disable-default-apps', '--disable-extensions', '--mute-audio', '--hide-scrollbars',
  // WebGL (the 3-D view) on the CPU: Chromium only falls back to SwiftShader when told to.
  '--use-angle=swiftshader', '--enable-unsafe-swiftshader',
  `--user-data-dir=${profile}`, '--remote-debugging-pipe', 'about:blank',
], { stdio: ['ignore', 'ignore', 'pipe', 'pipe', 'pipe'] });

let browserStderr = '';
browser.stderr.on('data', (d) => { browserStderr = (browserStderr + d).slice(-4000); });

const result = {
  report: path.resolve(reportPath),
  ok: false,
  console_errors: [],
  exceptions: [],
  log_errors: [],
  network_requests: [],
  charts: [],
  self_check: null,
  flags: [],
  screenshots: [],
  failures: [],
};

let finished = false;
function finish(code) {
  if (finished) return;
  finished = true;
  process.stdout.write(JSON.stringify(result, null, 1) + '\n');
  // Remove the throw-away profile once Chromium has really gone (it writes into it until then).
  const cleanup = () => {
    // Chromium's helper processes may still be writing for a moment: retry a few times.
    for (let i = 0; i < 20; ++i) {
      try { fs.rmSync(profile, { recursive: true, force: true }); } catch (e) { /* retry */ }
      if (!fs.existsSync(profile)) break;
      Atomics.wait(new Int32Array(new SharedArrayBuffer(4)), 0, 0, 100);
    }
    process.exit(code);
  };
  if (browser.exitCode !== null || browser.signalCode !== null) return cleanup();
  browser.once('exit', cleanup);
  setTimeout(cleanup, 3000).unref();
  try { browser.kill('SIGKILL'); } catch (e) { cleanup(); }
}
browser.on('error', (e) => { result.failures.push(`cannot start ${chromium}: ${e.message}`); finish(2); });
browser.on('exit', (code, signal) => {
  if (!finished) {
    result.failures.push(`chromium exited early (code ${code}, signal ${signal}): ${browserStderr}`);
    finish(2);
  }
});
const timer = setTimeout(() => {
  result.failures.push(`timed out after ${timeoutS} s`);
  finish(1);
}, timeoutS * 1000);
timer.unref();

// ---- DevTools protocol over the pipe: NUL-terminated JSON messages on fds 3 (in) and 4 (out) ----
const toBrowser = browser.stdio[3];
const fromBrowser = browser.stdio[4];
let nextId = 1;
const pending = new Map();
const listeners = [];
let buffer = '';
fromBrowser.on('data', (chunk) => {
  buffer += chunk.toString('utf8');
  let end;
  while ((end = buffer.indexOf('\0')) >= 0) {
    const text = buffer.slice(0, end);
    buffer = buffer.slice(end + 1);
    let msg;
    try { msg = JSON.parse(text); } catch (e) { continue; }
    if (msg.id !== undefined && pending.has(msg.id)) {
      const { resolve, reject, method } = pending.get(msg.id);
      pending.delete(msg.id);
      if (msg.error) reject(new Error(`${method}: ${msg.error.message}`));
      else resolve(msg.result);
    } else if (msg.method) {
      for (const l of listeners) l(msg);
    }
  }
});
function send(method, params = {}, sessionId = undefined) {
  const id = nextId++;
  const msg = { id, method, params };
  if (sessionId) msg.sessionId = sessionId;
  return new Promise((resolve, reject) => {
    pending.set(id, { resolve, reject, method });
    toBrowser.write(JSON.stringify(msg) + '\0');
  });
}
function waitFor(method, sessionId) {
  return new Promise((resolve) => {
    const l = (msg) => {
      if (msg.method === method && msg.sessionId === sessionId) {
        listeners.splice(listeners.indexOf(l), 1);
        resolve(msg.params);
      }
    };
    listeners.push(l);
  });
}
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

function remoteText(args) {
  return (args || []).map((a) => (a.value !== undefined ? String(a.value) : a.description || a.type))
    .join(' ');
}

async function main() {
  const { targetId } = await send('Target.createTarget', { url: 'about:blank' });
  const { sessionId } = await send('Target.attachToTarget', { targetId, flatten: true });
  listeners.push((msg) => {
    if (msg.sessionId !== sessionId) return;
    const p = msg.params;
    if (msg.method === 'Runtime.consoleAPICalled' && (p.type === 'error' || p.type === 'assert')) {
      result.console_errors.push(remoteText(p.args));
    } else if (msg.method === 'Runtime.exceptionThrown') {
      const d = p.exceptionDetails;
      result.exceptions.push((d.exception && d.exception.description) || d.text);
    } else if (msg.method === 'Log.entryAdded' && p.entry.level === 'error') {
      result.log_errors.push(`${p.entry.source}: ${p.entry.text}${p.entry.url ? ' ' + p.entry.url : ''}`);
      // A load the page's Content-Security-Policy refused is a network request all the same.
      const m = /Refused to (?:load|connect to|frame) '([^']+)'/.exec(p.entry.text);
      if (m) result.network_requests.push(`${m[1]} (blocked by the page's CSP)`);
    } else if (msg.method === 'Network.requestWillBeSent') {
      const url = p.request.url;
      if (url !== reportUrl && !url.startsWith('data:') && !url.startsWith('blob:') &&
          url !== 'about:blank') {
        result.network_requests.push(url);
      }
    }
  });
  await send('Runtime.enable', {}, sessionId);
  await send('Log.enable', {}, sessionId);
  await send('Network.enable', {}, sessionId);
  await send('Page.enable', {}, sessionId);
  await send('Emulation.setDeviceMetricsOverride',
    { width: 1400, height: 1000, deviceScaleFactor: 1, mobile: false }, sessionId);
  const loaded = waitFor('Page.loadEventFired', sessionId);
  const nav = await send('Page.navigate', { url: reportUrl }, sessionId);
  if (nav.errorText) throw new Error(`cannot open ${reportUrl}: ${nav.errorText}`);
  await loaded;

  // Pages without charts (the batch index) have nothing to draw.
  const allowNoCharts = process.argv.includes('--allow-no-charts');
  // The page sets window.__reportSelfCheck once every chart has been drawn.
  let selfCheck = null;
  for (;;) {
    const r = await send('Runtime.evaluate',
      { expression: 'JSON.stringify(window.__reportSelfCheck || null)', returnByValue: true },
      sessionId);
    selfCheck = JSON.parse(r.result.value);
    if (selfCheck) break;
    await sleep(200);
  }
  result.self_check = selfCheck;

  // Cross-check every chart independently of the page's own code: the Plotly div holds traces
  // with points, and its drawing surface exists (an SVG for 2-D plots, a canvas for 3-D ones).
  const probe = `JSON.stringify(Array.from(document.querySelectorAll('.chart')).map(function (el) {
      var traces = (el.data || []);
      var points = 0;
      traces.forEach(function (t) {
        ['x', 'y', 'z'].forEach(function (k) { if (t[k] && t[k].length > points) points = t[k].length; });
      });
      var rect = el.getBoundingClientRect();
      return { id: el.id, traces: traces.length, points: points,
               svg: !!el.querySelector('svg.main-svg'), canvas: !!el.querySelector('canvas'),
               is3d: el.classList.contains('chart-3d'), width: rect.width, height: rect.height,
               glError: !!el.querySelector('.no-webgl') };
    }))`;
  const charts = JSON.parse((await send('Runtime.evaluate',
    { expression: probe, returnByValue: true }, sessionId)).result.value);
  result.charts = charts;
  if (charts.length === 0 && !allowNoCharts) result.failures.push('the report has no chart at all');
  for (const c of charts) {
    if (c.traces === 0 || c.points === 0) result.failures.push(`chart ${c.id} has no data`);
    if (!c.svg) result.failures.push(`chart ${c.id} was not drawn`);
    if (c.is3d && (!c.canvas || c.glError)) result.failures.push(`3-D chart ${c.id} has no WebGL canvas`);
    if (c.width < 50 || c.height < 50) result.failures.push(`chart ${c.id} is not visible`);
  }
  // The base path must show on the height map: along the path, the terrain colour under each
  // point (the heatmap's colour scale at that cell's height) against the path's line colour or its
  // edge, whichever stands out more; the worst WCAG contrast ratio over the path must reach 3:1
  // (the guideline for graphical objects). A white path on the white top of a pallet has 1:1.
  const contrastProbe = `(function () {
      var el = document.getElementById('chart-heightmap');
      if (!el || !el._fullData) return JSON.stringify(null);
      function rgb(c) {
        if (!c) return null;
        c = String(c).trim();
        var m = c.match(/^#([0-9a-f]{2})([0-9a-f]{2})([0-9a-f]{2})$/i);
        if (m) return [parseInt(m[1], 16), parseInt(m[2], 16), parseInt(m[3], 16)];
        m = c.match(/^rgba?\\(([^,]+),([^,]+),([^,)]+)/i);
        if (m) return [parseFloat(m[1]), parseFloat(m[2]), parseFloat(m[3])];
        return null;
      }
      function lum(c) {
        var v = c.map(function (x) { x /= 255; return x <= 0.03928 ? x / 12.92 : Math.pow((x + 0.055) / 1.055, 2.4); });
        return 0.2126 * v[0] + 0.7152 * v[1] + 0.0722 * v[2];
      }
      function contrast(a, b) { var la = lum(a), lb = lum(b); return (Math.max(la, lb) + 0.05) / (Math.min(la, lb) + 0.05); }
      var heat = el._fullData[0];
      var scale = heat.colorscale.map(function (s) { return [s[0], rgb(s[1])]; });
      function colourAt(z) {
        var f = (z - heat.zmin) / ((heat.zmax - heat.zmin) || 1);
        f = Math.max(0, Math.min(1, f));
        for (var i = 1; i < scale.length; ++i) {
          if (f <= scale[i][0]) {
            var t = (f - scale[i - 1][0]) / ((scale[i][0] - scale[i - 1][0]) || 1);
            return scale[i - 1][1].map(function (a, k) { return a + t * (scale[i][1][k] - a); });
          }
        }
        return scale[scale.length - 1][1];
      }
      function nearest(arr, v) {
        var best = 0;
        for (var i = 1; i < arr.length; ++i) if (Math.abs(arr[i] - v) < Math.abs(arr[best] - v)) best = i;
        return best;
      }
      var paths = [];
      el._fullData.forEach(function (t) {
        if (!/ base path$/.test(t.name || '')) return;
        var edge = el._fullData.filter(function (e) { return e.name === t.name + ' edge'; })[0];
        var colours = [rgb(t.line.color)].concat(edge ? [rgb(edge.line.color)] : []);
        var worst = Infinity, at = null;
        for (var k = 0; k < t.x.length; ++k) {
          var z = heat.z[nearest(heat.y, t.y[k])][nearest(heat.x, t.x[k])];
          if (z === null || z === undefined) continue;
          var ground = colourAt(z);
          var c = Math.max.apply(null, colours.map(function (col) { return contrast(col, ground); }));
          if (c < worst) { worst = c; at = [t.x[k], t.y[k], z]; }
        }
        paths.push({ name: t.name, line: t.line.color, edge: edge ? edge.line.color : null,
                     min_contrast: worst, at: at });
      });
      return JSON.stringify(paths);
    })()`;
  const basePaths = JSON.parse((await send('Runtime.evaluate',
    { expression: contrastProbe, returnByValue: true }, sessionId)).result.value);
  result.base_paths = basePaths;
  for (const bp of basePaths || []) {
    if (!(bp.min_contrast >= 3))
      result.failures.push(`${bp.name} does not show on the height map: contrast ${bp.min_contrast.toFixed(2)}:1 ` +
                           `with the terrain at ${JSON.stringify(bp.at)} (line ${bp.line}, edge ${bp.edge})`);
  }
  if (!selfCheck.ok) result.failures.push(`the page's self-check failed: ${JSON.stringify(selfCheck.errors)}`);
  result.flags = selfCheck.flags || [];

  if (shotDir) {
    fs.mkdirSync(shotDir, { recursive: true });
    const shots = JSON.parse((await send('Runtime.evaluate', {
      expression: `JSON.stringify(Array.from(document.querySelectorAll('[data-shot]')).map(function (el) {
          var r = el.getBoundingClientRect();
          return { name: el.getAttribute('data-shot'), x: r.left + window.scrollX,
                   y: r.top + window.scrollY, width: r.width, height: r.height };
        }))`, returnByValue: true }, sessionId)).result.value);
    for (const s of shots) {
      const shot = await send('Page.captureScreenshot', {
        format: 'png', captureBeyondViewport: true,
        clip: { x: s.x, y: s.y, width: s.width, height: s.height, scale: 1 } }, sessionId);
      const file = path.join(shotDir, `${s.name}.png`);
      fs.writeFileSync(file, Buffer.from(shot.data, 'base64'));
      result.screenshots.push(file);
    }
  }
  // Late errors (a chart that throws after its first draw) still count.
  await sleep(300);
  for (const e of result.console_errors) result.failures.push(`console error: ${e}`);
  for (const e of result.exceptions) result.failures.push(`uncaught exception: ${e}`);
  for (const e of result.log_errors) result.failures.push(`browser log error: ${e}`);
  for (const u of result.network_requests) result.failures.push(`network request: ${u}`);
  result.ok = result.failures.length === 0;
  finish(result.ok ? 0 : 1);
}

main().catch((e) => { result.failures.push(String(e && e.stack || e)); finish(1); });
