const all = JSON.parse(document.getElementById('grid').textContent), grid = all;
function decode(part) {  // base64 little-endian float32 rows, NaN = missing
  const bytes = Uint8Array.from(atob(part.z), c => c.charCodeAt(0)), values = new Float32Array(bytes.buffer), [rows, cols] = part.shape;
  part.z = Array.from({length: rows}, (_, i) => Array.from(values.subarray(i * cols, (i + 1) * cols)));
}
decode(all); decode(all.mesh);
function finite(v) { return v !== null && Number.isFinite(v); }
// Cross-section viewer: one image column (a vertical line, across horizontal wrinkles) chosen with the slider.
const slider = document.getElementById('row'), profile = document.getElementById('profile');
let zlo = Infinity, zhi = -Infinity;  // one vertical scale for every position of the slider
for (const r of grid.z) for (const v of r) if (finite(v)) { zlo = Math.min(zlo, v); zhi = Math.max(zhi, v); }
if (!(zhi > zlo)) { zlo = (finite(zlo) ? zlo : 0) - 1; zhi = zlo + 2; }
function ticks(lo, hi, count) {  // round steps (1, 2, 5 x 10^k) covering [lo, hi]
  const raw = (hi - lo) / count, unit = Math.pow(10, Math.floor(Math.log10(raw)));
  const step = [1, 2, 5, 10].map(f => f * unit).find(s => s >= raw), out = [];
  for (let t = Math.ceil(lo / step) * step; t <= hi + 1e-9 * step; t += step) out.push(+t.toFixed(10));
  return out;
}
function drawAxes(ctx, frame, X, Y, xTicks, yTicks, xLabel, yLabel) {  // the left and bottom axes of a 2-D plot, ticks and labels
  const {w, h, left, right, top, bottom} = frame;
  ctx.clearRect(0, 0, w, h); ctx.strokeStyle = '#999'; ctx.fillStyle = '#333'; ctx.lineWidth = 1; ctx.font = '11px sans-serif';
  ctx.beginPath(); ctx.moveTo(left, top); ctx.lineTo(left, h - bottom); ctx.lineTo(w - right, h - bottom); ctx.stroke();
  ctx.textAlign = 'right'; ctx.textBaseline = 'middle';
  for (const t of yTicks) { ctx.fillText(t.toString(), left - 6, Y(t)); ctx.beginPath(); ctx.moveTo(left - 3, Y(t)); ctx.lineTo(left, Y(t)); ctx.stroke(); }
  ctx.textAlign = 'center'; ctx.textBaseline = 'top';
  for (const t of xTicks) { ctx.fillText(t.toString(), X(t), h - bottom + 5); ctx.beginPath(); ctx.moveTo(X(t), h - bottom); ctx.lineTo(X(t), h - bottom + 3); ctx.stroke(); }
  ctx.fillText(xLabel, (left + w - right) / 2, h - bottom + 20);
  ctx.save(); ctx.translate(12, (top + h - bottom) / 2); ctx.rotate(-Math.PI / 2); ctx.fillText(yLabel, 0, -4); ctx.restore();
}
function drawProfile() {
  const row = grid.z[+slider.value], ctx = profile.getContext('2d'), w = profile.width, h = profile.height;
  const left = 58, right = 10, top = 10, bottom = 34, length = (row.length - 1) * grid.dy / 1000;  // mm
  const X = mm => left + mm / (length || 1) * (w - left - right), Y = v => h - bottom - (v - zlo) / (zhi - zlo) * (h - top - bottom);
  drawAxes(ctx, {w, h, left, right, top, bottom}, X, Y, ticks(0, length, 6), ticks(zlo, zhi, 4), 'y (mm, top to bottom)', 'height (um)');
  ctx.strokeStyle = '#7a3b12'; ctx.lineWidth = 1.5; ctx.beginPath(); let pen = false;
  row.forEach((v, i) => { if (!finite(v)) { pen = false; return; }
    const x = X(i * grid.dy / 1000), y = Y(v);
    if (pen) ctx.lineTo(x, y); else ctx.moveTo(x, y); pen = true; });
  ctx.stroke();
  document.getElementById('rowlabel').textContent = (slider.value * grid.dx / 1000).toFixed(2) + ' mm';
}
slider.max = grid.z.length - 1; slider.value = Math.floor(grid.z.length / 2);
slider.addEventListener('input', drawProfile); drawProfile();
// 3-D view: the height map as a lit WebGL surface (hand-written: a height field, one light
// and an orbit camera need about 200 lines; a general 3-D library inlined in every report
// would be about 600 kB). Colour = height on the copper map of the 2-D map above, shading =
// Lambert from the upper left. Axes in mm (x, y) and um (true heights, before exaggeration)
// are drawn on a 2-D canvas laid over the WebGL one. Drag or one finger turns, the wheel or
// two fingers zoom, double-click or "Reset view" returns to the start.
const view3d = (() => {
  const mesh = all.mesh, [n, m] = mesh.shape, zs = all.exaggeration, mid = all.mid;
  const gl3 = document.getElementById('view3d'), overlay = document.getElementById('view3d-axes');
  const W = gl3.width, H = gl3.height, hx = (m - 1) * mesh.dx / 2000, hy = (n - 1) * mesh.dy / 2000;  // half extents, mm
  let zlo = Infinity, zhi = -Infinity;
  for (const r of mesh.z) for (const v of r) if (finite(v)) { zlo = Math.min(zlo, v); zhi = Math.max(zhi, v); }
  if (!(zhi > zlo)) { zlo = (finite(zlo) ? zlo : 0) - 1; zhi = zlo + 2; }
  const Z = v => (v - mid) * zs / 1000;  // um -> exaggerated mm
  const start = {yaw: -0.6, pitch: 0.95, distance: 4.0 * Math.max(hx, hy, 0.5 * (Z(zhi) - Z(zlo))), panX: 0, panY: 0};
  const state = Object.assign({}, start);
  const copper = t => [Math.min(1, 1.25 * t), 0.7812 * t, 0.4975 * t];  // matplotlib's copper
  // mat4, column-major as WebGL expects
  const multiply = (a, b) => { const o = new Float32Array(16);
    for (let i = 0; i < 4; i++) for (let j = 0; j < 4; j++) { let s = 0; for (let k = 0; k < 4; k++) s += a[k * 4 + j] * b[i * 4 + k]; o[i * 4 + j] = s; }
    return o; };
  function matrix() {  // projection x camera: orbit around the field's centre
    const f = 1 / Math.tan(0.3), near = state.distance / 50, far = state.distance * 10;
    const projection = new Float32Array([f * H / W, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) / (near - far), -1, 0, 0, 2 * far * near / (near - far), 0]);
    const cy = Math.cos(state.yaw), sy = Math.sin(state.yaw), cp = Math.cos(state.pitch), sp = Math.sin(state.pitch);
    const turn = new Float32Array([cy, -sy * cp, sy * sp, 0, sy, cy * cp, -cy * sp, 0, 0, sp, cp, 0, 0, 0, -state.distance, 1]);
    const M = multiply(projection, turn);
    for (let k = 0; k < 4; k++) { M[k * 4] += state.panX * M[k * 4 + 3]; M[k * 4 + 1] += state.panY * M[k * 4 + 3]; }  // shift on screen
    return M;
  }
  function frame() {  // the start view: the box and its labels fill the canvas left of the colour bar, centred
    const corners = [];
    for (const x of [-1.3 * hx, 1.15 * hx]) for (const y of [-1.35 * hy, 1.1 * hy]) for (const z of [Z(zlo), Z(zhi)]) corners.push([x, y, z]);
    for (let pass = 0; pass < 3; pass++) {
      const M = matrix(), points = corners.map(c => project(M, ...c));
      if (points.some(p => !p)) { state.distance *= 2; continue; }
      const xs = points.map(p => p[0]), ys = points.map(p => p[1]);
      const width = Math.max(...xs) - Math.min(...xs), height = Math.max(...ys) - Math.min(...ys);
      state.distance *= Math.max(width / (W - 90), height / (H - 30));
      const M2 = matrix(), moved = corners.map(c => project(M2, ...c));
      state.panX -= ((Math.max(...moved.map(p => p[0])) + Math.min(...moved.map(p => p[0]))) / 2 - (W - 60) / 2) * 2 / W;
      state.panY += ((Math.max(...moved.map(p => p[1])) + Math.min(...moved.map(p => p[1]))) / 2 - H / 2) * 2 / H;
    }
    Object.assign(start, state);
  }
  function project(M, x, y, z) {  // world (mm) -> canvas pixels, or null behind the camera
    const c = [0, 1, 2, 3].map(j => M[j] * x + M[4 + j] * y + M[8 + j] * z + M[12 + j]);
    return c[3] > 0 ? [(c[0] / c[3] + 1) * W / 2, (1 - c[1] / c[3]) * H / 2] : null;
  }
  const gl = gl3.getContext('webgl', {preserveDrawingBuffer: true, antialias: true});
  if (!gl) { document.getElementById('nowebgl').hidden = false; return null; }
  // vertices: position (mm, y up), normal, height on [0, 1]
  const data = new Float32Array(n * m * 7), at = (i, j) => mesh.z[Math.min(n - 1, Math.max(0, i))][Math.min(m - 1, Math.max(0, j))];
  for (let i = 0; i < n; i++) for (let j = 0; j < m; j++) {
    const v = mesh.z[i][j], k = (i * m + j) * 7, here = finite(v) ? v : mid;
    const left = finite(at(i, j - 1)) ? at(i, j - 1) : here, right = finite(at(i, j + 1)) ? at(i, j + 1) : here;
    const up = finite(at(i - 1, j)) ? at(i - 1, j) : here, down = finite(at(i + 1, j)) ? at(i + 1, j) : here;
    const gx = (Z(right) - Z(left)) / (2 * mesh.dx / 1000), gy = (Z(up) - Z(down)) / (2 * mesh.dy / 1000), norm = Math.hypot(gx, gy, 1);
    data.set([j * mesh.dx / 1000 - hx, hy - i * mesh.dy / 1000, Z(here), -gx / norm, -gy / norm, 1 / norm, (here - zlo) / (zhi - zlo)], k);
  }
  const indices = [];  // two triangles per cell whose four corners are measured
  for (let i = 0; i < n - 1; i++) for (let j = 0; j < m - 1; j++) {
    const a = i * m + j, b = a + 1, c = a + m, d = c + 1;
    if ([mesh.z[i][j], mesh.z[i][j + 1], mesh.z[i + 1][j], mesh.z[i + 1][j + 1]].every(finite)) indices.push(a, c, b, b, c, d);
  }
  function shader(type, source) { const s = gl.createShader(type); gl.shaderSource(s, source); gl.compileShader(s); return s; }
  const program = gl.createProgram();
  gl.attachShader(program, shader(gl.VERTEX_SHADER, `attribute vec3 p; attribute vec3 normal; attribute float h; uniform mat4 M;
    varying vec3 vn; varying float vh; void main() { gl_Position = M * vec4(p, 1.0); vn = normal; vh = h; }`));
  gl.attachShader(program, shader(gl.FRAGMENT_SHADER, `precision mediump float; varying vec3 vn; varying float vh;
    void main() { vec3 light = normalize(vec3(-0.5, 0.5, 0.7071)); float t = clamp(vh, 0.0, 1.0);
      vec3 colour = vec3(min(1.0, 1.25 * t), 0.7812 * t, 0.4975 * t) * 0.8 + 0.2;
      float lambert = max(dot(normalize(vn), light), 0.0); gl_FragColor = vec4(colour * (0.3 + 0.75 * lambert), 1.0); }`));
  gl.linkProgram(program); gl.useProgram(program);
  gl.bindBuffer(gl.ARRAY_BUFFER, gl.createBuffer()); gl.bufferData(gl.ARRAY_BUFFER, data, gl.STATIC_DRAW);
  [['p', 3, 0], ['normal', 3, 12], ['h', 1, 24]].forEach(([name, size, offset]) => {
    const where = gl.getAttribLocation(program, name); gl.enableVertexAttribArray(where); gl.vertexAttribPointer(where, size, gl.FLOAT, false, 28, offset); });
  gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, gl.createBuffer()); gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, new Uint16Array(indices), gl.STATIC_DRAW);
  gl.enable(gl.DEPTH_TEST);
  frame();
  function axes(M) {  // box edges at the lowest height, ticks in mm and um, and the colour bar
    const ctx = overlay.getContext('2d'), base = Z(zlo);
    ctx.clearRect(0, 0, W, H); ctx.font = '11px sans-serif'; ctx.fillStyle = '#222'; ctx.strokeStyle = '#555'; ctx.lineWidth = 1;
    const line = (a, b) => { const p = project(M, ...a), q = project(M, ...b); if (!p || !q) return;
      ctx.beginPath(); ctx.moveTo(...p); ctx.lineTo(...q); ctx.stroke(); };
    const label = (text, point, dx = 0, dy = 0) => { const p = project(M, ...point); if (p) ctx.fillText(text, p[0] + dx, p[1] + dy); };
    ctx.textAlign = 'center'; ctx.textBaseline = 'middle';
    line([-hx, -hy, base], [hx, -hy, base]); line([-hx, -hy, base], [-hx, hy, base]); line([-hx, -hy, base], [-hx, -hy, Z(zhi)]);
    for (const t of ticks(0, 2 * hx, 5)) { line([t - hx, -hy, base], [t - hx, -hy - 0.04 * hy, base]); label(t.toString(), [t - hx, -hy - 0.12 * hy, base]); }
    for (const t of ticks(0, 2 * hy, 5)) { line([-hx, hy - t, base], [-hx - 0.04 * hx, hy - t, base]); label(t.toString(), [-hx - 0.12 * hx, hy - t, base]); }
    for (const t of ticks(zlo, zhi, 4)) { line([-hx, -hy, Z(t)], [-hx - 0.04 * hx, -hy - 0.04 * hy, Z(t)]); label(t.toString(), [-hx - 0.09 * hx, -hy - 0.09 * hy, Z(t)], -14); }
    ctx.font = 'bold 11px sans-serif';
    label('x (mm)', [0, -hy - 0.28 * hy, base]); label('y (mm)', [-hx - 0.3 * hx, 0, base]); label('height (um)', [-hx, -hy, Z(zhi)], 0, -14);
    const left = W - 46, top = 40, tall = H - 80;  // colour bar: height (um), the surface's colours
    for (let k = 0; k < tall; k++) { const c = copper(1 - k / tall).map(v => Math.round(255 * (0.8 * v + 0.2)));
      ctx.fillStyle = `rgb(${c})`; ctx.fillRect(left, top + k, 12, 1); }
    ctx.strokeRect(left, top, 12, tall); ctx.font = '11px sans-serif'; ctx.fillStyle = '#222'; ctx.textAlign = 'right';
    for (const t of ticks(zlo, zhi, 5)) ctx.fillText(t.toString(), left - 4, top + tall * (1 - (t - zlo) / (zhi - zlo)));
    ctx.save(); ctx.translate(W - 12, H / 2); ctx.rotate(-Math.PI / 2); ctx.textAlign = 'center'; ctx.fillText('height (um)', 0, 0); ctx.restore();
  }
  function render() {
    const M = matrix();
    gl.viewport(0, 0, W, H); gl.clearColor(1, 1, 1, 1); gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    gl.uniformMatrix4fv(gl.getUniformLocation(program, 'M'), false, M); gl.drawElements(gl.TRIANGLES, indices.length, gl.UNSIGNED_SHORT, 0);
    axes(M);
  }
  const turn = (dx, dy) => { state.yaw += dx / 150; state.pitch = Math.min(1.55, Math.max(0.05, state.pitch - dy / 150)); render(); };
  const zoom = factor => { state.distance = Math.min(20 * start.distance, Math.max(start.distance / 20, state.distance * factor)); render(); };
  const reset = () => { Object.assign(state, start); render(); };
  let mouse = null, touches = null;
  overlay.addEventListener('pointerdown', e => { if (e.pointerType !== 'touch') { mouse = [e.clientX, e.clientY]; e.preventDefault(); } });
  window.addEventListener('pointermove', e => { if (!mouse || e.pointerType === 'touch') return; turn(e.clientX - mouse[0], e.clientY - mouse[1]); mouse = [e.clientX, e.clientY]; });
  window.addEventListener('pointerup', () => { mouse = null; });
  overlay.addEventListener('wheel', e => { e.preventDefault(); zoom(Math.exp(e.deltaY / 500)); }, {passive: false});
  overlay.addEventListener('dblclick', reset);
  document.getElementById('reset3d').addEventListener('click', reset);
  const fingers = e => Array.from(e.touches, t => [t.clientX, t.clientY]);
  const spread = f => Math.hypot(f[0][0] - f[1][0], f[0][1] - f[1][1]);
  overlay.addEventListener('touchstart', e => { e.preventDefault(); touches = fingers(e); }, {passive: false});
  overlay.addEventListener('touchmove', e => { e.preventDefault(); const now = fingers(e);
    if (touches && now.length === 1 && touches.length === 1) turn(now[0][0] - touches[0][0], now[0][1] - touches[0][1]);
    else if (touches && now.length === 2 && touches.length === 2) zoom(spread(touches) / Math.max(1, spread(now)));
    touches = now; }, {passive: false});
  overlay.addEventListener('touchend', e => { touches = fingers(e); });
  render();
  // for tests and the curious: the view's state and what it shows (mean and spread of the
  // surface's brightness, the share of the canvas it covers, a checksum of the pixels)
  return {state, reset, snapshot() { render(); const pixels = new Uint8Array(W * H * 4); gl.readPixels(0, 0, W, H, gl.RGBA, gl.UNSIGNED_BYTE, pixels);
    let count = 0, total = 0, squares = 0, checksum = 0;
    for (let k = 0; k < pixels.length; k += 4) { const y = (pixels[k] + pixels[k + 1] + pixels[k + 2]) / 3; checksum = (checksum * 31 + y) % 1000000007;
      if (y < 250) { count++; total += y; squares += y * y; } }
    const mean = total / Math.max(1, count);
    return Object.assign({}, state, {covered: count / (W * H), mean, spread: Math.sqrt(Math.max(0, squares / Math.max(1, count) - mean * mean)), checksum}); }};
})();
// Fractal dimension: each estimator's log-log points and its fitted line (whose slope gives
// the table's D), on one pair of axes.
(() => {
  const canvas = document.getElementById('fractal');
  if (!canvas || !all.fractal.length) return;
  const ctx = canvas.getContext('2d'), w = canvas.width, h = canvas.height, left = 58, right = 10, top = 10, bottom = 40;
  const xs = all.fractal.flatMap(r => r.x), ys = all.fractal.flatMap(r => r.y);
  let x0 = Math.min(...xs), x1 = Math.max(...xs), y0 = Math.min(...ys), y1 = Math.max(...ys);
  if (!(x1 > x0)) { x0 -= 1; x1 += 1; } if (!(y1 > y0)) { y0 -= 1; y1 += 1; }
  const padX = 0.03 * (x1 - x0), padY = 0.03 * (y1 - y0);  // no point on the axes
  x0 -= padX; x1 += padX; y0 -= padY; y1 += padY;
  const X = v => left + (v - x0) / (x1 - x0) * (w - left - right), Y = v => h - bottom - (v - y0) / (y1 - y0) * (h - top - bottom);
  drawAxes(ctx, {w, h, left, right, top, bottom}, X, Y, ticks(x0, x1, 6), ticks(y0, y1, 5), "ln(scale) (each method's own axis)", 'ln(measure)');
  const colours = ['#1f77b4', '#ff7f0e', '#2ca02c', '#d62728', '#9467bd', '#8c564b'];
  ctx.textAlign = 'left'; ctx.textBaseline = 'middle';
  ctx.save(); ctx.beginPath(); ctx.rect(left, top, w - left - right, h - top - bottom); ctx.clip();  // a fitted line may leave the points' range
  all.fractal.forEach((r, i) => {
    const colour = colours[i % colours.length], lo = Math.min(...r.x), hi = Math.max(...r.x);
    ctx.fillStyle = colour; ctx.strokeStyle = colour;
    r.x.forEach((x, k) => { ctx.beginPath(); ctx.arc(X(x), Y(r.y[k]), 3, 0, 2 * Math.PI); ctx.fill(); });
    ctx.globalAlpha = 0.6; ctx.lineWidth = 1.5; ctx.beginPath();
    ctx.moveTo(X(lo), Y(r.slope * lo + r.intercept)); ctx.lineTo(X(hi), Y(r.slope * hi + r.intercept)); ctx.stroke(); ctx.globalAlpha = 1;
  });
  ctx.restore();
  const names = all.fractal.map(r => r.method + ': D = ' + (finite(r.dimension) ? r.dimension.toFixed(3) : 'not defined'));
  const legend = [left + 8, top + 2, Math.max(...names.map(n => ctx.measureText(n).width)) + 30, 16 * names.length + 6];
  ctx.fillStyle = 'rgba(255, 255, 255, 0.85)'; ctx.strokeStyle = '#ccc'; ctx.fillRect(...legend); ctx.strokeRect(...legend);
  names.forEach((name, i) => {
    ctx.fillStyle = colours[i % colours.length];
    ctx.beginPath(); ctx.arc(left + 18, top + 13 + 16 * i, 3, 0, 2 * Math.PI); ctx.fill(); ctx.fillText(name, left + 26, top + 13 + 16 * i);
  });
})();
