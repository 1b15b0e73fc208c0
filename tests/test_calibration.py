"""Light calibration from rendered chrome and matte spheres."""

import json

import numpy as np
import pytest

from skintopo.calibration import calibrate_lights
from skintopo.cli import main
from skintopo.errors import SkinTopoError
from skintopo.formats import write_png
from skintopo.synth.targets import sphere_images, sphere_normals_of

SHAPE = (240, 300)
SPHERE = sphere_images("matte-sphere", np.zeros((0, 3)), shape=SHAPE)[1]  # (cx, cy, r) in pixels, off the pixel grid
INSIDE = np.isfinite(sphere_normals_of(SHAPE, SPHERE[:2], SPHERE[2])[..., 2])


def true_lights():
    slant = np.radians([30, 40, 45, 55, 35, 60])
    tilt = np.radians([10, 95, 185, 275, 140, 320])
    return np.stack([np.sin(slant) * np.cos(tilt), np.sin(slant) * np.sin(tilt), np.cos(slant)], axis=1)


def sixteen_bit(images):
    return [np.round(image * 65535).astype(np.uint16) for image in images]


def render_chrome(lights, seed=0):
    """Mirror sphere (skintopo.synth.targets: an LED about 2 degrees wide reflected where the
    mirror direction of the view meets it, a dim room, noise, a saturated highlight), 16-bit."""
    return sixteen_bit(sphere_images("chrome-sphere", lights, shape=SHAPE, seed=seed)[0])


def render_matte(lights, intensities):
    return sixteen_bit(sphere_images("matte-sphere", lights, shape=SHAPE, intensities=intensities, noise=0.0)[0])


def write(folder, images):
    folder.mkdir(exist_ok=True)
    paths = []
    for i, image in enumerate(images):
        paths.append(folder / f"sphere_{i}.png")
        write_png(paths[-1], image)
    return paths


def angle_degrees(a, b):
    return np.degrees(np.arccos(np.clip(np.sum(np.asarray(a) * np.asarray(b), axis=-1), -1, 1)))


def test_chrome_sphere_gives_light_directions_within_half_a_degree(tmp_path):
    lights = true_lights()
    paths = write(tmp_path / "chrome", render_chrome(lights))
    result = calibrate_lights(paths)
    found = np.array([entry["light"] for entry in result["lights"]])
    errors = angle_degrees(found, lights)
    print("chrome sphere: light direction errors (deg)", np.round(errors, 3), "sphere", result["sphere"])
    assert errors.max() < 0.5
    assert result["sphere"]["radius_px"] == pytest.approx(SPHERE[2], abs=0.5)


def test_matte_sphere_gives_directions_and_relative_intensities(tmp_path):
    lights = true_lights()
    intensity = np.array([1.0, 0.8, 0.9, 0.7, 1.1, 0.95])
    paths = write(tmp_path / "matte", render_matte(lights, intensity))
    result = calibrate_lights(paths, method="matte", mask=None)
    found = np.array([entry["light"] for entry in result["lights"]])
    assert angle_degrees(found, lights).max() < 0.5
    np.testing.assert_allclose([entry["intensity"] for entry in result["lights"]], intensity / intensity.max(), rtol=0.01)


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


def spot(shape, centre, falloff=0.2):
    """LED spot: 1 at ``centre`` falling by ``falloff`` at the farthest corner (quadratic)."""
    rows, columns = np.indices(shape)
    distance2 = (rows - centre[0]) ** 2 + (columns - centre[1]) ** 2
    return 1 - falloff * distance2 / distance2.max()


def test_flat_field_correction_makes_a_flat_target_flat(tmp_path):
    from conftest import four_lights

    from skintopo.acquisition import load_acquisition, write_acquisition
    from skintopo.reconstruct import reconstruct_band

    shape, lights = (96, 128), four_lights()
    spots = [spot(shape, c) for c in ((0, 64), (48, 0), (95, 64), (48, 127))]  # each LED lights its own side
    flat_normals = np.zeros(shape + (3,))
    flat_normals[..., 2] = 1.0
    skin = np.stack([0.5 * lights[i, 2] * spots[i] for i in range(4)])  # flat skin, albedo 0.5
    target = np.stack([0.8 * lights[i, 2] * spots[i] for i in range(4)])  # white reference target, albedo 0.8
    folder = tmp_path / "acq"
    write_acquisition(folder, {"red": (skin, lights)}, 20.0)
    before = reconstruct_band(load_acquisition(folder), "red").height
    for i in range(4):
        write_png(folder / f"flat_{i}.png", np.round(target[i] * 65535).astype(np.uint16))
    manifest = json.loads((folder / "acquisition.json").read_text())
    for i, entry in enumerate(manifest["images"]):
        entry["flat"] = f"flat_{i}.png"
    (folder / "acquisition.json").write_text(json.dumps(manifest))
    after = reconstruct_band(load_acquisition(folder), "red").height
    rms = {name: float(np.nanstd(h.z)) for name, h in (("before", before), ("after", after))}
    print(f"flat target under a 20% fall-off spot: height RMS {rms['before']:.2f} um before, {rms['after']:.3f} um after flat-field")
    assert rms["before"] > 5 and rms["after"] < 1.0


def test_dark_frame_and_crosstalk(tmp_path):
    from conftest import four_lights

    from skintopo.acquisition import load_acquisition

    rng = np.random.default_rng(4)
    lights = four_lights()
    led = rng.uniform(0.2, 0.6, size=(4, 20, 24, 3))  # true per-LED-band signal, observation i
    mixing = np.array([[1.0, 0.08, 0.02], [0.1, 1.0, 0.12], [0.01, 0.15, 1.0]])  # camera = M @ led
    dark = np.full((20, 24, 3), 0.02)
    entries = []
    for i in range(4):
        camera = led[i] @ mixing.T + dark
        write_png(tmp_path / f"rgb_{i}.png", np.round(camera * 65535).astype(np.uint16))
        for band in ("red", "green", "blue"):
            entries.append({"file": f"rgb_{i}.png", "band": band, "light": lights[i].tolist()})
    write_png(tmp_path / "dark.png", np.round(dark * 65535).astype(np.uint16))
    manifest = {"format": "skintopo-acquisition", "version": 1, "pixel_size_um": 10, "dark": "dark.png",
                "crosstalk": mixing.tolist(), "images": entries}
    (tmp_path / "acquisition.json").write_text(json.dumps(manifest))
    acquisition = load_acquisition(tmp_path)
    for c, band in enumerate(("red", "green", "blue")):
        np.testing.assert_allclose(acquisition.bands[band].images, led[..., c], atol=1e-4)
    manifest["crosstalk"] = [[1, 0, 0], [1, 0, 0], [0, 0, 1]]
    (tmp_path / "acquisition.json").write_text(json.dumps(manifest))
    with pytest.raises(SkinTopoError, match="'crosstalk' must be an invertible 3 x 3 matrix"):
        load_acquisition(tmp_path)


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
