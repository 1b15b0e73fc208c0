"""Near-field photometric stereo against the simulator, a second renderer, and LED calibration."""

from dataclasses import replace

import numpy as np
import pytest

from skintopo.device import paper_device
from skintopo.filters import polynomial_form, sphere_fit
from skintopo.height import integrate_normals
from skintopo.nearfield import near_field_photometric_stereo, per_pixel_photometric_stereo, remaining_change_um
from skintopo.normals import photometric_stereo
from skintopo.synth import Effects, RenderSettings, preset_spec, simulate_acquisition
from skintopo.synth.nearfield import camera_grid_surface, device_surface, simulate_device_acquisition


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


def test_a_started_band_takes_the_start_bands_shadows_but_not_its_saturation():
    """Green started from red keeps red's shadow decisions (shadows are geometry) but not
    red's saturated observations: where red lost an LED to saturation, green still uses it,
    and green's own saturated observations are left out."""
    device, _, bands, _, _ = _scene(128)
    red_images, green_images = bands["red"].copy(), bands["green"].copy()
    red_images[0, 40:60, 40:60] = np.nan  # saturated in red only
    green_images[1, 70:80, 70:80] = np.nan  # saturated in green only
    red_images[2, 90:100, 20:30] *= 0.01  # a shadow red's rule sees
    red = near_field_photometric_stereo(red_images, device, "red")
    green = near_field_photometric_stereo(green_images, device, "green", start=red)
    assert not red.used[0, 40:60, 40:60].any() and not red.shadowed[0, 40:60, 40:60].any()
    assert green.used[0, 40:60, 40:60].all()
    assert not green.used[1, 70:80, 70:80].any()
    lit = np.isfinite(green_images) & ~red.shadowed
    np.testing.assert_array_equal(green.used, lit)
    assert red.shadowed[2, 90:100, 20:30].all() and not green.used[2, 90:100, 20:30].any()


@pytest.mark.parametrize("q", [0.05, 0.3, 0.8])
def test_remaining_change_is_the_distance_to_the_fixed_point_of_a_linear_contraction(q):
    """For x_{k+1} = q x_k + c the distance still to go after a step is exactly q / (1 - q)
    times that step (the fixed point c / (1 - q) computed here, not by the function);
    before two changes, or while the changes grow, nothing is promised (infinity)."""
    c, x = 3.0, 0.0
    changes = []
    for _ in range(4):
        new = q * x + c
        changes.append(abs(new - x))
        x = new
    assert remaining_change_um(changes) == pytest.approx(abs(c / (1 - q) - x), rel=1e-9)
    assert remaining_change_um(changes[:1]) == np.inf
    assert remaining_change_um([1.0, 2.0]) == np.inf


def test_remaining_change_uses_the_prior_contraction_until_the_changes_give_one():
    """With one change the bound needs the contraction from elsewhere (another band of the
    same capture); with two, the changes' own."""
    assert remaining_change_um([2.0], prior=0.2) == pytest.approx(2.0 * 0.2 / 0.8)
    assert remaining_change_um([2.0, 0.1], prior=0.9) == pytest.approx(0.1 * 0.05 / 0.95)
    assert remaining_change_um([2.0], prior=None) == np.inf


def test_per_pixel_solve_recovers_rho_n_under_the_leds_and_leaves_shadows_out():
    """Intensities made with the LED model's own light vectors (Led.light_vectors, NumPy) at
    random points on a 150 mm plane, for known albedo x normal, LEDs of four angular
    fall-offs: the compiled per-pixel solve gives g back; an observation darkened to a
    shadow is left out (and g is still exact from the other three); a pixel with two lit
    LEDs is invalid."""
    device = paper_device(size_px=64)
    device = replace(device, leds=tuple(replace(led, mu=mu) for led, mu in zip(device.leds, (1.0, 1.6, 0.0, 2.3))))
    rng = np.random.default_rng(3)
    count = 500
    rays = np.stack([rng.uniform(-0.2, 0.2, count), rng.uniform(-0.2, 0.2, count), -np.ones(count)])
    depth = rng.uniform(145.0, 155.0, count)
    normals = np.stack([rng.uniform(-0.3, 0.3, count), rng.uniform(-0.3, 0.3, count), np.ones(count)])
    g_true = 0.6 * normals / np.linalg.norm(normals, axis=0)
    lights = np.stack([led.light_vectors(depth * rays, "green") for led in device.leds]) * device.working_distance_mm**2
    intensity = np.einsum("mkp,kp->mp", lights, g_true)
    intensity[1, :100] *= 0.01  # shadowed
    intensity[:2, 100:110] = 0.0  # only two lit
    normals, albedo, residual, used = per_pixel_photometric_stereo(intensity, rays, depth, device, "green")
    g = albedo * normals
    fine = np.ones(count, bool)
    fine[100:110] = False
    np.testing.assert_allclose(g[:, fine], g_true[:, fine], rtol=1e-4, atol=1e-6)
    assert not used[1, :100].any() and used[:, 110:].all()
    assert np.isnan(g[:, 100:110]).all()
    assert np.nanmax(residual[fine]) < 1e-8


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


@pytest.mark.slow
def test_on_shiny_skin_the_device_matches_ideal_lights_once_the_highlights_colour_is_calibrated():
    """Skin optics (`default-v1`: translucency, a slightly blue surface reflection, cast shadows,
    albedo variation), 512 px through the paper-like device, red after the cross-band
    separation: with the highlight taken as white the device is 3.5 um worse than ideal
    lights (measured 19.02 against 15.56 um after form); with the colour measured from a
    cross-polarised repeat capture (:func:`skintopo.calibration.specular_colour_from_differences`;
    the same skin rendered without surface reflection, other noise) 0.77 um (11.26 against
    10.49 um), the radius -1.00% (ideal -0.91%; at 1000 px -0.95%)."""
    from skintopo.calibration import specular_colour_from_differences
    from skintopo.normals import separate_specular

    rgb = ("red", "green", "blue")
    device = paper_device(size_px=512)
    spec = replace(preset_spec("forehead-moderate", size_px=512, pixel_um=device.pixel_um), form_shape="sphere", form_radius_mm=80.0)
    surface = device_surface(spec, device, seed=1)
    crop = camera_grid_surface(surface, device)
    truth, lights = crop.height, device.central_directions()
    settings = RenderSettings(effects=Effects(interreflection=False), noise=1.0)
    crossed = replace(settings, effects=Effects(interreflection=False, specular=False))

    def exposed(bands, info):
        return {b: (bands[b][0] if isinstance(bands[b], tuple) else bands[b]) / info["exposure_gain"][b] for b in rgb}

    near = exposed(*simulate_device_acquisition(surface, device, settings, seed=1))
    near_crossed = exposed(*simulate_device_acquisition(surface, device, crossed, seed=2, skin_seed=1))
    ideal = exposed(*simulate_acquisition(crop, replace(settings, lights=lights), seed=1))
    ideal_crossed = exposed(*simulate_acquisition(crop, replace(crossed, lights=lights), seed=2, skin_seed=1))
    colours = [specular_colour_from_differences(near, near_crossed)[0], specular_colour_from_differences(ideal, ideal_crossed)[0]]
    np.testing.assert_allclose(colours, [[0.956, 1.0, 1.044]] * 2, atol=0.003)  # the renders' Fresnel colour

    def red(images, colour):
        return images["red"] - separate_specular(*(images[b] for b in rgb), specular_colour=colour).band_specular("red")

    gaps = []
    for colour_near, colour_ideal in ((None, None), colours):
        height = near_field_photometric_stereo(red(near, colour_near), device, "red").height
        ideal_height = integrate_normals(photometric_stereo(red(ideal, colour_ideal), lights).normals, truth.spacing)
        gaps.append(_after_form(height, truth) - _after_form(ideal_height, truth))
    assert gaps[0] > 2.0 and gaps[1] < 1.5
    assert sphere_fit(height)[0] / 1000 == pytest.approx(80.0, rel=0.012)
