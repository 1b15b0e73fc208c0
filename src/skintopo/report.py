"""A self-contained HTML report a clinician can read.

One file, nothing loaded from anywhere (images are inline PNG data; the 3-D view, a lit
WebGL surface with axes, and the profile viewer are inline JavaScript), so it opens offline
and leaks nothing. Every user-provided string is HTML-escaped. Large maps are
downsampled for display only (at most ``DISPLAY_PIXELS`` a side for images, ``MESH_CELLS``
for the 3-D view); every number in the tables comes from the full-resolution data.
Missing points (NaN) are shown as missing (transparent grey), never as zeros.

The maps (height, albedo, wrinkles, pores, melanin, haemoglobin) are coloured with NumPy and encoded by libpng, their
extent, colour bar and wrinkle ids written in HTML; the fractal log-log plot is drawn by the
page's script from its points. matplotlib draws only true figures: the cross-sections
against a ground truth, the study's charts and the ``wrinkles`` command's picture file.
"""

from __future__ import annotations

import base64
import functools
import importlib.resources
import io
import json
from dataclasses import dataclass

import numpy as np
from markupsafe import Markup

DISPLAY_PIXELS = 600
MESH_CELLS = 200  # a side of the 3-D view's mesh (WebGL 1 indexes at most 65536 vertices)
PROFILE_POINTS = 400
REPORT_TEMPLATE = "report.html"  # in skintopo/templates, as the other pages
REPORT_TEMPLATE_PARTS = ("base.html", "macros.html")  # what it extends and imports (loaded when it is rendered)


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


def _decimation_step(shape, limit):
    """The step that leaves at most ``limit`` pixels along each side of an image of ``shape``."""
    return max(1, int(np.ceil(max(shape[:2]) / limit)))


def _decimate(array, limit):
    step = _decimation_step(array.shape, limit)
    return array[::step, ::step], step


# The report's maps are coloured and encoded here with NumPy and libpng (imagecodecs), their
# axes, colour bars and labels written in HTML: drawing them with matplotlib took about 2 s of
# a 5 s measure (its import, and 0.3 s a figure). Colour maps as matplotlib defines them
# (piecewise linear in each channel): copper, and tab10's colours for wrinkle labels.
_LABEL_COLOURS = np.array([(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75),
                           (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207)]) / 255.0
MISSING_RGBA = (0.6, 0.6, 0.6, 0.3)  # missing points: transparent grey


def copper(values):
    """matplotlib's "copper" colour map of values in [0, 1]: RGB in [0, 1], shape (..., 3)
    (red reaches 1 at 0.809524; green and blue rise linearly to 0.7812 and 0.4975)."""
    t = np.clip(values, 0.0, 1.0)
    return np.stack([np.minimum(1.0, t / 0.809524), 0.7812 * t, 0.4975 * t], axis=-1)


def hillshade(z, spacing):
    """Lambert shading of a height map lit from the upper left (azimuth 315 degrees, 45
    degrees above the surface), as matplotlib's ``LightSource.hillshade``: n . l with the
    normals of the heights in micrometres, contrast-stretched to [0, 1] over the map."""
    dz_drow, dz_dcolumn = np.gradient(np.asarray(z, float), *spacing)
    normal = np.stack([-dz_dcolumn, dz_drow, np.ones_like(dz_drow)])  # x right, y up (rows run down)
    light = np.array([-0.5, 0.5, np.sqrt(0.5)])  # toward the upper left (x < 0, y > 0), 45 degrees up
    intensity = np.tensordot(light, normal, axes=1) / np.linalg.norm(normal, axis=0)
    low, high = intensity.min(), intensity.max()
    return (intensity - low) / (high - low) if high - low > 1e-6 else np.full(intensity.shape, 0.5)


def _png(rgba):
    """RGB or RGBA in [0, 1] as base64 PNG (8 bits a channel) for a data: URI, compressed at
    zlib level 1 (a 600 x 600 height map: 8% larger than at the default level 6, 4x faster)."""
    import imagecodecs

    pixels = np.ascontiguousarray(np.round(np.clip(rgba, 0, 1) * 255), dtype=np.uint8)
    return base64.b64encode(imagecodecs.png_encode(pixels, level=1)).decode("ascii")


def _colour_bar(colour_map):
    """A horizontal colour bar (256 x 1 PNG, stretched by the page)."""
    return _png(colour_map(np.linspace(0.0, 1.0, 256))[None])


def _map_picture(alt, rgba, height, *, bar=None, labels=()):
    """What the report's ``map`` macro draws: the image, the field's extent in mm (the image's
    axes), an optional colour bar (base64 PNG, low, high, label) and text labels (x, y in
    per cent of the image from its top-left corner, text)."""
    rows, columns = height.shape
    return {"alt": alt, "png": _png(rgba), "width_mm": columns * height.spacing[1] / 1000, "height_mm": rows * height.spacing[0] / 1000,
            "bar": bar, "labels": list(labels)}


def _filled(z):
    missing = ~np.isfinite(z)
    return np.where(missing, np.nanmedian(z) if (~missing).any() else 0.0, z), missing


def _finite_range(values, missing):
    """The finite values' lowest and highest (0, 1 when there are none)."""
    return (float(np.min(values[~missing])), float(np.max(values[~missing]))) if (~missing).any() else (0.0, 1.0)


def _scaled(values, low, high):
    """``values`` mapped from [low, high] to [0, 1] (zeros when the range is empty)."""
    return np.clip((values - low) / (high - low), 0, 1) if high > low else np.zeros(np.shape(values))


def shaded_height_picture(height):
    """The height map: colour = height (copper, over the finite range), shading = slope
    (:func:`hillshade`, blended as soft light), missing points transparent grey."""
    z, step = _decimate(height.z, DISPLAY_PIXELS)
    filled, missing = _filled(z)
    low, high = _finite_range(z, missing)
    rgb = copper(_scaled(filled, low, high))
    light = hillshade(filled, (height.spacing[0] * step, height.spacing[1] * step))[..., None]
    rgba = np.concatenate([2 * light * rgb + (1 - 2 * light) * rgb**2, np.ones(z.shape + (1,))], axis=-1)  # soft light
    rgba[missing] = MISSING_RGBA
    return _map_picture("shaded height map", rgba, height, bar=(_colour_bar(copper), low, high, "height (um)"))


def greys(t):
    """Black to white."""
    return np.repeat(np.clip(np.asarray(t, float), 0, 1)[..., None], 3, axis=-1)


def reds(t):
    """White to dark red (haemoglobin): linear from (1, 1, 1) to (0.55, 0, 0)."""
    t = np.clip(np.asarray(t, float), 0, 1)[..., None]
    return (1 - t) * np.ones(3) + t * np.array([0.55, 0.0, 0.0])


def browns(t):
    """Light beige to dark brown (melanin): linear from (0.98, 0.94, 0.86) to (0.25, 0.12, 0.03)."""
    t = np.clip(np.asarray(t, float), 0, 1)[..., None]
    return (1 - t) * np.array([0.98, 0.94, 0.86]) + t * np.array([0.25, 0.12, 0.03])


def value_picture(values, height, alt, label, colour_map=greys):
    """A map of ``values`` (on the height's grid) coloured by ``colour_map`` over its finite
    range, missing points transparent grey, with its colour bar labelled ``label``."""
    values, _ = _decimate(np.asarray(values, float), DISPLAY_PIXELS)
    filled, missing = _filled(values)
    low, high = _finite_range(values, missing)
    rgba = np.concatenate([colour_map(_scaled(filled, low, high)), np.ones(values.shape + (1,))], axis=-1)
    rgba[missing] = MISSING_RGBA
    return _map_picture(alt, rgba, height, bar=(_colour_bar(colour_map), low, high, label))


def albedo_picture(albedo, height):
    """The albedo in grey levels over its finite range, missing points transparent grey."""
    return value_picture(albedo, height, "albedo", "albedo (relative)")


def grey_relief(height):
    """The grey shaded height that the overlays are drawn on, at display size: :func:`hillshade`
    of the height with its missing points at the median height, as RGB."""
    z, step = _decimate(_filled(np.where(height.mask, height.z, np.nan))[0], DISPLAY_PIXELS)
    return np.repeat(hillshade(z, (height.spacing[0] * step, height.spacing[1] * step))[..., None], 3, axis=-1)


def pore_overlay_picture(height, pores, relief=None):
    """The pores over the grey shaded height (``relief``: :func:`grey_relief` of it, when
    already made): each pore's opening tinted cyan (50%)."""
    rgb = grey_relief(height) if relief is None else relief.copy()
    inside = _decimate(pores.labels, DISPLAY_PIXELS)[0] > 0
    rgb[inside] = 0.5 * rgb[inside] + 0.5 * np.array([0.0, 0.85, 0.95])
    return _map_picture(f"{len(pores.pores)} pore(s)", rgb, height)


def wrinkle_overlay_rgb(height, measures, relief=None):
    """The wrinkles over the grey shaded height (``relief``: :func:`grey_relief` of it, when
    already made), at display size: each wrinkle's half-depth region tinted in its colour
    (35%), its centre line in red. Returns (RGB, step)."""
    rgb = grey_relief(height) if relief is None else relief.copy()
    step = _decimation_step(height.shape, DISPLAY_PIXELS)
    labels = _decimate(measures.labels, DISPLAY_PIXELS)[0]
    inside = labels > 0
    rgb[inside] = 0.65 * rgb[inside] + 0.35 * _LABEL_COLOURS[(labels[inside] - 1) % len(_LABEL_COLOURS)]
    lines = _thicken(measures.lines) if max(height.shape) > DISPLAY_PIXELS else measures.lines
    rgb[_decimate(lines, DISPLAY_PIXELS)[0]] = (1.0, 0.0, 0.0)
    return rgb, step


def wrinkle_overlay_picture(height, measures, relief=None):
    """:func:`wrinkle_overlay_rgb` with each wrinkle's id at its centroid."""
    rgb, _ = wrinkle_overlay_rgb(height, measures, relief)
    rows, columns = height.shape
    field = (columns * height.spacing[1] / 1000, rows * height.spacing[0] / 1000)
    labels = [(100 * w.centroid_x_mm / field[0], 100 * w.centroid_y_mm / field[1], str(w.id)) for w in measures.wrinkles]
    return _map_picture(f"{len(measures.wrinkles)} wrinkle(s)", rgb, height, labels=labels)


def wrinkle_overlay_png(height, measures):
    """:func:`wrinkle_overlay_rgb` as a figure with axes in mm and each wrinkle's id (the
    ``wrinkles`` command's picture file)."""
    plt = pyplot()
    rgb, _ = wrinkle_overlay_rgb(height, measures)
    rows, columns = height.shape
    figure, axes = plt.subplots(figsize=(8, 8 * rows / columns))
    axes.imshow(rgb, extent=(0, columns * height.spacing[1] / 1000, rows * height.spacing[0] / 1000, 0), interpolation="nearest")
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


def fractal_plot_data(results):
    """Each estimator's log-log points and fitted line, drawn by the page's script (as the
    profile viewer is)."""
    from skintopo.texture import finite_or_none

    return [{"method": r.method, "dimension": finite_or_none(r.dimension), "x": [float(v) for v in r.x], "y": [float(v) for v in r.y],
             "slope": float(r.slope), "intercept": float(r.intercept)} for r in results]


def _float32_base64(values):
    """A 2-D array as base64 of little-endian float32 (NaN = missing): a third of the size of
    the same numbers written as JSON text; the page's script decodes it."""
    return base64.b64encode(np.ascontiguousarray(values, dtype="<f4").tobytes()).decode("ascii")


@dataclass(frozen=True)
class HeightViews:
    """The parts of the report that need the height map alone (:func:`height_views`):
    ``shaded_height`` (:func:`shaded_height_picture`), ``relief`` (:func:`grey_relief`, what
    the wrinkle and pore overlays are drawn on) and ``viewer``, the 3-D view's mesh and the
    profile viewer's grid (float32 base64), the 3-D view's height exaggeration and the median
    height."""

    height: object
    shaded_height: dict
    relief: np.ndarray
    viewer: dict


def height_views(height) -> HeightViews:
    """The :class:`HeightViews` of ``height``; the page template and its parts are loaded and
    compiled here too (jinja2 keeps them), so that a caller who makes the views while other work runs (``skintopo
    measure`` does, while the wrinkles are measured: :func:`skintopo.pipeline.measure_height`)
    leaves :func:`build_report` only what needs the measures."""
    for template in (REPORT_TEMPLATE, *REPORT_TEMPLATE_PARTS):
        _environment().get_template(template)
    z, step = _decimate(np.asarray(height.z, float), MESH_CELLS)
    profile_z, profile_step = _decimate(np.asarray(height.z, float), PROFILE_POINTS)
    finite_z = z[np.isfinite(z)]
    span = float(np.ptp(finite_z)) if finite_z.size else 1.0
    size = max(height.shape[1] * height.spacing[1], height.shape[0] * height.spacing[0])
    viewer = {  # profiles along image columns: "z" holds one row per column
        "z": _float32_base64(profile_z.T), "shape": profile_z.T.shape,
        "dx": height.spacing[1] * profile_step, "dy": height.spacing[0] * profile_step,
        "mesh": {"z": _float32_base64(z), "shape": z.shape, "dx": height.spacing[1] * step, "dy": height.spacing[0] * step},
        "exaggeration": 0.25 * size / max(span, 1e-9), "mid": float(np.median(finite_z)) if finite_z.size else 0.0,
    }
    return HeightViews(height, shaded_height_picture(height), grey_relief(height), viewer)


def build_report(*, title, height, albedo=None, parameters=(), regions=None, fractal_results=(), wrinkles=None, evaluations=None,
                 settings=None, cross_sections=(), pores=None, chromophores=None, chromophore_statistics=None, views=None):
    """The report as one HTML string (see the module notes). ``parameters`` is a list of
    :class:`skintopo.texture.Parameter` (the whole field); ``regions`` {name: (box in um
    x0, y0, x1, y1, its list of Parameter)} for the extra regions; ``wrinkles`` a :class:`skintopo.wrinkles.WrinkleMeasures`;
    ``evaluations`` {height map name: evaluation dict} when ground truth exists, with
    ``cross_sections`` the PNGs of :func:`cross_section_pngs`; ``settings`` a dict of inputs
    and options, shown as given (escaped); ``pores`` a :class:`skintopo.pores.PoreMeasures`;
    ``chromophores`` a :class:`skintopo.chromophores.ChromophoreMaps` with its
    ``chromophore_statistics`` per region; ``views``: :func:`height_views` of ``height`` when
    already made (made here otherwise)."""
    from skintopo.texture import parameter_note

    views = views if views is not None and views.height is height else height_views(height)
    field_mm = (height.shape[1] * height.spacing[1] / 1000, height.shape[0] * height.spacing[0] / 1000)
    surface_images = [views.shaded_height]
    if albedo is not None:
        surface_images.append(albedo_picture(albedo, height))
    exaggeration = views.viewer["exaggeration"]
    payload = json.dumps(views.viewer | {"fractal": fractal_plot_data(fractal_results)})
    context = {
        "title": title, "field_mm": field_mm, "shape": height.shape, "pixel_um": height.spacing[1],
        "missing_percent": 100 * (1 - height.mask.mean()), "surface_images": surface_images, "exaggeration": exaggeration,
        "wrinkles": wrinkles.totals if wrinkles is not None else None,
        "wrinkle_overlay": wrinkle_overlay_picture(height, wrinkles, views.relief) if wrinkles is not None else None,
        "wrinkle_rows": [[w.id, w.length_mm, w.orientation_deg, w.mean_depth_um, w.max_depth_um, w.mean_width_mm, w.cross_section_mm2,
                          w.volume_mm3, w.severity] for w in (wrinkles.wrinkles if wrinkles is not None else ())],
        "parameter_rows": [[p.name, p.value, p.unit, p.reference, parameter_note(p)] for p in parameters],
        "regions": [(name, box) for name, (box, _) in (regions or {}).items()],
        "region_rows": _region_rows(parameters, regions),
        "fractal_plot": bool(fractal_results),
        "evaluation_rows": [[n, e["rms_height_error_um"], e.get("rms_height_error_in_wrinkles_um"), e["l2_normal_error"],
                             e["mean_angular_error_deg"]] for n, e in (evaluations or {}).items()],
        "cross_sections": cross_sections,
        "pores": pores.totals if pores is not None else None,
        "pore_edge_um": pores.parameters["edge_um"] if pores is not None else None,
        "pore_overlay": pore_overlay_picture(height, pores, views.relief) if pores is not None else None,
        "pore_rows": [[p.id, p.diameter_um, p.area_mm2, p.depth_um, p.mean_depth_um, p.volume_mm3, p.roundness]
                      for p in (pores.pores if pores is not None else ())],
        "colour_maps": [value_picture(chromophores.melanin, height, "melanin index", "melanin (OD at 523 nm)", browns),
                        value_picture(chromophores.haemoglobin, height, "haemoglobin index", "haemoglobin (OD at 523 nm)", reds)]
        if chromophores is not None else None,
        "colour": {"reflectance": chromophores.reflectance, "smoothing_um": chromophores.smoothing_um} if chromophores is not None else None,
        "colour_rows": [[region, name, s["mean"], s["standard_deviation"], s["relative_variation"]]
                        for region, maps in (chromophore_statistics or {}).items() for name, s in maps.items()],
        "settings_rows": _setting_rows(settings or {}),
        # JSON inside <script type=application/json> is raw text: escape '<' so no '</script>' can close it.
        "payload": Markup(payload.replace("<", "\\u003c")),
    }
    return render_page(REPORT_TEMPLATE, context, style="report.css", script="report.js")


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
