// The viewer page: an orbit camera around the scene's centre, renders asked from the server
// (low resolution while the camera moves, full resolution when it stops; the newest request
// wins), a dataset view beside its exact ground truth and error, the training curves, and
// keyframes exported as nerfstudio's camera_path.json. No libraries, no build step.
'use strict';

const $ = (id) => document.getElementById(id);
const client = Math.random().toString(36).slice(2, 10);
const S = {
  center: [0, 0, 0], radius: 1, target: [0, 0, 0], dist: 3, yaw: 0, pitch: 0.3, fov: 50,
  exact: null, views: [], home: null, step: null, keys: [], mode: 'rgb', res: 256,
};
let seq = 0, inflight = null, dirty = false, idleTimer = null;

// --- vectors and the camera ---------------------------------------------------------------
const sub = (a, b) => a.map((v, i) => v - b[i]);
const add = (a, b) => a.map((v, i) => v + b[i]);
const mul = (a, s) => a.map((v) => v * s);
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const unit = (a) => mul(a, 1 / Math.max(Math.hypot(...a), 1e-12));

function back() { // unit vector from the target to the eye
  const c = Math.cos(S.pitch);
  return [c * Math.sin(S.yaw), Math.sin(S.pitch), c * Math.cos(S.yaw)];
}
function basis() {
  const b = back();
  let r = cross([0, 1, 0], b);
  if (Math.hypot(...r) < 1e-9) r = [1, 0, 0];
  r = unit(r);
  return { r, u: cross(b, r), b, e: add(S.target, mul(b, S.dist)) };
}
// The camera-to-world matrix, 16 numbers row by row (OpenGL frame: the camera looks down -Z).
function c2w() {
  if (S.exact) return S.exact;
  const { r, u, b, e } = basis();
  return [r[0], u[0], b[0], e[0], r[1], u[1], b[1], e[1], r[2], u[2], b[2], e[2], 0, 0, 0, 1];
}
// Orbit parameters from a pose: the eye stays, the target is the point nearest the scene's
// centre along the viewing direction.
function fromPose(m) {
  const e = [m[3], m[7], m[11]], b = unit([m[2], m[6], m[10]]);
  S.dist = Math.max(dot(sub(e, S.center), b), 0.05 * S.radius);
  S.target = sub(e, mul(b, S.dist));
  S.pitch = Math.asin(Math.max(-1, Math.min(1, b[1])));
  S.yaw = Math.atan2(b[0], b[2]);
}

// --- rendering ------------------------------------------------------------------------------
function size(full) {
  const c = $('view');
  const aspect = Math.max(c.clientWidth, 1) / Math.max(c.clientHeight, 1);
  const h = full ? S.res : Math.max(32, Math.round(S.res / 4));
  return [Math.max(1, Math.round(h * aspect)), h];
}
function renderUrl(w, h, m, fov, mode, ordered) {
  let u = `/api/render?w=${w}&h=${h}&fov=${fov}&c2w=${m.map((v) => +v.toPrecision(12)).join(',')}&mode=${mode}`;
  if (ordered) u += `&client=${client}&seq=${++seq}`;
  return u;
}
function send(full) {
  const [w, h] = size(full);
  const ctrl = new AbortController();
  const url = renderUrl(w, h, c2w(), S.fov, S.mode, true);
  const me = { ctrl, full, seq };
  inflight = me;
  const t0 = performance.now();
  fetch(url, { signal: ctrl.signal })
    .then(async (r) => {
      if (r.status === 409) return;
      if (!r.ok) { $('overlay').textContent = (await r.text()).trim(); return; }
      const bmp = await createImageBitmap(await r.blob());
      if (me.seq !== seq) return; // a newer frame was asked for meanwhile
      draw(bmp);
      // for tests and scripts: frames drawn, whether the last was full size, its step
      const d = document.body.dataset;
      d.frames = (+d.frames || 0) + 1; d.full = full; d.step = r.headers.get('X-Step');
      $('overlay').textContent = '';
      $('info').textContent = `${w}×${h} ${full ? 'full' : 'preview'} · render ${r.headers.get('X-Render-Ms')} ms · frame ${(performance.now() - t0).toFixed(0)} ms · step ${r.headers.get('X-Step')}`;
    })
    .catch((e) => { if (e.name !== 'AbortError') $('overlay').textContent = String(e); })
    .finally(() => {
      if (inflight === me) inflight = null;
      if (dirty) { dirty = false; send(false); }
    });
}
// Latest request wins: a full frame is aborted by any newer request; previews are coalesced
// (one in flight, the newest camera sent when it returns).
function update(full) {
  if (inflight) {
    if (inflight.full || full) { inflight.ctrl.abort(); inflight = null; dirty = false; } else { dirty = true; return; }
  }
  send(full);
}
function moved() {
  update(false);
  clearTimeout(idleTimer);
  idleTimer = setTimeout(() => update(true), 250);
}
function draw(bmp) {
  const c = $('view');
  c.width = c.clientWidth; c.height = c.clientHeight;
  const g = c.getContext('2d');
  g.imageSmoothingEnabled = true;
  g.drawImage(bmp, 0, 0, c.width, c.height);
}

// --- mouse and touch --------------------------------------------------------------------------
const pointers = new Map();
function orbit(dx, dy) {
  S.yaw -= dx * 0.008;
  S.pitch = Math.max(-1.55, Math.min(1.55, S.pitch + dy * 0.008));
}
function pan(dx, dy) {
  const { r, u } = basis();
  const k = S.dist * 2 * Math.tan((S.fov * Math.PI) / 360) / $('view').clientHeight;
  S.target = add(S.target, add(mul(r, -dx * k), mul(u, dy * k)));
}
function zoom(f) { S.dist = Math.max(1e-3 * S.radius, Math.min(100 * S.radius, S.dist * f)); }
function setupInput() {
  const c = $('view');
  c.addEventListener('contextmenu', (e) => e.preventDefault());
  c.addEventListener('pointerdown', (e) => {
    c.setPointerCapture(e.pointerId);
    pointers.set(e.pointerId, { x: e.clientX, y: e.clientY, pan: e.button === 2 || e.shiftKey });
  });
  const up = (e) => pointers.delete(e.pointerId);
  c.addEventListener('pointerup', up);
  c.addEventListener('pointercancel', up);
  c.addEventListener('pointermove', (e) => {
    const p = pointers.get(e.pointerId);
    if (!p) return;
    if (S.exact) { fromPose(S.exact); S.exact = null; }
    if (pointers.size === 2) {
      const [a, b] = [...pointers.values()];
      const before = Math.hypot(a.x - b.x, a.y - b.y);
      const mid0 = [(a.x + b.x) / 2, (a.y + b.y) / 2];
      p.x = e.clientX; p.y = e.clientY;
      const after = Math.hypot(a.x - b.x, a.y - b.y);
      if (after > 0) zoom(before / after);
      pan((a.x + b.x) / 2 - mid0[0], (a.y + b.y) / 2 - mid0[1]);
    } else {
      const dx = e.clientX - p.x, dy = e.clientY - p.y;
      p.x = e.clientX; p.y = e.clientY;
      if (p.pan) pan(dx, dy); else orbit(dx, dy);
    }
    moved();
  });
  c.addEventListener('wheel', (e) => {
    e.preventDefault();
    if (S.exact) { fromPose(S.exact); S.exact = null; }
    zoom(Math.exp(e.deltaY * 0.001));
    moved();
  }, { passive: false });
  window.addEventListener('resize', moved);
}

// --- dataset views and the comparison ----------------------------------------------------------
async function blobUrl(url) {
  const r = await fetch(url);
  if (!r.ok) throw new Error((await r.text()).trim());
  return [URL.createObjectURL(await r.blob()), r.headers];
}
function snap() {
  const v = S.views[+$('views').value];
  if (!v) return;
  S.exact = v.c2w; S.fov = v.fov; S.compared = +$('views').value;
  update(true);
  compare();
}
// The chosen view's NeRF, ground truth and error, side by side (again when a newer checkpoint
// is loaded, without moving the camera).
async function compare() {
  const k = S.compared, v = S.views[k];
  if (!v) return;
  $('compare').hidden = false;
  const depth = S.mode === 'depth';
  try {
    const [nerf] = await blobUrl(renderUrl(v.width, v.height, v.c2w, v.fov, depth ? 'depth' : 'rgb', false));
    const [gt] = await blobUrl(`/api/gt?view=${k}&kind=${depth ? 'depth' : 'rgb'}`);
    const [err, h] = await blobUrl(`/api/error?view=${k}`);
    $('cmp-nerf').src = nerf; $('cmp-gt').src = gt; $('cmp-err').src = err;
    $('cmp-err-cap').textContent = `colour error (PSNR ${h.get('X-PSNR')} dB, step ${h.get('X-Step')}; bright = 0.25 or more)`;
  } catch (e) { $('cmp-err-cap').textContent = String(e); }
}
async function loadViews() {
  const r = await fetch('/api/views');
  if (!r.ok) return false;
  const j = await r.json();
  S.center = j.center; S.radius = j.radius; S.views = j.views;
  $('views').innerHTML = j.views.map((v) => `<option value="${v.index}">${v.index}: ${v.split}/${v.name} (${v.width}×${v.height})</option>`).join('');
  const first = j.views[0];
  if (first) { S.fov = first.fov; S.home = first.c2w; fromPose(first.c2w); } else { S.target = S.center; }
  return true;
}

// --- status and curves -------------------------------------------------------------------------
async function poll() {
  try {
    const st = await (await fetch('/api/status')).json();
    $('run').textContent = st.run;
    $('status').textContent = st.message + (st.error && st.loaded ? ` (newest does not load: ${st.error})` : '');
    const step = st.loaded ? st.loaded.step : null;
    if (!S.views.length) await loadViews();
    if (step !== S.step) {
      S.step = step;
      update(true);
      if (!$('compare').hidden) compare();
    }
    if (step === null) $('overlay').textContent = st.message;
    drawCurves(await (await fetch('/api/metrics')).json());
  } catch (e) { $('status').textContent = 'server unreachable: ' + e; }
}
function drawCurves(m) {
  const c = $('curves'), g = c.getContext('2d');
  g.clearRect(0, 0, c.width, c.height);
  const loss = m.loss.map((p) => [p[0], Math.log10(Math.max(p[2], 1e-12))]);
  plot(g, 0, 0, c.width / 2, c.height, loss, 'training loss (log10) vs step', '#6cf');
  plot(g, c.width / 2, 0, c.width / 2, c.height, m.val_psnr.map((p) => [p[0], p[2]]), 'validation PSNR (dB) vs step', '#fc6');
}
function ticks(lo, hi, n) {
  const step = Math.pow(10, Math.floor(Math.log10((hi - lo) / n || 1)));
  const k = [1, 2, 5, 10].find((f) => (hi - lo) / (f * step) <= n) * step;
  const out = [];
  for (let v = Math.ceil(lo / k) * k; v <= hi + 1e-9; v += k) out.push(v);
  return out;
}
function plot(g, x0, y0, w, h, pts, title, colour) {
  const L = 50, R = 12, T = 22, B = 26;
  g.fillStyle = '#ccc'; g.font = '12px sans-serif';
  g.fillText(title, x0 + L, y0 + 14);
  if (!pts.length) { g.fillText('no points yet', x0 + L, y0 + h / 2); return; }
  let [xl, xh] = [Math.min(...pts.map((p) => p[0])), Math.max(...pts.map((p) => p[0]))];
  let [yl, yh] = [Math.min(...pts.map((p) => p[1])), Math.max(...pts.map((p) => p[1]))];
  if (xh <= xl) { xl -= 1; xh += 1; }
  if (yh - yl < 1e-6) { yl -= 0.5; yh += 0.5; }
  const px = (x) => x0 + L + ((x - xl) / (xh - xl)) * (w - L - R);
  const py = (y) => y0 + h - B - ((y - yl) / (yh - yl)) * (h - T - B);
  g.strokeStyle = '#555'; g.lineWidth = 1;
  g.strokeRect(x0 + L, y0 + T, w - L - R, h - T - B);
  g.fillStyle = '#999';
  for (const v of ticks(yl, yh, 4)) { g.fillText(+v.toPrecision(4) + '', x0 + 4, py(v) + 4); }
  for (const v of ticks(xl, xh, 4)) { g.fillText(+v.toPrecision(6) + '', px(v) - 10, y0 + h - 8); }
  g.strokeStyle = colour; g.lineWidth = 1.5;
  g.beginPath();
  pts.forEach((p, i) => (i ? g.lineTo(px(p[0]), py(p[1])) : g.moveTo(px(p[0]), py(p[1]))));
  g.stroke();
  if (pts.length === 1) { g.fillStyle = colour; g.fillRect(px(pts[0][0]) - 2, py(pts[0][1]) - 2, 4, 4); }
}

// --- keyframes and the camera-path export ---------------------------------------------------------
function showKeys() {
  $('keys').innerHTML = S.keys.map((k, i) => `<li>eye ${[k.c2w[3], k.c2w[7], k.c2w[11]].map((v) => v.toFixed(2)).join(', ')} fov ${k.fov.toFixed(1)}<button data-i="${i}">✕</button></li>`).join('');
  for (const b of $('keys').querySelectorAll('button')) b.onclick = () => { S.keys.splice(+b.dataset.i, 1); showKeys(); };
}
async function exportPath() {
  const v = S.views[0] || { width: 800, height: 800 };
  const body = {
    keyframes: S.keys, render_width: v.width, render_height: v.height,
    fps: +$('fps').value, seconds: +$('seconds').value, is_cycle: $('cycle').checked,
  };
  const r = await fetch('/api/camera_path', { method: 'POST', body: JSON.stringify(body) });
  const text = await r.text();
  if (!r.ok) { $('exportmsg').textContent = text.trim(); return; }
  const a = document.createElement('a');
  a.href = URL.createObjectURL(new Blob([text], { type: 'application/json' }));
  a.download = 'camera_path.json';
  a.click();
  $('exportmsg').textContent = `${JSON.parse(text).camera_path.length} frames at ${v.width}×${v.height}: render-nerf RUN --camera-path camera_path.json`;
}

// --- start ---------------------------------------------------------------------------------------
function start() {
  setupInput();
  $('mode').onchange = () => { S.mode = $('mode').value; update(true); };
  $('res').onchange = () => { S.res = +$('res').value; update(true); };
  $('reset').onclick = () => { S.exact = null; if (S.home) fromPose(S.home); update(true); };
  $('snap').onclick = snap;
  $('addkey').onclick = () => { S.keys.push({ c2w: c2w().slice(), fov: S.fov }); showKeys(); };
  $('export').onclick = exportPath;
  poll();
  setInterval(poll, 1500);
}
start();
