"""Light calibration from rendered chrome and matte spheres."""

import json

import numpy as np
import pytest

from skintopo.calibration import calibrate_lights, sphere_normals
from skintopo.cli import main
from skintopo.errors import SkinTopoError
from skintopo.formats import write_png

SHAPE, SPHERE = (240, 300), (152.3, 117.8, 86.4)  # cx, cy, r in pixels


def true_lights():
    slant = np.radians([30, 40, 45, 55, 35, 60])
    tilt = np.radians([10, 95, 185, 275, 140, 320])
    return np.stack([np.sin(slant) * np.cos(tilt), np.sin(slant) * np.sin(tilt), np.cos(slant)], axis=1)


def render_chrome(light, rng, *, gain=3.0, noise=0.003):
    """Mirror sphere: the light (an LED about 2 degrees wide) reflected where the mirror
    direction of the view meets it, a dim reflected environment, black background, noise,
    clipped at full scale (saturated highlight), 16-bit."""
    normals = sphere_normals(SHAPE, SPHERE)
    inside = np.isfinite(normals[..., 2])
    n = np.nan_to_num(normals)
    mirror = 2 * n[..., 2:3] * n - np.array([0.0, 0.0, 1.0])
    angle = np.degrees(np.arccos(np.clip(mirror @ light, -1, 1)))
    image = np.where(inside, 0.06 + gain * np.exp(-((angle / 2.0) ** 2)), 0.0)
    image = image + noise * rng.standard_normal(SHAPE)
    return (np.clip(image, 0, 1) * 65535).astype(np.uint16)


def render_matte(light, intensity):
    normals = np.nan_to_num(sphere_normals(SHAPE, SPHERE))
    image = 0.7 * intensity * np.maximum(normals @ light, 0)
    return (np.clip(image, 0, 1) * 65535).astype(np.uint16)


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
    rng = np.random.default_rng(0)
    lights = true_lights()
    paths = write(tmp_path / "chrome", [render_chrome(light, rng) for light in lights])
    result = calibrate_lights(paths)
    found = np.array([entry["light"] for entry in result["lights"]])
    errors = angle_degrees(found, lights)
    print("chrome sphere: light direction errors (deg)", np.round(errors, 3), "sphere", result["sphere"])
    assert errors.max() < 0.5
    assert result["sphere"]["radius_px"] == pytest.approx(SPHERE[2], abs=0.5)


def test_matte_sphere_gives_directions_and_relative_intensities(tmp_path):
    lights = true_lights()
    intensity = np.array([1.0, 0.8, 0.9, 0.7, 1.1, 0.95])
    paths = write(tmp_path / "matte", [render_matte(light, e) for light, e in zip(lights, intensity)])
    result = calibrate_lights(paths, method="matte", mask=None)
    found = np.array([entry["light"] for entry in result["lights"]])
    assert angle_degrees(found, lights).max() < 0.5
    np.testing.assert_allclose([entry["intensity"] for entry in result["lights"]], intensity / intensity.max(), rtol=0.01)


def test_calibrate_command_writes_lights_json(tmp_path, capsys):
    rng = np.random.default_rng(1)
    paths = write(tmp_path / "chrome", [render_chrome(light, rng) for light in true_lights()[:4]])
    out = tmp_path / "lights.json"
    assert main(["calibrate", "lights", *map(str, paths), "-o", str(out)]) == 0
    data = json.loads(out.read_text())
    assert len(data["lights"]) == 4 and data["lights"][0]["file"] == "sphere_0.png"


def test_bad_sphere_images(tmp_path, capsys):
    rng = np.random.default_rng(2)
    dark = np.zeros(SHAPE, np.uint16)
    with pytest.raises(SkinTopoError, match="sphere not found"):
        calibrate_lights(write(tmp_path / "none", [dark, dark]))
    no_highlight = (np.where(np.isfinite(sphere_normals(SHAPE, SPHERE)[..., 2]), 0.3, 0.0) * 65535).astype(np.uint16)
    paths = write(tmp_path / "missing", [render_chrome(true_lights()[0], rng), no_highlight])
    with pytest.raises(SkinTopoError, match="sphere_1.png: no specular highlight"):
        calibrate_lights(paths)
    burnt = render_chrome(true_lights()[0], rng, gain=3.0)
    burnt[np.isfinite(sphere_normals(SHAPE, SPHERE)[..., 2])] = 65535
    with pytest.raises(SkinTopoError, match="sphere_0.png: .* of the sphere is saturated"):
        calibrate_lights(write(tmp_path / "burnt", [burnt]), mask=np.isfinite(sphere_normals(SHAPE, SPHERE)[..., 2]))
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
