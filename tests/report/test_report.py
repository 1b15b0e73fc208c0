"""The HTML report: self-contained, escaped user text, regions beside the field."""

import base64
import json
import re

import numpy as np

from skintopo.heightmap import HeightMap
from skintopo.pipeline import crop_region
from skintopo.report import build_report
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
