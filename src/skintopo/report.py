"""A self-contained HTML report a clinician can read.

One file, nothing loaded from anywhere (images are inline PNG data, the 3-D view and the
profile viewer are a few lines of inline JavaScript drawing on a canvas), so it opens
offline and leaks nothing. Every user-provided string is HTML-escaped. Large maps are
downsampled for display only (at most ``DISPLAY_PIXELS`` a side for images, ``MESH_CELLS``
for the 3-D view); every number in the tables comes from the full-resolution data.
Missing points (NaN) are shown as missing (transparent grey), never as zeros.
"""

from __future__ import annotations

import base64
import html
import io
import json

import numpy as np

DISPLAY_PIXELS = 600
MESH_CELLS = 90
PROFILE_POINTS = 400


def _png(figure):
    import matplotlib.pyplot as plt

    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=100)
    plt.close(figure)
    return base64.b64encode(buffer.getvalue()).decode("ascii")


def _decimate(array, limit):
    step = max(1, int(np.ceil(max(array.shape[:2]) / limit)))
    return array[::step, ::step], step


def shaded_height_png(height, title="height"):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LightSource

    z, step = _decimate(height.z, DISPLAY_PIXELS)
    missing = ~np.isfinite(z)
    filled = np.where(missing, np.nanmedian(z) if (~missing).any() else 0.0, z)
    shade = LightSource(azdeg=315, altdeg=45).shade(filled, cmap=plt.get_cmap("copper"), blend_mode="soft",
                                                  vert_exag=1.0, dx=height.spacing[1] * step, dy=height.spacing[0] * step)
    shade[missing] = (0.6, 0.6, 0.6, 0.3)
    rows, columns = height.shape
    figure, axes = plt.subplots(figsize=(6, 6 * rows / columns))
    axes.imshow(shade, extent=(0, columns * height.spacing[1] / 1000, rows * height.spacing[0] / 1000, 0))
    axes.set(xlabel="x (mm)", ylabel="y (mm)", title=title)
    figure.tight_layout()
    return _png(figure)


def image_png(values, title, spacing, cmap="gray"):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    data, _ = _decimate(np.asarray(values, float), DISPLAY_PIXELS)
    rows, columns = np.asarray(values).shape
    figure, axes = plt.subplots(figsize=(6, 6 * rows / columns))
    shown = axes.imshow(np.ma.masked_invalid(data), cmap=cmap, extent=(0, columns * spacing[1] / 1000, rows * spacing[0] / 1000, 0))
    figure.colorbar(shown, ax=axes, shrink=0.8)
    axes.set(xlabel="x (mm)", ylabel="y (mm)", title=title)
    figure.tight_layout()
    return _png(figure)


def wrinkle_overlay_png(height, measures):
    """Shaded height with the wrinkles' half-depth regions, centre lines and ids."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LightSource

    z = np.where(height.mask, height.z, np.nanmedian(height.z))
    shaded = LightSource(azdeg=315, altdeg=45).hillshade(z, dx=height.spacing[1], dy=height.spacing[0])
    rows, columns = height.shape
    figure, axes = plt.subplots(figsize=(8, 8 * rows / columns))
    extent = (0, columns * height.spacing[1] / 1000, rows * height.spacing[0] / 1000, 0)
    axes.imshow(_decimate(shaded, DISPLAY_PIXELS)[0], cmap="gray", extent=extent)
    axes.imshow(np.ma.masked_equal(_decimate(measures.labels, DISPLAY_PIXELS)[0], 0), cmap="tab10", alpha=0.35, extent=extent, interpolation="nearest")
    lines = _thicken(measures.lines) if max(rows, columns) > DISPLAY_PIXELS else measures.lines
    axes.imshow(np.ma.masked_equal(_decimate(lines.astype(int), DISPLAY_PIXELS)[0], 0), cmap="autumn", extent=extent, interpolation="nearest")
    for wrinkle in measures.wrinkles:
        axes.text(wrinkle.centroid_x_mm, wrinkle.centroid_y_mm, str(wrinkle.id), color="yellow", fontsize=14, weight="bold", ha="center", va="center")
    axes.set(xlabel="x (mm)", ylabel="y (mm, image rows)", title=f"{len(measures.wrinkles)} wrinkle(s)")
    figure.tight_layout()
    return _png(figure)


def _thicken(mask):
    """Centre lines two pixels wider each side, so they survive downsampling for display."""
    import scipy.ndimage

    return scipy.ndimage.binary_dilation(mask, iterations=2)


_BAND_COLOURS = {"red": "tab:red", "green": "tab:green", "blue": "tab:blue", "white": "0.4", "algorithm": "tab:purple"}


def cross_section_pngs(heights, truth, wrinkle_labels, *, title=""):
    """The paper's Figures 3 and 5: a cross-section across the deepest true wrinkle, per band
    against the ground truth, and the algorithm (with red) against it. Returns two base64 PNGs."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from skintopo.evaluation import cross_section_line, wrinkle_max_depths
    from skintopo.filters import extract_profile

    deepest = int(np.nanargmax(wrinkle_max_depths(truth, wrinkle_labels))) + 1
    start, end = cross_section_line(wrinkle_labels, deepest, truth.spacing)

    def profile(height):
        distance, z = extract_profile(height, start, end, width_um=100.0)
        return distance / 1000.0, z - np.nanmedian(z)

    distance, reference = profile(truth)
    pictures = []
    for chosen, caption in (([b for b in ("red", "green", "blue", "white") if b in heights], "cross-section per band"),
                            ([b for b in ("red", "algorithm") if b in heights], "algorithm vs ground truth")):
        figure, axes = plt.subplots(figsize=(7, 4))
        axes.plot(distance, reference, "k--", label="ground truth")
        for name in chosen:
            axes.plot(distance, profile(heights[name])[1], color=_BAND_COLOURS[name], label=name, alpha=0.5 if name == "red" and len(chosen) == 2 else 1)
        axes.set(xlabel="distance across the wrinkle (mm)", ylabel="height (um)", title=f"{title}{caption}")
        axes.legend()
        figure.tight_layout()
        pictures.append(_png(figure))
    return pictures


def fractal_png(results):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(6, 4))
    for result in results:
        axes.plot(result.x, result.y, "o", label=f"{result.method}: D = {result.dimension:.3f}")
        axes.plot(result.x, result.slope * np.asarray(result.x) + result.intercept, "-", alpha=0.6)
    axes.set(xlabel="ln(scale) (method's own axis)", ylabel="ln(measure)", title="fractal dimension: log-log fits")
    axes.legend(fontsize=8)
    figure.tight_layout()
    return _png(figure)


def _table(headers, rows):
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in headers)
    body = "".join("<tr>" + "".join(f"<td>{_cell(v)}</td>" for v in row) + "</tr>" for row in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _cell(value):
    if value is None or (isinstance(value, float) and not np.isfinite(value)):
        return "<span class=missing>missing</span>"
    if isinstance(value, (float, np.floating)):
        return f"{value:.5g}"
    return html.escape(str(value))


_SCRIPT = """
const all = JSON.parse(document.getElementById('grid').textContent), grid = all;
function decode(part) {  // base64 little-endian float32 rows, NaN = missing
  const bytes = Uint8Array.from(atob(part.z), c => c.charCodeAt(0)), values = new Float32Array(bytes.buffer), [rows, cols] = part.shape;
  part.z = Array.from({length: rows}, (_, i) => Array.from(values.subarray(i * cols, (i + 1) * cols)));
}
decode(all); decode(all.mesh);
function finite(v) { return v !== null && Number.isFinite(v); }
// Cross-section viewer: one image column (a vertical line, across horizontal wrinkles) chosen with the slider.
const slider = document.getElementById('row'), profile = document.getElementById('profile');
function drawProfile() {
  const row = grid.z[+slider.value], ctx = profile.getContext('2d'), w = profile.width, h = profile.height;
  ctx.clearRect(0, 0, w, h);
  const vals = row.filter(finite), lo = Math.min(...vals), hi = Math.max(...vals);
  ctx.strokeStyle = '#7a3b12'; ctx.lineWidth = 1.5; ctx.beginPath(); let pen = false;
  row.forEach((v, i) => { if (!finite(v)) { pen = false; return; }
    const x = 40 + i * (w - 50) / (row.length - 1), y = h - 25 - (v - lo) / ((hi - lo) || 1) * (h - 40);
    if (pen) ctx.lineTo(x, y); else ctx.moveTo(x, y); pen = true; });
  ctx.stroke(); ctx.fillStyle = '#333';
  ctx.fillText((hi - lo).toFixed(1) + ' um range', 45, 12);
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
"""

_BASE_STYLE = """
body { font-family: sans-serif; margin: 2em; color: #222; max-width: 1100px; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; border-bottom: 1px solid #ccc; margin-top: 2em; }
table { border-collapse: collapse; margin: 0.5em 0; font-size: 0.9em; }
td, th { border: 1px solid #ccc; padding: 3px 8px; text-align: right; } th { background: #f3f3f3; }
td:first-child { text-align: left; } .missing { color: #999; font-style: italic; }
img { max-width: 100%; } .note { color: #555; font-size: 0.9em; }
@media (max-width: 600px) { body { margin: 0.5em; } }
"""
_STYLE = """
.pair { display: flex; gap: 1em; flex-wrap: wrap; } .pair img { max-width: 48%; }
canvas { border: 1px solid #ddd; max-width: 100%; }
"""


def _float32_base64(values):
    """A 2-D array as base64 of little-endian float32 (NaN = missing): a third of the size of
    the same numbers written as JSON text; the page's script decodes it."""
    return base64.b64encode(np.ascontiguousarray(values, dtype="<f4").tobytes()).decode("ascii")


def build_report(*, title, height, albedo=None, parameters=(), fractal_results=(), wrinkles=None, evaluations=None, settings=None,
                 cross_sections=()):
    """The report as one HTML string (see the module notes). ``parameters`` is a list of
    :class:`skintopo.texture.Parameter`; ``wrinkles`` a :class:`skintopo.wrinkles.WrinkleMeasures`;
    ``evaluations`` {height map name: evaluation dict} when ground truth exists, with
    ``cross_sections`` the PNGs of :func:`cross_section_pngs`; ``settings`` a dict of inputs
    and options, shown as given (escaped)."""
    sections = [f"<h1>{html.escape(title)}</h1>"]
    field_mm = (height.shape[1] * height.spacing[1] / 1000, height.shape[0] * height.spacing[0] / 1000)
    sections.append(f"<p class=note>Field {field_mm[0]:.2f} x {field_mm[1]:.2f} mm, {height.shape[1]} x {height.shape[0]} pixels of "
                    f"{height.spacing[1]:g} um; {100 * (1 - height.mask.mean()):.1f}% of the points missing (shown grey). "
                    "Heights in micrometres, positive toward the camera.</p>")
    images = [f"<img alt='shaded height map' src='data:image/png;base64,{shaded_height_png(height)}'>"]
    if albedo is not None:
        images.append(f"<img alt='albedo' src='data:image/png;base64,{image_png(albedo, 'albedo (relative)', height.spacing)}'>")
    sections.append("<h2>Surface</h2><div class=pair>" + "".join(images) + "</div>")

    z, step = _decimate(np.asarray(height.z, float), MESH_CELLS)
    profile_z, profile_step = _decimate(np.asarray(height.z, float), PROFILE_POINTS)
    finite_z = z[np.isfinite(z)]
    span = float(np.ptp(finite_z)) if finite_z.size else 1.0
    size = max(field_mm) * 1000
    grid = {  # profiles along image columns: "z" holds one row per column
        "z": _float32_base64(profile_z.T), "shape": profile_z.T.shape,
        "dx": height.spacing[1] * profile_step, "dy": height.spacing[0] * profile_step,
    }
    mesh = {"z": _float32_base64(z), "shape": z.shape, "dx": height.spacing[1] * step, "dy": height.spacing[0] * step}
    sections.append(
        "<h2>3-D view</h2><p class=note>Drag to turn. Heights exaggerated "
        f"{0.25 * size / max(span, 1e-9):.1f} x; downsampled for display only.</p>"
        "<canvas id=view3d width=700 height=500></canvas>"
        "<h2>Cross-section</h2><p class=note>Vertical profile (top to bottom) at x = <span id=rowlabel></span>; move the slider to choose it.</p>"
        "<input type=range id=row min=0 step=1 style='width:700px'><br><canvas id=profile width=700 height=220></canvas>"
    )
    if wrinkles is not None:
        rows = [[w.id, w.length_mm, w.orientation_deg, w.mean_depth_um, w.max_depth_um, w.mean_width_mm, w.cross_section_mm2, w.volume_mm3, w.severity]
                for w in wrinkles.wrinkles]
        totals = wrinkles.totals
        sections.append(
            "<h2>Wrinkles</h2>"
            f"<img alt='wrinkle overlay' src='data:image/png;base64,{wrinkle_overlay_png(height, wrinkles)}'>"
            + _table(["id", "length (mm)", "orientation (deg)", "mean depth (um)", "max depth (um)", "width at half depth (mm)",
                      "cross-section (mm2)", "volume (mm3)", "severity"], rows)
            + f"<p class=note>{totals['count']} wrinkle(s), total length {totals['total_length_mm']:.2f} mm, "
            f"wrinkle area {100 * totals['area_fraction']:.1f}% of the field. Depths against the local surrounding skin level; "
            "severity = mean depth x length / 100 (a ranking aid, not a clinical scale).</p>"
        )
    if parameters:
        sections.append("<h2>Surface texture (ISO 25178-2) and fractal dimension</h2>"
                        + _table(["parameter", "value", "unit", "standard / method"], [[p.name, p.value, p.unit, p.reference] for p in parameters]))
    if fractal_results:
        sections.append(f"<img alt='fractal log-log plot' src='data:image/png;base64,{fractal_png(fractal_results)}'>")
    if evaluations:
        names = list(evaluations)
        sections.append(
            "<h2>Against the ground truth (the paper's Tables 1 and 2)</h2>"
            + _table(["height map", "RMS height error (um)", "in wrinkles (um)", "L2 normal error", "mean angle (deg)"],
                     [[n, evaluations[n]["rms_height_error_um"], evaluations[n].get("rms_height_error_in_wrinkles_um"),
                       evaluations[n]["l2_normal_error"], evaluations[n]["mean_angular_error_deg"]] for n in names])
            + "".join(f"<img alt='cross-section' src='data:image/png;base64,{png}'>" for png in cross_sections)
        )
    if settings:
        sections.append("<h2>Inputs and settings</h2>" + _table(["setting", "value"], [[k, json.dumps(v, default=str)] for k, v in settings.items()]))
    payload = json.dumps(grid | {"mesh": mesh, "exaggeration": 0.25 * size / max(span, 1e-9), "size": size,
                                 "mid": float(np.median(finite_z)) if finite_z.size else 0.0})
    # JSON inside <script type=application/json>: escape '<' so no '</script>' can close it.
    payload = payload.replace("<", "\\u003c")
    return html_page(title, "".join(sections) + f"<script id=grid type='application/json'>{payload}</script>", style=_STYLE, script=_SCRIPT)


def html_page(title, body, *, style="", script=None):
    """One self-contained HTML page: a Content-Security-Policy that lets it load nothing
    from anywhere (images only as data: URIs, inline style and, when given, inline script),
    so a patient's report never contacts a server."""
    policy = "default-src 'none'; img-src data:; style-src 'unsafe-inline'" + ("; script-src 'unsafe-inline'" if script else "")
    return (
        "<!DOCTYPE html><html lang=en><head><meta charset=utf-8><meta name=viewport content='width=device-width, initial-scale=1'>"
        f"<meta http-equiv='Content-Security-Policy' content=\"{policy}\">"
        f"<title>{html.escape(title)}</title><style>{_BASE_STYLE}{style}</style></head><body>"
        + body + (f"<script>{script}</script>" if script else "") + "</body></html>"
    )
