"""``skintopo init``: a manifest from a folder of images and the calibrated lights."""

import json
import re
from pathlib import Path

import numpy as np

from skintopo.acquisition import load_acquisition
from skintopo.cli import main
from skintopo.formats import write_png
from skintopo.normals import angular_error_degrees


def test_init_writes_a_manifest_from_a_folder_and_the_calibrated_lights(tmp_path, capsys):
    from skintopo.normals import photometric_stereo, render_lambertian
    from tests.helpers.analytic import four_lights, normals_from_slopes, paraboloid_with_wrinkles

    z, p, q = paraboloid_with_wrinkles(shape=(48, 64), spacing=10.0)
    truth = normals_from_slopes(p, q)
    lights = four_lights()
    folder = tmp_path / "capture"
    folder.mkdir()
    for band, albedo in (("red", 0.6), ("green", 0.41), ("blue", 0.33)):
        for index, image in enumerate(render_lambertian(truth, albedo, lights), start=1):
            write_png(folder / f"{band}_{index}.png", np.round(np.clip(image, 0, 1) * 65535).astype(np.uint16))
    lights_file = tmp_path / "lights.json"  # as 'skintopo calibrate lights' writes it
    lights_file.write_text(json.dumps({"method": "chrome", "lights": [{"file": f"sphere_{i}.png", "light": list(s)} for i, s in enumerate(lights)]}))
    images_before = {p.name: p.read_bytes() for p in folder.iterdir()}
    assert main(["init", str(folder), "--lights", str(lights_file), "--pixel-um", "10"]) == 0
    assert "red (4 images), green (4 images), blue (4 images)" in capsys.readouterr().out
    assert {p.name: p.read_bytes() for p in folder.iterdir() if p.name != "acquisition.json"} == images_before  # images untouched
    acquisition = load_acquisition(folder)
    assert acquisition.pixel_um == 10.0 and sorted(acquisition.bands) == ["blue", "green", "red"]
    np.testing.assert_allclose(acquisition.bands["green"].lights, lights, atol=1e-9)
    green = acquisition.bands["green"]
    error = angular_error_degrees(photometric_stereo(green.images, green.lights).normals, truth)
    assert np.nanmax(error) < 0.1
    assert main(["init", str(folder), "--lights", str(lights_file), "--pixel-um", "10", "-q"]) == 2
    assert "acquisition.json: exists; use --overwrite" in capsys.readouterr().err
    manifest = (folder / "acquisition.json").read_bytes()
    (folder / "blue_4.png").unlink()
    assert main(["init", str(folder), "--lights", str(lights_file), "--pixel-um", "10", "--overwrite", "-q"]) == 2
    assert "band blue: 3 image(s) (blue_1.png, blue_2.png, blue_3.png) for 4 light(s)" in capsys.readouterr().err
    assert (folder / "acquisition.json").read_bytes() == manifest and not list(folder.glob(".*"))  # nothing written
    lights_file.write_text("{}")
    assert main(["init", str(folder), "--lights", str(lights_file), "--pixel-um", "10", "--overwrite", "-q"]) == 2
    assert "not a lights file of 'skintopo calibrate lights'" in capsys.readouterr().err


def test_the_readme_manifest_example_is_a_valid_acquisition(tmp_path):
    """The manifest printed in the README's "Bring your own device" loads as written, with
    four lights per band, once images of those names exist."""
    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    manifest = re.search(r"## Bring your own device.*?```json\n(.*?)```", readme, re.S).group(1)
    (tmp_path / "acquisition.json").write_text(manifest)
    rng = np.random.default_rng(0)
    for entry in json.loads(manifest)["images"]:
        write_png(tmp_path / entry["file"], rng.integers(1000, 60000, size=(24, 32)).astype(np.uint16))
    acquisition = load_acquisition(tmp_path)
    assert sorted(acquisition.bands) == ["blue", "green", "red"] and all(len(b.lights) == 4 for b in acquisition.bands.values())
    assert acquisition.pixel_um == 20.0
