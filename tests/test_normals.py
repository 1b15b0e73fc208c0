import numpy as np
import pytest
from analytic import SURFACES, normals_from_slopes, plane_and_bump
from conftest import four_lights

from skintopo.errors import SkinTopoError
from skintopo.normals import angular_error_degrees, photometric_stereo, render_lambertian


@pytest.mark.parametrize("name", sorted(SURFACES))
def test_noise_free_lambertian_normals_recovered_within_0_1_degree(name):
    z, p, q = SURFACES[name]()
    truth = normals_from_slopes(p, q)
    lights = four_lights(slant_degrees=40.0, first_tilt_degrees=20.0)
    albedo = 0.3 + 0.4 * np.random.default_rng(1).random(z.shape)
    images = render_lambertian(truth, albedo, lights)  # attached shadows (n.s < 0) render as 0
    result = photometric_stereo(images, lights)
    error = angular_error_degrees(result.normals, truth)
    print(f"{name}: mean {np.nanmean(error):.2e} deg, max {np.nanmax(error):.2e} deg")
    shading = np.einsum("rci,mi->mrc", truth, lights)
    usable = (shading > 0.05 * shading.max(axis=0)).sum(axis=0)  # the default shadow rule
    np.testing.assert_array_equal(result.lights_used, usable)
    np.testing.assert_array_equal(result.valid, usable >= 3)  # steep slopes: some pixels keep only 2 lights
    assert result.valid.mean() > 0.9
    assert np.nanmax(error) < 0.1
    np.testing.assert_allclose(result.albedo[result.valid], albedo[result.valid], rtol=1e-4)
    assert np.nanmax(result.residual) < 1e-5


def test_saturated_and_shadowed_observations_are_excluded_per_pixel():
    z, p, q = plane_and_bump(shape=(40, 50))
    truth = normals_from_slopes(0.2 * p, 0.2 * q)  # gentle: no attached shadows
    lights = np.array([four_lights()[i] for i in range(4)] + [[0.0, 0.0, 1.0]])
    images = render_lambertian(truth, 0.5, lights).astype(np.float32)
    corrupted = images.copy()
    corrupted[0, :10] = np.nan  # saturated observations (NaN) in the first 10 rows
    corrupted[1, 10:20] = 0.001 * images[1, 10:20]  # a cast shadow on light 1
    result = photometric_stereo(corrupted, lights)
    error = angular_error_degrees(result.normals, truth)
    assert np.nanmax(error) < 0.1
    assert (result.lights_used[:10] == 4).all()
    assert (result.lights_used[10:20] == 4).all()
    assert (result.lights_used[20:] == 5).all()
    # Without shadow exclusion, the shadowed rows are wrong.
    naive = photometric_stereo(corrupted, lights, shadow_fraction=0.0)
    assert np.nanmean(angular_error_degrees(naive.normals, truth)[10:20]) > 5


def test_pixels_left_with_fewer_than_three_lights_are_invalid_not_guessed():
    lights = four_lights()
    normals = np.zeros((5, 6, 3))
    normals[..., 2] = 1
    images = render_lambertian(normals, 0.5, lights).astype(np.float32)
    images[:2, 2, 3] = np.nan  # two of four saturated: 2 left
    result = photometric_stereo(images, lights)
    assert not result.valid[2, 3]
    assert np.isnan(result.normals[2, 3]).all() and np.isnan(result.albedo[2, 3])
    assert result.valid.sum() == 29


def test_mask_limits_the_solve():
    lights = four_lights()
    normals = np.zeros((4, 4, 3))
    normals[..., 2] = 1
    mask = np.zeros((4, 4), bool)
    mask[1:3, 1:3] = True
    result = photometric_stereo(render_lambertian(normals, 0.5, lights), lights, mask=mask)
    np.testing.assert_array_equal(result.valid, mask)


@pytest.mark.parametrize(
    "lights, message",
    [
        ([[0, 0, 1], [0.6, 0, 0.8]], "at least 3"),
        ([[0, 0, 1], [0.6, 0, 0.8], [-0.6, 0, 0.8]], "coplanar"),
        ([[0, 0, 1], [0.6, 0, 0.8], [0, 0.5, 0.5]], "not a unit vector"),
        ([[0, 0, 1], [0.6, 0, 0.8], [0, 0, 0]], "zero vector"),
    ],
)
def test_degenerate_light_sets_are_refused(lights, message):
    images = np.ones((len(lights), 3, 3))
    with pytest.raises(SkinTopoError, match=message):
        photometric_stereo(images, lights)


def test_robust_solver_removes_one_specular_outlier_per_pixel():
    z, p, q = plane_and_bump(shape=(40, 50))
    truth = normals_from_slopes(0.2 * p, 0.2 * q)
    lights = np.array([four_lights()[i] for i in range(4)] + [[0.0, 0.0, 1.0]])
    images = render_lambertian(truth, 0.5, lights).astype(np.float32)
    images[2, 5:30] += 0.3  # a highlight in light 2
    plain = photometric_stereo(images, lights)
    robust = photometric_stereo(images, lights, solver="robust")
    assert np.nanmean(angular_error_degrees(plain.normals, truth)[5:30]) > 5
    assert np.nanmax(angular_error_degrees(robust.normals, truth)) < 0.1
    assert not robust.used[2, 5:30].any() and robust.used[2, 30:].all()


def test_specular_free_band_removes_white_highlights():
    from skintopo.normals import specular_free_images

    z, p, q = plane_and_bump(shape=(40, 50))
    truth = normals_from_slopes(0.2 * p, 0.2 * q)
    lights = four_lights()
    highlight = np.zeros((4, 40, 50))
    highlight[1, 10:20] = 0.2  # the same (white) specular in every band
    bands = [render_lambertian(truth, albedo, lights) + highlight for albedo in (0.6, 0.41, 0.33)]
    free = photometric_stereo(specular_free_images(*bands), lights)
    assert np.nanmax(angular_error_degrees(free.normals, truth)) < 0.1
    assert np.nanmean(angular_error_degrees(photometric_stereo(bands[2], lights).normals, truth)[10:20]) > 5
