"""Reading acquisitions: colour channels, gamma and sRGB decoding, saturation, the bands asked for."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import tifffile

from skintopo.acquisition import load_acquisition, read_image, write_acquisition
from skintopo.errors import AcquisitionError, SkinTopoError
from skintopo.formats import write_png
from tests.helpers.manifests import edit_manifest


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


def _set(*path_and_value):
    """An edit of the manifest: the value at a path of keys and indices."""
    *path, key, value = path_and_value

    def change(manifest):
        target = manifest
        for step in path:
            target = target[step]
        target[key] = value
    return change


MANIFEST_PROBLEMS = [
    (_set("pixel_size_um", -1), "acquisition.json: field 'pixel_size_um' must be a positive number of micrometres, got -1"),
    (_set("gamma", "linear"), "acquisition.json: field 'gamma' must be a positive number or \"srgb\", got 'linear'"),
    (_set("full_scale", 0), "acquisition.json: field 'full_scale' must be a positive number, got 0"),
    (_set("crosstalk", [[1, 0, 0], [1, 0, 0], [0, 0, 1]]), "field 'crosstalk' must be an invertible 3 x 3 matrix"),
    (_set("crosstalk", [[1, 0], [0, 1]]), "field 'crosstalk' must be an invertible 3 x 3 matrix"),
    (_set("device", 5), "acquisition.json: field 'device' must name a device file (device.json)"),
    (_set("dark", 3), "acquisition.json: field 'dark' must name an image file"),
    (_set("images", []), "acquisition.json: field 'images' must be a non-empty list"),
    (_set("images", 0, 7), "images[0] must be an object"),
    (_set("images", 0, "file", ""), "images[0]: field 'file' must name an image file"),
    (_set("images", 1, "colour", "red"), "images[1] (red_01.png): unknown field 'colour'"),
    (_set("images", 2, "band", "purple"), "images[2] (red_02.png): field 'band' must be one of ['red', 'green', 'blue', 'white'], got 'purple'"),
    (_set("images", 0, "led", "north"), "images[0] (red_00.png): field 'led' needs a 'device' file in the manifest"),
    (_set("images", 3, "light", [0.0, 1.0]), "images[3] (red_03.png): field 'light' must be a list of 3 numbers (unit vector x, y, z)"),
    (_set("images", 0, "light", [0.0, 0.0, 2.0]), "acquisition.json: images[0] (red_00.png): light direction [0.0, 0.0, 2.0] is not a unit vector"),
    (_set("images", 3, "light", [0.0, True, 1.0]), "images[3] (red_03.png): field 'light' must be a list of 3 numbers (unit vector x, y, z)"),
    (_set("images", 4, "intensity", -2), "images[4] (green_00.png): field 'intensity' must be a positive number, got -2"),
    (_set("images", 5, "wavelength_nm", 0), "images[5] (green_01.png): field 'wavelength_nm' must be a positive number, got 0"),
    (_set("images", 6, "channel", "alpha"), "images[6] (green_02.png): field 'channel' must be one of"),
    (_set("images", 7, "flat", 4), "images[7] (green_03.png): field 'flat' must name an image file"),
    (_set("lens", "50 mm"), "acquisition.json: unknown field 'lens'"),
    (_set("format", "other"), "acquisition.json: field 'format' must be 'skintopo-acquisition', got 'other'"),
    (_set("version", 99), "acquisition.json: field 'version' must be 1 (this reader's format), got 99"),
]


@pytest.mark.parametrize("change, message", MANIFEST_PROBLEMS, ids=[m.split(": ", 1)[-1][:40] for _, m in MANIFEST_PROBLEMS])
def test_each_manifest_problem_is_named(lambertian_acquisition, change, message):
    folder, _, _ = lambertian_acquisition
    edit_manifest(folder, change)
    with pytest.raises(AcquisitionError) as error:
        load_acquisition(folder)
    assert any(message in problem for problem in error.value.problems), error.value.problems
    assert error.value.source.endswith("acquisition.json")


def test_every_problem_of_a_manifest_is_reported_at_once(lambertian_acquisition):
    folder, _, _ = lambertian_acquisition

    def change(manifest):
        manifest["gamma"] = -1
        manifest["images"][0]["band"] = "purple"
        manifest["images"][1]["intensity"] = 0
    edit_manifest(folder, change)
    with pytest.raises(AcquisitionError) as error:
        load_acquisition(folder)
    assert len(error.value.problems) == 3


def test_manifest_and_folder_errors(lambertian_acquisition, tmp_path):
    folder, _, _ = lambertian_acquisition
    with pytest.raises(AcquisitionError, match="pixel_size_um is 10.0 but 20.0 was given"):
        load_acquisition(folder, pixel_um=20.0)
    assert load_acquisition(folder, pixel_um=10.0).pixel_um == 10.0
    (folder / "acquisition.json").write_text("{not json")
    with pytest.raises(AcquisitionError, match="not valid JSON"):
        load_acquisition(folder)
    (folder / "acquisition.json").write_text("[1, 2]")
    with pytest.raises(AcquisitionError, match="the manifest must be a JSON object"):
        load_acquisition(folder)
    with pytest.raises(AcquisitionError, match="no such acquisition folder or manifest"):
        load_acquisition(tmp_path / "nowhere")


def test_written_acquisition_reads_back(tmp_path):
    """write_acquisition -> load_acquisition: images to 16-bit precision (divided by the band's
    declared intensity), lights, pixel size, wavelength defaults, mask and description; a folder
    that is not empty is refused."""
    rng = np.random.default_rng(4)
    lights = np.array([[0.6, 0.0, 0.8], [0.0, 0.6, 0.8], [-0.6, 0.0, 0.8], [0.0, -0.6, 0.8]])
    images = {band: rng.uniform(0.1, 0.9, (4, 12, 16)) for band in ("red", "blue")}
    mask = np.ones((12, 16), bool)
    mask[:2] = False
    write_acquisition(tmp_path / "a", {band: (im, lights) for band, im in images.items()}, 15.0, mask=mask,
                      description="phantom", intensities={"red": 2.0, "blue": 0.5})
    acquisition = load_acquisition(tmp_path / "a")
    assert acquisition.pixel_um == 15.0 and sorted(acquisition.bands) == ["blue", "red"]
    for band, intensity in (("red", 2.0), ("blue", 0.5)):
        np.testing.assert_allclose(acquisition.bands[band].lights, lights)
        np.testing.assert_allclose(acquisition.bands[band].images, images[band] / intensity, atol=1 / 65535 / intensity)
    np.testing.assert_array_equal(acquisition.mask, mask)
    manifest = json.loads((tmp_path / "a" / "acquisition.json").read_text())
    assert manifest["description"] == "phantom" and {e["wavelength_nm"] for e in manifest["images"] if e["band"] == "red"} == {625.0}
    with pytest.raises(SkinTopoError, match="not empty|exists"):
        write_acquisition(tmp_path / "a", {"red": (images["red"], lights)}, 15.0)


def test_image_reading_errors_and_layouts(tmp_path):
    """Planar RGB TIFF is turned channel-last; RGBA keeps RGB; every refusal names the file."""
    rgb = np.arange(3 * 5 * 6, dtype=np.uint16).reshape(3, 5, 6)
    tifffile.imwrite(tmp_path / "planar.tif", rgb, photometric="rgb", planarconfig="separate")
    np.testing.assert_array_equal(read_image(tmp_path / "planar.tif"), np.moveaxis(rgb, 0, -1))
    tifffile.imwrite(tmp_path / "rgba.tiff", np.zeros((5, 6, 4), np.uint8), photometric="rgb", extrasamples=["unassalpha"])
    assert read_image(tmp_path / "rgba.tiff").shape == (5, 6, 3)
    for name, content, message in (
        ("missing.png", None, "missing.png: image file not found"),
        ("broken.tif", b"not a tiff", "broken.tif: not a readable TIFF image"),
        ("picture.bmp", b"BM", "picture.bmp: unsupported image type '.bmp' \\(use PNG, TIFF or a camera raw file\\)"),
    ):
        if content is not None:
            (tmp_path / name).write_bytes(content)
        with pytest.raises(SkinTopoError, match=message):
            read_image(tmp_path / name)
    tifffile.imwrite(tmp_path / "signed.tif", np.zeros((4, 4), np.int16))
    with pytest.raises(SkinTopoError, match="signed.tif: unsupported pixel type int16"):
        read_image(tmp_path / "signed.tif")
    tifffile.imwrite(tmp_path / "stack.tif", np.zeros((2, 4, 4, 2), np.uint8), photometric="minisblack")
    with pytest.raises(SkinTopoError, match="stack.tif: expected a grey or RGB image, got an array of shape"):
        read_image(tmp_path / "stack.tif")


def test_a_mask_of_another_size_is_named(lambertian_acquisition):
    folder, _, _ = lambertian_acquisition
    write_png(folder / "mask.png", np.full((10, 10), 255, np.uint8))
    edit_manifest(folder, _set("mask", "mask.png"))
    with pytest.raises(AcquisitionError, match="mask.png: mask size 10x10 differs from the images \\(64x48\\)"):
        load_acquisition(folder)
    write_png(folder / "mask.png", np.where(np.arange(64)[None, :] < 32, 255, 0).astype(np.uint8) * np.ones((48, 1), np.uint8))
    np.testing.assert_array_equal(load_acquisition(folder).mask[0], np.arange(64) < 32)


def test_dark_frame_and_flat_fields_are_applied(lambertian_acquisition):
    """A dark frame of 1000 counts added to every image and named in the manifest is taken off
    again; a flat-target image (here half of full scale, less the dark frame) divides an image
    and l_z multiplies it (the LED's intensity and spot fall-off removed together)."""
    from skintopo.formats import read_png

    folder, _, _ = lambertian_acquisition
    plain = load_acquisition(folder)
    manifest = json.loads((folder / "acquisition.json").read_text())
    for entry in manifest["images"]:
        counts = read_png(folder / entry["file"]).astype(np.int64) + 1000
        write_png(folder / entry["file"], counts.astype(np.uint16))
    write_png(folder / "dark.png", np.full((48, 64), 1000, np.uint16))
    write_png(folder / "flat.png", np.full((48, 64), 32768, np.uint16))
    edit_manifest(folder, _set("dark", "dark.png"))
    darkened = load_acquisition(folder)
    np.testing.assert_allclose(darkened.bands["red"].images, plain.bands["red"].images, atol=2 / 65535)

    def flat_on_red(manifest):
        for entry in manifest["images"]:
            if entry["band"] == "red":
                entry.pop("intensity", None)
                entry["flat"] = "flat.png"
    edit_manifest(folder, flat_on_red)
    flattened = load_acquisition(folder)
    l_z = plain.bands["red"].lights[:, 2]
    flat = (32768 - 1000) / 65535  # the flat target's image has the dark frame taken off too
    np.testing.assert_allclose(flattened.bands["red"].images, plain.bands["red"].images / flat * l_z[:, None, None],
                               rtol=1e-3, atol=3 / 65535)
    np.testing.assert_allclose(flattened.bands["green"].images, plain.bands["green"].images, atol=2 / 65535)
    assert flattened.bands["red"].images.dtype == np.float32  # as every band's images (BandImages)


def _diligent_folder(folder, counts, lights, intensities=None):
    folder.mkdir()
    names = [f"{i + 1:03d}.png" for i in range(len(counts))]
    for name, image in zip(names, counts):
        write_png(folder / name, image)
    (folder / "filenames.txt").write_text("\n".join(names) + "\n")
    np.savetxt(folder / "light_directions.txt", lights)
    if intensities is not None:
        np.savetxt(folder / "light_intensities.txt", intensities)
    return folder


def test_diligent_layout_divides_by_each_lights_channel_intensity(tmp_path):
    """A DiLiGenT folder (RGB 16-bit images, filenames.txt, light_directions.txt,
    light_intensities.txt): each channel divided by its light's intensity for that channel,
    white the mean of the three, pixel size assumed 1 um unless given; every inconsistency
    named, a light that is not a unit vector too."""
    rng = np.random.default_rng(5)
    counts = rng.integers(1000, 30000, (4, 6, 8, 3)).astype(np.uint16)
    lights = np.array([[0.6, 0.0, 0.8], [0.0, 0.6, 0.8], [-0.6, 0.0, 0.8], [0.0, -0.6, 0.8]])
    intensities = np.array([[1.0, 2.0, 4.0], [0.5, 1.0, 1.0], [1.0, 1.0, 1.0], [2.0, 2.0, 2.0]])
    folder = _diligent_folder(tmp_path / "ball", counts, lights, intensities)
    acquisition = load_acquisition(folder)
    assert acquisition.layout == "diligent" and acquisition.pixel_um == 1.0 and acquisition.pixel_um_assumed
    expected = counts / 65535 / intensities[:, None, None, :]
    for band, channel in (("red", 0), ("green", 1), ("blue", 2)):
        np.testing.assert_allclose(acquisition.bands[band].images, expected[..., channel], rtol=1e-6)
    np.testing.assert_allclose(acquisition.bands["white"].images, expected.mean(axis=-1), rtol=1e-6)
    np.testing.assert_allclose(acquisition.bands["red"].lights, lights)
    assert load_acquisition(folder, pixel_um=5.0).pixel_um == 5.0 and sorted(load_acquisition(folder, bands=["blue"]).bands) == ["blue"]
    for name, content, message in (
        ("light_intensities.txt", "1 1 1\n1 1 1\n1 1 1\n", "light_intensities.txt: 3 lines for 4 images in filenames.txt"),
        ("light_intensities.txt", "1 1 1\n1 1 1\n1 0 1\n1 1 1\n", "light_intensities.txt: intensities must be positive"),
        ("light_directions.txt", "0 0\n0 0\n0 0\n0 0\n", "light_directions.txt: expected 3 numbers per line, got 2"),
        ("light_directions.txt", "0 0 1\n0 0 1\n0 0 1\nx y z\n", "light_directions.txt: not a table of numbers"),
        ("light_directions.txt", "0.6 0 0.8\n0 0.6 0.8\n-0.6 0 0.8\n0 0.3 1\n",
         "light_directions.txt: line 4 \\(004.png\\): light direction .* is not a unit vector"),
        ("light_directions.txt", "0.6 0 0.8\n0 0.6 0.8\n-0.6 0 0.8\n", "light_directions.txt: 3 lines for 4 images in filenames.txt"),
        ("light_directions.txt", "0.6 0 0.8\n", "light_directions.txt: 1 lines for 4 images in filenames.txt"),
    ):
        broken = tmp_path / f"broken_{name}_{len(content)}"
        shutil.copytree(folder, broken)
        (broken / name).write_text(content)
        with pytest.raises(AcquisitionError, match=message) as error:
            load_acquisition(broken)
        assert error.value.source == str(broken)
    write_png(folder / "mask.png", np.full((5, 8), 255, np.uint8))
    with pytest.raises(AcquisitionError, match="mask.png: mask size 8x5 differs from the images \\(8x6\\)") as error:
        load_acquisition(folder)
    assert error.value.source == str(folder)
    plain = load_acquisition(_diligent_folder(tmp_path / "plain", counts, lights))  # no light_intensities.txt: all 1
    assert plain.bands["green"].band == "green" and [Path(f).name for f in plain.bands["green"].files] == ["001.png", "002.png", "003.png", "004.png"]
    np.testing.assert_allclose(plain.bands["green"].images, counts[..., 1] / 65535, rtol=1e-6)
    grey = _diligent_folder(tmp_path / "grey", counts[..., 0], lights)
    with pytest.raises(AcquisitionError, match="DiLiGenT images are RGB; this one has a single channel"):
        load_acquisition(grey)


def test_an_acquisition_with_its_device_round_trips_and_its_inconsistencies_are_named(tmp_path):
    """write_acquisition(device=...) names each image's LED and writes device.json beside the
    manifest; loading gives each band's lights as the LEDs' directions to the field's centre,
    the LED names, the device and the band's wavelength. A manifest that gives a light
    direction with a device, a pixel size that the device contradicts, images of another size
    than the camera's, or a bad device file are each named."""
    from skintopo.device import paper_device

    device = paper_device(size_px=16)
    rng = np.random.default_rng(2)
    images = rng.uniform(0.2, 0.8, (4, 16, 16))
    folder = tmp_path / "new" / "visit"  # parent folders are made
    write_acquisition(folder, {"red": (images, np.tile([0.0, 0.0, 1.0], (4, 1)))}, device.pixel_um, device=device)
    manifest = json.loads((folder / "acquisition.json").read_text())
    assert manifest["device"] == "device.json" and [e["led"] for e in manifest["images"]] == [led.name for led in device.leds]
    assert "light" not in manifest["images"][0] and "\n  " in (folder / "acquisition.json").read_text()  # indented for people
    assert json.loads((folder / "device.json").read_text()) == json.loads(json.dumps(device.describe()))
    acquisition = load_acquisition(folder)
    band = acquisition.bands["red"]
    assert acquisition.layout == "manifest" and acquisition.pixel_um_assumed is False and acquisition.device.leds == device.leds
    assert acquisition.mask.dtype == bool and acquisition.mask.all()
    expected = device.central_directions()
    np.testing.assert_allclose(band.lights, expected / np.linalg.norm(expected, axis=1, keepdims=True), atol=1e-12)
    assert band.leds == tuple(led.name for led in device.leds) and band.wavelength_nm == 625.0
    assert [Path(f).name for f in band.files] == [f"red_{i:02d}.png" for i in range(4)]
    np.testing.assert_allclose(band.images, images, atol=1 / 65535)

    def problems_of(change, device_change=None):
        trial = tmp_path / f"trial{len(list(tmp_path.iterdir()))}"
        shutil.copytree(folder, trial)
        edit_manifest(trial, change)
        if device_change is not None:
            data = json.loads((trial / "device.json").read_text())
            device_change(data)
            (trial / "device.json").write_text(json.dumps(data))
        with pytest.raises(AcquisitionError) as error:
            load_acquisition(trial)
        assert error.value.source == str(trial / "acquisition.json")
        return error.value.problems

    assert problems_of(_set("images", 0, "light", [0.0, 0.0, 1.0])) == [
        "acquisition.json: images[0] (red_00.png): with a 'device', name the image's LED ('led'), not a light direction ('light')"]
    assert problems_of(_set("pixel_size_um", 1.5 * device.pixel_um)) == [
        f"acquisition.json: pixel_size_um is {1.5 * device.pixel_um} but the device's pixel footprint at its working distance is "
        f"{device.pixel_um:.6g} um"]
    assert any(p.startswith("device.json: ") and "mu must be a number >= 0" in p
               for p in problems_of(lambda m: None, lambda d: d["leds"][0].update(mu=-1)))
    camera = device.describe()["camera"]
    assert problems_of(lambda m: None, lambda d: d["camera"].update(size_px=[16, 20], principal_point_px=camera["principal_point_px"])) == [
        "acquisition.json: the images are 16 x 16 pixels but the device's camera has 16 x 20"]


def test_crosstalk_between_camera_channels_is_unmixed(tmp_path):
    """Camera channel c records sum_b M[c, b] v_b of the LED bands' signals v: with the
    manifest's 'crosstalk' M each band reads back its own v (M^-1 applied per pixel)."""
    rng = np.random.default_rng(5)
    crosstalk = np.array([[0.9, 0.08, 0.02], [0.1, 0.8, 0.1], [0.03, 0.12, 0.85]])
    lights = [[0.6, 0, 0.8], [0, 0.6, 0.8], [-0.6, 0, 0.8], [0, -0.6, 0.8]]
    truth, entries = [], []
    for i, light in enumerate(lights):
        signal = rng.uniform(0.1, 0.9, (6, 7, 3))  # per band: red, green, blue
        truth.append(signal)
        tifffile.imwrite(tmp_path / f"w{i}.tif", np.round(signal @ crosstalk.T * 65535).astype(np.uint16), photometric="rgb")
        entries += [{"file": f"w{i}.tif", "band": band, "light": light, "channel": band} for band in ("red", "green", "blue")]
    manifest = {"format": "skintopo-acquisition", "version": 1, "pixel_size_um": 5, "crosstalk": crosstalk.tolist(), "images": entries}
    (tmp_path / "acquisition.json").write_text(json.dumps(manifest))
    acquisition = load_acquisition(tmp_path)
    for index, band in enumerate(("red", "green", "blue")):
        np.testing.assert_allclose(acquisition.bands[band].images, np.stack([t[..., index] for t in truth]), atol=3e-5)


def test_loading_a_manifest_file_lights_saturation_and_problems_after_a_bad_entry(lambertian_acquisition, tmp_path):
    """The manifest file itself may be given, with the bands and the saturation asked for; a
    pixel at exactly the saturation level is saturated; light directions within the unit
    tolerance are normalised; an entry that is not an object does not hide the next one's
    problem; a single-channel image given a channel is named; every error names its source."""
    folder, _, _ = lambertian_acquisition
    image = read_image(folder / "red_00.png")
    image[0, :4] = 52428  # exactly 0.8 of full scale (65535 * 0.8 = 52428.0)
    write_png(folder / "red_00.png", image)
    edit_manifest(folder, _set("images", 1, "light", [0.0, 0.6, 0.8 * 1.0009 / 1.0]))
    acquisition = load_acquisition(folder / "acquisition.json", bands=["red"], saturation=0.8)
    assert list(acquisition.bands) == ["red"]
    red = acquisition.bands["red"].images
    assert np.isnan(red[0, 0, :4]).all() and np.isnan(red[0]).sum() == np.sum(image >= 52428)
    np.testing.assert_allclose(np.linalg.norm(acquisition.bands["red"].lights, axis=1), 1.0, rtol=1e-12)
    with pytest.raises(AcquisitionError) as error:
        load_acquisition(folder / "acquisition.json", bands=["ultraviolet"])
    assert error.value.source == str(folder / "acquisition.json") and "unknown band(s) ['ultraviolet']" in str(error.value)

    original = (folder / "acquisition.json").read_text()

    def two_bad_entries(manifest):
        manifest["images"][0] = 7
        manifest["images"][1]["file"] = ""
        manifest["images"][2]["band"] = "purple"
    edit_manifest(folder, two_bad_entries)
    with pytest.raises(AcquisitionError) as error:
        load_acquisition(folder)
    assert len(error.value.problems) == 3 and "images[2] (red_02.png): field 'band'" in error.value.problems[2]
    (folder / "acquisition.json").write_text(original)
    edit_manifest(folder, _set("images", 3, "channel", "green"))
    with pytest.raises(AcquisitionError) as error:
        load_acquisition(folder)
    assert error.value.problems == ["acquisition.json: images[3] (red_03.png): field 'channel' is 'green' but the image has a single channel"]
    (tmp_path / "empty").mkdir()
    with pytest.raises(AcquisitionError) as error:
        load_acquisition(tmp_path / "empty")
    assert error.value.source == str(tmp_path / "empty") and "neither acquisition.json nor a DiLiGenT layout" in str(error.value)


def test_unreadable_and_mismatched_images_are_named_with_their_sizes(lambertian_acquisition):
    folder, _, _ = lambertian_acquisition
    (folder / "red_01.png").write_bytes(b"\x89PNG broken")
    write_png(folder / "red_02.png", np.zeros((48, 50), np.uint16))
    with pytest.raises(AcquisitionError) as error:
        load_acquisition(folder)
    problems = error.value.problems
    assert any(p.endswith("red_01.png: not a readable PNG image (not a PNG image)") for p in problems), problems
    assert any(p.endswith("red_02.png: image size 50x48 differs from red_00.png (64x48)") for p in problems), problems
    assert error.value.source == str(folder / "acquisition.json")


def test_an_rgb_image_three_rows_high_stays_channel_last(tmp_path):
    rgb = np.arange(3 * 10 * 3, dtype=np.uint16).reshape(3, 10, 3)
    tifffile.imwrite(tmp_path / "strip.tif", rgb, photometric="rgb")
    np.testing.assert_array_equal(read_image(tmp_path / "strip.tif"), rgb)


def test_a_folder_manifest_errors_name_the_folder(tmp_path):
    from skintopo.acquisition.manifest import manifest_for_folder

    lights = [{"light": [0.6, 0, 0.8]}, {"light": [0, 0.6, 0.8]}, {"light": [-0.6, 0, 0.8]}]
    for folder, pattern, message in ((tmp_path, "{band}", "must contain {band} and {index}"), (tmp_path / "none", "{band}_{index}", "no such folder"),
                                     (tmp_path, "{band}_{index}", "no image named like '{band}_{index}'")):
        with pytest.raises(AcquisitionError) as error:
            manifest_for_folder(folder, lights, 10.0, pattern=pattern)
        assert error.value.source == str(folder) and message in str(error.value)
    for index in (1, 2, 3):
        write_png(tmp_path / f"red_{index}.png", np.zeros((4, 4), np.uint16))
    lights[1]["intensity"] = 2.5
    manifest = manifest_for_folder(tmp_path, lights, 10.0, mask=tmp_path / "sub" / "mask.png")
    assert [e.get("intensity") for e in manifest["images"]] == [None, 2.5, None] and manifest["mask"] == "mask.png"
    with pytest.raises(SkinTopoError, match=r"unknown band 'purple'; choose from \['red', 'green', 'blue', 'white'\]"):
        write_acquisition(tmp_path / "new", {"purple": (np.zeros((3, 4, 4)), np.eye(3))}, 10.0)


def _write_dng(path, mosaic):
    """A minimal DNG (TIFF with the DNG tags LibRaw needs): an RGGB colour filter mosaic, black
    level 0, white level 65535, identity colour matrix."""
    tags = [(50706, "B", 4, (1, 4, 0, 0), True),  # DNGVersion
            (50708, "s", 0, "skintopo test camera", True),  # UniqueCameraModel
            (33421, "H", 2, (2, 2), True),  # CFARepeatPatternDim
            (33422, "B", 4, (0, 1, 1, 2), True),  # CFAPattern: R G / G B
            (50717, "I", 1, 65535, True),  # WhiteLevel
            (50714, "H", 1, 0, True),  # BlackLevel
            (50721, "2i", 9, (1, 1, 0, 1, 0, 1, 0, 1, 1, 1, 0, 1, 0, 1, 0, 1, 1, 1), True)]  # ColorMatrix1 = I
    tifffile.imwrite(path, mosaic, photometric=32803, extratags=tags, subfiletype=0)


def test_camera_raw_is_read_linear_in_the_cameras_own_channels(tmp_path):
    """A DNG whose mosaic records red 4000, green 12000 and blue 30000 counts everywhere reads
    back as exactly those 16-bit values in every pixel (demosaiced, no gamma, no white balance,
    no brightening, the camera's channels); a file that is not raw is named."""
    mosaic = np.zeros((32, 48), np.uint16)
    mosaic[0::2, 0::2], mosaic[0::2, 1::2], mosaic[1::2, 0::2], mosaic[1::2, 1::2] = 4000, 12000, 12000, 30000
    _write_dng(tmp_path / "capture.dng", mosaic)
    image = read_image(tmp_path / "capture.dng")
    assert image.shape == (32, 48, 3) and image.dtype == np.uint16
    np.testing.assert_array_equal(image[2:-2, 2:-2], np.broadcast_to([4000, 12000, 30000], (28, 44, 3)))
    (tmp_path / "broken.nef").write_bytes(b"not a raw file")
    with pytest.raises(SkinTopoError, match="broken.nef: not a readable camera raw file"):
        read_image(tmp_path / "broken.nef")
