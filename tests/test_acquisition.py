"""Reading, validating and refusing acquisitions; the reconstruct command end to end."""

import json

import numpy as np
import tifffile
import pytest
from analytic import rms_error_after_offset

from skintopo.acquisition import load_acquisition, read_image
from skintopo.cli import main
from skintopo.errors import AcquisitionError
from skintopo.formats import write_png
from skintopo.heightmap import HeightMap
from skintopo.normals import angular_error_degrees


def edit_manifest(folder, change):
    path = folder / "acquisition.json"
    manifest = json.loads(path.read_text())
    change(manifest)
    path.write_text(json.dumps(manifest))


def run_reconstruct(folder, out, capsys, *extra):
    code = main(["reconstruct", str(folder), "-o", str(out), "-q", *extra])
    return code, capsys.readouterr().err


def assert_refused(folder, tmp_path, capsys, *fragments):
    out = tmp_path / "out"
    code, err = run_reconstruct(folder, out, capsys)
    assert code == 2
    assert "Traceback" not in err
    for fragment in fragments:
        assert fragment in err, err
    assert not out.exists()
    assert not list(tmp_path.glob(".out.*"))  # no staging folder left behind
    return err


def test_reconstruct_end_to_end(lambertian_acquisition, tmp_path, capsys):
    folder, z, normals = lambertian_acquisition
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    out = tmp_path / "out"
    assert main(["reconstruct", str(folder), "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "red" in printed and "wrote" in printed
    for band in ("red", "green", "blue"):
        got = np.load(out / band / "normals.npy")
        assert got.dtype == np.float32 and got.shape == normals.shape
        error = angular_error_degrees(got, normals)
        assert np.nanmean(error) < 0.1  # 16-bit quantisation only
        height = HeightMap.load(out / band / "height.x3p")
        assert height.spacing == (10.0, 10.0)
        assert rms_error_after_offset(height.z, z) < 0.01 * np.ptp(z)
        albedo = np.load(out / band / "albedo.npy")
        assert albedo.shape == z.shape
    summary = json.loads((out / "summary.json").read_text())
    assert summary["options"]["integrator"] == "auto" and summary["acquisition"]["pixel_um"] == 10.0
    assert str(folder.parent) not in (out / "summary.json").read_text()  # no input path recorded
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before  # inputs untouched


def test_refuses_non_empty_output_unless_overwrite(lambertian_acquisition, tmp_path, capsys):
    folder, _, _ = lambertian_acquisition
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("x")
    code, err = run_reconstruct(folder, out, capsys)
    assert code == 2 and "not empty" in err and (out / "keep.txt").exists()
    code, _ = run_reconstruct(folder, out, capsys, "--overwrite", "--band", "green")
    assert code == 0 and not (out / "keep.txt").exists() and (out / "green" / "height.x3p").exists()
    assert not (out / "red").exists()


def test_refuses_output_over_the_input(lambertian_acquisition, tmp_path, capsys):
    folder, _, _ = lambertian_acquisition
    code, err = run_reconstruct(folder, folder, capsys, "--overwrite")
    assert code == 2 and "overlaps the input" in err
    assert (folder / "acquisition.json").exists()


def test_missing_file(lambertian_acquisition, tmp_path, capsys):
    folder, _, _ = lambertian_acquisition
    (folder / "green_02.png").unlink()
    assert_refused(folder, tmp_path, capsys, "green_02.png: image file not found")


def test_mismatched_image_sizes(lambertian_acquisition, tmp_path, capsys):
    folder, _, _ = lambertian_acquisition
    write_png(folder / "blue_01.png", np.zeros((20, 30), np.uint16))
    assert_refused(folder, tmp_path, capsys, "blue_01.png: image size 30x20 differs")


def test_bit_depth_mix(lambertian_acquisition, tmp_path, capsys):
    folder, _, _ = lambertian_acquisition
    write_png(folder / "red_03.png", np.zeros((48, 64), np.uint8))
    assert_refused(folder, tmp_path, capsys, "red_03.png: pixel type uint8 differs", "one bit depth")


def test_fewer_than_three_lights(lambertian_acquisition, tmp_path, capsys):
    folder, _, _ = lambertian_acquisition
    edit_manifest(folder, lambda m: m.update(images=[e for e in m["images"] if e["band"] != "red" or e["file"] < "red_02"]))
    assert_refused(folder, tmp_path, capsys, "band red: only 2 light(s)")


def test_coplanar_lights(lambertian_acquisition, tmp_path, capsys):
    folder, _, _ = lambertian_acquisition

    def flatten(manifest):  # put every red light in the x-z plane
        for entry in manifest["images"]:
            if entry["band"] == "red":
                x, y, zc = entry["light"]
                r = np.hypot(x, y)
                entry["light"] = [r if x + y >= 0 else -r, 0.0, zc]

    edit_manifest(folder, flatten)
    assert_refused(folder, tmp_path, capsys, "band red: the light directions are coplanar")


@pytest.mark.parametrize("light, message", [([0.5, 0.0, 0.5], "is not a unit vector (norm 0.7071)"), ([0, 0, 0], "is the zero vector")])
def test_bad_light_vector(lambertian_acquisition, tmp_path, capsys, light, message):
    folder, _, _ = lambertian_acquisition
    edit_manifest(folder, lambda m: m["images"][5].update(light=light))
    assert_refused(folder, tmp_path, capsys, "images[5] (green_01.png)", message)


def test_malformed_manifest_reports_every_problem(lambertian_acquisition, tmp_path, capsys):
    folder, _, _ = lambertian_acquisition

    def break_it(manifest):
        manifest["pixel_size_um"] = -2
        manifest["images"][0]["band"] = "purple"
        manifest["images"][1]["ligth"] = [0, 0, 1]
        manifest["images"][2]["light"] = "up"

    edit_manifest(folder, break_it)
    err = assert_refused(
        folder, tmp_path, capsys,
        "4 problem(s)",
        "'pixel_size_um' must be a positive number",
        "images[0] (red_00.png): field 'band' must be one of",
        "images[1] (red_01.png): unknown field 'ligth'",
        "images[2] (red_02.png): field 'light' must be a list of 3 numbers",
    )
    assert err.count("  - ") == 4


def test_manifest_that_is_not_json(lambertian_acquisition, tmp_path, capsys):
    folder, _, _ = lambertian_acquisition
    (folder / "acquisition.json").write_text('{"format": "skintopo-acquisition", ')
    assert_refused(folder, tmp_path, capsys, "acquisition.json", "not valid JSON")


def test_mask_of_the_wrong_size(lambertian_acquisition, tmp_path, capsys):
    folder, _, _ = lambertian_acquisition
    write_png(folder / "mask.png", np.full((10, 10), 255, np.uint8))
    edit_manifest(folder, lambda m: m.update(mask="mask.png"))
    assert_refused(folder, tmp_path, capsys, "mask.png: mask size 10x10 differs from the images (64x48)")


def test_unreadable_image(lambertian_acquisition, tmp_path, capsys):
    folder, _, _ = lambertian_acquisition
    (folder / "red_00.png").write_bytes(b"\x89PNG garbage")
    assert_refused(folder, tmp_path, capsys, "red_00.png: not a readable PNG image")


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


def test_init_writes_a_manifest_from_a_folder_and_the_calibrated_lights(tmp_path, capsys):
    from analytic import normals_from_slopes, paraboloid_with_wrinkles
    from conftest import four_lights

    from skintopo.normals import photometric_stereo, render_lambertian

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
