"""Light calibration from rendered chrome and matte spheres."""

import json

import numpy as np
import pytest

from skintopo.calibration import calibrate_lights
from skintopo.errors import SkinTopoError
from skintopo.formats import write_png
from skintopo.synth.targets import sphere_images
from tests.helpers.spheres import SHAPE, angle_degrees, render_chrome, sixteen_bit, true_lights, write

SPHERE = sphere_images("matte-sphere", np.zeros((0, 3)), shape=SHAPE)[1]  # (cx, cy, r) in pixels, off the pixel grid


def render_matte(lights, intensities):
    return sixteen_bit(sphere_images("matte-sphere", lights, shape=SHAPE, intensities=intensities, noise=0.0)[0])


def spot(shape, centre, falloff=0.2):
    """LED spot: 1 at ``centre`` falling by ``falloff`` at the farthest corner (quadratic)."""
    rows, columns = np.indices(shape)
    distance2 = (rows - centre[0]) ** 2 + (columns - centre[1]) ** 2
    return 1 - falloff * distance2 / distance2.max()


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


def test_flat_field_correction_makes_a_flat_target_flat(tmp_path):
    from skintopo.acquisition import load_acquisition, write_acquisition
    from skintopo.reconstruct import reconstruct_band
    from tests.helpers.analytic import four_lights

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
    from skintopo.acquisition import load_acquisition
    from tests.helpers.analytic import four_lights

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
