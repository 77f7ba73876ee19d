// The design page: tools, sliders and the WebSocket to the selfsupport design server.
// Every edit goes to the server at once; frames come back when the background solve ends,
// so the page never waits. window.ssDesign exposes the page's state and actions (for tests
// and the browser console).
import { airyLayout, airyTraces, networkLayout, networkTraces, reciprocalLayout, reciprocalTraces } from './view.js';

const $ = (id) => document.getElementById(id);
const ui = { tool: 'orbit', handles: [], cut: [], showHull: true };
const st = { frame: null, analysis: null, state: null, seq: 0, sentAt: new Map(), latency: [], errors: [],
  frames: 0, messages: [], drawn: 0, saved: [], dragging: false, lightDraws: 0 };
let ws = null, plotted = false;

// ------------------------------------------------------------------------- connection
function connect() {
  // the token leaves the address bar (history, screen shares, bookmarks); the page's cookie
  // carries the session from here on, for the WebSocket and for a reload
  if (new URLSearchParams(location.search).has('token')) history.replaceState(null, '', location.pathname);
  ws = new WebSocket(`ws://${location.host}/ws`);
  ws.onopen = () => { $('conn').textContent = 'connected'; };
  ws.onclose = () => { $('conn').textContent = 'disconnected (reload the page)'; };
  ws.onmessage = (ev) => receive(JSON.parse(ev.data));
}

function send(msg) {
  if (!ws || ws.readyState !== WebSocket.OPEN) { showError('not connected'); return false; }
  ws.send(JSON.stringify(msg));
  if (msg.type === 'drag_end' && st.dragging) { st.dragging = false; scheduleDraw('net'); }  // the full picture again
  return true;
}

function sendEdit(edit, drag = null) {
  if (send({ type: 'edit', edit, drag })) st.pending = performance.now();
  st.dragging = !!drag;
}

function receive(m) {
  st.messages.push(m.type);
  if (st.messages.length > 50) st.messages.shift();
  switch (m.type) {
    case 'state':
      st.state = m; st.seq = m.seq;
      if (st.pending !== undefined) { st.sentAt.set(m.seq, st.pending); st.pending = undefined; }
      $('undo').disabled = !m.can_undo; $('redo').disabled = !m.can_redo;
      break;
    case 'solving': setSolve(`solving #${m.seq}…`, true); break;
    case 'progress': $('iter').textContent = `it ${m.iteration}` + (m.error != null ? `, err ${m.error.toExponential(1)}` : ''); break;
    case 'cancelled': if (m.what === 'probe') $('probe').textContent = 'probe cancelled (the design changed)'; break;
    case 'frame': onFrame(m); break;
    case 'analysis': st.analysis = m; scheduleDraw('side'); break;
    case 'error':
      showError(`${m.what || ''}: ${m.message}`); st.errorSeq = m.seq;
      if (m.what === 'solve') setSolve(`#${m.seq} failed`, false);
      if (m.what === 'save' && m.exists && st.lastSave) confirmOverwrite(st.lastSave, m.exists);
      break;
    case 'probing': $('probe').textContent = `probing vertex ${m.vertex}…`; break;
    case 'probe_step': $('probe').textContent = `probe v${m.vertex}: ${Math.round(m.kg)} kg ${m.found ? 'stands' : 'no network'}`; break;
    case 'probe':
      st.probe = m;
      $('probe').textContent = m.kg == null ? `vertex ${m.vertex}: not even the self-weight is certified`
        : `vertex ${m.vertex}: max extra load ≈ ${Math.round(m.kg)} kg` + (m.upper_kg != null ? ` (fails at ${Math.round(m.upper_kg)})` : ' (cap reached)');
      break;
    case 'saved': st.saved.push(m); showError(''); $('solve').textContent = `saved ${m.paths.join(', ')}`; break;
  }
}

function onFrame(m) {
  // a cut, hole or subdivision renumbers the vertices: picks made before refer to others now
  if (st.frame && m.n_vertices !== st.frame.n_vertices) { ui.handles = []; ui.cut = []; }
  st.frame = m; st.frames++;
  if (st.errorSeq !== undefined && m.seq > st.errorSeq) { $('error').textContent = ''; st.errorSeq = undefined; }
  const t0 = st.sentAt.get(m.seq);
  if (t0 !== undefined) {
    st.latency.push(performance.now() - t0);
    if (st.latency.length > 500) st.latency.shift();
    for (const k of st.sentAt.keys()) if (k <= m.seq) st.sentAt.delete(k);
  }
  const stale = m.seq < st.seq ? ` (an edit #${st.seq} is on its way)` : '';
  setSolve(`#${m.seq} ${m.status}, ${m.iterations} it${m.warm ? ' (warm)' : ''}, ` +
    `max rel. error ${m.max_rel_error == null ? 'n/a' : m.max_rel_error.toExponential(1)}, ` +
    `${m.n_vertices} V${stale}`, m.seq < st.seq);
  $('iter').textContent = `solve ${(m.wall_time * 1000).toFixed(0)} ms`;
  if (st.latency.length) $('latency').textContent = `edit→frame ${st.latency[st.latency.length - 1].toFixed(0)} ms`;
  syncSliders(m.design);
  scheduleDraw('net');
}

// save: the server replaces only the files this session wrote; for any other existing file it
// answers with the names in `exists`, and the save is sent again naming them once the user agrees
function save(what) {
  st.lastSave = { type: 'save', what, path: $('save-name').value };
  send(st.lastSave);
}
function confirmOverwrite(msg, exists) {
  st.lastSave = null;
  if (window.confirm(`${exists.join(', ')} already exists in the working folder and was not written by this design session.\n\nReplace it?`)) {
    send({ ...msg, overwrite: exists });
  } else {
    showError(`not saved: ${exists.join(', ')} exists; give another name`);
  }
}

function setSolve(text, busy) { const s = $('solve'); s.textContent = text; s.classList.toggle('busy', !!busy); }
function showError(text) { $('error').textContent = text; if (text) st.errors.push(text); }

// ---------------------------------------------------------------------------- drawing
// Drawing is coalesced into animation frames: a frame that arrives while an older one waits to be
// drawn replaces it, so a slow display never queues up stale pictures. The analysis panels are
// drawn when the edits pause (no edit waiting for its frame for SIDE_DELAY ms): while dragging,
// the page's time goes to the network view (the panels took 0.2-0.5 s a draw in headless Chromium).
const SIDE_DELAY = 250;
// (WebGL at one pixel per CSS pixel: plotly's default of 2 quadruples the fill cost of every
// frame, 1.3-1.5x the frame time measured in headless Chromium)
const PLOT_CONFIG = { displaylogo: false, responsive: true, plotGlPixelRatio: 1 };
const dirty = { net: false, side: false };
let drawScheduled = false, sideTimer = null;
const editInFlight = () => st.pending !== undefined || (st.state && st.frame && st.frame.seq < st.state.seq);
function scheduleDraw(what) {
  if (what === 'side') {  // (an analysis of an older frame than the one shown is never drawn: see draw)
    clearTimeout(sideTimer);
    sideTimer = setTimeout(function fire() {
      if (editInFlight()) { sideTimer = setTimeout(fire, SIDE_DELAY); return; }
      sideTimer = null; dirty.side = true; requestDraw();
    }, SIDE_DELAY);
    return;
  }
  dirty[what] = true;
  requestDraw();
}
function requestDraw() {
  if (!drawScheduled) { drawScheduled = true; requestAnimationFrame(draw); }
}

function draw() {
  drawScheduled = false;
  const f = st.frame;
  if (!f) return;
  const a = st.analysis && st.analysis.seq === f.seq ? st.analysis : null;
  const t0 = performance.now();
  if (dirty.net) {
    // while a drag goes on, the light picture: the network's edges, supports and handles only. The
    // transparent reference and hull band and the vertex markers cost most of a software-rendered
    // (SwiftShader) frame; they come back with the frame after the drag ends
    const light = !!st.dragging;
    const title = `thrust network: ${f.n_vertices} vertices, ${f.n_edges} edges` + (light ? ' (dragging: edges only)' : '');
    Plotly.react('net', networkTraces(f, ui, { light }), networkLayout(title), PLOT_CONFIG);
    st.drawnLight = light;
    if (light) st.lightDraws++;
    dirty.net = false;
  }
  const t1 = performance.now();
  if (dirty.side && a) {
    // (no mode bars on the small panels: they would cover the panel titles)
    Plotly.react('airy', airyTraces(f, a), airyLayout(a.airy_error && `Airy surface: ${a.airy_error}`), { displayModeBar: false, responsive: true });
    Plotly.react('recip', reciprocalTraces(a), reciprocalLayout(), { displayModeBar: false, responsive: true });
    dirty.side = false;
  }
  st.drawMs = { net: t1 - t0, side: performance.now() - t1 };
  if (!plotted) {
    plotted = true;
    // a click (press and release within a few pixels) picks the vertex nearest the pointer
    const net = $('net');
    net.addEventListener('pointerdown', (ev) => { press = { x: ev.clientX, y: ev.clientY, t: performance.now() }; }, true);
    net.addEventListener('pointerup', (ev) => {
      if (press && Math.hypot(ev.clientX - press.x, ev.clientY - press.y) < 6 && performance.now() - press.t < 800) {
        const i = nearestVertex(ev.clientX, ev.clientY);
        if (i >= 0) pick(i);
      }
      press = null;
    }, true);
  }
  st.drawn = f.seq;
}

// ------------------------------------------------------------------------------ tools
let press = null;
const PICK_TOOLS = new Set(['pin', 'handle', 'pillar', 'cut', 'probe']);

/** Screen position (client pixels) and depth of vertex i, from plotly's own camera: its model,
 *  view and projection matrices applied to the scene's scaled coordinates (plotly's 3D picking
 *  reads a pick buffer in which the thick force lines hide the vertex markers; this does not). */
function screenOf(i) {
  const f = st.frame, sc = $('net')._fullLayout.scene._scene;
  const cp = sc.glplot.cameraParams, ds = sc.dataScale, r = sc.container.getBoundingClientRect();
  const mul = (m, v) => [0, 1, 2, 3].map((k) => m[k] * v[0] + m[4 + k] * v[1] + m[8 + k] * v[2] + m[12 + k] * v[3]);
  const v = mul(cp.projection, mul(cp.view, mul(cp.model,
    [f.vertices[3 * i] * ds[0], f.vertices[3 * i + 1] * ds[1], f.vertices[3 * i + 2] * ds[2], 1])));
  return [r.left + (v[0] / v[3] + 1) / 2 * r.width, r.top + (1 - v[1] / v[3]) / 2 * r.height, v[2] / v[3]];
}

/** The vertex drawn within 10 px of (x, y), the front one where several are; -1: none. */
function nearestVertex(x, y) {
  if (!st.frame || !PICK_TOOLS.has(ui.tool)) return -1;
  let best = -1, bestKey = Infinity;
  for (let i = 0; i < st.frame.n_vertices; i++) {
    const [sx, sy, depth] = screenOf(i), d = Math.hypot(sx - x, sy - y);
    if (d < 10 && depth + d * 1e-3 < bestKey) { best = i; bestKey = depth + d * 1e-3; }
  }
  return best;
}

/** What a click on vertex i does with the current tool. */
function pick(i) {
  const f = st.frame;
  if (!f) return;
  const sel = { vertices: [i] };
  switch (ui.tool) {
    case 'pin': sendEdit({ op: f.supports.includes(i) ? 'unpin' : 'pin', select: sel }); break;
    case 'handle': {
      const k = ui.handles.indexOf(i);
      if (k >= 0) ui.handles.splice(k, 1); else ui.handles.push(i);
      scheduleDraw('net'); break;
    }
    case 'pillar': sendEdit({ op: 'pillar', select: sel, roi_rings: Number($('rings').value) }); break;
    case 'cut': ui.cut.push(i); scheduleDraw('net'); break;
    case 'probe': send({ type: 'probe', vertex: i }); break;
  }
}

function setTool(t) {
  ui.tool = t;
  document.querySelector(`input[name=tool][value=${t}]`).checked = true;
  $('dragpad').hidden = t !== 'drag';
}

// a drag on the pad moves the handles in the view's screen plane (height only: vertically;
// top view only: on the ground plane), by the bounding box's diagonal per the view's smaller side
function dragOffset(dx, dy) {
  const f = st.frame, R = f.reference.vertices;
  let lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
  for (let k = 0; k < R.length; k++) { lo[k % 3] = Math.min(lo[k % 3], R[k]); hi[k % 3] = Math.max(hi[k % 3], R[k]); }
  const diag = Math.hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]);
  const box = $('net').getBoundingClientRect();
  const s = diag / Math.min(box.width, box.height);
  const mode = $('mode').value;
  if (mode === 'height') return [0, 0, -dy * s];
  const gd = $('net'), eye = (gd._fullLayout && gd._fullLayout.scene.camera.eye) || { x: 1, y: -1, z: 1 };
  const d = norm([-eye.x, -eye.y, -eye.z]), right = norm(cross(d, [0, 0, 1])), up = cross(right, d);
  if (mode === 'top_view') {
    const fw = norm([d[0], d[1], 0]);
    return [s * (dx * right[0] - dy * fw[0]), s * (dx * right[1] - dy * fw[1]), 0];
  }
  return [0, 1, 2].map((k) => s * (dx * right[k] - dy * up[k]));
}
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const norm = (v) => { const n = Math.hypot(...v) || 1; return v.map((x) => x / n); };

function moveEdit(offset) {
  return { op: 'move', select: { vertices: [...ui.handles] }, offset, mode: $('mode').value, roi_rings: Number($('rings').value) };
}

let drag = null;
function dragStart(ev) {
  if (!ui.handles.length) { showError('drag: pick handle vertices first (tool "pick handles")'); return; }
  drag = { id: `d${Date.now()}${Math.random().toString(36).slice(2, 6)}`, x: ev.clientX, y: ev.clientY, last: 0, moved: false };
  $('dragpad').setPointerCapture(ev.pointerId);
}
function dragMove(ev, final = false) {
  if (!drag) return;
  const now = performance.now();
  if (!final && now - drag.last < 50) return; // the server coalesces solves; 20 steps a second are plenty
  const dx = ev.clientX - drag.x, dy = ev.clientY - drag.y;
  if (!dx && !dy) return;
  drag.last = now; drag.moved = true;
  sendEdit(moveEdit(dragOffset(dx, dy)), drag.id);
}
function dragEnd(ev) {
  if (!drag) return;
  dragMove(ev, true);
  if (drag.moved) send({ type: 'drag_end' });
  drag = null;
}

// ---------------------------------------------------------------------------- sliders
const SLIDERS = {
  density: { get: (d) => d.density, edit: (v) => ({ op: 'material', density: v }), fmt: (v) => v.toFixed(0) },
  thickness: { get: (d) => d.thickness, edit: (v) => ({ op: 'material', thickness: v }), fmt: (v) => v.toFixed(2) },
  // w_max on a log scale: 0 is "no bound", else 10^v N/m
  w_max: { get: (d) => (d.w_max ? Math.log10(d.w_max) : 0), edit: (v) => ({ op: 'material', w_max: v <= 0 ? 0 : 10 ** v }),
    fmt: (v) => (v <= 0 ? 'none' : (10 ** v).toPrecision(2)) },
  planarity: { get: (d) => d.objective.planarity || 0, edit: (v) => ({ op: 'objective', weights: { planarity: v } }), fmt: (v) => v.toFixed(1) },
  fairness: { get: (d) => d.objective.fairness || 0, edit: (v) => ({ op: 'objective', weights: { fairness: v } }), fmt: (v) => v.toFixed(1) },
};
function syncSliders(d) {
  for (const [id, s] of Object.entries(SLIDERS)) {
    const el = $(id);
    if (document.activeElement !== el) el.value = s.get(d);
    el.nextElementSibling.textContent = s.fmt(Number(el.value));
  }
}

// ------------------------------------------------------------------------------- wiring
function wire() {
  document.querySelectorAll('input[name=tool]').forEach((r) => r.addEventListener('change', () => setTool(r.value)));
  $('undo').onclick = () => send({ type: 'undo' });
  $('redo').onclick = () => send({ type: 'redo' });
  $('clear-handles').onclick = () => { ui.handles = []; scheduleDraw('net'); };
  $('clear-cut').onclick = () => { ui.cut = []; scheduleDraw('net'); };
  $('apply-cut').onclick = () => {
    if (ui.cut.length < 2) { showError('cut: pick at least two vertices with the cut tool'); return; }
    const R = st.frame.reference.vertices;
    sendEdit({ op: 'cut', path: ui.cut.map((i) => [R[3 * i], R[3 * i + 1]]), support: $('cut-support').checked });
    ui.cut = [];
  };
  $('add-mass').onclick = () => {
    if (!ui.handles.length) { showError('extra mass: pick handle vertices first'); return; }
    sendEdit({ op: 'load', select: { vertices: [...ui.handles] }, extra_mass: Number($('extra-mass').value) });
  };
  for (const [id, s] of Object.entries(SLIDERS)) {
    const el = $(id);
    el.addEventListener('input', () => { el.nextElementSibling.textContent = s.fmt(Number(el.value)); });
    el.addEventListener('change', () => sendEdit(s.edit(Number(el.value))));
  }
  document.querySelectorAll('[data-save]').forEach((b) => b.addEventListener('click', () => save(b.dataset.save)));
  const pad = $('dragpad');
  pad.addEventListener('pointerdown', dragStart);
  pad.addEventListener('pointermove', (ev) => dragMove(ev));
  pad.addEventListener('pointerup', dragEnd);
  pad.addEventListener('pointercancel', dragEnd);
  document.addEventListener('keydown', (ev) => {
    if (!(ev.ctrlKey || ev.metaKey) || ev.target.tagName === 'INPUT') return;
    if (ev.key === 'z' && !ev.shiftKey) { send({ type: 'undo' }); ev.preventDefault(); }
    if (ev.key === 'y' || (ev.key === 'z' && ev.shiftKey)) { send({ type: 'redo' }); ev.preventDefault(); }
  });
}

window.ssDesign = { ui, st, pick, setTool, send, sendEdit, save, dragOffset, screenOf, nearestVertex };
wire();
connect();
