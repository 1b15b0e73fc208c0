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
function drawProfile() {
  const row = grid.z[+slider.value], ctx = profile.getContext('2d'), w = profile.width, h = profile.height;
  const left = 58, right = 10, top = 10, bottom = 34, length = (row.length - 1) * grid.dy / 1000;  // mm
  const X = mm => left + mm / (length || 1) * (w - left - right), Y = v => h - bottom - (v - zlo) / (zhi - zlo) * (h - top - bottom);
  ctx.clearRect(0, 0, w, h); ctx.strokeStyle = '#999'; ctx.fillStyle = '#333'; ctx.lineWidth = 1; ctx.font = '11px sans-serif';
  ctx.beginPath(); ctx.moveTo(left, top); ctx.lineTo(left, h - bottom); ctx.lineTo(w - right, h - bottom); ctx.stroke();
  ctx.textAlign = 'right'; ctx.textBaseline = 'middle';
  for (const t of ticks(zlo, zhi, 4)) { ctx.fillText(t.toString(), left - 6, Y(t)); ctx.beginPath(); ctx.moveTo(left - 3, Y(t)); ctx.lineTo(left, Y(t)); ctx.stroke(); }
  ctx.textAlign = 'center'; ctx.textBaseline = 'top';
  for (const t of ticks(0, length, 6)) { ctx.fillText(t.toString(), X(t), h - bottom + 5); ctx.beginPath(); ctx.moveTo(X(t), h - bottom); ctx.lineTo(X(t), h - bottom + 3); ctx.stroke(); }
  ctx.fillText('y (mm, top to bottom)', (left + w - right) / 2, h - 14);
  ctx.save(); ctx.translate(12, (top + h - bottom) / 2); ctx.rotate(-Math.PI / 2); ctx.fillText('height (um)', 0, -4); ctx.restore();
  ctx.strokeStyle = '#7a3b12'; ctx.lineWidth = 1.5; ctx.beginPath(); let pen = false;
  row.forEach((v, i) => { if (!finite(v)) { pen = false; return; }
    const x = X(i * grid.dy / 1000), y = Y(v);
    if (pen) ctx.lineTo(x, y); else ctx.moveTo(x, y); pen = true; });
  ctx.stroke();
  document.getElementById('rowlabel').textContent = (slider.value * grid.dx / 1000).toFixed(2) + ' mm';
}
slider.max = grid.z.length - 1; slider.value = Math.floor(grid.z.length / 2);
slider.addEventListener('input', drawProfile); drawProfile();
// 3-D view: shaded quads, painter's algorithm on a 2-D canvas; drag to turn.
const view = document.getElementById('view3d'); let yaw = 0.6, pitch = 0.9, drag = null;
function draw3d() {
  const grid = Object.assign({}, all.mesh, {exaggeration: all.exaggeration, size: all.size, mid: all.mid});
  const ctx = view.getContext('2d'), W = view.width, H = view.height, z = grid.z;
  const n = z.length, m = z[0].length, zs = grid.exaggeration, quads = [];
  const cy = Math.cos(yaw), sy = Math.sin(yaw), cp = Math.cos(pitch), sp = Math.sin(pitch);
  const sx = grid.dx / grid.size, sz = grid.dy / grid.size;
  function project(i, j) { const x = (j - m / 2) * sx, y = (i - n / 2) * sz, h = (z[i][j] - grid.mid) * zs / grid.size;
    const X = x * cy - y * sy, Y = x * sy + y * cy; return [X, Y * cp - h * sp, Y * sp + h * cp]; }
  for (let i = 0; i < n - 1; i++) for (let j = 0; j < m - 1; j++) {
    if (![z[i][j], z[i + 1][j], z[i][j + 1], z[i + 1][j + 1]].every(finite)) continue;
    const p = [project(i, j), project(i, j + 1), project(i + 1, j + 1), project(i + 1, j)];
    const gx = (z[i][j + 1] - z[i][j]) * zs / grid.size / sx, gy = (z[i + 1][j] - z[i][j]) * zs / grid.size / sz;
    const shade = Math.max(0.15, (0.5 - 0.5 * gx + 0.5 * gy + 0.7) / Math.sqrt(gx * gx + gy * gy + 1) / 1.35);
    quads.push([p[0][2] + p[2][2], p, shade]); }
  quads.sort((a, b) => a[0] - b[0]); ctx.clearRect(0, 0, W, H); const k = 0.8 * Math.min(W, H);
  for (const [_, p, s] of quads) { ctx.fillStyle = `rgb(${Math.round(230 * s)},${Math.round(170 * s)},${Math.round(130 * s)})`;
    ctx.beginPath(); p.forEach((q, t) => { const x = W / 2 + q[0] * k, y = H / 2 + q[1] * k; t ? ctx.lineTo(x, y) : ctx.moveTo(x, y); });
    ctx.closePath(); ctx.fill(); }
}
view.addEventListener('mousedown', e => drag = [e.clientX, e.clientY, yaw, pitch]);
window.addEventListener('mouseup', () => drag = null);
window.addEventListener('mousemove', e => { if (!drag) return; yaw = drag[2] + (e.clientX - drag[0]) / 150;
  pitch = Math.min(1.5, Math.max(0.1, drag[3] + (e.clientY - drag[1]) / 150)); draw3d(); });
draw3d();
