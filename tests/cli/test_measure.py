"""``skintopo measure``: outputs, the report opened in headless Chromium, refused inputs, and a device acquisition measured."""

import json

import numpy as np
import pytest

from skintopo.cli import main
from skintopo.filters import polynomial_form
from skintopo.heightmap import HeightMap
from tests.helpers import browser
from tests.helpers.analytic import fbm


def _after_form(height, truth):
    error = height.z - truth.z
    valid = np.isfinite(error)
    form = polynomial_form(np.where(valid, error, 0.0), truth.spacing, order=2, mask=valid)
    return float(np.sqrt(np.mean((error - form)[valid] ** 2)))


def test_device_acquisition_from_synth_to_measure(tmp_path):
    """``synth --device paper`` writes device.json and images that name their LED; ``measure``
    reconstructs it with near-field photometric stereo on the skin-plane grid: the red band's
    height against the ground truth within 30 um RMS after form removal (diffuse skin at 254 um
    pixels: 4.3 um measured). Bad device manifests are refused with the file and the reason."""
    import subprocess
    import sys

    from skintopo.heightmap import HeightMap

    run = [sys.executable, "-m", "skintopo.cli"]
    acquisition = tmp_path / "acq"
    subprocess.run([*run, "synth", "--device", "paper", "--size", "256", "--no-interreflection", "--no-specular", "--no-translucency",
                    "-o", str(acquisition), "-q"], check=True)
    manifest = json.loads((acquisition / "acquisition.json").read_text())
    assert manifest["device"] == "device.json" and {e["led"] for e in manifest["images"]} == {"east", "north", "west", "south"}
    done = subprocess.run([*run, "measure", str(acquisition), "--method", "red", "-o", str(tmp_path / "out"), "-q"],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    measured, truth = HeightMap.load(tmp_path / "out" / "height.x3p"), HeightMap.load(acquisition / "ground_truth" / "height.x3p")
    assert measured.shape == truth.shape and measured.spacing == pytest.approx(truth.spacing)
    # measure levels the map (a plane): compare after removing a quadratic form from the difference
    assert _after_form(measured, truth) < 30.0
    # the physics height runs through the device too (its accuracy: tests/physics), on the same grid
    assert main(["correct", str(acquisition), "--method", "physics", "-o", str(tmp_path / "physics"), "-q"]) == 0
    assert json.loads((tmp_path / "physics" / "physics.json").read_text())["components"]["lights"] == "device"
    assert json.loads((tmp_path / "physics" / "summary.json").read_text())["height"].endswith("near-field LEDs)")
    assert HeightMap.load(tmp_path / "physics" / "height.x3p").shape == truth.shape

    def refused(change, message):
        broken = json.loads(json.dumps(manifest))
        change(broken)
        (acquisition / "acquisition.json").write_text(json.dumps(broken))
        done = subprocess.run([*run, "measure", str(acquisition), "-o", str(tmp_path / "bad"), "-q"], capture_output=True, text=True)
        assert done.returncode != 0 and message in done.stderr and not (tmp_path / "bad").exists(), done.stderr

    refused(lambda m: m["images"][0].update(led="up"), "field 'led' must name one of the device's LEDs")
    refused(lambda m: m["images"][0].update(light=[0, 0, 1]), "name the image's LED ('led'), not a light direction")
    refused(lambda m: m.update(pixel_size_um=20.0), "the device's pixel footprint")
    refused(lambda m: m["images"][1].update(led="east"), "each LED may have one image per band")
    device = json.loads((acquisition / "device.json").read_text())
    device["camera"]["focal_length_mm"] = -1
    (acquisition / "device.json").write_text(json.dumps(device))
    refused(lambda m: None, "focal_length_mm must be a positive number")


@pytest.mark.slow
def test_measure_acquisition_writes_everything_and_the_report_renders(tmp_path):
    acquisition = tmp_path / "acq"
    assert main(["synth", "-o", str(acquisition), "--preset", "forehead-moderate", "--size", "160", "-q"]) == 0
    out = tmp_path / "out"
    assert main(["measure", str(acquisition), "-o", str(out), "-q", "--region", "centre=800,800,2400,2400"]) == 0
    for name in ("parameters.json", "parameters.csv", "wrinkles.json", "wrinkles.csv", "height.x3p", "summary.json", "report.html",
                 "pores.json", "pores.csv", "pores.png", "chromophores.json", "melanin.npy", "haemoglobin.npy"):
        assert (out / name).exists(), name
    summary = json.loads((out / "summary.json").read_text())
    assert summary["source"]["height"] == "spectral correction (paper)"
    # no white reference: relative reflectance, said in the summary and the report; the region has its own statistics
    assert summary["source"]["chromophores"] == "melanin and haemoglobin indices (relative reflectance)"
    melanin = np.load(out / "melanin.npy")
    assert summary["chromophores"]["field"]["melanin"]["mean"] == pytest.approx(float(np.nanmean(melanin)), rel=1e-6)
    assert summary["chromophores"]["centre"]["melanin"]["pixels"] == 80 * 80
    assert summary["pore_totals"]["count"] == len(json.loads((out / "pores.json").read_text())["pores"])
    centre_sa = next(p["value"] for p in json.loads((out / "parameters.json").read_text())["parameters"]
                     if p["region"] == "centre" and p["name"] == "Sa")
    page = (out / "report.html").read_text()
    assert "<h2>Regions</h2>" in page and "centre = 800, 800, 2400, 2400" in page and f"{centre_sa:.5g}" in page
    assert "<h2>Pores</h2>" in page and "Colour: melanin and haemoglobin" in page and "Reflectance relative" in page
    if browser.CHROMIUM is None:
        pytest.skip("no chromium on this machine (Debian package 'chromium'): report not rendered")
    screenshot = tmp_path / "shot.png"
    stderr = browser.screenshot(out / "report.html", screenshot, 1400, 1900, tmp_path / "profile")
    assert "Uncaught" not in stderr  # no JavaScript error in the console
    from skintopo.formats import read_png

    image = read_png(screenshot)[..., :3]
    # The 3-D view sits below the two surface images: lit (many shades), not blank.
    band = image[int(0.40 * image.shape[0]) : int(0.70 * image.shape[0]), 40:740]
    assert band.std() > 20 and len(np.unique(band.reshape(-1, 3), axis=0)) > 200
    # On a phone (390 px) nothing is cut off: wide tables scroll inside their box, so the last
    # columns of the whole page are background only.
    phone = tmp_path / "phone.png"
    browser.screenshot(out / "report.html", phone, 390, 6000, tmp_path / "profile")
    assert (read_png(phone)[..., :3][:, -6:] >= 250).all(), "the report reaches the right edge at 390 px"
    # The 3-D view is WebGL, lit, and answers the mouse, the wheel, two fingers and one finger;
    # Reset view returns exactly to the start.
    probe = browser.probe_3d_view(out / "report.html", tmp_path)
    assert probe["webgl"], "no WebGL in headless Chromium"
    start = probe["start"]
    assert start["covered"] > 0.2 and start["spread"] > 15  # the surface fills the view and its shading varies
    assert probe["drag"]["yaw"] != start["yaw"] and probe["drag"]["checksum"] != start["checksum"]
    assert probe["wheel"]["distance"] < 0.8 * start["distance"] and probe["wheel"]["covered"] > start["covered"]
    assert probe["pinch"]["distance"] < 0.5 * probe["wheel"]["distance"]  # fingers spread 40 -> 120 px: 3 x closer
    assert probe["swipe"]["yaw"] != probe["pinch"]["yaw"] and probe["swipe"]["pitch"] != probe["pinch"]["pitch"]
    assert probe["reset"] == start


def test_invalid_acquisition_stops_before_any_output(tmp_path, capsys):
    (tmp_path / "acq").mkdir()
    (tmp_path / "acq" / "acquisition.json").write_text("{}")
    assert main(["measure", str(tmp_path / "acq"), "-o", str(tmp_path / "out")]) == 2
    assert "acquisition.json" in capsys.readouterr().err and not (tmp_path / "out").exists()


@pytest.mark.parametrize("command", ["measure", "correct", "reconstruct"])
def test_a_field_larger_than_memory_is_refused_naming_the_size_needed(tmp_path, capsys, monkeypatch, command):
    """With 1 GiB available, a 96 x 96 field (16 images) fits, and with 10 MiB it does not:
    the command stops before reading the other images and writes nothing, and the message
    names the field, the memory needed (0.3 GiB baseline + pixels x (4 bytes x 16 images +
    the command's figure)) and the memory available."""
    from skintopo.pipeline import PROCESSING_BYTES_PER_PIXEL

    acquisition = tmp_path / "acq"
    assert main(["synth", "-o", str(acquisition), "--size", "96", "--no-interreflection", "-q"]) == 0
    monkeypatch.setattr("skintopo.acquisition.images.available_memory", lambda: 2**30)
    assert main([command, str(acquisition), "-o", str(tmp_path / "fits"), "-q"]) == 0
    monkeypatch.setattr("skintopo.acquisition.images.available_memory", lambda: 10 * 2**20)
    assert main([command, str(acquisition), "-o", str(tmp_path / "out"), "-q"]) == 2
    need = (0.3 * 2**30 + 96 * 96 * (4 * 16 + PROCESSING_BYTES_PER_PIXEL[command])) / 2**30
    message = capsys.readouterr().err
    assert f"96 x 96 pixels with 16 images needs about {need:.1f} GiB" in message and "0.0 GiB are available" in message
    assert "acquisition.json" in message and not (tmp_path / "out").exists()


def test_measure_command(tmp_path, capsys):
    z = fbm(128, 0.6, 0) * 30
    HeightMap(z, 5.0).save(tmp_path / "h.x3p")
    assert main(["measure", str(tmp_path / "h.x3p"), "-o", str(tmp_path / "out"), "--region", "corner=0,0,200,200"]) == 0
    data = json.loads((tmp_path / "out" / "parameters.json").read_text())
    names = {(p["region"], p["name"]) for p in data["parameters"]}
    assert ("field", "Vmc") in names and ("corner", "D_cube-counting") in names
    assert "region,name,value,unit,reference" in (tmp_path / "out" / "parameters.csv").read_text()
    assert "Sa" in capsys.readouterr().out
    assert main(["measure", str(tmp_path / "h.x3p"), "-o", str(tmp_path / "o2"), "--region", "far=0,0,5000,5000", "-q"]) == 2
    assert not (tmp_path / "o2").exists()
    written, given = HeightMap.load(tmp_path / "out" / "height.x3p"), HeightMap.load(tmp_path / "h.x3p")  # written alongside the wrinkles
    assert written.spacing == given.spacing == (5.0, 5.0) and np.array_equal(written.z, given.z)
    # um -> m -> binary32 -> um: 24 significant bits, rounded to nearest (half an ulp, 2^-24 relative)
    assert np.all(np.abs(written.z - z) <= 2.0**-24 * np.abs(z) * (1 + 1e-6))


def test_a_measure_that_fails_after_the_height_is_written_leaves_no_output(tmp_path, capsys, monkeypatch):
    """height.x3p is written into the staging folder while the wrinkles are measured; when the
    measure then fails, neither the output folder nor the staging folder is left behind."""
    from skintopo import pipeline
    from skintopo.errors import SkinTopoError

    HeightMap(fbm(96, 0.6, 1) * 30, 5.0).save(tmp_path / "h.x3p")

    def failing(height, segmentation, **settings):
        raise SkinTopoError("wrinkle measures failed (planted)")

    monkeypatch.setattr(pipeline, "measure_wrinkles", failing)
    written = []
    monkeypatch.setattr("skintopo.results.write_height_file", lambda folder, height: written.append(folder) or height.save(folder / "height.x3p"))
    assert main(["measure", str(tmp_path / "h.x3p"), "-o", str(tmp_path / "out"), "-q"]) == 2
    assert "planted" in capsys.readouterr().err
    assert len(written) == 1 and not written[0].exists() and sorted(p.name for p in tmp_path.iterdir()) == ["h.x3p"]


def test_progress_bars_show_in_a_terminal_of_unknown_size(tmp_path):
    """In a pseudo-terminal whose size was never set (tqdm draws nothing on 0 rows), measure
    shows its band and step bars on stderr; -q shows none."""
    import os
    import pty
    import subprocess
    import sys

    HeightMap(fbm(96, 0.6, 1) * 20, 10.0).save(tmp_path / "h.x3p")

    def terminal_output(*extra):
        leader, follower = pty.openpty()
        run = subprocess.Popen([sys.executable, "-m", "skintopo.cli", "measure", str(tmp_path / "h.x3p"), "-o",
                                str(tmp_path / f"out{len(extra)}"), *extra], stdin=follower, stdout=follower, stderr=follower)
        os.close(follower)
        output = b""
        while True:
            try:
                chunk = os.read(leader, 4096)
            except OSError:  # the terminal closed with the process
                break
            if not chunk:
                break
            output += chunk
        assert run.wait(timeout=120) == 0
        return output.decode(errors="replace")

    shown = terminal_output()
    assert "measure:" in shown and "step/s, wrinkle measures]" in shown and "write:" in shown
    assert "step" not in terminal_output("-q")
