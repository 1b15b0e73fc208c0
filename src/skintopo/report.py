"""A self-contained HTML report a clinician can read.

One file, nothing loaded from anywhere (images are inline PNG data; the 3-D view, a lit
WebGL surface with axes, and the profile viewer are inline JavaScript), so it opens offline
and leaks nothing. Every user-provided string is HTML-escaped. Large maps are
downsampled for display only (at most ``DISPLAY_PIXELS`` a side for images, ``MESH_CELLS``
for the 3-D view); every number in the tables comes from the full-resolution data.
Missing points (NaN) are shown as missing (transparent grey), never as zeros.
"""

from __future__ import annotations

import base64
import functools
import importlib.resources
import io
import json

import numpy as np
from markupsafe import Markup

DISPLAY_PIXELS = 600
MESH_CELLS = 200  # a side of the 3-D view's mesh (WebGL 1 indexes at most 65536 vertices)
PROFILE_POINTS = 400


@functools.cache
def pyplot():
    """matplotlib.pyplot on the file-only Agg backend (set once; figures are never shown)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot

    return matplotlib.pyplot


def figure_png(figure, dpi=100):
    """A matplotlib figure as base64 PNG (for a data: URI); the figure is closed."""
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=dpi)
    pyplot().close(figure)
    return base64.b64encode(buffer.getvalue()).decode("ascii")


def _decimate(array, limit):
    step = max(1, int(np.ceil(max(array.shape[:2]) / limit)))
    return array[::step, ::step], step


def shaded_height_png(height, title="height"):
    plt = pyplot()
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
    # the colour is the height (copper map over the finite range), the shading the slope
    levels = plt.cm.ScalarMappable(plt.Normalize(*(np.nanmin(z), np.nanmax(z)) if (~missing).any() else (0, 1)), plt.get_cmap("copper"))
    figure.colorbar(levels, ax=axes, shrink=0.8, label="height (um)")
    axes.set(xlabel="x (mm)", ylabel="y (mm)", title=title)
    figure.tight_layout()
    return figure_png(figure)


def image_png(values, title, spacing, cmap="gray"):
    plt = pyplot()

    data, _ = _decimate(np.asarray(values, float), DISPLAY_PIXELS)
    rows, columns = np.asarray(values).shape
    figure, axes = plt.subplots(figsize=(6, 6 * rows / columns))
    shown = axes.imshow(np.ma.masked_invalid(data), cmap=cmap, extent=(0, columns * spacing[1] / 1000, rows * spacing[0] / 1000, 0))
    figure.colorbar(shown, ax=axes, shrink=0.8)
    axes.set(xlabel="x (mm)", ylabel="y (mm)", title=title)
    figure.tight_layout()
    return figure_png(figure)


def wrinkle_overlay_png(height, measures):
    """Shaded height with the wrinkles' half-depth regions, centre lines and ids."""
    plt = pyplot()
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
    return figure_png(figure)


def _thicken(mask):
    """Centre lines two pixels wider each side, so they survive downsampling for display."""
    import scipy.ndimage

    return scipy.ndimage.binary_dilation(mask, iterations=2)


_BAND_COLOURS = {"red": "tab:red", "green": "tab:green", "blue": "tab:blue", "white": "0.4", "algorithm": "tab:purple"}


def cross_section_pngs(heights, truth, wrinkle_labels, *, title=""):
    """The paper's Figures 3 and 5: a cross-section across the deepest true wrinkle, per band
    against the ground truth, and the algorithm (with red) against it. Returns two base64 PNGs."""
    plt = pyplot()

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
        pictures.append(figure_png(figure))
    return pictures


def fractal_png(results):
    plt = pyplot()

    figure, axes = plt.subplots(figsize=(6, 4))
    for result in results:
        axes.plot(result.x, result.y, "o", label=f"{result.method}: D = {result.dimension:.3f}")
        axes.plot(result.x, result.slope * np.asarray(result.x) + result.intercept, "-", alpha=0.6)
    axes.set(xlabel="ln(scale) (method's own axis)", ylabel="ln(measure)", title="fractal dimension: log-log fits")
    axes.legend(fontsize=8)
    figure.tight_layout()
    return figure_png(figure)





def _float32_base64(values):
    """A 2-D array as base64 of little-endian float32 (NaN = missing): a third of the size of
    the same numbers written as JSON text; the page's script decodes it."""
    return base64.b64encode(np.ascontiguousarray(values, dtype="<f4").tobytes()).decode("ascii")


def build_report(*, title, height, albedo=None, parameters=(), regions=None, fractal_results=(), wrinkles=None, evaluations=None,
                 settings=None, cross_sections=()):
    """The report as one HTML string (see the module notes). ``parameters`` is a list of
    :class:`skintopo.texture.Parameter` (the whole field); ``regions`` {name: (box in um
    x0, y0, x1, y1, its list of Parameter)} for the extra regions; ``wrinkles`` a :class:`skintopo.wrinkles.WrinkleMeasures`;
    ``evaluations`` {height map name: evaluation dict} when ground truth exists, with
    ``cross_sections`` the PNGs of :func:`cross_section_pngs`; ``settings`` a dict of inputs
    and options, shown as given (escaped)."""
    from skintopo.texture import parameter_note

    field_mm = (height.shape[1] * height.spacing[1] / 1000, height.shape[0] * height.spacing[0] / 1000)
    surface_images = [("shaded height map", shaded_height_png(height))]
    if albedo is not None:
        surface_images.append(("albedo", image_png(albedo, "albedo (relative)", height.spacing)))
    z, step = _decimate(np.asarray(height.z, float), MESH_CELLS)
    profile_z, profile_step = _decimate(np.asarray(height.z, float), PROFILE_POINTS)
    finite_z = z[np.isfinite(z)]
    span = float(np.ptp(finite_z)) if finite_z.size else 1.0
    size = max(field_mm) * 1000
    exaggeration = 0.25 * size / max(span, 1e-9)
    grid = {  # profiles along image columns: "z" holds one row per column
        "z": _float32_base64(profile_z.T), "shape": profile_z.T.shape,
        "dx": height.spacing[1] * profile_step, "dy": height.spacing[0] * profile_step,
    }
    mesh = {"z": _float32_base64(z), "shape": z.shape, "dx": height.spacing[1] * step, "dy": height.spacing[0] * step}
    payload = json.dumps(grid | {"mesh": mesh, "exaggeration": exaggeration,
                                 "mid": float(np.median(finite_z)) if finite_z.size else 0.0})
    context = {
        "title": title, "field_mm": field_mm, "shape": height.shape, "pixel_um": height.spacing[1],
        "missing_percent": 100 * (1 - height.mask.mean()), "surface_images": surface_images, "exaggeration": exaggeration,
        "wrinkles": wrinkles.totals if wrinkles is not None else None,
        "wrinkle_overlay": wrinkle_overlay_png(height, wrinkles) if wrinkles is not None else None,
        "wrinkle_rows": [[w.id, w.length_mm, w.orientation_deg, w.mean_depth_um, w.max_depth_um, w.mean_width_mm, w.cross_section_mm2,
                          w.volume_mm3, w.severity] for w in (wrinkles.wrinkles if wrinkles is not None else ())],
        "parameter_rows": [[p.name, p.value, p.unit, p.reference, parameter_note(p)] for p in parameters],
        "regions": [(name, box) for name, (box, _) in (regions or {}).items()],
        "region_rows": _region_rows(parameters, regions),
        "fractal_plot": fractal_png(fractal_results) if fractal_results else None,
        "evaluation_rows": [[n, e["rms_height_error_um"], e.get("rms_height_error_in_wrinkles_um"), e["l2_normal_error"],
                             e["mean_angular_error_deg"]] for n, e in (evaluations or {}).items()],
        "cross_sections": cross_sections,
        "settings_rows": _setting_rows(settings or {}),
        # JSON inside <script type=application/json> is raw text: escape '<' so no '</script>' can close it.
        "payload": Markup(payload.replace("<", "\\u003c")),
    }
    return render_page("report.html", context, style="report.css", script="report.js")


def _setting_rows(settings, prefix=""):
    """Nested settings as readable rows: ("options > height > method", "physics"); a list of
    plain values joined by commas, anything deeper as JSON."""
    rows = []
    for key, value in settings.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict) and value:
            rows += _setting_rows(value, f"{name} > ")
        elif isinstance(value, (list, tuple)) and all(isinstance(v, (int, float, str)) for v in value):
            rows.append([name, ", ".join(f"{v:g}" if isinstance(v, float) else str(v) for v in value)])
        elif isinstance(value, (list, tuple, dict)):
            rows.append([name, json.dumps(value, default=str)])
        else:
            rows.append([name, "none" if value is None else value])
    return rows


def _region_rows(parameters, regions):
    """One row per field parameter: name, unit, field value, each region's value, and the
    note of any value without one or out of range (:func:`skintopo.texture.parameter_note`),
    naming where it applies."""
    from skintopo.texture import parameter_note

    if not regions:
        return []
    names = ["field", *regions]
    by_region = [{p.name: p for p in parameters}] + [{p.name: p for p in region} for _, region in regions.values()]
    rows = []
    for p in parameters:
        found = [values.get(p.name) for values in by_region]  # None where a region lacks the parameter
        notes = {}
        for where, parameter in zip(names, found):
            note = parameter_note(parameter) if parameter is not None else ""
            if note:
                notes.setdefault(note, []).append(where)
        rows.append([p.name, p.unit, *(None if q is None else q.value for q in found),
                     "; ".join(f"{', '.join(where)}: {note}" for note, where in notes.items())])
    return rows


@functools.cache
def _environment():
    """The page templates (``skintopo/templates``), autoescaped."""
    import jinja2

    environment = jinja2.Environment(loader=jinja2.PackageLoader("skintopo", "templates"), autoescape=True,
                                     undefined=jinja2.StrictUndefined, trim_blocks=True, lstrip_blocks=True)
    environment.filters["cell"] = _cell
    return environment


def _cell(value):
    """A table cell: numbers to 5 significant digits, missing values marked as such."""
    if value is None or (isinstance(value, float) and not np.isfinite(value)):
        return Markup("<span class=missing>missing</span>")
    if isinstance(value, (float, np.floating)):
        return f"{value:.5g}"
    return str(value)


def _resource(name):
    return Markup(importlib.resources.files("skintopo").joinpath("templates", name).read_text(encoding="utf-8"))


def render_page(template, context, *, style=None, script=None):
    """One self-contained HTML page from ``template`` (which extends ``base.html``: the
    security header that lets the page load nothing from anywhere), with the shared style,
    the page's own style and script files from the same folder."""
    return _environment().get_template(template).render(
        base_style=_resource("base.css"), style=_resource(style) if style else "", script=_resource(script) if script else None, **context)
