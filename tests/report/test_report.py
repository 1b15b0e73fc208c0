"""The HTML report: self-contained, escaped user text, regions beside the field."""

import base64
import json
import re
from types import SimpleNamespace

import numpy as np

from skintopo.heightmap import HeightMap
from skintopo.pipeline import crop_region
from skintopo.report import build_report, copper, hillshade, wrinkle_overlay_picture, wrinkle_overlay_rgb
from skintopo.synth import make_surface, preset_spec
from skintopo.texture import measure_texture


def test_report_is_self_contained_and_escapes_user_text():
    z = make_surface(preset_spec("forehead-low", size_px=96), seed=1).height.z.copy()
    z[10:20, 10:20] = np.nan
    title = "<script>alert('x')</script> & patient"
    page = build_report(title=title, height=HeightMap(z, 20.0), settings={"note": "</script><b>bold</b>"})
    assert "<script>alert" not in page and "&lt;script&gt;alert" in page
    assert "</script><b>" not in page
    nested = build_report(title="t", height=HeightMap(z, 20.0), settings={"options": {"height": {"method": "physics", "kernels": None},
                                                                                    "regions": [["a", [0.0, 0.0, 5.5, 9.0]]]},
                                                                        "shape": [96, 96]})
    assert "<td>options &gt; height &gt; method</td><td>physics</td>" in nested
    assert "<td>options &gt; height &gt; kernels</td><td>none</td>" in nested and "<td>shape</td><td>96, 96</td>" in nested
    assert not re.search(r"(src|href)=['\"]?(https?:)?//", page)  # nothing loaded from anywhere
    assert "http://" not in page and "https://" not in page
    assert "default-src 'none'" in page
    grid = json.loads(re.search(r"<script id=grid type=.application/json.>(.*?)</script>", page, re.S).group(1))
    columns = np.frombuffer(base64.b64decode(grid["z"]), dtype="<f4").reshape(grid["shape"])
    assert np.isnan(columns[10:20, 10:20]).all() and np.isfinite(columns[30:, 30:]).all()  # missing points stay gaps, never zeros
    np.testing.assert_allclose(columns.T[40:50, 40:50], z[40:50, 40:50], rtol=1e-6)  # float32 of the heights


def test_report_shows_each_region_beside_the_field():
    """A map whose left half is a plane and right half rough: the region of the left half must
    show Sa = 0 (a plane after levelling), the field a rough surface's Sa."""
    z = np.random.default_rng(2).normal(scale=5.0, size=(64, 64))
    z[:, :32] = 0.2 * np.arange(64)[:, None]  # a tilted plane
    height = HeightMap(z, 10.0)
    box = (0.0, 0.0, 320.0, 640.0)  # x0, y0, x1, y1 in um: the left half
    region = measure_texture(crop_region(height, box, "left"))
    page = build_report(title="regions", height=height, parameters=measure_texture(height), regions={"left": (box, region)})
    rows = dict(re.findall(r"<tr><td>(Sa)</td><td>um</td>(.*?)</tr>", page))
    field, left, note = re.findall(r"<td>([^<]*)</td>", rows["Sa"])
    field, left = float(field), float(left)
    assert left < 1e-9 and field > 1.0 and note == ""
    assert "left = 0, 0, 320, 640" in page


def test_values_without_meaning_carry_their_reason_in_the_report():
    """A dimension outside [2, 3] and a missing Str are shown with why, in the field's table
    and, naming the region, in the regions' table."""
    from skintopo.texture import Parameter

    field = [Parameter("Sa", 1.0, "um", "ISO"), Parameter("Str", float("nan"), "", "ISO"), Parameter("D_power-spectrum", 1.7, "", "PSD")]
    corner = [Parameter("Sa", 2.0, "um", "ISO"), Parameter("Str", 0.5, "", "ISO"), Parameter("D_power-spectrum", 2.4, "", "PSD")]
    z = np.random.default_rng(0).normal(size=(32, 32))
    page = build_report(title="t", height=HeightMap(z, 10.0), parameters=field, regions={"corner": ((0, 0, 100, 100), corner)})
    assert page.count("outside [2, 3]") == 2 and "field: outside [2, 3]" in page
    assert "field: the autocorrelation does not fall to s = 0.2" in page
    assert "corner: outside" not in page


def test_colour_map_and_shading_match_matplotlib():
    """The maps are coloured and shaded with NumPy; matplotlib's copper map and
    LightSource.hillshade (azimuth 315, altitude 45) are the reference, on rectangular pixels."""
    import matplotlib
    from matplotlib.colors import LightSource

    t = np.linspace(0, 1, 1001)
    np.testing.assert_allclose(copper(t), matplotlib.colormaps["copper"](t)[:, :3], atol=1.5 / 255)  # matplotlib's 256-entry table
    z = make_surface(preset_spec("forehead-moderate", size_px=64), seed=2).height.z
    np.testing.assert_allclose(hillshade(z, (20.0, 12.5)), LightSource(azdeg=315, altdeg=45).hillshade(z, dx=12.5, dy=20.0), atol=1e-12)


def _pictures(page):
    """The report's inline PNG maps, decoded, in page order."""
    import imagecodecs

    return [imagecodecs.png_decode(base64.b64decode(data)) for data in re.findall(r'<img alt="[^"]*" src="data:image/png;base64,([^"]+)"', page)]


def test_height_map_picture_colours_heights_and_shows_missing_points():
    """The height map: the colour bar spans the finite heights; missing points are
    transparent grey, the rest opaque; the lowest point is copper's black whatever the light,
    and on a plane (flat shading, mid-grey after the stretch) the highest is copper's top end
    under the soft-light blend 2 l c + (1 - 2 l) c^2."""
    ramp = np.add.outer(np.linspace(0.0, 50.0, 40), np.zeros(60))  # a plane rising down the image
    z = ramp.copy()
    z[5:9, 10:20] = np.nan
    page = build_report(title="t", height=HeightMap(z, 10.0))
    assert re.search(r"<span>0</span><img alt=\"colour bar\"[^>]*><span>50</span></span> height \(um\)", page)
    image = _pictures(page)[0]
    assert image.shape == (40, 60, 4)
    assert (image[5:9, 10:20] == np.round(np.array([0.6, 0.6, 0.6, 0.3]) * 255)).all()
    assert (np.delete(image[..., 3], np.s_[5:9], axis=0) == 255).all()
    assert (image[0, 30, :3] == 0).all()
    plane = _pictures(build_report(title="t", height=HeightMap(ramp, 10.0)))[0]
    light, top = 0.5, copper(1.0)
    np.testing.assert_allclose(plane[-1, 30, :3] / 255, 2 * light * top + (1 - 2 * light) * top**2, atol=1 / 255)


def test_wrinkle_overlay_tints_each_wrinkle_and_labels_it_at_its_centroid():
    """Two wrinkles drawn as labels: each tinted with its own colour, its centre line red, and
    its id placed over the picture at its centroid (per cent of the field)."""
    z = np.zeros((50, 80))
    labels = np.zeros(z.shape, int)
    labels[10:14, 10:70] = 1
    labels[30:34, 20:60] = 2
    lines = np.zeros(z.shape, bool)
    lines[12, 10:70] = True
    wrinkles = [SimpleNamespace(id=1, centroid_x_mm=0.4, centroid_y_mm=0.12), SimpleNamespace(id=2, centroid_x_mm=0.4, centroid_y_mm=0.32)]
    measures = SimpleNamespace(labels=labels, lines=lines, wrinkles=wrinkles)
    rgb, step = wrinkle_overlay_rgb(HeightMap(z, 10.0), measures)
    assert step == 1 and rgb.shape == (50, 80, 3)
    np.testing.assert_allclose(rgb[12, 30], (1.0, 0.0, 0.0))
    blue, orange = np.array([31, 119, 180]) / 255, np.array([255, 127, 14]) / 255  # tab10's first two
    np.testing.assert_allclose(rgb[11, 30], 0.65 * 0.5 + 0.35 * blue)  # a flat map shades mid-grey
    np.testing.assert_allclose(rgb[31, 30], 0.65 * 0.5 + 0.35 * orange)
    np.testing.assert_allclose(rgb[40, 30], (0.5, 0.5, 0.5))
    picture = wrinkle_overlay_picture(HeightMap(z, 10.0), measures)
    np.testing.assert_allclose([label[:2] for label in picture["labels"]], [(50.0, 24.0), (50.0, 64.0)])  # of 0.8 x 0.5 mm
    assert [label[2] for label in picture["labels"]] == ["1", "2"]


def test_height_views_made_early_give_the_same_page_and_only_for_their_own_height():
    """The views `skintopo measure` makes while the wrinkles are measured are the ones the
    report makes itself; views of another height map are not used."""
    from skintopo.report import height_views

    z = make_surface(preset_spec("forehead-low", size_px=96), seed=2).height.z
    height, other = HeightMap(z, 20.0), HeightMap(z[::-1].copy(), 20.0)
    page = build_report(title="t", height=height)
    assert build_report(title="t", height=height, views=height_views(height)) == page
    assert build_report(title="t", height=height, views=height_views(other)) == page
    assert height_views(other).shaded_height["png"] not in page
