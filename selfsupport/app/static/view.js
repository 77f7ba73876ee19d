// Plotly traces of a frame (network coloured by force, reference, hull band) and of the
// analysis panels (Airy surface, reciprocal diagram): the style of selfsupport.figures.viewer.
// Pure functions of the server's messages; app.js owns the page.

export const FORCE_BINS = 6;
const TURBO = [[0, '#30123b'], [0.1, '#4662d7'], [0.2, '#36aaf9'], [0.3, '#1ae4b6'], [0.4, '#72fe5e'],
  [0.5, '#c8ef34'], [0.6, '#faba39'], [0.7, '#f66b19'], [0.8, '#ca2a04'], [0.9, '#a01101'], [1, '#7a0403']];

function turboAt(t) {
  t = Math.min(1, Math.max(0, t));
  for (let k = 1; k < TURBO.length; k++) {
    if (t <= TURBO[k][0]) {
      const [t0, c0] = TURBO[k - 1], [t1, c1] = TURBO[k];
      const s = (t - t0) / (t1 - t0), a = hex(c0), b = hex(c1);
      return `rgb(${a.map((x, i) => Math.round(x + s * (b[i] - x))).join(',')})`;
    }
  }
  return TURBO[TURBO.length - 1][1];
}
const hex = (c) => [1, 3, 5].map((i) => parseInt(c.slice(i, i + 2), 16));

function xyz(flat) {
  const n = flat.length / 3, x = new Array(n), y = new Array(n), z = new Array(n);
  for (let i = 0; i < n; i++) { x[i] = flat[3 * i]; y[i] = flat[3 * i + 1]; z[i] = flat[3 * i + 2]; }
  return { x, y, z };
}

function segments(P, pairs) {
  const x = [], y = [], z = [];
  for (const [a, b] of pairs) {
    x.push(P.x[a], P.x[b], null); y.push(P.y[a], P.y[b], null); z.push(P.z[a], P.z[b], null);
  }
  return { x, y, z };
}

function triangles(flat) {
  const n = flat.length / 3, i = new Array(n), j = new Array(n), k = new Array(n);
  for (let t = 0; t < n; t++) { i[t] = flat[3 * t]; j[t] = flat[3 * t + 1]; k[t] = flat[3 * t + 2]; }
  return { i, j, k };
}

export function forceRange(frame) {
  let lo = Infinity, hi = 0;
  frame.forces.forEach((f, e) => { if (frame.active[e]) { lo = Math.min(lo, f); hi = Math.max(hi, f); } });
  return hi > 0 ? [lo, hi] : [0, 1];
}

/** Area-weighted vertex normals of a triangle mesh (flat arrays), unit length. */
function vertexNormals(V, T) {
  const N = new Float64Array(V.length);
  for (let t = 0; t < T.length; t += 3) {
    const a = 3 * T[t], b = 3 * T[t + 1], c = 3 * T[t + 2];
    const u = [V[b] - V[a], V[b + 1] - V[a + 1], V[b + 2] - V[a + 2]];
    const w = [V[c] - V[a], V[c + 1] - V[a + 1], V[c + 2] - V[a + 2]];
    const n = [u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0]];
    for (const i of [a, b, c]) { N[i] += n[0]; N[i + 1] += n[1]; N[i + 2] += n[2]; }
  }
  for (let i = 0; i < N.length; i += 3) {
    const l = Math.hypot(N[i], N[i + 1], N[i + 2]) || 1;
    N[i] /= l; N[i + 1] /= l; N[i + 2] /= l;
  }
  return N;
}

/** The main view's traces (the layout's uirevision keeps the camera); ``light``: the edges,
 *  supports, handles and cut only, no colour bar (the picture drawn while a drag goes on). */
export function networkTraces(frame, ui, { light = false } = {}) {
  const P = xyz(frame.vertices);
  const traces = light ? [] : referenceTraces(frame, ui);
  forceTraces(frame, P, traces);
  const n = P.x.length;
  if (!light) {  // vertices carry their index (customdata): hovering shows it
    const idx = Array.from({ length: n }, (_, i) => i);
    traces.push({ type: 'scatter3d', mode: 'markers', name: 'vertices', ...P, customdata: idx,
      marker: { size: n > 500 ? 2 : 3, color: '#333' }, hovertemplate: 'vertex %{customdata}<extra></extra>',
      showlegend: false });
  }
  const pick = (ids) => ({ x: ids.map((i) => P.x[i]), y: ids.map((i) => P.y[i]), z: ids.map((i) => P.z[i]), customdata: ids });
  traces.push({ type: 'scatter3d', mode: 'markers', name: 'supports', ...pick(frame.supports),
    marker: { size: 4, color: 'black', symbol: 'square' }, hovertemplate: 'support %{customdata}<extra></extra>' });
  traces.push({ type: 'scatter3d', mode: 'markers', name: 'handles', ...pick(ui.handles.filter((i) => i < n)),
    marker: { size: 6, color: '#ff8c00' }, hovertemplate: 'handle %{customdata}<extra></extra>' });
  traces.push({ type: 'scatter3d', mode: 'lines+markers', name: 'cut path', ...pick(ui.cut.filter((i) => i < n)),
    marker: { size: 5, color: '#d000d0' }, line: { color: '#d000d0', width: 4 }, hoverinfo: 'skip' });
  // colorbar of the forces (the viewer's: Turbo, newtons); not while dragging: redrawing it is
  // one more animation frame per picture in headless Chromium
  if (light) return traces;
  const [fmin, fmax] = forceRange(frame);
  traces.push({ type: 'scatter3d', mode: 'markers', x: [P.x[0]], y: [P.y[0]], z: [P.z[0]], hoverinfo: 'skip',
    showlegend: false, name: 'force scale', marker: { size: 0.1, opacity: 0, color: [fmin], cmin: fmin, cmax: fmax,
      colorscale: TURBO, showscale: true, colorbar: { title: { text: 'edge force [N]' }, x: 0, xanchor: 'left', len: 0.7, thickness: 12 } } });
  return traces;
}

/** The reference surface and the hull band (reference ± t/2), transparent meshes. */
function referenceTraces(frame, ui) {
  const R = xyz(frame.reference.vertices), T = triangles(frame.reference.triangles);
  const traces = [];
  traces.push({ type: 'mesh3d', name: 'reference', ...R, ...T, color: 'lightsteelblue', opacity: 0.25,
    hoverinfo: 'skip', flatshading: true, showlegend: true });
  // hull band: the reference ± t/2 along its vertex normals (the masonry's extent; the sign of the
  // normals does not matter)
  const Rv = frame.reference.vertices, N = vertexNormals(Rv, frame.reference.triangles), half = 0.5 * frame.design.thickness;
  // (one trace for both sheets: each transparent object costs plotly's WebGL renderer a pass)
  const nR = Rv.length / 3, band = Rv.concat(Rv);
  for (let k = 0; k < Rv.length; k++) { band[k] += half * N[k]; band[Rv.length + k] -= half * N[k]; }
  const B = xyz(band), BT = { i: T.i.concat(T.i.map((v) => v + nR)), j: T.j.concat(T.j.map((v) => v + nR)),
    k: T.k.concat(T.k.map((v) => v + nR)) };
  traces.push({ type: 'mesh3d', name: 'hull band (reference ± t/2)', ...B, ...BT, color: '#c9a36b', opacity: 0.12,
    hoverinfo: 'skip', showlegend: true, visible: ui.showHull ? true : 'legendonly' });
  return traces;
}

/** The edges binned by force (one trace per colour) and the support-support edges, into ``traces``. */
function forceTraces(frame, P, traces) {
  const fmax = forceRange(frame)[1];
  const bins = Array.from({ length: FORCE_BINS }, () => []), passive = [];
  const E = frame.edges;
  for (let e = 0; e < frame.forces.length; e++) {
    const pair = [E[2 * e], E[2 * e + 1]];
    if (!frame.active[e]) { passive.push(pair); continue; }
    bins[Math.min(FORCE_BINS - 1, Math.floor(frame.forces[e] / fmax * FORCE_BINS))].push(pair);
  }
  bins.forEach((pairs, b) => traces.push({ type: 'scatter3d', mode: 'lines', ...segments(P, pairs),
    line: { width: 1.5 + 7 * (b + 0.5) / FORCE_BINS, color: turboAt((b + 0.5) / FORCE_BINS) },
    hoverinfo: 'skip', showlegend: false, name: `forces ${b + 1}/${FORCE_BINS}` }));
  traces.push({ type: 'scatter3d', mode: 'lines', ...segments(P, passive), line: { width: 1, color: 'gray' },
    hoverinfo: 'skip', showlegend: false, name: 'support–support edges' });
}

export function networkLayout(title) {
  return { uirevision: 'keep', margin: { l: 0, r: 0, t: 28, b: 0 }, title: { text: title, font: { size: 13 } },
    legend: { orientation: 'h', x: 0.5, xanchor: 'center', y: 0 }, showlegend: true,
    scene: { aspectmode: 'data', xaxis: { title: { text: 'x [m]' } }, yaxis: { title: { text: 'y [m]' } },
      zaxis: { title: { text: 'z [m]' } }, camera: { eye: { x: 1.1, y: -1.9, z: 1.15 } } } };
}

export function airyTraces(frame, analysis) {
  if (!analysis || !analysis.airy) return [];
  const P = xyz(frame.vertices), T = triangles(frame.reference.triangles);
  const phi = analysis.airy.phi.map((v) => v / 1000);
  return [{ type: 'mesh3d', x: P.x, y: P.y, z: phi, ...T, intensity: phi, colorscale: 'Viridis', showscale: false,
    flatshading: true, hovertemplate: 'φ = %{z:.4g} kN·m<extra></extra>', name: 'Airy surface Φ' }];
}

export function reciprocalTraces(analysis) {
  if (!analysis || !analysis.reciprocal) return [];
  const s = analysis.reciprocal.segments, x = [], y = [];
  for (let k = 0; k < s.length; k += 4) { x.push(s[k], s[k + 2], null); y.push(s[k + 1], s[k + 3], null); }
  return [{ type: 'scatter', mode: 'lines', x, y, line: { color: '#1f3b73', width: 1 }, hoverinfo: 'skip',
    name: 'reciprocal diagram' }];
}

export const airyLayout = (note) => ({ uirevision: 'keep', margin: { l: 0, r: 0, t: 24, b: 0 },
  title: { text: note || 'Airy stress surface Φ (φ in kN·m, not to scale)', font: { size: 12 } },
  scene: { aspectmode: 'cube', xaxis: { title: { text: 'x' } }, yaxis: { title: { text: 'y' } }, zaxis: { title: { text: 'φ' } } } });

export const reciprocalLayout = () => ({ uirevision: 'keep', margin: { l: 50, r: 10, t: 24, b: 36 },
  title: { text: 'reciprocal force diagram', font: { size: 12 } },
  xaxis: { title: { text: '∂φ/∂x [N]' } }, yaxis: { title: { text: '∂φ/∂y [N]' }, scaleanchor: 'x' } });
