"""Reading acquisitions: colour channels, gamma and sRGB decoding, saturation, the bands asked for."""

import json

import numpy as np
import pytest
import tifffile

from skintopo.acquisition import load_acquisition, read_image
from skintopo.errors import AcquisitionError
from skintopo.formats import write_png


def edit_manifest(folder, change):
    path = folder / "acquisition.json"
    manifest = json.loads(path.read_text())
    change(manifest)
    path.write_text(json.dumps(manifest))


def test_missing_band_requested(lambertian_acquisition):
    folder, _, _ = lambertian_acquisition
    with pytest.raises(AcquisitionError, match=r"band\(s\) \['white'\] not in this acquisition"):
        load_acquisition(folder, bands=["white"])


def test_rgb_images_under_white_light_give_one_band_per_channel(tmp_path):
    rng = np.random.default_rng(0)
    lights = [[0.6, 0, 0.8], [0, 0.6, 0.8], [-0.6, 0, 0.8], [0, -0.6, 0.8]]
    entries = []
    for i, light in enumerate(lights):
        rgb = (rng.random((8, 9, 3)) * 60000).astype(np.uint16)  # below saturation
        tifffile.imwrite(tmp_path / f"w{i}.tif", rgb, photometric="rgb")
        for channel in ("red", "green", "blue"):
            entries.append({"file": f"w{i}.tif", "band": channel, "light": light, "channel": channel})
        entries.append({"file": f"w{i}.tif", "band": "white", "light": light, "intensity": 2.0})
    manifest = {"format": "skintopo-acquisition", "version": 1, "pixel_size_um": 5, "images": entries}
    (tmp_path / "acquisition.json").write_text(json.dumps(manifest))
    acquisition = load_acquisition(tmp_path)
    first = read_image(tmp_path / "w0.tif").astype(np.float32) / 65535
    np.testing.assert_allclose(acquisition.bands["green"].images[0], first[..., 1], rtol=1e-6)
    np.testing.assert_allclose(acquisition.bands["white"].images[0], first.mean(axis=2) / 2, rtol=1e-5)


def test_gamma_is_undone_only_when_declared(lambertian_acquisition):
    folder, _, _ = lambertian_acquisition
    linear = load_acquisition(folder, bands=["red"]).bands["red"].images
    edit_manifest(folder, lambda m: m.update(gamma=2.2))
    decoded = load_acquisition(folder, bands=["red"]).bands["red"].images
    np.testing.assert_allclose(decoded, linear**2.2, rtol=1e-4, atol=1e-7)


def test_saturated_pixels_are_marked(lambertian_acquisition):
    folder, _, _ = lambertian_acquisition
    image = read_image(folder / "red_00.png")
    image[:3, :3] = 65535
    write_png(folder / "red_00.png", image)
    images = load_acquisition(folder, bands=["red"]).bands["red"].images
    assert np.isnan(images[0, :3, :3]).all() and np.isfinite(images[1:]).all()


def test_srgb_encoded_images_are_decoded_by_the_standard_curve(tmp_path):
    """IEC 61966-2-1: linear = V / 12.92 for V <= 0.04045, else ((V + 0.055) / 1.055)^2.4.
    Reference points: V = 0.5 -> 0.21404, V = 0.04045 -> 0.0031308, V = 1 -> 1."""
    lights = [[0.6, 0, 0.8], [0, 0.6, 0.8], [-0.6, 0, 0.8], [0, -0.6, 0.8]]
    codes = np.array([[0, 2651, 32768, 65535]], dtype=np.uint16)  # 2651 / 65535 = 0.04045
    entries = []
    for i, light in enumerate(lights):
        write_png(tmp_path / f"g{i}.png", codes)
        entries.append({"file": f"g{i}.png", "band": "green", "light": light})
    manifest = {"format": "skintopo-acquisition", "version": 1, "pixel_size_um": 5, "gamma": "srgb", "images": entries}
    (tmp_path / "acquisition.json").write_text(json.dumps(manifest))
    decoded = load_acquisition(tmp_path, saturation=1.01).bands["green"].images[0, 0]
    np.testing.assert_allclose(decoded, [0.0, 0.0031308, 0.21404, 1.0], rtol=2e-4, atol=1e-7)
