"""The real device (issue 22): device file checks, the camera and LED models against closed
forms, and near-field photometric stereo against the simulator's raw geometry (a forehead
on a sphere of 80 mm seen through a paper-like device)."""

import json
import warnings
from dataclasses import replace

import numpy as np
import pytest

from skintopo.device import DeviceError, Camera, Led, paper_device, parse_device, read_device
from skintopo.filters import polynomial_form, sphere_fit
from skintopo.height import integrate_normals
from skintopo.nearfield import near_field_photometric_stereo
from skintopo.normals import photometric_stereo
from skintopo.synth import Effects, RenderSettings, preset_spec, simulate_acquisition
from skintopo.synth.nearfield import device_surface, simulate_device_acquisition, camera_grid_surface


def _device_dict(**changes):
    data = paper_device(size_px=64).describe()
    data.update(changes)
    return data


def test_device_file_round_trip(tmp_path):
    device = paper_device(size_px=64)
    path = tmp_path / "device.json"
    path.write_text(json.dumps(device.describe()))
    again = read_device(path)
    assert again.leds == device.leds and again.camera.focal_length_px == pytest.approx(device.camera.focal_length_px)
    assert again.pixel_um == pytest.approx(65000 / 64)


@pytest.mark.parametrize("change, message", [
    (lambda d: d["camera"].update(focal_length_mm=0), "focal_length_mm must be a positive number"),
    (lambda d: d["camera"].update(focal_length_mm=-17), "focal_length_mm must be a positive number"),
    (lambda d: d["leds"][1].update(position_mm=[0, 60, -170]), "LED 'north' at z = -170 mm is behind the skin"),
    (lambda d: d["leds"][0].update(direction=[0, 0, 1]), "points away from the skin"),
    (lambda d: d["leds"][0].update(mu=-1), "mu must be a number >= 0"),
    (lambda d: d["leds"][2].update(intensity={"red": 0}), "intensity of red must be a positive number"),
    (lambda d: d.update(leds=d["leds"][:2]), "only 2 light(s)"),
    (lambda d: d["leds"][0].update(position_mm="far"), "'position_mm' must be [x, y, z] in millimetres"),
    (lambda d: d.update(colour="blue"), "unknown field 'colour'"),
])
def test_bad_device_files_get_clear_messages(tmp_path, change, message):
    data = _device_dict()
    change(data)
    path = tmp_path / "device.json"
    path.write_text(json.dumps(data))
    with pytest.raises(DeviceError) as caught:
        read_device(path)
    assert message in str(caught.value) and "device.json" in str(caught.value)


@pytest.mark.parametrize("working, height", [(0.15, -0.1495), (150.0, -0.07)])
def test_positions_in_metres_are_warned_about(working, height):
    """Everything in metres (LEDs 0.5 um above the skin), or the LEDs alone (all at the camera)."""
    data = _device_dict(working_distance_mm=working)
    data["leds"] = [{"name": f"led{i}", "position_mm": [0.06 * np.cos(a), 0.06 * np.sin(a), height]}
                    for i, a in enumerate(np.radians([0, 90, 180, 270]))]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            parse_device(data, "metres.json")
            messages = [str(w.message) for w in caught]
        except DeviceError as error:  # LEDs at the camera also leave no usable light geometry
            messages = [str(error)]
    assert any("given in metres" in m and "metres.json" in m for m in messages), messages
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        parse_device(_device_dict(), "millimetres.json")
    assert not caught


def test_camera_projection_inverts_its_rays_with_distortion():
    camera = Camera(12.0, 5.0, (40, 60), (31.2, 18.7), (-0.08, 0.02))
    columns, rows = np.meshgrid(np.linspace(0, 59, 7), np.linspace(0, 39, 5))
    a, b = camera.rays(columns, rows)
    depth = 97.0
    u, v = camera.project(np.stack([depth * a, depth * b, np.full(a.shape, -depth)]))
    assert np.allclose(u, columns, atol=1e-6) and np.allclose(v, rows, atol=1e-6)


def test_led_light_vector_is_inverse_square_with_its_angular_fall_off():
    # Closed forms: an isotropic source straight above gives Phi / r^2 along the axis; a
    # Lambertian emitter (mu = 1) seen 30 degrees off its axis gives cos(30) Phi / r^2.
    above = Led("a", (0.0, 0.0, -50.0), (0.0, 0.0, -1.0), mu=0.0, intensity={"red": 2.0})
    s = above.light_vectors(np.array([[0.0], [0.0], [-150.0]]), "red")[:, 0]
    assert np.allclose(s, [0, 0, 2.0 / 100.0**2])
    tilted = Led("b", (0.0, 0.0, 0.0), (0.0, 0.0, -1.0), mu=1.0)
    point = 80.0 * np.array([np.sin(np.radians(30)), 0.0, -np.cos(np.radians(30))])
    s = tilted.light_vectors(point[:, None])[:, 0]
    assert np.linalg.norm(s) == pytest.approx(np.cos(np.radians(30)) / 80.0**2)
    assert np.allclose(s / np.linalg.norm(s), -point / 80.0)


def _scene(size=256):
    device = paper_device(size_px=size)
    spec = replace(preset_spec("forehead-moderate", size_px=size, pixel_um=device.pixel_um), form_shape="sphere",
                   form_radius_mm=80.0, microrelief=False)
    surface = device_surface(spec, device, seed=1)
    bands, _ = simulate_device_acquisition(surface, device, RenderSettings(effects=Effects.none(), noise=1.0), seed=1)
    crop = camera_grid_surface(surface, device)
    return device, crop, bands, crop.height, crop.wrinkle_labels


def _after_form(height, truth):
    error = height.z - truth.z
    valid = np.isfinite(error)
    form = polynomial_form(np.where(valid, error, 0.0), truth.spacing, order=2, mask=valid)
    return float(np.sqrt(np.mean((error - form)[valid] ** 2)))


def test_near_field_solver_recovers_the_forehead_that_a_distant_light_solver_bends():
    """Simulated paper-like device (65 mm field, 256 px here: 254 um pixels), Lambertian skin,
    sensor noise: the near-field height has the error of the same scene under ideal distant
    lights (+ 0.65 um after form removal, measured), the forehead radius within 0.2% (0.15%);
    the distant-light solver on the same images bends it (radius -48%, 350 um after form)."""
    device, crop, bands, truth, labels = _scene()
    near = near_field_photometric_stereo(bands["red"], device, "red")
    assert near.converged and near.height.mask.mean() > 0.99
    near_error = _after_form(near.height, truth)
    radius_mm = sphere_fit(near.height)[0] / 1000
    assert radius_mm == pytest.approx(80.0, rel=2e-3)

    lights = device.central_directions()
    ideal, _ = simulate_acquisition(crop, RenderSettings(lights=lights, effects=Effects.none(), noise=1.0), seed=1)
    ideal_error = _after_form(integrate_normals(photometric_stereo(ideal["red"][0], lights).normals, truth.spacing), truth)
    assert near_error < ideal_error + 2.0

    bent = integrate_normals(photometric_stereo(bands["red"], lights).normals, truth.spacing)
    assert _after_form(bent, truth) > 50 * near_error
    assert sphere_fit(bent)[0] / 1000 < 60.0


def test_a_band_started_from_another_bands_depth_reaches_its_own_height():
    """The pipeline starts green and blue from red's depth and keeps red's scale (one distance
    per capture; a band's own photometric scale differs by about 0.1%, which scales the 7 mm
    form by micrometres): after form removal the height is as good as the one solved from
    scratch (3.47 against 3.36 um at 256 px, measured; asserted within 0.3 um), the radius
    within 0.5%."""
    device, _, bands, truth, _ = _scene(256)
    red = near_field_photometric_stereo(bands["red"], device, "red")
    alone = near_field_photometric_stereo(bands["blue"], device, "blue")
    started = near_field_photometric_stereo(bands["blue"], device, "blue", start=red)
    assert started.converged and started.options["start"]["band"] == "red"
    assert len(started.changes_um) <= len(alone.changes_um)
    assert _after_form(started.height, truth) < _after_form(alone.height, truth) + 0.3
    assert sphere_fit(started.height)[0] / 1000 == pytest.approx(80.0, rel=5e-3)


def test_working_distance_scale_is_off_by_the_depth_the_forehead_falls_away():
    """The photometric scale finds the forehead's distance; fixing the median depth at the
    working distance instead scales the whole shape by the median fall-off (about 3% here,
    so the radius is about 3% off): the option exists for devices held at a known distance."""
    device, _, bands, truth, _ = _scene(128)
    photometric = near_field_photometric_stereo(bands["red"], device, "red")
    fixed = near_field_photometric_stereo(bands["red"], device, "red", scale="working-distance")
    assert sphere_fit(photometric.height)[0] / 1000 == pytest.approx(80.0, rel=5e-3)
    assert abs(sphere_fit(fixed.height)[0] / 1000 / 80.0 - 1) > 0.01


def test_wrong_image_count_is_refused():
    device = paper_device(size_px=32)
    with pytest.raises(Exception, match="expected 4 images"):
        near_field_photometric_stereo(np.ones((3, 32, 32)), device, "red")


def test_leds_calibrated_from_chrome_spheres_at_two_places_and_a_flat_target():
    """Rendered chrome sphere (10 mm radius) at two places in the depth of field and a flat
    matte target, seen by the paper-like device whose 4 LEDs (about 100 mm from the spheres)
    have mu 1.0 / 1.6 / 2.3 / 0.8, tilted axes and unequal intensities: positions within 1 mm,
    mu within 10%, directions within 1 degree, intensities within 3%."""
    from skintopo.calibration import calibrate_device
    from skintopo.device import aimed_at
    from skintopo.synth.nearfield import SPHERE_PLACES_MM, device_flat_images, device_sphere_images

    device = paper_device(size_px=1000)
    truth = tuple(replace(led, mu=mu, direction=aimed_at(led.position_mm, (3.0 * (i - 1.5), -2.0, -150.0)),
                          intensity={band: share for band in ("red", "green", "blue")})
                  for i, (led, mu, share) in enumerate(zip(device.leds, (1.0, 1.6, 2.3, 0.8), (1.0, 0.9, 0.8, 1.1))))
    device = replace(device, leds=truth)
    places = [device_sphere_images(device, centre, 10.0, seed=k) for k, centre in enumerate(SPHERE_PLACES_MM)]
    found, details = calibrate_device(device.camera, 150.0, places, 10.0, flat_images=device_flat_images(device, 150.0),
                                      names=[led.name for led in truth])
    assert np.allclose(details["sphere_centres_mm"], SPHERE_PLACES_MM, atol=0.05)
    errors = []
    for true, led in zip(truth, found.leds):
        errors.append((np.linalg.norm(np.subtract(led.position_mm, true.position_mm)), led.mu / true.mu - 1))
        assert errors[-1][0] < 1.0, (true.name, led.position_mm)
        assert led.mu == pytest.approx(true.mu, rel=0.1)
        assert np.degrees(np.arccos(min(1.0, np.dot(led.direction, true.direction)))) < 1.0
        assert led.intensity["red"] == pytest.approx(true.intensity["red"] / 1.1, rel=0.03)


def test_one_sphere_place_is_not_enough():
    from skintopo.calibration import led_positions_from_chrome_spheres

    with pytest.raises(Exception, match="two or more places"):
        led_positions_from_chrome_spheres([[np.zeros((8, 8))] * 4], paper_device(size_px=8).camera, 10.0)


@pytest.mark.slow
def test_a_second_renderer_confirms_the_near_field_solver(mitsuba_renderer):
    """Mitsuba 3 renders the same forehead (mesh with smooth normals, direct light) through the
    device (``perspective`` sensor, ``point`` emitters: isotropic LEDs, mu = 0) and, as the ideal,
    by an orthographic camera under distant lights. As in our simulator, the near-field height is
    as good as the ideal one after form removal (5.2 vs 5.9 um at 256 px, measured; ours 3.7 vs
    2.8), within a factor of 1.5 and 2 um, and the radius within 0.5% (0.07%)."""
    renderer = mitsuba_renderer
    device = paper_device(size_px=256)
    device = replace(device, leds=tuple(replace(led, mu=0.0) for led in device.leds))
    spec = replace(preset_spec("forehead-moderate", size_px=256, pixel_um=device.pixel_um), form_shape="sphere",
                   form_radius_mm=80.0, microrelief=False)
    surface = device_surface(spec, device, seed=1)
    truth = camera_grid_surface(surface, device)
    albedo = (0.6, 0.45, 0.35)
    through_device = renderer.render_device(surface.height.z, device.pixel_um, device, albedo, spp=16, seed=1)
    near = near_field_photometric_stereo(through_device[0], device, "red")
    lights = device.central_directions()
    ideal_images = renderer.render(truth.height.z, device.pixel_um, lights, albedo, spp=16, max_depth=2, seed=1, face_normals=False)
    ideal = integrate_normals(photometric_stereo(ideal_images[0], lights).normals, truth.height.spacing)
    near_error, ideal_error = _after_form(near.height, truth.height), _after_form(ideal, truth.height)
    assert near_error < 1.5 * ideal_error and near_error < ideal_error + 2.0, (near_error, ideal_error)
    assert sphere_fit(near.height)[0] / 1000 == pytest.approx(80.0, rel=5e-3)


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
