"""The measure command's outputs and the HTML report, opened in headless Chromium."""

import base64
import json
import re
import shutil
import subprocess

import numpy as np
import pytest

from skintopo.cli import main
from skintopo.heightmap import HeightMap
from skintopo.pipeline import crop_region
from skintopo.report import build_report
from skintopo.texture import measure_texture
from skintopo.synth import make_surface, preset_spec

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


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
    field, left = (float(v) for v in re.findall(r"<td>([^<]*)</td>", rows["Sa"]))
    assert left < 1e-9 and field > 1.0
    assert "left = 0, 0, 320, 640" in page


@pytest.mark.slow
def test_measure_acquisition_writes_everything_and_the_report_renders(tmp_path):
    acquisition = tmp_path / "acq"
    assert main(["synth", "-o", str(acquisition), "--preset", "forehead-moderate", "--size", "160", "-q"]) == 0
    out = tmp_path / "out"
    assert main(["measure", str(acquisition), "-o", str(out), "-q", "--region", "centre=800,800,2400,2400"]) == 0
    for name in ("parameters.json", "parameters.csv", "wrinkles.json", "wrinkles.csv", "height.x3p", "summary.json", "report.html"):
        assert (out / name).exists(), name
    summary = json.loads((out / "summary.json").read_text())
    assert summary["source"]["height"] == "spectral correction (paper)"
    centre_sa = next(p["value"] for p in json.loads((out / "parameters.json").read_text())["parameters"]
                     if p["region"] == "centre" and p["name"] == "Sa")
    page = (out / "report.html").read_text()
    assert "<h2>Regions</h2>" in page and "centre = 800, 800, 2400, 2400" in page and f"{centre_sa:.5g}" in page
    if CHROMIUM is None:
        pytest.skip("no chromium on this machine (Debian package 'chromium'): report not rendered")
    screenshot = tmp_path / "shot.png"
    run = subprocess.run(
        [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync", "--enable-logging=stderr", "--v=0",
         f"--user-data-dir={tmp_path / 'profile'}", f"--screenshot={screenshot}", "--window-size=1100,1900",
         (out / "report.html").as_uri()],
        capture_output=True, text=True, timeout=120,
    )
    assert "Uncaught" not in run.stderr  # no JavaScript error in the console
    from skintopo.formats import read_png

    image = read_png(screenshot)[..., :3]
    # The 3-D canvas sits below the two surface images: its area must not be blank.
    band = image[int(0.42 * image.shape[0]) : int(0.62 * image.shape[0]), 40:700]
    assert band.std() > 20 and len(np.unique(band.reshape(-1, 3), axis=0)) > 200
    # On a phone (390 px) nothing is cut off: wide tables scroll inside their box, so the last
    # columns of the whole page are background only.
    phone = tmp_path / "phone.png"
    subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--no-first-run",
                    "--disable-background-networking", "--disable-component-update", "--disable-sync",
                    f"--user-data-dir={tmp_path / 'profile'}", f"--screenshot={phone}", "--window-size=390,6000",
                    (out / "report.html").as_uri()], capture_output=True, text=True, timeout=120)
    assert (read_png(phone)[..., :3][:, -6:] >= 250).all(), "the report reaches the right edge at 390 px"


def test_demo_command_runs_at_a_small_size(tmp_path, capsys):
    assert main(["demo", "-o", str(tmp_path / "demo"), "--size", "128"]) == 0
    printed = capsys.readouterr().out
    assert "algorithm" in printed and "report:" in printed
    assert (tmp_path / "demo" / "result" / "report.html").stat().st_size > 50_000
    summary = json.loads((tmp_path / "demo" / "summary.json").read_text())
    assert set(summary["evaluation"]) == {"red", "green", "blue", "white", "algorithm"}


def test_invalid_acquisition_stops_before_any_output(tmp_path, capsys):
    (tmp_path / "acq").mkdir()
    (tmp_path / "acq" / "acquisition.json").write_text("{}")
    assert main(["measure", str(tmp_path / "acq"), "-o", str(tmp_path / "out")]) == 2
    assert "acquisition.json" in capsys.readouterr().err and not (tmp_path / "out").exists()
