"""``skintopo calibrate`` (lights, leds): the files written, bad sphere images, and a rehearsal from calibration to measure."""

import json

import numpy as np
import pytest

from skintopo.calibration import calibrate_lights
from skintopo.cli import main
from skintopo.device import read_device
from skintopo.errors import SkinTopoError
from skintopo.synth.targets import sphere_images, sphere_normals_of
from tests.helpers.spheres import SHAPE, angle_degrees, render_chrome, true_lights, write

SPHERE = sphere_images("matte-sphere", np.zeros((0, 3)), shape=SHAPE)[1]  # (cx, cy, r) in pixels, off the pixel grid


INSIDE = np.isfinite(sphere_normals_of(SHAPE, SPHERE[:2], SPHERE[2])[..., 2])


def test_calibrate_command_writes_lights_json(tmp_path, capsys):
    paths = write(tmp_path / "chrome", render_chrome(true_lights()[:4], seed=1))
    out = tmp_path / "lights.json"
    assert main(["calibrate", "lights", *map(str, paths), "-o", str(out)]) == 0
    data = json.loads(out.read_text())
    assert len(data["lights"]) == 4 and data["lights"][0]["file"] == "sphere_0.png"


def test_bad_sphere_images(tmp_path, capsys):
    dark = np.zeros(SHAPE, np.uint16)
    with pytest.raises(SkinTopoError, match="sphere not found"):
        calibrate_lights(write(tmp_path / "none", [dark, dark]))
    no_highlight = (np.where(INSIDE, 0.3, 0.0) * 65535).astype(np.uint16)
    paths = write(tmp_path / "missing", [render_chrome(true_lights()[:1], seed=2)[0], no_highlight])
    with pytest.raises(SkinTopoError, match="sphere_1.png: no specular highlight"):
        calibrate_lights(paths)
    burnt = render_chrome(true_lights()[:1], seed=3)[0]
    burnt[INSIDE] = 65535
    with pytest.raises(SkinTopoError, match="sphere_0.png: .* of the sphere is saturated"):
        calibrate_lights(write(tmp_path / "burnt", [burnt]), mask=INSIDE)
    (tmp_path / "broken.nef").write_bytes(b"not a raw file")
    assert main(["calibrate", "lights", str(tmp_path / "broken.nef"), "-o", str(tmp_path / "l.json")]) == 2
    assert "broken.nef: not a readable camera raw file" in capsys.readouterr().err


@pytest.mark.slow
def test_rehearse_a_real_device_from_calibration_to_measure_without_writing_json(tmp_path, capsys):
    """synth calibration targets -> calibrate lights -> init -> measure, as with a real camera:
    the simulator writes the skin images without a manifest and a chrome sphere under the same
    lights; the lights found are within half a degree of the simulator's, and measure runs on
    the manifest that init wrote."""
    spheres, skin, lights_json = tmp_path / "spheres", tmp_path / "capture", tmp_path / "lights.json"
    assert main(["synth", "--target", "chrome-sphere", "-o", str(spheres), "-q"]) == 0
    assert main(["synth", "-o", str(skin), "--size", "96", "--no-manifest", "-q"]) == 0
    assert not (skin / "acquisition.json").exists() and (skin / "red_00.png").is_file()
    truth = json.loads((spheres / "ground_truth.json").read_text())
    files = [str(spheres / name) for name in truth["files"]]
    assert main(["calibrate", "lights", *files, "-o", str(lights_json), "-q"]) == 0
    assert main(["init", str(skin), "--lights", str(lights_json), "--pixel-um", "20", "--mask", "mask.png", "-q"]) == 0
    manifest = json.loads((skin / "acquisition.json").read_text())
    red = [entry["light"] for entry in manifest["images"] if entry["band"] == "red"]
    errors = angle_degrees(red, truth["lights"])
    print("lights from the simulated chrome sphere: errors (deg)", np.round(errors, 3))
    assert errors.max() < 0.5
    assert main(["measure", str(skin), "-o", str(tmp_path / "out"), "-q"]) == 0
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["source"]["height"] == "spectral correction (paper)"
    assert main(["synth", "--target", "matte-sphere", "-o", str(tmp_path / "matte"), "-q"]) == 0
    matte = json.loads((tmp_path / "matte" / "ground_truth.json").read_text())
    found = calibrate_lights([tmp_path / "matte" / name for name in matte["files"]], method="matte")
    assert angle_degrees([entry["light"] for entry in found["lights"]], matte["lights"]).max() < 0.5


def test_calibrate_leds_command_on_a_rendered_rehearsal(tmp_path):
    """``synth --target chrome-sphere --device paper`` then ``calibrate leds``: the device file
    written has every LED within 1 mm and mu within 10% of the rehearsal's true device
    (LEDs displaced up to 3 mm from the design, mu 1.3)."""
    import subprocess
    import sys

    run = [sys.executable, "-m", "skintopo.cli"]
    rehearsal = tmp_path / "calibration"
    subprocess.run([*run, "synth", "--target", "chrome-sphere", "--device", "paper", "--size", "1000", "-o", str(rehearsal), "-q"],
                   check=True)
    out = tmp_path / "device.json"
    done = subprocess.run([*run, "calibrate", "leds", str(rehearsal / "design.json"), "--place", str(rehearsal / "place_1"),
                           "--place", str(rehearsal / "place_2"), "--sphere-radius-mm", "10", "--flat", str(rehearsal / "flat"),
                           "-o", str(out)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    found, truth = read_device(out), read_device(rehearsal / "ground_truth.json")
    for led, true in zip(found.leds, truth.leds):
        assert np.linalg.norm(np.subtract(led.position_mm, true.position_mm)) < 1.0
        assert led.mu == pytest.approx(true.mu, rel=0.1)
    single = subprocess.run([*run, "calibrate", "leds", str(rehearsal / "design.json"), "--place", str(rehearsal / "place_1"),
                             "--sphere-radius-mm", "10", "-o", str(tmp_path / "one.json")], capture_output=True, text=True)
    assert single.returncode != 0 and "two or more places" in single.stderr and not (tmp_path / "one.json").exists()
